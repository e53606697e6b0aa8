//! The OPT8241-CDK's chip as data, shared by sdid (which executes it over
//! USB) and sdictl (which prints it offline): the OPT9221 register map
//! ([`registers`]), what the chip can do for a configuration ([`limits`],
//! [`pll`]), what sdid asks of it ([`config`]) and the exact register
//! sequence that opens and configures it ([`plan`]), and the depth frame
//! whose flags say which pixels saturated ([`saturation`]).
//!
//! No I/O and no libusb here, so `sdictl board plan` needs neither.
#![forbid(unsafe_code)]

pub mod config;
pub mod configure;
pub mod depth_frame;
pub mod descriptors;
pub mod frame_assembler;
pub mod health;
pub mod limits;
pub mod plan;
pub mod pll;
pub mod protocol;
pub mod range;
pub mod raw_quads;
pub mod registers;
pub mod roi;
pub mod saturation_probe;
pub mod uvc_switch;

pub use config::BoardConfig;
pub use limits::BoardLimits;
pub use plan::{open_plan, Plan, Step};
pub use pll::PllSettings;
pub use range::{OutOfRange, Range};
pub use roi::Roi;
