//! exp(-t) in f32 for the per-pixel range weights of M3, written so row loops
//! vectorize: no branches, tables or float-to-int conversions.
//!
//! 2^-y = 2^-n 2^-u with n = round(y) taken from the mantissa of y + 1.5 2^23
//! and u = y - n in [-1/2, 1/2]; 2^-u by a degree-4 least-squares polynomial
//! with p(0) = 1 (relative error < 1e-5 in f32: weights, not values). y is capped at 126, where the
//! weight (1e-38) is the smallest normal f32; NaN also gives that weight.

/// 1.5 2^23: adding it leaves round(y) in the low mantissa bits.
const ROUND_MAGIC: f32 = 12_582_912.0;
/// Bit pattern of `ROUND_MAGIC`.
const ROUND_MAGIC_BITS: u32 = 0x4B40_0000;

/// a b + c, fused where the caller was compiled with FMA (`FMA` is then
/// true), two roundings otherwise, so the fallback never calls libm's fmaf.
#[inline(always)]
pub(crate) fn madd<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

/// exp(-t) for t >= 0 (see module docs).
#[cfg(test)]
#[inline(always)]
pub(crate) fn exp_neg<const FMA: bool>(t: f32) -> f32 {
    exp2_neg::<FMA>(t * std::f32::consts::LOG2_E)
}

/// 2^-y for y >= 0 (see module docs): callers fold their scale factors
/// into y, so one fused multiply-add feeds it.
#[inline(always)]
pub(crate) fn exp2_neg<const FMA: bool>(y: f32) -> f32 {
    // `<` form: compiles to one min instruction, NaN goes to the cap.
    let y = if y < 126.0 { y } else { 126.0 };
    let big = y + ROUND_MAGIC;
    let u = y - (big - ROUND_MAGIC);
    let n = big.to_bits().wrapping_sub(ROUND_MAGIC_BITS);
    let p = madd::<FMA>(u, 0.009_600_403, -0.055_916_935);
    let p = madd::<FMA>(u, p, 0.240_237_19);
    let p = madd::<FMA>(u, p, -0.693_121_97);
    let p = madd::<FMA>(u, p, 1.0);
    p * f32::from_bits((127u32 << 23).wrapping_sub(n << 23))
}

#[cfg(test)]
mod tests {
    use super::exp_neg;

    fn worst_relative_error(exp: impl Fn(f32) -> f32) -> f64 {
        let mut worst = 0.0f64;
        for i in 0..200_000 {
            let t = i as f32 * 1e-3;
            let want = (-(t as f64)).exp();
            if want > 1e-30 {
                worst = worst.max((exp(t) as f64 / want - 1.0).abs());
            }
        }
        worst
    }

    #[test]
    fn matches_std_exp_over_the_weight_range() {
        for (name, worst) in [
            ("fused", worst_relative_error(exp_neg::<true>)),
            ("unfused", worst_relative_error(exp_neg::<false>)),
        ] {
            assert!(worst < 1e-5, "{name}: worst relative error {worst}");
        }
        assert_eq!(exp_neg::<true>(0.0), 1.0);
        assert_eq!(exp_neg::<false>(0.0), 1.0);
    }

    #[test]
    fn huge_and_nan_arguments_give_a_tiny_finite_weight() {
        for t in [1e3, 1e30, f32::INFINITY, f32::NAN] {
            let w = exp_neg::<false>(t);
            assert!(w.is_finite() && (0.0..1e-37).contains(&w), "{t} -> {w}");
        }
    }
}
