//! The "no signal" cards shown while the sensor is paused or unplugged.

use super::pack::{Packer, Src};
use super::PixelFormat;

/// The "no signal" card in 8-bit grey: a 32-pixel checkerboard of two dark
/// greys with a bright horizontal bar through the middle.
pub fn no_signal_grey(width: usize, height: usize) -> Vec<u8> {
    let mut img = vec![0u8; width * height];
    for (y, row) in img.chunks_exact_mut(width.max(1)).enumerate() {
        let bar = y >= height * 7 / 16 && y < height * 9 / 16;
        for (x, p) in row.iter_mut().enumerate() {
            *p = if bar {
                200
            } else if (x / 32 + y / 32) % 2 == 0 {
                40
            } else {
                72
            };
        }
    }
    img
}

/// [`no_signal_grey`] packed in `format` (the loopback and PipeWire nodes' card).
pub fn no_signal_card(format: PixelFormat, width: usize, height: usize) -> Vec<u8> {
    let grey = no_signal_grey(width, height);
    let mut card = vec![0u8; width * height * format.bytes_per_pixel()];
    Packer::new(width, height, format).pack_grey8(Src::packed(&grey, width, height, 1), &mut card);
    card
}

/// The y4m stream's card in RGB8: dark grey with a diagonal stripe pattern.
pub fn no_signal_stripes_rgb8(width: usize, height: usize) -> Vec<u8> {
    let mut rgb = vec![0u8; width * height * 3];
    for (i, px) in rgb.chunks_exact_mut(3).enumerate() {
        let (x, y) = (i % width, i / width);
        let g = if (x + y) / 16 % 2 == 0 { 40 } else { 60 };
        px.copy_from_slice(&[g, g, g]);
    }
    rgb
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_signal_card_has_bar_and_checkerboard() {
        let img = no_signal_grey(64, 64);
        assert_eq!(img[0], 40);
        assert_eq!(img[32], 72);
        assert_eq!(img[32 * 64], 200);
        let rgb = no_signal_card(PixelFormat::Rgb24, 64, 64);
        assert_eq!(&rgb[..6], &[40, 40, 40, 40, 40, 40]);
        let yuyv = no_signal_card(PixelFormat::Yuyv, 64, 64);
        assert_eq!(&yuyv[..4], &[50, 128, 50, 128]);
    }
}
