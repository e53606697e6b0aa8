//! separation.svg: the error of each estimator against its run time.

use plotters::prelude::*;

use super::{ReportError, Row};

/// Error (mean of the I+ and I- relative RMSE) against time per frame, log-log.
pub(super) fn plot(svg: &mut String, scene: &str, rows: &[Row]) -> Result<(), ReportError> {
    let err = |r: &Row| 0.5 * (r.rmse_plus + r.rmse_minus);
    let pe = |e: DrawingAreaErrorKind<_>| ReportError::Plot(e.to_string());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for r in rows {
        x0 = x0.min(r.ms_per_frame);
        x1 = x1.max(r.ms_per_frame);
        y0 = y0.min(err(r));
        y1 = y1.max(err(r));
    }
    let (x0, x1) = ((x0 * 0.5).max(1e-4), (x1 * 2.0).max(1e-3));
    let (y0, y1) = ((y0 * 0.5).max(1e-4), (y1 * 2.0).max(1e-3));
    let root = SVGBackend::with_string(svg, (900, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(pe)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("SDI separation on {scene}: error vs run time"),
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(pe)?;
    chart
        .configure_mesh()
        .x_desc("time per frame, ms")
        .y_desc("relative RMSE, mean of I+ and I-")
        .draw()
        .map_err(pe)?;
    let series: [(&str, &str, RGBColor); 8] = [
        ("M1", "", BLUE),
        ("M1", "read:=0", RGBColor(120, 120, 255)),
        ("M1", "non-neg", RGBColor(0, 160, 160)),
        ("M1 pooled", "r=", RGBColor(0, 0, 90)),
        ("M2 auto", "", GREEN),
        ("M3 exact", "", RED),
        ("M3 separable", "", RGBColor(230, 130, 0)),
        ("M3 grid", "", RGBColor(160, 0, 160)),
    ];
    for (method, tag, colour) in series {
        let pts: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| {
                r.method == method
                    && (tag.is_empty() && !r.params.contains(',')
                        || !tag.is_empty() && r.params.contains(tag))
            })
            .map(|r| (r.ms_per_frame.max(x0), err(r)))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let label = if tag.is_empty() {
            method.to_string()
        } else {
            format!("{method} ({tag})")
        };
        chart
            .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
            .map_err(pe)?
            .label(label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 4, colour.filled())))
            .map_err(pe)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(pe)?;
    root.present().map_err(pe)?;
    Ok(())
}
