//! Fast M3, separable approximation, O(r) per pixel: a horizontal pass
//! gathers weighted moments along rows, a vertical pass combines them with
//! the range weight between column neighbours, i.e. the 2-D range weight
//! w_r(I(x+dx, y+dy) - I(x, y)) is replaced by
//! w_r(I(x+dx, y+dy) - I(x, y+dy)) w_r(I(x, y+dy) - I(x, y)).
//!
//! Moments are kept about each pixel's own value (shifted when combined), so
//! f32 is enough. Each pair's range weight is evaluated once for both of its
//! pixels, in both passes; horizontal moments live in a ring of 2r+1 rows
//! that stays in cache; the horizontal pass gathers blocks of [`LANES`]
//! pixels whose accumulators stay in registers over all taps, the vertical
//! pass runs along whole rows. The loops are branch-free and compiled for
//! AVX2+FMA and SSE4.1 with run-time selection, since the daemon is not
//! built for one CPU.
//! Saturated and non-finite pixels get zero weight and are flagged.

use multiversion::multiversion;

use super::bilateral::check_input;
use super::fast_exp::{exp2_neg, madd};
use super::{BilateralParams, LocalMoments, SeparationError};
use crate::frame::Frame;
use crate::PixelFlags;

/// Pixels per block of the horizontal pass (32 measured fastest of 8 to 64
/// with AVX2; 64 with AVX-512, whose 32 registers hold the accumulators).
const LANES: usize = 32;
const LANES_AVX512: usize = 64;
/// Pixels per block of the vertical pass with AVX-512 (about 10% faster
/// than row-wide loops at sigma_d 3; with AVX2 and SSE row-wide loops are
/// faster).
const VERTICAL_BLOCK_AVX512: usize = 32;

/// Reusable separable M3: keeps its buffers between frames.
#[derive(Debug, Clone, Default)]
pub struct SeparableBilateral {
    /// The frame, rows padded by r zeros each side, 0 where unusable; and
    /// 1/0 usability (0 in the padding), same layout.
    value: Vec<f32>,
    valid: Vec<f32>,
    /// Horizontal moments of 2r+1 rows: per row m0 | m1 | m2 | mb (sum w,
    /// sum w d, sum w d^2, sum w^2 with d = I' - I).
    ring: Vec<f32>,
    /// The vertical pass's sums for one row: s0 | s1 | s2 | q.
    sums: Vec<f32>,
    /// Pair weights along the current row: r rows of (w + r), entry p of
    /// row dx - 1 for the pixels at padded columns p and p + dx.
    row_pairs: Vec<f32>,
    /// Pair weights down the columns: r x (2r+1) rows of w, entry x of
    /// [dy - 1][y mod (2r+1)] for the pixels (x, y) and (x, y + dy); then a
    /// row of zeros.
    column_pairs: Vec<f32>,
    out: LocalMoments,
}

impl SeparableBilateral {
    pub fn new() -> Self {
        Self::default()
    }

    /// The result of the last [`Self::compute`].
    pub fn moments(&self) -> &LocalMoments {
        &self.out
    }

    /// M3 of `frame` (see module docs).
    pub fn compute(
        &mut self,
        frame: &Frame,
        params: BilateralParams,
    ) -> Result<&LocalMoments, SeparationError> {
        self.compute_with(frame, params, run)
    }

    fn compute_with(
        &mut self,
        frame: &Frame,
        params: BilateralParams,
        run: fn(&mut Kernel),
    ) -> Result<&LocalMoments, SeparationError> {
        check_input(frame, &params)?;
        let (w, h) = (frame.width(), frame.height());
        let r = params.radius_on(w, h);
        let stride = w + 2 * r;
        let slots = (2 * r + 1).min(h);
        self.out.ensure_size(w, h);
        self.value.resize(stride * h, 0.0);
        self.valid.resize(stride * h, 0.0);
        self.ring.resize(slots * 4 * w, 0.0);
        self.sums.resize(4 * w, 0.0);
        self.row_pairs.resize(r * (w + r), 0.0);
        // Plus one row of zeros: the pair weights beyond the frame.
        self.column_pairs.resize((r * slots + 1) * w, 0.0);
        // Weights as powers of two: w_d w_r = 2^-(dist^2 k_d + d^2 k), with
        // -log2 w_d per offset and k = log2(e) / (2 sigma_range^2), finite even
        // when sigma_range underflows, so d = 0 always gives w_r = 1.
        let domain: Vec<f32> = params
            .domain_weights(r)
            .iter()
            .map(|&v| (-v.log2()) as f32)
            .collect();
        let k = (std::f64::consts::LOG2_E * 0.5 / (params.sigma_range_dn * params.sigma_range_dn))
            .min(1e30) as f32;
        let mut kernel = Kernel {
            w,
            h,
            r,
            slots,
            k,
            domain: &domain,
            frame,
            value: &mut self.value,
            valid: &mut self.valid,
            ring: &mut self.ring,
            sums: &mut self.sums,
            row_pairs: &mut self.row_pairs,
            column_pairs: &mut self.column_pairs,
            out: &mut self.out,
        };
        run(&mut kernel);
        Ok(&self.out)
    }
}

/// One frame's inputs and buffers for [`run`].
struct Kernel<'a> {
    w: usize,
    h: usize,
    r: usize,
    slots: usize,
    /// log2(e) / (2 sigma_range^2).
    k: f32,
    /// -log2 of the domain weights for offsets 0..=r.
    domain: &'a [f32],
    frame: &'a Frame,
    value: &'a mut [f32],
    valid: &'a mut [f32],
    ring: &'a mut [f32],
    sums: &'a mut [f32],
    row_pairs: &'a mut [f32],
    column_pairs: &'a mut [f32],
    out: &'a mut LocalMoments,
}

/// The whole frame: padded input, then row by row the horizontal pass
/// (r rows ahead) and the vertical pass.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "x86_64+sse4.1"
))]
fn run(kn: &mut Kernel) {
    const FMA: bool = multiversion::target::target_cfg_f!(target_feature = "fma");
    const AVX512: bool = multiversion::target::target_cfg_f!(target_feature = "avx512f");
    if AVX512 {
        run_with::<FMA, LANES_AVX512, VERTICAL_BLOCK_AVX512>(kn);
    } else {
        run_with::<FMA, LANES, 1>(kn);
    }
}

#[inline(always)]
fn run_with<const FMA: bool, const N: usize, const B: usize>(kn: &mut Kernel) {
    prepare(kn);
    let (h, r) = (kn.h, kn.r);
    let mut next = 0;
    let mut taps = Vec::with_capacity(2 * r);
    for y in 0..h {
        while next <= (y + r).min(h - 1) {
            horizontal::<FMA, N>(kn, next);
            next += 1;
        }
        column_taps::<FMA>(kn, y, &mut taps);
        vertical::<FMA, B>(kn, y, &taps);
    }
}

/// Padded value and usability rows, and the input flags.
#[inline(always)]
fn prepare(kn: &mut Kernel) {
    let (w, r) = (kn.w, kn.r);
    let stride = w + 2 * r;
    for y in 0..kn.h {
        let dn = &kn.frame.dn.data[y * w..][..w];
        let sat = &kn.frame.saturated.data[y * w..][..w];
        let fl = &mut kn.out.flags.data[y * w..][..w];
        let v = &mut kn.value[y * stride..][..stride];
        let ok = &mut kn.valid[y * stride..][..stride];
        v[..r].fill(0.0);
        v[r + w..].fill(0.0);
        ok[..r].fill(0.0);
        ok[r + w..].fill(0.0);
        let (v, ok) = (&mut v[r..r + w], &mut ok[r..r + w]);
        for x in 0..w {
            let finite = dn[x].is_finite();
            let unsaturated = sat[x] == 0;
            let good = finite && unsaturated;
            v[x] = if good { dn[x] } else { 0.0 };
            ok[x] = if good { 1.0 } else { 0.0 };
            fl[x] = if unsaturated {
                0
            } else {
                PixelFlags::SATURATED.bits()
            } | if finite {
                0
            } else {
                PixelFlags::NONFINITE.bits()
            };
        }
    }
}

/// Row moments of row `y` into its ring slot: each pair's range weight is
/// evaluated once, then every pixel gathers its 2r+1 taps block by block.
#[inline(always)]
fn horizontal<const FMA: bool, const N: usize>(kn: &mut Kernel, y: usize) {
    let (w, r, k) = (kn.w, kn.r, kn.k);
    let stride = w + 2 * r;
    let v = &kn.value[y * stride..][..stride];
    let ok = &kn.valid[y * stride..][..stride];
    for dx in 1..=r {
        let kd = kn.domain[dx];
        let e = &mut kn.row_pairs[(dx - 1) * (w + r)..][..w + r];
        let (here, there) = (&v[..w + r], &v[dx..][..w + r]);
        let (ok_here, ok_there) = (&ok[..w + r], &ok[dx..][..w + r]);
        // Zero unless both pixels are usable: an unusable pixel gets zero
        // moments, so the vertical pass needs no mask.
        let pair = |p: usize| {
            let d = there[p] - here[p];
            exp2_neg::<FMA>(madd::<FMA>(d * d, k, kd)) * (ok_here[p] * ok_there[p])
        };
        for (p, e) in e.iter_mut().enumerate() {
            *e = pair(p);
        }
    }
    let s = y % kn.slots;
    let mut x0 = 0;
    while x0 + N <= w {
        horizontal_block::<N, FMA>(kn, y, s, x0);
        x0 += N;
    }
    for x in x0..w {
        horizontal_block::<1, FMA>(kn, y, s, x);
    }
}

#[inline(always)]
fn horizontal_block<const N: usize, const FMA: bool>(
    kn: &mut Kernel,
    y: usize,
    slot: usize,
    x0: usize,
) {
    let (w, r) = (kn.w, kn.r);
    let stride = w + 2 * r;
    let v = &kn.value[y * stride..][..stride];
    let ok = &kn.valid[y * stride..][..stride];
    let p0 = r + x0;
    let (vc, okc) = (&v[p0..][..N], &ok[p0..][..N]);
    let mut a0 = [0.0f32; N];
    let mut a1 = [0.0f32; N];
    let mut a2 = [0.0f32; N];
    let mut ab = [0.0f32; N];
    a0.copy_from_slice(okc);
    ab.copy_from_slice(okc);
    for dx in 1..=r {
        let pairs = &kn.row_pairs[(dx - 1) * (w + r)..][..w + r];
        // Forward neighbour p + dx (pair at p) and backward p - dx (pair at p - dx).
        let (fwd, bwd) = (&pairs[p0..][..N], &pairs[p0 - dx..][..N]);
        let (vf, vb) = (&v[p0 + dx..][..N], &v[p0 - dx..][..N]);
        for l in 0..N {
            let (df, db) = (vf[l] - vc[l], vb[l] - vc[l]);
            let (wf, wb) = (fwd[l], bwd[l]);
            let (wdf, wdb) = (wf * df, wb * db);
            a0[l] += wf + wb;
            a1[l] += wdf + wdb;
            a2[l] = madd::<FMA>(wdf, df, madd::<FMA>(wdb, db, a2[l]));
            ab[l] = madd::<FMA>(wf, wf, madd::<FMA>(wb, wb, ab[l]));
        }
    }
    let row = &mut kn.ring[slot * 4 * w..][..4 * w];
    row[x0..][..N].copy_from_slice(&a0);
    row[w + x0..][..N].copy_from_slice(&a1);
    row[2 * w + x0..][..N].copy_from_slice(&a2);
    row[3 * w + x0..][..N].copy_from_slice(&ab);
}

/// One column neighbour row of an output row, as offsets into the buffers:
/// its padded value row, its ring moments and its pair weights with the
/// output row (a row of zeros beyond the frame's top or bottom).
#[derive(Debug, Clone, Copy, Default)]
struct Tap {
    value: usize,
    moments: usize,
    pairs: usize,
}

/// Output row `y`'s neighbours at each dy, above and below; and the pair
/// weights with the rows below (those above were stored on their turn).
#[inline(always)]
fn column_taps<const FMA: bool>(kn: &mut Kernel, y: usize, taps: &mut Vec<[Tap; 2]>) {
    let (w, h, r, k, slots) = (kn.w, kn.h, kn.r, kn.k, kn.slots);
    let stride = w + 2 * r;
    let zeros = r * slots * w;
    let vc = &kn.value[y * stride + r..][..w];
    taps.clear();
    for dy in 1..=r {
        let pairs = |lower: usize| ((dy - 1) * slots + lower % slots) * w;
        let tap = |yy: usize, pairs: usize| Tap {
            value: yy * stride + r,
            moments: (yy % slots) * 4 * w,
            pairs,
        };
        let above = y
            .checked_sub(dy)
            .map_or(tap(y, zeros), |yy| tap(yy, pairs(yy)));
        let below = if y + dy < h {
            let vn = &kn.value[(y + dy) * stride + r..][..w];
            let e = &mut kn.column_pairs[pairs(y)..][..w];
            let kd = kn.domain[dy];
            for x in 0..w {
                let d = vn[x] - vc[x];
                e[x] = exp2_neg::<FMA>(madd::<FMA>(d * d, k, kd));
            }
            tap(y + dy, pairs(y))
        } else {
            tap(y, zeros)
        };
        taps.push([above, below]);
    }
}

/// Output row `y`: column neighbours' row moments shifted to each pixel's
/// value and weighted, then mean, variance and effective sample count.
/// Row-wide loops (the accumulators, 4 rows, stay in L1), or with `B` > 1
/// blocks of `B` pixels (what AVX-512's 32 registers hold).
#[inline(always)]
fn vertical<const FMA: bool, const B: usize>(kn: &mut Kernel, y: usize, taps: &[[Tap; 2]]) {
    let (w, r, slots) = (kn.w, kn.r, kn.slots);
    let stride = w + 2 * r;
    let vc = &kn.value[y * stride + r..][..w];
    let rows = TapRows {
        value: kn.value,
        ring: kn.ring,
        column_pairs: kn.column_pairs,
        w,
    };
    let (s0, rest) = kn.sums.split_at_mut(w);
    let (s1, rest) = rest.split_at_mut(w);
    let (s2, q) = rest.split_at_mut(w);
    let (s0, s1, s2, q) = (&mut s0[..w], &mut s1[..w], &mut s2[..w], &mut q[..w]);
    // Centre: weight 1 for a usable pixel (an unusable one has zero moments).
    let c = &kn.ring[(y % slots) * 4 * w..][..4 * w];
    s0.copy_from_slice(&c[..w]);
    s1.copy_from_slice(&c[w..2 * w]);
    s2.copy_from_slice(&c[2 * w..3 * w]);
    q.copy_from_slice(&c[3 * w..]);
    if B > 1 {
        // Blocks of B pixels whose sums stay in registers over all taps.
        let mut x0 = 0;
        while x0 + B <= w {
            let sums = [&mut *s0, &mut *s1, &mut *s2, &mut *q];
            vertical_block::<B, FMA>(rows, taps, vc, sums, x0);
            x0 += B;
        }
        for x in x0..w {
            vertical_block::<1, FMA>(rows, taps, vc, [&mut *s0, &mut *s1, &mut *s2, &mut *q], x);
        }
    } else {
        let row = |tap: &Tap| {
            let m = &kn.ring[tap.moments..][..4 * w];
            (
                &kn.value[tap.value..][..w],
                &kn.column_pairs[tap.pairs..][..w],
                [&m[..w], &m[w..2 * w], &m[2 * w..3 * w], &m[3 * w..]],
            )
        };
        // Two tap pairs (four neighbour rows) per sweep: half the loads and
        // stores of the sums.
        let mut pairs = taps.chunks_exact(2);
        for two in &mut pairs {
            let [a, b] = two[0];
            let [c, d] = two[1];
            accumulate::<4, FMA>([row(&a), row(&b), row(&c), row(&d)], vc, [s0, s1, s2, q]);
        }
        for &[a, b] in pairs.remainder() {
            accumulate::<2, FMA>([row(&a), row(&b)], vc, [s0, s1, s2, q]);
        }
    }
    let ok = &kn.valid[y * stride + r..][..w];
    let out = &mut *kn.out;
    let mean = &mut out.mean_dn.data[y * w..][..w];
    let var = &mut out.variance_dn2.data[y * w..][..w];
    let samples = &mut out.samples.data[y * w..][..w];
    let fl = &mut out.flags.data[y * w..][..w];
    for x in 0..w {
        let inv = 1.0 / s0[x];
        let m = s1[x] * inv;
        let v = s2[x] * inv - m * m;
        let n = if q[x] > 0.0 {
            s0[x] * s0[x] / q[x]
        } else {
            0.0
        };
        // Fewer than two effective samples (or an unusable pixel): no variance.
        let good = ok[x] > 0.0 && s0[x] > 0.0 && n >= 2.0 && v.is_finite();
        mean[x] = if good { vc[x] + m } else { 0.0 };
        var[x] = if good { v.max(0.0) } else { 0.0 };
        samples[x] = n;
        fl[x] |= if good {
            0
        } else {
            PixelFlags::INSUFFICIENT.bits()
        };
    }
}

/// One neighbour row of [`vertical`]: its values, its pair weights with the
/// output row, its row moments m0 | m1 | m2 | mb.
type NeighbourRow<'a> = (&'a [f32], &'a [f32], [&'a [f32]; 4]);

/// Adds `T` neighbour rows' moments, moved to each pixel's value `vc` and
/// weighted, to the sums s0 | s1 | s2 | q.
#[inline(always)]
fn accumulate<const T: usize, const FMA: bool>(
    rows: [NeighbourRow; T],
    vc: &[f32],
    sums: [&mut [f32]; 4],
) {
    let [s0, s1, s2, q] = sums;
    let w = vc
        .len()
        .min(s0.len())
        .min(s1.len())
        .min(s2.len())
        .min(q.len());
    let rows = rows.map(|(v, p, [m0, m1, m2, mb])| {
        (&v[..w], &p[..w], [&m0[..w], &m1[..w], &m2[..w], &mb[..w]])
    });
    for x in 0..w {
        let (mut t0, mut t1, mut t2, mut tq) = (s0[x], s1[x], s2[x], q[x]);
        for (v, p, [m0, m1, m2, mb]) in &rows {
            // Moments about I' moved to I: m1 + d m0 and m2 + d (2 m1 + d m0).
            let d = v[x] - vc[x];
            let t = madd::<FMA>(d, m0[x], m1[x]);
            let u = madd::<FMA>(d, t + m1[x], m2[x]);
            let wt = p[x];
            t0 = madd::<FMA>(wt, m0[x], t0);
            t1 = madd::<FMA>(wt, t, t1);
            t2 = madd::<FMA>(wt, u, t2);
            tq = madd::<FMA>(wt * wt, mb[x], tq);
        }
        (s0[x], s1[x], s2[x], q[x]) = (t0, t1, t2, tq);
    }
}

/// What [`Tap`]s point into.
#[derive(Clone, Copy)]
struct TapRows<'a> {
    value: &'a [f32],
    ring: &'a [f32],
    column_pairs: &'a [f32],
    w: usize,
}

/// [`vertical`]'s sums over all taps for the `N` pixels from `x0`.
#[inline(always)]
fn vertical_block<const N: usize, const FMA: bool>(
    rows: TapRows,
    taps: &[[Tap; 2]],
    vc: &[f32],
    sums: [&mut [f32]; 4],
    x0: usize,
) {
    let TapRows {
        value,
        ring,
        column_pairs,
        w,
    } = rows;
    let [s0, s1, s2, q] = sums;
    let vc = &vc[x0..][..N];
    let mut a0 = [0.0f32; N];
    let mut a1 = [0.0f32; N];
    let mut a2 = [0.0f32; N];
    let mut ab = [0.0f32; N];
    a0.copy_from_slice(&s0[x0..][..N]);
    a1.copy_from_slice(&s1[x0..][..N]);
    a2.copy_from_slice(&s2[x0..][..N]);
    ab.copy_from_slice(&q[x0..][..N]);
    for pair in taps {
        for tap in pair {
            let v = &value[tap.value + x0..][..N];
            let p = &column_pairs[tap.pairs + x0..][..N];
            let m0 = &ring[tap.moments + x0..][..N];
            let m1 = &ring[tap.moments + w + x0..][..N];
            let m2 = &ring[tap.moments + 2 * w + x0..][..N];
            let mb = &ring[tap.moments + 3 * w + x0..][..N];
            for l in 0..N {
                let d = v[l] - vc[l];
                let t = madd::<FMA>(d, m0[l], m1[l]);
                let u = madd::<FMA>(d, t + m1[l], m2[l]);
                let wt = p[l];
                a0[l] = madd::<FMA>(wt, m0[l], a0[l]);
                a1[l] = madd::<FMA>(wt, t, a1[l]);
                a2[l] = madd::<FMA>(wt, u, a2[l]);
                ab[l] = madd::<FMA>(wt * wt, mb[l], ab[l]);
            }
        }
    }
    s0[x0..][..N].copy_from_slice(&a0);
    s1[x0..][..N].copy_from_slice(&a1);
    s2[x0..][..N].copy_from_slice(&a2);
    q[x0..][..N].copy_from_slice(&ab);
}

/// One-shot separable M3 (see [`SeparableBilateral`] to reuse buffers), as
/// full [`super::Moments`].
pub fn bilateral_separable(
    frame: &Frame,
    params: BilateralParams,
) -> Result<super::Moments, SeparationError> {
    let mut m3 = SeparableBilateral::new();
    Ok(m3.compute(frame, params)?.to_moments())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The build's baseline code (no FMA, no AVX; row-wide and blocked
    /// vertical pass) against what this CPU runs, so both sides of the
    /// run-time selection are tested here.
    #[test]
    fn baseline_and_dispatched_code_agree() {
        let (w, h) = (37, 23);
        let mut f = Frame::new(w, h);
        for i in 0..w * h {
            f.dn.data[i] = ((i * 7919) % 1013) as f32 * 0.37 + ((i % w) / 9) as f32 * 150.0;
        }
        f.dn.data[5] = f32::NAN;
        f.dn.data[40] = f32::INFINITY;
        f.saturated.data[100] = 1;
        let p = BilateralParams::new(1.5, 40.0);
        let mut fast = SeparableBilateral::new();
        let a = fast.compute(&f, p).expect("dispatched").clone();
        type Run = fn(&mut Kernel);
        let baselines: [(&str, Run); 2] = [
            ("row-wide", run_with::<false, LANES, 1>),
            ("blocked", run_with::<false, LANES, 8>),
        ];
        for (name, run) in baselines {
            let mut base = SeparableBilateral::new();
            let b = base.compute_with(&f, p, run).expect("baseline");
            assert_eq!(a.flags, b.flags, "{name}");
            for i in 0..w * h {
                let (ma, mb) = (a.mean_dn.data[i], b.mean_dn.data[i]);
                let (va, vb) = (a.variance_dn2.data[i], b.variance_dn2.data[i]);
                assert!(
                    (ma - mb).abs() <= 1e-3 * (1.0 + mb.abs()),
                    "{name} mean {i}: {ma} vs {mb}"
                );
                assert!(
                    (va - vb).abs() <= 1e-3 * (1.0 + vb.abs()),
                    "{name} variance {i}: {va} vs {vb}"
                );
            }
        }
    }
}
