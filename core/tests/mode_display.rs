//! Display mapping: colours, ranges, and robustness to NaN/Inf and zero images.

use sdi_core::display::{robust_max_abs, Colormap, DisplayMap, DisplayRange};
use sdi_core::image::Image;

fn rgb(map: &DisplayMap, values: &[f32]) -> Vec<[u8; 3]> {
    let img = Image::from_vec(values.len(), 1, values.to_vec()).unwrap();
    let mut out = vec![0u8; values.len() * 3];
    map.render_rgb8(&img, &mut out);
    out.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

fn grey(map: &DisplayMap, values: &[f32]) -> Vec<u8> {
    let img = Image::from_vec(values.len(), 1, values.to_vec()).unwrap();
    let mut out = vec![0u8; values.len()];
    map.render_grey8(&img, &mut out);
    out
}

#[test]
fn positive_red_negative_blue_zero_neutral() {
    let map = DisplayMap::new(
        Colormap::Diverging,
        DisplayRange::Fixed { max_abs_dn: 100.0 },
    );
    let c = rgb(&map, &[100.0, 50.0, 0.0, -50.0, -100.0]);
    for p in &c[..2] {
        assert!(p[0] > p[2] + 60, "positive not red: {p:?}");
    }
    for p in &c[3..] {
        assert!(p[2] > p[0] + 60, "negative not blue: {p:?}");
    }
    let z = c[2];
    assert!(z.iter().all(|&v| v > 230), "zero not near white: {z:?}");
}

#[test]
fn grey_maps_zero_to_mid_and_is_monotonic() {
    let map = DisplayMap::new(Colormap::Grey, DisplayRange::Fixed { max_abs_dn: 10.0 });
    let g = grey(&map, &[-20.0, -10.0, -5.0, 0.0, 5.0, 10.0, 20.0]);
    assert_eq!(g[0], 0);
    assert_eq!(g[3], 128);
    assert_eq!(g[6], 255);
    assert!(g.windows(2).all(|w| w[0] <= w[1]));
    let rgb_grey = rgb(&map, &[5.0]);
    assert!(rgb_grey[0][0] == rgb_grey[0][1] && rgb_grey[0][1] == rgb_grey[0][2]);
}

#[test]
fn auto_range_ignores_outliers_nan_and_inf() {
    let mut v: Vec<f32> = (0..10_000)
        .map(|i| ((i % 201) as f32 - 100.0) * 0.5)
        .collect();
    v[0] = 1e30;
    v[1] = f32::NAN;
    v[2] = f32::INFINITY;
    v[3] = f32::NEG_INFINITY;
    let r = robust_max_abs(&v);
    assert!(r.is_finite() && (45.0..=50.0).contains(&r), "range {r}");
    let map = DisplayMap::default();
    let c = rgb(&map, &v);
    // The most extreme finite values reach the ends; NaN is neutral.
    assert_eq!(c[1], rgb(&map, &[0.0, 1.0])[0]);
    assert!(c[2][0] > c[2][2] && c[3][2] > c[3][0]);
}

#[test]
fn auto_range_of_degenerate_images_is_finite_and_positive() {
    for data in [
        vec![0.0f32; 100],
        vec![f32::NAN; 100],
        vec![f32::INFINITY, f32::NEG_INFINITY],
        vec![],
        vec![f32::MIN_POSITIVE * 0.5; 3],
        vec![f32::MAX, -f32::MAX],
    ] {
        let r = robust_max_abs(&data);
        assert!(r.is_finite() && r > 0.0, "{data:?} -> {r}");
    }
    // Mostly zeros with a few edges: the range comes from the edges, not 0.
    let mut sparse = vec![0.0f32; 10_000];
    sparse[5] = 40.0;
    sparse[6] = -30.0;
    assert_eq!(robust_max_abs(&sparse), 40.0);
    // A zero image renders as uniform neutral.
    let map = DisplayMap::default();
    let c = rgb(&map, &[0.0; 16]);
    assert!(c.windows(2).all(|w| w[0] == w[1]));
    assert_eq!(grey(&map, &[0.0; 4]), vec![128; 4]);
}

#[test]
fn short_output_buffer_does_not_panic() {
    let img = Image::filled(4, 4, 1.0f32);
    let mut out = vec![0u8; 5];
    DisplayMap::default().render_rgb8(&img, &mut out);
    DisplayMap::default().render_grey8(&img, &mut out);
}
