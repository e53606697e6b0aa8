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

/// The source row each row of a `dh`-row frame shows when a `w` x `h`
/// image is letterboxed into `dw` x `dh` (None: a bar). Rows that repeat
/// their predecessor's source are copies of it, for every packing.
pub fn source_rows(w: usize, h: usize, dw: usize, dh: usize) -> Vec<Option<usize>> {
    if w == 0 || h == 0 {
        return vec![None; dh];
    }
    let r = LetterboxRect::new(w, h, dw, dh);
    (0..dh)
        .map(|y| {
            (r.y0..r.y0 + r.height)
                .contains(&y)
                .then(|| source_index(y - r.y0, h, r.height))
        })
        .collect()
}

/// Nearest-neighbour scale of `src` (w x h RGB8) into `dst` (dw x dh),
/// preserving the aspect ratio with black bars. The column map is computed
/// once, and a row showing the same source row as the one above is a copy
/// of it (every other row when doubling). Returns the row map it scaled by
/// ([`source_rows`]), so a packing can copy the same rows.
pub fn letterbox_rgb8(
    src: &[u8],
    w: usize,
    h: usize,
    dst: &mut [u8],
    dw: usize,
    dh: usize,
) -> Vec<Option<usize>> {
    dst.fill(0);
    let rows = source_rows(w, h, dw, dh);
    if w == 0 || h == 0 {
        return rows;
    }
    let r = LetterboxRect::new(w, h, dw, dh);
    let cols: Vec<usize> = (0..r.width)
        .map(|x| source_index(x, w, r.width) * 3)
        .collect();
    let row_bytes = r.width * 3;
    for y in r.y0..r.y0 + r.height {
        let Some(sy) = rows[y] else { continue };
        let start = (y * dw + r.x0) * 3;
        if y > r.y0 && rows[y - 1] == Some(sy) {
            let above = start - dw * 3;
            dst.copy_within(above..above + row_bytes, start);
            continue;
        }
        let src_row = &src[sy * w * 3..(sy + 1) * w * 3];
        let row = &mut dst[start..start + row_bytes];
        for (px, &s) in row.chunks_exact_mut(3).zip(&cols) {
            px.copy_from_slice(&src_row[s..s + 3]);
        }
    }
    rows
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scale pixel by pixel, as it was written before the column map
    /// and the row copies.
    fn naive(src: &[u8], w: usize, h: usize, dw: usize, dh: usize) -> Vec<u8> {
        let mut dst = vec![0u8; dw * dh * 3];
        let r = LetterboxRect::new(w, h, dw, dh);
        for y in 0..r.height {
            for x in 0..r.width {
                let s = (source_index(y, h, r.height) * w + source_index(x, w, r.width)) * 3;
                let d = ((r.y0 + y) * dw + r.x0 + x) * 3;
                dst[d..d + 3].copy_from_slice(&src[s..s + 3]);
            }
        }
        dst
    }

    #[test]
    fn letterbox_matches_the_pixel_by_pixel_scale() {
        let sizes = [(320, 240), (1, 1), (5, 3), (640, 480), (1000, 10), (7, 300)];
        for (w, h) in sizes {
            let src: Vec<u8> = (0..w * h * 3).map(|i| (i * 31 % 251) as u8).collect();
            for (dw, dh) in [(640, 480), (16, 8), (1, 1), (3, 7)] {
                let mut dst = vec![9u8; dw * dh * 3];
                letterbox_rgb8(&src, w, h, &mut dst, dw, dh);
                assert!(dst == naive(&src, w, h, dw, dh), "{w}x{h} into {dw}x{dh}");
                let rows = source_rows(w, h, dw, dh);
                for (y, row) in dst.chunks_exact(dw * 3).enumerate() {
                    if y > 0 && rows[y] == rows[y - 1] {
                        assert_eq!(row, &dst[(y - 1) * dw * 3..y * dw * 3], "row {y}");
                    }
                }
            }
        }
    }

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
