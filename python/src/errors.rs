//! sdid's typed D-Bus errors (`sdi_api::SdiError`) as Python exceptions of
//! the same names, subclasses of `sdi.Error`, carrying sdid's message; and
//! the errors of this module's own work.

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use sdi_api::SdiError;

create_exception!(sdi, Error, PyException, "Base of every sdi error.");
create_exception!(
    sdi,
    BusError,
    Error,
    "The bus or sdid cannot be reached, or the call failed in transport."
);
create_exception!(
    sdi,
    Timeout,
    Error,
    "No frame in time; the message says what sdid reports."
);
create_exception!(
    sdi,
    StreamError,
    Error,
    "sdid's frame stream ended or broke."
);
create_exception!(
    sdi,
    InvalidMode,
    Error,
    "Unknown mode name; the message lists the valid modes."
);
create_exception!(
    sdi,
    OutOfRange,
    Error,
    "A number outside its allowed range (the message gives the range)."
);
create_exception!(
    sdi,
    DeviceUnavailable,
    Error,
    "The sensor or output device is gone."
);
create_exception!(
    sdi,
    Busy,
    Error,
    "Another long operation (dark frame, calibration, recording) is running."
);
create_exception!(
    sdi,
    Cancelled,
    Error,
    "The job (dark frame, calibration) was cancelled: Cancel, its caller left, or its deadline."
);
create_exception!(sdi, InvalidPath, Error, "A path sdid refuses.");
create_exception!(
    sdi,
    InvalidFd,
    Error,
    "A passed file descriptor sdid refuses."
);
create_exception!(
    sdi,
    NotRecording,
    Error,
    "StopRecording without a recording."
);
create_exception!(sdi, NoFrame, Error, "Snapshot before the first frame.");
create_exception!(
    sdi,
    RecordingStopped,
    Error,
    "sdid stopped the recording by itself."
);
create_exception!(sdi, Failed, Error, "Anything else sdid reports as failed.");

/// The exception of one of sdid's errors, with sdid's message. The match
/// is exhaustive: a new variant in `SdiError` needs its exception here.
pub fn from_sdi(e: SdiError) -> PyErr {
    match e {
        SdiError::ZBus(e) => bus(e),
        SdiError::InvalidMode(m) => InvalidMode::new_err(m),
        SdiError::OutOfRange(m) => OutOfRange::new_err(m),
        SdiError::DeviceUnavailable(m) => DeviceUnavailable::new_err(m),
        SdiError::Busy(m) => Busy::new_err(m),
        SdiError::Cancelled(m) => Cancelled::new_err(m),
        SdiError::InvalidPath(m) => InvalidPath::new_err(m),
        SdiError::InvalidFd(m) => InvalidFd::new_err(m),
        SdiError::NotRecording(m) => NotRecording::new_err(m),
        SdiError::NoFrame(m) => NoFrame::new_err(m),
        SdiError::RecordingStopped(m) => RecordingStopped::new_err(m),
        SdiError::Failed(m) => Failed::new_err(m),
    }
}

/// A transport or standard D-Bus error.
pub fn bus(e: zbus::Error) -> PyErr {
    BusError::new_err(e.to_string())
}

/// Adds every exception to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    for (name, ty) in [
        ("Error", py.get_type::<Error>()),
        ("BusError", py.get_type::<BusError>()),
        ("Timeout", py.get_type::<Timeout>()),
        ("StreamError", py.get_type::<StreamError>()),
        ("InvalidMode", py.get_type::<InvalidMode>()),
        ("OutOfRange", py.get_type::<OutOfRange>()),
        ("DeviceUnavailable", py.get_type::<DeviceUnavailable>()),
        ("Busy", py.get_type::<Busy>()),
        ("Cancelled", py.get_type::<Cancelled>()),
        ("InvalidPath", py.get_type::<InvalidPath>()),
        ("InvalidFd", py.get_type::<InvalidFd>()),
        ("NotRecording", py.get_type::<NotRecording>()),
        ("NoFrame", py.get_type::<NoFrame>()),
        ("RecordingStopped", py.get_type::<RecordingStopped>()),
        ("Failed", py.get_type::<Failed>()),
    ] {
        m.add(name, ty)?;
    }
    Ok(())
}
