//! Fitting an image into the published geometry: nearest-neighbour scaling
//! that keeps the aspect ratio, with black bars.

/// Where a `w` x `h` image lands in a `dw` x `dh` frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LetterboxRect {
    pub x0: usize,
    pub y0: usize,
    pub width: usize,
    pub height: usize,
}

impl LetterboxRect {
    pub fn new(w: usize, h: usize, dw: usize, dh: usize) -> Self {
        let scale = (dw as f64 / w as f64).min(dh as f64 / h as f64);
        let (sw, sh) = ((w as f64 * scale) as usize, (h as f64 * scale) as usize);
        Self {
            x0: (dw - sw) / 2,
            y0: (dh - sh) / 2,
            width: sw,
            height: sh,
        }
    }
}

/// The source row or column that scaled index `i` of `scaled_n` shows, of
/// `n` (nearest neighbour): one rule for every scaled view.
pub(crate) fn source_index(i: usize, n: usize, scaled_n: usize) -> usize {
    (i * n / scaled_n).min(n - 1)
}

/// Nearest-neighbour scale of `src` (w x h RGB8) into `dst` (dw x dh),
/// preserving the aspect ratio with black bars.
pub fn letterbox_rgb8(src: &[u8], w: usize, h: usize, dst: &mut [u8], dw: usize, dh: usize) {
    dst.fill(0);
    if w == 0 || h == 0 {
        return;
    }
    let r = LetterboxRect::new(w, h, dw, dh);
    for y in 0..r.height {
        let sy = source_index(y, h, r.height);
        let start = ((r.y0 + y) * dw + r.x0) * 3;
        let row = &mut dst[start..start + r.width * 3];
        for (x, px) in row.chunks_exact_mut(3).enumerate() {
            let sx = source_index(x, w, r.width);
            let s = (sy * w + sx) * 3;
            px.copy_from_slice(&src[s..s + 3]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn letterbox_doubles_qvga() {
        let src: Vec<u8> = (0..4 * 3 * 3).map(|i| i as u8).collect();
        let mut dst = vec![0u8; 8 * 6 * 3];
        letterbox_rgb8(&src, 4, 3, &mut dst, 8, 6);
        assert_eq!(&dst[0..3], &src[0..3]);
        assert_eq!(&dst[3..6], &src[0..3]);
        assert_eq!(&dst[(8 * 5 + 7) * 3..], &src[(4 * 2 + 3) * 3..]);
    }
}
