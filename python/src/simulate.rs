//! `sdi.simulate`: the simulator through a mode's pipeline exactly as
//! `sdictl sim` runs it (`sdi_core::simulator::SimRun`, one definition),
//! frames (and the ground truth) as numpy arrays.

use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{IntoPyArray, PyArrayDyn};
use pyo3::exceptions::{PyUserWarning, PyValueError};
use pyo3::prelude::*;
use sdi_config::SensorSpec;
use sdi_core::mode::ModeId;
use sdi_core::scene::SceneId;
use sdi_core::simulator::{
    light_travel::light_travel_warning, run_config, SimRun, Simulator,
    MAX_AMBIENT_ELECTRONS_PER_US, MAX_DARK_FRAMES, MAX_EXPOSURE_US, MAX_FRAMES,
};

fn value_err(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// Every mode's name.
#[pyfunction]
pub fn modes() -> Vec<&'static str> {
    ModeId::NAMES.to_vec()
}

/// Every simulated scene's name.
#[pyfunction]
pub fn scenes() -> Vec<&'static str> {
    SceneId::NAMES.to_vec()
}

/// A sensor description: a preset ("ti", "pmd") or a TOML file, as
/// `sdictl --sensor` and `sdid --sensor` read it.
pub fn sensor(name: &str) -> PyResult<sdi_core::sensor::SensorDescription> {
    name.parse::<SensorSpec>()
        .and_then(|spec| spec.load())
        .map_err(value_err)
}

fn check(name: &str, v: f64, ok: bool, allowed: &str) -> PyResult<()> {
    if v.is_finite() && ok {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!(
            "{name} = {v}: expected {allowed}"
        )))
    }
}

/// Simulates `frames` outputs of `mode` as `sdictl sim` does: (frames, H, W)
/// float32 DN, or in the separation mode (frames, 2, H, W) float32
/// electrons (I+, I-, by M3). With `truth`, returns (frames, truth): the
/// expected wells I+ and I- in electrons per exposure, (2, H, W) for a
/// static scene, (frames, 2, H, W) for a moving one.
#[pyfunction]
#[pyo3(signature = (mode, *, scene = None, frames = 30, seed = 0, sensor = "ti", exposure_us = None, ambient = 0.0, dark_frames = 32, scene_params = Vec::new(), truth = false))]
#[allow(clippy::too_many_arguments)]
pub fn simulate<'py>(
    py: Python<'py>,
    mode: &str,
    scene: Option<&str>,
    frames: usize,
    seed: u64,
    sensor: &str,
    exposure_us: Option<f64>,
    ambient: f64,
    dark_frames: u32,
    scene_params: Vec<String>,
    truth: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let mode: ModeId = mode.parse().map_err(value_err)?;
    if !(1..=MAX_FRAMES).contains(&frames) {
        return Err(PyValueError::new_err(format!(
            "frames = {frames}: expected 1 to {MAX_FRAMES}"
        )));
    }
    if dark_frames > MAX_DARK_FRAMES {
        return Err(PyValueError::new_err(format!(
            "dark_frames = {dark_frames}: expected 0 to {MAX_DARK_FRAMES}"
        )));
    }
    if let Some(us) = exposure_us {
        check(
            "exposure_us",
            us,
            us > 0.0 && us <= MAX_EXPOSURE_US,
            "0 < X <= 1000000",
        )?;
    }
    check(
        "ambient",
        ambient,
        (0.0..=MAX_AMBIENT_ELECTRONS_PER_US).contains(&ambient),
        "0 <= X <= 1000000 electrons/us",
    )?;
    let scene = match scene {
        Some(s) => s.parse::<SceneId>().map_err(value_err)?.spec(),
        None => mode.default_scene(),
    }
    .with_params(&scene_params)
    .map_err(value_err)?;
    let description = self::sensor(sensor)?;
    let config = run_config(&description, scene, exposure_us, ambient, seed);
    if let Some(w) = light_travel_warning(&config.scene, config.sensor.modulation_hz) {
        PyErr::warn(
            py,
            &py.get_type::<PyUserWarning>(),
            &std::ffi::CString::new(w).map_err(value_err)?,
            1,
        )?;
    }
    let sim = Simulator::new(config).map_err(value_err)?;
    let (w, h) = (sim.params().width, sim.params().height);
    let static_scene = sim.scene_is_static();
    let separated = mode == ModeId::Separation;
    let (out, wells) = py
        .detach(|| -> Result<_, String> {
            let mut run = SimRun::new(sim, mode, dark_frames).map_err(|e| e.to_string())?;
            let planes = if separated { 2 } else { 1 };
            let mut out = Vec::with_capacity(frames * planes * w * h);
            let mut wells = Vec::new();
            for _ in 0..frames {
                run.next_output(
                    &mut (),
                    |_, _| {},
                    |_, output, expected| -> Result<(), String> {
                        match (&output.channels, separated) {
                            (Some(c), true) => {
                                out.extend_from_slice(&c.i_plus_electrons.data);
                                out.extend_from_slice(&c.i_minus_electrons.data);
                            }
                            (None, true) => {
                                return Err("the separation pipeline gave no channels".into())
                            }
                            _ => out.extend_from_slice(&output.signed_dn.data),
                        }
                        if let (true, Some(e)) = (truth, expected) {
                            wells.extend_from_slice(&e.i_plus_electrons.data);
                            wells.extend_from_slice(&e.i_minus_electrons.data);
                        }
                        Ok(())
                    },
                )
                .map_err(|e| e.to_string())??;
            }
            Ok((out, wells))
        })
        .map_err(PyValueError::new_err)?;
    let shape: Vec<usize> = if separated {
        vec![frames, 2, h, w]
    } else {
        vec![frames, h, w]
    };
    let out = array(py, &shape, out)?;
    if !truth {
        return Ok(out.into_any());
    }
    let truth_shape: Vec<usize> = if static_scene {
        vec![2, h, w]
    } else {
        vec![frames, 2, h, w]
    };
    let wells = array(py, &truth_shape, wells)?;
    Ok((out, wells).into_pyobject(py)?.into_any())
}

/// `data` as an array of `shape` (no copy).
pub fn array<'py>(
    py: Python<'py>,
    shape: &[usize],
    data: Vec<f32>,
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    Ok(ArrayD::from_shape_vec(IxDyn(shape), data)
        .map_err(value_err)?
        .into_pyarray(py))
}
