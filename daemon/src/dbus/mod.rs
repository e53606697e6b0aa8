//! The D-Bus API: `org.sdi.Daemon`, `/org/sdi/Camera0`, `org.sdi.Camera1`.

pub mod camera;
pub mod client_fd;
pub mod client_file;
pub mod errors;
pub mod fairness;
pub mod job_slot;
pub mod paths;
pub mod peers;

pub use sdi_api::{BUS_NAME, INTERFACE, OBJECT_PATH};
