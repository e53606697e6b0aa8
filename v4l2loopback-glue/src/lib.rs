//! Publishing SDI frames on a v4l2loopback device, so browsers, ffmpeg and
//! OpenCV see a real V4L2 camera.
//!
//! # Usage
//!
//! ```no_run
//! use v4l2loopback_glue::{find_device, LoopbackWriter, LoopbackFormat};
//! # fn main() -> Result<(), v4l2loopback_glue::GlueError> {
//! let dev = find_device("SDI view")?; // path + module version
//! let mut view = LoopbackWriter::open(&dev.path, LoopbackFormat::view(30))?;
//! let yuyv = vec![0u8; 640 * 480 * 2]; // packed by sdi_core::view
//! view.write(&yuyv, 1_000_000)?; // sensor timestamp in µs
//! view.write_no_signal(1_033_333)?; // sensor paused: after the last frame
//! let _watchers: Option<u32> = view.watchers(); // None on 0.12.x
//! # Ok(()) }
//! ```
//!
//! * [`find_device`] / [`create_device`] / [`find_or_add_device`] / [`query_device`] /
//!   [`remove_device`]: the node by card label, by module version (0.12.x:
//!   module parameters only; 0.13/0.14: legacy control ioctls; 0.15+:
//!   renumbered control ioctls + [`control_version`]).
//! * [`LoopbackWriter::watchers`]: readers streaming, from the client-usage
//!   event (0.13+), so the daemon powers the light sources only while
//!   someone watches.
//! * [`LoopbackWriter::open`] negotiates [`LoopbackFormat`] (VIDIOC_S_FMT on the
//!   output type, VIDIOC_S_PARM), sets `keep_format`, clears `sustain_framerate`,
//!   requests mmap buffers (falls back to `write()`), STREAMONs and shows the
//!   "no signal" card (stamped at the open), so a reader can open at once and keeps working across
//!   daemon restarts.
//! * Two profiles: [`LoopbackFormat::view`] (YUYV 640x480, browser-safe) and
//!   [`LoopbackFormat::raw`] (Y16 at the sensor size; signed DN are stored as
//!   `dn + 32768`, see [`PixelFormat::Y16`]).
//! * Frames arrive packed in the node's format: the glue does device I/O
//!   only, rendering and colour conversion are `sdi_core::view`'s. No
//!   allocation per frame.
//! * Errors are typed ([`GlueError`]): EBUSY, EINVAL, ENODEV, a locked format
//!   under streaming readers, a missing module (with its modprobe command).
//!
//! The V4L2 ioctls are by hand (`sys.rs`), not the `v4l` crate's, because
//! v4l 0.14 panics on hostile input here (its `enum_devices`/`Node::index`
//! unwrap a `/dev/video*` name without digits or not UTF-8, its
//! `Capabilities` unwraps a non-UTF-8 card label, which any user of the
//! control device can set), lacks `device_caps` (exclusive_caps), and always
//! opens `O_NONBLOCK` without adopting a descriptor. The tests' Rust capture
//! client is `capture.rs` over the same `sys.rs` (v4l's bindings need
//! libclang to build); the independent readers are ffmpeg, GStreamer,
//! OpenCV, v4l2-compliance and the browsers.

mod capture;
mod device;
mod error;
mod format;
mod sys;
mod writer;

pub use capture::{capture_format, driver_of, CaptureFormat, CaptureReader, Captured};
pub use device::{
    control_version, create_device, find_device, find_or_add_device, modprobe_command,
    query_device, remove_device, video_nr, CreateOptions, Found, LoopbackDevice, ModuleVersion,
    NodeInfo, LABEL_MAX,
};
pub use error::GlueError;
pub use format::{IoMethod, LoopbackFormat, PixelFormat, Y16_ZERO_DN};
pub use writer::{DriverFeatures, LoopbackWriter};
