//! `sdi.Camera`: sdid's `org.sdi.Camera1` through the api crate's proxy
//! (`sdi_api::Camera1Proxy`), its settings as properties, its frames as
//! numpy arrays (`frames.rs`). Every call releases the GIL while it waits.

use std::collections::HashMap;
use std::os::fd::OwnedFd;
use std::os::unix::net::UnixStream;
use std::time::{Duration, Instant};

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use sdi_api::cameras::{self as served, ChooseError};
use sdi_api::{Camera1Proxy, Change, Properties, Setting};
use zbus::proxy::CacheProperties;
use zbus::zvariant::Fd;

use crate::errors::{self, BusError, StreamError, Timeout};
use crate::frames::{Frame, FrameReader, ReadError};

/// Longest wait for the bus to accept the connection (as sdictl's).
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// sdid's camera on the system bus (default) or the session bus.
#[pyclass(module = "sdi", frozen)]
pub struct Camera {
    rt: tokio::runtime::Runtime,
    proxy: Camera1Proxy<'static>,
}

impl Camera {
    /// Runs one proxy call with the GIL released.
    fn call<T: Send, F>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(Camera1Proxy<'static>) -> F + Send,
    ) -> T
    where
        F: std::future::Future<Output = T>,
    {
        py.detach(|| self.rt.block_on(f(self.proxy.clone())))
    }

    fn property<T: Send, F>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(Camera1Proxy<'static>) -> F + Send,
    ) -> PyResult<T>
    where
        F: std::future::Future<Output = zbus::Result<T>>,
    {
        self.call(py, f).map_err(errors::bus)
    }

    fn change(&self, py: Python<'_>, change: Change) -> PyResult<(u64, u64)> {
        self.call(py, |p| async move { change.send(&p).await })
            .map_err(errors::from_sdi)
    }

    /// Asks sdid to stream its frames into a new socket; our end.
    pub(crate) fn open_stream(&self, py: Python<'_>) -> PyResult<FrameReader> {
        let (ours, theirs) = UnixStream::pair().map_err(|e| {
            StreamError::new_err(format!("creating the socket for sdid's frames: {e}"))
        })?;
        let theirs = OwnedFd::from(theirs);
        self.call(py, |p| {
            let fd = Fd::from(&theirs);
            async move { p.stream_frames(fd).await }
        })
        .map_err(errors::from_sdi)?;
        drop(theirs);
        Ok(FrameReader::new(ours))
    }

    /// What sdid says about its frames, for a timeout's message.
    fn why_no_frames(&self, py: Python<'_>) -> String {
        let state = self.call(py, |p| async move {
            Ok::<_, zbus::Error>((p.stats().await?, p.backend().await?, p.device().await?))
        });
        match state {
            Err(e) => format!("sdid does not answer ({e})"),
            Ok((stats, backend, device)) => {
                let words = if stats.device_state.is_empty() {
                    String::new()
                } else {
                    format!(": {}", stats.device_state)
                };
                let what = if !stats.device_available {
                    format!("the device is unavailable{words}")
                } else if stats.fps == 0.0 {
                    if stats.last_frame_age_s < 0.0 {
                        format!("not streaming, no frame yet{words}")
                    } else {
                        format!(
                            "not streaming, last frame {:.1} s ago{words}",
                            stats.last_frame_age_s
                        )
                    }
                } else {
                    format!(
                        "streaming at {:.1} fps, yet none reached this reader",
                        stats.fps
                    )
                };
                format!("sdid ({backend} backend, {device}) reports {what}")
            }
        }
    }

    /// The next frame of `reader` before `timeout` seconds (None: no limit);
    /// Python's signal handlers run while it waits.
    pub(crate) fn read_frame(
        &self,
        py: Python<'_>,
        reader: &mut FrameReader,
        timeout: Option<f64>,
    ) -> PyResult<Frame> {
        let deadline = match timeout {
            Some(t) if t.is_finite() && t >= 0.0 => {
                Some(Instant::now() + Duration::from_secs_f64(t))
            }
            Some(t) => {
                return Err(PyValueError::new_err(format!(
                    "timeout {t} s: expected a finite number >= 0 or None"
                )))
            }
            None => None,
        };
        loop {
            match py.detach(|| reader.read(deadline)) {
                Ok(raw) => return raw.into_py(py),
                Err(ReadError::Interrupted) => py.check_signals()?,
                Err(ReadError::Timeout) => {
                    return Err(Timeout::new_err(format!(
                        "no frame within {} s; {}",
                        timeout.unwrap_or(0.0),
                        self.why_no_frames(py)
                    )))
                }
                Err(e) => return Err(StreamError::new_err(e.to_string())),
            }
        }
    }
}

/// A reply (`a{sv}`) as a dict keyed as on the bus, as `sdictl --json` prints it.
fn as_dict<'py, T: serde::Serialize + zbus::zvariant::Type>(
    py: Python<'py>,
    reply: &T,
) -> PyResult<Bound<'py, PyAny>> {
    let json = sdi_api::wire_json::object(reply)
        .map(|o| serde_json::Value::Object(o).to_string())
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (json,))
}

/// Why a camera could not be opened.
enum Opening {
    Bus(zbus::Error),
    Choose(ChooseError),
}

impl From<zbus::Error> for Opening {
    fn from(e: zbus::Error) -> Self {
        Opening::Bus(e)
    }
}

fn runtime() -> PyResult<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// The bus at `address`, else the system bus, within [`CONNECT_TIMEOUT`].
async fn connect(address: Option<&str>) -> zbus::Result<zbus::Connection> {
    let builder = match address {
        Some(a) => zbus::connection::Builder::address(a)?,
        None => zbus::connection::Builder::system()?,
    };
    tokio::time::timeout(CONNECT_TIMEOUT, builder.build())
        .await
        .map_err(|_| zbus::Error::Failure("timed out connecting to the bus".into()))?
}

/// The serials of the cameras sdid serves, in the order it opened them
/// (`bus` and `address` as for `Camera`).
#[pyfunction]
#[pyo3(signature = (bus = "system", address = None))]
pub fn cameras(py: Python<'_>, bus: &str, address: Option<String>) -> PyResult<Vec<String>> {
    let address = bus_address(bus, address)?;
    let rt = runtime()?;
    let listed = py.detach(|| {
        rt.block_on(async {
            let conn = connect(address.as_deref()).await?;
            served::list(&conn).await
        })
    });
    Ok(listed
        .map_err(errors::bus)?
        .into_iter()
        .map(|c| c.serial)
        .collect())
}

fn bus_address(bus: &str, address: Option<String>) -> PyResult<Option<String>> {
    if address.is_some() {
        return Ok(address);
    }
    match bus {
        "system" => Ok(None),
        "session" => sdi_api::bus::session_or_private_address().map(Some).ok_or_else(|| {
            BusError::new_err(
                "no session bus found (DBUS_SESSION_BUS_ADDRESS unset) and no private bus of sdid --session",
            )
        }),
        other => Err(PyValueError::new_err(format!(
            "bus '{other}': expected 'system' or 'session'"
        ))),
    }
}

#[pymethods]
impl Camera {
    /// Connects to sdid: `bus` is "system" (default) or "session" (the
    /// session bus, else the private bus `sdid --session` started);
    /// `address` (a D-Bus address) overrides both. `serial` names the
    /// camera among several (`sdi.cameras()`); the only one by default.
    #[new]
    #[pyo3(signature = (bus = "system", address = None, serial = None))]
    fn new(
        py: Python<'_>,
        bus: &str,
        address: Option<String>,
        serial: Option<String>,
    ) -> PyResult<Self> {
        let address = bus_address(bus, address)?;
        // One worker: the connection's reader runs between calls too.
        let rt = runtime()?;
        let proxy = py.detach(|| {
            rt.block_on(async {
                let conn = connect(address.as_deref()).await?;
                let listed = served::list(&conn).await?;
                let path = served::choose(&listed, serial.as_deref())
                    .map_err(Opening::Choose)?
                    .path
                    .clone();
                // No cache: a property read right after a change sees it.
                Ok(served::proxy(&conn, path, CacheProperties::No).await?)
            })
        });
        let proxy = proxy.map_err(|e| match e {
            Opening::Bus(e) => errors::bus(e),
            Opening::Choose(e @ ChooseError::NoCamera) => BusError::new_err(e.to_string()),
            Opening::Choose(e) => PyValueError::new_err(e.to_string()),
        })?;
        let camera = Self { rt, proxy };
        // Fails here, not at the first use, when sdid is not on the bus.
        camera.property(py, |p| async move { p.mode().await })?;
        Ok(camera)
    }

    /// The camera's serial: the board's USB serial, `sim-N` for the simulator.
    #[getter]
    fn serial(&self, py: Python<'_>) -> PyResult<String> {
        self.property(py, |p| async move { p.serial().await })
    }

    /// The current mode's name; setting it switches the mode.
    #[getter]
    fn mode(&self, py: Python<'_>) -> PyResult<String> {
        self.property(py, |p| async move { p.mode().await })
    }
    #[setter]
    fn set_mode(&self, py: Python<'_>, mode: String) -> PyResult<()> {
        self.change(py, Change::Mode(mode)).map(drop)
    }

    /// Exposure per frame, microseconds.
    #[getter]
    fn exposure_us(&self, py: Python<'_>) -> PyResult<f64> {
        self.property(py, |p| async move { p.exposure_us().await })
    }
    #[setter]
    fn set_exposure_us(&self, py: Python<'_>, us: f64) -> PyResult<()> {
        self.change(py, Change::ExposureUs(us)).map(drop)
    }

    /// Frames per second, Hz.
    #[getter]
    fn frame_rate(&self, py: Python<'_>) -> PyResult<f64> {
        self.property(py, |p| async move { p.frame_rate().await })
    }
    #[setter]
    fn set_frame_rate(&self, py: Python<'_>, hz: f64) -> PyResult<()> {
        self.change(py, Change::FrameRate(hz)).map(drop)
    }

    /// Carrier frequency, Hz.
    #[getter]
    fn modulation_hz(&self, py: Python<'_>) -> PyResult<f64> {
        self.property(py, |p| async move { p.modulation_hz().await })
    }
    #[setter]
    fn set_modulation_hz(&self, py: Python<'_>, hz: f64) -> PyResult<()> {
        self.change(py, Change::ModulationHz(hz)).map(drop)
    }

    /// "diverging" or "grey".
    #[getter]
    fn colormap(&self, py: Python<'_>) -> PyResult<String> {
        self.property(py, |p| async move { p.colormap().await })
    }
    #[setter]
    fn set_colormap(&self, py: Python<'_>, colormap: String) -> PyResult<()> {
        self.change(py, Change::Colormap(colormap)).map(drop)
    }

    /// |DN| at full scale of the view; 0 = symmetric auto.
    #[getter]
    fn range(&self, py: Python<'_>) -> PyResult<f64> {
        self.property(py, |p| async move { p.range().await })
    }
    #[setter]
    fn set_range(&self, py: Python<'_>, max_abs_dn: f64) -> PyResult<()> {
        self.change(py, Change::Range(max_abs_dn)).map(drop)
    }

    /// Changes a setting by its `sdictl set` name ("exposure-us",
    /// "exposure_us" or "ExposureUs"); returns (sequence, timestamp_us) of
    /// the first frame under it.
    fn set(&self, py: Python<'_>, name: &str, value: &Bound<'_, PyAny>) -> PyResult<(u64, u64)> {
        let setting = Setting::from_user(name).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let change = setting
            .change(&value.str()?.to_cow()?)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        self.change(py, change)
    }

    /// Every mode's name.
    #[getter]
    fn modes(&self, py: Python<'_>) -> PyResult<Vec<String>> {
        self.property(py, |p| async move { p.modes().await })
    }

    /// The physical setup the current mode expects: {ls1, ls2, optics}.
    #[getter]
    fn setup(&self, py: Python<'_>) -> PyResult<HashMap<String, String>> {
        self.property(py, |p| async move { p.setup().await })
    }

    /// The backend delivering frames: "sim", "replay", "opt8241".
    #[getter]
    fn backend(&self, py: Python<'_>) -> PyResult<String> {
        self.property(py, |p| async move { p.backend().await })
    }

    /// "sensor -> output".
    #[getter]
    fn device(&self, py: Python<'_>) -> PyResult<String> {
        self.property(py, |p| async move { p.device().await })
    }

    #[getter]
    fn width(&self, py: Python<'_>) -> PyResult<u32> {
        self.property(py, |p| async move { p.width().await })
    }

    #[getter]
    fn height(&self, py: Python<'_>) -> PyResult<u32> {
        self.property(py, |p| async move { p.height().await })
    }

    /// Path or label being recorded to, "" when not recording.
    #[getter]
    fn recording(&self, py: Python<'_>) -> PyResult<String> {
        self.property(py, |p| async move { p.recording().await })
    }

    /// The ranges the setters accept: {"ExposureUs": (min, max), "FrameRate": ..., "ModulationHz": ...}.
    #[getter]
    fn limits(&self, py: Python<'_>) -> PyResult<HashMap<String, (f64, f64)>> {
        self.property(py, |p| async move { p.limits().await })
    }

    /// Every property at once, keyed by its D-Bus name, as `sdictl --json status`.
    fn status<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let props = self.property(py, |p| async move { Properties::read(&p).await })?;
        as_dict(py, &props)
    }

    /// Frame counts, rates and the device's state (`Stats`), a dict keyed as on the bus.
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let stats = self.property(py, |p| async move { p.stats().await })?;
        as_dict(py, &stats)
    }

    /// The next frame sdid publishes; `timeout` seconds at most (None: no
    /// limit), else `sdi.Timeout` saying what sdid reports.
    #[pyo3(signature = (timeout = 2.0))]
    fn frame(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Frame> {
        let mut reader = self.open_stream(py)?;
        self.read_frame(py, &mut reader, timeout)
    }

    /// sdid's frames as they come, each within `timeout` seconds; a context
    /// manager that ends the stream.
    #[pyo3(signature = (timeout = 2.0))]
    fn frames(slf: Bound<'_, Self>, timeout: Option<f64>) -> PyResult<FrameStream> {
        let reader = slf.get().open_stream(slf.py())?;
        Ok(FrameStream {
            camera: slf.unbind(),
            reader: Some(reader),
            timeout,
        })
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        match self.property(py, |p| async move { p.device().await }) {
            Ok(d) => format!("<sdi.Camera {d}>"),
            Err(_) => "<sdi.Camera (sdid gone)>".into(),
        }
    }
}

/// sdid's frames, one per iteration; ends the stream on `close()` or when
/// its `with` block ends.
#[pyclass(module = "sdi")]
pub struct FrameStream {
    camera: Py<Camera>,
    reader: Option<FrameReader>,
    timeout: Option<f64>,
}

#[pymethods]
impl FrameStream {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&mut self, py: Python<'_>) -> PyResult<Option<Frame>> {
        let Some(reader) = self.reader.as_mut() else {
            return Ok(None);
        };
        self.camera
            .get()
            .read_frame(py, reader, self.timeout)
            .map(Some)
    }

    /// Ends the stream (sdid stops writing to it).
    fn close(&mut self) {
        self.reader = None;
    }

    fn __enter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&mut self, _args: &Bound<'_, pyo3::types::PyTuple>) -> bool {
        self.close();
        false
    }
}
