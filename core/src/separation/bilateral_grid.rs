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
    /// Each pixel's level coordinate (I - z_0) / s_r as its level k
    /// (saturating) and the fraction above it (both 0 when flat).
    level_k: Vec<i32>,
    level_frac: Vec<f32>,
    /// The pair of cell rows an output row blends (see
    /// [`CellLevels::pair_rows`]), the blend for one output row (flat
    /// nodes), the node index of level 0 of each cell column in both, and
    /// the row's gathered moments.
    pair_a: Vec<f32>,
    pair_d: Vec<f32>,
    row_nodes: Vec<f32>,
    row_base: Vec<isize>,
    gathered: Vec<[f32; 8]>,
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
    /// The columns in splat order: the first column of every cell, then the
    /// second, ...: consecutive pixels add to different nodes, so no add
    /// waits for the previous one's store.
    splat_order: Vec<usize>,
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
            level_k: Vec::new(),
            level_frac: Vec::new(),
            pair_a: Vec::new(),
            pair_d: Vec::new(),
            row_nodes: Vec::new(),
            row_base: Vec::new(),
            gathered: Vec::new(),
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
        let col_cell: Vec<usize> = (0..w).map(|x| cell_of(x, gx)).collect();
        let geo = Geometry {
            s,
            gx,
            gy,
            splat_order: interleaved_cells(&col_cell),
            col_cell,
            row_cell: (0..h).map(|y| cell_of(y, gy)).collect(),
            flat,
            z0,
            sr,
        };
        // One branch-free pass (vectorizes); unusable pixels' levels are never read.
        self.level_k.resize(w * h, 0);
        self.level_frac.resize(w * h, 0.0);
        if flat {
            self.level_k.fill(0);
            self.level_frac.fill(0.0);
        } else {
            levels(
                &frame.dn.data,
                z0,
                sr,
                &mut self.level_k,
                &mut self.level_frac,
            );
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
        layout_mv(self, w, h, geo)
    }

    #[inline(always)]
    fn layout_body(&mut self, w: usize, h: usize, geo: &Geometry) {
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
            let (ks, fl) = (&self.level_k[y * w..][..w], &flags[y * w..][..w]);
            // Runs of columns sharing a cell: min and max in registers, one
            // update per cell and row.
            let mut x = 0;
            while x < w {
                let cx = geo.col_cell[x];
                let (mut kmin, mut kmax) = (i32::MAX, i32::MIN);
                while x < w && geo.col_cell[x] == cx {
                    let k = ks[x];
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
        splat_mv(self, frame, geo, total)
    }

    #[inline(always)]
    fn splat_body(&mut self, frame: &Frame, geo: &Geometry, total: usize) {
        let (w, h) = (frame.width(), frame.height());
        let (flat, z0, sr) = (geo.flat, geo.z0, geo.sr);
        self.a.clear();
        self.a.resize(total, [0.0; 4]);
        let a = &mut self.a;
        let flags = &self.out.flags.data;
        for y in 0..h {
            let row = geo.row_cell[y] * geo.gx;
            let (ks, fr, fl) = (
                &self.level_k[y * w..][..w],
                &self.level_frac[y * w..][..w],
                &flags[y * w..][..w],
            );
            let dn = &frame.dn.data[y * w..][..w];
            for &x in &geo.splat_order {
                let cx = geo.col_cell[x];
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
                let (k, f) = (ks[x], fr[x]);
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
        blur_range_mv(self, sr)
    }

    #[inline(always)]
    fn blur_range_body(&mut self, sr: f32) {
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
        blur_cells_mv(self, gx, gy, along_x)
    }

    #[inline(always)]
    fn blur_cells_body(&mut self, gx: usize, gy: usize, along_x: bool) {
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

    /// Trilinear read of the blurred grid (in `b`) at every pixel: per
    /// output row, the grid blended along y (from the row's pair of cell
    /// rows, gathered once per pair), then per pixel a bilinear read along x
    /// of levels k and k + 1 (two adjacent nodes, one 8-lane operation), then
    /// the statistics.
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
            level_k,
            level_frac,
            pair_a,
            pair_d,
            row_nodes,
            row_base,
            gathered,
            out,
            ..
        } = self;
        let xs = &xs[..w];
        let fx: Vec<f32> = xs.iter().map(|&(_, _, f)| f).collect();
        // Node index of level 0 at each pixel's two cell columns.
        let (mut at_a, mut at_b) = (vec![0isize; w], vec![0isize; w]);
        gathered.resize(w, [0.0; 8]);
        let stats = RowStats {
            flat,
            z0,
            sr,
            cell_area,
            n_full,
            usable_px,
        };
        let cells = CellLevels {
            grid,
            lo,
            len,
            offset,
        };
        let mut pair = None;
        for (y, &(cy0, cy1, fy)) in ys.iter().enumerate() {
            if pair != Some((cy0, cy1)) {
                pair = Some((cy0, cy1));
                cells.pair_rows(gx, cy0, cy1, pair_a, pair_d, row_base);
                for (x, &(cx0, cx1, _)) in xs.iter().enumerate() {
                    (at_a[x], at_b[x]) = (row_base[cx0], row_base[cx1]);
                }
            }
            row_nodes.resize(pair_a.len(), 0.0);
            blend_row(row_nodes, pair_a, pair_d, fy);
            let (ks, fr) = (&level_k[y * w..][..w], &level_frac[y * w..][..w]);
            gather_row(row_nodes, [&at_a, &at_b], &fx, (ks, fr), gathered);
            let dn = &frame.dn.data[y * w..][..w];
            let at = y * w;
            stats.run(
                gathered,
                dn,
                &mut out.flags.data[at..][..w],
                [
                    &mut out.mean_dn.data[at..][..w],
                    &mut out.variance_dn2.data[at..][..w],
                    &mut out.samples.data[at..][..w],
                ],
            );
        }
    }
}

/// The blurred grid's sparse cells, for slicing.
struct CellLevels<'a> {
    grid: &'a [Node],
    lo: &'a [i32],
    len: &'a [u32],
    offset: &'a [usize],
}

impl CellLevels<'_> {
    /// Cell rows `cy0` and `cy1` laid side by side for blending along y: per
    /// cell column the union of the two cells' levels (a level a cell lacks
    /// is zero), as flat nodes of row `cy0` (`a`) and of row `cy1` minus
    /// row `cy0` (`d`); `base` is the node index of level 0 of each column.
    /// At least two nodes.
    fn pair_rows(
        &self,
        gx: usize,
        cy0: usize,
        cy1: usize,
        a: &mut Vec<f32>,
        d: &mut Vec<f32>,
        base: &mut Vec<isize>,
    ) {
        a.clear();
        d.clear();
        base.clear();
        let node = |c: usize, kk: i32| -> Node {
            let l = self.lo[c];
            if (l..l + self.len[c] as i32).contains(&kk) {
                self.grid
                    .get(self.offset[c] + (kk - l) as usize)
                    .copied()
                    .unwrap_or([0.0; 4])
            } else {
                [0.0; 4]
            }
        };
        for cx in 0..gx {
            let (c0, c1) = (cy0 * gx + cx, cy1 * gx + cx);
            let range = |c: usize| (self.lo[c], self.lo[c] + self.len[c] as i32);
            let ((l0, h0), (l1, h1)) = (range(c0), range(c1));
            let (from, to) = match (h0 > l0, h1 > l1) {
                (true, true) => (l0.min(l1), h0.max(h1)),
                (true, false) => (l0, h0),
                (false, true) => (l1, h1),
                (false, false) => (0, 0),
            };
            base.push((a.len() / 4) as isize - from as isize);
            for kk in from..to {
                let (n0, n1) = (node(c0, kk), node(c1, kk));
                a.extend_from_slice(&n0);
                d.extend((0..4).map(|l| n1[l] - n0[l]));
            }
        }
        if a.len() < 8 {
            a.resize(8, 0.0);
            d.resize(8, 0.0);
        }
    }
}

/// One output row's grid: `a + fy d` (see [`CellLevels::pair_rows`]).
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn blend_row(row: &mut [f32], a: &[f32], d: &[f32], fy: f32) {
    for ((r, &a), &d) in row.iter_mut().zip(a).zip(d) {
        *r = a + fy * d;
    }
}

/// Bilinear read along x of nodes k and k + 1 (adjacent in `nodes`, flat
/// 4 floats each) for every pixel of a row: moments about z_k in lanes
/// 0..3, about z_{k+1} in lanes 4..7, and the level fraction in lane 3.
/// `at` holds the node index of level 0 at each pixel's two cell columns,
/// `level` each pixel's level k and fraction. Every corner of a usable pixel lies
/// within one cell of its splat cell, whose levels layout dilated over two
/// cells, so both nodes are the column's own. Clamped into the row, so no
/// branch: only unusable pixels (whose output is discarded) can fall
/// outside their column.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn gather_row(
    nodes: &[f32],
    at: [&[isize]; 2],
    fx: &[f32],
    level: (&[i32], &[f32]),
    out: &mut [[f32; 8]],
) {
    let [at_a, at_b] = at;
    let (ks, fr) = level;
    let last = (nodes.len() / 4).saturating_sub(2);
    let read = |at: isize| -> &[f32] {
        let at = (at.max(0) as usize).min(last);
        &nodes[4 * at..][..8]
    };
    let n = [
        at_a.len(),
        at_b.len(),
        fx.len(),
        ks.len(),
        fr.len(),
        out.len(),
    ]
    .into_iter()
    .min()
    .unwrap_or(0);
    for x in 0..n {
        // i32 to isize: no overflow whatever an unusable pixel's level.
        let k = ks[x] as isize;
        let a = read(at_a[x] + k);
        let b = read(at_b[x] + k);
        let o = &mut out[x];
        for l in 0..8 {
            o[l] = a[l] + fx[x] * (b[l] - a[l]);
        }
        // Lane 3 (unused by the moments): the level fraction.
        o[3] = fr[x];
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
    /// `gathered`: per pixel the moments about z_k and z_{k+1} and the
    /// level fraction (see [`gather_row`]), `dn` the values; `flags` the input flags, to which
    /// INSUFFICIENT is added where a pixel has no statistics.
    fn run(self, gathered: &[[f32; 8]], dn: &[f32], flags: &mut [u8], out: [&mut [f32]; 3]) {
        row_stats(self, gathered, dn, flags, out)
    }
}

/// Branch-free along the row, so it vectorizes.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn row_stats(
    st: RowStats,
    gathered: &[[f32; 8]],
    dn: &[f32],
    flags: &mut [u8],
    out: [&mut [f32]; 3],
) {
    let [mean, var_out, samples] = out;
    let n = gathered
        .len()
        .min(dn.len())
        .min(flags.len())
        .min(mean.len())
        .min(var_out.len())
        .min(samples.len());
    let (gathered, dn, flags) = (&gathered[..n], &dn[..n], &mut flags[..n]);
    let (mean, var_out, samples) = (&mut mean[..n], &mut var_out[..n], &mut samples[..n]);
    for x in 0..n {
        let g = &gathered[x];
        let (q0, q1, q2, p0, p1, p2) = (g[0], g[1], g[2], g[4], g[5], g[6]);
        let usable = flags[x] == 0;
        // The level fraction (NaN for an unusable pixel's NaN level: 0).
        let f = g[3];
        let fc = if usable && !st.flat && f > 0.0 {
            f
        } else {
            0.0
        };
        // Moments about z_k and z_{k+1} moved to the pixel's own value.
        let (delta, delta1) = if st.flat {
            (st.z0 - dn[x], 0.0)
        } else {
            (-fc * st.sr, (1.0 - fc) * st.sr)
        };
        let (wr, wr1) = if st.flat { (1.0, 0.0) } else { (1.0 - fc, fc) };
        let s0 = wr * q0 + wr1 * p0;
        let s1 = wr * (q1 + delta * q0) + wr1 * (p1 + delta1 * p0);
        let s2 = wr * (q2 + 2.0 * delta * q1 + delta * delta * q0)
            + wr1 * (p2 + 2.0 * delta1 * p1 + delta1 * delta1 * p0);
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
        let weighted = usable && s0 > 0.0 && s0 < f32::INFINITY;
        let good = weighted && n_eff >= 2.0 && var < f32::INFINITY;
        mean[x] = if good { dn[x] + m } else { 0.0 };
        var_out[x] = if good { var } else { 0.0 };
        samples[x] = if weighted { n_eff } else { 0.0 };
        flags[x] |= if good {
            0
        } else {
            PixelFlags::INSUFFICIENT.bits()
        };
    }
}

/// Level k and fraction of each value (see [`BilateralGrid::compute`]),
/// saturating for unusable pixels, whose levels are never used.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn levels(dn: &[f32], z0: f32, sr: f32, level_k: &mut [i32], level_frac: &mut [f32]) {
    for ((k, f), &v) in level_k.iter_mut().zip(level_frac.iter_mut()).zip(dn) {
        let t = (v - z0) / sr;
        *k = t as i32;
        *f = t - *k as f32;
    }
}

/// [`BilateralGrid::layout`] compiled for the CPU found at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn layout_mv(g: &mut BilateralGrid, w: usize, h: usize, geo: &Geometry) {
    g.layout_body(w, h, geo);
}

/// [`BilateralGrid::splat`] compiled for the CPU found at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn splat_mv(g: &mut BilateralGrid, frame: &Frame, geo: &Geometry, total: usize) {
    g.splat_body(frame, geo, total);
}

/// [`BilateralGrid::blur_range`] compiled for the CPU found at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn blur_range_mv(g: &mut BilateralGrid, sr: f32) {
    g.blur_range_body(sr);
}

/// [`BilateralGrid::blur_cells`] compiled for the CPU found at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn blur_cells_mv(g: &mut BilateralGrid, gx: usize, gy: usize, along_x: bool) {
    g.blur_cells_body(gx, gy, along_x);
}

/// The indices of `cells` (ascending cell numbers) ordered by their rank
/// within their cell, then by cell.
fn interleaved_cells(cells: &[usize]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..cells.len()).collect();
    let mut start = 0;
    let rank: Vec<usize> = (0..cells.len())
        .map(|x| {
            if x > 0 && cells[x] != cells[x - 1] {
                start = x;
            }
            x - start
        })
        .collect();
    order.sort_by_key(|&x| (rank[x], cells[x]));
    order
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
