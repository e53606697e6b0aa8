//! The two-shot baseline: pairing, and the noise cost measured against the
//! snapshot on the simulator (section 5.5: variance ratio ~2 at low light).

use sdi_core::mode::{build_pipeline, ModeId, Pipeline, PipelineConfig};
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::SensorPreset;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

fn frame(seq: u64, v: f32) -> Frame {
    let mut f = Frame::new(2, 1);
    f.dn.data.fill(v);
    f.sequence = seq;
    f.timestamp_us = seq * 100;
    f
}

#[test]
fn pairs_even_then_odd_and_outputs_a_minus_b() {
    let mut p = build_pipeline(ModeId::TwoShot, PipelineConfig::default());
    assert!(p.process(&frame(4, 10.0)).is_none());
    let out = p.process(&frame(5, 3.0)).unwrap();
    assert_eq!(out.signed_dn.data, vec![7.0, 7.0]);
    assert_eq!((out.sequence, out.timestamp_us), (5, 400));
}

#[test]
fn unpaired_frames_are_dropped_not_mispaired() {
    let mut p = build_pipeline(ModeId::TwoShot, PipelineConfig::default());
    // Starts on an odd frame: nothing to pair with.
    assert!(p.process(&frame(1, 1.0)).is_none());
    // Frame 3 is missing: 2 must not pair with 5.
    assert!(p.process(&frame(2, 1.0)).is_none());
    assert!(p.process(&frame(5, 1.0)).is_none());
    assert!(p.process(&frame(6, 9.0)).is_none());
    assert_eq!(p.process(&frame(7, 4.0)).unwrap().signed_dn.data[0], 5.0);
    // reset forgets a held A frame.
    assert!(p.process(&frame(8, 9.0)).is_none());
    p.reset();
    assert!(p.process(&frame(9, 4.0)).is_none());
}

#[test]
fn saturation_of_either_frame_is_flagged() {
    let mut p = build_pipeline(ModeId::TwoShot, PipelineConfig::default());
    let mut a = frame(0, 1.0);
    a.saturated.data[0] = 1;
    let mut b = frame(1, 1.0);
    b.saturated.data[1] = 1;
    p.process(&a);
    assert_eq!(p.process(&b).unwrap().flags.data, vec![1, 1]);
}

/// Per-pixel variance over `n` outputs, averaged over pixels; and the mean.
fn run_stats(mode: ModeId, rate_e_per_us: f64, n: usize, seed: u64) -> (f64, f64) {
    let sensor = SensorPreset::TiOpt8241.params();
    let carrier_hz = sensor.modulation_hz;
    let scene = SceneSpec::FlatField {
        ls1_electrons_per_us: rate_e_per_us,
        ls2_electrons_per_us: rate_e_per_us * 0.5,
    };
    let mut config = SimConfig::new(sensor, scene);
    config.seed = seed;
    let mut sim = Simulator::new(config).unwrap();
    let mut p: Box<dyn Pipeline> = build_pipeline(mode, PipelineConfig::default());
    let mut frame = Frame::new(320, 240);
    let px = 320 * 240;
    let (mut sum, mut sum2) = (vec![0f64; px], vec![0f64; px]);
    let mut got = 0;
    let mut seq = 0;
    while got < n {
        sim.capture(&mode.illumination(seq, carrier_hz), &mut frame);
        seq = frame.sequence + 1;
        if let Some(out) = p.process(&frame) {
            for ((s, s2), &v) in sum.iter_mut().zip(&mut sum2).zip(&out.signed_dn.data) {
                *s += f64::from(v);
                *s2 += f64::from(v) * f64::from(v);
            }
            got += 1;
        }
    }
    let nf = n as f64;
    let var: f64 = sum
        .iter()
        .zip(&sum2)
        .map(|(&s, &s2)| (s2 - s * s / nf) / (nf - 1.0))
        .sum::<f64>()
        / px as f64;
    // Fixed pattern differs per pixel; the mean of means carries it only as a
    // zero-mean spatial average (std 4 DN / sqrt(76800)).
    let mean = sum.iter().sum::<f64>() / (nf * px as f64);
    (mean, var)
}

#[test]
fn low_light_two_shot_variance_is_twice_the_snapshot() {
    // ~10 electrons per well: read noise (15.05 DN^2) dominates.
    let (m1, v1) = run_stats(ModeId::Raw, 0.01, 24, 1);
    let (m2, v2) = run_stats(ModeId::TwoShot, 0.01, 24, 2);
    let ratio = v2 / v1;
    eprintln!("two-shot / snapshot variance at low light: {v2:.2} / {v1:.2} = {ratio:.3}");
    // 76800 pixels x 23 dof: the ratio's standard error is < 0.01.
    assert!((1.9..2.1).contains(&ratio), "ratio {ratio} ({v2} / {v1})");
    // Same signal: g (I+ - I-) = 0.052 * 5 electrons.
    assert!((m1 - m2).abs() < 0.1, "means {m1} vs {m2}");
}

#[test]
fn two_shot_mean_matches_snapshot_mean_at_high_light() {
    let g = SensorPreset::TiOpt8241.params().gain_dn_per_electron();
    // I+ = 4 * 1000, I- = 2 * 1000 electrons.
    let expected = g * (4000.0 - 2000.0);
    let (m1, _) = run_stats(ModeId::Raw, 4.0, 8, 3);
    let (m2, _) = run_stats(ModeId::TwoShot, 4.0, 8, 4);
    assert!((m1 - expected).abs() < 0.5, "{m1} vs {expected}");
    assert!((m2 - expected).abs() < 0.5, "{m2} vs {expected}");
}
