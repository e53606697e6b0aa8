//! Side-by-side benchmark, one run, one core: our two fast M3 variants
//! (separable and bilateral grid) and the daemon's per-frame path (the faster
//! of them, then unmix) against OpenCV's bilateral filters computing the
//! equivalent weighted mean and second moment.
//!
//! `cargo bench -p sdi-core --bench m3_vs_opencv` (needs /usr/bin/python3 with
//! python3-opencv; without it only our timings are printed).

mod support;

use std::time::Instant;

use rand::rngs::SmallRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use sdi_core::sensor::SkellamMixing;
use sdi_core::separation::{
    bilateral_exact, BilateralGrid, BilateralParams, LiveMethod, LiveSeparator, LocalMoments,
    SeparableBilateral, UnmixOptions,
};
use sdi_core::Frame;
use support::{python, time_ms};

const W: usize = 640;
const H: usize = 480;
const REPS: usize = 21;

/// A 6x4 chart of patches with the paper's noise (Gaussian limit of Skellam).
fn chart_frame(h: &SkellamMixing) -> Frame {
    let mut rng = SmallRng::seed_from_u64(7);
    let mut f = Frame::new(W, H);
    let g = h.gain_dn_per_electron;
    for y in 0..H {
        for x in 0..W {
            let k = (y * 4 / H) * 6 + x * 6 / W;
            let a = ((k as f64 * 0.618).fract() * 0.85 + 0.15) * 20_000.0;
            let b = ((k as f64 * 0.414 + 0.3).fract() * 0.85 + 0.15) * 20_000.0;
            let sd = (g * g * (a + b) + h.read_variance_dn2).sqrt();
            let n = Normal::new(g * (a - b), sd).unwrap();
            f.dn.data[y * W + x] = n.sample(&mut rng).round() as f32;
        }
    }
    f
}

/// Error of a fast M3 against the exact M3 on a 160x120 crop of the frame's
/// centre, over the crop's pixels at least one radius from its border:
/// (RMS of (mean - exact mean) / exact sd, RMS of variance / exact variance - 1).
fn error_vs_exact(frame: &Frame, fast: &LocalMoments, p: BilateralParams) -> (f64, f64) {
    let (cw, ch) = (160, 120);
    let (x0, y0) = ((W - cw) / 2, (H - ch) / 2);
    let mut crop = Frame::new(cw, ch);
    for y in 0..ch {
        for x in 0..cw {
            crop.dn.data[y * cw + x] = frame.dn.data[(y0 + y) * W + x0 + x];
        }
    }
    let Ok(exact) = bilateral_exact(&crop, p) else {
        return (f64::NAN, f64::NAN);
    };
    let r = p.radius();
    let (mut em, mut ev, mut n) = (0.0, 0.0, 0usize);
    for y in r..ch.saturating_sub(r) {
        for x in r..cw.saturating_sub(r) {
            let i = y * cw + x;
            let j = (y0 + y) * W + x0 + x;
            let (m, v) = (exact.mean_dn.data[i], exact.variance_dn2.data[i]);
            if v.is_nan() || v <= 0.0 {
                continue;
            }
            let dm = (fast.mean_dn.data[j] as f64 - m) / v.sqrt();
            let dv = fast.variance_dn2.data[j] as f64 / v - 1.0;
            em += dm * dm;
            ev += dv * dv;
            n += 1;
        }
    }
    ((em / n as f64).sqrt(), (ev / n as f64).sqrt())
}

/// OpenCV's (joint, mean-only) timings from the Python reference.
fn opencv(
    frame: &std::path::Path,
    sd: f64,
    sr: f64,
    radius: usize,
    reps: usize,
) -> ((f64, f64), (f64, f64)) {
    let nan = (f64::NAN, f64::NAN);
    let (mut joint, mut mean) = (nan, nan);
    let args = [
        frame.display().to_string(),
        W.to_string(),
        H.to_string(),
        sd.to_string(),
        sr.to_string(),
        radius.to_string(),
        reps.to_string(),
    ];
    let Some(stdout) = python("opencv_bilateral.py", &args, "OpenCV") else {
        return (joint, mean);
    };
    for line in stdout.lines() {
        let mut it = line.split_whitespace();
        let name = it.next();
        let v: Vec<f64> = it.filter_map(|v| v.parse().ok()).collect();
        let pair = (
            v.first().copied().unwrap_or(f64::NAN),
            v.get(1).copied().unwrap_or(f64::NAN),
        );
        match name {
            Some("opencv_joint_mean_and_second_moment") => joint = pair,
            Some("opencv_bilateralFilter_mean_only") => mean = pair,
            _ => {}
        }
    }
    (joint, mean)
}

fn main() {
    let h = SkellamMixing::new(0.08 * 0.65, 15.05);
    let frame = chart_frame(&h);
    let path = std::env::temp_dir().join(format!("sdi_m3_bench_{}.f32", std::process::id()));
    let bytes: Vec<u8> = frame.dn.data.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(&path, bytes).expect("write temp frame");
    println!("M3 at {W}x{H}, one core, median of {REPS} runs, measured side by side");
    println!(
        "each cell: median wall ms / mean CPU ms per frame (CPU time is immune to other load)"
    );
    println!(
        "{:<8} {:>6} {:>18} {:>18} {:>18} {:>18} {:>18} {:>13} {:>15} {:>15}",
        "sigma_d",
        "radius",
        "sdi separable",
        "sdi grid",
        "sdi live+unmix",
        "opencv joint",
        "opencv mean",
        "opencv/live",
        "err sep m/v",
        "err grid m/v"
    );
    let cell = |t: (f64, f64)| format!("{:>7.2} / {:>6.2}", t.0, t.1);
    let err = |e: (f64, f64)| format!("{:.3}/{:.3}", e.0, e.1);
    for (sd, sr) in [
        (1.0, 20.0),
        (1.5, 20.0),
        (2.0, 30.0),
        (3.0, 30.0),
        (4.0, 30.0),
        (4.5, 30.0),
        (5.0, 30.0),
        (6.0, 30.0),
        (8.0, 30.0),
        (12.0, 30.0),
    ] {
        let p = BilateralParams::new(sd, sr);
        // A live pipeline keeps its buffers across frames, as these do.
        let mut separable = SeparableBilateral::new();
        let sep = time_ms(REPS, || {
            std::hint::black_box(separable.compute(&frame, p).unwrap());
        });
        let mut grid = BilateralGrid::new();
        let grd = time_ms(REPS, || {
            std::hint::black_box(grid.compute(&frame, p).unwrap());
        });
        // What the daemon runs per frame: the faster M3 for these sigmas, then H^-1.
        let mut live = LiveSeparator::new(LiveMethod::Bilateral(p), h, UnmixOptions::default());
        let full = time_ms(REPS, || {
            std::hint::black_box(live.process(&frame).unwrap());
        });
        // OpenCV's cost grows with radius^2: fewer runs for the wide kernels.
        let reps = if sd > 3.0 { 3 } else { REPS };
        let (joint, mean) = opencv(&path, sd, sr, p.radius(), reps);
        // M3 alone against OpenCV's M3 alone: the faster of our two variants.
        let ours = if sep.0 <= grd.0 { sep } else { grd };
        let sep_err = error_vs_exact(&frame, separable.moments(), p);
        let grid_err = error_vs_exact(&frame, grid.moments(), p);
        println!(
            "{:<8} {:>6} {:>18} {:>18} {:>18} {:>18} {:>18} {:>5.1}x/{:.1}x {:>15} {:>15}",
            sd,
            p.radius(),
            cell(sep),
            cell(grd),
            cell(full),
            cell(joint),
            cell(mean),
            joint.0 / ours.0,
            joint.0 / full.0,
            err(sep_err),
            err(grid_err),
        );
    }
    println!("opencv/live: OpenCV joint (wall) over our faster M3 alone / over M3 + unmix");
    println!(
        "err m/v: against the exact M3 on a 160x120 crop, RMS of the mean's error in local \
         standard deviations / RMS relative error of the variance"
    );
    // Exact M3 for scale (one run).
    let t0 = Instant::now();
    std::hint::black_box(bilateral_exact(&frame, BilateralParams::new(1.5, 20.0)).unwrap());
    println!(
        "exact M3 (sigma_d 1.5, radius 4): {:.1} ms",
        t0.elapsed().as_secs_f64() * 1e3
    );
    let _ = std::fs::remove_file(&path);
}
