//! Simulator frames for the loopback tests: sdi-core's colour-chart scene
//! on the TI OPT8241 model through the bipolar-colour pipeline, rendered the
//! way the daemon publishes them (signed DN for Y16, the diverging display
//! mapping for GREY, YUYV and RGB24), with the exact bytes each frame must
//! arrive as on the node.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};

use sdi_core::dark_frame::DarkAccumulator;
use sdi_core::display::{Colormap, DisplayMap, DisplayRange};
use sdi_core::mode::{build_pipeline, ModeId, PipelineConfig};
use sdi_core::modulation::Illumination;
use sdi_core::sensor::SensorPreset;
use sdi_core::simulator::{SimConfig, Simulator};
use sdi_core::view::{Packer, PixelFormat, Src};
use sdi_core::{Frame, Image};

/// `n` processed simulator frames (signed DN, sensor size).
pub struct SimFrames {
    pub width: usize,
    pub height: usize,
    pub frames: Vec<Image<f32>>,
    display: DisplayMap,
}

impl SimFrames {
    /// Renders `n` bipolar-colour frames (8 dark frames averaged first, as
    /// the daemon's dark-frame stage does). Every frame carries fresh
    /// Poisson and read noise, so no two are equal.
    pub fn render(n: usize, seed: u64) -> Self {
        let sensor = SensorPreset::TiOpt8241.params();
        let carrier_hz = sensor.modulation_hz;
        let mode = ModeId::BipolarColour;
        let mut config = SimConfig::new(sensor, mode.default_scene());
        config.seed = seed;
        let mut sim = Simulator::new(config).expect("simulator parameters");
        let (w, h) = (sim.params().width, sim.params().height);
        let mut frame = Frame::new(w, h);
        let mut dark = DarkAccumulator::new(w, h);
        for _ in 0..8 {
            sim.capture(&Illumination::dark(carrier_hz), &mut frame);
            dark.push(&frame)
                .expect("simulated frames have the sensor size");
        }
        let mut pipeline = build_pipeline(
            mode,
            PipelineConfig {
                dark_frame_dn: dark.mean_dn(),
                ..PipelineConfig::default()
            },
        );
        let mut frames = Vec::with_capacity(n);
        let mut seq = frame.sequence + 1;
        while frames.len() < n {
            sim.capture(&mode.illumination(seq, carrier_hz), &mut frame);
            seq = frame.sequence + 1;
            if let Some(out) = pipeline.process(&frame) {
                frames.push(out.signed_dn.clone());
            }
        }
        Self {
            width: w,
            height: h,
            frames,
            display: DisplayMap::new(Colormap::Diverging, DisplayRange::SymmetricAuto),
        }
    }

    /// The frames packed in `format`, one per simulator frame: what a
    /// writer hands the glue and each must arrive as on the node.
    pub fn patterns(&self, format: PixelFormat) -> Vec<Vec<u8>> {
        let (w, h) = (self.width, self.height);
        let packer = Packer::new(w, h, format);
        let mut frames = Vec::new();
        for img in &self.frames {
            let mut bytes = vec![0u8; w * h * format.bytes_per_pixel()];
            match format {
                PixelFormat::Y16 => packer
                    .signed_dn(Src::packed(&img.data, w, h, 1), &mut bytes)
                    .expect("pack Y16"),
                PixelFormat::Grey => {
                    let mut g = vec![0u8; w * h];
                    self.display.render_grey8(img, &mut g);
                    packer
                        .grey8(Src::packed(&g, w, h, 1), &mut bytes)
                        .expect("pack GREY")
                }
                PixelFormat::Yuyv | PixelFormat::Rgb24 => {
                    let mut rgb = vec![0u8; w * h * 3];
                    self.display.render_rgb8(img, &mut rgb);
                    packer
                        .rgb8(Src::packed(&rgb, w, h, 3), &mut bytes)
                        .expect("pack RGB")
                }
            }
            frames.push(bytes);
        }
        frames
    }
}

/// A frame's checksum (std's SipHash of the bytes).
pub fn checksum(bytes: &[u8]) -> u64 {
    let mut h = DefaultHasher::new();
    bytes.hash(&mut h);
    h.finish()
}
