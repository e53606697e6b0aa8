//! sdi-core: the imaging science of snapshot difference imaging.
//!
//! Data flows one way: a [`scene`] is imaged by the [`simulator`] (a model of
//! the [`sensor`] driven by a [`modulation`]) into a [`frame::Frame`]; a
//! [`mode`] pipeline turns frames into signed images. No I/O happens here:
//! callers hand in buffers and writers.
#![forbid(unsafe_code)]

pub mod calibration;
pub mod dark_frame;
pub mod display;
pub mod frame;
pub mod image;
pub mod mode;
pub mod modulation;
pub mod named;
pub mod npy;
pub mod npy_header;
pub mod number;
pub mod pixel_flags;
pub mod quad_phase;
pub mod scene;
pub mod sensor;
pub mod separation;
pub mod serial;
pub mod simulator;
pub mod view;

pub use frame::Frame;
pub use image::Image;
pub use pixel_flags::PixelFlags;
