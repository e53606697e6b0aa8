//! H^-1 applied per pixel (section 6), with standard errors, clamping and an
//! optional projection onto I+, I- >= 0.

use super::{LocalMoments, MomentSource, SeparationError};
use crate::image::Image;
use crate::sensor::SkellamMixing;
use crate::PixelFlags;
use multiversion::multiversion;

/// How to invert H.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnmixOptions {
    /// Subtract sigma_read^2 before inverting (the paper's Fig. pol compares both).
    pub subtract_read_noise: bool,
    /// Never return negative intensities: weighted least squares on the boundary.
    pub nonnegative: bool,
}

impl Default for UnmixOptions {
    fn default() -> Self {
        Self {
            subtract_read_noise: true,
            nonnegative: false,
        }
    }
}

/// The two recovered latent images, electrons, with one-sigma standard errors.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Separated {
    pub i_plus_electrons: Image<f32>,
    pub i_minus_electrons: Image<f32>,
    pub i_plus_se_electrons: Image<f32>,
    pub i_minus_se_electrons: Image<f32>,
    /// [`PixelFlags`](crate::PixelFlags) bits (the moments' flags plus clamping and projection).
    pub flags: Image<u8>,
}

impl Separated {
    pub(crate) fn ensure_size(&mut self, width: usize, height: usize) {
        if self.flags.width != width || self.flags.height != height {
            *self = Self {
                i_plus_electrons: Image::new(width, height),
                i_minus_electrons: Image::new(width, height),
                i_plus_se_electrons: Image::new(width, height),
                i_minus_se_electrons: Image::new(width, height),
                flags: Image::new(width, height),
            };
        }
    }
}

/// (I+, I-) = H^-1 (mu, sigma^2 - sigma_read^2) for every pixel (section 6).
///
/// Written as half-sum and half-difference, S = (sigma^2 - sigma_read^2)/g^2 and
/// D = mu/g with g = rho eta, so nothing cancels when det H = 2 g^3 is tiny.
/// Var(I+-) = (Var S + Var D +- 2 Cov(S, D)) / 4 from the moments' sampling
/// (co)variances. A variance below sigma_read^2 is clamped to it and flagged.
pub fn unmix(
    moments: &impl MomentSource,
    h: &SkellamMixing,
    options: UnmixOptions,
) -> Result<Separated, SeparationError> {
    let mut out = Separated::default();
    unmix_into(moments, h, options, &mut out)?;
    Ok(out)
}

/// [`unmix`] into `out`, reusing its buffers (a live pipeline allocates
/// nothing after the first frame).
pub fn unmix_into(
    moments: &impl MomentSource,
    h: &SkellamMixing,
    options: UnmixOptions,
    out: &mut Separated,
) -> Result<(), SeparationError> {
    let (g, r) = check_mixing(h)?;
    let read = if options.subtract_read_noise { r } else { 0.0 };
    let (w, ht) = moments.size();
    out.ensure_size(w, ht);
    out.flags.data.copy_from_slice(&moments.flags().data);
    let g2 = g * g;
    for i in 0..w * ht {
        let mut f = out.flags.data[i];
        if f & PixelFlags::INSUFFICIENT.bits() != 0 {
            out.i_plus_electrons.data[i] = 0.0;
            out.i_minus_electrons.data[i] = 0.0;
            out.i_plus_se_electrons.data[i] = f32::INFINITY;
            out.i_minus_se_electrons.data[i] = f32::INFINITY;
            continue;
        }
        let px = moments.pixel(i);
        let mean = px.mean_dn;
        let mut excess = px.variance_dn2 - read;
        if excess < 0.0 {
            excess = 0.0;
            f |= PixelFlags::VARIANCE_CLAMPED.bits();
        }
        let (var_mean, var_var) = (px.mean_var_dn2, px.variance_var_dn4);
        let cov = px.mean_variance_cov_dn3;
        let sum = excess / g2;
        let diff = mean / g;
        let var_sum = var_var / (g2 * g2);
        let var_diff = var_mean / g2;
        let cov_sd = cov / (g2 * g);
        let mut p = 0.5 * (sum + diff);
        let mut m = 0.5 * (sum - diff);
        let se_p = (0.25 * (var_sum + var_diff + 2.0 * cov_sd)).max(0.0).sqrt();
        let se_m = (0.25 * (var_sum + var_diff - 2.0 * cov_sd)).max(0.0).sqrt();
        if options.nonnegative && (p < 0.0 || m < 0.0) {
            (p, m) = project(g, mean, excess, var_mean, var_var);
            f |= PixelFlags::PROJECTED.bits();
        }
        out.i_plus_electrons.data[i] = p as f32;
        out.i_minus_electrons.data[i] = m as f32;
        out.i_plus_se_electrons.data[i] = se_p as f32;
        out.i_minus_se_electrons.data[i] = se_m as f32;
        out.flags.data[i] = f;
    }
    Ok(())
}

/// Gain and read variance of `h`, refused when g^2 is not a normal f64
/// (g below about 1e-154: g^2 would underflow and H^-1 give inf - inf).
fn check_mixing(h: &SkellamMixing) -> Result<(f64, f64), SeparationError> {
    let g = h.gain_dn_per_electron;
    let ok = g > 0.0 && (g * g).is_normal() && g.is_finite();
    SeparationError::check("gain_dn_per_electron", g, ok, "> 1e-154 and finite")?;
    let r = h.read_variance_dn2;
    SeparationError::check("read_variance_dn2", r, r >= 0.0, ">= 0")?;
    Ok((g, r))
}

/// [`unmix_into`] for the fast M3 output: the same equations with
/// Cov(S, D) = 0 and Gaussian sampling variances (see [`LocalMoments`]),
/// in f32 loops that vectorize; the rare pixels needing the non-negative
/// projection are redone in f64. Scales are factored out so a tiny gain
/// (det H ~ 2 g^3) overflows only what f32 cannot hold anyway.
pub fn unmix_local_into(
    moments: &LocalMoments,
    h: &SkellamMixing,
    options: UnmixOptions,
    out: &mut Separated,
) -> Result<(), SeparationError> {
    let (g, r) = check_mixing(h)?;
    let (inv_g, inv_g2) = ((1.0 / g) as f32, (1.0 / (g * g)) as f32);
    if !(inv_g2.is_normal() && (g * g) as f32 > 0.0) {
        // Outside f32's range (g below ~1e-19 or above ~1e19): the f64 path.
        return unmix_into(moments, h, options, out);
    }
    let read = if options.subtract_read_noise {
        r as f32
    } else {
        0.0
    };
    let (w, ht) = moments.size();
    out.ensure_size(w, ht);
    let scales = LocalScales {
        inv_g,
        inv_g2,
        half_inv_g2: (0.5 / (g * g)) as f32,
        g2: (g * g) as f32,
        read,
    };
    let negative = unmix_local_pixels(
        scales,
        [
            &moments.mean_dn.data,
            &moments.variance_dn2.data,
            &moments.samples.data,
        ],
        &moments.flags.data,
        [
            &mut out.i_plus_electrons.data,
            &mut out.i_minus_electrons.data,
            &mut out.i_plus_se_electrons.data,
            &mut out.i_minus_se_electrons.data,
        ],
        &mut out.flags.data,
    );
    let (plus, minus) = (
        &mut out.i_plus_electrons.data,
        &mut out.i_minus_electrons.data,
    );
    let fl = &mut out.flags.data;
    if options.nonnegative && negative {
        for i in 0..w * ht {
            if fl[i] & PixelFlags::INSUFFICIENT.bits() == 0 && (plus[i] < 0.0 || minus[i] < 0.0) {
                let px = moments.pixel(i);
                let excess = (px.variance_dn2 - read as f64).max(0.0);
                let (p, m) = project(g, px.mean_dn, excess, px.mean_var_dn2, px.variance_var_dn4);
                (plus[i], minus[i]) = (p as f32, m as f32);
                fl[i] |= PixelFlags::PROJECTED.bits();
            }
        }
    }
    Ok(())
}

/// The f32 factors of [`unmix_local_into`].
#[derive(Clone, Copy)]
struct LocalScales {
    inv_g: f32,
    inv_g2: f32,
    half_inv_g2: f32,
    g2: f32,
    read: f32,
}

/// [`unmix_local_into`]'s per-pixel equations (mean, variance, samples in;
/// I+, I-, SE+, SE- out), branch-free so they vectorize; true when some
/// usable pixel came out negative.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn unmix_local_pixels(
    sc: LocalScales,
    inp: [&[f32]; 3],
    fl_in: &[u8],
    out: [&mut [f32]; 4],
    fl: &mut [u8],
) -> bool {
    let [mean, var, n] = inp;
    let [plus, minus, se_plus, se_minus] = out;
    let len = [mean.len(), var.len(), n.len(), fl_in.len(), fl.len()]
        .into_iter()
        .chain([plus.len(), minus.len(), se_plus.len(), se_minus.len()])
        .min()
        .unwrap_or(0);
    let (mean, var, n, fl_in) = (&mean[..len], &var[..len], &n[..len], &fl_in[..len]);
    let (plus, minus) = (&mut plus[..len], &mut minus[..len]);
    let (se_plus, se_minus, fl) = (&mut se_plus[..len], &mut se_minus[..len], &mut fl[..len]);
    let mut negative = false;
    for i in 0..len {
        let insufficient = fl_in[i] & PixelFlags::INSUFFICIENT.bits() != 0;
        let excess = var[i] - sc.read;
        let clamped = excess < 0.0 && !insufficient;
        let excess = excess.max(0.0);
        let (sum, diff) = (excess * sc.inv_g2, mean[i] * sc.inv_g);
        let (p, m) = (0.5 * (sum + diff), 0.5 * (sum - diff));
        // Var S = Var(var) / g^4, Var D = Var(mean) / g^2:
        // SE = sqrt(Var S + Var D) / 2 = sqrt(Var(var) + g^2 Var(mean)) / (2 g^2).
        let (v, nn) = (var[i], n[i]);
        let se = (2.0 * v * v / (nn - 1.0) + sc.g2 * v / nn).max(0.0).sqrt() * sc.half_inv_g2;
        plus[i] = if insufficient { 0.0 } else { p };
        minus[i] = if insufficient { 0.0 } else { m };
        se_plus[i] = if insufficient { f32::INFINITY } else { se };
        se_minus[i] = se_plus[i];
        fl[i] = fl_in[i]
            | if clamped {
                PixelFlags::VARIANCE_CLAMPED.bits()
            } else {
                0
            };
        negative |= !insufficient && (p < 0.0 || m < 0.0);
    }
    negative
}

/// Minimizes (mu - g(p - m))^2 / Var mu + (v - g^2 (p + m))^2 / Var v over the
/// boundary of p, m >= 0 (one of them zero) and returns the better feasible point.
fn project(g: f64, mean: f64, excess: f64, var_mean: f64, var_var: f64) -> (f64, f64) {
    const FLOOR: f64 = 1e-30;
    let wm = 1.0 / var_mean.max(FLOOR);
    let wv = 1.0 / var_var.max(FLOOR);
    let g2 = g * g;
    let denom = wm * g2 + wv * g2 * g2;
    let plus = ((wm * g * mean + wv * g2 * excess) / denom).max(0.0);
    let minus = ((-wm * g * mean + wv * g2 * excess) / denom).max(0.0);
    let cost = |p: f64, m: f64| {
        let a = mean - g * (p - m);
        let b = excess - g2 * (p + m);
        wm * a * a + wv * b * b
    };
    if cost(plus, 0.0) <= cost(0.0, minus) {
        (plus, 0.0)
    } else {
        (0.0, minus)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The vectorized path for [`LocalMoments`] against the general one.
    #[test]
    fn local_path_matches_the_general_one() {
        let (w, h) = (29, 7);
        let mut m = LocalMoments::new(w, h);
        for i in 0..w * h {
            m.mean_dn.data[i] = ((i * 37) % 201) as f32 - 100.0;
            m.variance_dn2.data[i] = ((i * 53) % 97) as f32 * 3.0;
            m.samples.data[i] = 1.0 + (i % 40) as f32;
            if m.samples.data[i] < 2.0 || i % 17 == 0 {
                m.flags.data[i] = PixelFlags::INSUFFICIENT.bits();
                m.mean_dn.data[i] = 0.0;
                m.variance_dn2.data[i] = 0.0;
            }
        }
        for gain in [0.052, 1e-6, 30.0, 1e-25] {
            for nonnegative in [false, true] {
                let mix = SkellamMixing::new(gain, 15.0);
                let options = UnmixOptions {
                    subtract_read_noise: true,
                    nonnegative,
                };
                let want = unmix(&m.to_moments(), &mix, options).expect("general");
                let mut got = Separated::default();
                unmix_local_into(&m, &mix, options, &mut got).expect("local");
                assert_eq!(got.flags, want.flags, "gain {gain}");
                let close = |a: &Image<f32>, b: &Image<f32>, what: &str| {
                    for i in 0..w * h {
                        let (x, y) = (a.data[i], b.data[i]);
                        let ok = x == y || (x - y).abs() <= 1e-4 * x.abs().max(y.abs());
                        assert!(ok, "{what} at {i}, gain {gain}: {x} vs {y}");
                    }
                };
                close(&got.i_plus_electrons, &want.i_plus_electrons, "I+");
                close(&got.i_minus_electrons, &want.i_minus_electrons, "I-");
                close(&got.i_plus_se_electrons, &want.i_plus_se_electrons, "SE+");
                close(&got.i_minus_se_electrons, &want.i_minus_se_electrons, "SE-");
            }
        }
    }
}
