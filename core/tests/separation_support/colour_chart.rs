//! The simulator's colour chart (TI preset, dark frame subtracted as in the
//! paper's section 6), with its ground truth and patch labels.

use sdi_core::calibration::DarkCalibration;
use sdi_core::modulation::Illumination;
use sdi_core::scene::{ColourChart, SceneSpec};
use sdi_core::sensor::{SensorPreset, SkellamMixing};
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

/// Frames of the colour chart, truth in electrons, patch index per pixel.
pub struct ChartRun {
    pub h: SkellamMixing,
    pub width: usize,
    pub height: usize,
    pub frames: Vec<Frame>,
    pub i_plus: Vec<f64>,
    pub i_minus: Vec<f64>,
    /// Patch (0..24) of each pixel, `None` on the surround.
    pub patch: Vec<Option<usize>>,
}

/// `n` dark-subtracted frames of the colour chart.
pub fn colour_chart(n: usize, seed: u64) -> ChartRun {
    let sensor = SensorPreset::TiOpt8241.params();
    let h = sensor.skellam();
    let scene = SceneSpec::from_name("colour-chart").expect("colour-chart scene");
    let mut config = SimConfig::new(sensor.clone(), scene);
    config.seed = seed;
    let mut sim = Simulator::new(config).expect("valid preset");
    let (w, ht) = (sensor.width, sensor.height);
    let mut frame = Frame::new(w, ht);
    let dark = Illumination::dark(sensor.modulation_hz);
    let darks: Vec<Frame> = (0..100)
        .map(|_| {
            sim.capture(&dark, &mut frame);
            frame.clone()
        })
        .collect();
    let cal = DarkCalibration::from_frames(&darks).expect("dark calibration");
    let light = Illumination::snapshot(sensor.modulation_hz);
    let frames = (0..n)
        .map(|_| {
            sim.capture(&light, &mut frame);
            cal.subtract(&mut frame).expect("same size");
            frame.clone()
        })
        .collect();
    let e = sim.last_expectation();
    let chart = ColourChart::new(w, ht, 1.0, 1.0);
    ChartRun {
        h,
        width: w,
        height: ht,
        frames,
        i_plus: e.i_plus_electrons.data.iter().map(|&v| v as f64).collect(),
        i_minus: e.i_minus_electrons.data.iter().map(|&v| v as f64).collect(),
        patch: (0..w * ht).map(|i| chart.patch_at(i % w, i / w)).collect(),
    }
}
