//! `sdictl list`, and the camera a command talks to: `--camera SERIAL`,
//! or the only one ([`sdi_api::cameras`]).

use sdi_api::cameras::{self, ChooseError};
use sdi_api::Camera1Proxy;
use serde_json::json;

use crate::exit::CliError;
use crate::stdout::outln;

/// The proxy of the camera `wanted` names, or of the only one.
pub async fn chosen(
    conn: &zbus::Connection,
    wanted: Option<&str>,
) -> Result<Camera1Proxy<'static>, CliError> {
    let listed = cameras::list(conn).await?;
    let path = cameras::choose(&listed, wanted)
        .map_err(|e| match e {
            ChooseError::NoCamera => CliError::Runtime(format!("{e} (sdictl doctor)")),
            e => CliError::Usage(format!("{e} (--camera SERIAL; sdictl list)")),
        })?
        .path
        .clone();
    Ok(cameras::proxy(conn, path, zbus::proxy::CacheProperties::Lazily).await?)
}

/// The proxy of the first camera sdid opened (the viewer's start when
/// none is named: its page picks among several).
pub async fn first(conn: &zbus::Connection) -> Result<Camera1Proxy<'static>, CliError> {
    let listed = cameras::list(conn).await?;
    let path = listed
        .first()
        .ok_or_else(|| CliError::Runtime(format!("{} (sdictl doctor)", ChooseError::NoCamera)))?
        .path
        .clone();
    Ok(cameras::proxy(conn, path, zbus::proxy::CacheProperties::Lazily).await?)
}

/// `sdictl list`: one line per camera (serial, backend, mode, device and
/// nodes).
pub async fn run(conn: &zbus::Connection, json: bool) -> Result<(), CliError> {
    let cameras = cameras::list(conn).await?;
    if json {
        let rows: Vec<_> = cameras
            .iter()
            .map(|c| {
                json!({"serial": c.serial, "path": c.path, "backend": c.backend,
                       "mode": c.mode, "device": c.device})
            })
            .collect();
        outln!("{}", json!({ "cameras": rows }))?;
        return Ok(());
    }
    for c in &cameras {
        outln!("{}\t{}\t{}\t{}", c.serial, c.backend, c.mode, c.device)?;
    }
    Ok(())
}
