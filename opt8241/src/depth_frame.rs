//! The depth frame ("phase, amplitude, ambient and flags"), the output the
//! saturation probe ([`crate::saturation_probe`]) switches to for one frame,
//! as data: the `output_mode` values, its format and its saturation flags.
//!
//! Depth frame, `pixel_data_size` = 4 and `op_data_arrange_mode` = 0
//! (both written at open, `plan.rs`): per pixel, in row order, two
//! little-endian 16-bit words: amplitude [11:0] | ambient [15:12], then
//! phase [11:0] | flags [15:12] (SDK `ToFFrameGenerator::_generateToFRawFrame`,
//! `dataArrangeMode == 0`). Bit 3 of the flags is set when a pixel's A or
//! B node voltage falls below `saturation_threshold` (OPT9221.dml, 0x5C36
//! [23:12]).

/// `output_mode` (0x5C25 [11:8]) for raw quads, what sdid streams.
pub const OUTPUT_MODE_RAW_QUADS: u32 = 15;
/// `output_mode` for phase, amplitude, ambient and flags (DML value 0).
pub const OUTPUT_MODE_DEPTH: u32 = 0;
/// `pixel_data_size` for 12-bit phase, 12-bit amplitude, 4-bit ambient and
/// 4-bit flags (DML value 4; 2 has no flags).
pub const PIXEL_DATA_SIZE_4_BYTES: u32 = 4;
/// `op_data_arrange_mode` continuous (DML value 0; the chip's default, 2,
/// rearranges the words in chunks of 8 pixels).
pub const OP_DATA_ARRANGE_CONTINUOUS: u32 = 0;
/// Bytes per pixel of a depth frame.
pub const DEPTH_BYTES_PER_PIXEL: usize = 4;
/// The saturation bit of the flags nibble (SDK `DenoiseFilter.cpp`,
/// `HDRFilter.cpp`: `#define SATURATED 0x08`).
pub const FLAG_SATURATED: u8 = 0x08;

/// Bytes of one depth frame of `width` x `height` pixels.
pub const fn depth_frame_bytes(width: usize, height: usize) -> usize {
    width * height * DEPTH_BYTES_PER_PIXEL
}

/// A depth frame of the wrong size.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("depth frame has {got} bytes, expected {expected}")]
pub struct DepthFrameLength {
    pub expected: usize,
    pub got: usize,
}

/// The saturation flag of every pixel of a depth frame (1 = saturated),
/// into `out` (resized to `width * height`).
pub fn saturated_from_depth(
    raw: &[u8],
    width: usize,
    height: usize,
    out: &mut Vec<u8>,
) -> Result<(), DepthFrameLength> {
    let expected = depth_frame_bytes(width, height);
    if raw.len() != expected {
        return Err(DepthFrameLength {
            expected,
            got: raw.len(),
        });
    }
    out.clear();
    out.extend(raw.chunks_exact(DEPTH_BYTES_PER_PIXEL).map(|px| {
        // flags are bits 15:12 of the second word: the high nibble of byte 3
        u8::from((px[3] >> 4) & FLAG_SATURATED != 0)
    }));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn depth_pixel(amplitude: u16, ambient: u16, phase: u16, flags: u16) -> [u8; 4] {
        let w0 = (amplitude & 0xFFF) | (ambient << 12);
        let w1 = (phase & 0xFFF) | (flags << 12);
        let (a, b) = (w0.to_le_bytes(), w1.to_le_bytes());
        [a[0], a[1], b[0], b[1]]
    }

    #[test]
    fn the_flag_is_bit_3_of_the_second_words_high_nibble() {
        let raw: Vec<u8> = [
            depth_pixel(100, 2, 0xFFF, 0x0),
            depth_pixel(0, 0xF, 0xFFF, 0x8),
            depth_pixel(4095, 0xF, 0, 0x7),
            depth_pixel(1, 0, 1, 0xF),
        ]
        .concat();
        let mut sat = Vec::new();
        saturated_from_depth(&raw, 2, 2, &mut sat).unwrap();
        assert_eq!(sat, [0, 1, 0, 1]);
        assert_eq!(
            saturated_from_depth(&raw[1..], 2, 2, &mut sat),
            Err(DepthFrameLength {
                expected: 16,
                got: 15
            })
        );
    }

    #[test]
    fn a_depth_frame_is_never_as_long_as_a_raw_quad_frame() {
        // the assembler tells them apart by length: 4 bytes against 2 per quad
        for quads in [4usize, 6] {
            assert!(depth_frame_bytes(320, 240) < 320 * 240 * quads * 2);
        }
    }
}
