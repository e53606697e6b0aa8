//! `--sensor ti|pmd|FILE.toml`: a sensor description, parsed once at the edge
//! by the same [`SensorSpec`] as `sdid --sensor` and `sensor =` in sdid.toml.

use sdi_config::SensorSpec;
use sdi_core::sensor::SensorDescription;

/// Clap value parser: a preset name or the path of a TOML description.
pub fn parse_sensor(s: &str) -> Result<SensorDescription, String> {
    s.parse::<SensorSpec>()
        .and_then(|spec| spec.load())
        .map_err(|e| e.to_string())
}
