//! Sign structure of each scene's difference image (sections 5.1-5.4),
//! measured on simulated frames after dark-frame subtraction (section 4,
//! measurement procedure). Region means are compared with 5 standard errors
//! of the frame noise.

use sdi_core::modulation::{Illumination, ModulationPattern, SourceDrive};
use sdi_core::scene::layout::OBJECTS;
use sdi_core::scene::{
    BirefringentChart, ColourChart, DepthEdgeScene, FanPellets, FanPelletsParams,
    PolarizationScene, Region, SceneSpec, SourcePlacement,
};
use sdi_core::sensor::{SensorParams, SensorPreset};
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::Frame;

fn ti(width: usize, height: usize) -> SensorParams {
    let mut p = SensorPreset::TiOpt8241.params();
    p.width = width;
    p.height = height;
    p
}

/// Mean over `frames` snapshot frames minus the mean of as many dark frames.
fn dark_subtracted_mean(spec: SceneSpec, sensor: &SensorParams, frames: usize) -> Vec<f64> {
    let mut s = Simulator::new(SimConfig::new(sensor.clone(), spec)).unwrap();
    let light = Illumination::snapshot(sensor.modulation_hz);
    let mut f = Frame::new(sensor.width, sensor.height);
    let mut acc = vec![0.0f64; sensor.width * sensor.height];
    for _ in 0..frames {
        s.capture(&light, &mut f);
        acc.iter_mut()
            .zip(&f.dn.data)
            .for_each(|(a, &v)| *a += v as f64);
        s.capture_dark(&mut f);
        acc.iter_mut()
            .zip(&f.dn.data)
            .for_each(|(a, &v)| *a -= v as f64);
    }
    acc.iter().map(|a| a / frames as f64).collect()
}

/// Mean and standard error of `values` at the selected pixels.
fn region(values: &[f64], select: impl Fn(usize) -> bool) -> (f64, f64, usize) {
    let v: Vec<f64> = (0..values.len())
        .filter(|&i| select(i))
        .map(|i| values[i])
        .collect();
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, (var / n).sqrt(), v.len())
}

#[test]
fn colour_chart_red_positive_blue_negative_grey_near_zero() {
    let sensor = ti(96, 64);
    let spec = SceneSpec::from_name("colour-chart").unwrap();
    let SceneSpec::ColourChart {
        red_led_electrons_per_us: red,
        blue_led_electrons_per_us: blue,
    } = spec
    else {
        unreachable!()
    };
    let mean = dark_subtracted_mean(spec, &sensor, 10);
    let chart = ColourChart::new(sensor.width, sensor.height, red as f32, blue as f32);
    let w = sensor.width;
    let patch = |p: usize| region(&mean, |i| chart.patch_at(i % w, i / w) == Some(p));
    let (red_mean, red_se, n) = patch(14);
    assert!(
        n > 20 && red_mean > 10.0 * red_se && red_mean > 100.0,
        "red {red_mean}"
    );
    let (blue_mean, blue_se, _) = patch(12);
    assert!(
        blue_mean < -10.0 * blue_se && blue_mean < -50.0,
        "blue {blue_mean}"
    );
    for grey in 18..24 {
        let (m, _, _) = patch(grey);
        assert!(m.abs() < 0.05 * red_mean, "grey patch {grey}: {m}");
    }
    // Each patch matches the model: rho eta (I+ - I-).
    let g = sensor.gain_dn_per_electron();
    let half = 0.5 * sensor.exposure_us;
    for p in 0..24 {
        let (r, b) = sdi_core::scene::layout::patch_reflectance(p);
        let expected = g * half * (r as f64 * red - b as f64 * blue);
        let (m, se, _) = patch(p);
        assert!(
            (m - expected).abs() < 5.0 * se + 0.5,
            "patch {p}: {m} vs {expected}"
        );
    }
}

#[test]
fn polarization_direct_only_is_zero_on_depolarizing_material() {
    let sensor = ti(96, 64);
    let spec = SceneSpec::from_name("polarization").unwrap();
    let mean = dark_subtracted_mean(spec, &sensor, 10);
    let scene = PolarizationScene::new(sensor.width, sensor.height, 12.0);
    let w = sensor.width;
    let scene = &scene;
    let in_region = |r: Region| move |i: usize| scene.components_at(i % w, i / w).0 == r;
    let (block, se, n) = region(&mean, in_region(Region::DepolarizingBlock));
    assert!(n > 50);
    assert!(block.abs() < 5.0 * se + 0.2, "depolarizing block {block}");
    let (wall, se, _) = region(&mean, in_region(Region::Wall));
    assert!(wall.abs() < 5.0 * se + 0.2, "wall {wall}");
    let (metal, se, _) = region(&mean, in_region(Region::MetalPlate));
    assert!(metal > 100.0 && metal > 10.0 * se, "metal {metal}");
    // The sphere's highlight (direct) is positive, its diffuse body is not.
    let highlight = |i: usize| {
        let (r, c) = scene.components_at(i % w, i / w);
        r == Region::GlossySphere && c.direct > 0.5
    };
    let (spec_mean, _, n) = region(&mean, highlight);
    assert!(n > 0 && spec_mean > 100.0, "highlight {spec_mean}");
}

#[test]
fn depth_edge_shadows_have_opposite_signs_on_opposite_sides() {
    for placement in [SourcePlacement::Horizontal, SourcePlacement::Vertical] {
        let sensor = ti(120, 90);
        let spec = SceneSpec::DepthEdge {
            source_spacing_mm: 100.0,
            placement,
            source_electrons_per_us: 12.0,
        };
        let mean = dark_subtracted_mean(spec, &sensor, 6);
        let scene = DepthEdgeScene::new(sensor.width, sensor.height, 100.0, placement, 12.0);
        let w = sensor.width;
        let lit = |i: usize| scene.lit_by(i % w, i / w);
        let (only1, se1, n1) = region(&mean, |i| lit(i) == (true, false));
        let (only2, se2, n2) = region(&mean, |i| lit(i) == (false, true));
        let (both, se_b, _) = region(&mean, |i| lit(i) == (true, true));
        assert!(n1 > 10 && n2 > 10, "{placement:?}: {n1} {n2}");
        assert!(only1 > 10.0 * se1 && only1 > 50.0, "{placement:?}: {only1}");
        assert!(
            only2 < -10.0 * se2 && only2 < -50.0,
            "{placement:?}: {only2}"
        );
        assert!(both.abs() < 5.0 * se_b + 0.2, "{placement:?}: {both}");
        // LS1 is left (above): its shadow-free side, positive, is the left
        // (upper) side of the near rectangle; the opposite side is negative.
        let (h, v) = (sensor.width as f32, sensor.height as f32);
        let sdi_core::scene::layout::Shape::Rect(u0, v0, u1, v1) = OBJECTS[0].shape else {
            unreachable!()
        };
        let (before, after) = match placement {
            SourcePlacement::Horizontal => {
                let y = (0.5 * (v0 + v1) * v) as usize;
                let (x0, x1) = ((u0 * h) as usize, (u1 * h) as usize);
                (mean[y * w + x0 - 2], mean[y * w + x1 + 1])
            }
            SourcePlacement::Vertical => {
                let x = (0.5 * (u0 + u1) * h) as usize;
                let (y0, y1) = ((v0 * v) as usize, (v1 * v) as usize);
                (mean[(y0 - 2) * w + x], mean[(y1 + 1) * w + x])
            }
        };
        assert!(
            before > 0.0 && after < 0.0,
            "{placement:?}: {before} {after}"
        );
    }
}

#[test]
fn depth_edge_width_grows_with_source_spacing() {
    let count = |spacing: f32| {
        let s = DepthEdgeScene::new(160, 120, spacing, SourcePlacement::Horizontal, 1.0);
        (0..120)
            .flat_map(|y| (0..160).map(move |x| (x, y)))
            .filter(|&(x, y)| s.lit_by(x, y) != (true, true))
            .count()
    };
    let (narrow, wide) = (count(40.0), count(160.0));
    assert!(wide > 2 * narrow, "{narrow} vs {wide}");
    assert_eq!(count(0.0), 0);
}

#[test]
fn birefringent_gradient_is_signed_at_edges_and_zero_on_flats() {
    let sensor = ti(96, 64);
    let spec = SceneSpec::from_name("birefringent").unwrap();
    let mean = dark_subtracted_mean(spec, &sensor, 10);
    let chart = BirefringentChart::new(sensor.width, sensor.height, 12.0, 1.0);
    let w = sensor.width;
    let step = |i: usize| {
        let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
        chart.reflectance(x, y) - chart.reflectance(x - 1.0, y)
    };
    let (rising, se_r, n_r) = region(&mean, |i| step(i) > 0.1);
    let (falling, se_f, n_f) = region(&mean, |i| step(i) < -0.1);
    let (flat, se_0, _) = region(&mean, |i| step(i) == 0.0);
    assert!(n_r > 10 && n_f > 10);
    assert!(rising > 10.0 * se_r && rising > 100.0, "rising {rising}");
    assert!(
        falling < -10.0 * se_f && falling < -100.0,
        "falling {falling}"
    );
    assert!(flat.abs() < 5.0 * se_0 + 0.2, "flat {flat}");
}

#[test]
fn temporal_gradient_leading_edges_positive_trailing_negative() {
    let sensor = ti(160, 120);
    let params = FanPelletsParams {
        background_electrons_per_us: 1.0,
        object_electrons_per_us: 12.0,
        fan_rpm: 1500.0,
        pellets: 12,
    };
    let spec = SceneSpec::FanPellets {
        background_electrons_per_us: 1.0,
        object_electrons_per_us: 12.0,
        fan_rpm: 1500.0,
        pellets: 12,
    };
    let mut config = SimConfig::new(sensor.clone(), spec);
    config.seed = 3;
    let mut s = Simulator::new(config).unwrap();
    let scene = FanPellets::new(sensor.width, sensor.height, params, 3);
    // Single transition at mid-exposure, both LEDs off: early light -> I-,
    // late light -> I+.
    let light = Illumination {
        modulation: ModulationPattern::single_transition(0.5),
        ls1: SourceDrive::Off,
        ls2: SourceDrive::Off,
    };
    let mut f = Frame::new(sensor.width, sensor.height);
    let (mut lead, mut trail, mut still) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..4 {
        let t0 = s.time_us();
        s.capture(&light, &mut f);
        let t1 = t0 + sensor.exposure_us;
        for y in 0..sensor.height {
            for x in 0..sensor.width {
                let (a, b) = (scene.rate_at(x, y, t0), scene.rate_at(x, y, t1));
                let mid = scene.rate_at(x, y, 0.5 * (t0 + t1));
                let d = f.dn.data[y * sensor.width + x] as f64;
                if b - a > 5.0 {
                    lead.push(d);
                } else if a - b > 5.0 {
                    trail.push(d);
                } else if (a - b).abs() < 1e-3 && (mid - a).abs() < 1e-3 {
                    still.push(d);
                }
            }
        }
    }
    let stats = |v: &[f64]| {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
        (m, (var / n).sqrt(), v.len())
    };
    let (l, se_l, n_l) = stats(&lead);
    let (t, se_t, n_t) = stats(&trail);
    assert!(n_l > 20 && n_t > 20, "{n_l} {n_t}");
    assert!(l > 10.0 * se_l && l > 20.0, "leading {l}");
    assert!(t < -10.0 * se_t && t < -20.0, "trailing {t}");
    // Still pixels (the wall, the floor, resting pellets) carry no signal
    // beyond the fixed pattern, which averages out over many pixels.
    let (m, se, _) = stats(&still);
    assert!(m.abs() < 5.0 * se + 0.5, "still {m}");
}

#[test]
fn falling_pellet_is_positive_below_and_negative_above() {
    let sensor = ti(160, 120);
    let params = FanPelletsParams {
        background_electrons_per_us: 1.0,
        object_electrons_per_us: 12.0,
        fan_rpm: 0.0,
        pellets: 40,
    };
    let scene = FanPellets::new(sensor.width, sensor.height, params, 17);
    // Expected wells straight from the simulator's integration (ground truth
    // of eq. wellmeasurement under the single-transition pattern).
    let spec = SceneSpec::FanPellets {
        background_electrons_per_us: 1.0,
        object_electrons_per_us: 12.0,
        fan_rpm: 0.0,
        pellets: 40,
    };
    let mut config = SimConfig::new(sensor.clone(), spec);
    config.seed = 17;
    let mut s = Simulator::new(config).unwrap();
    let light = Illumination {
        modulation: ModulationPattern::single_transition(0.5),
        ls1: SourceDrive::Off,
        ls2: SourceDrive::Off,
    };
    let t0 = 0.0;
    s.expect_wells(&light, t0);
    let e = s.last_expectation();
    let diff = |x: usize, y: usize| {
        let i = y * sensor.width + x;
        e.i_plus_electrons.data[i] as f64 - e.i_minus_electrons.data[i] as f64
    };
    let mid = t0 + 0.5 * sensor.exposure_us;
    let mut checked = 0;
    for k in 0..scene.pellet_count() {
        let (px, py, vy) = scene.pellet_state(k, mid);
        let r = 0.02 * sensor.height as f32;
        if vy.abs() < 200.0 || py - r < 5.0 || py + r + 2.0 > 0.9 * sensor.height as f32 {
            continue;
        }
        let x = px as usize;
        // Sum over the column through the pellet: lower half vs upper half.
        let (yc, reach) = (py as usize, (r + 3.0) as usize);
        let below: f64 = (yc + 1..=yc + reach).map(|y| diff(x, y)).sum();
        let above: f64 = (yc - reach..yc).map(|y| diff(x, y)).sum();
        if vy > 0.0 {
            assert!(below > 0.0 && above < 0.0, "falling {k}: {below} {above}");
        } else {
            assert!(below < 0.0 && above > 0.0, "rising {k}: {below} {above}");
        }
        checked += 1;
    }
    assert!(checked > 0, "no moving pellet in view");
}
