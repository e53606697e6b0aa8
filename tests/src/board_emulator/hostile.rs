//! A hostile USB device on the board's IDs: what a BadUSB-class device
//! claiming 0451:9105 (or 9106) may send sdid, which runs as root.
//!
//! Each [`HostileMode`] is one misbehaviour, on its own configfs gadget of
//! the same dummy_hcd UDC as [`super::BoardEmulator`] (unplug the genuine
//! board first: the UDC takes one gadget at a time). Where a mode needs the
//! board to be configured before it misbehaves (bulk-side modes), ep0 is the
//! genuine emulator's [`super::control_loop`]. The devices claim the genuine
//! board's serial number: a copy costs the attacker nothing, and it makes
//! `[board] serial` no defence.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use nix::poll::{poll, PollFd, PollFlags, PollTimeout};

use super::{
    descriptors, field, handle_setup, new_gadget, next_setups, open_endpoint, BoardState, Inner,
};

/// One way a device on the board's IDs misbehaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HostileMode {
    /// Configures like the board, then every frame is a few bytes short or
    /// long before its zero-length packet.
    WrongLength,
    /// Configures like the board, then sends only zero-length packets, as
    /// fast as the host takes them.
    EmptyFrames,
    /// Configures like the board, then sends 16 MiB frames.
    HugeFrames,
    /// Interface 0 of the vendor class, unknown subclass and protocol, with a
    /// bulk OUT and an interrupt IN endpoint: no bulk IN endpoint to stream
    /// from. (FunctionFS checks what it is given and dummy_hcd has no
    /// isochronous endpoints, so the garbage is what both let through.)
    GarbageDescriptors,
    /// Every control IN request answered with one byte.
    ShortReplies,
    /// ep0 never answers: every control request NAKs until the host gives up.
    EndlessNak,
    /// Every control request stalled.
    StallControl,
    /// Configures like the board, then halts the bulk endpoint on every
    /// transfer.
    StallBulk,
    /// Configures like the board, then drops off the bus in the middle of
    /// every frame and comes back 300 ms later.
    DisconnectMidTransfer,
    /// In UVC mode (0451:9106): drops off the bus on the switch request
    /// without answering it, and comes back in UVC mode.
    DisconnectDuringUvcSwitch,
    /// The genuine board's functions, bound and unbound every 100 ms.
    EnumerationStorm,
    /// The board's bulk-mode IDs with a USB mass-storage interface (bulk-only
    /// SCSI: bulk IN and OUT), stalling the vendor requests it does not know.
    MassStorage,
    /// The board's bulk-mode IDs with a HID keyboard interface (interrupt IN).
    Hid,
}

impl HostileMode {
    /// Every mode, in the order the VM test runs them.
    pub const ALL: [HostileMode; 13] = [
        Self::WrongLength,
        Self::EmptyFrames,
        Self::HugeFrames,
        Self::GarbageDescriptors,
        Self::ShortReplies,
        Self::EndlessNak,
        Self::StallControl,
        Self::StallBulk,
        Self::DisconnectMidTransfer,
        Self::DisconnectDuringUvcSwitch,
        Self::EnumerationStorm,
        Self::MassStorage,
        Self::Hid,
    ];

    /// The mode's name, as the test reports it.
    pub fn name(self) -> &'static str {
        match self {
            Self::WrongLength => "wrong-length",
            Self::EmptyFrames => "empty-frames",
            Self::HugeFrames => "huge-frames",
            Self::GarbageDescriptors => "garbage-descriptors",
            Self::ShortReplies => "short-replies",
            Self::EndlessNak => "endless-nak",
            Self::StallControl => "stall-control",
            Self::StallBulk => "stall-bulk",
            Self::DisconnectMidTransfer => "disconnect-mid-transfer",
            Self::DisconnectDuringUvcSwitch => "disconnect-during-uvc-switch",
            Self::EnumerationStorm => "enumeration-storm",
            Self::MassStorage => "mass-storage",
            Self::Hid => "hid",
        }
    }
}

/// Bytes of one [`HostileMode::HugeFrames`] frame.
pub const HUGE_FRAME_BYTES: usize = 16 << 20;
/// Half period of [`HostileMode::EnumerationStorm`]: bound this long, then
/// unbound this long.
pub const STORM_HALF_PERIOD: Duration = Duration::from_millis(100);
/// How long [`HostileMode::DisconnectMidTransfer`] and
/// [`HostileMode::DisconnectDuringUvcSwitch`] stay off the bus.
pub const OFF_BUS: Duration = Duration::from_millis(300);

const DESCRIPTORS_MAGIC_V2: u32 = 3;
const HAS_FS_DESC: u32 = 1;
const HAS_HS_DESC: u32 = 2;
const ALL_CTRL_RECIP: u32 = 64;

/// A FunctionFS v2 descriptor blob of any number of descriptors (the same
/// list at full and high speed, endpoints given as (address, attributes,
/// full-speed size, high-speed size)).
fn blob(interface: [u8; 9], endpoints: &[(u8, u8, u16, u16)]) -> Vec<u8> {
    let speed = |high: bool| {
        let mut d = interface.to_vec();
        for &(address, attributes, fs, hs) in endpoints {
            let mp = if high { hs } else { fs }.to_le_bytes();
            let interval = if attributes & 3 == 2 { 0 } else { 4 };
            d.extend_from_slice(&[7, 5, address, attributes, mp[0], mp[1], interval]);
        }
        d
    };
    let count = (1 + endpoints.len()) as u32;
    let mut out = Vec::new();
    out.extend_from_slice(&DESCRIPTORS_MAGIC_V2.to_le_bytes());
    let body: Vec<u8> = [speed(false), speed(true)].concat();
    out.extend_from_slice(&((20 + body.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(HAS_FS_DESC | HAS_HS_DESC | ALL_CTRL_RECIP).to_le_bytes());
    out.extend_from_slice(&count.to_le_bytes());
    out.extend_from_slice(&count.to_le_bytes());
    out.extend_from_slice(&body);
    out
}

/// A running hostile device; unplugged and torn down on drop.
pub struct HostileBoard {
    pub mode: HostileMode,
    /// Register writes and requests the device saw (bulk-side modes).
    pub state: Arc<Mutex<BoardState>>,
    /// Requests the device refused or left pending, and bulk transfers it
    /// started, by its own count.
    pub transfers: Arc<AtomicU32>,
    inner: Arc<Inner>,
}

impl HostileBoard {
    /// Creates gadget `name` misbehaving as `mode`, claiming `serial`, and
    /// plugs it in.
    pub fn start(name: &str, serial: &str, mode: HostileMode) -> std::io::Result<Self> {
        let product_id = if mode == HostileMode::DisconnectDuringUvcSwitch {
            "0x9106"
        } else {
            "0x9105"
        };
        let inner = new_gadget(name, serial, product_id, "SDI test (hostile)", mode.name())?;
        let board = Self {
            mode,
            state: inner.state.clone(),
            transfers: Arc::new(AtomicU32::new(0)),
            inner,
        };
        board.add_functions()?;
        board.inner.plug()?;
        if mode == HostileMode::EnumerationStorm {
            let inner = board.inner.clone();
            board.inner.spawn(move || storm(&inner));
        }
        Ok(board)
    }

    /// True once sdid has reached the part of the device that misbehaves:
    /// a control request answered badly, or (bulk-side modes) a transfer
    /// sent. Modes sdid turns away on the descriptors alone are engaged at
    /// once.
    pub fn engaged(&self) -> bool {
        use HostileMode::*;
        match self.mode {
            GarbageDescriptors | Hid | EnumerationStorm => true,
            // sdid's three attempts at its first request
            EndlessNak => self.transfers.load(Ordering::SeqCst) >= 3,
            _ => self.transfers.load(Ordering::SeqCst) > 0,
        }
    }

    fn add_functions(&self) -> std::io::Result<()> {
        use HostileMode::*;
        let inner = &self.inner;
        let name = inner.name.clone();
        let strings = descriptors::strings(self.mode.name());
        let ep1 = PathBuf::from(format!("/dev/ffs-{name}")).join("ep1");
        let n = self.transfers.clone();
        match self.mode {
            WrongLength
            | EmptyFrames
            | HugeFrames
            | StallBulk
            | DisconnectMidTransfer
            | EnumerationStorm => {
                let ep0 = inner.add_function(&name, &descriptors::descriptors(), &strings)?;
                let me = inner.clone();
                inner.spawn(move || genuine_ep0(ep0, &me));
                let (mode, me) = (self.mode, inner.clone());
                inner.spawn(move || bulk_side(mode, &ep1, &me, &n));
            }
            GarbageDescriptors => {
                let interface = [9, 4, 0, 0, 2, 0xFF, 0x42, 0x42, 1];
                // bulk OUT 1, interrupt IN 2 of 64 bytes
                let descs = blob(interface, &[(0x01, 2, 64, 512), (0x82, 3, 64, 64)]);
                let ep0 = inner.add_function(&name, &descs, &strings)?;
                let me = inner.clone();
                inner.spawn(move || answer_ep0(ep0, &me, &n, Answer::Stall));
            }
            ShortReplies | StallControl | EndlessNak => {
                let ep0 = inner.add_function(&name, &descriptors::descriptors(), &strings)?;
                let answer = match self.mode {
                    ShortReplies => Answer::OneByte,
                    StallControl => Answer::Stall,
                    _ => Answer::Never,
                };
                let me = inner.clone();
                inner.spawn(move || answer_ep0(ep0, &me, &n, answer));
            }
            MassStorage => {
                // bInterfaceClass 8 (mass storage), SCSI, bulk-only transport
                let interface = [9, 4, 0, 0, 2, 0x08, 0x06, 0x50, 1];
                let descs = blob(interface, &[(0x81, 2, 64, 512), (0x02, 2, 64, 512)]);
                let ep0 = inner.add_function(&name, &descs, &strings)?;
                let me = inner.clone();
                inner.spawn(move || answer_ep0(ep0, &me, &n, Answer::Stall));
            }
            Hid => {
                // bInterfaceClass 3 (HID), boot interface, keyboard
                let interface = [9, 4, 0, 0, 1, 0x03, 0x01, 0x01, 1];
                let descs = blob(interface, &[(0x81, 3, 8, 8)]);
                let ep0 = inner.add_function(&name, &descs, &strings)?;
                let me = inner.clone();
                inner.spawn(move || answer_ep0(ep0, &me, &n, Answer::Stall));
            }
            DisconnectDuringUvcSwitch => {
                let ep0 = inner.add_function(
                    &format!("{name}uvc"),
                    &descriptors::uvc_descriptors(),
                    &strings,
                )?;
                let me = inner.clone();
                inner.spawn(move || drop_on_uvc_switch(ep0, &me, &n));
            }
        }
        Ok(())
    }
}

impl Drop for HostileBoard {
    fn drop(&mut self) {
        let inner = &self.inner;
        inner.stop.store(true, Ordering::SeqCst);
        // Every thread polls with a timeout and sees `stop`.
        let _ = inner.unplug();
        loop {
            let threads = std::mem::take(&mut *inner.threads.lock().unwrap());
            if threads.is_empty() {
                break;
            }
            for t in threads {
                let _ = t.join();
            }
        }
        inner.parked.lock().unwrap().clear();
        for m in inner.mounts.lock().unwrap().iter() {
            let _ = std::process::Command::new("umount").arg(m).status();
        }
    }
}

/// How long [`Answer::Never`] leaves ep0 alone after a request: longer
/// than the host's control timeout.
const NAK_HOLD: Duration = Duration::from_millis(1500);

/// How [`answer_ep0`] answers a control request.
#[derive(Debug, Clone, Copy)]
enum Answer {
    /// Stall it (read in an IN data stage, write in an OUT one).
    Stall,
    /// One byte for an IN request, whatever length was asked; OUT data taken.
    OneByte,
    /// Never: the request NAKs until the host times out.
    Never,
}

/// Waits at most 100 ms for an event on ep0: a blocking read would wait for
/// ever when the gadget never binds, and the thread would not see `stop`.
fn ep0_ready(ep0: &File) -> bool {
    use std::os::fd::AsFd;
    let mut fds = [PollFd::new(ep0.as_fd(), PollFlags::POLLIN)];
    matches!(poll(&mut fds, PollTimeout::from(100u16)), Ok(n) if n > 0)
}

/// ep0 answered as the genuine board does ([`handle_setup`]).
fn genuine_ep0(mut ep0: File, inner: &Inner) {
    while !inner.stop.load(Ordering::SeqCst) {
        if !ep0_ready(&ep0) {
            continue;
        }
        for s in next_setups(&mut ep0) {
            let _ = handle_setup(&mut ep0, &inner.state, &inner.serial, &s);
        }
    }
}

fn answer_ep0(mut ep0: File, inner: &Inner, transfers: &AtomicU32, answer: Answer) {
    while !inner.stop.load(Ordering::SeqCst) {
        if !ep0_ready(&ep0) {
            continue;
        }
        for s in next_setups(&mut ep0) {
            transfers.fetch_add(1, Ordering::SeqCst);
            let is_in = s.rt & 0x80 != 0;
            match (answer, is_in) {
                // Left pending: the host times out (sdid waits 1 s) and its
                // next request cancels this one. Reading ep0 before then
                // would act on it (stall), so wait past that.
                (Answer::Never, _) => std::thread::sleep(NAK_HOLD),
                (Answer::OneByte, true) => {
                    let _ = ep0.write(&[0x5A]);
                }
                (Answer::OneByte, false) => {
                    let _ = ep0.read(&mut vec![0u8; s.length]);
                }
                (_, true) => {
                    let _ = ep0.read(&mut [0u8; 0]);
                }
                (_, false) => {
                    let _ = ep0.write(&[]);
                }
            }
        }
    }
}

/// UVC mode: the switch request (SET_CUR, control 6) is left unanswered,
/// the device drops off the bus and comes back in UVC mode; other requests
/// are stalled.
fn drop_on_uvc_switch(mut ep0: File, inner: &Inner, transfers: &AtomicU32) {
    while !inner.stop.load(Ordering::SeqCst) {
        if !ep0_ready(&ep0) {
            continue;
        }
        for s in next_setups(&mut ep0) {
            transfers.fetch_add(1, Ordering::SeqCst);
            if s.rt == 0x21 && s.value >> 8 == 6 {
                let _ = inner.unplug();
                std::thread::sleep(OFF_BUS);
                if !inner.stop.load(Ordering::SeqCst) {
                    let _ = inner.plug();
                }
            } else if s.rt & 0x80 != 0 {
                let _ = ep0.read(&mut [0u8; 0]);
            } else {
                let _ = ep0.write(&[]);
            }
        }
    }
}

/// Binds and unbinds the gadget every [`STORM_HALF_PERIOD`].
fn storm(inner: &Inner) {
    while !inner.stop.load(Ordering::SeqCst) {
        std::thread::sleep(STORM_HALF_PERIOD);
        let _ = inner.unplug();
        std::thread::sleep(STORM_HALF_PERIOD);
        if !inner.stop.load(Ordering::SeqCst) {
            let _ = inner.plug();
        }
    }
}

/// Bytes of one frame as configured, once sdid has started streaming.
fn streaming_frame_bytes(state: &Mutex<BoardState>) -> Option<usize> {
    let s = state.lock().unwrap();
    let on = field(s.reg(0x5880), 0, 0) == 0 && field(s.reg(0x5C25), 11, 8) == 15;
    let (w, h, quads) = s.geometry();
    on.then_some(w * h * quads * 2)
}

/// ep1 (bulk IN) of a mode that misbehaves once configured.
fn bulk_side(mode: HostileMode, ep1: &Path, inner: &Inner, transfers: &AtomicU32) {
    let mut file: Option<File> = None;
    let mut number: u8 = 0;
    let huge = if mode == HostileMode::HugeFrames {
        vec![0x5Au8; HUGE_FRAME_BYTES]
    } else {
        Vec::new()
    };
    while !inner.stop.load(Ordering::SeqCst) {
        let Some(frame_bytes) = streaming_frame_bytes(&inner.state) else {
            std::thread::sleep(Duration::from_millis(10));
            continue;
        };
        let Some(f) = open_endpoint(&mut file, ep1, true) else {
            continue;
        };
        number = number.wrapping_add(1);
        transfers.fetch_add(1, Ordering::SeqCst);
        let frame = |len: usize| {
            let mut b = vec![0u8; len];
            if let Some(first) = b.first_mut() {
                *first = number;
            }
            b
        };
        let ok = match mode {
            HostileMode::WrongLength => {
                let len = if number.is_multiple_of(2) {
                    frame_bytes.saturating_sub(3)
                } else {
                    frame_bytes + 5
                };
                send(f, &frame(len), true)
            }
            HostileMode::EmptyFrames => f.write(&[]).is_ok(),
            HostileMode::HugeFrames => send(f, &huge, true),
            // Reading an IN endpoint halts it (FunctionFS): every transfer
            // the host starts ends in a stall.
            HostileMode::StallBulk => {
                let _ = f.read(&mut [0u8; 1]);
                std::thread::sleep(Duration::from_millis(5));
                true
            }
            HostileMode::DisconnectMidTransfer => {
                let sent = send(f, &frame(frame_bytes / 2), false);
                let _ = inner.unplug();
                std::thread::sleep(OFF_BUS);
                if !inner.stop.load(Ordering::SeqCst) {
                    let _ = inner.plug();
                }
                file = None;
                sent
            }
            _ => {
                send(f, &frame(frame_bytes), true) && {
                    std::thread::sleep(Duration::from_millis(33));
                    true
                }
            }
        };
        if !ok {
            file = None;
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// Writes `bytes` in 64 KiB pieces, then a zero-length packet if `end`.
fn send(f: &mut File, bytes: &[u8], end: bool) -> bool {
    bytes.chunks(64 * 1024).all(|c| f.write_all(c).is_ok()) && (!end || f.write(&[]).is_ok())
}
