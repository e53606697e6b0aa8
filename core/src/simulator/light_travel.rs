//! Light travel time against the modulation period.
//!
//! The wells integrate f(t) against the light as it arrives (eq.
//! wellmeasurement). Light reaching the pixel tau = path / c after it left
//! the source sees f shifted by tau: for the 50/50 square wave of period T a
//! fraction w = 2 phi (phi = tau / T mod 1, folded to [0, 1/2]: a triangle)
//! of an in-phase source's charge lands in the other well, and vice versa:
//! I+' = (1 - w) I+ + w I-, I-' = w I+ + (1 - w) I-. At the depth-edge
//! scene's 1.5 m wall (3 m path, 10 ns) that is 2% at 1 MHz and 24% at
//! 12 MHz, the TI board's default.
//!
//! Applied inside [`super::Simulator`] (`SimConfig::light_travel`, on by
//! default) for scenes with per-pixel depth (`Scene::depth_m`: the
//! depth-edge scenes) under the 50/50 square wave; [`light_travel_warning`]
//! tells the user when it matters.

use crate::scene::SceneSpec;

/// Speed of light, m/s.
pub const SPEED_OF_LIGHT_M_PER_S: f64 = 299_792_458.0;

/// Fraction of the wrong well above which sdid and sdictl warn.
pub const WARN_WRONG_WELL_FRACTION: f64 = 0.03;

/// Fraction of a modulated source's charge that lands in the other well
/// when its light travels `path_m` (source -> scene -> sensor) under a 50/50
/// square wave of `modulation_hz`. 0 for non-positive or non-finite input.
pub fn wrong_well_fraction(path_m: f64, modulation_hz: f64) -> f64 {
    if !(path_m.is_finite() && modulation_hz.is_finite() && path_m > 0.0 && modulation_hz > 0.0) {
        return 0.0;
    }
    let phi = (path_m / SPEED_OF_LIGHT_M_PER_S * modulation_hz).fract();
    2.0 * phi.min(1.0 - phi)
}

/// The wells after a delay moved fraction `w` of each source's charge to the
/// other well.
pub fn delayed_wells(i_plus_electrons: f64, i_minus_electrons: f64, w: f64) -> (f64, f64) {
    (
        (1.0 - w) * i_plus_electrons + w * i_minus_electrons,
        w * i_plus_electrons + (1.0 - w) * i_minus_electrons,
    )
}

/// Farthest surface of a scene, metres, where the scene models depth
/// (sources taken beside the lens: path = 2 depth).
pub fn scene_max_depth_m(scene: &SceneSpec) -> Option<f64> {
    match scene {
        SceneSpec::DepthEdge { .. } => Some(1.5),
        _ => None,
    }
}

/// A warning when the scene's depth and the modulation frequency put more
/// than [`WARN_WRONG_WELL_FRACTION`] of the charge in the wrong well.
pub fn light_travel_warning(scene: &SceneSpec, modulation_hz: f64) -> Option<String> {
    let depth = scene_max_depth_m(scene)?;
    let w = wrong_well_fraction(2.0 * depth, modulation_hz);
    (w > WARN_WRONG_WELL_FRACTION).then(|| {
        format!(
            "light travel: at {depth} m and {:.1} MHz, {:.0}% of the charge reaches the wrong well \
             (round trip {:.1} ns against a half period of {:.1} ns), in the simulator as on a real sensor. \
             Lower the modulation frequency (below {:.1} MHz keeps it under {:.0}%).",
            modulation_hz / 1e6,
            100.0 * w,
            2.0 * depth / SPEED_OF_LIGHT_M_PER_S * 1e9,
            0.5e9 / modulation_hz,
            WARN_WRONG_WELL_FRACTION * SPEED_OF_LIGHT_M_PER_S / (4.0 * depth) / 1e6,
            100.0 * WARN_WRONG_WELL_FRACTION
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_at_1_mhz_and_visible_at_12_mhz_at_1_5_m() {
        let slow = wrong_well_fraction(3.0, 1e6);
        let fast = wrong_well_fraction(3.0, 12e6);
        assert!(slow < 0.021, "{slow}");
        assert!((fast - 0.24).abs() < 0.005, "{fast}");
        // Half a period of delay swaps the wells; a whole period restores them.
        let half = SPEED_OF_LIGHT_M_PER_S / 12e6 / 2.0;
        assert!((wrong_well_fraction(half, 12e6) - 1.0).abs() < 1e-9);
        assert!(wrong_well_fraction(2.0 * half, 12e6) < 1e-9);
        assert_eq!(wrong_well_fraction(f64::NAN, 12e6), 0.0);
        let (p, m) = delayed_wells(1000.0, 0.0, fast);
        assert!((p + m - 1000.0).abs() < 1e-9 && m > 200.0);
    }

    /// The simulator itself: LS1 alone on the depth-edge scene; at a wall
    /// pixel (1.5 m) the charge in I- is the wrong-well fraction.
    #[test]
    fn simulator_moves_charge_at_12_mhz_and_hardly_at_1_mhz() {
        use crate::modulation::{Illumination, SourceDrive};
        use crate::sensor::SensorPreset;
        use crate::simulator::{SimConfig, Simulator};
        let wrong_share = |hz: f64, travel: bool| {
            let mut p = SensorPreset::TiOpt8241.params();
            p.modulation_hz = hz;
            let mut c = SimConfig::new(p, SceneSpec::from_name("depth-edge").unwrap());
            c.light_travel = travel;
            let mut sim = Simulator::new(c).unwrap();
            let mut light = Illumination::snapshot(hz);
            light.ls2 = SourceDrive::Off;
            let mut f = crate::Frame::new(1, 1);
            sim.capture(&light, &mut f);
            let e = sim.last_expectation();
            // Pixel (0, 0) sees the wall.
            let (a, b) = (e.i_plus_electrons.data[0], e.i_minus_electrons.data[0]);
            assert!(a + b > 0.0);
            f64::from(b / (a + b))
        };
        let fast = wrong_share(12e6, true);
        let slow = wrong_share(1e6, true);
        assert!(
            (fast - wrong_well_fraction(3.0, 12e6)).abs() < 1e-4,
            "{fast}"
        );
        assert!(fast > 0.2, "{fast}");
        assert!(slow > 0.0 && slow < 0.021, "{slow}");
        assert_eq!(wrong_share(12e6, false), 0.0);
    }

    #[test]
    fn warns_for_the_depth_edge_scene_at_12_mhz_only() {
        let scene = SceneSpec::from_name("depth-edge").unwrap();
        assert!(light_travel_warning(&scene, 12e6).is_some());
        assert!(light_travel_warning(&scene, 1e6).is_none());
        let flat = SceneSpec::from_name("flat-field").unwrap();
        assert!(light_travel_warning(&flat, 100e6).is_none());
    }
}
