//! The cameras one sdid serves and each one's configuration: the board or
//! recording the configuration names, or the simulator's `cameras`
//! (serials `sim-0`, `sim-1`, ...). Each camera's `[camera."SERIAL"]`
//! section is laid over the file's settings; with several cameras each
//! one's outputs carry its serial ("SDI camera sim-1",
//! `sdid-view-sim-1.y4m`), so no two write into the same node.

use std::path::Path;

use sdi_config::{BackendKind, Config};

/// One camera to open.
#[derive(Debug, Clone)]
pub struct CameraPlan {
    /// Known before opening for the simulator and a board chosen by
    /// `[board] serial`; otherwise the opened board tells.
    pub serial: Option<String>,
    pub config: Config,
}

/// The cameras `c` asks for, in order (the first is `/org/sdi/Camera0`).
pub fn plans(c: &Config) -> Vec<CameraPlan> {
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
        let p = plans(&sim(1));
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].serial.as_deref(), Some("sim-0"));
        assert_eq!(p[0].config.output, Config::default().output);
    }

    #[test]
    fn several_cameras_each_get_their_serial_outputs_and_seed() {
        let mut c = sim(2);
        c.output.y4m_path = "/run/x/view.y4m".into();
        c.output.data_label = "SDI data".into();
        let p = plans(&c);
        let serials: Vec<_> = p.iter().filter_map(|p| p.serial.clone()).collect();
        assert_eq!(serials, ["sim-0", "sim-1"]);
        assert_eq!(p[1].config.output.label, "SDI camera sim-1");
        assert_eq!(p[1].config.output.data_label, "SDI data sim-1");
        assert_eq!(p[0].config.output.y4m_path, "/run/x/view-sim-0.y4m");
        assert_eq!(p[1].config.output.y4m_path, "/run/x/view-sim-1.y4m");
        assert_ne!(p[0].config.seed, p[1].config.seed);
        // The sinks read the count: PipeWire carries one camera.
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
        let p = plans(&c);
        assert_eq!(p[0].config.mode, sdi_core::mode::ModeId::DepthEdge);
    }
}
