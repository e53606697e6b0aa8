//! M2: statistics over the segments of one frame (section 6, M2), and an
//! automatic segmentation so nobody has to draw patches by hand.

use super::{input_flags, usable, Moments, SeparationError};
use crate::frame::Frame;
use crate::image::Image;

/// Label of pixels that belong to no segment (output flagged insufficient).
pub const IGNORE_LABEL: u32 = u32::MAX;

/// A label image plus the pixels allowed into each segment's statistics.
#[derive(Debug, Clone, PartialEq)]
pub struct Segmentation {
    pub labels: Image<u32>,
    /// Non-zero where a pixel lies far enough inside its segment to be used
    /// for statistics (blurred edges would add the step between patches to
    /// the variance). Every pixel still receives its segment's estimate.
    pub interior: Image<u8>,
}

/// Mean and unbiased variance (1/(|P|-1)) of the segment P(x) each pixel
/// belongs to, exact two-pass central moments in f64. Saturated and
/// non-finite pixels are left out of their segment's statistics and flagged.
/// `interior`, when given, further restricts which pixels enter the statistics.
pub fn segment_moments(
    frame: &Frame,
    labels: &Image<u32>,
    interior: Option<&Image<u8>>,
) -> Result<Moments, SeparationError> {
    if let Some(m) = interior {
        if !m.same_size(labels) {
            return Err(SeparationError::SizeMismatch {
                want_w: labels.width,
                want_h: labels.height,
                got_w: m.width,
                got_h: m.height,
            });
        }
    }
    let counts = |i: usize| usable(frame, i) && interior.is_none_or(|m| m.data[i] != 0);
    if !frame.dn.same_size(labels) {
        return Err(SeparationError::SizeMismatch {
            want_w: frame.width(),
            want_h: frame.height(),
            got_w: labels.width,
            got_h: labels.height,
        });
    }
    if frame.dn.is_empty() {
        return Err(SeparationError::Empty);
    }
    // Dense segment ids.
    let mut ids: std::collections::HashMap<u32, usize> = Default::default();
    let dense: Vec<usize> = labels
        .data
        .iter()
        .map(|&l| {
            if l == IGNORE_LABEL {
                usize::MAX
            } else {
                let next = ids.len();
                *ids.entry(l).or_insert(next)
            }
        })
        .collect();
    let k = ids.len();
    let mut n = vec![0.0f64; k];
    let mut sum = vec![0.0f64; k];
    for (i, &s) in dense.iter().enumerate() {
        if s != usize::MAX && counts(i) {
            n[s] += 1.0;
            sum[s] += frame.dn.data[i] as f64;
        }
    }
    let mean: Vec<f64> = sum.iter().zip(&n).map(|(s, n)| s / n.max(1.0)).collect();
    let (mut c2, mut c3, mut c4) = (vec![0.0f64; k], vec![0.0f64; k], vec![0.0f64; k]);
    for (i, &s) in dense.iter().enumerate() {
        if s != usize::MAX && counts(i) {
            let d = frame.dn.data[i] as f64 - mean[s];
            let d2 = d * d;
            c2[s] += d2;
            c3[s] += d2 * d;
            c4[s] += d2 * d2;
        }
    }
    let mut out = Moments::new(frame.width(), frame.height());
    for (i, &s) in dense.iter().enumerate() {
        out.flags.data[i] |= input_flags(frame, i);
        if s == usize::MAX || n[s] < 2.0 {
            out.set_insufficient(i);
            continue;
        }
        let ns = n[s];
        out.set_from_central(
            i,
            ns,
            mean[s],
            c2[s] / (ns - 1.0),
            c3[s] / ns,
            Some(c4[s] / ns),
        );
    }
    Ok(out)
}

/// Parameters of [`auto_segment`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentParams {
    /// Half-width of the box filter that denoises before region growing, px.
    pub smooth_radius_px: usize,
    /// A pixel joins a region when its smoothed value is within this many
    /// noise standard deviations (of the smoothed image) of the region mean.
    pub tolerance_sigmas: f64,
    /// Regions smaller than this are merged into their most similar neighbour.
    pub min_pixels: usize,
}

impl Default for SegmentParams {
    fn default() -> Self {
        Self {
            smooth_radius_px: 2,
            tolerance_sigmas: 4.0,
            min_pixels: 16,
        }
    }
}

/// Segments a difference frame into flat regions: box-filter it, estimate the
/// noise from neighbour differences (robust MAD), join 4-neighbours whose
/// smoothed values differ by less than the tolerance (edges of a patch are
/// steeper than that and split it), then merge small regions (the blurred
/// edges themselves) into the neighbouring region with the closest mean. Unusable pixels get [`IGNORE_LABEL`].
///
/// It sees only the difference mu, so two patches with equal I+ - I- but
/// different I+ + I- end up in one segment.
pub fn auto_segment(frame: &Frame, params: SegmentParams) -> Result<Segmentation, SeparationError> {
    let (w, h) = (frame.width(), frame.height());
    if w * h == 0 {
        return Err(SeparationError::Empty);
    }
    let t = params.tolerance_sigmas;
    SeparationError::check("tolerance_sigmas", t, t > 0.0, "> 0")?;
    let smooth = box_mean(frame, params.smooth_radius_px);
    let side = 2 * params.smooth_radius_px + 1;
    let box_n = (side.min(w) * side.min(h)) as f64;
    let sigma = noise_sigma(frame) / box_n.sqrt();
    let tol = (t * sigma).max(0.5 / box_n.sqrt());
    let mut labels = Image::filled(w, h, IGNORE_LABEL);
    let mut sizes: Vec<usize> = Vec::new();
    let mut means: Vec<f64> = Vec::new();
    let mut stack = Vec::new();
    for start in 0..w * h {
        if labels.data[start] != IGNORE_LABEL || !usable(frame, start) {
            continue;
        }
        let id = sizes.len() as u32;
        let (mut n, mut s) = (0usize, 0.0f64);
        labels.data[start] = id;
        stack.push(start);
        while let Some(p) = stack.pop() {
            n += 1;
            s += smooth[p];
            let here = smooth[p];
            let (x, y) = (p % w, p / w);
            let mut visit = |q: usize| {
                if labels.data[q] == IGNORE_LABEL
                    && usable(frame, q)
                    && (smooth[q] - here).abs() <= tol
                {
                    labels.data[q] = id;
                    stack.push(q);
                }
            };
            if x > 0 {
                visit(p - 1);
            }
            if x + 1 < w {
                visit(p + 1);
            }
            if y > 0 {
                visit(p - w);
            }
            if y + 1 < h {
                visit(p + w);
            }
        }
        sizes.push(n);
        means.push(s / n as f64);
    }
    merge_small(&mut labels, &smooth, &sizes, &means, &params);
    let interior = interior_mask(&labels, params.smooth_radius_px + 1, true);
    Ok(Segmentation { labels, interior })
}

/// Pixels whose whole (2 r + 1)^2 neighbourhood carries their own label;
/// with `fill_thin`, segments with fewer than two such pixels use all their pixels.
fn interior_mask(labels: &Image<u32>, r: usize, fill_thin: bool) -> Image<u8> {
    let (w, h) = (labels.width, labels.height);
    let mut mask = Image::filled(w, h, 0u8);
    let mut per_label: std::collections::HashMap<u32, usize> = Default::default();
    for y in 0..h {
        for x in 0..w {
            let l = labels.data[y * w + x];
            let inside = (y.saturating_sub(r)..(y + r + 1).min(h)).all(|yy| {
                (x.saturating_sub(r)..(x + r + 1).min(w)).all(|xx| labels.data[yy * w + xx] == l)
            });
            if inside {
                mask.data[y * w + x] = 1;
                *per_label.entry(l).or_default() += 1;
            }
        }
    }
    for (m, l) in mask.data.iter_mut().zip(&labels.data) {
        if fill_thin && per_label.get(l).copied().unwrap_or(0) < 2 {
            *m = 1;
        }
    }
    mask
}

/// Reassigns pixels of regions that are too small, or too thin to have an
/// interior (the blurred edges between patches), to the adjacent kept region
/// whose mean is closest to the pixel's smoothed value.
fn merge_small(
    labels: &mut Image<u32>,
    smooth: &[f64],
    sizes: &[usize],
    means: &[f64],
    params: &SegmentParams,
) {
    let (w, h) = (labels.width, labels.height);
    let probe = interior_mask(labels, 1, false);
    let mut inner = vec![0usize; sizes.len()];
    for (m, &l) in probe.data.iter().zip(&labels.data) {
        if *m != 0 && l != IGNORE_LABEL {
            inner[l as usize] += 1;
        }
    }
    let mut keep: Vec<bool> = (0..sizes.len())
        .map(|l| sizes[l] >= params.min_pixels && inner[l] >= 2)
        .collect();
    if !keep.iter().any(|&k| k) {
        // Nothing qualifies: keep the largest region(s).
        let max = sizes.iter().copied().max().unwrap_or(0);
        keep = sizes.iter().map(|&s| s == max).collect();
    }
    let kept = |l: u32| l != IGNORE_LABEL && keep[l as usize];
    for _ in 0..w.max(h) {
        let mut changed = false;
        for (p, &here) in smooth.iter().enumerate() {
            let l = labels.data[p];
            if l == IGNORE_LABEL || kept(l) {
                continue;
            }
            let (x, y) = (p % w, p / w);
            let mut best: Option<(f64, u32)> = None;
            let mut consider = |q: usize| {
                let lq = labels.data[q];
                if kept(lq) {
                    let d = (means[lq as usize] - here).abs();
                    if best.is_none_or(|(bd, _)| d < bd) {
                        best = Some((d, lq));
                    }
                }
            };
            if x > 0 {
                consider(p - 1);
            }
            if x + 1 < w {
                consider(p + 1);
            }
            if y > 0 {
                consider(p - w);
            }
            if y + 1 < h {
                consider(p + w);
            }
            if let Some((_, lq)) = best {
                labels.data[p] = lq;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
}

/// Box mean over usable pixels (integral images, f64), radius `r`.
fn box_mean(frame: &Frame, r: usize) -> Vec<f64> {
    let (w, h) = (frame.width(), frame.height());
    let stride = w + 1;
    let mut sum = vec![0.0f64; stride * (h + 1)];
    let mut cnt = vec![0.0f64; stride * (h + 1)];
    for y in 0..h {
        let (mut rs, mut rc) = (0.0, 0.0);
        for x in 0..w {
            let i = y * w + x;
            if usable(frame, i) {
                rs += frame.dn.data[i] as f64;
                rc += 1.0;
            }
            sum[(y + 1) * stride + x + 1] = sum[y * stride + x + 1] + rs;
            cnt[(y + 1) * stride + x + 1] = cnt[y * stride + x + 1] + rc;
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
            let a = |t: &[f64]| {
                t[y1 * stride + x1] - t[y0 * stride + x1] - t[y1 * stride + x0]
                    + t[y0 * stride + x0]
            };
            let c = a(&cnt);
            out[y * w + x] = if c > 0.0 { a(&sum) / c } else { 0.0 };
        }
    }
    out
}

/// Per-pixel noise sigma from horizontal neighbour differences: 1.4826 MAD / sqrt(2).
fn noise_sigma(frame: &Frame) -> f64 {
    let (w, h) = (frame.width(), frame.height());
    let mut d: Vec<f64> = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 1..w {
            let (i, j) = (y * w + x - 1, y * w + x);
            if usable(frame, i) && usable(frame, j) {
                d.push((frame.dn.data[j] as f64 - frame.dn.data[i] as f64).abs());
            }
        }
    }
    if d.is_empty() {
        return 1.0;
    }
    let mid = d.len() / 2;
    let (_, m, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
    (1.4826 * *m / std::f64::consts::SQRT_2).max(0.5)
}
