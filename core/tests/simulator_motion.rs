//! Moving scenes: the closed-form time integration of the fan (and the
//! sampled pellets) against the sub-stepped render it replaced and against a
//! finely sub-stepped reference.

use sdi_core::modulation::{Illumination, ModulationPattern, SourceDrive};
use sdi_core::scene::{FanPellets, FanPelletsParams, Radiance, Scene, SceneSpec};
use sdi_core::sensor::SensorPreset;
use sdi_core::simulator::{SimConfig, Simulator};

const PARAMS: FanPelletsParams = FanPelletsParams {
    background_electrons_per_us: 1.0,
    object_electrons_per_us: 12.0,
    fan_rpm: 1500.0,
    pellets: 12,
};

/// Mean of `n` point renders at the midpoints of n equal steps.
fn sampled_mean(scene: &FanPellets, t0: f64, t1: f64, n: usize) -> Vec<f32> {
    let mut r = Radiance::default();
    let mut sum = vec![0f64; scene.width() * scene.height()];
    for k in 0..n {
        scene.render(t0 + (k as f64 + 0.5) / n as f64 * (t1 - t0), &mut r);
        let a = r.ambient.as_ref().expect("ambient");
        sum.iter_mut()
            .zip(&a.data)
            .for_each(|(s, &v)| *s += v as f64);
    }
    sum.iter().map(|s| (s / n as f64) as f32).collect()
}

fn closed_form(scene: &mut FanPellets, t0: f64, t1: f64, samples: usize) -> Vec<f32> {
    let mut r = Radiance::default();
    assert!(scene.render_mean(t0, t1, samples, &mut r));
    r.ambient.expect("ambient").data
}

/// (max, mean) of |a - b| in units of the object-background contrast.
fn diff(a: &[f32], b: &[f32]) -> (f64, f64) {
    let c = (PARAMS.object_electrons_per_us - PARAMS.background_electrons_per_us) as f64;
    let d: Vec<f64> = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() as f64 / c)
        .collect();
    let max = d.iter().cloned().fold(0.0, f64::max);
    (max, d.iter().sum::<f64>() / d.len() as f64)
}

/// The fan's closed form is exact: against the mean of 2048 renders (the
/// pellets and hub edge sampled as finely), within 1e-3 of the contrast per
/// pixel. With the simulator's sample counts (8 per half exposure, 16 per
/// exposure) it differs from the previous sub-stepped render (which has its
/// own midpoint error) by at most 5% of the contrast at any pixel, 2e-3 on
/// average, and is never further from the fine reference than that render.
#[test]
fn closed_form_fan_matches_fine_substeps_and_the_old_render() {
    let (w, h) = (320, 240);
    let mut scene = FanPellets::new(w, h, PARAMS, 3);
    for t0 in [0.0, 16_667.0, 123_456.0, 1.0e6] {
        for (len_us, samples) in [(1000.0, 8), (2000.0, 16)] {
            let t1 = t0 + len_us;
            let fine = sampled_mean(&scene, t0, t1, 2048);
            let old = sampled_mean(&scene, t0, t1, samples);
            let exact = closed_form(&mut scene, t0, t1, 2048);
            let fast = closed_form(&mut scene, t0, t1, samples);
            let (exact_max, _) = diff(&exact, &fine);
            let (old_max, old_mean) = diff(&old, &fine);
            let (fast_max, fast_mean) = diff(&fast, &fine);
            let (change_max, change_mean) = diff(&fast, &old);
            let at = format!("t0 {t0} us, {len_us} us");
            assert!(exact_max < 1e-3, "{at}: closed form vs fine {exact_max}");
            assert!(change_max < 0.05, "{at}: vs old render {change_max}");
            assert!(change_mean < 2e-3, "{at}: vs old render {change_mean}");
            assert!(fast_max <= old_max && fast_mean <= old_mean, "{at}");
        }
    }
}

/// A fan standing still: the closed form degenerates to one render.
#[test]
fn still_fan_renders_as_one_instant() {
    let params = FanPelletsParams {
        fan_rpm: 0.0,
        pellets: 0,
        ..PARAMS
    };
    let mut scene = FanPellets::new(160, 120, params, 5);
    let still = sampled_mean(&scene, 500.0, 2500.0, 1);
    let mean = closed_form(&mut scene, 500.0, 2500.0, 16);
    assert!(diff(&mean, &still).0 < 1e-5);
}

/// The simulator's expected wells: closed form against the previous 16
/// sub-steps, under the temporal-gradient pattern and the snapshot square
/// wave. Per pixel within 5% of the electrons a full-contrast edge brings in
/// the exposure; in total within 0.1%.
#[test]
fn expected_wells_match_the_substepped_integration() {
    let mut sensor = SensorPreset::TiOpt8241.params();
    (sensor.width, sensor.height) = (320, 240);
    let spec = SceneSpec::from_name("fan-pellets").expect("scene");
    let contrast_e = (PARAMS.object_electrons_per_us - PARAMS.background_electrons_per_us) as f64
        * sensor.exposure_us;
    let lights = [
        Illumination {
            modulation: ModulationPattern::single_transition(0.5),
            ls1: SourceDrive::Off,
            ls2: SourceDrive::Off,
        },
        Illumination::snapshot(sensor.modulation_hz),
    ];
    for light in lights {
        let mut sim = Simulator::new(SimConfig::new(sensor.clone(), spec.clone())).expect("sim");
        for t0 in [0.0, 250_000.0, 777_777.0] {
            sim.expect_wells(&light, t0);
            let fast = sim.last_expectation().clone();
            sim.expect_wells_substepped(&light, t0);
            let old = sim.last_expectation().clone();
            for (a, b) in [
                (&fast.i_plus_electrons, &old.i_plus_electrons),
                (&fast.i_minus_electrons, &old.i_minus_electrons),
            ] {
                let max = a
                    .data
                    .iter()
                    .zip(&b.data)
                    .map(|(x, y)| (x - y).abs() as f64)
                    .fold(0.0, f64::max);
                let (sa, sb): (f64, f64) = (
                    a.data.iter().map(|&v| v as f64).sum(),
                    b.data.iter().map(|&v| v as f64).sum(),
                );
                assert!(max < 0.05 * contrast_e, "t0 {t0}: max {max} e");
                assert!((sa - sb).abs() < 1e-3 * sb, "t0 {t0}: totals {sa} {sb}");
            }
        }
    }
}
