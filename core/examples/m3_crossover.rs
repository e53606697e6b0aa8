//! Where the bilateral grid (O(1) per pixel) overtakes the separable M3
//! (O(sigma_domain) per pixel): best of 30 runs each at 640x480, one core.
//! `cargo run --release -p sdi-core --example m3_crossover`
use sdi_core::separation::{BilateralGrid, BilateralParams, SeparableBilateral};
use sdi_core::Frame;
/// Best wall time of 30 runs, ms.
fn min_ms(mut f: impl FnMut()) -> f64 {
    (0..30)
        .map(|_| {
            let t = std::time::Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::MAX, f64::min)
}
fn main() {
    // Vertical bands 300 DN apart with +-50 DN of pseudo-random texture.
    let (w, h) = (640, 480);
    let mut f = Frame::new(w, h);
    for i in 0..w * h {
        f.dn.data[i] = ((i * 7919) % 1000) as f32 * 0.1 + ((i % w) / 100 * 300) as f32;
    }
    let mut s = SeparableBilateral::new();
    let mut g = BilateralGrid::new();
    for sd in [1.5, 3.0, 4.0, 5.0, 6.0, 8.0] {
        let p = BilateralParams::new(sd, 30.0);
        let a = min_ms(|| {
            std::hint::black_box(s.compute(&f, p).unwrap());
        });
        let b = min_ms(|| {
            std::hint::black_box(g.compute(&f, p).unwrap());
        });
        println!("sd {sd}: separable {a:.2} ms grid {b:.2} ms");
    }
}
