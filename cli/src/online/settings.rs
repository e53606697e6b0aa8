//! `sdictl modes`, `set-mode`, `get` and `set`: properties read and
//! settings changed through the typed proxy; the settable names are
//! `sdi_api::Setting`'s table.

use sdi_api::{Camera1Proxy, Properties, Setting};
use serde_json::{json, Value as Json};

use super::wire_json;
use crate::exit::CliError;
use crate::stdout::outln;

pub async fn modes(camera: &Camera1Proxy<'_>, json: bool) -> Result<(), CliError> {
    let modes = camera.modes().await?;
    let current = camera.mode().await?;
    if json {
        outln!("{}", json!({"modes": modes, "current": current}))?;
    } else {
        for m in modes {
            let mark = if m == current { "*" } else { " " };
            outln!("{mark} {m}")?;
        }
    }
    Ok(())
}

pub async fn set_mode(camera: &Camera1Proxy<'_>, mode: &str, json: bool) -> Result<(), CliError> {
    let (sequence, timestamp_us) = camera.set_mode(mode).await?;
    if json {
        outln!(
            "{}",
            json!({"mode": mode, "first_sequence": sequence, "first_timestamp_us": timestamp_us})
        )?;
    } else {
        outln!("{mode} from frame {sequence} (timestamp {timestamp_us} us)")?;
    }
    Ok(())
}

/// Prints one property, named as on the bus or in kebab or snake case.
pub async fn get(camera: &Camera1Proxy<'_>, property: &str, json: bool) -> Result<(), CliError> {
    // "exposure-us", "exposure_us" and "ExposureUs" all name `ExposureUs`.
    let name = sdi_api::contract::bus_name(property);
    let Some(value) = Properties::read_one(camera, &name).await else {
        return Err(CliError::Usage(format!(
            "unknown property '{property}'; properties: {}",
            Properties::names().join(", ")
        )));
    };
    let value = value?;
    match (json, wire_json::value(&value)) {
        (true, v) => outln!("{}", json!({ name: v }))?,
        (false, Json::String(s)) => outln!("{s}")?,
        (false, other) => outln!("{other}")?,
    }
    Ok(())
}

pub async fn set(
    camera: &Camera1Proxy<'_>,
    property: &str,
    value: &str,
    json: bool,
) -> Result<(), CliError> {
    let setting = Setting::from_user(property)?;
    let (sequence, timestamp_us) = setting.change(value)?.send(camera).await?;
    let name = setting.property_name();
    if json {
        outln!(
            "{}",
            json!({ name: value, "first_sequence": sequence, "first_timestamp_us": timestamp_us })
        )?;
    } else {
        outln!("{name} = {value} from frame {sequence} (timestamp {timestamp_us} us)")?;
    }
    Ok(())
}
