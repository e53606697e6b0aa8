//! `[lights]` drive real light-source hardware from the modes: sdid with the
//! SCPI driver pointed at a small instrument on 127.0.0.1 that records every
//! command; two-shot alternates LS1 and LS2 per frame, temporal gradient
//! turns both off.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::require_dbus;

/// A two-channel function generator on loopback: answers `*IDN?` and
/// `SYSTem:ERRor?`, records everything.
fn instrument() -> (String, Arc<Mutex<Vec<String>>>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let log = Arc::new(Mutex::new(Vec::new()));
    let l = log.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let mut w = stream.try_clone().unwrap();
            for line in BufReader::new(stream).lines() {
                let Ok(line) = line else { break };
                let answer: Option<&[u8]> = match line.trim() {
                    "*IDN?" => Some(b"SDI Test,FG-2,0001,1.0\n"),
                    "SYSTem:ERRor?" => Some(b"0,\"No error\"\n"),
                    _ => None,
                };
                l.lock().unwrap().push(line.trim().to_owned());
                if let Some(a) = answer {
                    if w.write_all(a).is_err() {
                        break;
                    }
                }
            }
        }
    });
    (addr, log)
}

/// (CH1 on, CH2 on) of each configuration, a configuration ending with
/// `SYSTem:ERRor?`.
fn drives(log: &[String]) -> Vec<(bool, bool)> {
    let mut out = Vec::new();
    let (mut ch1, mut ch2) = (None, None);
    for c in log {
        match c.as_str() {
            "OUTPut1:STATe ON" => ch1 = Some(true),
            "OUTPut1:STATe OFF" => ch1 = Some(false),
            "OUTPut2:STATe ON" => ch2 = Some(true),
            "OUTPut2:STATe OFF" => ch2 = Some(false),
            "SYSTem:ERRor?" => {
                if let (Some(a), Some(b)) = (ch1.take(), ch2.take()) {
                    out.push((a, b));
                }
            }
            _ => {}
        }
    }
    out
}

fn wait_drives(log: &Mutex<Vec<String>>, n: usize) -> Vec<(bool, bool)> {
    let t0 = Instant::now();
    loop {
        let d = drives(&log.lock().unwrap());
        if d.len() >= n {
            return d;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "only {} configurations: {:?}",
            d.len(),
            log.lock().unwrap()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn modes_drive_the_scpi_light_sources() {
    require_dbus!();
    let (addr, log) = instrument();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sdid.toml");
    std::fs::write(
        &cfg,
        format!("[lights]\ndriver = \"scpi-tcp\"\naddress = \"{addr}\"\n"),
    )
    .unwrap();
    let bus = Bus::start();
    let d = Daemon::start(
        &bus,
        &["--config", cfg.to_str().unwrap(), "--backend", "sim"],
    );
    assert_eq!(
        log.lock().unwrap().first().map(String::as_str),
        Some("*IDN?")
    );
    // raw mode: both sources on, in antiphase (CH2 180 degrees), set once
    let first = wait_drives(&log, 1);
    assert_eq!(first[0], (true, true));
    assert!(log.lock().unwrap().iter().any(|c| c == "SOURce2:PHASe 180"));
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(
        drives(&log.lock().unwrap()).len(),
        1,
        "unchanged drive resent"
    );

    // two-shot: LS1 and LS2 alternate frame by frame
    assert!(d.ctl(&["set-mode", "two-shot"]).status.success());
    let d2 = wait_drives(&log, 7);
    let shots = &d2[1..];
    assert!(
        shots
            .iter()
            .all(|&s| s == (true, false) || s == (false, true)),
        "{shots:?}"
    );
    for pair in shots.windows(2) {
        assert_ne!(pair[0], pair[1], "not alternating: {shots:?}");
    }

    // temporal gradient: both off, and it stays so
    assert!(d.ctl(&["set-mode", "temporal-gradient"]).status.success());
    let t0 = Instant::now();
    loop {
        let d = drives(&log.lock().unwrap());
        if d.last() == Some(&(false, false)) {
            break;
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "{d:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
    let n = drives(&log.lock().unwrap()).len();
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(drives(&log.lock().unwrap()).len(), n);
    eprintln!(
        "instrument received {} commands, {n} configurations",
        log.lock().unwrap().len()
    );
}

#[test]
fn unreachable_instrument_is_a_clear_startup_error() {
    require_dbus!();
    // A port nobody listens on.
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sdid.toml");
    std::fs::write(
        &cfg,
        format!("[lights]\ndriver = \"scpi-tcp\"\naddress = \"127.0.0.1:{port}\"\n"),
    )
    .unwrap();
    let out = sdi_tests::sdid_command::SdidCommand::new()
        .args(["--session"])
        .sim()
        .y4m("-")
        .config(&cfg)
        .command()
        .stdout(std::process::Stdio::null())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("[lights]") && err.contains(&port.to_string()),
        "{err}"
    );
}
