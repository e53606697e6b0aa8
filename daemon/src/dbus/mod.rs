//! The D-Bus API: `org.sdi.Daemon`, `/org/sdi/Camera0`, `org.sdi.Camera1`.

pub mod camera;
pub mod client_fd;
pub mod client_file;
pub mod errors;
pub mod fairness;
pub mod job_slot;
pub mod paths;
pub mod peers;

pub use sdi_api::{camera_path, BUS_NAME, CAMERAS_PATH, INTERFACE, OBJECT_PATH};
