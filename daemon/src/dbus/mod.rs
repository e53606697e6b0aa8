//! The D-Bus API: `org.sdi.Daemon`, `/org/sdi/Camera0`, `org.sdi.Camera1`.

pub mod camera;
pub mod client_fd;
pub mod errors;
pub mod paths;

pub const BUS_NAME: &str = "org.sdi.Daemon";
pub const OBJECT_PATH: &str = "/org/sdi/Camera0";
pub const INTERFACE: &str = "org.sdi.Camera1";
