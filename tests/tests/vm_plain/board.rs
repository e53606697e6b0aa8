//! The OPT8241 backend against the board emulator over the kernel's real USB
//! stack (dummy_hcd + configfs gadget + FunctionFS), inside the VM.

use std::time::{Duration, Instant};

use sdi_core::mode::ModeId;
use sdi_core::modulation::Illumination;
use sdi_core::Frame;
use sdi_daemon::backend::board::{
    board_config, BoardBackend, BoardBackendConfig, OnUnplug, ReconnectCounts,
};
use sdi_daemon::backend::opt8241::usb::{open_board, UsbError, UsbTransport, UVC_SWITCH_TIMEOUT};
use sdi_daemon::backend::opt8241::{BoardError, BoardSelector, Opt8241};
use sdi_daemon::backend::{Backend, BackendError};
use sdi_opt8241::protocol::RegisterBus;
use sdi_opt8241::registers::field;
use sdi_opt8241::{BoardConfig, Roi};
use sdi_tests::board_emulator::BoardEmulator;
use sdi_tests::wait::wait_for;

fn matches_sent(emu: &BoardEmulator, frame: &Frame) -> bool {
    let s = emu.state.lock().unwrap();
    s.sent
        .iter()
        .any(|(_, dn)| dn.len() == frame.dn.data.len() && dn[1..] == frame.dn.data[1..])
}

/// Calls `attempt` until its result is other than "no frame yet", as the
/// frame loop does: the board and the backend both yield that after each
/// 100 ms slice of their wait (the 2 s no-frame rule runs across calls).
fn past_not_yet<E>(
    mut attempt: impl FnMut() -> Result<(), E>,
    not_yet: impl Fn(&E) -> bool,
) -> Result<(), E> {
    loop {
        match attempt() {
            Err(e) if not_yet(&e) => continue,
            r => return r,
        }
    }
}

/// The board's next frame as the frame loop gets it.
fn next_frame(
    board: &mut Opt8241,
    ill: &Illumination,
    frame: &mut Frame,
) -> Result<(), BoardError> {
    past_not_yet(
        || board.next_frame(ill, frame),
        |e| matches!(e, BoardError::NotYet),
    )
}

#[test]
fn opt8241_backend_against_usb_emulator() {
    if crate::GUEST.on_host() {
        return;
    }
    let emu = BoardEmulator::start("opt8241", "EMU0001").expect("gadget");
    let selector = BoardSelector::default();

    // 1. enumerate: found by IDs, endpoint from the descriptors
    let open = wait_for("enumeration", Duration::from_secs(20), || {
        // A fresh context per attempt: its device list is a new scan.
        let ctx = rusb::Context::new().unwrap();
        match open_board(&ctx, &selector) {
            Ok(o) => Some(o),
            Err(e) => {
                let devs = std::fs::read_dir("/sys/bus/usb/devices")
                    .map(|d| d.flatten().map(|e| e.file_name()).collect::<Vec<_>>())
                    .unwrap_or_default();
                eprintln!("not yet: {e}; sysfs: {devs:?}");
                None
            }
        }
    });
    assert_eq!(open.serial.as_deref(), Some("EMU0001"));
    assert_eq!(open.endpoint.address & 0x80, 0x80);
    eprintln!("endpoint {:?}", open.endpoint);

    // 2. registers over real control transfers; the firmware's clamps are reported
    let mut bus = RegisterBus::new(UsbTransport {
        handle: open.handle.clone(),
    });
    assert_eq!(bus.firmware_version().unwrap(), (0x00, 0x11));
    assert_eq!(bus.serial_number().unwrap(), "EMU0001");
    let w = bus.write_field(field::INTG_DUTY_CYCLE, 40).unwrap();
    assert!(w.clamped() && w.actual == 20, "{w:?}");
    let w = bus.write_field(field::PIX_CNT_MAX, 1000).unwrap();
    assert_eq!(w.actual, 60_000);
    drop(bus);
    drop(open);

    // 3. configure the whole board; the emulator checks what it received
    let config = BoardConfig {
        roi: Roi {
            x: 0,
            y: 0,
            width: 64,
            height: 48,
        },
        frame_rate_hz: 30.0,
        integration_percent: 90.0,
        ..BoardConfig::default()
    };
    let mut board = Opt8241::open(selector.clone(), config).expect("open board");
    let clamps: Vec<_> = board.init_report().clamps.iter().map(|c| c.field).collect();
    assert_eq!(clamps, vec!["intg_duty_cycle"]);
    {
        let s = emu.state.lock().unwrap();
        let after_setup = &s.writes[2..];
        assert_eq!(
            after_setup.first().map(|w| (w.address, w.written & 1)),
            Some((0x5880, 1))
        );
        // the timing generator restarts, then the trailing PLL update pulse
        let n = after_setup.len();
        let tail: Vec<_> = after_setup[n - 3..]
            .iter()
            .map(|w| (w.address, w.written))
            .collect();
        assert_eq!(tail[0].0, 0x5880);
        assert_eq!(tail[0].1 & 1, 0);
        assert_eq!((tail[1].0, (tail[1].1 >> 2) & 1), (0x5802, 1));
        assert_eq!((tail[2].0, (tail[2].1 >> 2) & 1), (0x5802, 0));
        for w in after_setup {
            assert_eq!(
                w.written, w.kept,
                "sdid wrote a value the firmware had to clamp: {w:?}"
            );
        }
        assert_eq!(s.reg_value(0x5C4C) & 0x3F, 20);
        assert_eq!((s.reg_value(0x5C25) >> 8) & 0xF, 15);
        assert!(s.stalled.is_empty(), "{:?}", s.stalled);
        // nothing of the leftover 6-quad dealiasing profile survives the open
        assert_eq!(s.reg_value(0x5883) & 0xFF, 0x14, "4 quads, 1 sub frame");
        assert_eq!((s.reg_value(0x5C02) >> 23) & 1, 0, "dealias_en");
        assert_eq!((s.reg_value(0x5812) >> 7) & 1, 0, "quad_hop_en");
        assert_eq!((s.reg_value(0x5C4D) >> 6) & 7, 0, "normal_frm_intg_scale");
        assert_eq!((s.reg_value(0x5C31) >> 4) & 0x1F, 0, "amplitude_scale");
        assert_eq!((s.reg_value(0x5C39) >> 1) & 3, 0, "op_clk_freq");
        assert_eq!((s.reg_value(0x580E) >> 3) & 1, 0, "sscg_en");
        assert_eq!(s.reg_value(0x5C2E) & 0x7F, 0x72, "tillum_slv_addr");
        assert_eq!((s.reg_value(0x5C2F) >> 12) & 1, 1, "binning_en");
        assert_eq!(s.reg_value(0x5C2F) & 0x3FF, 1, "rows_to_merge");
        // the second PLL follows the first
        assert_eq!(s.reg_value(0x580D), s.reg_value(0x580C), "PLL 2 = PLL 1");
        // the PLL took the 12 MHz setting: an update edge after the settle time
        let pll = sdi_tests::board_emulator::chip::pll_in_effect(&s.writes);
        assert_eq!(
            pll,
            Some([s.reg_value(0x580C), s.reg_value(0x580F)]),
            "PLL never took effect"
        );
        assert_eq!((s.reg_value(0x580C) >> 16) & 0x3F, 14, "mod_m1 for 12 MHz");
    }

    // 4. stream N frames and compare with what the emulator sent
    let ill = Illumination::snapshot(12e6);
    let mut frame = Frame::new(1, 1);
    for i in 0..8 {
        next_frame(&mut board, &ill, &mut frame).unwrap_or_else(|e| panic!("frame {i}: {e}"));
        assert_eq!((frame.width(), frame.height()), (64, 48));
        assert!(
            matches_sent(&emu, &frame),
            "frame {i} differs from every frame sent"
        );
    }

    // 5. a misaligned frame is detected and the stream recovers
    emu.shift_next_frame
        .store(10, std::sync::atomic::Ordering::SeqCst);
    for i in 0..6 {
        next_frame(&mut board, &ill, &mut frame).unwrap_or_else(|e| panic!("after shift {i}: {e}"));
        assert!(matches_sent(&emu, &frame));
    }
    let stats = board.stats();
    eprintln!("stats {stats:?}");
    assert!(stats.assembler.misaligned >= 1, "{stats:?}");
    assert!(stats.assembler.resyncs >= 1, "{stats:?}");

    // 6. unplug mid-stream, then plug back in
    emu.unplug().unwrap();
    wait_for("DeviceUnavailable", Duration::from_secs(20), || match board
        .next_frame(&ill, &mut frame)
    {
        Err(BoardError::DeviceUnavailable) => Some(()),
        _ => None,
    });
    assert!(!board.is_connected());
    emu.plug().unwrap();
    wait_for("reconnect", Duration::from_secs(30), || {
        board.reconnect().ok()
    });
    next_frame(&mut board, &ill, &mut frame).expect("frame after replug");
    assert!(matches_sent(&emu, &frame));
    assert_eq!(board.stats().reconnects, 1);
}

/// A UVC-mode board whose firmware does not come back after the switch
/// request: opening it ends in the typed timeout error, after about
/// `UVC_SWITCH_TIMEOUT`, not in a hang.
#[test]
fn uvc_switch_that_never_comes_back_is_a_typed_timeout() {
    if crate::GUEST.on_host() {
        return;
    }
    let emu = BoardEmulator::start_uvc("stuck", "EMU0004").expect("gadget");
    emu.ignore_uvc_switch
        .store(true, std::sync::atomic::Ordering::SeqCst);
    wait_for("enumeration in UVC mode", Duration::from_secs(20), || {
        sdi_daemon::backend::board::board_attached()
            .ok()
            .filter(|&a| a)
    });
    let t0 = Instant::now();
    let err = Opt8241::open(BoardSelector::default(), BoardConfig::default())
        .err()
        .expect("opening must fail");
    let took = t0.elapsed();
    eprintln!("MEASURED: switch timeout after {took:?}: {err}");
    assert!(
        matches!(err, BoardError::Usb(UsbError::UvcSwitchTimeout { .. })),
        "{err:?}"
    );
    assert!(took >= UVC_SWITCH_TIMEOUT && took < UVC_SWITCH_TIMEOUT + Duration::from_secs(10));
    let s = emu.state.lock().unwrap();
    assert_eq!(s.uvc_requests.len(), 1, "{:?}", s.uvc_requests);
    assert!(s.switched_to_bulk.is_none());
}

/// The backend's next frame as the frame loop gets it.
fn capture(
    backend: &mut BoardBackend,
    ill: &Illumination,
    frame: &mut Frame,
) -> Result<(), BackendError> {
    past_not_yet(
        || backend.capture(ill, frame),
        |e| matches!(e, BackendError::NotYet),
    )
}

/// Unplugs and replugs the emulator under a running `BoardBackend` (with or
/// without its libusb hotplug watch); returns how the backend found the
/// board again, the hotplug events libusb delivered, and the time from
/// replug to the first frame.
fn backend_replug(
    name: &str,
    serial: &str,
    hotplug_events: bool,
) -> (ReconnectCounts, Option<u64>, Duration) {
    let emu = BoardEmulator::start(name, serial).expect("gadget");
    wait_for("enumeration", Duration::from_secs(20), || {
        sdi_daemon::backend::board::board_attached()
            .ok()
            .filter(|&a| a)
    });
    let mut backend = BoardBackend::open(BoardBackendConfig {
        selector: BoardSelector {
            serial: Some(serial.into()),
            ..BoardSelector::default()
        },
        board: board_config(
            Some(Roi {
                x: 0,
                y: 0,
                width: 64,
                height: 48,
            }),
            Some(30.0),
            None,
            None,
        ),
        on_unplug: OnUnplug::NoSignal,
        seed: 1,
        mode: ModeId::Raw,
        hotplug_events,
    })
    .expect("open the board backend");
    let ill = Illumination::snapshot(12e6);
    let mut frame = Frame::new(1, 1);
    for i in 0..3 {
        capture(&mut backend, &ill, &mut frame).unwrap_or_else(|e| panic!("frame {i}: {e}"));
    }
    emu.unplug().unwrap();
    wait_for("Unavailable", Duration::from_secs(20), || {
        matches!(
            backend.capture(&ill, &mut frame),
            Err(BackendError::Unavailable(_))
        )
        .then_some(())
    });
    // Let a hotplug "left" event (if any) arrive, as between a real unplug
    // and replug.
    for _ in 0..10 {
        let _ = backend.capture(&ill, &mut frame);
    }
    let t_plug = Instant::now();
    emu.plug().unwrap();
    wait_for("frames after replug", Duration::from_secs(30), || {
        backend.capture(&ill, &mut frame).ok()
    });
    let back = t_plug.elapsed();
    assert!(matches_sent(&emu, &frame));
    (backend.reconnects(), backend.hotplug_events(), back)
}

/// A replugged board that no hotplug event announces is found by the bus
/// scan. Whether libusb announces it depends on how it was built, not on
/// sdid: Debian's libusb takes events from udevd (none in the VM), the copy
/// rusb builds without libusb-1.0-0-dev reads the kernel's uevents (events
/// with or without udevd). So the test turns the watch off, as a libusb
/// without events would.
#[test]
fn backend_replug_without_hotplug_events_is_found_by_the_bus_scan() {
    if crate::GUEST.on_host() {
        return;
    }
    let (reconnects, events, back) = backend_replug("noudev", "EMU0005", false);
    eprintln!(
        "MEASURED: without hotplug events: reconnects {reconnects:?}, \
         first frame {back:?} after replug"
    );
    assert_eq!(events, None, "the watch was off");
    assert_eq!(
        reconnects,
        ReconnectCounts {
            by_hotplug: 0,
            by_poll: 1
        }
    );
}

/// With systemd-udevd running in the guest, libusb delivers the hotplug
/// events and the arrival (not the scan) brings the board back.
#[test]
fn backend_replug_with_udevd_is_found_by_a_hotplug_event() {
    if crate::GUEST.on_host() {
        return;
    }
    let run = |cmd: &str, args: &[&str]| {
        let st = std::process::Command::new(cmd)
            .args(args)
            .status()
            .unwrap_or_else(|e| panic!("{cmd}: {e}"));
        assert!(st.success(), "{cmd} {args:?}: {st}");
    };
    run("/lib/systemd/systemd-udevd", &["--daemon"]);
    // --settle waits on the udev monitor; `udevadm settle` pings udevd's
    // control socket, which udevd 252 can refuse (tests/src/udev.rs).
    run("udevadm", &["trigger", "--action=add", "--settle"]);
    let (reconnects, events, back) = backend_replug("udev", "EMU0006", true);
    eprintln!(
        "MEASURED: with udevd: hotplug events {events:?}, reconnects {reconnects:?}, \
         first frame {back:?} after replug"
    );
    assert!(events.is_some_and(|n| n >= 2), "left + arrived: {events:?}");
    assert_eq!(
        reconnects,
        ReconnectCounts {
            by_hotplug: 1,
            by_poll: 0
        }
    );
}
