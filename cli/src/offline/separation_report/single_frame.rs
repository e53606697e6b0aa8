//! The single-frame estimators on one frame: M2 (automatic segments) and
//! M3 (bilateral local moments), each timed.

use std::time::Instant;

use sdi_core::sensor::SkellamMixing;
use sdi_core::separation::{
    auto_segment, bilateral_exact, noise_sigma, segment_moments, unmix, unmix_local_into,
    BilateralGrid, BilateralParams, SegmentParams, SeparableBilateral, Separated, UnmixOptions,
};
use sdi_core::Frame;

use super::args::{Chosen, Estimator};
use super::metrics::row;
use super::{ReportError, Row, Truth};

/// M2 (automatic segments of one frame) at a few smoothing radii.
pub(super) fn m2_rows(
    one: &Frame,
    truth: &Truth,
    h: &SkellamMixing,
    chosen: &Chosen,
) -> Result<Vec<Row>, ReportError> {
    let mut rows = Vec::new();
    if !chosen.has(Estimator::M2) {
        return Ok(rows);
    }
    for radius in [1, 2, 4] {
        let p = SegmentParams {
            smooth_radius_px: radius,
            ..SegmentParams::default()
        };
        let t0 = Instant::now();
        let seg = auto_segment(one, p)?;
        let m = segment_moments(one, &seg.labels, Some(&seg.interior))?;
        let sep = unmix(&m, h, UnmixOptions::default())?;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let params = format!("smooth r={radius}");
        rows.push(row("M2 auto", params, &sep, truth, ms));
    }
    Ok(rows)
}

/// M3 (local moments by a bilateral filter on one frame), each chosen
/// variant at a few domain and range scales; the range scale comes from
/// the frame itself (robust MAD), never from the truth.
pub(super) fn m3_rows(
    one: &Frame,
    truth: &Truth,
    h: &SkellamMixing,
    chosen: &Chosen,
) -> Result<Vec<Row>, ReportError> {
    let with_read = UnmixOptions::default();
    let noise_dn = noise_sigma(one);
    let mut rows = Vec::new();
    for sd in [1.5, 3.0] {
        for k in [2.0, 4.0] {
            let p = BilateralParams::new(sd, k * noise_dn);
            let params = format!("sd={sd} sr={k}sigma");
            if chosen.has(Estimator::M3Exact) {
                let (sep, ms) =
                    median_of_3(|| Ok(unmix(&bilateral_exact(one, p)?, h, with_read)?))?;
                rows.push(row("M3 exact", params.clone(), &sep, truth, ms));
            }
            // The fast variants as the daemon runs them: buffers kept, f32 unmix.
            let mut out = Separated::default();
            if chosen.has(Estimator::M3Separable) {
                let mut separable = SeparableBilateral::new();
                let ((), ms) = median_of_3(|| {
                    Ok(unmix_local_into(
                        separable.compute(one, p)?,
                        h,
                        with_read,
                        &mut out,
                    )?)
                })?;
                rows.push(row("M3 separable", params.clone(), &out, truth, ms));
            }
            if chosen.has(Estimator::M3Grid) {
                let mut grid = BilateralGrid::new();
                let ((), ms) = median_of_3(|| {
                    Ok(unmix_local_into(
                        grid.compute(one, p)?,
                        h,
                        with_read,
                        &mut out,
                    )?)
                })?;
                rows.push(row("M3 grid", params.clone(), &out, truth, ms));
            }
        }
    }
    Ok(rows)
}

/// The last result of three runs and their median wall time, ms (the
/// machine is shared).
fn median_of_3<T>(
    mut run: impl FnMut() -> Result<T, ReportError>,
) -> Result<(T, f64), ReportError> {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..3 {
        let t0 = Instant::now();
        last = Some(run()?);
        times.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let result = last.ok_or(ReportError::Plot("no run".into()))?;
    Ok((result, times[1]))
}
