//! Typed replies printed by their D-Bus keys (`sdi_api::wire_json`).

use serde_json::Value as Json;
use zbus::zvariant;

pub use sdi_api::wire_json::value;

use crate::exit::CliError;
use crate::stdout::outln;

/// `reply` (an `a{sv}` type) as a JSON object keyed as on the wire.
pub fn object<T: serde::Serialize + zvariant::Type>(
    reply: &T,
) -> Result<serde_json::Map<String, Json>, CliError> {
    sdi_api::wire_json::object(reply).map_err(CliError::Encode)
}

/// Prints a typed reply: one JSON object, or one `key: value` line per
/// field in key order.
pub fn print<T: serde::Serialize + zvariant::Type>(reply: &T, json: bool) -> Result<(), CliError> {
    let fields = object(reply)?;
    if json {
        outln!("{}", Json::Object(fields))?;
    } else {
        for (k, v) in &fields {
            outln!("{k}: {v}")?;
        }
    }
    Ok(())
}
