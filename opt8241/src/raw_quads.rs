//! Raw-quad frames: their geometry, and their decoding into the pipeline's
//! signed difference frame.
//!
//! With output_mode = 15 the board sends, per pixel in row order,
//! quad_cnt_max little-endian 16-bit words, each a signed 12-bit A-B value in
//! bits 11:0 (SDK `TI3DToF/ToFFrameGenerator.cpp`, `_generateToFRawIQFrame`,
//! "Sign extension"; frame size `width * height * quads * 2`,
//! `TintinCDKCamera.cpp` `_setStreamerFrameSize`). With LS1 driven by f and
//! LS2 by not-f and no delay between the modulation and the light, quad 0
//! is LS1 - LS2 (I+ - I-, eq. pixeleff) and the antiphase quad its
//! negative; with a delay, the difference is the projection of all quads
//! onto a calibrated axis (`sdi_core::quad_phase`).

use sdi_core::quad_phase::{PhaseAxis, PhaseSums, QuadBasis};
use sdi_core::Frame;

/// Geometry of one raw-quad frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QuadLayout {
    pub width: usize,
    pub height: usize,
    /// quad_cnt_max: 4 or 6.
    pub quads: usize,
}

impl QuadLayout {
    pub const OPT8241_FULL: QuadLayout = QuadLayout {
        width: 320,
        height: 240,
        quads: 4,
    };

    /// Bytes of one frame on the wire (614,400 for 320x240 with 4 quads).
    pub const fn frame_bytes(&self) -> usize {
        self.width * self.height * self.quads * 2
    }
}

/// Smallest and largest 12-bit code: pixels there are flagged saturated.
pub const CODE_MIN_DN: i16 = -2048;
pub const CODE_MAX_DN: i16 = 2047;

/// Signed value of bits 11:0 of a quad word.
#[inline]
pub fn sign_extend_12(word: u16) -> i16 {
    ((word << 4) as i16) >> 4
}

/// Which quads make the difference image.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum QuadCombine {
    /// Quad 0 alone: one readout, the paper's noise model (eq. skellamvar).
    #[default]
    Quad0,
    /// (quad 0 - quad 2) / 2: two readouts averaged, same DN scale.
    Quad0MinusQuad2,
    /// Every quad's first harmonic projected onto the calibrated axis of
    /// LS1 - LS2: right under any delay on the LED path, and with 6 quads.
    Projected(PhaseAxis),
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("raw frame has {got} bytes, expected {expected}")]
    Length { expected: usize, got: usize },
    #[error("dark frame is {got} pixels, expected {expected}")]
    DarkSize { expected: usize, got: usize },
    #[error("{quads} quads per pixel: the phase projection needs 4 or 6")]
    Quads { quads: usize },
}

/// Decodes raw-quad buffers into [`Frame`]s, subtracting a dark frame.
#[derive(Debug, Clone)]
pub struct QuadDecoder {
    pub layout: QuadLayout,
    pub combine: QuadCombine,
    /// The first byte of a frame carries its number (debug_frame_number_en):
    /// pixel (0, 0) is then copied from its right neighbour.
    pub frame_number_in_first_byte: bool,
    dark_dn: Option<Vec<f32>>,
}

impl QuadDecoder {
    pub fn new(layout: QuadLayout) -> Self {
        Self {
            layout,
            combine: QuadCombine::default(),
            frame_number_in_first_byte: true,
            dark_dn: None,
        }
    }

    /// Sets (or clears) the dark frame subtracted from every frame, DN.
    pub fn set_dark_dn(&mut self, dark: Option<Vec<f32>>) -> Result<(), DecodeError> {
        let n = self.layout.width * self.layout.height;
        if let Some(d) = &dark {
            if d.len() != n {
                return Err(DecodeError::DarkSize {
                    expected: n,
                    got: d.len(),
                });
            }
        }
        self.dark_dn = dark;
        Ok(())
    }

    /// Decodes one frame. `out` is resized if needed; its timestamp and
    /// sequence are left to the caller.
    pub fn decode(&self, raw: &[u8], out: &mut Frame) -> Result<(), DecodeError> {
        let l = self.layout;
        if raw.len() != l.frame_bytes() {
            return Err(DecodeError::Length {
                expected: l.frame_bytes(),
                got: raw.len(),
            });
        }
        if out.width() != l.width || out.height() != l.height {
            *out = Frame::new(l.width, l.height);
        }
        let stride = l.quads * 2;
        let basis = match self.combine {
            QuadCombine::Projected(_) => {
                Some(QuadBasis::new(l.quads).map_err(|_| DecodeError::Quads { quads: l.quads })?)
            }
            _ => None,
        };
        let mut quads = [0.0f32; 6];
        for (i, px) in raw.chunks_exact(stride).enumerate() {
            let quad = |k: usize| sign_extend_12(u16::from_le_bytes([px[2 * k], px[2 * k + 1]]));
            let q0 = quad(0);
            let (value, saturated) = match self.combine {
                QuadCombine::Quad0 => (q0 as f32, q0 <= CODE_MIN_DN || q0 >= CODE_MAX_DN),
                QuadCombine::Quad0MinusQuad2 => {
                    let q2 = quad(2);
                    let sat = [q0, q2]
                        .iter()
                        .any(|&q| q <= CODE_MIN_DN || q >= CODE_MAX_DN);
                    ((q0 as f32 - q2 as f32) * 0.5, sat)
                }
                QuadCombine::Projected(axis) => {
                    let mut sat = false;
                    for (k, q) in quads.iter_mut().enumerate().take(l.quads) {
                        let v = quad(k);
                        sat |= v <= CODE_MIN_DN || v >= CODE_MAX_DN;
                        *q = f32::from(v);
                    }
                    let value = basis
                        .as_ref()
                        .map_or(0.0, |b| b.project(&quads[..l.quads], &axis));
                    (value, sat)
                }
            };
            let dark = self.dark_dn.as_ref().map_or(0.0, |d| d[i]);
            out.dn.data[i] = value - dark;
            out.saturated.data[i] = u8::from(saturated);
        }
        if self.frame_number_in_first_byte && l.width > 1 {
            out.dn.data[0] = out.dn.data[1];
            out.saturated.data[0] = out.saturated.data[1];
        }
        Ok(())
    }
}

impl QuadDecoder {
    /// The summed (I, Q) of one raw frame's pixels, for measuring the
    /// phase axis (`sdi_core::quad_phase::fit_axis`): pixels with a quad at
    /// a 12-bit extreme, and pixel 0 when it carries the frame number,
    /// are left out.
    pub fn phase_sums(&self, raw: &[u8]) -> Result<PhaseSums, DecodeError> {
        let l = self.layout;
        if raw.len() != l.frame_bytes() {
            return Err(DecodeError::Length {
                expected: l.frame_bytes(),
                got: raw.len(),
            });
        }
        let basis = QuadBasis::new(l.quads).map_err(|_| DecodeError::Quads { quads: l.quads })?;
        let skip = usize::from(self.frame_number_in_first_byte);
        let mut sums = PhaseSums::new(l.quads);
        let mut quads = [0.0f32; 6];
        'pixels: for px in raw.chunks_exact(l.quads * 2).skip(skip) {
            for (k, q) in quads.iter_mut().enumerate().take(l.quads) {
                let v = sign_extend_12(u16::from_le_bytes([px[2 * k], px[2 * k + 1]]));
                if v <= CODE_MIN_DN || v >= CODE_MAX_DN {
                    continue 'pixels;
                }
                *q = f32::from(v);
            }
            let (i, q) = basis.in_phase_quadrature(&quads[..l.quads]);
            sums.push(i, q);
        }
        Ok(sums)
    }
}

/// Encodes a difference image as raw quads (q0 = d, q1 = q3 = 0, q2 = -d):
/// the inverse of [`QuadDecoder::decode`] for emulators and tests.
pub fn encode_quads(layout: QuadLayout, dn: &[f32], frame_number: Option<u8>) -> Vec<u8> {
    let mut out = vec![0u8; layout.frame_bytes()];
    for (px, &d) in out.chunks_exact_mut(layout.quads * 2).zip(dn) {
        let q0 = d.round().clamp(CODE_MIN_DN as f32, CODE_MAX_DN as f32) as i16;
        let words = [q0, 0, -q0, 0, 0, 0];
        for (k, w) in words.iter().take(layout.quads).enumerate() {
            let bits = (*w as u16) & 0x0FFF;
            px[2 * k..2 * k + 2].copy_from_slice(&bits.to_le_bytes());
        }
    }
    if let (Some(n), Some(b)) = (frame_number, out.first_mut()) {
        *b = n;
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A 4 x 3 frame of four quads, for tests here and in the assembler's.
    pub(crate) const SMALL: QuadLayout = QuadLayout {
        width: 4,
        height: 3,
        quads: 4,
    };
    #[test]
    fn full_frame_is_614400_bytes() {
        assert_eq!(QuadLayout::OPT8241_FULL.frame_bytes(), 614_400);
    }

    #[test]
    fn sign_extension_of_12_bit_words() {
        assert_eq!(sign_extend_12(0x0000), 0);
        assert_eq!(sign_extend_12(0x07FF), 2047);
        assert_eq!(sign_extend_12(0x0800), -2048);
        assert_eq!(sign_extend_12(0x0FFF), -1);
        // bits 15:12 are not part of the value
        assert_eq!(sign_extend_12(0xF001), 1);
        assert_eq!(sign_extend_12(0xA801), -2047);
    }

    #[test]
    fn decode_is_pixel_major_row_order_and_inverts_encode() {
        let dn: Vec<f32> = (0..12).map(|i| (i as f32 - 6.0) * 100.0).collect();
        let raw = encode_quads(SMALL, &dn, None);
        assert_eq!(raw.len(), SMALL.frame_bytes());
        // pixel 1 starts at byte 8: q0 = -500 -> 0xE0C (12 bits)
        assert_eq!(
            u16::from_le_bytes([raw[8], raw[9]]),
            (-500i16 as u16) & 0xFFF
        );
        let mut dec = QuadDecoder::new(SMALL);
        dec.frame_number_in_first_byte = false;
        let mut f = Frame::new(1, 1);
        dec.decode(&raw, &mut f).unwrap();
        assert_eq!(f.width(), 4);
        assert_eq!(f.dn.data, dn);
        dec.combine = QuadCombine::Quad0MinusQuad2;
        dec.decode(&raw, &mut f).unwrap();
        assert_eq!(f.dn.data, dn);
    }

    #[test]
    fn extremes_are_flagged_saturated_and_dark_is_subtracted() {
        let mut dn = vec![0.0f32; 12];
        dn[5] = 5000.0;
        dn[6] = -5000.0;
        dn[7] = 7.0;
        let raw = encode_quads(SMALL, &dn, Some(9));
        let mut dec = QuadDecoder::new(SMALL);
        dec.set_dark_dn(Some(vec![2.0; 12])).unwrap();
        let mut f = Frame::new(4, 3);
        dec.decode(&raw, &mut f).unwrap();
        assert_eq!(f.dn.data[5], 2047.0 - 2.0);
        assert_eq!(f.dn.data[6], -2048.0 - 2.0);
        assert_eq!(f.dn.data[7], 5.0);
        assert_eq!(f.saturated.data[5], 1);
        assert_eq!(f.saturated.data[6], 1);
        assert_eq!(f.saturated_count(), 2);
        // pixel 0 carried the frame number: replaced by its neighbour
        assert_eq!(f.dn.data[0], f.dn.data[1]);
        assert!(dec.set_dark_dn(Some(vec![0.0; 3])).is_err());
    }

    #[test]
    fn a_delay_on_the_led_path_needs_the_calibrated_axis() {
        // 4 quads, the difference d delayed by a quarter period: all of it
        // in quad 1 (and -d in quad 3); quad 0 reads nothing.
        let layout = QuadLayout {
            width: 2,
            height: 1,
            quads: 4,
        };
        let raw: Vec<u8> = [0i16, 300, 0, -300, 0, -120, 0, 120]
            .iter()
            .flat_map(|v| (*v as u16 & 0xFFF).to_le_bytes())
            .collect();
        let mut dec = QuadDecoder::new(layout);
        dec.frame_number_in_first_byte = false;
        let mut f = Frame::new(2, 1);
        dec.decode(&raw, &mut f).unwrap();
        assert_eq!(f.dn.data, [0.0, 0.0], "quad 0 alone loses it");
        dec.combine = QuadCombine::Projected(PhaseAxis {
            angle_rad: std::f64::consts::FRAC_PI_2,
        });
        dec.decode(&raw, &mut f).unwrap();
        assert!((f.dn.data[0] - 300.0).abs() < 1e-3, "{:?}", f.dn.data);
        assert!((f.dn.data[1] + 120.0).abs() < 1e-3, "{:?}", f.dn.data);
    }

    #[test]
    fn phase_sums_leave_out_the_frame_number_and_saturated_pixels() {
        let layout = QuadLayout {
            width: 3,
            height: 1,
            quads: 4,
        };
        // pixel 0: the frame number; 1: d = 100 a quarter period late; 2: saturated
        let raw: Vec<u8> = [9i16, 0, 0, 0, 0, 100, 0, -100, 2047, 0, -2048, 0]
            .iter()
            .flat_map(|v| (*v as u16 & 0xFFF).to_le_bytes())
            .collect();
        let dec = QuadDecoder::new(layout);
        let s = dec.phase_sums(&raw).unwrap();
        assert_eq!((s.sum_i, s.sum_q, s.samples), (0.0, 200.0, 1));
        assert!(dec.phase_sums(&raw[..4]).is_err());
    }

    #[test]
    fn six_quads_project_against_quad_three() {
        let layout = QuadLayout {
            width: 1,
            height: 1,
            quads: 6,
        };
        // zero delay, first harmonic: q_k = d cos(60 k degrees), d = 200
        let q: [i16; 6] = [200, 100, -100, -200, -100, 100];
        let raw: Vec<u8> = q
            .iter()
            .flat_map(|v| (*v as u16 & 0xFFF).to_le_bytes())
            .collect();
        let mut dec = QuadDecoder::new(layout);
        dec.frame_number_in_first_byte = false;
        dec.combine = QuadCombine::Projected(PhaseAxis { angle_rad: 0.0 });
        let mut f = Frame::new(1, 1);
        dec.decode(&raw, &mut f).unwrap();
        assert!((f.dn.data[0] - 200.0).abs() < 1e-3, "{:?}", f.dn.data);
    }

    #[test]
    fn wrong_length_is_a_typed_error() {
        let dec = QuadDecoder::new(SMALL);
        let mut f = Frame::new(4, 3);
        let e = dec.decode(&[0u8; 10], &mut f).unwrap_err();
        assert_eq!(
            e,
            DecodeError::Length {
                expected: 96,
                got: 10
            }
        );
    }
}
