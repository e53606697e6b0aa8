//! `--sensor` / `sensor =`: a preset name (ti, pmd) or the path of a sensor
//! description file (TOML, see `core/sensors/`).

use std::path::Path;

use sdi_core::sensor::description::{PMD_TOML, TI_TOML};
use sdi_core::sensor::SensorDescription;

/// The description named by `spec`, validated.
pub fn load(spec: &str) -> Result<SensorDescription, String> {
    let text = match spec {
        "ti" => TI_TOML.to_string(),
        "pmd" => PMD_TOML.to_string(),
        path => std::fs::read_to_string(Path::new(path)).map_err(|e| {
            format!("sensor '{path}' is neither a preset (ti, pmd) nor a readable sensor file: {e}")
        })?,
    };
    SensorDescription::from_toml(&text).map_err(|e| format!("sensor '{spec}': {e}"))
}
