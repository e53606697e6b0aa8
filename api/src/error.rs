//! Every error `org.sdi.Camera1` returns, `org.sdi.Error.*`: the daemon
//! returns these variants, the proxy decodes them back into them.

/// The interface's errors; the message says what was wrong and what is allowed.
#[derive(Debug, zbus::DBusError)]
#[zbus(prefix = "org.sdi.Error")]
pub enum SdiError {
    /// Transport and standard D-Bus errors (no daemon, access denied, ...).
    #[zbus(error)]
    ZBus(zbus::Error),
    /// Unknown mode name; the message lists the valid modes.
    InvalidMode(String),
    /// A number outside its allowed range (the message gives the range).
    OutOfRange(String),
    /// The sensor or output device is gone.
    DeviceUnavailable(String),
    /// Another long operation (dark frame, calibration, recording) is running;
    /// the message names it.
    Busy(String),
    /// The job (dark frame, calibration) was cancelled: `Cancel`, its caller
    /// left the bus, or it ran past its deadline; the message says which.
    Cancelled(String),
    /// A path a path method refuses (anything but a new `<state dir>/NAME.ext`;
    /// one message whatever the reason), or a recording label it cannot show.
    InvalidPath(String),
    /// A passed file descriptor the method does not take (the message says
    /// what it was given and what it takes).
    InvalidFd(String),
    /// StopRecording without a recording.
    NotRecording(String),
    /// Snapshot before the first frame.
    NoFrame(String),
    /// The daemon stopped the recording by itself: `[recording] max_bytes`
    /// reached, free space below `min_free_bytes`, or the disk full. Every
    /// frame written before stays readable; the message says why.
    RecordingStopped(String),
    /// Anything else (I/O while writing a file, ...).
    Failed(String),
}
