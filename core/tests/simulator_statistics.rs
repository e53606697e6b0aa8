//! Statistical tests of the sensor model (section 3, eq. skellamvar;
//! section 5.5, eq. pre_post_noise). Bounds are derived from the sample size:
//! means within 5 standard errors; mean per-pixel variances within 5 standard
//! errors of a chi-square with (frames - 1) degrees of freedom per pixel.
//!
//! The ADC rounds to integer codes, which adds the uniform quantization
//! variance 1/12 DN^2 to every readout (Sheppard's correction).

use sdi_core::modulation::{Illumination, ModulationPattern, SourceDrive};
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::{SensorParams, SensorPreset};
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

const QUANTIZATION_DN2: f64 = 1.0 / 12.0;

fn small_ti() -> SensorParams {
    let mut p = SensorPreset::TiOpt8241.params();
    p.width = 48;
    p.height = 32;
    p.fixed_pattern_sigma_dn = 0.0;
    p
}

fn flat(ls1: f64, ls2: f64) -> SceneSpec {
    SceneSpec::FlatField {
        ls1_electrons_per_us: ls1,
        ls2_electrons_per_us: ls2,
    }
}

fn sim(sensor: SensorParams, scene: SceneSpec, ambient: f64, seed: u64) -> Simulator {
    let mut c = SimConfig::new(sensor, scene);
    c.ambient_electrons_per_us = ambient;
    c.seed = seed;
    Simulator::new(c).unwrap()
}

/// Per-pixel mean and variance over frames (Welford).
struct PixelStats {
    n: usize,
    mean: Vec<f64>,
    m2: Vec<f64>,
}

impl PixelStats {
    fn new(pixels: usize) -> Self {
        Self {
            n: 0,
            mean: vec![0.0; pixels],
            m2: vec![0.0; pixels],
        }
    }

    fn push(&mut self, values: impl Iterator<Item = f64>) {
        self.n += 1;
        let n = self.n as f64;
        for ((m, s), x) in self.mean.iter_mut().zip(&mut self.m2).zip(values) {
            let d = x - *m;
            *m += d / n;
            *s += d * (x - *m);
        }
    }

    /// Grand mean over pixels and frames.
    fn grand_mean(&self) -> f64 {
        self.mean.iter().sum::<f64>() / self.mean.len() as f64
    }

    /// Average over pixels of the per-pixel unbiased variance.
    fn mean_variance(&self) -> f64 {
        self.m2.iter().sum::<f64>() / ((self.n - 1) * self.m2.len()) as f64
    }

    /// Standard error of `grand_mean` for a true variance `var`.
    fn se_mean(&self, var: f64) -> f64 {
        (var / (self.n * self.mean.len()) as f64).sqrt()
    }

    /// Standard error of `mean_variance` for a (near-Gaussian) true variance.
    fn se_variance(&self, var: f64) -> f64 {
        var * (2.0 / ((self.n - 1) * self.mean.len()) as f64).sqrt()
    }
}

fn stats_of(
    sim: &mut Simulator,
    light: &Illumination,
    frames: usize,
    reference: bool,
) -> PixelStats {
    let p = sim.params().clone();
    let mut frame = Frame::new(p.width, p.height);
    let mut st = PixelStats::new(p.width * p.height);
    for _ in 0..frames {
        if reference {
            sim.capture_reference(light, &mut frame);
        } else {
            sim.capture(light, &mut frame);
        }
        st.push(frame.dn.data.iter().map(|&v| v as f64));
    }
    st
}

fn assert_mean_var(st: &PixelStats, mean: f64, var: f64, what: &str) {
    let (m, v) = (st.grand_mean(), st.mean_variance());
    let (sm, sv) = (st.se_mean(var), st.se_variance(var));
    assert!(
        (m - mean).abs() < 5.0 * sm,
        "{what}: mean {m} vs {mean} (se {sm})"
    );
    assert!(
        (v - var).abs() < 5.0 * sv,
        "{what}: variance {v} vs {var} (se {sv})"
    );
}

/// Expected mean and variance of one snapshot readout (eq. skellamvar).
fn predicted(p: &SensorParams, i_plus: f64, i_minus: f64) -> (f64, f64) {
    let (mean, var) = p.skellam().forward(i_plus, i_minus);
    (mean, var + QUANTIZATION_DN2)
}

#[test]
fn flat_field_mean_and_variance_follow_skellam_model() {
    // (label, sensor, LS1 rate, LS2 rate): bright (moment-matched path), dim
    // (exact per-well path), coarse gain (exact path, lattice visible), PMD.
    let mut coarse = small_ti();
    coarse.conversion_gain_dn_per_electron = 2.0;
    coarse.demodulation_contrast = 0.5;
    coarse.read_noise_electrons = 1.5;
    let mut pmd = SensorPreset::PmdCamBoardNano.params();
    pmd.width = 40;
    pmd.height = 30;
    pmd.fixed_pattern_sigma_dn = 0.0;
    let cases = [
        ("bright", small_ti(), 4.0, 2.0),
        ("dim", small_ti(), 0.02, 0.01),
        ("coarse", coarse, 0.004, 0.002),
        ("pmd", pmd, 3.0, 1.0),
    ];
    for (label, sensor, ls1, ls2) in cases {
        let half_exposure = 0.5 * sensor.exposure_us;
        let (ip, im) = (ls1 * half_exposure, ls2 * half_exposure);
        let (mean, var) = predicted(&sensor, ip, im);
        for reference in [false, true] {
            let mut s = sim(sensor.clone(), flat(ls1, ls2), 0.0, 11);
            let light = Illumination::snapshot(sensor.modulation_hz);
            let st = stats_of(&mut s, &light, 120, reference);
            assert_mean_var(&st, mean, var, &format!("{label} reference={reference}"));
            let exp = s.last_expectation();
            assert!((exp.i_plus_electrons.data[0] as f64 - ip).abs() < 1e-3 * ip.max(1.0));
            assert!((exp.i_minus_electrons.data[0] as f64 - im).abs() < 1e-3 * im.max(1.0));
        }
    }
}

/// Section 5.5: at low light the two-shot (post-ADC) difference reads noise
/// twice, the snapshot once: variance ratio -> 2 (paper: 1.97 PMD,
/// 1.99 +- 0.37 TI).
#[test]
fn two_shot_variance_is_twice_snapshot_at_low_light() {
    for preset in <SensorPreset as strum::IntoEnumIterator>::iter() {
        let mut sensor = preset.params();
        sensor.width = 48;
        sensor.height = 32;
        // The fixed pattern stays on: per-pixel variance over frames and the
        // two-shot subtraction both remove it.
        let scene = flat(0.001, 0.001);
        let hz = sensor.modulation_hz;
        let snapshot = Illumination::snapshot(hz);
        let ls1_only = Illumination {
            ls2: SourceDrive::Off,
            ..Illumination::snapshot(hz)
        };
        let ls2_only = Illumination {
            ls1: SourceDrive::Off,
            ..Illumination::snapshot(hz)
        };
        let frames = 150;
        let mut s = sim(sensor.clone(), scene.clone(), 0.0, 5);
        let snap = stats_of(&mut s, &snapshot, frames, false);
        let mut s = sim(sensor.clone(), scene, 0.0, 6);
        let (w, h) = (sensor.width, sensor.height);
        let (mut a, mut b) = (Frame::new(w, h), Frame::new(w, h));
        let mut two = PixelStats::new(w * h);
        for _ in 0..frames {
            s.capture(&ls1_only, &mut a);
            s.capture(&ls2_only, &mut b);
            two.push(
                a.dn.data
                    .iter()
                    .zip(&b.dn.data)
                    .map(|(x, y)| (x - y) as f64),
            );
        }
        let ip = 0.001 * 0.5 * sensor.exposure_us;
        let (_, v_snap) = predicted(&sensor, ip, ip);
        let g2 = sensor.gain_dn_per_electron().powi(2);
        let v_two = g2 * 2.0 * ip + 2.0 * (sensor.read_variance_dn2() + QUANTIZATION_DN2);
        let ratio = two.mean_variance() / snap.mean_variance();
        let expected = v_two / v_snap;
        // Relative standard errors add in quadrature for a ratio.
        let rel = ((snap.se_variance(v_snap) / v_snap).powi(2)
            + (two.se_variance(v_two) / v_two).powi(2))
        .sqrt();
        assert!(
            (ratio - expected).abs() < 5.0 * rel * expected,
            "{}: ratio {ratio}, expected {expected}",
            preset.name()
        );
        assert!(
            (ratio - 2.0).abs() < 0.15,
            "{}: ratio {ratio}",
            preset.name()
        );
        // Within the paper's TI measurement, 1.99 +- 0.37.
        assert!((ratio - 1.99).abs() < 0.37);
    }
}

#[test]
fn ambient_cancels_in_the_mean_and_adds_shot_noise() {
    let sensor = small_ti();
    let light = Illumination::snapshot(sensor.modulation_hz);
    let ambient = 5.0;
    let half = 0.5 * sensor.exposure_us;
    let (ip, im) = (4.0 * half, 2.0 * half);
    let mut s = sim(sensor.clone(), flat(4.0, 2.0), ambient, 21);
    let st = stats_of(&mut s, &light, 120, false);
    let (mean, var) = predicted(&sensor, ip + ambient * half, im + ambient * half);
    let (mean0, var0) = predicted(&sensor, ip, im);
    assert!(
        (mean - mean0).abs() < 1e-9,
        "ambient must cancel in the model"
    );
    assert_mean_var(&st, mean, var, "with ambient");
    assert!(st.mean_variance() > var0 + 10.0 * st.se_variance(var));
}

#[test]
fn dark_frames_hold_fixed_pattern_read_noise_and_ambient_shot_noise() {
    let mut sensor = small_ti();
    sensor.fixed_pattern_sigma_dn = 4.0;
    for ambient in [0.0, 3.0] {
        let mut s = sim(sensor.clone(), flat(4.0, 2.0), ambient, 8);
        let frames = 100;
        let mut frame = Frame::new(sensor.width, sensor.height);
        let mut st = PixelStats::new(sensor.width * sensor.height);
        for _ in 0..frames {
            s.capture_dark(&mut frame);
            assert_eq!(frame.saturated_count(), 0);
            st.push(frame.dn.data.iter().map(|&v| v as f64));
        }
        let a = ambient * 0.5 * sensor.exposure_us;
        let (_, var) = predicted(&sensor, a, a);
        // Per pixel the dark mean is the fixed pattern.
        let se = (var / frames as f64).sqrt();
        let fpn = s.fixed_pattern_dn();
        let worst = st
            .mean
            .iter()
            .zip(&fpn.data)
            .map(|(m, &f)| (m - f as f64).abs() / se)
            .fold(0.0, f64::max);
        // 1536 pixels: the largest of |N(0,1)| stays below 5 with p > 0.999.
        assert!(worst < 5.0, "ambient {ambient}: worst {worst} se");
        let v = st.mean_variance();
        assert!((v - var).abs() < 5.0 * st.se_variance(var), "{v} vs {var}");
    }
}

#[test]
fn saturation_clips_and_is_flagged() {
    let sensor = small_ti();
    let light = Illumination::snapshot(sensor.modulation_hz);
    let (lo, hi) = sensor.adc_range_dn();
    let mut frame = Frame::new(sensor.width, sensor.height);
    // 1e7 electrons in I+: the well clips at full well; the difference then
    // exceeds the ADC range, which clips too.
    let rate = 1e7 / (0.5 * sensor.exposure_us);
    let mut s = sim(sensor.clone(), flat(rate, 0.0), 0.0, 1);
    s.capture(&light, &mut frame);
    assert_eq!(frame.saturated_count(), frame.dn.len());
    assert!(frame.dn.data.iter().all(|&v| v as f64 == hi));
    let mut s = sim(sensor.clone(), flat(0.0, rate), 0.0, 1);
    s.capture(&light, &mut frame);
    assert_eq!(frame.saturated_count(), frame.dn.len());
    assert!(frame.dn.data.iter().all(|&v| v as f64 == lo));
    // Both wells full: they cancel (two saturated wells subtract to ~0) but
    // every pixel is still flagged.
    let mut s = sim(sensor.clone(), flat(rate, rate), 0.0, 1);
    s.capture(&light, &mut frame);
    assert_eq!(frame.saturated_count(), frame.dn.len());
    let read_sd = sensor.read_variance_dn2().sqrt();
    assert!(frame
        .dn
        .data
        .iter()
        .all(|&v| (v as f64).abs() < 6.0 * read_sd));
    // Well below full well nothing is flagged; above it, everything.
    let fw = sensor.full_well_electrons;
    let per_us = |e: f64| e / (0.5 * sensor.exposure_us);
    let mut s = sim(
        sensor.clone(),
        flat(per_us(0.9 * fw), per_us(0.9 * fw)),
        0.0,
        2,
    );
    s.capture(&light, &mut frame);
    assert_eq!(frame.saturated_count(), 0);
    let mut s = sim(
        sensor.clone(),
        flat(per_us(1.1 * fw), per_us(0.9 * fw)),
        0.0,
        2,
    );
    s.capture(&light, &mut frame);
    assert_eq!(frame.saturated_count(), frame.dn.len());
}

#[test]
fn adc_offset_shifts_the_code_range_and_is_removed_from_frames() {
    let mut sensor = small_ti();
    sensor.adc_offset_dn = 1000.0;
    let light = Illumination::snapshot(sensor.modulation_hz);
    let mut s = sim(sensor.clone(), flat(4.0, 2.0), 0.0, 3);
    let st = stats_of(&mut s, &light, 60, false);
    let half = 0.5 * sensor.exposure_us;
    let (mean, var) = predicted(&sensor, 4.0 * half, 2.0 * half);
    assert_mean_var(&st, mean, var, "offset 1000");
    // Codes now top out 1000 DN earlier: a +1500 DN difference clips.
    let (_, hi) = sensor.adc_range_dn();
    let rate = 1500.0 / sensor.gain_dn_per_electron() / half;
    let mut s = sim(sensor.clone(), flat(rate, 0.0), 0.0, 3);
    let mut frame = Frame::new(sensor.width, sensor.height);
    s.capture(&light, &mut frame);
    assert_eq!(frame.saturated_count(), frame.dn.len());
    assert!(frame.dn.data.iter().all(|&v| v as f64 == hi - 1000.0));
}

#[test]
fn extremes_stay_finite() {
    // Zero photons: read noise only, mean zero.
    let sensor = small_ti();
    let light = Illumination::snapshot(sensor.modulation_hz);
    let mut s = sim(sensor.clone(), flat(0.0, 0.0), 0.0, 4);
    let st = stats_of(&mut s, &light, 80, false);
    let (mean, var) = predicted(&sensor, 0.0, 0.0);
    assert_mean_var(&st, mean, var, "zero photons");
    // Tiny eta: the difference vanishes, read noise remains.
    let mut tiny = small_ti();
    tiny.demodulation_contrast = 1e-9;
    let mut s = sim(tiny.clone(), flat(4.0, 0.0), 0.0, 4);
    let st = stats_of(&mut s, &light, 80, false);
    let (mean, var) = predicted(&tiny, 4000.0, 0.0);
    assert_mean_var(&st, mean, var, "tiny eta");
    // No read noise, no light: exactly zero.
    let mut quiet = small_ti();
    quiet.read_noise_electrons = 0.0;
    let mut s = sim(quiet.clone(), flat(0.0, 0.0), 0.0, 4);
    let mut frame = Frame::new(quiet.width, quiet.height);
    s.capture(&light, &mut frame);
    assert!(frame.dn.data.iter().all(|&v| v == 0.0));
}

#[test]
fn invalid_configurations_are_rejected() {
    let sensor = small_ti();
    for ambient in [f64::NAN, -1.0, f64::INFINITY] {
        let mut c = SimConfig::new(sensor.clone(), flat(1.0, 1.0));
        c.ambient_electrons_per_us = ambient;
        let err = Simulator::new(c).err().unwrap();
        assert_eq!(err.name, "ambient_electrons_per_us");
    }
    let mut bad = sensor.clone();
    bad.demodulation_contrast = 0.0;
    assert!(Simulator::new(SimConfig::new(bad, flat(1.0, 1.0))).is_err());
    let mut bad = sensor.clone();
    bad.conversion_gain_dn_per_electron = f64::NAN;
    assert!(Simulator::new(SimConfig::new(bad, flat(1.0, 1.0))).is_err());
    assert!(Simulator::new(SimConfig::new(sensor.clone(), flat(f64::NAN, 1.0))).is_err());
    let mut c = SimConfig::new(sensor, flat(1.0, 1.0));
    c.substeps = 0;
    assert!(Simulator::new(c).is_err());
}

#[test]
fn runs_are_deterministic_given_the_seed() {
    let mut sensor = small_ti();
    sensor.fixed_pattern_sigma_dn = 4.0;
    let light = Illumination {
        modulation: ModulationPattern::single_transition(0.5),
        ls1: SourceDrive::Off,
        ls2: SourceDrive::Off,
    };
    let run = |seed| {
        let scene = SceneSpec::from_name("fan-pellets").unwrap();
        let mut s = sim(sensor.clone(), scene, 0.0, seed);
        let mut f = Frame::new(sensor.width, sensor.height);
        (0..3)
            .map(|_| {
                s.capture(&light, &mut f);
                f.clone()
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(run(9), run(9));
    assert_ne!(run(9), run(10));
}

/// The bright-pixel path matches the Skellam's skewness too (first
/// Cornish-Fisher term): I- = 0, I+ = 150 electrons just above the
/// threshold, no read noise. Sample skewness has standard error sqrt(6/n).
#[test]
fn bright_path_reproduces_poisson_skewness() {
    let mut sensor = small_ti();
    sensor.read_noise_electrons = 0.0;
    sensor.conversion_gain_dn_per_electron = 0.5;
    sensor.demodulation_contrast = 0.5;
    let g = sensor.gain_dn_per_electron();
    let lambda = 150.0;
    let rate = lambda / (0.5 * sensor.exposure_us);
    let mut s = sim(sensor.clone(), flat(rate, 0.0), 0.0, 12);
    let light = Illumination::snapshot(sensor.modulation_hz);
    let mut frame = Frame::new(sensor.width, sensor.height);
    let mut xs = Vec::new();
    for _ in 0..200 {
        s.capture(&light, &mut frame);
        xs.extend(frame.dn.data.iter().map(|&v| v as f64));
    }
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let m2 = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    let m3 = xs.iter().map(|x| (x - mean).powi(3)).sum::<f64>() / n;
    let skew = m3 / m2.powf(1.5);
    let var = g * g * lambda + QUANTIZATION_DN2;
    let expected = g.powi(3) * lambda / var.powf(1.5);
    assert!(
        (skew - expected).abs() < 5.0 * (6.0 / n).sqrt(),
        "skewness {skew} vs {expected}"
    );
}
