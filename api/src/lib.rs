//! The one definition of sdid's D-Bus contract, `org.sdi.Camera1` on
//! `/org/sdi/Camera0` of `org.sdi.Daemon`: the daemon serves it, `sdictl`
//! and the tests call it through [`Camera1Proxy`]. Every reply that is a
//! dictionary on the wire (`a{sv}`) is a typed struct here ([`types`]);
//! every error is a variant of [`SdiError`]. `daemon/dbus/org.sdi.Camera1.xml`
//! is the served introspection, checked by `tests/tests/dbus_api.rs`.
#![forbid(unsafe_code)]

pub mod board_ids;
pub mod bus;
pub mod error;
pub mod proxy;
pub mod types;

pub use error::SdiError;
pub use proxy::Camera1Proxy;
pub use types::{CalibrationReply, DarkFrameReply, RecordingReply, Stats};

/// Well-known bus name of sdid.
pub const BUS_NAME: &str = "org.sdi.Daemon";
/// The camera object.
pub const OBJECT_PATH: &str = "/org/sdi/Camera0";
/// The camera interface.
pub const INTERFACE: &str = "org.sdi.Camera1";
