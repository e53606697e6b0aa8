//! `sdictl separate`: I+ and I- from a recording or an `.npy` stack, offline
//! (paper section 6: (I+, I-) = H^-1 (mu, sigma^2 - sigma_read^2), eq.
//! skellammatrix).
//!
//! - `m1`: mean and variance over all N frames per pixel, streaming (constant
//!   memory in N); writes (2, H, W). With `--window W`: over the last W frames,
//!   one output per frame, (N, 2, H, W).
//! - `m1-pooled`: M1 followed by edge-aware pooling of the moments, (2, H, W).
//! - `m2`: per frame, statistics over segments (automatic, or `--segments
//!   LABELS.npy`), (N, 2, H, W).
//! - `m3`: per frame, bilateral-weighted statistics; the range sigma is k times
//!   the frame's own noise (robust MAD of neighbour differences), never a
//!   ground truth. (N, 2, H, W).
//! - `ml`: per frame, Skellam maximum likelihood over the last W frames
//!   (default 16) of each pixel, non-negative. (N, 2, H, W).
//!
//! Values are electrons per exposure, float32, I+ first. `--sigma` writes the
//! one-sigma standard error of each channel (same shape) from the estimator's
//! own sampling statistics; pixels without a usable estimate are 0 with an
//! infinite standard error and are flagged (`--flags`, bits of
//! `sdi_core::separation::flags` as float32).

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::{Args, ValueEnum};
use sdi_core::calibration::CalibrationStore;
use sdi_core::sensor::{mixing_with_adc, SensorDescription, SkellamMixing};
use sdi_core::separation::{
    label_from_f32, sanitize, BatchError, BatchMethod, BatchParams, BatchSeparator, Separated,
    UnmixOptions,
};
use sdi_core::{Frame, Image};

use super::frames::{FrameInput, InputInfo, NpyOut};
use super::sensor_arg::parse_sensor;
use crate::atomic_file::AtomicFile;
use crate::exit::CliError;
use crate::output_name::{refuse_same, OutputName};
use crate::stdout::outln;

/// Longest temporal window.
pub const MAX_WINDOW: usize = sdi_core::separation::MAX_BATCH_WINDOW;

/// Separation estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Method {
    /// Mean and variance over frames (section 6, M1).
    M1,
    /// M1, then edge-aware pooling of the per-pixel moments (beyond the paper).
    M1Pooled,
    /// Statistics over segments of each frame (section 6, M2).
    M2,
    /// Bilateral-weighted statistics of each frame (section 6, M3).
    M3,
    /// Per-pixel Skellam maximum likelihood over a temporal window (beyond the paper).
    Ml,
}

#[derive(Debug, Args)]
pub struct SeparateArgs {
    /// Estimator.
    #[arg(long, value_enum)]
    pub method: Method,
    /// Input frames: a recording (.sdirec, dark frame subtracted as recorded)
    /// or an .npy stack (N x H x W, DN, dark frame already subtracted).
    #[arg(long = "in")]
    pub input: PathBuf,
    /// Output .npy (float32 electrons): (2, H, W) for m1/m1-pooled, else (N, 2, H, W).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the per-pixel standard error of each channel (same shape).
    #[arg(long)]
    pub sigma: Option<PathBuf>,
    /// Also write the per-pixel flags (float32 bit values; (H, W) or (N, H, W)).
    #[arg(long)]
    pub flags: Option<PathBuf>,
    /// Temporal window, frames: m1 (sliding, one output per frame) and ml (default 16).
    #[arg(long, value_parser = clap::value_parser!(u32).range(2..=MAX_WINDOW as i64), allow_negative_numbers = true)]
    pub window: Option<u32>,
    /// Sensor description (ti, pmd or a TOML file) giving H [default: a
    /// recording's stored sensor, else ti].
    #[arg(long, value_parser = parse_sensor)]
    pub sensor: Option<SensorDescription>,
    /// Calibration store (TOML, as written by `sdictl calibrate`): gain and read
    /// noise measured on the sensor; overrides --sensor.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// m2: segment labels (H x W .npy, float32; negative or NaN = no segment).
    #[arg(long)]
    pub segments: Option<PathBuf>,
    /// m3: spatial sigma, px.
    #[arg(long, default_value_t = 3.0, value_parser = parse_positive)]
    pub sigma_domain_px: f64,
    /// m3: range sigma in units of the frame's own noise (estimated from the data).
    #[arg(long, default_value_t = 3.0, value_parser = parse_positive)]
    pub range_sigmas: f64,
    /// Do not subtract the read-noise variance before inverting H.
    #[arg(long)]
    pub keep_read_noise: bool,
    /// Project negative estimates onto I+, I- >= 0.
    #[arg(long)]
    pub nonnegative: bool,
}

fn parse_positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 1000.0 => Ok(v),
        _ => Err("expected a finite number in (0, 1000]".into()),
    }
}

fn io_err(what: &str, path: &Path, e: impl std::fmt::Display) -> CliError {
    CliError::Runtime(format!("{what} '{}': {e}", path.display()))
}

/// Where H came from, for the log line.
#[derive(Debug, Clone)]
pub struct MixingSource {
    pub h: SkellamMixing,
    pub from: String,
}

/// H: a calibration store, else an explicit sensor, else the recording's
/// sensor (with its measured dark variance, which contains the ADC rounding),
/// else the TI preset. Sensor descriptions count the rounding (1/12 DN^2).
pub fn choose_mixing(
    calibration: Option<&Path>,
    sensor: Option<&SensorDescription>,
    info: &InputInfo,
) -> Result<MixingSource, CliError> {
    if let Some(path) = calibration {
        let text = std::fs::read_to_string(path).map_err(|e| io_err("cannot read", path, e))?;
        let store = CalibrationStore::from_toml(&text)
            .map_err(|e| CliError::Usage(format!("'{}': {e}", path.display())))?;
        let model = info.sensor.as_ref().map(|s| s.model.as_str());
        let records = &store.sensors;
        let pick = records
            .iter()
            .find(|r| Some(r.model.as_str()) == model)
            .or(if records.len() == 1 {
                records.first()
            } else {
                None
            })
            .ok_or_else(|| {
                CliError::Usage(format!(
                    "'{}' holds {} calibrations and none for this input's sensor; keep one",
                    path.display(),
                    records.len()
                ))
            })?;
        let h = pick
            .skellam()
            .map_err(|e| CliError::Usage(format!("'{}': {e}", path.display())))?;
        return Ok(MixingSource {
            h,
            from: format!(
                "calibration {} {} ({})",
                pick.model,
                pick.serial,
                path.display()
            ),
        });
    }
    if let Some(d) = sensor {
        return Ok(MixingSource {
            h: mixing_with_adc(&d.params()),
            from: format!("sensor description {}", d.model),
        });
    }
    if let Some(p) = &info.sensor {
        let mut h = mixing_with_adc(p);
        let mut from = format!("recording's sensor {}", p.model);
        if let Some(r) = info
            .read_variance_dn2
            .filter(|r| r.is_finite() && *r >= 0.0)
        {
            h.read_variance_dn2 = r;
            from += " with its measured dark variance";
        }
        return Ok(MixingSource { h, from });
    }
    let d = parse_sensor("ti").map_err(CliError::Runtime)?;
    Ok(MixingSource {
        h: mixing_with_adc(&d.params()),
        from: "sensor preset ti (default)".into(),
    })
}

/// The output files, kept until every one is written.
struct Outputs {
    files: Vec<(AtomicFile, PathBuf)>,
    out: NpyOut,
    sigma: Option<NpyOut>,
    flags: Option<NpyOut>,
    plane: Vec<f32>,
    flag_plane: Vec<f32>,
    nonfinite: usize,
}

impl Outputs {
    fn open(args: &SeparateArgs, w: usize, h: usize) -> Result<Self, CliError> {
        // Input and outputs are compared as directory entries, however spelled.
        let flagged: Vec<(&str, &Path)> = [
            ("--out", Some(args.out.as_path())),
            ("--sigma", args.sigma.as_deref()),
            ("--flags", args.flags.as_deref()),
        ]
        .into_iter()
        .filter_map(|(flag, p)| p.map(|p| (flag, p)))
        .collect();
        let mut names = vec![OutputName::of(&args.input)?];
        for (_, p) in &flagged {
            names.push(OutputName::create_dir_of(p)?);
        }
        let entries: Vec<_> = std::iter::once(("--in", args.input.as_path()))
            .chain(flagged.iter().copied())
            .zip(&names)
            .map(|((flag, p), n)| (flag, p, n))
            .collect();
        refuse_same(&entries)?;
        let mut files = Vec::new();
        let mut open = |p: &PathBuf, tail: &[usize]| -> Result<NpyOut, CliError> {
            if p.is_dir() {
                return Err(io_err("cannot write", p, "is a directory"));
            }
            if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir).map_err(|e| io_err("cannot create", dir, e))?;
            }
            let f = AtomicFile::new(p).map_err(|e| io_err("bad output", p, e))?;
            let wr = f
                .create()
                .map_err(|e| io_err("cannot create", f.tmp_path(), e))?;
            let npy = NpyOut::new(wr, tail).map_err(|e| io_err("cannot write", p, e))?;
            files.push((f, p.clone()));
            Ok(npy)
        };
        let out = open(&args.out, &[2, h, w])?;
        let sigma = args
            .sigma
            .as_ref()
            .map(|p| open(p, &[2, h, w]))
            .transpose()?;
        let flags = args.flags.as_ref().map(|p| open(p, &[h, w])).transpose()?;
        Ok(Self {
            files,
            out,
            sigma,
            flags,
            plane: vec![0.0; 2 * w * h],
            flag_plane: vec![0.0; w * h],
            nonfinite: 0,
        })
    }

    /// Appends one (2, H, W) result. Non-finite estimates (an overflow in
    /// f32) become 0 and are flagged NONFINITE; standard errors are finite
    /// or +inf, never NaN.
    fn push(&mut self, s: &mut Separated) -> Result<(), CliError> {
        self.nonfinite += sanitize(s);
        let n = s.flags.data.len();
        let bad = |e: std::io::Error| CliError::Runtime(format!("cannot write output: {e}"));
        self.plane[..n].copy_from_slice(&s.i_plus_electrons.data);
        self.plane[n..].copy_from_slice(&s.i_minus_electrons.data);
        self.out.push(&self.plane).map_err(bad)?;
        if let Some(sig) = &mut self.sigma {
            self.plane[..n].copy_from_slice(&s.i_plus_se_electrons.data);
            self.plane[n..].copy_from_slice(&s.i_minus_se_electrons.data);
            sig.push(&self.plane).map_err(bad)?;
        }
        if let Some(fl) = &mut self.flags {
            for (o, &f) in self.flag_plane.iter_mut().zip(&s.flags.data) {
                *o = f32::from(f);
            }
            fl.push(&self.flag_plane).map_err(bad)?;
        }
        Ok(())
    }

    fn finish(self, single: bool) -> Result<usize, CliError> {
        let count = self.out.count();
        let bad = |e: std::io::Error| CliError::Runtime(format!("cannot write output: {e}"));
        self.out.finish(single).map_err(bad)?;
        if let Some(s) = self.sigma {
            s.finish(single).map_err(bad)?;
        }
        if let Some(f) = self.flags {
            f.finish(single).map_err(bad)?;
        }
        for (f, p) in self.files {
            f.commit().map_err(|e| io_err("cannot write", &p, e))?;
        }
        Ok(count)
    }
}

/// The run's refusals in the words of this command's flags.
fn batch_err(e: BatchError) -> CliError {
    CliError::Usage(match e {
        BatchError::LabelsNotM2 => "--segments applies to --method m2 only".into(),
        BatchError::WindowNotM1OrMl => "--window applies to m1 and ml only".into(),
        e => e.to_string(),
    })
}

impl From<Method> for BatchMethod {
    fn from(m: Method) -> Self {
        match m {
            Method::M1 => BatchMethod::M1,
            Method::M1Pooled => BatchMethod::M1Pooled,
            Method::M2 => BatchMethod::M2,
            Method::M3 => BatchMethod::M3,
            Method::Ml => BatchMethod::Ml,
        }
    }
}

/// Reads labels for M2 (H x W float32; negative or non-finite = no segment).
fn read_labels(path: &Path, w: usize, h: usize) -> Result<Image<u32>, CliError> {
    let file = std::fs::File::open(path).map_err(|e| io_err("cannot read", path, e))?;
    let (shape, data) = sdi_core::npy::read_f32(std::io::BufReader::new(file))
        .map_err(|e| CliError::Usage(format!("'{}': {e}", path.display())))?;
    if shape != [h, w] {
        return Err(CliError::Usage(format!(
            "'{}': labels of shape {shape:?}, expected [{h}, {w}]",
            path.display()
        )));
    }
    let labels = data.iter().map(|&v| label_from_f32(v)).collect();
    Ok(Image {
        width: w,
        height: h,
        data: labels,
    })
}

/// Summary of a run, for tests and the log line.
#[derive(Debug, Clone)]
pub struct SeparateSummary {
    pub frames_in: usize,
    pub outputs: usize,
    pub seconds: f64,
    pub h: SkellamMixing,
}

/// Runs `sdictl separate`.
/// With `json`, the summary on stdout is one JSON object.
pub fn run(args: SeparateArgs, json: bool) -> Result<(), CliError> {
    let s = separate(&args)?;
    if json {
        outln!(
            "{}",
            serde_json::json!({
                "frames_in": s.frames_in,
                "outputs": s.outputs,
                "method": args.method.to_possible_value().map(|v| v.get_name().to_owned()),
                "seconds": s.seconds,
                "gain_dn_per_electron": s.h.gain_dn_per_electron,
                "read_variance_dn2": s.h.read_variance_dn2,
                "out": args.out.display().to_string(),
                "sigma": args.sigma.as_ref().map(|p| p.display().to_string()),
                "flags": args.flags.as_ref().map(|p| p.display().to_string()),
            })
        )?;
        return Ok(());
    }
    outln!(
        "separated {} frames ({:?}) into {} output{} in {:.2} s; H: gain {:.6} DN/electron, read variance {:.4} DN^2; wrote {}",
        s.frames_in,
        args.method,
        s.outputs,
        if s.outputs == 1 { "" } else { "s" },
        s.seconds,
        s.h.gain_dn_per_electron,
        s.h.read_variance_dn2,
        args.out.display()
    )?;
    Ok(())
}

/// The work of `sdictl separate`, returning what it did.
pub fn separate(args: &SeparateArgs) -> Result<SeparateSummary, CliError> {
    let t0 = Instant::now();
    let (mut input, info) = FrameInput::open(&args.input)?;
    let mix = choose_mixing(args.calibration.as_deref(), args.sensor.as_ref(), &info)?;
    let (w, ht) = (info.width, info.height);
    let labels = args
        .segments
        .as_deref()
        .map(|p| read_labels(p, w, ht))
        .transpose()?;
    let params = BatchParams {
        method: args.method.into(),
        window: args.window.map(|w| w as usize),
        labels,
        sigma_domain_px: args.sigma_domain_px,
        range_sigmas: args.range_sigmas,
        options: UnmixOptions {
            subtract_read_noise: !args.keep_read_noise,
            nonnegative: args.nonnegative,
        },
    };
    let mut separator = BatchSeparator::new(params, mix.h, w, ht).map_err(batch_err)?;
    eprintln!("H from {}", mix.from);
    let h = mix.h;
    let mut outs = Outputs::open(args, w, ht)?;
    let mut frame = Frame::new(w, ht);
    let mut sep = Separated::default();
    while input.next_frame(&args.input, &mut frame)? {
        if separator.frames() == 0 && input.lacks_dark() {
            eprintln!("warning: the recording holds no dark frame; frames are used as recorded (offset and fixed pattern end up in I+ - I-)");
        }
        if separator.push(&frame, &mut sep).map_err(batch_err)? {
            outs.push(&mut sep)?;
        }
    }
    let frames_in = separator.frames();
    if separator.finish(&mut sep).map_err(batch_err)? {
        outs.push(&mut sep)?;
    }
    if frames_in == 0 {
        return Err(CliError::Usage(format!(
            "'{}' holds no frames",
            args.input.display()
        )));
    }
    if outs.nonfinite > 0 {
        eprintln!(
            "warning: {} estimates overflowed float32 and were written as 0 (flagged NONFINITE)",
            outs.nonfinite
        );
    }
    let outputs = outs.finish(separator.single_output())?;
    Ok(SeparateSummary {
        frames_in,
        outputs,
        seconds: t0.elapsed().as_secs_f64(),
        h,
    })
}
