//! The one definition of sdid's D-Bus contract, `org.sdi.Camera1` on
//! `/org/sdi/Camera0` (and `Camera1` ... with several cameras, listed by
//! the object manager at `/org/sdi`) of `org.sdi.Daemon`: the daemon serves it, `sdictl`
//! and the tests call it through [`Camera1Proxy`]. Every reply that is a
//! dictionary on the wire (`a{sv}`) is a typed struct here ([`types`]);
//! every error is a variant of [`SdiError`]; the settings a client changes
//! are one table, [`Setting`]. `daemon/dbus/org.sdi.Camera1.xml` is the
//! served introspection, checked by `tests/tests/integration/dbus_api.rs`;
//! `tests/tests/integration/dbus_contract.rs` checks the proxy against it both ways.
#![forbid(unsafe_code)]

pub mod board_ids;
pub mod bus;
pub mod cameras;
pub mod contract;
pub mod error;
pub mod frame_stream;
pub mod proxy;
pub mod setting;
pub mod types;
pub mod wire_json;

pub use error::SdiError;
pub use proxy::{Camera1Proxy, Properties};
pub use setting::{Change, Setting, SettingError, SettingKind};
pub use types::{
    CalibrationReply, DarkFrameReply, JobProgress, PhaseCalibrationReply, RecordingReply, Stats,
};

/// Well-known bus name of sdid.
pub const BUS_NAME: &str = "org.sdi.Daemon";
/// The first camera's object (the only one with one board).
pub const OBJECT_PATH: &str = "/org/sdi/Camera0";
/// Where `org.freedesktop.DBus.ObjectManager` lists every camera, each
/// with its `Serial`.
pub const CAMERAS_PATH: &str = "/org/sdi";

/// The object of the camera sdid opened `index`-th: `/org/sdi/Camera<index>`
/// (a camera that comes back keeps its index).
pub fn camera_path(index: usize) -> String {
    format!("{CAMERAS_PATH}/Camera{index}")
}
/// The camera interface.
pub const INTERFACE: &str = "org.sdi.Camera1";
