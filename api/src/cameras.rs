//! The cameras sdid serves, as a client finds them: the object manager at
//! [`CAMERAS_PATH`] lists each `org.sdi.Camera1` object with its `Serial`;
//! a client names one by serial, and the only one is the default. One
//! definition for `sdictl --camera` and Python's `Camera(serial=...)`.

use std::collections::HashMap;

use zbus::zvariant::{OwnedObjectPath, OwnedValue};

use crate::{Camera1Proxy, BUS_NAME, CAMERAS_PATH, INTERFACE};

/// One camera as the object manager lists it.
#[derive(Debug, Clone, PartialEq)]
pub struct Listed {
    pub path: String,
    pub serial: String,
    pub backend: String,
    pub mode: String,
    /// "sensor -> output nodes".
    pub device: String,
}

/// Why no camera could be chosen.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ChooseError {
    #[error("sdid serves no camera")]
    NoCamera,
    #[error("sdid serves {} cameras ({}): choose one by serial", .0.len(), .0.join(", "))]
    Ambiguous(Vec<String>),
    #[error("no camera {wanted:?}; sdid serves: {}", .serials.join(", "))]
    Unknown {
        wanted: String,
        serials: Vec<String>,
    },
}

/// Every camera sdid serves, in the order it opened them.
pub async fn list(conn: &zbus::Connection) -> zbus::Result<Vec<Listed>> {
    let manager = zbus::fdo::ObjectManagerProxy::builder(conn)
        .destination(BUS_NAME)?
        .path(CAMERAS_PATH)?
        .build()
        .await?;
    let objects = manager.get_managed_objects().await?;
    let mut cameras: Vec<Listed> = objects
        .into_iter()
        .filter_map(|(path, interfaces)| {
            let props = interfaces
                .into_iter()
                .find(|(name, _)| name.as_str() == INTERFACE)?
                .1;
            Some(listed(path, &props))
        })
        .collect();
    cameras.sort_by_key(|c| index_of(&c.path));
    Ok(cameras)
}

fn listed(path: OwnedObjectPath, props: &HashMap<String, OwnedValue>) -> Listed {
    let text = |name: &str| {
        props
            .get(name)
            .and_then(|v| String::try_from(v.clone()).ok())
            .unwrap_or_default()
    };
    Listed {
        path: path.to_string(),
        serial: text("Serial"),
        backend: text("Backend"),
        mode: text("Mode"),
        device: text("Device"),
    }
}

/// `/org/sdi/Camera12` -> 12 (an unnumbered path last).
fn index_of(path: &str) -> u64 {
    path.rsplit("Camera")
        .next()
        .and_then(|n| n.parse().ok())
        .unwrap_or(u64::MAX)
}

/// The camera `wanted` names, or the only one.
pub fn choose<'a>(cameras: &'a [Listed], wanted: Option<&str>) -> Result<&'a Listed, ChooseError> {
    let serials = || cameras.iter().map(|c| c.serial.clone()).collect::<Vec<_>>();
    match (wanted, cameras) {
        (_, []) => Err(ChooseError::NoCamera),
        (None, [only]) => Ok(only),
        (None, _) => Err(ChooseError::Ambiguous(serials())),
        (Some(w), _) => {
            cameras
                .iter()
                .find(|c| c.serial == w)
                .ok_or_else(|| ChooseError::Unknown {
                    wanted: w.to_owned(),
                    serials: serials(),
                })
        }
    }
}

/// The proxy of the camera at `path`; `cache` as zbus's property cache.
pub async fn proxy(
    conn: &zbus::Connection,
    path: String,
    cache: zbus::proxy::CacheProperties,
) -> zbus::Result<Camera1Proxy<'static>> {
    Camera1Proxy::builder(conn)
        .path(path)?
        .cache_properties(cache)
        .build()
        .await
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(serial: &str, index: usize) -> Listed {
        Listed {
            path: crate::camera_path(index),
            serial: serial.into(),
            backend: "sim".into(),
            mode: "raw".into(),
            device: String::new(),
        }
    }

    #[test]
    fn the_only_camera_is_the_default_and_several_need_a_name() {
        let path = |r: Result<&Listed, ChooseError>| r.map(|c| c.path.clone());
        let one = [cam("sim-0", 0)];
        assert_eq!(path(choose(&one, None)), Ok("/org/sdi/Camera0".into()));
        let two = [cam("sim-0", 0), cam("sim-1", 1)];
        let e = path(choose(&two, None)).unwrap_err().to_string();
        assert!(e.contains("2 cameras (sim-0, sim-1)"), "{e}");
        assert_eq!(
            path(choose(&two, Some("sim-1"))),
            Ok("/org/sdi/Camera1".into())
        );
        let e = path(choose(&two, Some("sim-7"))).unwrap_err().to_string();
        assert!(e.contains("\"sim-7\"") && e.contains("sim-0, sim-1"), "{e}");
        assert_eq!(path(choose(&[], None)), Err(ChooseError::NoCamera));
    }

    #[test]
    fn paths_sort_by_their_number() {
        assert!(index_of("/org/sdi/Camera2") < index_of("/org/sdi/Camera10"));
        assert_eq!(index_of("/org/sdi/Other"), u64::MAX);
    }
}
