//! Typed errors of the glue.

use nix::errno::Errno;

/// Everything that can go wrong while finding a device or publishing frames.
#[derive(Debug, thiserror::Error)]
pub enum GlueError {
    #[error("the v4l2loopback kernel module is not loaded; load it with: {modprobe}")]
    ModuleNotLoaded { modprobe: String },
    #[error("no v4l2loopback device labelled {label:?}; {hint}{}", not_added_suffix(.not_added))]
    DeviceNotFound {
        label: String,
        hint: String,
        /// Why [`crate::find_or_add_device`] could not add it, if it tried.
        not_added: Option<String>,
    },
    #[error(
        "label {label:?} is {len} bytes but v4l2loopback keeps at most {max}, \
         so a node with it could never be found by its label"
    )]
    LabelTooLong {
        label: String,
        len: usize,
        max: usize,
    },
    #[error("{path} is not a v4l2loopback device (driver {driver:?})")]
    NotLoopback { path: String, driver: String },
    #[error("{op}: device busy (EBUSY): another writer owns it or too many openers")]
    Busy { op: &'static str },
    #[error("{op}: invalid argument (EINVAL): {detail}")]
    InvalidArgument { op: &'static str, detail: String },
    #[error("{op}: device vanished (ENODEV): it was removed or the module unloaded")]
    DeviceGone { op: &'static str },
    #[error(
        "format is locked to {current} (readers are streaming or keep_format is on); \
         wanted {wanted}: close the readers (or reload the device) to change it"
    )]
    FormatLocked { wanted: String, current: String },
    #[error("input is {got} but the writer expects {expected}")]
    InputMismatch { expected: String, got: String },
    #[error("not supported by v4l2loopback {version}: {what}")]
    Unsupported { version: String, what: &'static str },
    #[error("{op}: {errno}")]
    Io { op: &'static str, errno: Errno },
}

impl GlueError {
    /// Maps an errno of operation `op` to a typed error.
    pub(crate) fn from_errno(op: &'static str, errno: Errno) -> Self {
        match errno {
            Errno::EBUSY => Self::Busy { op },
            Errno::EINVAL => Self::InvalidArgument {
                op,
                detail: "rejected by the driver".into(),
            },
            Errno::ENODEV | Errno::ENXIO => Self::DeviceGone { op },
            _ => Self::Io { op, errno },
        }
    }
}

fn not_added_suffix(not_added: &Option<String>) -> String {
    not_added
        .as_ref()
        .map(|why| format!("; not added: {why}"))
        .unwrap_or_default()
}

/// `.map_err(err("OP"))` shorthand.
pub(crate) fn err(op: &'static str) -> impl Fn(Errno) -> GlueError {
    move |e| GlueError::from_errno(op, e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errnos_map_to_typed_errors() {
        assert!(matches!(
            GlueError::from_errno("x", Errno::EBUSY),
            GlueError::Busy { .. }
        ));
        assert!(matches!(
            GlueError::from_errno("x", Errno::ENODEV),
            GlueError::DeviceGone { .. }
        ));
        assert!(matches!(
            GlueError::from_errno("x", Errno::EINVAL),
            GlueError::InvalidArgument { .. }
        ));
        assert!(matches!(
            GlueError::from_errno("x", Errno::EIO),
            GlueError::Io { .. }
        ));
    }
}
