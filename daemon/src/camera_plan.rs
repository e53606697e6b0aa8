//! The cameras one sdid serves and each one's configuration: every board
//! attached at start (unless `[board] serial` names one), the recording,
//! or the simulator's `cameras` (serials `sim-0`, `sim-1`, ...). Each
//! camera's `[camera."SERIAL"]` section is laid over the file's settings;
//! with several cameras each one's outputs carry its serial ("SDI camera
//! sim-1", `sdid-view-sim-1.y4m`, PipeWire node `sdi-camera-sim-1`), so no
//! two write into the same node.

use std::path::Path;

use sdi_config::{BackendKind, Config, MAX_CAMERAS};
use sdi_core::serial::{names_a_file, plain_byte};

/// One camera to open.
#[derive(Debug, Clone)]
pub struct CameraPlan {
    /// Known before opening for the simulator and a board chosen by
    /// `[board] serial`; otherwise the opened board tells.
    pub serial: Option<String>,
    pub config: Config,
}

/// The cameras `c` asks for, in order (the first is `/org/sdi/Camera0`);
/// `boards`: the serials of the boards attached, when `c` may serve
/// every one (the board or auto backend, no `[board] serial`).
pub fn plans(c: &Config, boards: &[String]) -> Vec<CameraPlan> {
    if let Some(plans) = board_plans(c, boards) {
        return plans;
    }
    let serial = match c.backend {
        BackendKind::Sim => Some(sdi_config::sim_serial(0)),
        BackendKind::Opt8241 | BackendKind::Auto => c.board.serial.clone(),
        BackendKind::Replay => None,
    };
    if c.cameras <= 1 {
        let config = match &serial {
            Some(s) => c.for_camera(s),
            None => c.clone(),
        };
        return vec![CameraPlan { serial, config }];
    }
    c.sim_serials()
        .into_iter()
        .enumerate()
        .map(|(index, serial)| {
            let mut config = c.for_camera(&serial);
            config.seed = c.seed.wrapping_add(index as u64);
            name_outputs(&mut config, &serial);
            CameraPlan {
                serial: Some(serial),
                config,
            }
        })
        .collect()
}

/// One camera per attached board: each board chosen by its serial (so a
/// replugged board comes back to its camera, and a board plugged in later
/// is a camera of its own), each with its section; with several, outputs
/// named by serial. A board whose serial cannot name a file is left out (a
/// device chooses its own serial), as are boards past [`MAX_CAMERAS`].
fn board_plans(c: &Config, boards: &[String]) -> Option<Vec<CameraPlan>> {
    let (usable, refused): (Vec<&String>, Vec<&String>) =
        boards.iter().partition(|s| names_a_file(s));
    if !serves_boards_by_serial(c) || usable.is_empty() {
        return None;
    }
    for s in refused {
        tracing::warn!(
            "a board with serial {s:?} is not served: its serial cannot name its outputs"
        );
    }
    if usable.len() > MAX_CAMERAS as usize {
        tracing::warn!(
            "{} boards attached: serving the first {MAX_CAMERAS} by serial",
            usable.len()
        );
    }
    let count = usable.len().min(MAX_CAMERAS as usize);
    Some(
        usable
            .into_iter()
            .take(count)
            .map(|serial| board_plan(c, serial, count))
            .collect(),
    )
}

/// Whether `c` serves every board it finds, each by its serial: the board
/// or auto backend, and no `[board] serial` pinning one.
pub fn serves_boards_by_serial(c: &Config) -> bool {
    matches!(c.backend, BackendKind::Opt8241 | BackendKind::Auto) && c.board.serial.is_none()
}

/// The camera of board `serial`, one of `count` cameras (with `auto`,
/// the simulator still stands in for a board that cannot be opened).
pub fn board_plan(c: &Config, serial: &str, count: usize) -> CameraPlan {
    let mut config = c.for_camera(serial);
    config.board.serial = Some(serial.to_owned());
    config.cameras = count as u32;
    if count > 1 {
        name_outputs(&mut config, serial);
    }
    CameraPlan {
        serial: Some(serial.to_owned()),
        config,
    }
}

/// The boards of `attached` that are not cameras yet (`known`) and can be.
pub fn new_boards(known: &[String], attached: &[String]) -> Vec<String> {
    attached
        .iter()
        .filter(|s| !known.contains(s) && names_a_file(s))
        .cloned()
        .collect()
}

/// A device's serial as a camera's name on the bus: the serial itself
/// when it [names a file](names_a_file), else its usable characters
/// (others as `_`, at most 64), `fallback` when none are left. (A device
/// chooses its serial; a NUL would break every listing of the cameras.)
pub fn camera_name(serial: &str, fallback: &str) -> String {
    if names_a_file(serial) {
        return serial.to_owned();
    }
    let name: String = serial
        .chars()
        .take(64)
        .map(|c| match u8::try_from(c).is_ok_and(plain_byte) {
            true => c,
            false => '_',
        })
        .collect();
    match name.trim_matches('_').is_empty() {
        true => fallback.to_owned(),
        false => name,
    }
}

/// Each output of one of several cameras, named with its serial.
fn name_outputs(c: &mut Config, serial: &str) {
    let o = &mut c.output;
    o.label = format!("{} {serial}", o.label);
    if !o.data_label.is_empty() {
        o.data_label = format!("{} {serial}", o.data_label);
    }
    let fifo = match o.y4m_path.as_str() {
        "" => crate::sink::y4m::default_fifo_path(),
        p => Path::new(p).to_owned(),
    };
    o.y4m_path = with_serial(&fifo, serial).display().to_string();
}

/// `dir/view.y4m` -> `dir/view-SERIAL.y4m`.
fn with_serial(path: &Path, serial: &str) -> std::path::PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned());
    let name = match (stem, path.extension()) {
        (Some(stem), Some(ext)) => format!("{stem}-{serial}.{}", ext.to_string_lossy()),
        (Some(stem), None) => format!("{stem}-{serial}"),
        (None, _) => format!("sdid-view-{serial}.y4m"),
    };
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sim(cameras: u32) -> Config {
        Config {
            backend: BackendKind::Sim,
            cameras,
            ..Config::default()
        }
    }

    #[test]
    fn one_camera_keeps_its_outputs() {
        let p = plans(&sim(1), &[]);
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].serial.as_deref(), Some("sim-0"));
        assert_eq!(p[0].config.output, Config::default().output);
    }

    #[test]
    fn several_cameras_each_get_their_serial_outputs_and_seed() {
        let mut c = sim(2);
        c.output.y4m_path = "/run/x/view.y4m".into();
        c.output.data_label = "SDI data".into();
        let p = plans(&c, &[]);
        let serials: Vec<_> = p.iter().filter_map(|p| p.serial.clone()).collect();
        assert_eq!(serials, ["sim-0", "sim-1"]);
        assert_eq!(p[1].config.output.label, "SDI camera sim-1");
        assert_eq!(p[1].config.output.data_label, "SDI data sim-1");
        assert_eq!(p[0].config.output.y4m_path, "/run/x/view-sim-0.y4m");
        assert_eq!(p[1].config.output.y4m_path, "/run/x/view-sim-1.y4m");
        assert_ne!(p[0].config.seed, p[1].config.seed);
        // The sinks read the count: each PipeWire camera is named by serial.
        assert!(p.iter().all(|p| p.config.cameras == 2));
    }

    #[test]
    fn a_board_named_by_serial_takes_its_section() {
        let mut c = Config {
            backend: BackendKind::Opt8241,
            ..Config::default()
        };
        c.board.serial = Some("A1B2".into());
        c.camera.insert(
            "A1B2".into(),
            sdi_config::CameraSection {
                mode: Some(sdi_core::mode::ModeId::DepthEdge),
                ..Default::default()
            },
        );
        let p = plans(&c, &[]);
        assert_eq!(p[0].config.mode, sdi_core::mode::ModeId::DepthEdge);
    }

    #[test]
    fn every_attached_board_is_a_camera_of_its_serial() {
        let boards = ["B2".to_string(), "A1".into(), "../../etc/x".into()];
        let mut c = Config::default();
        c.camera.insert(
            "B2".into(),
            sdi_config::CameraSection {
                mode: Some(sdi_core::mode::ModeId::DepthEdge),
                ..Default::default()
            },
        );
        let p = plans(&c, &boards);
        let serials: Vec<_> = p.iter().map(|p| p.config.board.serial.clone()).collect();
        assert_eq!(serials, [Some("B2".into()), Some("A1".into())]);
        assert!(p.iter().all(|p| p.config.backend == BackendKind::Auto));
        assert_eq!(p[0].config.mode, sdi_core::mode::ModeId::DepthEdge);
        assert_eq!(p[1].config.output.label, "SDI camera A1");
        assert!(p.iter().all(|p| p.config.cameras == 2));
        // One board: one camera, pinned to its serial, outputs as before.
        let one = plans(&c, &boards[..1]);
        assert_eq!(one.len(), 1);
        assert_eq!(one[0].config.board.serial.as_deref(), Some("B2"));
        assert_eq!(one[0].config.output, Config::default().output);
        // A board named in [board]: that one, as before.
        c.board.serial = Some("A1".into());
        assert_eq!(plans(&c, &boards).len(), 1);
        // The simulator is not a board.
        assert_eq!(plans(&sim(1), &boards).len(), 1);
    }

    #[test]
    fn a_board_plugged_later_is_new_unless_known_or_unnamable() {
        let known = ["A1".to_string()];
        let attached = ["A1".to_string(), "B2".into(), "a/b".into()];
        assert_eq!(new_boards(&known, &attached), ["B2"]);
        let p = board_plan(&Config::default(), "B2", 2);
        assert_eq!(p.config.board.serial.as_deref(), Some("B2"));
        assert_eq!(p.config.output.label, "SDI camera B2");
    }

    #[test]
    fn a_hostile_serial_is_named_safely() {
        assert_eq!(camera_name("A1B2", "opt8241"), "A1B2");
        assert_eq!(camera_name("a\0b/c", "opt8241"), "a_b_c");
        assert_eq!(camera_name("\0\0", "opt8241"), "opt8241");
        assert_eq!(camera_name(&"x".repeat(100), "opt8241").len(), 64);
    }
}
