//! Two-channel SCPI function generator: channel 1 drives LS1 with f(t),
//! channel 2 drives LS2 with not-f (180 degrees out of phase, or inverted
//! output polarity), square wave, common frequency and duty cycle.
//!
//! Ports: raw SCPI over TCP (port 5025, the LXI socket convention) and the
//! kernel's USBTMC driver (`/dev/usbtmcN`, one message per read/write).
//! Commands are the SCPI-1999 forms that Keysight 33500-series and Rigol
//! DG-series generators accept (`SOURce<n>:FUNCtion SQUare`, `...:FREQuency`,
//! `...:FUNCtion:SQUare:DCYCle`, `...:PHASe`, `OUTPut<n>[:STATe]`,
//! `OUTPut<n>:POLarity`); each configuration ends with `SYSTem:ERRor?`.
//!
//! By hand: the Rust SCPI/VISA crates need the vendors' VISA libraries or
//! lack USBTMC; these dozen line-based commands over a socket or a
//! character device need neither.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::path::{Path, PathBuf};
use std::time::Duration;

use sdi_core::modulation::SourceDrive;

use super::{LightDrive, LightError, LightSource};

/// Default SCPI-raw TCP port (the one `[lights] address` gets when it has none).
pub use sdi_config::SCPI_TCP_PORT;
/// Longest accepted answer line.
const MAX_ANSWER_BYTES: usize = 4096;

/// A line-oriented connection to an instrument.
pub trait ScpiPort: Send {
    fn name(&self) -> String;
    fn send(&mut self, command: &str) -> Result<(), LightError>;
    /// Sends `command` and reads one answer line (terminator stripped).
    fn query(&mut self, command: &str) -> Result<String, LightError>;
}

/// SCPI over TCP.
pub struct TcpPort {
    addr: String,
    reader: BufReader<TcpStream>,
    timeout: Duration,
}

impl TcpPort {
    pub fn connect(
        addr: impl ToSocketAddrs + std::fmt::Display,
        timeout: Duration,
    ) -> Result<Self, LightError> {
        let name = addr.to_string();
        let io = |source| LightError::Io {
            port: name.clone(),
            source,
        };
        let sock = addr
            .to_socket_addrs()
            .map_err(io)?
            .next()
            .ok_or_else(|| io(std::io::Error::new(ErrorKind::NotFound, "no address")))?;
        let stream = TcpStream::connect_timeout(&sock, timeout).map_err(io)?;
        stream.set_read_timeout(Some(timeout)).map_err(io)?;
        stream.set_write_timeout(Some(timeout)).map_err(io)?;
        let _ = stream.set_nodelay(true);
        Ok(Self {
            addr: name,
            reader: BufReader::new(stream),
            timeout,
        })
    }
}

impl ScpiPort for TcpPort {
    fn name(&self) -> String {
        format!("tcp:{}", self.addr)
    }

    fn send(&mut self, command: &str) -> Result<(), LightError> {
        let port = self.name();
        self.reader
            .get_mut()
            .write_all(format!("{command}\n").as_bytes())
            .map_err(|source| LightError::Io { port, source })
    }

    fn query(&mut self, command: &str) -> Result<String, LightError> {
        self.send(command)?;
        let mut raw = Vec::new();
        let res = (&mut self.reader)
            .take(MAX_ANSWER_BYTES as u64)
            .read_until(b'\n', &mut raw);
        let port = self.name();
        match res {
            Ok(0) => Err(LightError::NoAnswer {
                port,
                command: command.into(),
                timeout_ms: self.timeout.as_millis(),
            }),
            Ok(_) if raw.last() != Some(&b'\n') => Err(LightError::Malformed {
                port,
                command: command.into(),
                answer: String::from_utf8_lossy(&raw).into_owned(),
            }),
            Ok(_) => parse_answer(&port, command, &raw),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                Err(LightError::NoAnswer {
                    port,
                    command: command.into(),
                    timeout_ms: self.timeout.as_millis(),
                })
            }
            Err(source) => Err(LightError::Io { port, source }),
        }
    }
}

/// SCPI over the kernel's USBTMC driver.
pub struct UsbtmcPort {
    path: PathBuf,
    file: File,
}

impl UsbtmcPort {
    pub fn open(path: impl AsRef<Path>) -> Result<Self, LightError> {
        let path = path.as_ref().to_path_buf();
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .open(&path)
            .map_err(|source| LightError::Io {
                port: path.display().to_string(),
                source,
            })?;
        Ok(Self { path, file })
    }
}

impl ScpiPort for UsbtmcPort {
    fn name(&self) -> String {
        self.path.display().to_string()
    }

    fn send(&mut self, command: &str) -> Result<(), LightError> {
        let port = self.name();
        self.file
            .write_all(format!("{command}\n").as_bytes())
            .map_err(|source| LightError::Io { port, source })
    }

    fn query(&mut self, command: &str) -> Result<String, LightError> {
        self.send(command)?;
        let mut buf = vec![0u8; MAX_ANSWER_BYTES];
        let port = self.name();
        match self.file.read(&mut buf) {
            Ok(0) => Err(LightError::Malformed {
                port,
                command: command.into(),
                answer: String::new(),
            }),
            Ok(n) => parse_answer(&port, command, &buf[..n]),
            // The usbtmc driver fails the read with ETIMEDOUT.
            Err(e) if e.raw_os_error() == Some(libc::ETIMEDOUT) => Err(LightError::NoAnswer {
                port,
                command: command.into(),
                timeout_ms: 5000,
            }),
            Err(source) => Err(LightError::Io { port, source }),
        }
    }
}

/// One answer line: UTF-8, printable, terminator stripped, not empty.
fn parse_answer(port: &str, command: &str, raw: &[u8]) -> Result<String, LightError> {
    let malformed = || LightError::Malformed {
        port: port.into(),
        command: command.into(),
        answer: String::from_utf8_lossy(raw).into_owned(),
    };
    let text = std::str::from_utf8(raw).map_err(|_| malformed())?;
    let text = text.trim_end_matches(['\n', '\r']);
    if text.is_empty() || text.chars().any(|c| c.is_control()) {
        return Err(malformed());
    }
    Ok(text.to_string())
}

/// `*IDN?` fields.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    pub manufacturer: String,
    pub model: String,
    pub serial: String,
    pub firmware: String,
}

/// How channel 2 becomes not-f.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Antiphase {
    /// Same waveform, 180 degrees phase (then phases re-aligned).
    #[default]
    Phase180,
    /// Output polarity inverted.
    InvertedPolarity,
}

/// A two-channel function generator as an LS1/LS2 driver.
pub struct FunctionGenerator<P> {
    port: P,
    pub identity: Identity,
    pub antiphase: Antiphase,
    /// Output high level of the square wave, volts (LED driver input).
    pub high_volts: f64,
    pub low_volts: f64,
}

impl<P: ScpiPort> FunctionGenerator<P> {
    /// Connects and checks the answer to `*IDN?`.
    pub fn new(mut port: P) -> Result<Self, LightError> {
        let answer = port.query("*IDN?")?;
        let parts: Vec<&str> = answer.split(',').map(str::trim).collect();
        if parts.len() != 4 || parts[0].is_empty() || parts[1].is_empty() {
            return Err(LightError::Malformed {
                port: port.name(),
                command: "*IDN?".into(),
                answer,
            });
        }
        Ok(Self {
            identity: Identity {
                manufacturer: parts[0].into(),
                model: parts[1].into(),
                serial: parts[2].into(),
                firmware: parts[3].into(),
            },
            port,
            antiphase: Antiphase::default(),
            high_volts: 3.3,
            low_volts: 0.0,
        })
    }

    pub fn port(&self) -> &P {
        &self.port
    }

    /// Checks the instrument's error queue after `after`.
    fn check_errors(&mut self, after: &str) -> Result<(), LightError> {
        let answer = self.port.query("SYSTem:ERRor?")?;
        let code = answer.split(',').next().unwrap_or("").trim();
        match code.parse::<i32>() {
            Ok(0) => Ok(()),
            Ok(_) => Err(LightError::Instrument {
                port: self.port.name(),
                command: after.into(),
                error: answer,
            }),
            Err(_) => Err(LightError::Malformed {
                port: self.port.name(),
                command: "SYSTem:ERRor?".into(),
                answer,
            }),
        }
    }

    fn channel_commands(&self, ch: u8, drive: SourceDrive, d: &LightDrive) -> Vec<String> {
        let mut c = Vec::new();
        if drive == SourceDrive::Off {
            c.push(format!("OUTPut{ch}:STATe OFF"));
            return c;
        }
        c.push(format!("SOURce{ch}:FUNCtion SQUare"));
        c.push(format!("SOURce{ch}:FREQuency {:.6E}", d.carrier_hz));
        c.push(format!("SOURce{ch}:VOLTage:HIGH {:.4}", self.high_volts));
        c.push(format!("SOURce{ch}:VOLTage:LOW {:.4}", self.low_volts));
        let inverted = drive == SourceDrive::Inverted;
        match self.antiphase {
            Antiphase::Phase180 => {
                c.push(format!(
                    "SOURce{ch}:FUNCtion:SQUare:DCYCle {:.4}",
                    d.duty * 100.0
                ));
                c.push(format!(
                    "SOURce{ch}:PHASe {}",
                    if inverted { 180 } else { 0 }
                ));
            }
            Antiphase::InvertedPolarity => {
                c.push(format!(
                    "SOURce{ch}:FUNCtion:SQUare:DCYCle {:.4}",
                    d.duty * 100.0
                ));
                c.push(format!(
                    "OUTPut{ch}:POLarity {}",
                    if inverted { "INVerted" } else { "NORMal" }
                ));
            }
        }
        c.push(format!("OUTPut{ch}:STATe ON"));
        c
    }

    /// The SCPI commands a drive becomes (for logs and tests).
    pub fn commands_for(&self, d: &LightDrive) -> Result<Vec<String>, LightError> {
        d.validate()?;
        for s in [d.ls1, d.ls2] {
            if s == SourceDrive::Constant {
                return Err(LightError::Unsupported {
                    rig: "function generator",
                    ls1: d.ls1,
                    ls2: d.ls2,
                    why: "a constant (unmodulated) source is not a square wave",
                });
            }
        }
        let mut c = self.channel_commands(1, d.ls1, d);
        c.extend(self.channel_commands(2, d.ls2, d));
        if self.antiphase == Antiphase::Phase180
            && d.ls1 != SourceDrive::Off
            && d.ls2 != SourceDrive::Off
        {
            // Restart both channels' phase accumulators together.
            c.push("SOURce1:PHASe:SYNChronize".into());
        }
        Ok(c)
    }
}

impl<P: ScpiPort> LightSource for FunctionGenerator<P> {
    fn describe(&self) -> String {
        format!(
            "{} {} on {} (CH1 = LS1, CH2 = LS2)",
            self.identity.manufacturer,
            self.identity.model,
            self.port.name()
        )
    }

    fn apply(&mut self, drive: &LightDrive) -> Result<(), LightError> {
        let commands = self.commands_for(drive)?;
        for c in &commands {
            self.port.send(c)?;
        }
        self.check_errors(commands.last().map_or("", String::as_str))
    }
}

#[cfg(test)]
mod tests {
    use std::io::{BufRead, BufReader, Write};
    use std::net::TcpListener;
    use std::sync::{Arc, Mutex};

    use super::*;
    use sdi_core::modulation::Illumination;

    /// How the fake instrument answers.
    #[derive(Clone, Copy)]
    enum Behaviour {
        Good,
        SilentIdn,
        GarbageIdn,
        ErrorQueue,
    }

    /// A tiny SCPI instrument on 127.0.0.1 that records every line it gets.
    fn instrument(b: Behaviour) -> (String, Arc<Mutex<Vec<String>>>) {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let log = Arc::new(Mutex::new(Vec::new()));
        let log2 = log.clone();
        std::thread::spawn(move || {
            let (stream, _) = listener.accept().unwrap();
            let mut out = stream.try_clone().unwrap();
            for line in BufReader::new(stream).lines() {
                let Ok(line) = line else { break };
                log2.lock().unwrap().push(line.clone());
                let answer: Option<&[u8]> = match (line.as_str(), b) {
                    ("*IDN?", Behaviour::SilentIdn) => None,
                    ("*IDN?", Behaviour::GarbageIdn) => Some(b"\xff\xfe\n"),
                    ("*IDN?", _) => Some(b"ACME Instruments,FG-2,SN123,1.0\n"),
                    ("SYSTem:ERRor?", Behaviour::ErrorQueue) => {
                        Some(b"-222,\"Data out of range\"\n")
                    }
                    ("SYSTem:ERRor?", _) => Some(b"+0,\"No error\"\n"),
                    _ => None,
                };
                if let Some(a) = answer {
                    if out.write_all(a).is_err() {
                        break;
                    }
                }
            }
        });
        (addr, log)
    }

    fn connect(addr: &str) -> TcpPort {
        TcpPort::connect(addr.to_string(), Duration::from_millis(300)).unwrap()
    }

    #[test]
    fn snapshot_drive_programs_both_channels_in_antiphase() {
        let (addr, log) = instrument(Behaviour::Good);
        let mut fg = FunctionGenerator::new(connect(&addr)).unwrap();
        assert_eq!(fg.identity.model, "FG-2");
        fg.apply(&LightDrive::from_illumination(&Illumination::snapshot(2e6)))
            .unwrap();
        let log = log.lock().unwrap().clone();
        assert_eq!(log[0], "*IDN?");
        for want in [
            "SOURce1:FUNCtion SQUare",
            "SOURce1:FREQuency 2.000000E6",
            "SOURce2:FREQuency 2.000000E6",
            "SOURce1:FUNCtion:SQUare:DCYCle 50.0000",
            "SOURce1:PHASe 0",
            "SOURce2:PHASe 180",
            "OUTPut1:STATe ON",
            "OUTPut2:STATe ON",
            "SOURce1:PHASe:SYNChronize",
        ] {
            assert!(log.iter().any(|l| l == want), "missing {want}: {log:?}");
        }
        assert_eq!(log.last().unwrap(), "SYSTem:ERRor?");
        assert!(fg.describe().contains("ACME"));
    }

    #[test]
    fn off_and_polarity_variants() {
        let (addr, log) = instrument(Behaviour::Good);
        let mut fg = FunctionGenerator::new(connect(&addr)).unwrap();
        fg.antiphase = Antiphase::InvertedPolarity;
        fg.apply(&LightDrive::from_illumination(&Illumination::snapshot(1e6)))
            .unwrap();
        fg.apply(&LightDrive::off(1e6)).unwrap();
        let log = log.lock().unwrap().clone();
        assert!(log.iter().any(|l| l == "OUTPut2:POLarity INVerted"));
        assert!(log.iter().any(|l| l == "OUTPut1:POLarity NORMal"));
        let tail: Vec<_> = log.iter().rev().take(3).cloned().collect();
        assert_eq!(
            tail,
            vec!["SYSTem:ERRor?", "OUTPut2:STATe OFF", "OUTPut1:STATe OFF"]
        );
        let constant = LightDrive {
            ls1: SourceDrive::Constant,
            ..LightDrive::off(1e6)
        };
        assert!(matches!(
            fg.apply(&constant),
            Err(LightError::Unsupported { .. })
        ));
    }

    #[test]
    fn missing_answer_is_a_clear_error() {
        let (addr, _) = instrument(Behaviour::SilentIdn);
        let e = FunctionGenerator::new(connect(&addr)).err().unwrap();
        assert!(matches!(e, LightError::NoAnswer { .. }), "{e}");
        assert!(e.to_string().contains("did not answer \"*IDN?\""), "{e}");
    }

    #[test]
    fn malformed_answer_is_a_clear_error() {
        let (addr, _) = instrument(Behaviour::GarbageIdn);
        let e = FunctionGenerator::new(connect(&addr)).err().unwrap();
        assert!(matches!(e, LightError::Malformed { .. }), "{e}");
    }

    #[test]
    fn instrument_errors_are_reported() {
        let (addr, _) = instrument(Behaviour::ErrorQueue);
        let mut fg = FunctionGenerator::new(connect(&addr)).unwrap();
        let e = fg
            .apply(&LightDrive::from_illumination(&Illumination::snapshot(3e6)))
            .unwrap_err();
        assert!(e.to_string().contains("Data out of range"), "{e}");
    }

    #[test]
    fn connection_refused_is_an_io_error() {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap().to_string();
        drop(l);
        let e = TcpPort::connect(addr, Duration::from_millis(200))
            .err()
            .unwrap();
        assert!(matches!(e, LightError::Io { .. }));
    }

    #[test]
    fn answers_are_validated() {
        assert_eq!(parse_answer("p", "c", b"ok\r\n").unwrap(), "ok");
        assert!(parse_answer("p", "c", b"\n").is_err());
        assert!(parse_answer("p", "c", b"a\x07b\n").is_err());
    }
}
