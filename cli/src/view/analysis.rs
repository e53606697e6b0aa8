//! The page's statistics, computed here so they are tested against numpy:
//! the histogram of a frame's signed DN, a pixel's DN over time (mean and
//! variance) and, for a region, each pixel's temporal variance against its
//! mean with a least-squares line (the paper's noise law, section 5:
//! sigma^2 = g |mu| + sigma_read^2, eq. skellamvar; Fig. exp_variance).

use serde::Serialize;

/// Bins of the histogram.
pub const HISTOGRAM_BINS: usize = 64;
/// Frames a probe or region remembers.
pub const WINDOW_FRAMES: usize = 120;
/// Largest region, pixels (bounds the per-pixel sums).
pub const MAX_REGION_PIXELS: usize = 64 * 64;

/// Counts of finite values in `bins` equal bins over [lo, hi] (numpy's
/// `histogram(x, bins, range=(lo, hi))`: the last bin includes hi).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Histogram {
    pub lo: f64,
    pub hi: f64,
    pub counts: Vec<u64>,
}

impl Histogram {
    /// Over the finite extremes of `values` (a single value gets a unit range).
    pub fn of(values: &[f32], bins: usize) -> Self {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &v in values.iter().filter(|v| v.is_finite()) {
            lo = lo.min(f64::from(v));
            hi = hi.max(f64::from(v));
        }
        if lo > hi {
            (lo, hi) = (0.0, 1.0);
        } else if lo == hi {
            (lo, hi) = (lo - 0.5, hi + 0.5);
        }
        let mut counts = vec![0u64; bins.max(1)];
        let last = counts.len() - 1;
        let scale = counts.len() as f64 / (hi - lo);
        for &v in values.iter().filter(|v| v.is_finite()) {
            let i = ((f64::from(v) - lo) * scale) as usize;
            counts[i.min(last)] += 1;
        }
        Self { lo, hi, counts }
    }
}

/// Mean and sample variance (ddof = 1, numpy's `var(x, ddof=1)`); the
/// variance is 0 for fewer than two values.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Moments {
    pub n: usize,
    pub mean: f64,
    pub variance: f64,
}

impl Moments {
    /// Two-pass: exact enough for DN in f32 over a short window.
    pub fn of(values: impl Iterator<Item = f64> + Clone) -> Self {
        let (n, sum) = values
            .clone()
            .fold((0usize, 0.0), |(n, s), v| (n + 1, s + v));
        if n == 0 {
            return Self::default();
        }
        let mean = sum / n as f64;
        let ss: f64 = values.map(|v| (v - mean) * (v - mean)).sum();
        let variance = if n > 1 { ss / (n - 1) as f64 } else { 0.0 };
        Self { n, mean, variance }
    }
}

/// Least-squares line y = slope x + intercept (numpy's `polyfit(x, y, 1)`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LineFit {
    pub slope: f64,
    pub intercept: f64,
}

impl LineFit {
    /// None for fewer than two points or when every x is the same.
    pub fn of(points: &[(f64, f64)]) -> Option<Self> {
        let n = points.len() as f64;
        if points.len() < 2 {
            return None;
        }
        let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
        let my = points.iter().map(|p| p.1).sum::<f64>() / n;
        let sxx: f64 = points.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
        let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        if sxx <= 0.0 || !sxx.is_finite() {
            return None;
        }
        let slope = sxy / sxx;
        Some(Self {
            slope,
            intercept: my - slope * mx,
        })
    }
}

/// A clicked pixel's DN over the last [`WINDOW_FRAMES`] frames.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Probe {
    pub x: usize,
    pub y: usize,
    pub values: Vec<f32>,
    pub moments: Moments,
}

impl Probe {
    pub fn new(x: usize, y: usize) -> Self {
        Self {
            x,
            y,
            values: Vec::new(),
            moments: Moments::default(),
        }
    }

    /// Adds the probed pixel of a `width`-wide frame; a pixel outside it is skipped.
    pub fn push(&mut self, dn: &[f32], width: usize) {
        // The coordinates come from the page: no arithmetic may overflow.
        let index = self
            .y
            .checked_mul(width)
            .and_then(|i| i.checked_add(self.x));
        let Some(&v) = index.filter(|_| self.x < width).and_then(|i| dn.get(i)) else {
            return;
        };
        if self.values.len() == WINDOW_FRAMES {
            self.values.remove(0);
        }
        self.values.push(v);
        self.moments = Moments::of(self.values.iter().map(|&v| f64::from(v)));
    }
}

/// A rectangle of pixels, each with its DN over the last frames: the
/// variance-against-mean points and their line.
#[derive(Debug, Clone, PartialEq)]
pub struct Region {
    pub x0: usize,
    pub y0: usize,
    pub width: usize,
    pub height: usize,
    /// Per frame, the region's pixels row by row.
    frames: Vec<Vec<f32>>,
}

/// What the page plots for a region.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RegionReport {
    pub frames: usize,
    /// (mean, variance) of each pixel over the frames, DN and DN^2.
    pub points: Vec<(f64, f64)>,
    pub fit: Option<LineFit>,
}

impl Region {
    /// The region, cut to [`MAX_REGION_PIXELS`] by shrinking its height.
    pub fn new(x0: usize, y0: usize, width: usize, height: usize) -> Self {
        let width = width.clamp(1, MAX_REGION_PIXELS);
        let height = height.clamp(1, MAX_REGION_PIXELS / width);
        Self {
            x0,
            y0,
            width,
            height,
            frames: Vec::new(),
        }
    }

    /// Adds the region's pixels of a frame; a frame it does not fit in is skipped.
    pub fn push(&mut self, dn: &[f32], frame_width: usize, frame_height: usize) {
        if self.x0.saturating_add(self.width) > frame_width
            || self.y0.saturating_add(self.height) > frame_height
        {
            return;
        }
        if self.frames.len() == WINDOW_FRAMES {
            self.frames.remove(0);
        }
        let mut cut = Vec::with_capacity(self.width * self.height);
        for row in self.y0..self.y0 + self.height {
            let start = row * frame_width + self.x0;
            cut.extend_from_slice(&dn[start..start + self.width]);
        }
        self.frames.push(cut);
    }

    /// Each pixel's temporal (mean, variance) with |mean| on the x axis:
    /// the noise law is in the magnitude of the difference (eq. skellamvar).
    pub fn report(&self) -> RegionReport {
        let pixels = self.width * self.height;
        let points: Vec<(f64, f64)> = (0..pixels)
            .map(|i| Moments::of(self.frames.iter().map(move |f| f64::from(f[i]))))
            .filter(|m| m.n > 1 && m.mean.is_finite() && m.variance.is_finite())
            .map(|m| (m.mean.abs(), m.variance))
            .collect();
        RegionReport {
            frames: self.frames.len(),
            fit: LineFit::of(&points),
            points,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// numpy: np.histogram([-2, -1, 0, 1, 2, 2, nan], 4, range=(-2, 2)) -> [1, 1, 1, 3]
    #[test]
    fn histogram_bins_as_numpy() {
        let h = Histogram::of(&[-2.0, -1.0, 0.0, 1.0, 2.0, 2.0, f32::NAN], 4);
        assert_eq!((h.lo, h.hi), (-2.0, 2.0));
        assert_eq!(h.counts, vec![1, 1, 1, 3]);
        assert_eq!(Histogram::of(&[], 3).counts, vec![0, 0, 0]);
        assert_eq!(Histogram::of(&[5.0], 2).counts, vec![0, 1]);
    }

    /// numpy: x = [1, 2, 4, 7]; x.mean() = 3.5, x.var(ddof=1) = 7.0
    #[test]
    fn moments_as_numpy() {
        let m = Moments::of([1.0, 2.0, 4.0, 7.0].into_iter());
        assert_eq!((m.n, m.mean, m.variance), (4, 3.5, 7.0));
        assert_eq!(Moments::of([3.0].into_iter()).variance, 0.0);
    }

    /// numpy: np.polyfit([0, 1, 2, 3], [1, 3, 7, 9], 1) -> [2.8, 0.8]
    #[test]
    fn line_fit_as_numpy() {
        let f = LineFit::of(&[(0.0, 1.0), (1.0, 3.0), (2.0, 7.0), (3.0, 9.0)]).unwrap();
        assert!((f.slope - 2.8).abs() < 1e-12 && (f.intercept - 0.8).abs() < 1e-12);
        assert!(LineFit::of(&[(1.0, 1.0), (1.0, 2.0)]).is_none());
    }

    #[test]
    fn probe_and_region_follow_the_frames() {
        let mut probe = Probe::new(1, 1);
        let mut region = Region::new(0, 0, 2, 1);
        for k in 0..WINDOW_FRAMES + 5 {
            let v = k as f32;
            let frame = [v, 2.0 * v, 0.0, v];
            probe.push(&frame, 2);
            region.push(&frame, 2, 2);
        }
        assert_eq!(probe.values.len(), WINDOW_FRAMES);
        assert_eq!(probe.values[0], 5.0);
        let r = region.report();
        assert_eq!((r.frames, r.points.len()), (WINDOW_FRAMES, 2));
        // pixel 1 is twice pixel 0: mean x2, variance x4
        assert!((r.points[1].0 - 2.0 * r.points[0].0).abs() < 1e-9);
        assert!((r.points[1].1 - 4.0 * r.points[0].1).abs() < 1e-6);
        let mut outside = Probe::new(9, 0);
        outside.push(&[1.0], 1);
        assert!(outside.values.is_empty());
        let mut huge = Probe::new(usize::MAX, usize::MAX);
        huge.push(&[1.0], 1);
        assert!(huge.values.is_empty());
        let mut huge = Region::new(usize::MAX, usize::MAX, 4, 4);
        huge.push(&[1.0; 4], 2, 2);
        assert_eq!(huge.report().frames, 0);
        let big = Region::new(0, 0, 1000, 1000);
        assert!(big.width * big.height <= MAX_REGION_PIXELS);
    }
}
