//! `--sensor ti|pmd|FILE.toml`: a sensor description, parsed once at the edge.

use std::path::Path;

use sdi_core::sensor::description::{PMD_TOML, TI_TOML};
use sdi_core::sensor::SensorDescription;

/// Clap value parser: a preset name or the path of a TOML description.
pub fn parse_sensor(s: &str) -> Result<SensorDescription, String> {
    let text = match s {
        "ti" => TI_TOML.to_string(),
        "pmd" => PMD_TOML.to_string(),
        path => std::fs::read_to_string(Path::new(path)).map_err(|e| {
            format!("'{path}' is neither a preset (ti, pmd) nor a readable sensor file: {e}")
        })?,
    };
    SensorDescription::from_toml(&text).map_err(|e| format!("'{s}': {e}"))
}
