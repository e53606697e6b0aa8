//! The interface's errors are `sdi_api::SdiError` (`org.sdi.Error.*`), the
//! one definition shared with clients; this module adds what needs the daemon.

use sdi_core::mode::ModeId;

pub use sdi_api::error::{check_range, SdiError};

/// `InvalidMode` for an unknown mode name, listing the valid ones.
pub fn invalid_mode(given: &str) -> SdiError {
    SdiError::InvalidMode(format!(
        "unknown mode '{}'; valid modes: {}",
        given.escape_debug(),
        ModeId::names().join(", ")
    ))
}
