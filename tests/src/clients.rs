//! The real `sdid` on v4l2loopback inside the VM, for the tests of the
//! programs people open on it (GStreamer, browsers, PipeWire): the view node
//! and the Y16 data node, a private bus, `sdictl` on it.

use std::path::{Path, PathBuf};
use std::process::{Child, Output, Stdio};
use std::time::Duration;

use crate::dbus::{sdictl, Bus, Daemon};
use crate::loopback::{self, ModuleBuild, ModuleParams};
use crate::process::stdout_of;
use crate::wait::wait_until;

/// Card labels of the two nodes.
pub const VIEW_LABEL: &str = "SDI camera";
pub const DATA_LABEL: &str = "SDI data";
/// Simulator sensor presets: `sdid --sensor NAME`, and its frame size.
#[derive(Clone, Copy, Debug)]
pub struct Sensor {
    pub name: &'static str,
    pub width: usize,
    pub height: usize,
}

/// The small sensor (165x120) keeps the simulator cheap under TCG.
pub const PMD: Sensor = Sensor {
    name: "pmd",
    width: 165,
    height: 120,
};
/// The board's OPT8241 (320x240): an even row width (GStreamer cannot map
/// 165-pixel Y16 rows, see docs/loopback.md).
pub const TI: Sensor = Sensor {
    name: "ti",
    width: 320,
    height: 240,
};

/// Loads Debian's v4l2loopback with the view and data nodes as udev/modprobe.d
/// does (exclusive_caps=1, max_buffers=10).
pub fn load_module(view_nr: u32, data_nr: u32) {
    load_module_build(ModuleBuild::Debian0127, view_nr, data_nr);
}

/// Like [`load_module`], for module `build`.
pub fn load_module_build(build: ModuleBuild, view_nr: u32, data_nr: u32) {
    let mut p = ModuleParams::nodes(&[(view_nr, VIEW_LABEL), (data_nr, DATA_LABEL)]);
    p.extra.push("max_buffers=10".into());
    if let Err(e) = loopback::load_module(build, &p) {
        panic!("loading {build} failed: {e}");
    }
}

/// `sdid` publishing on the view and data nodes, killed on drop.
pub struct Sdid {
    pub bus: Bus,
    child: Option<Child>,
    pub view: PathBuf,
    pub data: PathBuf,
    config: PathBuf,
    fps: String,
    pub sensor: Sensor,
    /// `--backend ...` (and `--sensor` for the simulator).
    backend: Vec<String>,
    /// `--sink`, the environment added and where stderr goes (default:
    /// loopback, none, inherited).
    sink: &'static str,
    env: Vec<(String, String)>,
    log: Option<PathBuf>,
}

/// `--backend sim --sensor NAME`.
fn sim_backend(sensor: Sensor) -> Vec<String> {
    ["--backend", "sim", "--sensor", sensor.name]
        .map(str::to_owned)
        .to_vec()
}

impl Sdid {
    /// Starts sdid (simulator, `sensor`, `fps`) and waits until it serves
    /// D-Bus and both nodes are capture devices.
    pub fn start(view_nr: u32, data_nr: u32, sensor: Sensor, fps: u32) -> Self {
        Self::new(view_nr, data_nr, sensor, fps, "", sim_backend(sensor)).started()
    }

    /// Starts sdid on the board of serial `serial` (the USB board emulator,
    /// streaming `sensor`'s size as its ROI), with "no signal" frames while
    /// the board is unplugged (`on_unplug = "no-signal"`, the default).
    pub fn start_on_board(
        view_nr: u32,
        data_nr: u32,
        sensor: Sensor,
        fps: u32,
        serial: &str,
    ) -> Self {
        let board = format!(
            "[board]\nserial = \"{serial}\"\non_unplug = \"no-signal\"\nroi = [0, 0, {}, {}]\n",
            sensor.width, sensor.height
        );
        let backend = ["--backend", "opt8241"].map(str::to_owned);
        Self::new(view_nr, data_nr, sensor, fps, &board, backend.to_vec()).started()
    }

    /// Starts sdid on the simulator with `--sink auto` in a user session
    /// (`env`: its `XDG_RUNTIME_DIR`, ...): the loopback nodes and, where
    /// that session's PipeWire runs, the PipeWire camera beside them. Its
    /// stderr, with every published PipeWire buffer's CRC-32
    /// (`sdid::pipewire::frames=trace`), and the camera process's, which
    /// inherits it, are appended to `log`.
    pub fn start_auto(
        view_nr: u32,
        data_nr: u32,
        sensor: Sensor,
        fps: u32,
        env: Vec<(String, String)>,
        log: &Path,
    ) -> Self {
        let mut s = Self::new(view_nr, data_nr, sensor, fps, "", sim_backend(sensor));
        s.sink = "auto";
        s.env = env;
        s.log = Some(log.to_owned());
        s.started()
    }

    /// [`Self::spawn`]ed.
    fn started(mut self) -> Self {
        self.spawn();
        self
    }

    /// Writes `sdid.toml` (the node labels, then `extra_config`) and a new
    /// bus; sdid is not started yet (loopback sink, inherited stderr).
    fn new(
        view_nr: u32,
        data_nr: u32,
        sensor: Sensor,
        fps: u32,
        extra_config: &str,
        backend: Vec<String>,
    ) -> Self {
        let dir = Path::new("/tmp/sdi-clients");
        std::fs::create_dir_all(dir).expect("mkdir /tmp/sdi-clients");
        let config = dir.join("sdid.toml");
        std::fs::write(
            &config,
            format!(
                "[output]\nlabel = \"{VIEW_LABEL}\"\ndata_label = \"{DATA_LABEL}\"\n{extra_config}"
            ),
        )
        .expect("write sdid.toml");
        Self {
            bus: Bus::start(),
            child: None,
            view: PathBuf::from(format!("/dev/video{view_nr}")),
            data: PathBuf::from(format!("/dev/video{data_nr}")),
            config,
            fps: fps.to_string(),
            sensor,
            backend,
            sink: "loopback",
            env: Vec::new(),
            log: None,
        }
    }

    fn spawn(&mut self) {
        let mut cmd = Daemon::bare_command(&self.bus, &[]);
        cmd.arg("--config")
            .arg(&self.config)
            .args(&self.backend)
            .args(["--sink", self.sink])
            .args(["--frame-rate-hz", &self.fps, "--exposure-us", "2000"])
            .envs(self.env.iter().map(|(k, v)| (k, v)))
            .stdout(Stdio::null());
        if let Some(log) = &self.log {
            let file = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(log)
                .expect("open sdid's log");
            cmd.env("RUST_LOG", "info,sdid::pipewire::frames=trace")
                .stderr(file);
        }
        let child = cmd.spawn().expect("spawn sdid");
        self.child = Some(child);
        let t = wait_until(
            "sdid serving D-Bus with both nodes capture-ready",
            Duration::from_secs(60),
            || {
                self.ctl(&["get", "mode"]).status.success()
                    && loopback::advertises_capture(&self.view)
                    && loopback::advertises_capture(&self.data)
            },
        );
        eprintln!("sdid up after {:.1} s", t.as_secs_f64());
    }

    /// Stops sdid (SIGKILL: the nodes lose their producer at once).
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Kills and starts sdid again on the same bus and nodes.
    pub fn restart(&mut self) {
        self.kill();
        self.spawn();
    }

    /// Runs `sdictl` on sdid's bus.
    pub fn ctl(&self, args: &[&str]) -> Output {
        sdictl(&self.bus.address, args)
    }

    /// `sdictl set-mode`, asserting success.
    pub fn set_mode(&self, mode: &str) {
        stdout_of(&self.ctl(&["set-mode", mode]));
    }

    /// Mean colour (R, G, B) of the mode's current rendering at the sensor
    /// size, from `sdictl snapshot x.png`: what the view node letterboxes.
    pub fn snapshot_mean_rgb(&self) -> [f64; 3] {
        let png = Path::new("/tmp/sdi-clients/snap.png");
        let _ = std::fs::remove_file(png);
        stdout_of(&self.ctl(&["snapshot", &png.display().to_string()]));
        let img = image::open(png).expect("read snapshot png").to_rgb8();
        mean_rgb(img.as_raw())
    }

    /// Mean colour of the whole 640x480 view frame: the snapshot's mean
    /// over the picture rows, black letterbox bars elsewhere.
    pub fn expected_view_mean(&self) -> [f64; 3] {
        let (_, rows) = letterbox_rows(self.sensor.width, self.sensor.height);
        self.snapshot_mean_rgb().map(|c| c * rows as f64 / 480.0)
    }

    /// Mean signed DN of the latest frame, from `sdictl snapshot x.npy`.
    pub fn snapshot_mean_dn(&self) -> f64 {
        let npy = Path::new("/tmp/sdi-clients/snap.npy");
        let _ = std::fs::remove_file(npy);
        stdout_of(&self.ctl(&["snapshot", &npy.display().to_string()]));
        let file = std::fs::File::open(npy).expect("open snapshot npy");
        let (_, data) = sdi_core::npy::read_f32(file).expect("snapshot npy of f32");
        data.iter().map(|&v| f64::from(v)).sum::<f64>() / data.len().max(1) as f64
    }
}

impl Drop for Sdid {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Mean of each channel of packed RGB8.
pub fn mean_rgb(rgb: &[u8]) -> [f64; 3] {
    let mut m = [0.0; 3];
    for px in rgb.chunks_exact(3) {
        for (a, &b) in m.iter_mut().zip(px) {
            *a += f64::from(b);
        }
    }
    let n = (rgb.len() / 3).max(1) as f64;
    m.map(|a| a / n)
}

/// The largest difference between two colours, channel by channel.
pub fn off_by(a: [f64; 3], b: [f64; 3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// `sdictl set-mode MODE`, then the mean colour of the whole 640x480 view
/// frame in it, for a sensor of `width` x `height`: `sdictl snapshot` into
/// `png`, its mean over the picture rows, black bars elsewhere. `sdictl`
/// runs sdictl with the arguments given, on the daemon's bus.
pub fn set_mode_view_mean(
    sdictl: impl Fn(&[&str]) -> Output,
    mode: &str,
    png: &Path,
    width: usize,
    height: usize,
) -> [f64; 3] {
    let out = sdictl(&["set-mode", mode]);
    assert!(out.status.success(), "set-mode {mode}: {out:?}");
    let _ = std::fs::remove_file(png);
    let out = sdictl(&["snapshot", &png.display().to_string()]);
    assert!(out.status.success(), "snapshot: {out:?}");
    let img = image::open(png).expect("read snapshot png").to_rgb8();
    let (_, rows) = letterbox_rows(width, height);
    mean_rgb(img.as_raw()).map(|c| c * rows as f64 / 480.0)
}

/// Rows of the view node's letterbox: the sensor picture scaled into 640x480
/// keeps its aspect, so (top bar rows, picture rows).
pub fn letterbox_rows(w: usize, h: usize) -> (usize, usize) {
    let scale = (640.0 / w as f64).min(480.0 / h as f64);
    let sh = (h as f64 * scale) as usize;
    ((480 - sh) / 2, sh)
}
