//! Every mode on its own scene: the output is finite and shows the sign
//! structure the paper describes.

use sdi_core::dark_frame::DarkAccumulator;
use sdi_core::mode::{build_pipeline, ModeId, PipelineConfig};
use sdi_core::modulation::Illumination;
use sdi_core::sensor::SensorPreset;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

/// The mean output image of `n` frames of `mode` on its default scene.
fn mean_output(mode: ModeId, n: usize) -> Vec<f32> {
    let scene = mode.default_scene();
    let sensor = SensorPreset::PmdCamBoardNano.params();
    let carrier_hz = sensor.modulation_hz;
    let mut sim = Simulator::new(SimConfig::new(sensor, scene)).unwrap();
    let (w, h) = (sim.params().width, sim.params().height);
    let mut frame = Frame::new(w, h);
    // Measurement procedure (section 4): average a dark frame, subtract it.
    let mut dark = DarkAccumulator::new(w, h);
    for _ in 0..16 {
        sim.capture(&Illumination::dark(carrier_hz), &mut frame);
        dark.push(&frame)
            .expect("simulated frames have the sensor size");
    }
    let mut p = build_pipeline(
        mode,
        PipelineConfig {
            dark_frame_dn: dark.mean_dn(),
            ..Default::default()
        },
    );
    let mut sum = vec![0f32; w * h];
    let (mut got, mut seq) = (0, frame.sequence + 1);
    while got < n {
        sim.capture(&mode.illumination(seq, carrier_hz), &mut frame);
        seq = frame.sequence + 1;
        if let Some(out) = p.process(&frame) {
            assert!(out.signed_dn.data.iter().all(|v| v.is_finite()), "{mode}");
            for (s, &v) in sum.iter_mut().zip(&out.signed_dn.data) {
                *s += v / n as f32;
            }
            got += 1;
        }
    }
    sum
}

/// Fraction of pixels above `t` and below `-t`.
fn sign_fractions(img: &[f32], t: f32) -> (f64, f64) {
    let n = img.len() as f64;
    let pos = img.iter().filter(|&&v| v > t).count() as f64 / n;
    let neg = img.iter().filter(|&&v| v < -t).count() as f64 / n;
    (pos, neg)
}

#[test]
fn bipolar_modes_show_both_signs() {
    // PMD read noise is ~11 DN per frame; 8-frame means have ~4 DN
    // (two-shot: ~6 DN), after dark subtraction.
    for mode in [
        ModeId::BipolarColour,
        ModeId::DepthEdge,
        ModeId::DepthEdgeVertical,
        ModeId::SpatialGradient,
        ModeId::TemporalGradient,
        ModeId::TwoShot,
    ] {
        let img = mean_output(mode, 8);
        let (pos, neg) = sign_fractions(&img, 20.0);
        eprintln!(
            "{mode}: {:.2}% > +20 DN, {:.2}% < -20 DN",
            pos * 100.0,
            neg * 100.0
        );
        assert!(
            pos > 0.001 && neg > 0.001,
            "{mode}: {pos} positive, {neg} negative"
        );
    }
}

#[test]
fn direct_only_is_mostly_positive() {
    let img = mean_output(ModeId::DirectOnly, 8);
    let (pos, neg) = sign_fractions(&img, 20.0);
    eprintln!(
        "direct-only: {:.2}% > +20 DN, {:.2}% < -20 DN",
        pos * 100.0,
        neg * 100.0
    );
    assert!(
        pos > 0.01 && neg < pos * 0.1,
        "{pos} positive, {neg} negative"
    );
}
