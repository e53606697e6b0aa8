//! TI OPT8241-CDK over USB (vendor bulk mode, USB 0451:9105): the I/O.
//!
//! Everything without I/O is in `sdi_opt8241` (`opt8241/src/`), shared
//! with sdictl and the fuzz targets: the register map, limits and open
//! plan, the vendor protocol over a `Transport` (`protocol`), the
//! execution of the plan (`configure`), health polling (`health`), frame
//! assembly and decoding (`frame_assembler`, `raw_quads`), the saturation
//! probe (`saturation_probe`, `depth_frame`) and the choices made from USB
//! descriptors (`descriptors`, `uvc_switch`). Here: [`usb`] (libusb
//! transport, discovery, the UVC -> bulk switch, the bulk stream threads),
//! [`hotplug`] (libusb hotplug events), [`ids`] (the board's USB IDs), and
//! [`device`], which ties them into the [`Opt8241`] the backend drives.
//! Sources of every register and request: `docs/hardware.md`.

pub mod device;
pub mod hotplug;
pub mod ids;
pub mod usb;

pub use device::{BoardError, Opt8241};
pub use usb::BoardSelector;
