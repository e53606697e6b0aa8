//! A test-only OPT8241-CDK on the kernel's real USB stack: a configfs gadget
//! (0451:9105) with a FunctionFS function, bound to dummy_hcd's UDC, so the
//! backend reaches it through libusb exactly as it reaches the board.
//!
//! The emulator keeps a register file with the firmware's laser-safety masks,
//! answers the vendor requests (0x08/0x09 registers, 0x1A version, 0x30
//! revision, 0x32 serial) and, while tg_dis = 0, streams simulator frames in
//! the raw-quad format, each ended by a zero-length packet, with the frame
//! number in byte 0 when debug_frame_number_en is set. It is written from the
//! public descriptions, independently of the backend's code.
//! Runs only as root inside the VM (modules dummy_hcd, libcomposite, usb_f_fs).

mod descriptors;

use std::collections::HashMap;
use std::fs::{self, File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use sdi_core::modulation::Illumination;
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

/// A running emulated board.
pub struct BoardEmulator {
    pub name: String,
    gadget: PathBuf,
    ffs_mount: PathBuf,
    pub state: Arc<Mutex<BoardState>>,
    stop: Arc<AtomicBool>,
    /// Rotate the next frame by this many bytes (misalignment injection).
    pub shift_next_frame: Arc<AtomicU32>,
    threads: Vec<JoinHandle<()>>,
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

/// Loads the modules and mounts configfs (idempotent).
pub fn prepare_kernel() -> std::io::Result<()> {
    for m in ["dummy_hcd", "libcomposite", "usb_f_fs"] {
        run("modprobe", &[m])?;
    }
    if !Path::new(GADGET_ROOT).exists() {
        run("mount", &["-t", "configfs", "none", "/sys/kernel/config"])?;
    }
    Ok(())
}

/// The UDC of dummy_hcd.
pub fn udc_name() -> std::io::Result<String> {
    fs::read_dir("/sys/class/udc")?
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .next()
        .ok_or_else(|| std::io::Error::other("no UDC (is dummy_hcd loaded?)"))
}

impl BoardEmulator {
    /// Creates the gadget, starts the FunctionFS threads and plugs it in.
    pub fn start(name: &str, serial: &str) -> std::io::Result<Self> {
        prepare_kernel()?;
        let gadget = Path::new(GADGET_ROOT).join(name);
        fs::create_dir_all(&gadget)?;
        write_attr(gadget.join("idVendor"), "0x0451")?;
        write_attr(gadget.join("idProduct"), "0x9105")?;
        write_attr(gadget.join("bcdUSB"), "0x0200")?;
        let strings = gadget.join("strings/0x409");
        fs::create_dir_all(&strings)?;
        write_attr(strings.join("serialnumber"), serial)?;
        write_attr(strings.join("manufacturer"), "SDI test")?;
        write_attr(strings.join("product"), "OPT8241-CDK emulator")?;
        let config = gadget.join("configs/c.1");
        fs::create_dir_all(&config)?;
        let function = gadget.join(format!("functions/ffs.{name}"));
        fs::create_dir_all(&function)?;
        let link = config.join(format!("ffs.{name}"));
        if !link.exists() {
            std::os::unix::fs::symlink(&function, &link)?;
        }
        let ffs_mount = PathBuf::from(format!("/dev/ffs-{name}"));
        fs::create_dir_all(&ffs_mount)?;
        run(
            "mount",
            &["-t", "functionfs", name, &ffs_mount.to_string_lossy()],
        )?;
        let mut ep0 = OpenOptions::new()
            .read(true)
            .write(true)
            .open(ffs_mount.join("ep0"))?;
        ep0.write_all(&descriptors::descriptors())?;
        ep0.write_all(&descriptors::strings("OPT8241 bulk"))?;
        let mut emu = Self {
            name: name.into(),
            gadget,
            ffs_mount,
            state: Arc::new(Mutex::new(BoardState::default())),
            stop: Arc::new(AtomicBool::new(false)),
            shift_next_frame: Arc::new(AtomicU32::new(0)),
            threads: Vec::new(),
        };
        {
            let mut s = emu.state.lock().unwrap();
            s.registers.insert(0x5880, 1); // tg_dis
            s.registers.insert(0x5883, 0x44);
            s.registers.insert(0x581F, 239 << 16);
            s.registers.insert(0x5821, 19 << 3);
        }
        let (state, stop, serial) = (emu.state.clone(), emu.stop.clone(), serial.to_string());
        emu.threads.push(std::thread::spawn(move || {
            control_loop(ep0, &state, &stop, &serial)
        }));
        let ep1 = emu.ffs_mount.join("ep1");
        let (state, stop, shift) = (
            emu.state.clone(),
            emu.stop.clone(),
            emu.shift_next_frame.clone(),
        );
        emu.threads.push(std::thread::spawn(move || {
            stream_loop(&ep1, &state, &stop, &shift)
        }));
        emu.plug()?;
        Ok(emu)
    }

    /// Binds the gadget to the UDC: the host sees a new device.
    pub fn plug(&self) -> std::io::Result<()> {
        write_attr(self.gadget.join("UDC"), &udc_name()?)
    }

    /// Unbinds the gadget: the host sees the device vanish.
    pub fn unplug(&self) -> std::io::Result<()> {
        write_attr(self.gadget.join("UDC"), "\n")
    }
}

impl Drop for BoardEmulator {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // A reader blocked on ep0 wakes only on an event: if the gadget is
        // unplugged, plug it in once so that binding delivers one.
        let bound = fs::read_to_string(self.gadget.join("UDC")).unwrap_or_default();
        if bound.trim().is_empty() {
            let _ = self.plug();
            std::thread::sleep(Duration::from_millis(200));
        }
        let _ = self.unplug();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
        let _ = Command::new("umount").arg(&self.ffs_mount).status();
    }
}

const EVENT_BYTES: usize = 12;
const EV_SETUP: u8 = 4;

fn control_loop(mut ep0: File, state: &Mutex<BoardState>, stop: &AtomicBool, serial: &str) {
    let mut buf = [0u8; EVENT_BYTES * 4];
    while !stop.load(Ordering::SeqCst) {
        let n = match ep0.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(_) => {
                // EL2HLT/ESHUTDOWN while unbound: wait and try again.
                std::thread::sleep(Duration::from_millis(20));
                continue;
            }
        };
        for ev in buf[..n].chunks_exact(EVENT_BYTES) {
            if ev[8] != EV_SETUP {
                continue;
            }
            let rt = ev[0];
            let req = ev[1];
            let value = u16::from_le_bytes([ev[2], ev[3]]);
            let index = u16::from_le_bytes([ev[4], ev[5]]);
            let length = u16::from_le_bytes([ev[6], ev[7]]) as usize;
            let address = ((value & 0xFF) << 8) | (index & 0xFF);
            let _ = handle_setup(
                &mut ep0, state, serial, rt, req, address, length, value, index,
            );
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn handle_setup(
    ep0: &mut File,
    state: &Mutex<BoardState>,
    serial: &str,
    rt: u8,
    req: u8,
    address: u16,
    length: usize,
    value: u16,
    index: u16,
) -> std::io::Result<()> {
    let is_in = rt & 0x80 != 0;
    match (rt, req) {
        (0xC0, 0x08) => {
            let v = state.lock().unwrap().reg(address);
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

fn stream_loop(ep1: &Path, state: &Mutex<BoardState>, stop: &AtomicBool, shift: &AtomicU32) {
    // ep1 exists once the descriptors are written; open it when the host
    // has enabled the function (writes fail before that).
    let mut sim: Option<(Simulator, (usize, usize))> = None;
    let mut frame = Frame::new(1, 1);
    let mut number: u8 = 0;
    let mut file: Option<File> = None;
    while !stop.load(Ordering::SeqCst) {
        let (running, (w, h, quads), period, numbers) = {
            let s = state.lock().unwrap();
            (
                field(s.reg(0x5880), 0, 0) == 0 && field(s.reg(0x5C25), 11, 8) == 15,
                s.geometry(),
                s.frame_period(),
                field(s.reg(0x5C39), 12, 12) == 1,
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
        simulator.capture(&Illumination::snapshot(12e6), &mut frame);
        let (mut bytes, kept) = encode_raw_quads(&frame.dn.data, quads);
        number = number.wrapping_add(1);
        if numbers {
            bytes[0] = number;
        }
        let drop_bytes = shift.swap(0, Ordering::SeqCst) as usize;
        if file.is_none() {
            file = OpenOptions::new().write(true).open(ep1).ok();
        }
        let Some(f) = file.as_mut() else {
            std::thread::sleep(Duration::from_millis(20));
            continue;
        };
        state.lock().unwrap().sent.push((number, kept));
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
