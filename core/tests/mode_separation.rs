//! The live separation mode: the signed image as in raw mode, plus I+ and I-
//! recovered with the configured estimator and H, after dark subtraction.

mod separation_support;

use sdi_core::image::Image;
use sdi_core::mode::{build_pipeline, ModeId, PipelineConfig};
use sdi_core::sensor::SensorPreset;
use sdi_core::separation::LiveMethod;
use sdi_core::separation::LiveSeparatorConfig;
use separation_support::{chart, rel_rmse_bias, Sampler};
use strum::IntoEnumIterator;

const OFFSET_DN: f32 = 120.0;

fn config(method: LiveMethod) -> PipelineConfig {
    let h = SensorPreset::TiOpt8241.params().skellam();
    PipelineConfig {
        dark_frame_dn: Some(Image {
            width: 32,
            height: 24,
            data: vec![OFFSET_DN; 32 * 24],
        }),
        separation: LiveSeparatorConfig::new(method, h),
        ..Default::default()
    }
}

#[test]
fn sliding_window_recovers_both_channels_after_dark_subtraction() {
    let cfg = config(LiveMethod::SlidingWindow { frames: 200 });
    let t = chart(4, 3, 8, 20_000.0);
    let mut s = Sampler::new(cfg.separation.h, 7);
    let mut sep = build_pipeline(ModeId::Separation, cfg.clone());
    let mut raw = build_pipeline(ModeId::Raw, cfg);
    let mut frame = s.frame(&t);
    frame.dn.data.iter_mut().for_each(|v| *v += OFFSET_DN);
    let first = sep.process(&frame).unwrap();
    assert!(first.channels.is_none(), "one frame has no variance");
    assert_eq!(first.signed_dn, raw.process(&frame).unwrap().signed_dn);
    for _ in 0..250 {
        let mut f = s.frame(&t);
        f.dn.data.iter_mut().for_each(|v| *v += OFFSET_DN);
        frame = f;
        sep.process(&frame).unwrap();
    }
    let out = sep.process(&frame).unwrap();
    let ch = out.channels.as_ref().unwrap();
    let (rp, bp) = rel_rmse_bias(&ch.i_plus_electrons, &t.i_plus);
    let (rm, bm) = rel_rmse_bias(&ch.i_minus_electrons, &t.i_minus);
    eprintln!("M1 window 200: I+ rmse {rp:.3} bias {bp:.3}; I- rmse {rm:.3} bias {bm:.3}");
    // 200 frames: sqrt(2/199) = 10% relative noise on the variance.
    assert!(rp < 0.25 && rm < 0.25, "{rp} {rm}");
    // Without the dark subtraction the 120 DN offset would bias I+ - I- by
    // 120 / g = 2300 electrons, 20% of the mean.
    assert!(bp.abs() < 0.05 && bm.abs() < 0.05, "{bp} {bm}");
}

#[test]
fn bilateral_separates_every_frame_and_other_modes_do_not() {
    let cfg = config(LiveMethod::Bilateral(sdi_core::mode::DEFAULT_BILATERAL));
    let t = chart(4, 3, 8, 20_000.0);
    let mut s = Sampler::new(cfg.separation.h, 9);
    let mut sep = build_pipeline(ModeId::Separation, cfg.clone());
    let frame = s.frame(&t);
    let ch = sep.process(&frame).unwrap().channels.clone().unwrap();
    assert!(ch
        .i_plus_electrons
        .data
        .iter()
        .chain(&ch.i_minus_electrons.data)
        .all(|v| v.is_finite()));
    for m in ModeId::iter().filter(|&m| m != ModeId::Separation) {
        let mut p = build_pipeline(m, cfg.clone());
        for _ in 0..2 {
            if let Some(out) = p.process(&frame) {
                assert!(out.channels.is_none(), "{m} computed a separation");
            }
        }
    }
}
