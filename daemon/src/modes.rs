//! TEMPORARY adapter: the daemon's view of the mode pipelines and display
//! mapping until `sdi_core::mode::pipeline` and `sdi_core::display` land on
//! main. Same names and signatures as core's API; delete after merging.

use sdi_core::modulation::{Illumination, ModulationPattern, SourceDrive};
use sdi_core::scene::SceneSpec;
use sdi_core::{Frame, Image};

pub use sdi_core::mode::ModeId;

/// What a pipeline needs besides the frames.
#[derive(Debug, Clone, Default)]
pub struct PipelineConfig {
    pub dark_frame_dn: Option<Image<f32>>,
}

/// One processed frame: signed values in DN.
#[derive(Debug, Clone, PartialEq)]
pub struct ModeOutput {
    pub signed_dn: Image<f32>,
    pub saturated: Image<u8>,
    pub timestamp_us: u64,
    pub sequence: u64,
}

/// A mode's per-frame processing.
pub trait Pipeline: Send {
    fn mode(&self) -> ModeId;
    fn process(&mut self, frame: &Frame) -> Option<&ModeOutput>;
    fn set_dark_frame(&mut self, dark_dn: Option<Image<f32>>);
}

struct DarkSubtract {
    mode: ModeId,
    dark: Option<Image<f32>>,
    out: Option<ModeOutput>,
}

impl Pipeline for DarkSubtract {
    fn mode(&self) -> ModeId {
        self.mode
    }
    fn process(&mut self, frame: &Frame) -> Option<&ModeOutput> {
        let out = self.out.get_or_insert_with(|| ModeOutput {
            signed_dn: frame.dn.clone(),
            saturated: frame.saturated.clone(),
            timestamp_us: 0,
            sequence: 0,
        });
        out.signed_dn.clone_from(&frame.dn);
        out.saturated.clone_from(&frame.saturated);
        if let Some(d) = self.dark.as_ref().filter(|d| d.same_size(&frame.dn)) {
            for (v, &o) in out.signed_dn.data.iter_mut().zip(&d.data) {
                *v -= o;
            }
        }
        out.timestamp_us = frame.timestamp_us;
        out.sequence = frame.sequence;
        Some(out)
    }
    fn set_dark_frame(&mut self, dark_dn: Option<Image<f32>>) {
        self.dark = dark_dn;
    }
}

pub fn build_pipeline(mode: ModeId, config: PipelineConfig) -> Box<dyn Pipeline> {
    Box::new(DarkSubtract {
        mode,
        dark: config.dark_frame_dn,
        out: None,
    })
}

/// How the sources are driven for `mode` in frame `frame_index`.
pub fn illumination(mode: ModeId, frame_index: u64, carrier_hz: f64) -> Illumination {
    match mode {
        ModeId::TemporalGradient => Illumination {
            modulation: ModulationPattern::single_transition(0.5),
            ls1: SourceDrive::Off,
            ls2: SourceDrive::Off,
        },
        ModeId::TwoShot => {
            let mut i = Illumination::snapshot(carrier_hz);
            if frame_index % 2 == 0 {
                i.ls2 = SourceDrive::Off;
            } else {
                i.ls1 = SourceDrive::Off;
            }
            i
        }
        _ => Illumination::snapshot(carrier_hz),
    }
}

pub fn default_scene(_mode: ModeId) -> SceneSpec {
    SceneSpec::FlatField {
        ls1_electrons_per_us: 4.0,
        ls2_electrons_per_us: 2.0,
    }
}

/// Colour map of the view stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Colormap {
    Diverging,
    Grey,
}

/// Mapping of signed DN to display intensity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DisplayRange {
    SymmetricAuto,
    Fixed { max_abs_dn: f32 },
}

/// Signed image -> 8-bit display.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DisplayMap {
    pub colormap: Colormap,
    pub range: DisplayRange,
}

impl DisplayMap {
    fn scale(&self, img: &Image<f32>) -> f32 {
        match self.range {
            DisplayRange::Fixed { max_abs_dn } => max_abs_dn.max(f32::MIN_POSITIVE),
            DisplayRange::SymmetricAuto => img
                .data
                .iter()
                .filter(|v| v.is_finite())
                .fold(0f32, |m, v| m.max(v.abs()))
                .max(1.0),
        }
    }

    /// Renders `img` into `out` (3 bytes per pixel).
    pub fn render_rgb8(&self, img: &Image<f32>, out: &mut [u8]) {
        let s = self.scale(img);
        for (px, &v) in out.chunks_exact_mut(3).zip(&img.data) {
            let t = if v.is_finite() {
                (v / s).clamp(-1.0, 1.0)
            } else {
                0.0
            };
            let rgb = match self.colormap {
                Colormap::Grey => {
                    let g = ((t + 1.0) * 127.5) as u8;
                    [g, g, g]
                }
                Colormap::Diverging => {
                    // Blue (negative) - white - red (positive).
                    let a = (255.0 * (1.0 - t.abs())) as u8;
                    if t >= 0.0 {
                        [255, a, a]
                    } else {
                        [a, a, 255]
                    }
                }
            };
            px.copy_from_slice(&rgb);
        }
    }

    /// Renders `img` into `out` (1 byte per pixel, mid-grey at zero).
    pub fn render_grey8(&self, img: &Image<f32>, out: &mut [u8]) {
        let s = self.scale(img);
        for (g, &v) in out.iter_mut().zip(&img.data) {
            let t = if v.is_finite() {
                (v / s).clamp(-1.0, 1.0)
            } else {
                0.0
            };
            *g = ((t + 1.0) * 127.5) as u8;
        }
    }
}

/// Minimal `.npy` (v1.0, little-endian f32, C order) writer.
pub fn write_npy_f32<W: std::io::Write>(
    w: &mut W,
    shape: &[usize],
    data: &[f32],
) -> std::io::Result<()> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    let total = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat((64 - total % 64) % 64));
    dict.push('\n');
    w.write_all(b"\x93NUMPY\x01\x00")?;
    w.write_all(&(dict.len() as u16).to_le_bytes())?;
    w.write_all(dict.as_bytes())?;
    let mut buf = Vec::with_capacity(data.len() * 4);
    for v in data {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    w.write_all(&buf)
}
