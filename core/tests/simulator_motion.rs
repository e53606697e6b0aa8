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

#[test]
fn closed_form_fan_matches_fine_substeps() {
    let (w, h) = (320, 240);
    let mut scene = FanPellets::new(w, h, PARAMS, 3);
    for t0 in [0.0, 16_667.0, 123_456.0, 1.0e6] {
        for len in [1000.0, 2000.0] {
            let t1 = t0 + len;
            let fine = sampled_mean(&scene, t0, t1, 2048);
            let old = sampled_mean(&scene, t0, t1, (len / 2000.0 * 16.0) as usize);
            // Pellets and the hub edge are sampled finely here too, so the
            // difference to `fine` is the fan's closed form alone.
            let exact = closed_form(&mut scene, t0, t1, 2048);
            let fast = closed_form(&mut scene, t0, t1, (len / 2000.0 * 16.0) as usize);
            let (e_max, e_mean) = diff(&exact, &fine);
            let (o_max, o_mean) = diff(&old, &fine);
            let (f_max, f_mean) = diff(&fast, &fine);
            let (fo_max, fo_mean) = diff(&fast, &old);
            println!("t0 {t0} len {len}: closed-vs-fine max {e_max:.4} mean {e_mean:.2e} | old-vs-fine max {o_max:.4} mean {o_mean:.2e} | fast-vs-fine max {f_max:.4} mean {f_mean:.2e} | fast-vs-old max {fo_max:.4} mean {fo_mean:.2e}");
        }
    }
}
