//! [`Config::validate`]: each setting checked once, at load, as libcamera's
//! `CameraConfiguration::validate()` does: valid, adjusted (the change is
//! returned for the caller to log), or invalid (a typed error naming the key).

use std::fmt;

use sdi_core::display::MAX_RANGE_DN;
use sdi_core::number::Number;
use sdi_core::sensor::capture_range::{self, CaptureRange};
use sdi_core::sensor::ParamError;
use sdi_core::separation::{BilateralParams, LiveMethod, SeparationError};

use crate::camera::{in_section, MAX_CAMERAS};
use crate::choice::{BackendKind, LightDriver, SeparationMethod};
use crate::file::{Config, SeparationSection};

/// The TCP port of SCPI instruments (IEC 61158 "SCPI-RAW"), added to an
/// `[lights] address` without one.
pub const SCPI_TCP_PORT: u16 = 5025;

/// The smallest `[recording] max_bytes`: room for the header, one
/// uncompressed 320 x 240 i16 frame and the end record.
pub const MIN_RECORDING_BYTES: u64 = 256 << 10;
/// The largest `[recording] min_free_bytes` (1 EiB): a floor above it
/// (e.g. a negative number written as an unsigned one) refuses every recording.
pub const MAX_MIN_FREE_BYTES: u64 = 1 << 60;

/// A setting that cannot be used as given.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {reason}")]
pub struct Invalid {
    /// The key as written in `sdid.toml` (`frame_rate_hz`, `lights.address`).
    pub key: &'static str,
    pub reason: String,
}

/// A setting changed to the nearest usable value.
#[derive(Debug, Clone, PartialEq)]
pub struct Adjustment {
    pub key: &'static str,
    pub given: String,
    pub used: String,
    pub why: &'static str,
}

impl fmt::Display for Adjustment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} = {} adjusted to {}: {}",
            self.key, self.given, self.used, self.why
        )
    }
}

fn invalid(key: &'static str, reason: impl Into<String>) -> Invalid {
    Invalid {
        key,
        reason: reason.into(),
    }
}

fn check_capture(range: CaptureRange, value: Option<f64>) -> Result<(), Invalid> {
    match value {
        Some(v) => range
            .check(v)
            .map(|_| ())
            .map_err(|e| invalid(range.name, e.to_string())),
        None => Ok(()),
    }
}

impl SeparationSection {
    /// The estimator these settings select; the parameters are checked by
    /// [`Config::validate`] ([`LiveMethod::validate`], one set of bounds).
    pub fn live_method(&self) -> LiveMethod {
        match self.method {
            SeparationMethod::M3 => LiveMethod::Bilateral(BilateralParams::new(
                self.sigma_domain_px,
                self.sigma_range_dn,
            )),
            SeparationMethod::Window => LiveMethod::SlidingWindow {
                frames: self.window_frames,
            },
        }
    }
}

impl Config {
    /// Checks every setting and combination; adjusts what has a nearest
    /// usable value and returns those adjustments, refuses the rest.
    pub fn validate(&mut self) -> Result<Vec<Adjustment>, Invalid> {
        let mut adjusted = Vec::new();
        check_capture(capture_range::EXPOSURE_US, self.exposure_us)?;
        check_capture(capture_range::FRAME_RATE_HZ, self.frame_rate_hz)?;
        check_capture(capture_range::MODULATION_HZ, self.modulation_hz)?;
        if let (Some(e), Some(f)) = (self.exposure_us, self.frame_rate_hz) {
            let period_us = 1e6 / f;
            if e > period_us {
                return Err(invalid(
                    "exposure_us",
                    format!(
                        "{} us is longer than the frame period {period_us:.1} us of frame_rate_hz = {}",
                        Number(e),
                        Number(f)
                    ),
                ));
            }
        }
        self.check_cameras()?;
        if self.backend == BackendKind::Replay && self.replay.path.is_none() {
            return Err(invalid(
                "replay.path",
                "backend = \"replay\" needs a recording (or --replay FILE)",
            ));
        }

        let r = self.display.range_max_abs_dn;
        if r.is_nan() || r < 0.0 {
            return Err(invalid(
                "display.range_max_abs_dn",
                format!("{} must be 0 (auto) or a positive number of DN", Number(r)),
            ));
        }
        if r > MAX_RANGE_DN {
            self.display.range_max_abs_dn = MAX_RANGE_DN;
            adjusted.push(Adjustment {
                key: "display.range_max_abs_dn",
                given: r.to_string(),
                used: MAX_RANGE_DN.to_string(),
                why: "the largest fixed display range",
            });
        }

        self.separation.live_method().validate().map_err(|e| {
            let key = match &e {
                SeparationError::Parameter(ParamError {
                    name: "sigma_domain_px",
                    ..
                }) => "separation.sigma_domain_px",
                SeparationError::Parameter(ParamError {
                    name: "sigma_range_dn",
                    ..
                }) => "separation.sigma_range_dn",
                _ => "separation.window_frames",
            };
            invalid(key, e.to_string())
        })?;

        if let Some(max) = self.recording.max_bytes {
            if max == 0 {
                return Err(invalid(
                    "recording.max_bytes",
                    "0 would end every recording at once; leave it out for no limit",
                ));
            }
            if max < MIN_RECORDING_BYTES {
                self.recording.max_bytes = Some(MIN_RECORDING_BYTES);
                adjusted.push(Adjustment {
                    key: "recording.max_bytes",
                    given: max.to_string(),
                    used: MIN_RECORDING_BYTES.to_string(),
                    why: "the smallest recording: header, a frame and the end record",
                });
            }
        }
        if self.recording.min_free_bytes > MAX_MIN_FREE_BYTES {
            return Err(invalid(
                "recording.min_free_bytes",
                format!(
                    "{} bytes is more than any file system offers (at most {MAX_MIN_FREE_BYTES}); 0 turns the floor off",
                    self.recording.min_free_bytes
                ),
            ));
        }

        let l = &mut self.lights;
        match l.driver {
            LightDriver::None | LightDriver::Board => {}
            LightDriver::ScpiTcp => {
                if l.address.is_empty() {
                    return Err(invalid(
                        "lights.address",
                        "driver = \"scpi-tcp\" needs address = \"host:port\"",
                    ));
                }
                if !l.address.contains(':') {
                    let given = std::mem::take(&mut l.address);
                    l.address = format!("{given}:{SCPI_TCP_PORT}");
                    adjusted.push(Adjustment {
                        key: "lights.address",
                        given,
                        used: l.address.clone(),
                        why: "no port given: the SCPI port",
                    });
                }
            }
            LightDriver::Usbtmc => {
                if l.device.as_os_str().is_empty() {
                    return Err(invalid(
                        "lights.device",
                        "driver = \"usbtmc\" needs device = \"/dev/usbtmcN\"",
                    ));
                }
            }
            LightDriver::Gpio => {
                if l.gpio_chip.as_os_str().is_empty() {
                    return Err(invalid(
                        "lights.gpio_chip",
                        "driver = \"gpio\" needs gpio_chip = \"/dev/gpiochipN\"",
                    ));
                }
                if l.ls1_line == l.ls2_line {
                    return Err(invalid(
                        "lights.ls2_line",
                        format!("LS1 and LS2 both on line {}", l.ls1_line),
                    ));
                }
            }
        }
        for serial in self.camera.keys() {
            let mut own = self.for_camera(serial);
            let own_adjusted = own.validate().map_err(|e| in_section(serial, e))?;
            for a in own_adjusted {
                section_adjustment(&mut adjusted, serial, a);
            }
        }
        Ok(adjusted)
    }

    /// `cameras`: the simulator's, within [1, MAX_CAMERAS], each with its
    /// own output (stdout carries one stream).
    fn check_cameras(&self) -> Result<(), Invalid> {
        if self.cameras == 0 || self.cameras > MAX_CAMERAS {
            return Err(invalid(
                "cameras",
                format!("{} is not within [1, {MAX_CAMERAS}]", self.cameras),
            ));
        }
        if self.cameras == 1 {
            return Ok(());
        }
        if self.backend != BackendKind::Sim {
            return Err(invalid(
                "cameras",
                "several cameras come from the simulator (backend = \"sim\"); boards are one camera each",
            ));
        }
        if self.output.y4m_path == "-" {
            return Err(invalid(
                "output.y4m_path",
                "stdout carries one camera's stream; with several cameras leave it out (one FIFO per camera)",
            ));
        }
        Ok(())
    }
}

/// A camera section's adjustment, named by its section.
fn section_adjustment(adjusted: &mut Vec<Adjustment>, serial: &str, a: Adjustment) {
    adjusted.push(Adjustment {
        key: "camera",
        given: format!("[camera.{serial:?}] {} = {}", a.key, a.given),
        used: a.used,
        why: a.why,
    });
}
