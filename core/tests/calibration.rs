//! Calibration against the simulator: dark frame / fixed pattern, the
//! photon-transfer fit of rho*eta and sigma_read^2, and the TOML store.

use sdi_core::calibration::{
    fit_photon_transfer, CalibrationError, CalibrationRecord, CalibrationStore, DarkCalibration,
    PtcPoint,
};
use sdi_core::modulation::{Illumination, SourceDrive};
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::SensorPreset;
use sdi_core::separation::Welford;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

fn small_ti() -> sdi_core::sensor::SensorParams {
    let mut p = SensorPreset::TiOpt8241.params();
    p.width = 32;
    p.height = 24;
    p
}

fn sim(rate: f64, seed: u64) -> Simulator {
    let scene = SceneSpec::FlatField {
        ls1_electrons_per_us: rate,
        ls2_electrons_per_us: 0.0,
    };
    let mut c = SimConfig::new(small_ti(), scene);
    c.seed = seed;
    Simulator::new(c).unwrap()
}

#[test]
fn dark_frame_recovers_fixed_pattern_and_read_noise() {
    let p = small_ti();
    let mut s = sim(0.0, 1);
    let dark = Illumination::dark(p.modulation_hz);
    let frames: Vec<Frame> = (0..200)
        .map(|_| {
            let mut f = Frame::new(p.width, p.height);
            s.capture(&dark, &mut f);
            f
        })
        .collect();
    let cal = DarkCalibration::from_frames(&frames).unwrap();
    // Quantization adds 1/12 DN^2 to the read variance.
    let want = p.read_variance_dn2() + 1.0 / 12.0;
    assert!(
        (cal.read_variance_dn2 - want).abs() < 4.0 * cal.read_variance_se_dn2 + 0.3,
        "{} vs {want}",
        cal.read_variance_dn2
    );
    assert!(
        (cal.fixed_pattern_sigma_dn - p.fixed_pattern_sigma_dn).abs() < 0.6,
        "{}",
        cal.fixed_pattern_sigma_dn
    );
    let mut f = frames[0].clone();
    cal.subtract(&mut f).unwrap();
    let m = f.dn.data.iter().map(|&v| v as f64).sum::<f64>() / f.dn.len() as f64;
    assert!(m.abs() < 1.0);
    assert!(matches!(
        DarkCalibration::from_frames(&frames[..1]),
        Err(CalibrationError::TooFew { .. })
    ));
    assert!(cal.subtract(&mut Frame::new(3, 3)).is_err());
}

#[test]
fn photon_transfer_fit_recovers_gain_and_read_noise() {
    let p = small_ti();
    let illum = Illumination {
        ls2: SourceDrive::Off,
        ..Illumination::snapshot(p.modulation_hz)
    };
    let mut points = Vec::new();
    for (k, rate) in [0.5, 2.0, 5.0, 10.0, 16.0].into_iter().enumerate() {
        let mut s = sim(rate, 10 + k as u64);
        let mut acc = Welford::new(p.width, p.height);
        let mut f = Frame::new(p.width, p.height);
        for _ in 0..200 {
            s.capture(&illum, &mut f);
            acc.push(&f).unwrap();
        }
        points.push(PtcPoint::from_moments(&acc.moments().unwrap()).unwrap());
    }
    let fit = fit_photon_transfer(&points).unwrap();
    let g = p.gain_dn_per_electron();
    let r = p.read_variance_dn2() + 1.0 / 12.0;
    eprintln!(
        "PTC: g = {:.5} +- {:.5} (true {g:.5}), read = {:.2} +- {:.2} DN^2 (true {r:.2}), chi2/dof {:.2}",
        fit.gain_dn_per_electron, fit.gain_se, fit.read_variance_dn2, fit.read_variance_se_dn2, fit.reduced_chi2
    );
    assert!((fit.gain_dn_per_electron - g).abs() < 4.0 * fit.gain_se.max(1e-4));
    assert!((fit.gain_dn_per_electron / g - 1.0).abs() < 0.03);
    assert!((fit.read_variance_dn2 - r).abs() < 4.0 * fit.read_variance_se_dn2.max(0.1));

    // Stored and loaded as H.
    let rec = CalibrationRecord::from_fit(&p.model, "SN-0001", &fit, 4.0, 200);
    let mut store = CalibrationStore::default();
    store.upsert(rec.clone());
    store.upsert(rec.clone());
    assert_eq!(store.sensors.len(), 1);
    let text = store.to_toml().unwrap();
    assert!(text.contains("[[sensor]]") && text.contains("SN-0001"));
    let back = CalibrationStore::from_toml(&text).unwrap();
    assert_eq!(back, store);
    let h = back.skellam(&p.model, "SN-0001").unwrap();
    assert_eq!(h.gain_dn_per_electron, fit.gain_dn_per_electron);
    assert!(back.skellam(&p.model, "other").is_err());
    assert!(CalibrationStore::from_toml("sensor = 3").is_err());
}

#[test]
fn photon_transfer_rejects_bad_input() {
    let pt = |m: f64, v: f64| PtcPoint {
        mean_dn: m,
        variance_dn2: v,
        variance_se_dn2: 1.0,
    };
    assert!(matches!(
        fit_photon_transfer(&[pt(1.0, 2.0), pt(2.0, 3.0)]),
        Err(CalibrationError::TooFew { .. })
    ));
    assert_eq!(
        fit_photon_transfer(&[pt(5.0, 2.0), pt(5.0, 3.0), pt(5.0, 4.0)]),
        Err(CalibrationError::Degenerate)
    );
    assert!(matches!(
        fit_photon_transfer(&[pt(1.0, f64::NAN), pt(2.0, 3.0), pt(3.0, 4.0)]),
        Err(CalibrationError::NonFinite(_))
    ));
}
