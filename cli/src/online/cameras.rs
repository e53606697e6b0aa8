//! `sdictl list`, and the camera a command talks to: `--camera SERIAL`,
//! or the only one ([`sdi_api::cameras`]).

use std::path::Path;

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
/// nodes, then the nodes' `/dev/v4l/by-id` links where udev made some).
pub async fn run(conn: &zbus::Connection, json: bool) -> Result<(), CliError> {
    let cameras = cameras::list(conn).await?;
    if json {
        let rows: Vec<_> = cameras
            .iter()
            .map(|c| {
                json!({"serial": c.serial, "path": c.path, "backend": c.backend,
                       "mode": c.mode, "device": c.device,
                       "links": by_id_links(Path::new(BY_ID), &c.device)})
            })
            .collect();
        outln!("{}", json!({ "cameras": rows }))?;
        return Ok(());
    }
    for c in &cameras {
        let links = by_id_links(Path::new(BY_ID), &c.device);
        let links = match links.is_empty() {
            true => String::new(),
            false => format!("\t{}", links.join(" ")),
        };
        outln!(
            "{}\t{}\t{}\t{}{links}",
            c.serial,
            c.backend,
            c.mode,
            c.device
        )?;
    }
    Ok(())
}

/// Where udev links SDI's loopback nodes (udev/70-sdi-loopback.rules).
const BY_ID: &str = "/dev/v4l/by-id";

/// The `sdi-*` links in `dir` to the nodes a camera's `device` names
/// ("sensor -> /dev/video42 + /dev/video43 (Y16 data)"), in the nodes'
/// order; none where udev made none (another label, no rules installed).
fn by_id_links(dir: &Path, device: &str) -> Vec<String> {
    let Some((_, outputs)) = device.rsplit_once(" -> ") else {
        return Vec::new();
    };
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut links: Vec<(String, std::path::PathBuf)> = entries
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("sdi-"))
        .filter_map(|e| {
            let target = std::fs::canonicalize(e.path()).ok()?;
            Some((e.path().display().to_string(), target))
        })
        .collect();
    links.sort();
    outputs
        .split_whitespace()
        .filter(|w| w.starts_with('/'))
        .flat_map(|node| {
            links
                .iter()
                .filter(move |(_, target)| target.as_path() == Path::new(node))
                .map(|(link, _)| link.clone())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::symlink;

    #[test]
    fn by_id_links_follow_the_named_nodes() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().canonicalize().unwrap();
        let node = |n: &str| {
            let p = root.join(n);
            std::fs::write(&p, "").unwrap();
            p.display().to_string()
        };
        let (view, data, other) = (node("video42"), node("video43"), node("video44"));
        let by_id = root.join("by-id");
        std::fs::create_dir(&by_id).unwrap();
        symlink(&data, by_id.join("sdi-sim-0-data")).unwrap();
        symlink(&view, by_id.join("sdi-sim-0-view")).unwrap();
        symlink(&other, by_id.join("sdi-sim-1-view")).unwrap();
        symlink(&view, by_id.join("usb-Not_SDI-video-index0")).unwrap();
        symlink(root.join("gone"), by_id.join("sdi-dangling")).unwrap();
        let link = |n: &str| by_id.join(n).display().to_string();
        assert_eq!(
            by_id_links(&by_id, &format!("sim -> {view} + {data} (Y16 data)")),
            [link("sdi-sim-0-view"), link("sdi-sim-0-data")]
        );
        assert!(by_id_links(&by_id, "sim -> /tmp/sdid-view.y4m").is_empty());
        assert!(by_id_links(&by_id, "no arrow").is_empty());
        assert!(by_id_links(&root.join("none"), &format!("sim -> {view}")).is_empty());
    }
}
