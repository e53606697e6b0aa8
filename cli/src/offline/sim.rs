//! `sdictl sim`: simulator + mode pipeline, written as an N x H x W float32
//! `.npy` in DN and optionally one display frame as PNG.
//!
//! Like the paper's measurement procedure (section 4), a dark frame is first
//! averaged (LEDs off, 50/50 modulation so uncorrelated light cancels in the
//! mean) and then subtracted by the pipeline of modes that need it.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use clap::Args;
use sdi_core::display::{Colormap, DisplayMap, DisplayRange};
use sdi_core::mode::{ModeId, ModeOutput};
use sdi_core::npy::NpyF32Writer;
use sdi_core::scene::SceneId;
use sdi_core::sensor::SensorDescription;
use sdi_core::simulator::{run_config, SimRun, Simulator};
use sdi_core::Image;

use crate::atomic_file::AtomicFile;
use crate::exit::CliError;
use crate::output_name::{refuse_same, OutputName};
use crate::stdout::outln;

pub use sdi_core::simulator::{
    MAX_AMBIENT_ELECTRONS_PER_US, MAX_DARK_FRAMES, MAX_EXPOSURE_US, MAX_FRAMES,
};

#[derive(Debug, Args)]
pub struct SimArgs {
    /// Scene to simulate [default: the mode's own scene].
    #[arg(long, value_parser = sdi_config::cli::choice::<SceneId>())]
    pub scene: Option<SceneId>,
    /// A scene parameter, KEY=VALUE (repeatable): e.g. source_spacing_mm,
    /// displacement_px, fan_rpm, pellets, the sources' electrons_per_us;
    /// an unknown key lists the scene's keys and defaults.
    #[arg(long = "scene-param", value_name = "KEY=VALUE")]
    pub scene_params: Vec<String>,
    /// Difference mode to run.
    #[arg(long, value_parser = sdi_config::cli::choice::<ModeId>())]
    pub mode: ModeId,
    /// Number of output frames to write (1..=10000).
    #[arg(long, value_parser = parse_frames, allow_negative_numbers = true)]
    pub frames: usize,
    /// Sensor: preset (ti, pmd) or a sensor description file (TOML).
    #[arg(long, default_value = "ti", value_parser = super::sensor_arg::parse_sensor)]
    pub sensor: SensorDescription,
    /// Exposure per frame, microseconds (0 < X <= 1e6) [default: the sensor's].
    #[arg(long, value_parser = parse_exposure_us, allow_negative_numbers = true)]
    pub exposure_us: Option<f64>,
    /// Uniform ambient light, electrons per microsecond per pixel (0 <= X <= 1e6).
    #[arg(long, default_value_t = 0.0, value_parser = parse_ambient, allow_negative_numbers = true)]
    pub ambient: f64,
    /// Random seed: same seed, same frames.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub seed: u64,
    /// Dark frames averaged before the run and subtracted (0 = none).
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u32).range(0..=i64::from(MAX_DARK_FRAMES)), allow_negative_numbers = true)]
    pub dark_frames: u32,
    /// Output .npy file (N x H x W float32, DN; separation: N x 2 x H x W
    /// float32 electrons, I+ then I-, recovered by M3 on each frame).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the ground truth: the expected wells I+ and I- in electrons
    /// per exposure under the snapshot illumination, (2, H, W) for a static
    /// scene, (N, 2, H, W) for a moving one.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// two-shot only: also write the dark-subtracted A (LS1 only) and B (LS2
    /// only) frames, (N, 2, H, W) DN.
    #[arg(long)]
    pub two_shot_frames: Option<PathBuf>,
    /// Also write the last frame as a display image (PNG).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Colormap of the PNG.
    #[arg(long, default_value = "diverging",
        value_parser = sdi_config::cli::choice::<Colormap>())]
    pub colormap: Colormap,
    /// Display range of the PNG: 'auto' (robust symmetric) or max |DN| (> 0).
    #[arg(long, default_value = "auto", value_parser = |s: &str| s.parse::<DisplayRange>(), allow_negative_numbers = true)]
    pub range: DisplayRange,
}

fn parse_frames(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(n) if (1..=MAX_FRAMES).contains(&n) => Ok(n),
        _ => Err(format!("expected a whole number from 1 to {MAX_FRAMES}")),
    }
}

fn parse_bounded(s: &str, ok: impl Fn(f64) -> bool, allowed: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && ok(v) => Ok(v),
        _ => Err(format!("expected a finite number {allowed}")),
    }
}

fn parse_exposure_us(s: &str) -> Result<f64, String> {
    parse_bounded(
        s,
        |v| v > 0.0 && v <= MAX_EXPOSURE_US,
        "of microseconds, 0 < X <= 1000000",
    )
}

fn parse_ambient(s: &str) -> Result<f64, String> {
    parse_bounded(
        s,
        |v| (0.0..=MAX_AMBIENT_ELECTRONS_PER_US).contains(&v),
        "of electrons/us, 0 <= X <= 1000000",
    )
}

fn io_error(what: &str, path: &Path, e: impl std::fmt::Display) -> CliError {
    CliError::Runtime(format!("{what} '{}': {e}", path.display()))
}

/// Creates each output's directory and refuses two outputs that are the
/// same file (by directory inode and name, `output_name.rs`), before any
/// frame is simulated.
fn check_outputs(args: &SimArgs) -> Result<(), CliError> {
    let flagged: Vec<(&str, &Path)> = [
        ("--out", Some(args.out.as_path())),
        ("--png", args.png.as_deref()),
        ("--truth", args.truth.as_deref()),
        ("--two-shot-frames", args.two_shot_frames.as_deref()),
    ]
    .into_iter()
    .filter_map(|(flag, p)| p.map(|p| (flag, p)))
    .collect();
    let names = flagged
        .iter()
        .map(|(_, p)| OutputName::create_dir_of(p))
        .collect::<Result<Vec<_>, _>>()?;
    let entries: Vec<_> = flagged
        .iter()
        .zip(&names)
        .map(|((flag, p), n)| (*flag, *p, n))
        .collect();
    refuse_same(&entries)
}

/// Runs `sdictl sim`.
/// With `json`, the summary on stdout is one JSON object.
pub fn run(args: SimArgs, json: bool) -> Result<(), CliError> {
    let sim = simulator(&args)?;
    let (w, h) = (sim.params().width, sim.params().height);
    if args.two_shot_frames.is_some() && args.mode != ModeId::TwoShot {
        return Err(CliError::Usage(
            "--two-shot-frames needs --mode two-shot".into(),
        ));
    }
    check_outputs(&args)?;
    let mut out = Outputs::create(&args, w, h)?;
    let static_scene = sim.scene_is_static();
    let mut run = SimRun::new(sim, args.mode, args.dark_frames)
        .map_err(|e| CliError::Runtime(e.to_string()))?;
    let last = simulate(&args, &mut run, &mut out)?;
    let display = DisplayMap::new(args.colormap, args.range);
    out.commit(&args, &display, &last, static_scene)?;
    let summary = Summary {
        scene: run.simulator().config().scene.name(),
        width: w,
        height: h,
        dark_frames: run.dark_frames(),
        png_max_abs_dn: args.png.as_ref().map(|_| display.max_abs_dn(&last)),
    };
    print_summary(&args, &summary, json)
}

/// The simulator of `args`' scene, sensor, exposure, ambient light and seed.
fn simulator(args: &SimArgs) -> Result<Simulator, CliError> {
    let scene = args
        .scene
        .map_or_else(|| args.mode.default_scene(), SceneId::spec)
        .with_params(&args.scene_params)
        .map_err(|e| CliError::Usage(e.to_string()))?;
    let config = run_config(
        &args.sensor,
        scene,
        args.exposure_us,
        args.ambient,
        args.seed,
    );
    let carrier_hz = config.sensor.modulation_hz;
    if let Some(w) =
        sdi_core::simulator::light_travel::light_travel_warning(&config.scene, carrier_hz)
    {
        eprintln!("warning: {w}");
    }
    Simulator::new(config).map_err(|e| CliError::Usage(e.to_string()))
}

/// The output files, written under temporary names until [`Outputs::commit`].
struct Outputs {
    npy_file: AtomicFile,
    png_file: Option<AtomicFile>,
    /// Where the `.npy` is written until it is committed.
    tmp: PathBuf,
    npy: NpyF32Writer<BufWriter<File>>,
    extras: super::sim_truth::Extras,
}

impl Outputs {
    /// Creates the `.npy` (frames of `width` x `height`, two channels in
    /// the separation mode), the PNG and the truth files.
    fn create(args: &SimArgs, width: usize, height: usize) -> Result<Self, CliError> {
        let npy_file =
            AtomicFile::new(&args.out).map_err(|e| io_error("bad output", &args.out, e))?;
        let png_file = match &args.png {
            Some(p) => Some(AtomicFile::new(p).map_err(|e| io_error("bad output", p, e))?),
            None => None,
        };
        let tmp = npy_file.tmp_path().to_path_buf();
        let writer = npy_file
            .create()
            .map_err(|e| io_error("cannot create", &tmp, e))?;
        let shape: &[usize] = if args.mode == ModeId::Separation {
            &[args.frames, 2, height, width]
        } else {
            &[args.frames, height, width]
        };
        let npy =
            NpyF32Writer::new(writer, shape).map_err(|e| io_error("cannot write", &tmp, e))?;
        let extras = super::sim_truth::Extras::open(
            args.truth.as_deref(),
            args.two_shot_frames.as_deref(),
            width,
            height,
        )?;
        Ok(Self {
            npy_file,
            png_file,
            tmp,
            npy,
            extras,
        })
    }

    /// Appends one output: both channels in the separation mode, else the
    /// signed difference.
    fn write(&mut self, out: &ModeOutput, separated: bool) -> Result<(), CliError> {
        let tmp = &self.tmp;
        match (&out.channels, separated) {
            (Some(c), true) => self
                .npy
                .write(&c.i_plus_electrons.data)
                .and_then(|()| self.npy.write(&c.i_minus_electrons.data))
                .map_err(|e| io_error("cannot write", tmp, e)),
            (None, true) => Err(CliError::Runtime(
                "the separation pipeline gave no channels".into(),
            )),
            _ => self
                .npy
                .write(&out.signed_dn.data)
                .map_err(|e| io_error("cannot write", tmp, e)),
        }
    }

    /// Finishes the `.npy`, renders `last` into the PNG, and moves every
    /// file to its name.
    fn commit(
        self,
        args: &SimArgs,
        display: &DisplayMap,
        last: &Image<f32>,
        static_scene: bool,
    ) -> Result<(), CliError> {
        let tmp = self.tmp;
        self.npy
            .finish()
            .and_then(|mut w| w.flush())
            .map_err(|e| io_error("cannot write", &tmp, e))?;
        if let Some(png) = &self.png_file {
            write_png(png.tmp_path(), display, last)?;
        }
        self.extras.finish(static_scene)?;
        self.npy_file
            .commit()
            .map_err(|e| io_error("cannot write", &args.out, e))?;
        if let (Some(png), Some(path)) = (self.png_file, &args.png) {
            png.commit()
                .map_err(|e| io_error("cannot write", path, e))?;
        }
        Ok(())
    }
}

/// Runs the simulator through the mode until `args.frames` outputs are
/// written; the last output's signed difference, for the PNG.
fn simulate(args: &SimArgs, run: &mut SimRun, out: &mut Outputs) -> Result<Image<f32>, CliError> {
    let (w, h) = (
        run.simulator().params().width,
        run.simulator().params().height,
    );
    let separated = args.mode == ModeId::Separation;
    let two_shot = args.mode == ModeId::TwoShot;
    let mut last = Image::<f32>::new(w, h);
    let dark_dn = run.dark_dn().cloned();
    for written in 1..=args.frames {
        let result = run
            .next_output(
                out,
                |out, frame| out.extras.captured(frame, dark_dn.as_ref()),
                |out, output, truth| -> Result<(), CliError> {
                    out.write(output, separated)?;
                    match truth {
                        Some(t) => out.extras.output(t, !two_shot)?,
                        None => out.extras.output_pair_only()?,
                    }
                    if written == args.frames {
                        last.data.copy_from_slice(&output.signed_dn.data);
                    }
                    Ok(())
                },
            )
            .map_err(|e| CliError::Runtime(e.to_string()))?;
        result?;
    }
    Ok(last)
}

/// What `sdictl sim` reports besides its arguments.
struct Summary {
    scene: &'static str,
    width: usize,
    height: usize,
    dark_frames: u32,
    /// The display range of the PNG, DN (when one was written).
    png_max_abs_dn: Option<f32>,
}

/// Prints the summary line, or with `json` one JSON object.
fn print_summary(args: &SimArgs, s: &Summary, json: bool) -> Result<(), CliError> {
    let (w, h) = (s.width, s.height);
    if json {
        let path = |p: Option<&Path>| p.map(|p| p.display().to_string());
        outln!(
            "{}",
            serde_json::json!({
                "frames": args.frames,
                "width": w,
                "height": h,
                "mode": args.mode.to_string(),
                "scene": s.scene,
                "dark_frames": s.dark_frames,
                "out": args.out.display().to_string(),
                "png": path(args.png.as_deref()),
                "png_max_abs_dn": s.png_max_abs_dn,
                "truth": path(args.truth.as_deref()),
                "two_shot_frames": path(args.two_shot_frames.as_deref()),
            })
        )?;
    } else {
        outln!(
            "wrote {} frames of {w}x{h} ({} on scene {}, {} dark frames averaged) to {}{}",
            args.frames,
            args.mode,
            s.scene,
            s.dark_frames,
            args.out.display(),
            match (&args.png, s.png_max_abs_dn) {
                (Some(p), Some(max)) =>
                    format!("; display frame (+-{max:.1} DN) to {}", p.display()),
                _ => String::new(),
            }
        )?;
    }
    Ok(())
}

fn write_png(path: &Path, display: &DisplayMap, img: &Image<f32>) -> Result<(), CliError> {
    let (w, h) = (img.width as u32, img.height as u32);
    let (buf, colour) = match display.colormap {
        Colormap::Grey => {
            let mut buf = vec![0u8; img.len()];
            display.render_grey8(img, &mut buf);
            (buf, image::ExtendedColorType::L8)
        }
        Colormap::Diverging => {
            let mut buf = vec![0u8; img.len() * 3];
            display.render_rgb8(img, &mut buf);
            (buf, image::ExtendedColorType::Rgb8)
        }
    };
    image::save_buffer_with_format(path, &buf, w, h, colour, image::ImageFormat::Png)
        .map_err(|e| io_error("cannot write", path, e))
}
