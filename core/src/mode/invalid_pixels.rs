//! The invalid-pixel stage: flags saturated pixels and neutralizes NaN/Inf so
//! no sink ever sees a non-finite value.

use crate::PixelFlags;

/// Combines the sensor's saturation flags into `out_flags` and replaces
/// non-finite values by 0 (flagged [`PixelFlags::NONFINITE`]); with `zero_saturated`,
/// saturated values become 0 too. All slices have the same length.
#[inline]
pub fn handle_invalid(
    dn: &mut [f32],
    saturated_in: &[u8],
    out_flags: &mut [u8],
    zero_saturated: bool,
) {
    let (saturated, nonfinite) = (PixelFlags::SATURATED.bits(), PixelFlags::NONFINITE.bits());
    // Branch-free (selects, not jumps), so the loop vectorizes.
    for ((v, &sat), f) in dn.iter_mut().zip(saturated_in).zip(out_flags.iter_mut()) {
        let (sat, finite) = (sat != 0, v.is_finite());
        *f = if sat { saturated } else { 0 } | if finite { 0 } else { nonfinite };
        *v = if !finite || (sat && zero_saturated) {
            0.0
        } else {
            *v
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nan_and_inf_become_flagged_zero() {
        let mut dn = [1.0, f32::NAN, f32::INFINITY, -3.0];
        let sat = [0, 0, 1, 1];
        let mut out = [9u8; 4];
        handle_invalid(&mut dn, &sat, &mut out, false);
        assert_eq!(dn, [1.0, 0.0, 0.0, -3.0]);
        assert_eq!(
            out,
            [
                0,
                PixelFlags::NONFINITE.bits(),
                PixelFlags::NONFINITE.bits() | PixelFlags::SATURATED.bits(),
                PixelFlags::SATURATED.bits()
            ]
        );
        handle_invalid(&mut dn, &sat, &mut out, true);
        assert_eq!(dn[3], 0.0);
    }
}
