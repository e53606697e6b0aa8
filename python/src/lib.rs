//! `import sdi`: sdid's camera (`org.sdi.Camera1`) and the offline science
//! from Python, on the workspace's own crates so that no contract is
//! written twice: the D-Bus proxy and errors of `sdi-api`, the frame
//! stream's wire format, the recording reader, the simulator run and the
//! separation estimators of `sdi-core` that `sdictl` runs.
#![deny(unsafe_code)]

mod camera;
mod errors;
mod frames;
mod recording;
mod separate;
mod simulate;

use pyo3::prelude::*;

#[pymodule]
fn _sdi(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    errors::register(m)?;
    m.add_class::<camera::Camera>()?;
    m.add_class::<camera::FrameStream>()?;
    m.add_class::<frames::Frame>()?;
    m.add_class::<recording::Recording>()?;
    m.add_class::<recording::RecordedFrame>()?;
    m.add_class::<recording::RecordingFrames>()?;
    m.add_class::<separate::Separation>()?;
    m.add_function(wrap_pyfunction!(camera::cameras, m)?)?;
    m.add_function(wrap_pyfunction!(recording::read_recording, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::simulate, m)?)?;
    m.add_function(wrap_pyfunction!(separate::separate, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::modes, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::scenes, m)?)?;
    Ok(())
}
