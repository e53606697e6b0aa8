//! sdid's command line: flags parsed at the edge into the typed
//! [`Config`](sdi_config::Config) and the other [`StartOptions`].

use std::path::PathBuf;

use clap::Parser;
use sdi_core::mode::ModeId;
use sdi_core::scene::SceneId;
use sdi_core::sensor::capture_range;

use crate::bus::BusChoice;
use crate::startup::{StartError, StartOptions};
use sdi_config::{cli, BackendKind, Config, SensorSpec, SinkKind};

/// The SDI difference-camera daemon.
#[derive(Debug, Parser)]
#[command(name = "sdid", version, about)]
pub struct Args {
    /// Configuration file [default: /etc/sdi/sdid.toml if present].
    #[arg(long)]
    config: Option<PathBuf>,
    /// Serve on the session bus (starts a private one if none exists) instead of the system bus.
    #[arg(long)]
    session: bool,
    /// Serve on the bus at this address.
    #[arg(long, conflicts_with = "session")]
    bus_address: Option<String>,
    /// Frame source: auto (the board if attached, else the simulator), sim, replay or opt8241.
    #[arg(long, value_parser = cli::choice::<BackendKind>())]
    backend: Option<BackendKind>,
    /// Recording to play (implies --backend replay).
    #[arg(long)]
    replay: Option<PathBuf>,
    /// Loop the replayed recording.
    #[arg(long = "loop")]
    looping: bool,
    /// Mode at start.
    #[arg(long, value_parser = cli::choice::<ModeId>())]
    mode: Option<ModeId>,
    /// Simulated cameras, each its own D-Bus object and outputs (serials
    /// sim-0, sim-1, ...; with --backend sim) [default: 1].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=sdi_config::MAX_CAMERAS as i64))]
    cameras: Option<u32>,
    /// Simulator sensor: preset (ti, pmd) or a sensor description file (TOML).
    #[arg(long)]
    sensor: Option<SensorSpec>,
    /// Simulator scene for every mode [default: each mode's own].
    #[arg(long, value_parser = cli::choice::<SceneId>())]
    scene: Option<SceneId>,
    /// Frame rate, Hz [0.1, 240].
    #[arg(long, value_parser = cli::in_range(capture_range::FRAME_RATE_HZ))]
    frame_rate_hz: Option<f64>,
    /// Exposure per frame, us [1, 1e6].
    #[arg(long, value_parser = cli::in_range(capture_range::EXPOSURE_US))]
    exposure_us: Option<f64>,
    /// Modulation frequency, Hz [1e3, 100e6].
    #[arg(long, value_parser = cli::in_range(capture_range::MODULATION_HZ))]
    modulation_hz: Option<f64>,
    /// Output sink: auto (v4l2loopback, else PipeWire, else y4m), loopback,
    /// pipewire or y4m.
    #[arg(long, value_parser = cli::choice::<SinkKind>())]
    sink: Option<SinkKind>,
    /// y4m fallback target: "-" (stdout) or a FIFO path [default: stdout if
    /// it is a pipe, else $XDG_RUNTIME_DIR/sdid-view.y4m].
    #[arg(long)]
    y4m_path: Option<String>,
    /// Where calibrations are kept [default: $STATE_DIRECTORY, else
    /// $XDG_STATE_HOME/sdi, else ~/.local/state/sdi].
    #[arg(long)]
    state_dir: Option<PathBuf>,
}

impl Args {
    /// Reads the configuration file, applies the command line's overrides
    /// and validates the result once (adjustments are logged).
    pub fn into_options(self) -> Result<StartOptions, StartError> {
        let (mut config, file) =
            Config::read(self.config.as_deref()).map_err(StartError::Config)?;
        self.apply(&mut config);
        let adjusted = config
            .validate()
            .map_err(|source| StartError::Invalid { file, source })?;
        for a in adjusted {
            tracing::warn!("configuration: {a}");
        }
        let bus = match (self.bus_address, self.session) {
            (Some(address), _) => BusChoice::Address(address),
            (None, true) => BusChoice::Session,
            (None, false) => BusChoice::System,
        };
        Ok(StartOptions {
            config,
            bus,
            state_dir: self.state_dir,
            mode_given: self.mode.is_some(),
        })
    }

    /// The command line's overrides, already typed; validated with the rest after.
    fn apply(&self, c: &mut Config) {
        if let Some(b) = self.backend {
            c.backend = b;
        }
        if let Some(p) = &self.replay {
            c.backend = BackendKind::Replay;
            c.replay.path = Some(p.clone());
        }
        if self.looping {
            c.replay.looping = true;
        }
        if let Some(m) = self.mode {
            c.mode = m;
        }
        if let Some(n) = self.cameras {
            c.cameras = n;
        }
        if let Some(s) = &self.sensor {
            c.sensor = s.clone();
        }
        c.scene = self.scene.or(c.scene);
        c.frame_rate_hz = self.frame_rate_hz.or(c.frame_rate_hz);
        c.exposure_us = self.exposure_us.or(c.exposure_us);
        c.modulation_hz = self.modulation_hz.or(c.modulation_hz);
        if let Some(s) = self.sink {
            c.output.sink = s;
        }
        if let Some(p) = &self.y4m_path {
            c.output.y4m_path = p.clone();
        }
    }
}
