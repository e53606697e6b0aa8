//! A two-channel SCPI function generator on 127.0.0.1 for sdid's
//! `[lights] driver = "scpi-tcp"`: answers `*IDN?` and `SYSTem:ERRor?`,
//! records every command, and reports each configuration's output states
//! (CH1 = LS1, CH2 = LS2) to the test, e.g. to light the board emulator's
//! scene as sdid drives it.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::sync::{Arc, Mutex};

/// The instrument: its address for `[lights] address` and what it received.
pub struct ScpiRig {
    pub address: String,
    pub log: Arc<Mutex<Vec<String>>>,
}

impl ScpiRig {
    /// Listens on a free loopback port; `on_drive(ls1_on, ls2_on)` runs at
    /// the end of each configuration (`SYSTem:ERRor?`), before it is
    /// answered, so the drive is in effect when sdid's `apply` returns.
    pub fn start(on_drive: impl Fn(bool, bool) + Send + 'static) -> std::io::Result<Self> {
        let listener = TcpListener::bind("127.0.0.1:0")?;
        let address = listener.local_addr()?.to_string();
        let log = Arc::new(Mutex::new(Vec::new()));
        let l = log.clone();
        std::thread::spawn(move || {
            let (mut ch1, mut ch2) = (false, false);
            for stream in listener.incoming().flatten() {
                let Ok(mut w) = stream.try_clone() else {
                    continue;
                };
                for line in BufReader::new(stream).lines() {
                    let Ok(line) = line else { break };
                    let line = line.trim().to_owned();
                    match line.as_str() {
                        "OUTPut1:STATe ON" => ch1 = true,
                        "OUTPut1:STATe OFF" => ch1 = false,
                        "OUTPut2:STATe ON" => ch2 = true,
                        "OUTPut2:STATe OFF" => ch2 = false,
                        "SYSTem:ERRor?" => on_drive(ch1, ch2),
                        _ => {}
                    }
                    let answer: Option<&[u8]> = match line.as_str() {
                        "*IDN?" => Some(b"SDI Test,FG-2,0001,1.0\n"),
                        "SYSTem:ERRor?" => Some(b"0,\"No error\"\n"),
                        _ => None,
                    };
                    l.lock().unwrap().push(line);
                    if let Some(a) = answer {
                        if w.write_all(a).is_err() {
                            break;
                        }
                    }
                }
            }
        });
        Ok(Self { address, log })
    }
}
