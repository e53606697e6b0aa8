//! A ToF sensor's phase quads turned into the snapshot difference: the
//! in-phase and quadrature parts of the quads, projected onto the axis
//! along which LS1 - LS2 lies (eq. pixeleff with a phase delay between the
//! modulation f(t) and the light).
//!
//! Quad k samples the correlation of the light with the demodulation
//! shifted by k / N of a period (N = 4 or 6 quads). With zero delay the
//! difference sits in quad 0 alone and its antiphase quad (N / 2) holds
//! the negative; an LED driver or a long ribbon cable delays the light and
//! moves part of it into the other quads. The first harmonic over the
//! quads, I = sum q_k cos(2 pi k / N), Q = sum q_k sin(2 pi k / N), keeps
//! it whatever the delay: with 4 quads I = q0 - q2 and Q = q1 - q3.
//! Projected onto the calibrated axis and scaled by 2 / N, a pixel with
//! zero delay gives (q0 - q2) / 2, quad 0's DN scale.

use std::f64::consts::{PI, TAU};

/// The direction of LS1 - LS2 in the (I, Q) plane, measured with one
/// source on (`sdictl calibrate phase`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PhaseAxis {
    /// atan2(Q, I) of LS1's light, radians.
    pub angle_rad: f64,
}

/// Which single source was on while the axis was measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LitSource {
    /// LS1 (driven by f): its light is the positive difference.
    Ls1,
    /// LS2 (driven by not-f): its light is the negative difference.
    Ls2,
}

/// Why no axis could be measured.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PhaseError {
    #[error("{quads} quads: the board runs 4 or 6")]
    Quads { quads: usize },
    #[error(
        "the lit source gave a mean amplitude of {amplitude_dn:.2} DN, below {min_dn} DN: \
         is the source on and in view?"
    )]
    TooDim { amplitude_dn: f64, min_dn: f64 },
}

/// cos and sin of each quad's phase, for 4 or 6 quads.
#[derive(Debug, Clone)]
pub struct QuadBasis {
    cos: Vec<f32>,
    sin: Vec<f32>,
}

impl QuadBasis {
    pub fn new(quads: usize) -> Result<Self, PhaseError> {
        if quads != 4 && quads != 6 {
            return Err(PhaseError::Quads { quads });
        }
        let phase = |k: usize| TAU * k as f64 / quads as f64;
        // Exact zeros and ones keep 4 quads' I = q0 - q2, Q = q1 - q3 exact.
        let round = |x: f64| ((x * 1e12).round() / 1e12) as f32;
        Ok(Self {
            cos: (0..quads).map(|k| round(phase(k).cos())).collect(),
            sin: (0..quads).map(|k| round(phase(k).sin())).collect(),
        })
    }

    pub fn quads(&self) -> usize {
        self.cos.len()
    }

    /// (I, Q) of one pixel's quads.
    pub fn in_phase_quadrature(&self, quads: &[f32]) -> (f32, f32) {
        let mut i = 0.0;
        let mut q = 0.0;
        for ((&v, &c), &s) in quads.iter().zip(&self.cos).zip(&self.sin) {
            i += v * c;
            q += v * s;
        }
        (i, q)
    }

    /// The difference LS1 - LS2 of one pixel, quad 0's DN scale.
    pub fn project(&self, quads: &[f32], axis: &PhaseAxis) -> f32 {
        let (i, q) = self.in_phase_quadrature(quads);
        let (s, c) = axis.angle_rad.sin_cos();
        (i * c as f32 + q * s as f32) * 2.0 / self.quads() as f32
    }
}

/// The axis from the summed (I, Q) of frames with one source on: LS1's
/// direction, turned half a turn when LS2 was the lit one. `min_dn` is the
/// smallest mean amplitude (per pixel and frame, quad 0's scale) trusted.
pub fn fit_axis(
    sum_i: f64,
    sum_q: f64,
    samples: u64,
    quads: usize,
    lit: LitSource,
    min_dn: f64,
) -> Result<PhaseAxis, PhaseError> {
    let amplitude_dn = sum_i.hypot(sum_q) / samples.max(1) as f64 * 2.0 / quads.max(1) as f64;
    if !(amplitude_dn.is_finite() && amplitude_dn >= min_dn) {
        return Err(PhaseError::TooDim {
            amplitude_dn,
            min_dn,
        });
    }
    let angle = sum_q.atan2(sum_i);
    let angle_rad = match lit {
        LitSource::Ls1 => angle,
        LitSource::Ls2 => angle + PI,
    };
    // Keep it in [-pi, pi).
    let angle_rad = (angle_rad + PI).rem_euclid(TAU) - PI;
    Ok(PhaseAxis { angle_rad })
}

/// (I, Q) of many pixels and frames with one source on, summed for
/// [`fit_axis`]; `sum_abs` adds each pixel's |(I, Q)| so the spread of
/// the pixels' directions is known ([`PhaseSums::coherence`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PhaseSums {
    /// Quads per pixel of the frames summed (4 or 6); 0 before any.
    pub quads: usize,
    pub sum_i: f64,
    pub sum_q: f64,
    pub sum_abs: f64,
    pub samples: u64,
}

impl PhaseSums {
    /// Nothing summed yet, of frames with `quads` quads per pixel.
    pub fn new(quads: usize) -> Self {
        Self {
            quads,
            ..Self::default()
        }
    }

    /// Adds one pixel's (I, Q).
    #[inline]
    pub fn push(&mut self, i: f32, q: f32) {
        self.sum_i += f64::from(i);
        self.sum_q += f64::from(q);
        self.sum_abs += f64::from(i).hypot(f64::from(q));
        self.samples += 1;
    }

    /// Adds another frame's sums (of the same quads).
    pub fn add(&mut self, other: &PhaseSums) {
        if self.quads == 0 {
            self.quads = other.quads;
        }
        self.sum_i += other.sum_i;
        self.sum_q += other.sum_q;
        self.sum_abs += other.sum_abs;
        self.samples += other.samples;
    }

    /// |sum of (I, Q)| / sum of |(I, Q)|: 1 when every pixel's light lies
    /// along one direction, near 0 for noise or light from both sources
    /// at opposite phases; 0 with nothing summed.
    pub fn coherence(&self) -> f64 {
        if self.sum_abs > 0.0 {
            self.sum_i.hypot(self.sum_q) / self.sum_abs
        } else {
            0.0
        }
    }

    /// The axis of these sums ([`fit_axis`]).
    pub fn fit(&self, lit: LitSource, min_dn: f64) -> Result<PhaseAxis, PhaseError> {
        if self.quads != 4 && self.quads != 6 {
            return Err(PhaseError::Quads { quads: self.quads });
        }
        fit_axis(
            self.sum_i,
            self.sum_q,
            self.samples,
            self.quads,
            lit,
            min_dn,
        )
    }

    /// Mean amplitude per pixel and frame, quad 0's DN scale.
    pub fn amplitude_dn(&self) -> f64 {
        self.sum_i.hypot(self.sum_q) / self.samples.max(1) as f64 * 2.0 / self.quads.max(1) as f64
    }
}

impl PhaseAxis {
    /// An axis read back from a store: a finite angle in [-pi, pi].
    pub fn checked(angle_rad: f64) -> Option<Self> {
        (angle_rad.is_finite() && angle_rad.abs() <= PI).then_some(Self { angle_rad })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Quads of a pixel whose difference d arrives delayed by `delay_rad`,
    /// first harmonic only: q_k = d cos(2 pi k / N - delay).
    fn quads_for(d: f32, delay_rad: f64, n: usize) -> Vec<f32> {
        (0..n)
            .map(|k| d * (TAU * k as f64 / n as f64 - delay_rad).cos() as f32)
            .collect()
    }

    #[test]
    fn four_quads_are_q0_minus_q2_and_q1_minus_q3() {
        let b = QuadBasis::new(4).unwrap();
        let (i, q) = b.in_phase_quadrature(&[100.0, 7.0, -90.0, 3.0]);
        assert_eq!((i, q), (190.0, 4.0));
        // zero delay: (q0 - q2) / 2
        let axis = PhaseAxis { angle_rad: 0.0 };
        assert_eq!(b.project(&[100.0, 7.0, -90.0, 3.0], &axis), 95.0);
    }

    #[test]
    fn six_quads_use_quad_three_as_the_antiphase() {
        let b = QuadBasis::new(6).unwrap();
        // only quads 0 and 3 carry signal: I = q0 - q3, Q = 0
        let (i, q) = b.in_phase_quadrature(&[50.0, 0.0, 0.0, -50.0, 0.0, 0.0]);
        assert!((i - 100.0).abs() < 1e-4 && q.abs() < 1e-4, "{i} {q}");
        // quad 2 is not antiphase: (q0 - q2) would be wrong
        let d = b.project(&quads_for(80.0, 0.0, 6), &PhaseAxis { angle_rad: 0.0 });
        assert!((d - 80.0).abs() < 1e-3, "{d}");
    }

    #[test]
    fn a_calibrated_axis_recovers_the_difference_under_any_delay() {
        for n in [4, 6] {
            let b = QuadBasis::new(n).unwrap();
            for delay in [0.0, 0.3, 1.2, -2.0, 3.0] {
                // calibrate with LS1 alone
                let (i, q) = b.in_phase_quadrature(&quads_for(200.0, delay, n));
                let axis = fit_axis(f64::from(i), f64::from(q), 1, n, LitSource::Ls1, 1.0).unwrap();
                assert!(
                    (axis.angle_rad - delay).abs() < 1e-4,
                    "{n} {delay}: {axis:?}"
                );
                for d in [-150.0f32, 0.0, 37.5] {
                    let got = b.project(&quads_for(d, delay, n), &axis);
                    assert!((got - d).abs() < 1e-3, "{n} {delay} {d}: {got}");
                }
                // quad 0 alone loses the delayed part
                if delay.abs() > 1.0 {
                    let q0 = quads_for(100.0, delay, n)[0];
                    assert!((q0 - 100.0).abs() > 40.0);
                }
            }
        }
    }

    #[test]
    fn ls2_lit_turns_the_axis_half_a_turn() {
        let b = QuadBasis::new(4).unwrap();
        // LS2 alone gives a negative difference along LS1's axis
        let (i, q) = b.in_phase_quadrature(&quads_for(-120.0, 0.5, 4));
        let axis = fit_axis(f64::from(i), f64::from(q), 1, 4, LitSource::Ls2, 1.0).unwrap();
        assert!((axis.angle_rad - 0.5).abs() < 1e-4, "{axis:?}");
    }

    #[test]
    fn a_dark_scene_or_wrong_quads_is_an_error() {
        assert!(matches!(
            fit_axis(0.5, 0.5, 10, 4, LitSource::Ls1, 5.0),
            Err(PhaseError::TooDim { .. })
        ));
        assert!(fit_axis(f64::NAN, 0.0, 1, 4, LitSource::Ls1, 5.0).is_err());
        assert!(QuadBasis::new(5).is_err());
    }
    #[test]
    fn sums_fit_like_fit_axis_and_measure_coherence() {
        let b = QuadBasis::new(4).unwrap();
        let mut sums = PhaseSums::new(4);
        for d in [100.0f32, 120.0, 80.0] {
            let (i, q) = b.in_phase_quadrature(&quads_for(d, 1.0, 4));
            sums.push(i, q);
        }
        let axis = sums.fit(LitSource::Ls1, 5.0).unwrap();
        assert!((axis.angle_rad - 1.0).abs() < 1e-4, "{axis:?}");
        assert!((sums.amplitude_dn() - 100.0).abs() < 1e-3);
        assert!((sums.coherence() - 1.0).abs() < 1e-6);
        // two pixels at opposite phases cancel: no direction to trust
        let mut opposed = PhaseSums::new(4);
        opposed.push(50.0, 0.0);
        opposed.push(-50.0, 0.0);
        assert_eq!(opposed.coherence(), 0.0);
        assert!(opposed.fit(LitSource::Ls1, 5.0).is_err());
        let mut total = PhaseSums::default();
        total.add(&sums);
        total.add(&opposed);
        assert_eq!((total.samples, total.quads), (5, 4));
        // nothing summed: no quads to fit with
        assert!(matches!(
            PhaseSums::default().fit(LitSource::Ls1, 5.0),
            Err(PhaseError::Quads { quads: 0 })
        ));
        assert_eq!(PhaseSums::default().coherence(), 0.0);
    }

    #[test]
    fn a_stored_angle_must_be_finite_and_within_half_a_turn() {
        assert!(PhaseAxis::checked(1.0).is_some());
        assert!(PhaseAxis::checked(-PI).is_some());
        assert!(PhaseAxis::checked(4.0).is_none());
        assert!(PhaseAxis::checked(f64::NAN).is_none());
        assert!(PhaseAxis::checked(f64::INFINITY).is_none());
    }
}
