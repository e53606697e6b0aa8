//! Configuration: `/etc/sdi/sdid.toml` (or `--config`), then command-line
//! overrides. The file format is a contract shared with `sdictl doctor`, so
//! its types live in the `sdi-config` crate; this module re-exports them.

pub use sdi_config::*;
