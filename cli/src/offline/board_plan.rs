//! `sdictl board plan`: the exact register sequence sdid would perform to
//! open and configure the OPT8241-CDK, offline, from the same plan sdid
//! executes (`sdi_opt8241::plan`), so a user with a board can diff it
//! against TI's SDK.

use clap::Args;
use sdi_core::number::Number;
use sdi_opt8241::{open_plan, BoardConfig};

use crate::exit::CliError;
use crate::stdout::outln;

#[derive(Debug, Args)]
pub struct BoardPlanArgs {
    /// Frame rate, Hz (default 30).
    #[arg(long = "frame-rate", allow_negative_numbers = true)]
    frame_rate_hz: Option<f64>,
    /// Integration of one quad, microseconds (default 20 % of the quad).
    #[arg(long, allow_negative_numbers = true)]
    exposure_us: Option<f64>,
    /// Modulation frequency, Hz (default 12 MHz).
    #[arg(long, allow_negative_numbers = true)]
    modulation_hz: Option<f64>,
}

pub fn run(args: &BoardPlanArgs, json: bool) -> Result<(), CliError> {
    let config = BoardConfig::with_capture(
        None,
        args.frame_rate_hz,
        args.exposure_us,
        args.modulation_hz,
    );
    let plan = open_plan(&config).map_err(|e| CliError::Usage(e.to_string()))?;
    let limits = config.limits();
    let range = |r: &sdi_opt8241::Range| {
        serde_json::json!({
            "min": r.min,
            "max": r.max,
            "min_set_by": r.min_set_by,
            "max_set_by": r.max_set_by,
        })
    };
    if json {
        let steps: Vec<_> = plan.steps.iter().map(|s| s.line()).collect();
        let clamps: Vec<_> = plan
            .clamps
            .iter()
            .map(|c| {
                serde_json::json!({
                    "field": c.field,
                    "requested": c.requested,
                    "actual": c.actual,
                    "reason": c.reason,
                })
            })
            .collect();
        outln!(
            "{}",
            serde_json::json!({
                "config": {
                    "quads": config.quads,
                    "sub_frames": config.sub_frames,
                    "frame_rate_hz": config.frame_rate_hz,
                    "exposure_us": config.exposure_us(),
                    "modulation_hz": config.modulation_hz,
                    "roi": [config.roi.x, config.roi.y, config.roi.width, config.roi.height],
                    "op_clk_freq": config.op_clk_freq,
                },
                "pll": {
                    "mod_m": plan.pll.m,
                    "mod_m_frac": plan.pll.m_frac,
                    "mod_n": plan.pll.n,
                    "mod_ps": plan.pll.ps,
                    "vco_hz": plan.pll.vco_hz,
                    "modulation_hz": plan.pll.modulation_hz,
                },
                "limits": {
                    "frame_rate_hz": range(&limits.frame_rate_hz),
                    "exposure_us": range(&limits.exposure_us),
                    "modulation_hz": range(&limits.modulation_hz),
                },
                "clamps": clamps,
                "steps": steps,
            })
        )?;
        return Ok(());
    }
    outln!(
        "# OPT8241-CDK open plan: {} quads, {} sub frame(s), {} Hz, exposure {:.1} us, modulation {} Hz (PLL gives {:.1} Hz), ROI {}x{}+{}+{}",
        config.quads,
        config.sub_frames,
        config.frame_rate_hz,
        config.exposure_us(),
        config.modulation_hz,
        plan.pll.modulation_hz,
        config.roi.width,
        config.roi.height,
        config.roi.x,
        config.roi.y,
    )?;
    for (name, r) in [
        ("frame_rate_hz", &limits.frame_rate_hz),
        ("exposure_us", &limits.exposure_us),
        ("modulation_hz", &limits.modulation_hz),
    ] {
        outln!(
            "# {name}: [{}, {}] ({}; {})",
            Number(r.min),
            Number(r.max),
            r.min_set_by,
            r.max_set_by
        )?;
    }
    for c in &plan.clamps {
        outln!(
            "# clamp: {} {} -> {} ({})",
            c.field,
            c.requested,
            c.actual,
            c.reason
        )?;
    }
    for step in &plan.steps {
        outln!("{step}")?;
    }
    Ok(())
}
