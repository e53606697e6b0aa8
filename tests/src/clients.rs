//! The real `sdid` on v4l2loopback inside the VM, for the tests of the
//! programs people open on it (GStreamer, browsers, PipeWire): the view node
//! and the Y16 data node, a private bus, `sdictl` on it.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::dbus::Bus;
use crate::loopback::{self, ModuleBuild, ModuleParams};
use crate::process::stdout_of;

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

/// Path of a binary the host test put in the environment (`SDID`, `SDICTL`).
pub fn exe(var: &str) -> PathBuf {
    PathBuf::from(std::env::var_os(var).unwrap_or_else(|| panic!("{var} from the host")))
}

/// Host side of a client VM test: the binaries the guest runs.
pub fn export_binaries() {
    std::env::set_var("SDID", crate::dbus::bin("sdid"));
    std::env::set_var("SDICTL", crate::dbus::bin("sdictl"));
}

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

/// Polls `ready` every 100 ms until it holds; panics with `what` after `limit`.
pub fn wait_until(what: &str, limit: Duration, mut ready: impl FnMut() -> bool) -> Duration {
    let t0 = Instant::now();
    while !ready() {
        assert!(t0.elapsed() < limit, "{what}: not after {limit:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
    t0.elapsed()
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
}

impl Sdid {
    /// Starts sdid (simulator, `sensor`, `fps`) and waits until it serves
    /// D-Bus and both nodes are capture devices.
    pub fn start(view_nr: u32, data_nr: u32, sensor: Sensor, fps: u32) -> Self {
        let backend = ["--backend", "sim", "--sensor", sensor.name].map(str::to_owned);
        Self::start_with(view_nr, data_nr, sensor, fps, "", backend.to_vec())
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
        Self::start_with(view_nr, data_nr, sensor, fps, &board, backend.to_vec())
    }

    fn start_with(
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
        let mut s = Self {
            bus: Bus::start(),
            child: None,
            view: PathBuf::from(format!("/dev/video{view_nr}")),
            data: PathBuf::from(format!("/dev/video{data_nr}")),
            config,
            fps: fps.to_string(),
            sensor,
            backend,
        };
        s.spawn();
        s
    }

    fn spawn(&mut self) {
        let child = Command::new(exe("SDID"))
            .args(["--bus-address", &self.bus.address, "--config"])
            .arg(&self.config)
            .args(&self.backend)
            .args(["--sink", "loopback"])
            .args(["--frame-rate-hz", &self.fps, "--exposure-us", "2000"])
            .env("RUST_LOG", "warn")
            .env_remove("INVOCATION_ID")
            .stdout(Stdio::null())
            .spawn()
            .expect("spawn sdid");
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
        Command::new(exe("SDICTL"))
            .args(["--bus-address", &self.bus.address])
            .args(args)
            .output()
            .expect("run sdictl")
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
        let bytes = std::fs::read(npy).expect("read snapshot npy");
        // header: magic(6) version(2) len(2, v1) header; data little-endian f32
        let hlen = usize::from(u16::from_le_bytes([bytes[8], bytes[9]]));
        let header = String::from_utf8_lossy(&bytes[10..10 + hlen]);
        assert!(header.contains("<f4"), "npy not f32: {header}");
        let data = &bytes[10 + hlen..];
        let n = data.len() / 4;
        data.chunks_exact(4)
            .map(|c| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])))
            .sum::<f64>()
            / n.max(1) as f64
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

/// Rows of the view node's letterbox: the sensor picture scaled into 640x480
/// keeps its aspect, so (top bar rows, picture rows).
pub fn letterbox_rows(w: usize, h: usize) -> (usize, usize) {
    let scale = (640.0 / w as f64).min(480.0 / h as f64);
    let sh = (h as f64 * scale) as usize;
    ((480 - sh) / 2, sh)
}
