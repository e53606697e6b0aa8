//! The view every sink publishes: a mode's output colormapped
//! ([`crate::display`]), letterboxed into the sink's geometry and packed into
//! its pixel format (YUYV, RGB24, GREY, Y16) by [`ViewRenderer`], plus the
//! "no signal" cards ([`no_signal_card`]).
//! One renderer for the v4l2loopback, PipeWire and y4m sinks, so a sink only
//! publishes bytes and each colour conversion has one definition.
//!
//! It lives in sdi-core, not in a sink's crate: it is pure computation on
//! core's [`ModeOutput`](crate::mode::ModeOutput) and [`DisplayMap`](crate::display::DisplayMap),
//! and both sdid and the PipeWire camera process (which draws its own card)
//! need it without depending on each other or on the v4l2loopback glue.

mod card;
mod format;
mod letterbox;
mod pack;
mod renderer;

pub use card::{no_signal_card, no_signal_grey, no_signal_stripes_rgb8};
pub use format::{PixelFormat, Y16_ZERO_DN};
pub use letterbox::{letterbox_rgb8, LetterboxRect};
#[cfg(test)]
pub(crate) use pack::rgb_row_to_yuyv;
pub(crate) use pack::yuv444_pixel;
pub use pack::{dn_to_y16, rgb8_to_yuv444_planes, yuv444_planes_mut, PackError, Packer, Src};
pub use renderer::ViewRenderer;
