//! Fast M3 on a bilateral grid (Paris & Durand 2006; Chen, Paris & Durand
//! 2007): O(1) work per pixel, whatever sigma_domain.
//!
//! Every usable pixel is splatted into a grid over (x, y, range): nearest cell
//! in x and y (cells of `s` px), linear in range (levels `z_k = z_0 + k s_r`).
//! Each grid node holds the weighted moments (sum w, sum w (I - z_k),
//! sum w (I - z_k)^2) about its own level, so f32 suffices (values stay within
//! a few s_r) and moving a moment to another level is the exact binomial
//! shift. The grid is blurred with [1 2 1]/4 along range, x and y, then
//! sliced at each pixel (x, y, I) by trilinear interpolation, which gives
//! the paper's M3 statistics with a Gaussian-like weight
//! mu = E_w[I], sigma^2 = E_w[I^2] - E_w[I]^2 (section 6, M3).
//!
//! Effective kernel: box splat (s^2/12) + blur (s^2/2) + bilinear slice
//! (s^2/6) = 0.75 s^2 in each spatial axis, tent + blur + tent = 0.833 s_r^2
//! in range, so the spacings are s = sigma_domain / sqrt(0.75) (at least
//! 1 px) and s_r = sigma_range / sqrt(0.833).
//!
//! The range axis is sparse: each (x, y) cell stores only the levels that
//! pixels within two cells of it occupy (plus one level of padding), which is
//! exactly what blur and slicing ever read, so the result equals the dense
//! grid's while a flat patch costs a handful of levels per cell.
//!
//! Extremes: a sigma_range so large that one level spans 8x the frame's
//! value range disables range weighting (a plain Gaussian, as the exact M3
//! does at infinity); one so small that the frame would need more than
//! [`MAX_LEVELS`] levels is raised to (value range / MAX_LEVELS).
//! Saturated and non-finite pixels are not splatted and are flagged.
//!
//! The effective sample count behind a pixel (for standard errors) is
//! approximated as (m0 / m0 of a flat patch) * 4 pi sigma_eff^2, the
//! Gaussian's (sum w)^2 / sum w^2 scaled by the fraction of the window the
//! range weights keep, and never more than the frame's usable pixels.

use super::bilateral::check_input;
use super::{BilateralParams, LocalMoments, Moments, SeparationError};
use crate::frame::Frame;
use crate::PixelFlags;
use multiversion::multiversion;

/// Largest number of range levels over a frame's value range.
pub const MAX_LEVELS: f32 = 4096.0;

/// Spatial sigma of the grid's kernel in cells (box splat, blur, bilinear slice).
const SPATIAL_SIGMA_CELLS: f32 = 0.866_025_4;
/// Range sigma of the grid's kernel in levels (tent splat, blur, tent slice).
const RANGE_SIGMA_LEVELS: f32 = 0.912_870_9;

/// One grid node: (sum w, sum w d, sum w d^2, unused) with d = I - z_k;
/// four lanes so every node operation is one SIMD operation.
type Node = [f32; 4];

#[inline(always)]
fn axpy(acc: &mut Node, a: f32, x: &Node) {
    for l in 0..4 {
        acc[l] += a * x[l];
    }
}

/// Reusable bilateral-grid M3: keeps its buffers between frames, so a live
/// pipeline allocates nothing after the first frame.
#[derive(Debug, Clone)]
pub struct BilateralGrid {
    /// First level and level count of each (x, y) cell.
    lo: Vec<i32>,
    len: Vec<u32>,
    offset: Vec<usize>,
    /// offset - lo per cell: node index of level k is `base + k`.
    base: Vec<isize>,
    scratch_lo: Vec<i32>,
    scratch_hi: Vec<i32>,
    /// Each pixel's level coordinate (I - z_0) / s_r (0 when flat).
    level: Vec<f32>,
    /// The blurred grid interpolated along y for one output row, and the
    /// node index of level 0 of each cell column in it.
    row_nodes: Vec<Node>,
    row_base: Vec<isize>,
    a: Vec<Node>,
    b: Vec<Node>,
    out: LocalMoments,
}

impl Default for BilateralGrid {
    fn default() -> Self {
        Self::new()
    }
}

/// Where a frame's pixels land in the grid.
struct Geometry {
    /// Cell edge, px.
    s: f32,
    gx: usize,
    gy: usize,
    /// Splat cell of each column and row.
    col_cell: Vec<usize>,
    row_cell: Vec<usize>,
    flat: bool,
    z0: f32,
    sr: f32,
}

impl BilateralGrid {
    pub fn new() -> Self {
        Self {
            lo: Vec::new(),
            len: Vec::new(),
            offset: Vec::new(),
            base: Vec::new(),
            scratch_lo: Vec::new(),
            scratch_hi: Vec::new(),
            level: Vec::new(),
            row_nodes: Vec::new(),
            row_base: Vec::new(),
            a: Vec::new(),
            b: Vec::new(),
            out: LocalMoments::default(),
        }
    }

    /// The moments of the last [`Self::compute`].
    pub fn moments(&self) -> &LocalMoments {
        &self.out
    }

    /// M3 of `frame` (see module docs).
    pub fn compute(
        &mut self,
        frame: &Frame,
        params: BilateralParams,
    ) -> Result<&LocalMoments, SeparationError> {
        check_input(frame, &params)?;
        let (w, h) = (frame.width(), frame.height());
        self.out.ensure_size(w, h);

        // Input flags; a pixel is usable exactly where they are 0. Branch-free
        // (`<` selects compile to min/max instructions), so it vectorizes.
        let (mut vmin, mut vmax) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut usable_px = 0usize;
        for y in 0..h {
            let dn = &frame.dn.data[y * w..][..w];
            let sat = &frame.saturated.data[y * w..][..w];
            let fl = &mut self.out.flags.data[y * w..][..w];
            for x in 0..w {
                let finite = dn[x].is_finite();
                fl[x] = if sat[x] != 0 {
                    PixelFlags::SATURATED.bits()
                } else {
                    0
                } | if finite {
                    0
                } else {
                    PixelFlags::NONFINITE.bits()
                };
                let ok = fl[x] == 0;
                usable_px += ok as usize;
                let (lo, hi) = if ok {
                    (dn[x], dn[x])
                } else {
                    (f32::INFINITY, f32::NEG_INFINITY)
                };
                vmin = if lo < vmin { lo } else { vmin };
                vmax = if hi > vmax { hi } else { vmax };
            }
        }
        if vmin > vmax {
            for i in 0..w * h {
                self.out.set_insufficient(i, 0.0);
            }
            return Ok(&self.out);
        }

        let s = ((params.sigma_domain_px as f32) / SPATIAL_SIGMA_CELLS).max(1.0);
        let spread = (vmax - vmin).max(1.0);
        let sr_wanted = params.sigma_range_dn as f32 / RANGE_SIGMA_LEVELS;
        let flat = sr_wanted >= 8.0 * spread;
        let (z0, sr) = if flat {
            (0.5 * (vmin + vmax), 1.0)
        } else {
            (vmin, sr_wanted.max(spread / MAX_LEVELS))
        };
        let gx = (w as f32 / s).ceil().max(1.0) as usize;
        let gy = (h as f32 / s).ceil().max(1.0) as usize;
        let cell_of = |p: usize, g: usize| (((p as f32 + 0.5) / s) as usize).min(g - 1);
        let geo = Geometry {
            s,
            gx,
            gy,
            col_cell: (0..w).map(|x| cell_of(x, gx)).collect(),
            row_cell: (0..h).map(|y| cell_of(y, gy)).collect(),
            flat,
            z0,
            sr,
        };
        // One branch-free pass (vectorizes); unusable pixels' levels are never read.
        self.level.resize(w * h, 0.0);
        if flat {
            self.level.fill(0.0);
        } else {
            for (t, &v) in self.level.iter_mut().zip(&frame.dn.data) {
                *t = (v - z0) / sr;
            }
        }

        self.layout(w, h, &geo);
        let total = self.offset.last().copied().unwrap_or(0);
        self.splat(frame, &geo, total);
        if !flat {
            self.blur_range(sr);
        } else {
            std::mem::swap(&mut self.a, &mut self.b);
        }
        // b -> a along x, a -> b along y.
        self.blur_cells(gx, gy, true);
        self.blur_cells(gx, gy, false);
        self.slice(frame, &geo, usable_px as f32);
        Ok(&self.out)
    }

    /// Per cell: the levels its own pixels touch, dilated over 5 x 5 cells
    /// and padded by one level (what blur and slicing read).
    fn layout(&mut self, w: usize, h: usize, geo: &Geometry) {
        let (gx, gy) = (geo.gx, geo.gy);
        let cells = gx * gy;
        let (lo, hi) = (&mut self.scratch_lo, &mut self.scratch_hi);
        lo.clear();
        lo.resize(cells, i32::MAX);
        hi.clear();
        hi.resize(cells, i32::MIN);
        let flags = &self.out.flags.data;
        for y in 0..h {
            let row = geo.row_cell[y] * gx;
            let (t, fl) = (&self.level[y * w..][..w], &flags[y * w..][..w]);
            // Runs of columns sharing a cell: min and max in registers, one
            // update per cell and row.
            let mut x = 0;
            while x < w {
                let cx = geo.col_cell[x];
                let (mut kmin, mut kmax) = (i32::MAX, i32::MIN);
                while x < w && geo.col_cell[x] == cx {
                    let k = t[x] as i32;
                    let ok = fl[x] == 0;
                    kmin = if ok { kmin.min(k) } else { kmin };
                    kmax = if ok {
                        kmax.max(k.saturating_add(1))
                    } else {
                        kmax
                    };
                    x += 1;
                }
                let c = row + cx;
                lo[c] = lo[c].min(kmin);
                hi[c] = hi[c].max(kmax);
            }
        }
        dilate(lo, hi, gx, gy);
        self.lo.clear();
        self.len.clear();
        self.offset.clear();
        self.base.clear();
        self.offset.push(0);
        let mut total = 0usize;
        for c in 0..cells {
            let (l, n) = if lo[c] <= hi[c] {
                (lo[c] - 1, (hi[c] - lo[c] + 3) as u32)
            } else {
                (0, 0)
            };
            self.lo.push(l);
            self.len.push(n);
            self.base.push(total as isize - l as isize);
            total += n as usize;
            self.offset.push(total);
        }
    }

    fn splat(&mut self, frame: &Frame, geo: &Geometry, total: usize) {
        let (w, h) = (frame.width(), frame.height());
        let (flat, z0, sr) = (geo.flat, geo.z0, geo.sr);
        self.a.clear();
        self.a.resize(total, [0.0; 4]);
        let a = &mut self.a;
        let flags = &self.out.flags.data;
        for y in 0..h {
            let row = geo.row_cell[y] * geo.gx;
            let (t, fl) = (&self.level[y * w..][..w], &flags[y * w..][..w]);
            let dn = &frame.dn.data[y * w..][..w];
            for (x, &cx) in geo.col_cell.iter().enumerate() {
                if fl[x] != 0 {
                    continue;
                }
                let v = dn[x];
                let base = self.base[row + cx];
                if flat {
                    let d = v - z0;
                    if let Some(n) = a.get_mut(base as usize) {
                        axpy(n, 1.0, &[1.0, d, d * d, 0.0]);
                    }
                    continue;
                }
                let k = t[x] as i32;
                let f = t[x] - k as f32;
                // v - z_k and v - z_{k+1}.
                let d = f * sr;
                let d1 = d - sr;
                let j = (base + k as isize) as usize;
                // Levels k and k + 1 are inside the cell by construction (layout).
                if let Some([n0, n1]) = a.get_mut(j..j + 2) {
                    axpy(n0, 1.0 - f, &[1.0, d, d * d, 0.0]);
                    axpy(n1, f, &[1.0, d1, d1 * d1, 0.0]);
                }
            }
        }
    }

    /// a -> b: [1 2 1]/4 along range within each cell, moments shifted to
    /// each node's level.
    fn blur_range(&mut self, sr: f32) {
        let total = self.a.len();
        // Every node is written below.
        self.b.resize(total, [0.0; 4]);
        let (a, b) = (&self.a, &mut self.b);
        // From the level below, I - z_k = (I - z_{k-1}) - s_r; from above, + s_r.
        let shift = |p: &Node, s: f32| -> Node {
            [
                p[0],
                p[1] + s * p[0],
                p[2] + 2.0 * s * p[1] + s * s * p[0],
                0.0,
            ]
        };
        for c in 0..self.len.len() {
            let (o, n) = (self.offset[c], self.len[c] as usize);
            if n == 0 {
                continue;
            }
            let (src, dst) = (&a[o..o + n], &mut b[o..o + n]);
            for j in 0..n {
                let mut acc = [0.0f32; 4];
                axpy(&mut acc, 0.5, &src[j]);
                if j > 0 {
                    axpy(&mut acc, 0.25, &shift(&src[j - 1], -sr));
                }
                if j + 1 < n {
                    axpy(&mut acc, 0.25, &shift(&src[j + 1], sr));
                }
                dst[j] = acc;
            }
        }
    }

    /// [1 2 1]/4 across cells at equal levels: b -> a along x, then a -> b
    /// along y (call with `along_x` true, then false).
    fn blur_cells(&mut self, gx: usize, gy: usize, along_x: bool) {
        let (src, dst) = if along_x {
            (&self.b, &mut self.a)
        } else {
            (&self.a, &mut self.b)
        };
        // Every node is written below (cells own disjoint ranges).
        dst.resize(src.len(), [0.0; 4]);
        for cy in 0..gy {
            for cx in 0..gx {
                let c = cy * gx + cx;
                let n = self.len[c] as usize;
                if n == 0 {
                    continue;
                }
                let o = self.offset[c];
                for (t, f) in dst[o..o + n].iter_mut().zip(&src[o..o + n]) {
                    *t = [0.5 * f[0], 0.5 * f[1], 0.5 * f[2], 0.0];
                }
                let neighbours = if along_x {
                    [(cx > 0).then(|| c - 1), (cx + 1 < gx).then(|| c + 1)]
                } else {
                    [(cy > 0).then(|| c - gx), (cy + 1 < gy).then(|| c + gx)]
                };
                for q in neighbours.into_iter().flatten() {
                    let nq = self.len[q] as i32;
                    let (l, lq) = (self.lo[c], self.lo[q]);
                    let from = l.max(lq);
                    let to = (l + n as i32).min(lq + nq);
                    if from >= to {
                        continue;
                    }
                    let m = (to - from) as usize;
                    let d = o + (from - l) as usize;
                    let s = self.offset[q] + (from - lq) as usize;
                    for (t, f) in dst[d..d + m].iter_mut().zip(&src[s..s + m]) {
                        axpy(t, 0.25, f);
                    }
                }
            }
        }
    }

    /// Trilinear read of the blurred grid (in `b`) at every pixel.
    fn slice(&mut self, frame: &Frame, geo: &Geometry, usable_px: f32) {
        let (w, h) = (frame.width(), frame.height());
        let (s, gx, gy, flat, z0, sr) = (geo.s, geo.gx, geo.gy, geo.flat, geo.z0, geo.sr);
        let axis = |n: usize, g: usize| -> Vec<(usize, usize, f32)> {
            (0..n)
                .map(|p| {
                    let u = ((p as f32 + 0.5) / s - 0.5).max(0.0);
                    let c0 = (u as usize).min(g - 1);
                    let c1 = (c0 + 1).min(g - 1);
                    (c0, c1, if c1 > c0 { u - c0 as f32 } else { 0.0 })
                })
                .collect()
        };
        let xs = axis(w, gx);
        let ys = axis(h, gy);
        let sigma_eff = s * SPATIAL_SIGMA_CELLS;
        let n_full = 4.0 * std::f32::consts::PI * sigma_eff * sigma_eff;
        let cell_area = s * s;
        let Self {
            b: grid,
            lo,
            len,
            offset,
            level,
            row_nodes,
            row_base,
            out,
            ..
        } = self;
        let xs = &xs[..w];
        // One row of the gathered moments about z_k (q) and z_{k+1} (p),
        // and the level fraction (-1 for unusable input).
        let mut rows = [(); 7].map(|_| vec![0.0f32; w]);
        let stats = RowStats {
            flat,
            z0,
            sr,
            cell_area,
            n_full,
            usable_px,
        };
        for (y, &(cy0, cy1, fy)) in ys.iter().enumerate() {
            // The grid blended along y for this row: per cell column, the
            // union of the two cells' levels (a level a cell lacks is zero).
            row_nodes.clear();
            row_base.clear();
            for cx in 0..gx {
                let (c0, c1) = (cy0 * gx + cx, cy1 * gx + cx);
                let range = |c: usize| (lo[c], lo[c] + len[c] as i32);
                let ((l0, h0), (l1, h1)) = (range(c0), range(c1));
                let (from, to) = match (h0 > l0, h1 > l1) {
                    (true, true) => (l0.min(l1), h0.max(h1)),
                    (true, false) => (l0, h0),
                    (false, true) => (l1, h1),
                    (false, false) => (0, 0),
                };
                row_base.push(row_nodes.len() as isize - from as isize);
                let node = |c: usize, l: i32, kk: i32| {
                    grid.get(offset[c] + (kk - l) as usize)
                        .copied()
                        .unwrap_or([0.0; 4])
                };
                for kk in from..to {
                    let mut acc = [0.0f32; 4];
                    if (l0..h0).contains(&kk) {
                        axpy(&mut acc, 1.0 - fy, &node(c0, l0, kk));
                    }
                    if (l1..h1).contains(&kk) {
                        axpy(&mut acc, fy, &node(c1, l1, kk));
                    }
                    row_nodes.push(acc);
                }
            }
            if row_nodes.len() < 2 {
                row_nodes.resize(2, [0.0; 4]);
            }
            let (nodes, rb) = (&row_nodes[..], &row_base[..gx]);
            // Nodes k and k + 1 at `at` = base of the column + k. Every corner
            // of a usable pixel lies within one cell of its splat cell, whose
            // levels layout dilated over two cells, so both are the column's
            // own nodes. Clamped into the row, so no branch: only unusable
            // pixels (whose output is discarded) can fall outside their column.
            let last = nodes.len() - 2;
            let read2 = |at: isize| -> (Node, Node) {
                let at = (at.max(0) as usize).min(last);
                (nodes[at], nodes[at + 1])
            };
            let t = &level[y * w..][..w];
            let dn = &frame.dn.data[y * w..][..w];
            let mean = &mut out.mean_dn.data[y * w..][..w];
            let var_out = &mut out.variance_dn2.data[y * w..][..w];
            let samples = &mut out.samples.data[y * w..][..w];
            let fl = &mut out.flags.data[y * w..][..w];
            let [q0, q1, q2, p0, p1, p2, fr] = &mut rows;
            let (q0, q1, q2) = (&mut q0[..w], &mut q1[..w], &mut q2[..w]);
            let (p0, p1, p2, fr) = (&mut p0[..w], &mut p1[..w], &mut p2[..w], &mut fr[..w]);
            // Gather: bilinear along x in the blended row at levels k, k + 1.
            for x in 0..w {
                let (cx0, cx1, fx) = xs[x];
                // Saturating: an unusable pixel's level may be infinite or NaN.
                let k = t[x] as i32 as isize;
                let (a0, a1) = read2(rb.get(cx0).copied().unwrap_or(0).saturating_add(k));
                let (b0, b1) = read2(rb.get(cx1).copied().unwrap_or(0).saturating_add(k));
                let (mut q, mut p) = ([0.0f32; 4], [0.0f32; 4]);
                axpy(&mut q, 1.0 - fx, &a0);
                axpy(&mut q, fx, &b0);
                axpy(&mut p, 1.0 - fx, &a1);
                axpy(&mut p, fx, &b1);
                (q0[x], q1[x], q2[x]) = (q[0], q[1], q[2]);
                (p0[x], p1[x], p2[x]) = (p[0], p[1], p[2]);
                fr[x] = if fl[x] != 0 {
                    -1.0
                } else if flat {
                    0.0
                } else {
                    t[x] - (t[x] as i32) as f32
                };
            }
            stats.run([q0, q1, q2, p0, p1, p2, dn], fr, [mean, var_out, samples]);
            for (fl, &good) in fl.iter_mut().zip(&*fr) {
                *fl |= if good > 0.0 {
                    0
                } else {
                    PixelFlags::INSUFFICIENT.bits()
                };
            }
        }
    }
}

/// Per-row conversion of the sliced moments to mean, variance and
/// effective sample count (see [`BilateralGrid::slice`]).
#[derive(Clone, Copy)]
struct RowStats {
    flat: bool,
    z0: f32,
    sr: f32,
    cell_area: f32,
    n_full: f32,
    usable_px: f32,
}

impl RowStats {
    /// `inp`: the moments about z_k (3 rows) and z_{k+1} (3 rows), and the
    /// values; `frac`: the level fraction (-1 for unusable input),
    /// overwritten with 1 where the pixel has statistics and 0 where not.
    fn run(self, inp: [&[f32]; 7], frac: &mut [f32], out: [&mut [f32]; 3]) {
        row_stats(self, inp, frac, out)
    }
}

/// Branch-free along the row, so it vectorizes.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn row_stats(st: RowStats, inp: [&[f32]; 7], frac: &mut [f32], out: [&mut [f32]; 3]) {
    let [q0, q1, q2, p0, p1, p2, dn] = inp;
    let [mean, var_out, samples] = out;
    let n = inp.iter().map(|r| r.len()).fold(frac.len(), usize::min);
    let n = n.min(mean.len()).min(var_out.len()).min(samples.len());
    let (q0, q1, q2, p0, p1, p2, dn) = (
        &q0[..n],
        &q1[..n],
        &q2[..n],
        &p0[..n],
        &p1[..n],
        &p2[..n],
        &dn[..n],
    );
    let (frac, mean, var_out, samples) = (
        &mut frac[..n],
        &mut mean[..n],
        &mut var_out[..n],
        &mut samples[..n],
    );
    for x in 0..n {
        let f = frac[x];
        // Moments about z_k and z_{k+1} moved to the pixel's own value.
        let fc = if f > 0.0 { f } else { 0.0 };
        let (delta, delta1) = if st.flat {
            (st.z0 - dn[x], 0.0)
        } else {
            (-fc * st.sr, (1.0 - fc) * st.sr)
        };
        let (wr, wr1) = if st.flat { (1.0, 0.0) } else { (1.0 - fc, fc) };
        let s0 = wr * q0[x] + wr1 * p0[x];
        let s1 = wr * (q1[x] + delta * q0[x]) + wr1 * (p1[x] + delta1 * p0[x]);
        let s2 = wr * (q2[x] + 2.0 * delta * q1[x] + delta * delta * q0[x])
            + wr1 * (p2[x] + 2.0 * delta1 * p1[x] + delta1 * delta1 * p0[x]);
        let inv = 1.0 / s0;
        let m = s1 * inv;
        let var = s2 * inv - m * m;
        let var = if var > 0.0 { var } else { 0.0 };
        // Range weight of a pixel with itself in a flat patch:
        // ((1 - f)^2 + f^2 + f (1 - f)) / 2.
        let self_range = if st.flat {
            1.0
        } else {
            0.5 * (1.0 - fc + fc * fc)
        };
        let share = s0 / (st.cell_area * self_range);
        let share = if share < 1.0 { share } else { 1.0 };
        let n_eff = share * st.n_full;
        let n_eff = if n_eff < st.usable_px {
            n_eff
        } else {
            st.usable_px
        };
        // Unusable input, no weight or fewer than two samples: no statistics.
        let weighted = f >= 0.0 && s0 > 0.0 && s0 < f32::INFINITY;
        let good = weighted && n_eff >= 2.0 && var < f32::INFINITY;
        mean[x] = if good { dn[x] + m } else { 0.0 };
        var_out[x] = if good { var } else { 0.0 };
        samples[x] = if weighted { n_eff } else { 0.0 };
        frac[x] = if good { 1.0 } else { 0.0 };
    }
}

/// Min of `lo` and max of `hi` over each cell's 5 x 5 neighbourhood (separable).
fn dilate(lo: &mut [i32], hi: &mut [i32], gx: usize, gy: usize) {
    const R: usize = 2;
    let mut tl = lo.to_vec();
    let mut th = hi.to_vec();
    for cy in 0..gy {
        for cx in 0..gx {
            let c = cy * gx + cx;
            let (a, b) = (cx.saturating_sub(R), (cx + R + 1).min(gx));
            let row = cy * gx;
            tl[c] = lo[row + a..row + b]
                .iter()
                .copied()
                .min()
                .unwrap_or(i32::MAX);
            th[c] = hi[row + a..row + b]
                .iter()
                .copied()
                .max()
                .unwrap_or(i32::MIN);
        }
    }
    for cy in 0..gy {
        let (a, b) = (cy.saturating_sub(R), (cy + R + 1).min(gy));
        for cx in 0..gx {
            let c = cy * gx + cx;
            lo[c] = (a..b).map(|yy| tl[yy * gx + cx]).min().unwrap_or(i32::MAX);
            hi[c] = (a..b).map(|yy| th[yy * gx + cx]).max().unwrap_or(i32::MIN);
        }
    }
}

/// One-shot M3 on a bilateral grid (see [`BilateralGrid`] to reuse buffers).
pub fn bilateral_grid(frame: &Frame, params: BilateralParams) -> Result<Moments, SeparationError> {
    let mut grid = BilateralGrid::new();
    Ok(grid.compute(frame, params)?.to_moments())
}
