//! `sdi.read_recording`: a `.sdirec` recording, read lazily through the
//! recording crate's reader, frames dark-subtracted as `sdictl separate`
//! uses them (`sdi_recording::RecordedFrames`).

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3};
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use sdi_recording::{Header, RecordedFrames, RecordingReader};

type Frames = RecordedFrames<BufReader<File>>;

fn open(path: &Path) -> PyResult<Frames> {
    let reader = RecordingReader::open(path).map_err(|e| match e {
        sdi_recording::ReadError::Io(io) => {
            PyOSError::new_err(format!("'{}': {io}", path.display()))
        }
        e => PyValueError::new_err(format!("'{}': {e}", path.display())),
    })?;
    Ok(RecordedFrames::new(reader))
}

fn next(
    frames: &mut Frames,
    path: &std::path::Path,
) -> PyResult<Option<sdi_recording::DarkSubtracted>> {
    frames
        .next_frame()
        .map_err(|e| PyValueError::new_err(format!("'{}': {e}", path.display())))
}

/// A recording: its header now, its frames when asked for.
#[pyclass(module = "sdi", frozen)]
pub struct Recording {
    path: PathBuf,
    header: Header,
}

/// One recorded frame, dark frame subtracted.
#[pyclass(module = "sdi", frozen, get_all)]
pub struct RecordedFrame {
    /// Signed difference, DN, float32 (height, width), dark frame subtracted.
    pub dn: Py<PyArray2<f32>>,
    /// Non-zero where a well or the ADC saturated, uint8 (height, width).
    pub saturated: Py<PyArray2<u8>>,
    pub sequence: u64,
    pub timestamp_us: u64,
    /// The mode the frame was recorded in.
    pub mode: String,
}

fn to_py(py: Python<'_>, f: sdi_recording::DarkSubtracted) -> PyResult<RecordedFrame> {
    let (w, h) = (f.frame.width(), f.frame.height());
    let shape_err = |e: numpy::ndarray::ShapeError| PyValueError::new_err(e.to_string());
    Ok(RecordedFrame {
        dn: Array2::from_shape_vec((h, w), f.frame.dn.data)
            .map_err(shape_err)?
            .into_pyarray(py)
            .unbind(),
        saturated: Array2::from_shape_vec((h, w), f.frame.saturated.data)
            .map_err(shape_err)?
            .into_pyarray(py)
            .unbind(),
        sequence: f.frame.sequence,
        timestamp_us: f.frame.timestamp_us,
        mode: f.mode,
    })
}

/// Iterates over a recording's frames, one read at a time.
#[pyclass(module = "sdi")]
pub struct RecordingFrames {
    path: PathBuf,
    frames: Frames,
}

#[pymethods]
impl RecordingFrames {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&mut self, py: Python<'_>) -> PyResult<Option<RecordedFrame>> {
        let (frames, path) = (&mut self.frames, &self.path);
        match py.detach(|| frames.next_frame()) {
            Ok(Some(f)) => to_py(py, f).map(Some),
            Ok(None) => Ok(None),
            Err(e) => Err(PyValueError::new_err(format!("'{}': {e}", path.display()))),
        }
    }
}

#[pymethods]
impl Recording {
    /// The path it was opened from.
    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    /// The header as recorded (mode, backend, sensor, exposure_us, ...), a dict.
    #[getter]
    fn header<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let json = serde_json::to_string(&self.header)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        py.import("json")?.call_method1("loads", (json,))
    }

    #[getter]
    fn width(&self) -> usize {
        self.header.sensor.width
    }

    #[getter]
    fn height(&self) -> usize {
        self.header.sensor.height
    }

    /// The mode when the recording started (each frame names its own).
    #[getter]
    fn mode(&self) -> String {
        self.header.mode.clone()
    }

    /// The frames one at a time.
    fn __iter__(&self) -> PyResult<RecordingFrames> {
        Ok(RecordingFrames {
            path: self.path.clone(),
            frames: open(&self.path)?,
        })
    }

    /// Frames `start` to `stop` (None: to the end) as one (n, height, width)
    /// float32 array, DN, dark frame subtracted.
    #[pyo3(signature = (start = 0, stop = None))]
    fn read<'py>(
        &self,
        py: Python<'py>,
        start: usize,
        stop: Option<usize>,
    ) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let (w, h) = (self.width(), self.height());
        let path = &self.path;
        let read = py.detach(|| -> PyResult<(usize, Vec<f32>)> {
            let mut frames = open(path)?;
            let (mut n, mut i, mut data) = (0, 0, Vec::new());
            while stop.is_none_or(|s| i < s) {
                let Some(f) = next(&mut frames, path)? else {
                    break;
                };
                if i >= start {
                    data.extend_from_slice(&f.frame.dn.data);
                    n += 1;
                }
                i += 1;
            }
            Ok((n, data))
        })?;
        let (n, data) = read;
        Ok(Array3::from_shape_vec((n, h, w), data)
            .map_err(|e| PyValueError::new_err(e.to_string()))?
            .into_pyarray(py))
    }

    fn __repr__(&self) -> String {
        format!(
            "<sdi.Recording '{}' {} {}x{}>",
            self.path.display(),
            self.header.mode,
            self.width(),
            self.height()
        )
    }
}

/// Opens a `.sdirec` recording: its header is read now, its frames when
/// iterated over or `read()`.
#[pyfunction]
pub fn read_recording(path: PathBuf) -> PyResult<Recording> {
    let frames = open(&path)?;
    Ok(Recording {
        header: frames.header().clone(),
        path,
    })
}
