//! A dense row-major 2-D image: the one container every stage passes along.
//!
//! By hand rather than `ndarray`/`image`: three public fields and no
//! strides or colour types keep every stage's inner loop a plain slice loop.

/// Row-major image of `width * height` samples.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Image<T> {
    pub width: usize,
    pub height: usize,
    pub data: Vec<T>,
}

impl<T: Clone + Default> Image<T> {
    /// An image filled with `T::default()`.
    pub fn new(width: usize, height: usize) -> Self {
        Self::filled(width, height, T::default())
    }
}

impl<T: Clone> Image<T> {
    pub fn filled(width: usize, height: usize, value: T) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }
}

impl<T> Image<T> {
    /// Wraps `data`; `None` when its length is not `width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Option<Self> {
        (data.len() == width * height).then_some(Self {
            width,
            height,
            data,
        })
    }

    pub fn len(&self) -> usize {
        self.data.len()
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    #[inline]
    pub fn index(&self, x: usize, y: usize) -> usize {
        y * self.width + x
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize) -> &T {
        &self.data[y * self.width + x]
    }

    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    pub fn same_size<U>(&self, other: &Image<U>) -> bool {
        self.width == other.width && self.height == other.height
    }
}

/// An image whose size is not the one expected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("frame is {got_w}x{got_h}, expected {want_w}x{want_h}")]
pub struct SizeMismatch {
    pub want_w: usize,
    pub want_h: usize,
    pub got_w: usize,
    pub got_h: usize,
}

impl SizeMismatch {
    /// `got` (width, height) where `want` was expected.
    pub fn new(want: (usize, usize), got: (usize, usize)) -> Self {
        Self {
            want_w: want.0,
            want_h: want.1,
            got_w: got.0,
            got_h: got.1,
        }
    }

    /// Ok when `got` (width, height) is `want`.
    pub fn check(want: (usize, usize), got: (usize, usize)) -> Result<(), Self> {
        if want == got {
            Ok(())
        } else {
            Err(Self::new(want, got))
        }
    }
}
