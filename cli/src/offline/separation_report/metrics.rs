//! The error measures: relative RMSE and bias per pixel and per patch,
//! M1's sampling floor, and the paper's ordering of the estimators.

use sdi_core::sensor::SkellamMixing;
use sdi_core::separation::Separated;
use sdi_core::Image;

use super::{Row, Truth};

fn rel(est: &Image<f32>, truth: &[f64]) -> (f64, f64) {
    let n = truth.len().max(1) as f64;
    let mean_t = (truth.iter().sum::<f64>() / n).abs().max(1e-9);
    let (mut se, mut b) = (0.0, 0.0);
    for (e, t) in est.data.iter().zip(truth) {
        let d = *e as f64 - t;
        se += d * d;
        b += d;
    }
    ((se / n).sqrt() / mean_t, b / n / mean_t)
}

/// Relative RMSE over the patches of the patch means.
fn rel_patch(est: &Image<f32>, truth: &[f64], patch: &[Option<usize>]) -> Option<f64> {
    let mut acc: Vec<(f64, f64, f64)> = Vec::new();
    for (i, p) in patch.iter().enumerate() {
        if let Some(p) = *p {
            if acc.len() <= p {
                acc.resize(p + 1, (0.0, 0.0, 0.0));
            }
            acc[p].0 += est.data[i] as f64;
            acc[p].1 += truth[i];
            acc[p].2 += 1.0;
        }
    }
    let used: Vec<_> = acc.into_iter().filter(|a| a.2 > 0.0).collect();
    if used.is_empty() {
        return None;
    }
    let k = used.len() as f64;
    let se: f64 = used.iter().map(|(e, t, n)| ((e - t) / n).powi(2)).sum();
    let mt: f64 = used.iter().map(|(_, t, n)| t / n).sum::<f64>() / k;
    Some((se / k).sqrt() / mt.abs().max(1e-9))
}

/// M1's per-pixel floor from sampling alone: Var(I+-) = (Var S + Var D) / 4,
/// Var S = 2 sigma^4 / ((N - 1) g^4) (sample variance), Var D = sigma^2 / (N g^2)
/// (mean), sigma^2 = g^2 (I+ + I-) + sigma_read^2; RMS over pixels / mean truth.
pub(super) fn m1_floor(t: &Truth, h: &SkellamMixing, n: usize) -> (f64, f64) {
    let g = h.gain_dn_per_electron;
    let nf = n as f64;
    let k = t.plus.len().max(1) as f64;
    let v: f64 = t
        .plus
        .iter()
        .zip(&t.minus)
        .map(|(p, m)| {
            let s2 = g * g * (p + m) + h.read_variance_dn2;
            0.25 * (2.0 * s2 * s2 / ((nf - 1.0) * g.powi(4)) + s2 / (nf * g * g))
        })
        .sum();
    let rms = (v / k).sqrt();
    let mean = |x: &[f64]| (x.iter().sum::<f64>() / k).abs().max(1e-9);
    (rms / mean(&t.plus), rms / mean(&t.minus))
}

pub(super) fn row(
    method: &'static str,
    params: String,
    sep: &Separated,
    t: &Truth,
    ms: f64,
) -> Row {
    let (rmse_plus, bias_plus) = rel(&sep.i_plus_electrons, &t.plus);
    let (rmse_minus, bias_minus) = rel(&sep.i_minus_electrons, &t.minus);
    let patch = |e: &Image<f32>, tr: &[f64]| t.patch.as_ref().and_then(|p| rel_patch(e, tr, p));
    Row {
        method,
        params,
        rmse_plus,
        bias_plus,
        rmse_minus,
        bias_minus,
        patch_plus: patch(&sep.i_plus_electrons, &t.plus),
        patch_minus: patch(&sep.i_minus_electrons, &t.minus),
        floor: None,
        ms_per_frame: ms,
    }
}

/// The paper's ordering M1 < M2 < M3: best M1 (largest N, plain), best M2
/// auto, best M3 (any variant), compared on the sum of the I+ and I- errors,
/// per patch when available, else per pixel.
pub fn ordering(rows: &[Row]) -> String {
    let err = |r: &Row| match (r.patch_plus, r.patch_minus) {
        (Some(a), Some(b)) => a + b,
        _ => r.rmse_plus + r.rmse_minus,
    };
    let best = |pred: &dyn Fn(&Row) -> bool| {
        rows.iter()
            .filter(|r| pred(r))
            .map(err)
            .fold(f64::INFINITY, f64::min)
    };
    let m1 = rows
        .iter()
        .rfind(|r| r.method == "M1" && !r.params.contains(','))
        .map_or(f64::INFINITY, err);
    let m2 = best(&|r| r.method == "M2 auto");
    let m3 = best(&|r| r.method.starts_with("M3"));
    let basis = if rows.iter().any(|r| r.patch_plus.is_some()) {
        "per patch"
    } else {
        "per pixel"
    };
    if [m1, m2, m3].iter().any(|e| !e.is_finite()) {
        return format!("ordering ({basis}): not all of M1, M2 auto and M3 ran");
    }
    format!(
        "ordering ({basis}, I+ + I- error): M1 {:.2}% < M2 auto {:.2}% < M3 {:.2}%: {}",
        100.0 * m1,
        100.0 * m2,
        100.0 * m3,
        if m1 < m2 && m2 < m3 {
            "holds"
        } else {
            "does NOT hold"
        }
    )
}
