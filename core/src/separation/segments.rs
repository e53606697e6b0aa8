//! M2: statistics over the segments of one frame (section 6, M2), and an
//! automatic segmentation so nobody has to draw patches by hand.

use super::{input_flags, usable, Moments, SeparationError};
use crate::frame::Frame;
use crate::image::{Image, SizeMismatch};

/// Label of pixels that belong to no segment (output flagged insufficient).
pub const IGNORE_LABEL: u32 = u32::MAX;

/// A segment label read from a float image (an `.npy` or numpy array):
/// a finite, non-negative value below `u32::MAX` truncated to its integer,
/// anything else (NaN, negative, huge) [`IGNORE_LABEL`].
pub fn label_from_f32(v: f32) -> u32 {
    if v.is_finite() && v >= 0.0 && v < u32::MAX as f32 {
        v as u32
    } else {
        IGNORE_LABEL
    }
}

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
        SizeMismatch::check((labels.width, labels.height), (m.width, m.height))?;
    }
    let counts = |i: usize| usable(frame, i) && interior.is_none_or(|m| m.data[i] != 0);
    SizeMismatch::check(
        (frame.width(), frame.height()),
        (labels.width, labels.height),
    )?;
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
    /// Half-width of the box over which the local variance (second feature)
    /// is taken, px; 0 disables the variance feature.
    pub variance_radius_px: usize,
    /// A pixel joins a region only when its local noise level differs from
    /// the region's mean by less than this fraction of that mean.
    pub variance_tolerance_rel: f64,
}

impl Default for SegmentParams {
    fn default() -> Self {
        Self {
            smooth_radius_px: 2,
            tolerance_sigmas: 4.0,
            min_pixels: 16,
            variance_radius_px: 4,
            variance_tolerance_rel: 0.6,
        }
    }
}

/// Segments a difference frame into flat regions: box-filter it, estimate the
/// noise from neighbour differences (robust MAD), grow regions over
/// 4-neighbours whose smoothed value is within the tolerance of the region's
/// running mean (the edge of a patch leaves it and splits the region), then merge small regions (the blurred
/// edges themselves) into the neighbouring region with the closest mean. Unusable pixels get [`IGNORE_LABEL`].
///
/// The difference mu alone cannot tell apart patches with equal I+ - I- but
/// different I+ + I- (the grey row of a colour chart and its black
/// surround), so the local noise level, proportional to the variance
/// g^2 (I+ + I-) + sigma_read^2 (the other half of H), is a second feature:
/// the box mean (radius `variance_radius_px`) of min(dx^2, dy^2) over
/// neighbour differences, which a step along x or y does not inflate. A
/// pixel joins a region only when that feature is within
/// `variance_tolerance_rel` of the region's mean, and small regions merge
/// into the neighbour closest in both features.
pub fn auto_segment(frame: &Frame, params: SegmentParams) -> Result<Segmentation, SeparationError> {
    let (w, h) = (frame.width(), frame.height());
    if w * h == 0 {
        return Err(SeparationError::Empty);
    }
    let t = params.tolerance_sigmas;
    SeparationError::check("tolerance_sigmas", t, t > 0.0, "> 0")?;
    // Radii beyond the image cover the same pixels as max(w, h); clamping
    // keeps `2 r + 1` and `x + r + 1` from overflowing (radius usize::MAX).
    let reach = w.max(h);
    let params = SegmentParams {
        smooth_radius_px: params.smooth_radius_px.min(reach),
        variance_radius_px: params.variance_radius_px.min(reach),
        ..params
    };
    let smooth = box_mean(frame, params.smooth_radius_px);
    let side = 2 * params.smooth_radius_px + 1;
    let box_n = (side.min(w) * side.min(h)) as f64;
    let sigma = noise_sigma(frame) / box_n.sqrt();
    let tol = (t * sigma).max(0.5 / box_n.sqrt());
    let tv = params.variance_tolerance_rel;
    SeparationError::check("variance_tolerance_rel", tv, tv > 0.0, "> 0")?;
    let use_var = params.variance_radius_px > 0;
    let local_var = if use_var {
        noise_feature(frame, params.variance_radius_px)
    } else {
        vec![0.0; w * h]
    };
    let var_rel_se = if use_var { tv } else { 0.0 };
    let var_ok = |v: f64, region_mean: f64| {
        !use_var || (v - region_mean).abs() <= tv * region_mean.max(1e-9)
    };
    let mut labels = Image::filled(w, h, IGNORE_LABEL);
    let mut sizes: Vec<usize> = Vec::new();
    let mut means: Vec<f64> = Vec::new();
    let mut var_means: Vec<f64> = Vec::new();
    let mut stack = Vec::new();
    for start in 0..w * h {
        if labels.data[start] != IGNORE_LABEL || !usable(frame, start) {
            continue;
        }
        let id = sizes.len() as u32;
        let (mut n, mut s) = (0usize, 0.0f64);
        let mut sv = 0.0f64;
        labels.data[start] = id;
        stack.push(start);
        while let Some(p) = stack.pop() {
            n += 1;
            s += smooth[p];
            sv += local_var[p];
            let region_var = sv / n as f64;
            // Against the region's running mean, so a gentle ramp (a blurred
            // step spread over the box) cannot carry a region across an edge.
            let here = s / n as f64;
            let visit = |q: usize| {
                if labels.data[q] == IGNORE_LABEL
                    && usable(frame, q)
                    && (smooth[q] - here).abs() <= tol
                    && var_ok(local_var[q], region_var)
                {
                    labels.data[q] = id;
                    stack.push(q);
                }
            };
            for_each_neighbour(p, w, h, visit);
        }
        sizes.push(n);
        means.push(s / n as f64);
        var_means.push(sv / n as f64);
    }
    // Distances in units of each feature's noise.
    let scale = Features {
        mean: sigma.max(1e-9),
        var_rel: if use_var { var_rel_se } else { 0.0 },
    };
    merge_small(
        &mut labels,
        (&smooth, &local_var),
        (&sizes, &means, &var_means),
        &params,
        scale,
    );
    let interior = interior_mask(&labels, params.smooth_radius_px + 1, true);
    Ok(Segmentation { labels, interior })
}

/// Pixels whose whole (2 r + 1)^2 neighbourhood carries their own label;
/// with `fill_thin`, segments with fewer than two such pixels use all their pixels.
/// Calls `f` with each of pixel `p`'s 4-neighbours inside the `w` x `h`
/// image: left, right, up, down.
#[inline]
fn for_each_neighbour(p: usize, w: usize, h: usize, mut f: impl FnMut(usize)) {
    let (x, y) = (p % w, p / w);
    if x > 0 {
        f(p - 1);
    }
    if x + 1 < w {
        f(p + 1);
    }
    if y > 0 {
        f(p - w);
    }
    if y + 1 < h {
        f(p + w);
    }
}

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
    (smooth, local_var): (&[f64], &[f64]),
    (sizes, means, var_means): (&[usize], &[f64], &[f64]),
    params: &SegmentParams,
    scale: Features,
) {
    let (w, h) = (labels.width, labels.height);
    // Kept regions need an interior at the radius the statistics use.
    let probe = interior_mask(labels, params.smooth_radius_px + 1, false);
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
            let mut best: Option<(f64, u32)> = None;
            let mut consider = |q: usize| {
                let lq = labels.data[q];
                if kept(lq) {
                    let k = lq as usize;
                    let mut d = (means[k] - here).abs() / scale.mean;
                    if scale.var_rel > 0.0 {
                        d += (var_means[k] - local_var[p]).abs()
                            / (scale.var_rel * var_means[k].max(1e-9));
                    }
                    if best.is_none_or(|(bd, _)| d < bd) {
                        best = Some((d, lq));
                    }
                }
            };
            for_each_neighbour(p, w, h, &mut consider);
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

/// Noise scales of the two segmentation features.
#[derive(Debug, Clone, Copy)]
struct Features {
    /// Noise sigma of the smoothed difference, DN.
    mean: f64,
    /// Relative standard error of the local variance (0: feature off).
    var_rel: f64,
}

/// Box mean (radius `r`) of min(dx^2, dy^2), the squared differences to the
/// next pixel along x and y: proportional to the local noise variance
/// (factor about 2 (1 - 2/pi) for Gaussian noise) and blind to a straight
/// step, which shows in only one of the two differences.
fn noise_feature(frame: &Frame, r: usize) -> Vec<f64> {
    let (w, h) = (frame.width(), frame.height());
    let mut e = Frame::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            // Forward differences, backward on the last row/column.
            let jx = if x + 1 < w {
                i + 1
            } else {
                i.saturating_sub(1)
            };
            let jy = if y + 1 < h {
                i + w
            } else {
                i.saturating_sub(w)
            };
            let d = |j: usize| {
                if j != i && usable(frame, i) && usable(frame, j) {
                    let v = frame.dn.data[j] as f64 - frame.dn.data[i] as f64;
                    Some(v * v)
                } else {
                    None
                }
            };
            match (d(jx), d(jy)) {
                (Some(a), Some(b)) => e.dn.data[i] = a.min(b) as f32,
                (Some(a), None) | (None, Some(a)) => e.dn.data[i] = a as f32,
                (None, None) => e.saturated.data[i] = 1,
            }
        }
    }
    box_mean(&e, r)
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

/// Per-pixel noise sigma of one frame from horizontal neighbour differences,
/// 1.4826 MAD / sqrt(2), DN (at least 0.5; 1 when no pair is usable): a
/// noise scale taken from the data alone (M3's range sigma).
pub fn noise_sigma(frame: &Frame) -> f64 {
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
