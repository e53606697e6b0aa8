//! A test-only OPT8241-CDK on the kernel's real USB stack: a configfs gadget
//! (0451:9105) with a FunctionFS function, bound to dummy_hcd's UDC, so the
//! backend reaches it through libusb exactly as it reaches the board.
//!
//! [`BoardEmulator::start_uvc`] first presents the board in UVC mode
//! (0451:9106, a VideoControl interface 0); the UVC SET_CUR of extension
//! unit 3, control 6 makes it re-enumerate as the bulk-mode board, as the
//! FX2 firmware does (`uvc.c`, `RENUMERATE_UNCOND`).
//!
//! The emulator keeps a register file with the firmware's laser-safety masks,
//! answers the vendor requests (0x08/0x09 registers, 0x1A version, 0x30
//! revision, 0x32 serial) and, while tg_dis = 0, streams simulator frames in
//! the raw-quad format (or, with output_mode = 0, depth frames whose flags
//! mark saturated pixels, `chip.rs`), each ended by a zero-length packet,
//! with the frame number in byte 0 when debug_frame_number_en is set. The
//! test sets a phase delay on the LED path (`led_delay_rad`), which sources
//! light the scene (`unlit`, e.g. from [`crate::light_rig`] as sdid drives
//! it) and a saturated region. It is written from the public descriptions,
//! independently of the backend's code.
//! Runs only as root inside the VM (modules dummy_hcd, libcomposite, usb_f_fs).

pub mod chip;
mod descriptors;
pub mod hostile;

use std::collections::HashMap;
use std::fs::{self, File, OpenOptions};
use std::io::{Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use sdi_core::modulation::{Illumination, SourceDrive};
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::SensorPreset;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

const GADGET_ROOT: &str = "/sys/kernel/config/usb_gadget";

/// One register write the emulator received.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RegisterWrite {
    pub address: u16,
    pub written: u32,
    pub kept: u32,
    /// When the write arrived (the PLL settle time, `chip.rs`).
    pub at: std::time::Instant,
}

/// State shared by the emulator threads and the test.
#[derive(Default)]
pub struct BoardState {
    pub registers: HashMap<u16, u32>,
    pub writes: Vec<RegisterWrite>,
    /// Frames sent, by frame number: the difference image encoded (DN).
    pub sent: Vec<(u8, Vec<f32>)>,
    /// Unknown requests seen (they were stalled).
    pub stalled: Vec<(u8, u8, u16, u16)>,
    /// UVC class requests received in UVC mode: (bmRequestType, bRequest,
    /// wValue, wIndex as FunctionFS passes it, data).
    pub uvc_requests: Vec<(u8, u8, u16, u16, Vec<u8>)>,
    /// When the gadget came back as 0451:9105 after the switch.
    pub switched_to_bulk: Option<Instant>,
    /// op_overflow reads set whatever the configuration (`chip.rs`).
    pub force_overflow: bool,
    /// Delay between the modulation and the LED light, as a phase of the
    /// modulation, radians ([`encode_raw_quads_delayed`]).
    pub led_delay_rad: f64,
    /// LS1, LS2 switched off (by the test's light rig); both lit by default.
    pub unlit: [bool; 2],
    /// Pixels whose wells both fill (`chip.rs`, [`chip::SaturatedRegion`]).
    pub saturated_region: Option<chip::SaturatedRegion>,
}

fn field(reg: u32, msb: u32, lsb: u32) -> u32 {
    (reg >> lsb) & ((1 << (msb - lsb + 1)) - 1)
}

impl BoardState {
    fn reg(&self, a: u16) -> u32 {
        self.registers.get(&a).copied().unwrap_or(0)
    }

    /// Current value of a register (0 if never written).
    pub fn reg_value(&self, a: u16) -> u32 {
        self.reg(a)
    }

    /// The firmware's laser-safety masks (reference firmware
    /// `vendorcommand.c`, `maskTFCRegisters`).
    fn mask(address: u16, mut v: u32) -> u32 {
        match address {
            0x5C4C => {
                if v & 0x3F > 20 {
                    v = (v & !0x3F) | 20;
                }
                v &= !(1 << 22);
            }
            0x580E => v &= !(0x1F << 13),
            0x5882 if v & 0x3F_0000 == 0 && v & 0xFFFF < 60_000 => v = (v & !0xFFFF) | 60_000,
            _ => {}
        }
        v
    }

    fn geometry(&self) -> (usize, usize, usize) {
        let rows =
            field(self.reg(0x581F), 23, 16) as i64 - field(self.reg(0x581F), 7, 0) as i64 + 1;
        let cols =
            (field(self.reg(0x5821), 7, 3) as i64 - field(self.reg(0x5820), 7, 3) as i64 + 1) * 16;
        let quads = field(self.reg(0x5883), 3, 0).max(1);
        (cols.max(16) as usize, rows.max(1) as usize, quads as usize)
    }

    fn frame_period(&self) -> Duration {
        let pix = field(self.reg(0x5882), 21, 0).max(1) as f64;
        let quads = field(self.reg(0x5883), 3, 0).max(1) as f64;
        let subs = field(self.reg(0x5883), 7, 4).max(1) as f64;
        Duration::from_secs_f64(pix * quads * subs / 48e6)
    }
}

/// Encodes a difference image as raw quads: q0 = d, q2 = -d, others 0,
/// 12-bit two's complement in bits 11:0, little-endian, pixel-major.
pub fn encode_raw_quads(dn: &[f32], quads: usize) -> (Vec<u8>, Vec<f32>) {
    let mut out = vec![0u8; dn.len() * quads * 2];
    let mut kept = Vec::with_capacity(dn.len());
    for (px, &d) in out.chunks_exact_mut(quads * 2).zip(dn) {
        let q0 = d.round().clamp(-2048.0, 2047.0) as i32;
        kept.push(q0 as f32);
        let w0 = (q0 & 0xFFF) as u16;
        let w2 = ((-q0) & 0xFFF) as u16;
        px[0..2].copy_from_slice(&w0.to_le_bytes());
        if quads > 2 {
            px[4..6].copy_from_slice(&w2.to_le_bytes());
        }
    }
    (out, kept)
}

/// [`encode_raw_quads`] with the light arriving `delay_rad` of a
/// modulation period late: the difference d spread over the quads as its
/// first harmonic, q_k = d cos(2 pi k / N - delay) (each quad rounded and
/// clamped to 12 bits). No delay is exactly [`encode_raw_quads`]. The
/// second vector is d as sent (rounded, clamped): what a decoder that
/// knows the delay recovers.
pub fn encode_raw_quads_delayed(dn: &[f32], quads: usize, delay_rad: f64) -> (Vec<u8>, Vec<f32>) {
    if delay_rad == 0.0 {
        return encode_raw_quads(dn, quads);
    }
    let mut out = vec![0u8; dn.len() * quads * 2];
    let mut kept = Vec::with_capacity(dn.len());
    for (px, &d) in out.chunks_exact_mut(quads * 2).zip(dn) {
        let d = f64::from(d.round().clamp(-2048.0, 2047.0));
        kept.push(d as f32);
        for k in 0..quads {
            let phase = std::f64::consts::TAU * k as f64 / quads as f64 - delay_rad;
            let q = (d * phase.cos()).round().clamp(-2048.0, 2047.0) as i32;
            px[2 * k..2 * k + 2].copy_from_slice(&((q & 0xFFF) as u16).to_le_bytes());
        }
    }
    (out, kept)
}

/// What the emulator threads share.
struct Inner {
    name: String,
    serial: String,
    gadget: PathBuf,
    state: Arc<Mutex<BoardState>>,
    stop: Arc<AtomicBool>,
    shift_next_frame: Arc<AtomicU32>,
    ignore_uvc_switch: Arc<AtomicBool>,
    mounts: Mutex<Vec<PathBuf>>,
    threads: Mutex<Vec<JoinHandle<()>>>,
    /// ep0 of the UVC function after the switch: closing it while the
    /// gadget is bound would unbind the gadget, so it stays open until drop.
    parked: Mutex<Vec<File>>,
}

/// A running emulated board.
pub struct BoardEmulator {
    pub name: String,
    pub state: Arc<Mutex<BoardState>>,
    /// Rotate the next frame by this many bytes (misalignment injection).
    pub shift_next_frame: Arc<AtomicU32>,
    /// In UVC mode: record the switch request but stay in UVC mode (a board
    /// whose firmware does not come back).
    pub ignore_uvc_switch: Arc<AtomicBool>,
    inner: Arc<Inner>,
}

fn write_attr(path: impl AsRef<Path>, value: &str) -> std::io::Result<()> {
    fs::write(path.as_ref(), value)
        .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", path.as_ref().display())))
}

fn run(cmd: &str, args: &[&str]) -> std::io::Result<()> {
    let st = Command::new(cmd).args(args).status()?;
    if st.success() {
        Ok(())
    } else {
        Err(std::io::Error::other(format!("{cmd} {args:?}: {st}")))
    }
}

/// Loads the modules and mounts configfs (idempotent). dummy_hcd with
/// two controllers: two boards can be plugged at once.
pub fn prepare_kernel() -> std::io::Result<()> {
    run("modprobe", &["dummy_hcd", "num=2"])?;
    for m in ["libcomposite", "usb_f_fs"] {
        run("modprobe", &[m])?;
    }
    if !Path::new(GADGET_ROOT).exists() {
        run("mount", &["-t", "configfs", "none", "/sys/kernel/config"])?;
    }
    Ok(())
}

/// A UDC of dummy_hcd no gadget is bound to (the first, by name).
pub fn udc_name() -> std::io::Result<String> {
    let bound: Vec<String> = fs::read_dir(GADGET_ROOT)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|g| fs::read_to_string(g.path().join("UDC")).ok())
        .map(|u| u.trim().to_owned())
        .filter(|u| !u.is_empty())
        .collect();
    let mut udcs: Vec<String> = fs::read_dir("/sys/class/udc")?
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    udcs.sort();
    udcs.into_iter()
        .find(|u| !bound.contains(u))
        .ok_or_else(|| std::io::Error::other("no free UDC (is dummy_hcd loaded?)"))
}

/// Creates configfs gadget `name` (0451:`product_id`, claiming `serial`)
/// with its configuration c.1, and the state its threads share, holding
/// the board's power-on registers; no function yet, not plugged in. The
/// genuine emulator and the hostile devices ([`hostile`]) both start here.
fn new_gadget(
    name: &str,
    serial: &str,
    product_id: &str,
    manufacturer: &str,
    product: &str,
) -> std::io::Result<Arc<Inner>> {
    prepare_kernel()?;
    let gadget = Path::new(GADGET_ROOT).join(name);
    fs::create_dir_all(&gadget)?;
    write_attr(gadget.join("idVendor"), "0x0451")?;
    write_attr(gadget.join("idProduct"), product_id)?;
    write_attr(gadget.join("bcdUSB"), "0x0200")?;
    let strings = gadget.join("strings/0x409");
    fs::create_dir_all(&strings)?;
    write_attr(strings.join("serialnumber"), serial)?;
    write_attr(strings.join("manufacturer"), manufacturer)?;
    write_attr(strings.join("product"), product)?;
    fs::create_dir_all(gadget.join("configs/c.1"))?;
    let inner = Arc::new(Inner {
        name: name.into(),
        serial: serial.into(),
        gadget,
        state: Arc::new(Mutex::new(BoardState::default())),
        stop: Arc::new(AtomicBool::new(false)),
        shift_next_frame: Arc::new(AtomicU32::new(0)),
        ignore_uvc_switch: Arc::new(AtomicBool::new(false)),
        mounts: Mutex::new(Vec::new()),
        threads: Mutex::new(Vec::new()),
        parked: Mutex::new(Vec::new()),
    });
    {
        let mut s = inner.state.lock().unwrap();
        s.registers.insert(0x5880, 1); // tg_dis
        s.registers.insert(0x5883, 0x44);
        s.registers.insert(0x581F, 239 << 16);
        s.registers.insert(0x5821, 19 << 3);
    }
    Ok(inner)
}

impl Inner {
    fn config(&self) -> PathBuf {
        self.gadget.join("configs/c.1")
    }

    fn plug(&self) -> std::io::Result<()> {
        write_attr(self.gadget.join("UDC"), &udc_name()?)
    }

    fn unplug(&self) -> std::io::Result<()> {
        write_attr(self.gadget.join("UDC"), "\n")
    }

    fn spawn(&self, f: impl FnOnce() + Send + 'static) {
        let t = std::thread::spawn(f);
        self.threads.lock().unwrap().push(t);
    }

    /// A FunctionFS function linked into the configuration, its
    /// descriptors written; returns its ep0.
    fn add_function(&self, instance: &str, descs: &[u8], strings: &[u8]) -> std::io::Result<File> {
        let function = self.gadget.join(format!("functions/ffs.{instance}"));
        fs::create_dir_all(&function)?;
        let link = self.config().join(format!("ffs.{instance}"));
        if !link.exists() {
            std::os::unix::fs::symlink(&function, &link)?;
        }
        let mount = PathBuf::from(format!("/dev/ffs-{instance}"));
        fs::create_dir_all(&mount)?;
        run(
            "mount",
            &["-t", "functionfs", instance, &mount.to_string_lossy()],
        )?;
        let mut ep0 = OpenOptions::new()
            .read(true)
            .write(true)
            .open(mount.join("ep0"))?;
        ep0.write_all(descs)?;
        ep0.write_all(strings)?;
        self.mounts.lock().unwrap().push(mount);
        Ok(ep0)
    }

    /// The bulk-mode function: registers over vendor requests, frames on ep1.
    fn add_bulk_function(&self) -> std::io::Result<()> {
        let ep0 = self.add_function(
            &self.name,
            &descriptors::descriptors(),
            &descriptors::strings("OPT8241 bulk"),
        )?;
        let ep1 = PathBuf::from(format!("/dev/ffs-{}", self.name)).join("ep1");
        let (state, stop, serial) = (self.state.clone(), self.stop.clone(), self.serial.clone());
        self.spawn(move || control_loop(ep0, &state, &stop, &serial));
        let (state, stop, shift) = (
            self.state.clone(),
            self.stop.clone(),
            self.shift_next_frame.clone(),
        );
        self.spawn(move || stream_loop(&ep1, &state, &stop, &shift));
        Ok(())
    }

    /// The UVC-mode function: a VideoControl interface that only knows the
    /// extension-unit request switching to bulk mode.
    fn add_uvc_function(self: &Arc<Self>) -> std::io::Result<()> {
        let ep0 = self.add_function(
            &format!("{}uvc", self.name),
            &descriptors::uvc_descriptors(),
            &descriptors::strings("OPT8241 UVC"),
        )?;
        let inner = self.clone();
        self.spawn(move || uvc_control_loop(ep0, &inner));
        Ok(())
    }

    /// What the firmware does on XU control 6: drop off the bus and come
    /// back as 0451:9105 with the bulk-mode interface.
    fn switch_to_bulk(&self) -> std::io::Result<()> {
        self.unplug()?;
        fs::remove_file(self.config().join(format!("ffs.{}uvc", self.name)))?;
        write_attr(self.gadget.join("idProduct"), "0x9105")?;
        self.add_bulk_function()?;
        self.plug()?;
        self.state.lock().unwrap().switched_to_bulk = Some(Instant::now());
        Ok(())
    }
}

impl BoardEmulator {
    /// Creates the gadget in bulk mode (0451:9105), starts the FunctionFS
    /// threads and plugs it in.
    pub fn start(name: &str, serial: &str) -> std::io::Result<Self> {
        Self::start_in(name, serial, false)
    }

    /// Like [`BoardEmulator::start`], but the board first enumerates in UVC
    /// mode (0451:9106) until the host switches it.
    pub fn start_uvc(name: &str, serial: &str) -> std::io::Result<Self> {
        Self::start_in(name, serial, true)
    }

    fn start_in(name: &str, serial: &str, uvc: bool) -> std::io::Result<Self> {
        let inner = new_gadget(
            name,
            serial,
            if uvc { "0x9106" } else { "0x9105" },
            "SDI test",
            "OPT8241-CDK emulator",
        )?;
        inner
            .state
            .lock()
            .unwrap()
            .registers
            .extend(chip::LEFTOVER_PROFILE.iter().copied());
        if uvc {
            inner.add_uvc_function()?;
        } else {
            inner.add_bulk_function()?;
        }
        let emu = Self {
            name: name.into(),
            state: inner.state.clone(),
            shift_next_frame: inner.shift_next_frame.clone(),
            ignore_uvc_switch: inner.ignore_uvc_switch.clone(),
            inner,
        };
        emu.plug()?;
        Ok(emu)
    }

    /// Binds the gadget to the UDC: the host sees a new device.
    pub fn plug(&self) -> std::io::Result<()> {
        self.inner.plug()
    }

    /// Unbinds the gadget: the host sees the device vanish.
    pub fn unplug(&self) -> std::io::Result<()> {
        self.inner.unplug()
    }
}

impl Drop for BoardEmulator {
    fn drop(&mut self) {
        self.inner.stop.store(true, Ordering::SeqCst);
        // A reader blocked on ep0 wakes only on an event: if the gadget is
        // unplugged, plug it in once so that binding delivers one.
        let bound = fs::read_to_string(self.inner.gadget.join("UDC")).unwrap_or_default();
        if bound.trim().is_empty() {
            let _ = self.plug();
            std::thread::sleep(Duration::from_millis(200));
        }
        let _ = self.unplug();
        loop {
            let threads = std::mem::take(&mut *self.inner.threads.lock().unwrap());
            if threads.is_empty() {
                break;
            }
            for t in threads {
                let _ = t.join();
            }
        }
        self.inner.parked.lock().unwrap().clear();
        for m in self.inner.mounts.lock().unwrap().iter() {
            let _ = Command::new("umount").arg(m).status();
        }
    }
}

const EVENT_BYTES: usize = 12;
const EV_SETUP: u8 = 4;

/// One control request from a FunctionFS SETUP event.
struct Setup {
    rt: u8,
    req: u8,
    value: u16,
    index: u16,
    length: usize,
}

/// The SETUP events of one read of ep0 (empty after an interrupted or
/// failed read, e.g. EL2HLT/ESHUTDOWN while unbound: then after a pause).
fn next_setups(ep0: &mut File) -> Vec<Setup> {
    let mut buf = [0u8; EVENT_BYTES * 4];
    let n = match ep0.read(&mut buf) {
        Ok(n) => n,
        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => 0,
        Err(_) => {
            std::thread::sleep(Duration::from_millis(20));
            0
        }
    };
    buf[..n]
        .chunks_exact(EVENT_BYTES)
        .filter(|ev| ev[8] == EV_SETUP)
        .map(|ev| Setup {
            rt: ev[0],
            req: ev[1],
            value: u16::from_le_bytes([ev[2], ev[3]]),
            index: u16::from_le_bytes([ev[4], ev[5]]),
            length: u16::from_le_bytes([ev[6], ev[7]]) as usize,
        })
        .collect()
}

fn control_loop(mut ep0: File, state: &Mutex<BoardState>, stop: &AtomicBool, serial: &str) {
    while !stop.load(Ordering::SeqCst) {
        for setup in next_setups(&mut ep0) {
            let _ = handle_setup(&mut ep0, state, serial, &setup);
        }
    }
}

/// UVC class request SET_CUR.
const UVC_SET_CUR: u8 = 0x01;

/// ep0 of the UVC-mode function. FunctionFS hands a class request to the
/// interface with wIndex replaced by the function's interface number, so the
/// extension unit id (wIndex high byte on the wire) is not visible here; the
/// control selector (wValue high byte) is.
fn uvc_control_loop(mut ep0: File, inner: &Arc<Inner>) {
    while !inner.stop.load(Ordering::SeqCst) {
        for s in next_setups(&mut ep0) {
            if s.rt == 0x21 && s.req == UVC_SET_CUR {
                let mut data = vec![0u8; s.length];
                let _ = ep0.read(&mut data);
                inner
                    .state
                    .lock()
                    .unwrap()
                    .uvc_requests
                    .push((s.rt, s.req, s.value, s.index, data));
                if s.value >> 8 == 6 && !inner.ignore_uvc_switch.load(Ordering::SeqCst) {
                    // The firmware re-enumerates right after the request.
                    std::thread::sleep(Duration::from_millis(50));
                    if let Err(e) = inner.switch_to_bulk() {
                        eprintln!("emulator: switch to bulk mode failed: {e}");
                    }
                    inner.parked.lock().unwrap().push(ep0);
                    return;
                }
            } else {
                inner
                    .state
                    .lock()
                    .unwrap()
                    .stalled
                    .push((s.rt, s.req, s.value, s.index));
                if s.rt & 0x80 != 0 {
                    let _ = ep0.read(&mut [0u8; 0]);
                } else {
                    let _ = ep0.write(&[]);
                }
            }
        }
    }
}

fn handle_setup(
    ep0: &mut File,
    state: &Mutex<BoardState>,
    serial: &str,
    setup: &Setup,
) -> std::io::Result<()> {
    let &Setup {
        rt,
        req,
        value,
        index,
        length,
    } = setup;
    let address = ((value & 0xFF) << 8) | (index & 0xFF);
    let is_in = rt & 0x80 != 0;
    match (rt, req) {
        (0xC0, 0x08) => {
            let v = chip::read(&state.lock().unwrap(), address);
            let b = v.to_le_bytes();
            ep0.write_all(&b[..3.min(length)])
        }
        (0x40, 0x09) => {
            let mut d = vec![0u8; length];
            ep0.read_exact(&mut d)?;
            if d.len() == 3 {
                let written = u32::from_le_bytes([d[0], d[1], d[2], 0]);
                let kept = BoardState::mask(address, written);
                let mut s = state.lock().unwrap();
                s.registers.insert(address, kept);
                s.writes.push(RegisterWrite {
                    address,
                    written,
                    kept,
                    at: std::time::Instant::now(),
                });
            }
            Ok(())
        }
        (0xC0, 0x1A) => ep0.write_all(&[0x00, 0x11][..2.min(length)]),
        (0xC0, 0x30) => ep0.write_all(&[0x02, 0x00][..2.min(length)]),
        (0xC0, 0x32) => {
            let b = serial.as_bytes();
            ep0.write_all(&b[..b.len().min(length)])
        }
        _ => {
            state.lock().unwrap().stalled.push((rt, req, value, index));
            // Reading in an IN data stage (or writing in an OUT one) stalls ep0.
            if is_in {
                let _ = ep0.read(&mut [0u8; 0]);
            } else {
                let _ = ep0.write(&[]);
            }
            Ok(())
        }
    }
}

/// `file`, opened on `ep1` (and for reading too with `read`) unless it is
/// open; `None`, after a pause, while it cannot be. Non-blocking: a write
/// while the gadget is unbound or the function disabled fails at once
/// instead of waiting for the next bind, so the stream thread sees its
/// stop flag and can be joined (transfers still wait to complete).
fn open_endpoint<'a>(file: &'a mut Option<File>, ep1: &Path, read: bool) -> Option<&'a mut File> {
    if file.is_none() {
        *file = OpenOptions::new()
            .read(read)
            .write(true)
            .custom_flags(nix::fcntl::OFlag::O_NONBLOCK.bits())
            .open(ep1)
            .ok();
    }
    if file.is_none() {
        std::thread::sleep(Duration::from_millis(20));
    }
    file.as_mut()
}

fn stream_loop(ep1: &Path, state: &Mutex<BoardState>, stop: &AtomicBool, shift: &AtomicU32) {
    // ep1 exists once the descriptors are written; open it when the host
    // has enabled the function (writes fail before that).
    let mut sim: Option<(Simulator, (usize, usize))> = None;
    let mut frame = Frame::new(1, 1);
    let mut number: u8 = 0;
    let mut file: Option<File> = None;
    while !stop.load(Ordering::SeqCst) {
        let (running, (w, h, quads), period, numbers, delay_rad, unlit, output) = {
            let s = state.lock().unwrap();
            let output = chip::Output::of(&s);
            (
                field(s.reg(0x5880), 0, 0) == 0 && output.is_some(),
                s.geometry(),
                s.frame_period(),
                field(s.reg(0x5C39), 12, 12) == 1,
                s.led_delay_rad,
                s.unlit,
                output,
            )
        };
        if !running {
            std::thread::sleep(Duration::from_millis(10));
            continue;
        }
        if sim.as_ref().map(|s| s.1) != Some((w, h)) {
            let mut params = SensorPreset::TiOpt8241.params();
            params.width = w;
            params.height = h;
            let scene = SceneSpec::from_name("flat-field").expect("scene");
            let mut cfg = SimConfig::new(params, scene);
            cfg.seed = 7;
            sim = Simulator::new(cfg).ok().map(|s| (s, (w, h)));
        }
        let Some((simulator, _)) = sim.as_mut() else {
            return;
        };
        let mut lit = Illumination::snapshot(12e6);
        if unlit[0] {
            lit.ls1 = SourceDrive::Off;
        }
        if unlit[1] {
            lit.ls2 = SourceDrive::Off;
        }
        simulator.capture(&lit, &mut frame);
        let region = state.lock().unwrap().saturated_region;
        if let Some(r) = region {
            r.fill_wells(&mut frame.dn.data, w);
        }
        let (mut bytes, kept) = match output {
            Some(chip::Output::Depth(layout)) => {
                (chip::encode_depth(w, h, region, layout), Vec::new())
            }
            _ => encode_raw_quads_delayed(&frame.dn.data, quads, delay_rad),
        };
        number = number.wrapping_add(1);
        if numbers {
            bytes[0] = number;
        }
        let drop_bytes = shift.swap(0, Ordering::SeqCst) as usize;
        let Some(f) = open_endpoint(&mut file, ep1, false) else {
            continue;
        };
        if !kept.is_empty() {
            state.lock().unwrap().sent.push((number, kept));
        }
        // Misalignment injection: the frame rotated by `drop_bytes`, so the
        // transfer has the right length but starts mid-frame.
        let len = bytes.len();
        bytes.rotate_left(drop_bytes.min(len));
        let payload = &bytes[..];
        let ok = payload.chunks(16 * 1024).all(|c| f.write_all(c).is_ok())
            // zero-length packet: end of frame
            && f.write(&[]).is_ok();
        if !ok {
            file = None;
            std::thread::sleep(Duration::from_millis(20));
            continue;
        }
        std::thread::sleep(period);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sdi_core::quad_phase::PhaseAxis;
    use sdi_opt8241::raw_quads::{QuadCombine, QuadDecoder, QuadLayout};

    /// The emulator's delayed quads against the backend's decoder: quad 0
    /// alone loses the delayed part, the projection onto the delay's axis
    /// recovers d within the 12-bit rounding of two quads.
    #[test]
    fn a_delayed_led_path_needs_the_projection() {
        let dn: Vec<f32> = vec![0.0, 300.0, -120.0, 37.0, 1000.0, -2047.0];
        let layout = QuadLayout {
            width: dn.len(),
            height: 1,
            quads: 4,
        };
        assert_eq!(
            encode_raw_quads_delayed(&dn, 4, 0.0),
            encode_raw_quads(&dn, 4)
        );
        let delay_rad = 60f64.to_radians();
        let (raw, sent) = encode_raw_quads_delayed(&dn, 4, delay_rad);
        assert_eq!(sent, dn);
        let mut dec = QuadDecoder::new(layout);
        dec.frame_number_in_first_byte = false;
        let mut f = Frame::new(1, 1);
        dec.decode(&raw, &mut f).unwrap();
        // quad 0 alone: d cos 60 degrees, half of it
        assert!((f.dn.data[4] - 500.0).abs() <= 0.5, "{:?}", f.dn.data);
        dec.combine = QuadCombine::Projected(PhaseAxis {
            angle_rad: delay_rad,
        });
        dec.decode(&raw, &mut f).unwrap();
        for (got, want) in f.dn.data.iter().zip(&sent) {
            assert!((got - want).abs() <= 0.71, "{got} vs {want}");
        }
    }
}
