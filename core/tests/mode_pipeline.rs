//! Structural tests of the mode pipelines: every mode builds, invalid pixels
//! are neutralized and flagged, buffers are reused, dark frames are applied
//! only where they fit.

use sdi_core::image::Image;
use sdi_core::mode::{build_pipeline, ModeId, PipelineConfig};
use sdi_core::modulation::SourceDrive;
use sdi_core::scene::SceneId;
use sdi_core::Frame;
use sdi_core::PixelFlags;
use strum::IntoEnumIterator;

fn frame(w: usize, h: usize, seq: u64, values: &[f32]) -> Frame {
    let mut f = Frame::new(w, h);
    f.dn.data.copy_from_slice(values);
    f.sequence = seq;
    f.timestamp_us = seq * 1000;
    f
}

#[test]
fn every_mode_builds_and_reports_itself() {
    for m in ModeId::iter() {
        let p = build_pipeline(m, PipelineConfig::default());
        assert_eq!(p.mode(), m);
    }
}

#[test]
fn snapshot_modes_use_snapshot_illumination_except_temporal() {
    for m in ModeId::iter() {
        let i = m.illumination(0, 1e6);
        match m {
            ModeId::TemporalGradient => {
                assert_eq!((i.ls1, i.ls2), (SourceDrive::Off, SourceDrive::Off))
            }
            ModeId::TwoShot => {
                assert_eq!((i.ls1, i.ls2), (SourceDrive::Modulated, SourceDrive::Off))
            }
            _ => assert_eq!(
                (i.ls1, i.ls2),
                (SourceDrive::Modulated, SourceDrive::Inverted)
            ),
        }
    }
}

#[test]
fn nan_inf_become_zero_and_flagged_saturation_kept() {
    let mut p = build_pipeline(ModeId::Raw, PipelineConfig::default());
    let mut f = frame(4, 1, 0, &[f32::NAN, f32::INFINITY, 2047.0, -5.0]);
    f.saturated.data[2] = 1;
    let out = p.process(&f).unwrap();
    assert_eq!(out.signed_dn.data, vec![0.0, 0.0, 2047.0, -5.0]);
    assert_eq!(
        out.flags.data,
        vec![
            PixelFlags::NONFINITE.bits(),
            PixelFlags::NONFINITE.bits(),
            PixelFlags::SATURATED.bits(),
            0
        ]
    );
    let mut z = build_pipeline(
        ModeId::Raw,
        PipelineConfig {
            zero_saturated: true,
            ..Default::default()
        },
    );
    assert_eq!(z.process(&f).unwrap().signed_dn.data[2], 0.0);
}

#[test]
fn output_buffers_are_reused_after_warm_up() {
    for m in [ModeId::BipolarColour, ModeId::TwoShot] {
        let mut p = build_pipeline(m, PipelineConfig::default());
        let mut ptr = None;
        for seq in 0..20u64 {
            let f = frame(8, 8, seq, &[seq as f32; 64]);
            if let Some(out) = p.process(&f) {
                let now = out.signed_dn.data.as_ptr();
                assert_eq!(*ptr.get_or_insert(now), now, "{m} reallocated");
            }
        }
        assert!(ptr.is_some());
    }
}

#[test]
fn dark_frame_subtracted_only_when_it_fits() {
    let mut p = build_pipeline(
        ModeId::DepthEdge,
        PipelineConfig {
            dark_frame_dn: Some(Image::filled(2, 1, 10.0)),
            ..Default::default()
        },
    );
    assert!(p.dark_frame_applies(2, 1));
    assert_eq!(
        p.process(&frame(2, 1, 0, &[15.0, 5.0]))
            .unwrap()
            .signed_dn
            .data,
        vec![5.0, -5.0]
    );
    assert!(!p.dark_frame_applies(3, 1));
    assert_eq!(
        p.process(&frame(3, 1, 1, &[1.0, 2.0, 3.0]))
            .unwrap()
            .signed_dn
            .data,
        vec![1.0, 2.0, 3.0]
    );
    p.set_dark_frame(None);
    assert!(!p.dark_frame_applies(2, 1));
    assert_eq!(
        p.process(&frame(2, 1, 2, &[15.0, 5.0]))
            .unwrap()
            .signed_dn
            .data,
        vec![15.0, 5.0]
    );
}

#[test]
fn timestamps_and_sequences_pass_through() {
    let mut p = build_pipeline(ModeId::SpatialGradient, PipelineConfig::default());
    let out = p.process(&frame(1, 1, 7, &[1.0])).unwrap();
    assert_eq!((out.sequence, out.timestamp_us), (7, 7000));
}

#[test]
fn default_scenes_are_named_after_the_paper() {
    let scene = |m: ModeId| m.spec().default_scene;
    assert_eq!(scene(ModeId::BipolarColour), SceneId::ColourChart);
    assert_eq!(scene(ModeId::TemporalGradient), SceneId::FanPellets);
    assert_eq!(scene(ModeId::DirectOnly), SceneId::Polarization);
    assert_eq!(scene(ModeId::SpatialGradient), SceneId::Birefringent);
    for m in ModeId::iter() {
        assert_eq!(m.default_scene().id(), scene(m));
    }
}
