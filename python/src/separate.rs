//! `sdi.separate`: I+ and I- from a stack of difference frames by the
//! estimator `sdictl separate` runs (`sdi_core::separation::BatchSeparator`,
//! one definition), so both give the same numbers on the same stack.

use numpy::{PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use sdi_core::sensor::mixing_with_adc;
use sdi_core::separation::{
    label_from_f32, sanitize, BatchMethod, BatchParams, BatchSeparator, Separated, UnmixOptions,
};
use sdi_core::{Frame, Image};

use crate::simulate::array;

/// What `sdi.separate` gives: the estimates, their standard errors and flags.
#[pyclass(module = "sdi", frozen, get_all)]
pub struct Separation {
    /// I+ then I-, electrons per exposure, float32: (2, H, W) for m1 and
    /// m1-pooled, else (N, 2, H, W), one per frame.
    pub estimate: Py<PyArrayDyn<f32>>,
    /// One-sigma standard errors, same shape; inf where there is no estimate.
    pub sigma: Py<PyArrayDyn<f32>>,
    /// `PixelFlags` bits, uint8: (H, W) or (N, H, W).
    pub flags: Py<PyArrayDyn<u8>>,
    pub method: String,
    /// Frames read.
    pub frames: usize,
    /// H's gain rho*eta, DN per electron.
    pub gain_dn_per_electron: f64,
    /// H's read-noise variance, DN^2.
    pub read_variance_dn2: f64,
    /// Estimates that overflowed float32, written as 0 and flagged NONFINITE.
    pub nonfinite: usize,
}

#[pymethods]
impl Separation {
    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "<sdi.Separation {} of {} frames, estimate {:?}>",
            self.method,
            self.frames,
            self.estimate.bind(py).shape()
        )
    }
}

/// Labels for M2: negative or non-finite = no segment.
fn labels(l: &Bound<'_, PyAny>, w: usize, h: usize) -> PyResult<Image<u32>> {
    let np = l.py().import("numpy")?;
    let l = np.call_method1("ascontiguousarray", (l, "float32"))?;
    let l = l.cast::<PyArrayDyn<f32>>()?.readonly();
    if l.shape() != [h, w] {
        return Err(PyValueError::new_err(format!(
            "segments of shape {:?}, expected ({h}, {w})",
            l.shape()
        )));
    }
    let data = l.as_slice()?.iter().map(|&v| label_from_f32(v)).collect();
    Ok(Image {
        width: w,
        height: h,
        data,
    })
}

/// Separates I+ and I- from `stack`, (N, H, W) or (H, W) difference frames
/// in DN with the dark frame subtracted (any real dtype; float32 as
/// `sdictl separate` reads an .npy), by `method`: "m1", "m1-pooled", "m2",
/// "m3" or "ml" (paper section 6; docs/offline-science.md). H comes from
/// `sensor` (a preset or a TOML file). The arguments are `sdictl
/// separate`'s flags.
#[pyfunction]
#[pyo3(signature = (stack, method = "m1", *, sensor = "ti", window = None, segments = None, sigma_domain_px = 3.0, range_sigmas = 3.0, keep_read_noise = false, nonnegative = false))]
#[allow(clippy::too_many_arguments)]
pub fn separate(
    py: Python<'_>,
    stack: &Bound<'_, PyAny>,
    method: &str,
    sensor: &str,
    window: Option<usize>,
    segments: Option<&Bound<'_, PyAny>>,
    sigma_domain_px: f64,
    range_sigmas: f64,
    keep_read_noise: bool,
    nonnegative: bool,
) -> PyResult<Separation> {
    let batch_method: BatchMethod = method.parse().map_err(|_| {
        PyValueError::new_err(format!(
            "method '{method}': expected one of m1, m1-pooled, m2, m3, ml"
        ))
    })?;
    for (name, v) in [
        ("sigma_domain_px", sigma_domain_px),
        ("range_sigmas", range_sigmas),
    ] {
        if !(v.is_finite() && v > 0.0 && v <= 1000.0) {
            return Err(PyValueError::new_err(format!(
                "{name} = {v}: expected a finite number in (0, 1000]"
            )));
        }
    }
    let np = py.import("numpy")?;
    let stack = np.call_method1("ascontiguousarray", (stack, "float32"))?;
    let stack = stack.cast::<PyArrayDyn<f32>>()?.readonly();
    let (n, h, w) = match *stack.shape() {
        [n, h, w] => (n, h, w),
        [h, w] => (1, h, w),
        ref s => {
            return Err(PyValueError::new_err(format!(
                "stack of shape {s:?}: expected (N, H, W) or (H, W)"
            )))
        }
    };
    if n == 0 || w * h == 0 {
        return Err(PyValueError::new_err("the stack holds no frames"));
    }
    let mixing = mixing_with_adc(&crate::simulate::sensor(sensor)?.params());
    let params = BatchParams {
        method: batch_method,
        window,
        labels: segments.map(|s| labels(s, w, h)).transpose()?,
        sigma_domain_px,
        range_sigmas,
        options: UnmixOptions {
            subtract_read_noise: !keep_read_noise,
            nonnegative,
        },
    };
    let mut separator = BatchSeparator::new(params, mixing, w, h)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let data = stack.as_slice()?;
    let npx = w * h;
    let single = separator.single_output();
    let outputs = if single { 1 } else { n };
    let mut est = Vec::with_capacity(outputs * 2 * npx);
    let mut sig = Vec::with_capacity(outputs * 2 * npx);
    let mut flags = Vec::with_capacity(outputs * npx);
    // The caller must not write into `stack` from another thread meanwhile.
    let nonfinite = py
        .detach(|| -> Result<usize, String> {
            let mut frame = Frame::new(w, h);
            let mut sep = Separated::default();
            let mut nonfinite = 0;
            let mut keep = |sep: &mut Separated| {
                nonfinite += sanitize(sep);
                est.extend_from_slice(&sep.i_plus_electrons.data);
                est.extend_from_slice(&sep.i_minus_electrons.data);
                sig.extend_from_slice(&sep.i_plus_se_electrons.data);
                sig.extend_from_slice(&sep.i_minus_se_electrons.data);
                flags.extend_from_slice(&sep.flags.data);
            };
            for (i, dn) in data.chunks_exact(npx).enumerate() {
                // As `sdictl separate` reads an .npy stack.
                frame.dn.data.copy_from_slice(dn);
                frame.saturated.data.fill(0);
                frame.sequence = i as u64;
                if separator
                    .push(&frame, &mut sep)
                    .map_err(|e| e.to_string())?
                {
                    keep(&mut sep);
                }
            }
            if separator.finish(&mut sep).map_err(|e| e.to_string())? {
                keep(&mut sep);
            }
            Ok(nonfinite)
        })
        .map_err(PyValueError::new_err)?;
    let (two, one): (Vec<usize>, Vec<usize>) = if single {
        (vec![2, h, w], vec![h, w])
    } else {
        (vec![n, 2, h, w], vec![n, h, w])
    };
    let flags = numpy::ndarray::ArrayD::from_shape_vec(one, flags)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(Separation {
        estimate: array(py, &two, est)?.unbind(),
        sigma: array(py, &two, sig)?.unbind(),
        flags: numpy::IntoPyArray::into_pyarray(flags, py).unbind(),
        method: batch_method.to_string(),
        frames: n,
        gain_dn_per_electron: mixing.gain_dn_per_electron,
        read_variance_dn2: mixing.read_variance_dn2,
        nonfinite,
    })
}
