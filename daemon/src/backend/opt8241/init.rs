//! Board configuration in the SDK's order, within the laser-safety limits.
//!
//! Order (TI Voxel SDK `ToFTintinCamera::_init`, `TintinCDKCamera::_init`,
//! `ToFCamera::_setFrameRate`, `TintinModulationFrequencyParameter::set`):
//! stop the timing generator; bulk framing without block headers; output
//! handshake; modulation PLL (update strobe around the writes); quads and
//! sub frames; ROI; raw-quad output; frame rate (pix_cnt_max) and then the
//! integration duty cycle again, since it is relative to the frame timing;
//! restart. Every write is read back; values the firmware clamped are
//! reported in [`InitReport::clamps`], never worked around.

use super::frame::QuadLayout;
use super::protocol::{FieldWrite, ProtocolError, RegisterBus, Transport};
use super::registers::{field, safety, Field, SYSTEM_CLOCK_HZ};

/// VCO range of the modulation PLL (OPT9221.dml, mod_m1 description).
pub const VCO_MIN_HZ: f64 = 300e6;
pub const VCO_MAX_HZ: f64 = 600e6;
/// Largest mod_ps1 (3-bit field).
pub const MOD_PS_MAX: u32 = 7;
/// mod_n1 as the SDK sets it (`TintinVCOFrequency::set`).
pub const MOD_N: u32 = 2;

/// Region of interest: columns in steps of 16 (SDK `_allowedROI`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Roi {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

impl Roi {
    pub const FULL: Roi = Roi {
        x: 0,
        y: 0,
        width: 320,
        height: 240,
    };
}

/// What sdid asks of the board.
#[derive(Debug, Clone, PartialEq)]
pub struct BoardConfig {
    /// quad_cnt_max: 4 or 6.
    pub quads: u32,
    /// sub_frame_cnt_max: 1, 2, 4 or 8.
    pub sub_frames: u32,
    /// Modulation (carrier) frequency of f(t). The stock board reaches
    /// down to about 9.4 MHz with 4 quads; lower needs an external generator.
    pub modulation_hz: f64,
    pub frame_rate_hz: f64,
    /// Integration as a fraction of the quad time, percent (0-100; the
    /// firmware caps it at 20/64 = 31 %).
    pub integration_percent: f64,
    pub roi: Roi,
    /// debug_frame_number_en: frame number in the first byte (alignment check).
    pub frame_numbers: bool,
}

impl Default for BoardConfig {
    fn default() -> Self {
        Self {
            quads: 4,
            sub_frames: 1,
            modulation_hz: 12e6,
            frame_rate_hz: 30.0,
            integration_percent: 20.0,
            roi: Roi::FULL,
            frame_numbers: true,
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error(
        "{name} = {} is out of range: expected {allowed}",
        sdi_core::number::Number(*.value)
    )]
    OutOfRange {
        name: &'static str,
        value: f64,
        allowed: String,
    },
    #[error(transparent)]
    Protocol(#[from] ProtocolError),
    #[error("board reports {0} after configuration")]
    StatusFlag(&'static str),
}

fn out_of_range(name: &'static str, value: f64, allowed: impl Into<String>) -> ConfigError {
    ConfigError::OutOfRange {
        name,
        value,
        allowed: allowed.into(),
    }
}

/// Modulation PLL settings: f_mod = VCO / (quads * (1 + ps)),
/// VCO = 2 * f_sys * (m + frac / 2^16) / 2^n (OPT9221.dml; SDK
/// `TintinVCOFrequency`, `TintinModulationFrequencyParameter`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PllSettings {
    pub m: u32,
    pub m_frac: u32,
    pub n: u32,
    pub ps: u32,
    /// What the settings really give.
    pub modulation_hz: f64,
    pub vco_hz: f64,
}

impl PllSettings {
    /// The SDK's choice: the largest prescaler keeping the VCO above its
    /// minimum, then m and its fraction.
    pub fn for_modulation(modulation_hz: f64, quads: u32) -> Result<Self, ConfigError> {
        let q = quads as f64;
        let lowest = VCO_MIN_HZ / (q * (MOD_PS_MAX + 1) as f64);
        let highest = VCO_MAX_HZ / q;
        if !(modulation_hz.is_finite() && modulation_hz >= lowest && modulation_hz <= highest) {
            return Err(out_of_range(
                "modulation_hz",
                modulation_hz,
                format!(
                    "[{:.3} MHz, {:.1} MHz] with {quads} quads (lower needs an external generator wired to the LEDs)",
                    lowest / 1e6,
                    highest / 1e6
                ),
            ));
        }
        let ps = ((VCO_MIN_HZ / q / modulation_hz).floor() as u32).min(MOD_PS_MAX);
        let vco_hz = (ps + 1) as f64 * q * modulation_hz;
        let mf = vco_hz * (1u32 << MOD_N) as f64 / (2.0 * SYSTEM_CLOCK_HZ);
        let m = mf.floor() as u32;
        let m_frac = ((mf - m as f64) * 65536.0).floor() as u32;
        let vco_real =
            2.0 * SYSTEM_CLOCK_HZ * (m as f64 + m_frac as f64 / 65536.0) / (1u32 << MOD_N) as f64;
        Ok(Self {
            m,
            m_frac,
            n: MOD_N,
            ps,
            vco_hz: vco_real,
            modulation_hz: vco_real / (q * (ps + 1) as f64),
        })
    }
}

/// pix_cnt_max for a frame rate: f_sys / (fps * quads * sub frames)
/// (SDK `ToFCamera::_setFrameRate`).
pub fn pix_cnt_max_for(frame_rate_hz: f64, quads: u32, sub_frames: u32) -> u32 {
    (SYSTEM_CLOCK_HZ / (frame_rate_hz * quads as f64 * sub_frames as f64)).floor() as u32
}

/// intg_duty_cycle for an integration percentage: round(p * 64 / 100)
/// (SDK `IntegrationTimeParameter::set`).
pub fn intg_duty_cycle_for(integration_percent: f64) -> u32 {
    (integration_percent * 64.0 / 100.0).round() as u32
}

/// A value the board (or our own limit) changed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Clamp {
    pub field: &'static str,
    pub requested: u32,
    pub actual: u32,
    pub reason: &'static str,
}

/// Everything configuration did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct InitReport {
    pub writes: Vec<FieldWrite>,
    pub clamps: Vec<Clamp>,
    pub pll: Option<PllSettings>,
    pub layout: Option<QuadLayout>,
    pub firmware_version: Option<(u8, u8)>,
}

impl InitReport {
    fn record(&mut self, w: FieldWrite, reason: &'static str) {
        if w.clamped() {
            self.clamps.push(Clamp {
                field: w.field.name,
                requested: w.requested,
                actual: w.actual,
                reason,
            });
        }
        self.writes.push(w);
    }
}

impl BoardConfig {
    /// Rejects NaN, infinities and values the hardware cannot do.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.quads != 4 && self.quads != 6 {
            return Err(out_of_range("quads", self.quads as f64, "4 or 6"));
        }
        if ![1, 2, 4, 8].contains(&self.sub_frames) {
            return Err(out_of_range(
                "sub_frames",
                self.sub_frames as f64,
                "1, 2, 4 or 8",
            ));
        }
        let fr = self.frame_rate_hz;
        if !(fr.is_finite() && fr > 0.0 && fr <= 1000.0) {
            return Err(out_of_range("frame_rate_hz", fr, "(0, 1000] Hz"));
        }
        let ip = self.integration_percent;
        if !(ip.is_finite() && (0.0..=100.0).contains(&ip)) {
            return Err(out_of_range("integration_percent", ip, "[0, 100] %"));
        }
        let r = self.roi;
        let ok = r.width > 0
            && r.height > 0
            && r.x.is_multiple_of(16)
            && r.width.is_multiple_of(16)
            && r.x + r.width <= 320
            && r.y + r.height <= 240;
        if !ok {
            return Err(out_of_range(
                "roi",
                f64::from(r.width),
                "columns multiples of 16 within 320, rows within 240",
            ));
        }
        PllSettings::for_modulation(self.modulation_hz, self.quads)?;
        Ok(())
    }

    pub fn layout(&self) -> QuadLayout {
        QuadLayout {
            width: self.roi.width as usize,
            height: self.roi.height as usize,
            quads: self.quads as usize,
        }
    }
}

/// Runs the init sequence on an opened board.
pub fn configure<T: Transport>(
    bus: &mut RegisterBus<T>,
    config: &BoardConfig,
) -> Result<InitReport, ConfigError> {
    config.validate()?;
    let mut report = InitReport {
        firmware_version: bus.firmware_version().ok(),
        ..Default::default()
    };
    let set = |bus: &mut RegisterBus<T>,
               report: &mut InitReport,
               f: Field,
               v: u32,
               reason: &'static str|
     -> Result<(), ConfigError> {
        let w = bus.write_field(f, v)?;
        report.record(w, reason);
        Ok(())
    };
    const BOARD: &str = "board kept a different value";
    // 1. stop the timing generator while reconfiguring
    set(bus, &mut report, field::TG_DIS, 1, BOARD)?;
    // 2. bulk framing: no UVC block headers, 512-byte blocks (TintinCDKCamera::_init)
    set(bus, &mut report, field::BLK_HEADER_EN, 0, BOARD)?;
    set(bus, &mut report, field::BLK_SIZE, 512, BOARD)?;
    // 3. output handshake as the SDK sets it (ToFTintinCamera::_init)
    set(bus, &mut report, field::OP_CS_POL, 1, BOARD)?;
    set(bus, &mut report, field::FB_READY_EN, 1, BOARD)?;
    // 4. no spread-spectrum clocking: a clean square wave
    set(bus, &mut report, field::SSCG_EN, 0, BOARD)?;
    // 5. quads and sub frames (the PLL divides by quad_cnt_max)
    set(bus, &mut report, field::QUAD_CNT_MAX, config.quads, BOARD)?;
    set(
        bus,
        &mut report,
        field::SUB_FRAME_CNT_MAX,
        config.sub_frames,
        BOARD,
    )?;
    // 6. modulation PLL, inside the update strobe
    let pll = PllSettings::for_modulation(config.modulation_hz, config.quads)?;
    set(bus, &mut report, field::MOD_PLL_UPDATE, 1, BOARD)?;
    set(bus, &mut report, field::MOD_M1, pll.m, BOARD)?;
    set(bus, &mut report, field::MOD_N1, pll.n, BOARD)?;
    set(bus, &mut report, field::MOD_M_FRAC1, pll.m_frac, BOARD)?;
    set(bus, &mut report, field::MOD_PS1, pll.ps, BOARD)?;
    set(bus, &mut report, field::MOD_PLL_UPDATE, 0, BOARD)?;
    report.pll = Some(pll);
    // 7. region of interest, no binning (ToFTintinCamera::_setROI)
    let r = config.roi;
    set(bus, &mut report, field::ROW_START, r.y, BOARD)?;
    set(bus, &mut report, field::ROW_END, r.y + r.height - 1, BOARD)?;
    set(bus, &mut report, field::COL_START, r.x / 16, BOARD)?;
    set(
        bus,
        &mut report,
        field::COL_END,
        (r.x + r.width) / 16 - 1,
        BOARD,
    )?;
    set(bus, &mut report, field::BINNING_EN, 0, BOARD)?;
    set(bus, &mut report, field::BIN_ROW_COUNT, r.height, BOARD)?;
    set(bus, &mut report, field::BIN_COL_COUNT, r.width, BOARD)?;
    // 8. raw quads out, frame numbers in the first byte
    set(bus, &mut report, field::OUTPUT_MODE, 15, BOARD)?;
    set(
        bus,
        &mut report,
        field::DEBUG_FRAME_NUMBER_EN,
        u32::from(config.frame_numbers),
        BOARD,
    )?;
    // 9. frame rate: pix_cnt_max, never below the firmware's minimum
    let mut pix = pix_cnt_max_for(config.frame_rate_hz, config.quads, config.sub_frames);
    if pix < safety::PIX_CNT_MAX_MIN {
        report.clamps.push(Clamp {
            field: field::PIX_CNT_MAX.name,
            requested: pix,
            actual: safety::PIX_CNT_MAX_MIN,
            reason: "laser safety: pix_cnt_max >= 60000 (frame rate lowered)",
        });
        pix = safety::PIX_CNT_MAX_MIN;
    }
    set(
        bus,
        &mut report,
        field::PIX_CNT_MAX,
        pix,
        "laser safety (firmware)",
    )?;
    // 10. integration after the frame rate (the SDK re-sets it there too)
    let mut duty = intg_duty_cycle_for(config.integration_percent);
    if duty > safety::INTG_DUTY_CYCLE_MAX {
        report.clamps.push(Clamp {
            field: field::INTG_DUTY_CYCLE.name,
            requested: duty,
            actual: safety::INTG_DUTY_CYCLE_MAX,
            reason: "laser safety: intg_duty_cycle <= 20",
        });
        duty = safety::INTG_DUTY_CYCLE_MAX;
    }
    set(
        bus,
        &mut report,
        field::INTG_DUTY_CYCLE,
        duty,
        "laser safety (firmware)",
    )?;
    // 11. restart and check the status flags
    set(bus, &mut report, field::TG_DIS, 0, BOARD)?;
    if bus.read_field(field::PIX_CNT_MAX_SET_FAILED)? != 0 {
        return Err(ConfigError::StatusFlag("pix_cnt_max_set_failed"));
    }
    if bus.read_field(field::INTG_DUTY_CYCLE_SET_FAILED)? != 0 {
        return Err(ConfigError::StatusFlag("intg_duty_cycle_set_failed"));
    }
    report.layout = Some(config.layout());
    for c in &report.clamps {
        tracing::warn!(
            field = c.field,
            requested = c.requested,
            actual = c.actual,
            reason = c.reason,
            "board clamp"
        );
    }
    Ok(report)
}

/// Board temperatures and status flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardStatus {
    pub sensor_celsius: i8,
    pub illumination_celsius: i8,
    pub master_pll_locked: bool,
    pub output_overflow: bool,
}

pub fn read_status<T: Transport>(bus: &mut RegisterBus<T>) -> Result<BoardStatus, ProtocolError> {
    let status = bus.read_register(field::MASTER_PLL_LOCK.address)?;
    Ok(BoardStatus {
        sensor_celsius: bus.read_field(field::TSENSOR)? as u8 as i8,
        illumination_celsius: bus.read_field(field::TILLUM)? as u8 as i8,
        master_pll_locked: field::MASTER_PLL_LOCK.extract(status) != 0,
        output_overflow: field::OP_OVERFLOW.extract(status) != 0,
    })
}

#[cfg(test)]
mod tests {
    use super::super::protocol::tests::FakeBoard;
    use super::*;

    #[test]
    fn pll_matches_sdk_formula() {
        // 12 MHz, 4 quads: ps = floor(300/4/12) = 6, VCO = 7*4*12 = 336 MHz,
        // m = 336 * 4 / 96 = 14 exactly.
        let p = PllSettings::for_modulation(12e6, 4).unwrap();
        assert_eq!((p.ps, p.n, p.m, p.m_frac), (6, 2, 14, 0));
        assert!((p.modulation_hz - 12e6).abs() < 1.0);
        for f in [9.5e6, 10e6, 20e6, 48e6, 80e6] {
            let p = PllSettings::for_modulation(f, 4).unwrap();
            assert!(p.vco_hz >= VCO_MIN_HZ - 1e3 && p.vco_hz <= VCO_MAX_HZ + 1e3);
            assert!((p.modulation_hz - f).abs() / f < 1e-4, "{f}: {p:?}");
        }
    }

    #[test]
    fn stock_board_cannot_modulate_at_paper_frequencies() {
        for f in [1e6, 5e6, 9.3e6, f64::NAN, -1.0] {
            let e = PllSettings::for_modulation(f, 4).unwrap_err();
            assert!(e.to_string().contains("external generator"), "{e}");
        }
        assert!(PllSettings::for_modulation(9.375e6, 4).is_ok());
    }

    #[test]
    fn frame_rate_and_integration_formulas() {
        assert_eq!(pix_cnt_max_for(30.0, 4, 1), 400_000);
        assert_eq!(pix_cnt_max_for(60.0, 4, 4), 50_000);
        assert_eq!(intg_duty_cycle_for(20.0), 13);
        assert_eq!(intg_duty_cycle_for(100.0), 64);
    }

    #[test]
    fn configure_writes_the_sdk_sequence_and_reads_back() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        let report = configure(&mut bus, &BoardConfig::default()).unwrap();
        assert!(report.clamps.is_empty(), "{:?}", report.clamps);
        let regs = &bus.transport().registers;
        let get = |f: Field| f.extract(regs.get(&f.address).copied().unwrap_or(0));
        assert_eq!(get(field::TG_DIS), 0);
        assert_eq!(get(field::OUTPUT_MODE), 15);
        assert_eq!(get(field::QUAD_CNT_MAX), 4);
        assert_eq!(get(field::PIX_CNT_MAX), 400_000);
        assert_eq!(get(field::INTG_DUTY_CYCLE), 13);
        assert_eq!(get(field::DEBUG_FRAME_NUMBER_EN), 1);
        assert_eq!(get(field::BLK_SIZE), 512);
        assert_eq!(get(field::COL_END), 19);
        assert_eq!(get(field::ROW_END), 239);
        // first write stops the TG, last write restarts it
        let first = report.writes.first().unwrap();
        let last = report.writes.last().unwrap();
        assert_eq!((first.field.name, first.requested), ("tg_dis", 1));
        assert_eq!((last.field.name, last.requested), ("tg_dis", 0));
        // PLL update strobe surrounds the PLL writes
        let names: Vec<_> = report.writes.iter().map(|w| w.field.name).collect();
        let up = names.iter().position(|n| *n == "mod_pll_update").unwrap();
        assert_eq!(names[up + 1], "mod_m1");
        assert_eq!(names[up + 5], "mod_pll_update");
        // integration comes after the frame rate
        let pix = names.iter().position(|n| *n == "pix_cnt_max").unwrap();
        let intg = names.iter().position(|n| *n == "intg_duty_cycle").unwrap();
        assert!(intg > pix);
    }

    #[test]
    fn unsafe_requests_are_clamped_and_reported() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        let cfg = BoardConfig {
            frame_rate_hz: 400.0,
            integration_percent: 80.0,
            ..BoardConfig::default()
        };
        let report = configure(&mut bus, &cfg).unwrap();
        let fields: Vec<_> = report.clamps.iter().map(|c| c.field).collect();
        assert_eq!(fields, vec!["pix_cnt_max", "intg_duty_cycle"]);
        assert_eq!(report.clamps[1].requested, 51);
        assert_eq!(report.clamps[1].actual, 20);
        let regs = &bus.transport().registers;
        assert_eq!(field::INTG_DUTY_CYCLE.extract(regs[&0x5C4C]), 20);
        assert_eq!(field::PIX_CNT_MAX.extract(regs[&0x5882]), 60_000);
    }

    #[test]
    fn bad_config_is_rejected_before_any_transfer() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        for cfg in [
            BoardConfig {
                quads: 5,
                ..Default::default()
            },
            BoardConfig {
                frame_rate_hz: f64::NAN,
                ..Default::default()
            },
            BoardConfig {
                modulation_hz: 2e6,
                ..Default::default()
            },
            BoardConfig {
                roi: Roi {
                    x: 8,
                    y: 0,
                    width: 64,
                    height: 10,
                },
                ..Default::default()
            },
        ] {
            assert!(matches!(
                configure(&mut bus, &cfg),
                Err(ConfigError::OutOfRange { .. })
            ));
        }
        assert!(bus.transport().log.is_empty());
    }

    #[test]
    fn status_decodes_signed_temperatures() {
        let mut bus = RegisterBus::new(FakeBoard::default());
        bus.transport_mut().registers.insert(0x5C61, 0xF6); // -10 C
        bus.transport_mut().registers.insert(0x5C62, 41);
        bus.transport_mut().registers.insert(0x5C63, 1 << 4);
        let s = read_status(&mut bus).unwrap();
        assert_eq!(s.sensor_celsius, -10);
        assert_eq!(s.illumination_celsius, 41);
        assert!(s.master_pll_locked);
        assert!(!s.output_overflow);
    }
}
