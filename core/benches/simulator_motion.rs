//! Side-by-side benchmark, one run, one core: the simulator on the moving
//! scene (fan and pellets, temporal-gradient pattern) with the closed-form
//! motion integration, against the previous 16-sub-step render
//! (`capture_substepped`) and a numpy simulation of the same scene; the
//! static colour chart for scale. Also prints how far the closed-form
//! expected wells are from the sub-stepped ones.
//!
//! `cargo bench -p sdi-core --bench simulator_motion` (the numpy column
//! needs /usr/bin/python3 with numpy). Times are the thread's CPU time
//! (CLOCK_THREAD_CPUTIME_ID).

mod support;

use sdi_core::modulation::{Illumination, ModulationPattern, SourceDrive};
use sdi_core::scene::SceneSpec;
use sdi_core::sensor::SensorPreset;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;
use support::{python, time_ms};

const REPS: usize = 60;

fn simulator(scene: &str, width: usize, height: usize) -> Option<Simulator> {
    let mut sensor = SensorPreset::TiOpt8241.params();
    (sensor.width, sensor.height) = (width, height);
    let spec = SceneSpec::from_name(scene)?;
    Simulator::new(SimConfig::new(sensor, spec)).ok()
}

fn numpy(width: usize, height: usize) -> (f64, f64) {
    let nan = (f64::NAN, f64::NAN);
    let args = [width.to_string(), height.to_string(), "7".into()];
    let Some(text) = python("numpy_fan_pellets.py", &args, "numpy") else {
        return nan;
    };
    let v: Vec<f64> = text
        .split_whitespace()
        .skip(1)
        .filter_map(|v| v.parse().ok())
        .collect();
    match v[..] {
        [wall, cpu] => (wall, cpu),
        _ => nan,
    }
}

fn cell(t: (f64, f64)) -> String {
    format!("{:.2} / {:.2}", t.0, t.1)
}

fn main() {
    let gradient = Illumination {
        modulation: ModulationPattern::single_transition(0.5),
        ls1: SourceDrive::Off,
        ls2: SourceDrive::Off,
    };
    println!("simulator capture, one core, side by side in one run");
    println!("each cell: median wall ms / mean thread CPU ms per frame");
    println!(
        "{:<9} {:>15} {:>8} {:>15} {:>15} {:>15} {:>10} {:>9} {:>22}",
        "size",
        "fan-pellets",
        "fps",
        "previous",
        "numpy",
        "static chart",
        "prev/ours",
        "np/ours",
        "max |wells diff| e"
    );
    for (w, h) in [(320, 240), (640, 480)] {
        let (Some(mut ours), Some(mut old), Some(mut chart)) = (
            simulator("fan-pellets", w, h),
            simulator("fan-pellets", w, h),
            simulator("colour-chart", w, h),
        ) else {
            eprintln!("cannot build the simulators");
            return;
        };
        let mut frame = Frame::new(w, h);
        let fast = time_ms(REPS, || ours.capture(&gradient, &mut frame));
        let previous = time_ms(REPS / 4, || old.capture_substepped(&gradient, &mut frame));
        let snapshot = Illumination::snapshot(chart.params().modulation_hz);
        let still = time_ms(REPS, || chart.capture(&snapshot, &mut frame));
        let np = numpy(w, h);
        // Closed form against sub-steps, same exposure.
        let t0 = ours.time_us();
        ours.expect_wells(&gradient, t0);
        let a = ours.last_expectation().clone();
        ours.expect_wells_substepped(&gradient, t0);
        let b = ours.last_expectation();
        let max_diff = [
            (&a.i_plus_electrons, &b.i_plus_electrons),
            (&a.i_minus_electrons, &b.i_minus_electrons),
        ]
        .iter()
        .flat_map(|(x, y)| x.data.iter().zip(&y.data).map(|(p, q)| (p - q).abs()))
        .fold(0.0f32, f32::max);
        let peak = b
            .i_plus_electrons
            .data
            .iter()
            .chain(&b.i_minus_electrons.data)
            .fold(0.0f32, |m, &v| m.max(v));
        println!(
            "{:<9} {:>15} {:>8.0} {:>15} {:>15} {:>15} {:>9.1}x {:>8.1}x {:>8.1} ({:.2}% of max)",
            format!("{w}x{h}"),
            cell(fast),
            1e3 / fast.1,
            cell(previous),
            cell(np),
            cell(still),
            previous.1 / fast.1,
            np.1 / fast.1,
            max_diff,
            100.0 * max_diff / peak
        );
    }
    println!("previous: the 16-sub-step render (capture_substepped); numpy: numpy_fan_pellets.py");
    println!("fps and ratios from CPU time; wells diff: closed form vs 16 sub-steps, one exposure");
}
