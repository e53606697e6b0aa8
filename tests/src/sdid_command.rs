//! `sdid` as the tests run it: one builder for every launch, so the
//! program's path, its log level and "not a systemd service" are said once,
//! and each test adds only its bus, backend, sink, files and environment.

use std::ffi::OsStr;
use std::path::Path;
use std::process::Command;

use crate::dbus::bin;

/// A `Command` for the test's `sdid`, built step by step.
pub struct SdidCommand(Command);

impl SdidCommand {
    /// The built `sdid` ([`bin`]), `RUST_LOG=warn`, and never taken for a
    /// systemd service (no `INVOCATION_ID`, no `JOURNAL_STREAM`), even when
    /// the tests run in one.
    pub fn new() -> Self {
        Self::wrapped_by(&[])
    }

    /// [`SdidCommand::new`] as a client of a PipeWire session (its runtime
    /// directory and bus: sdid's PipeWire camera joins that session).
    pub fn client_of(session: &crate::pipewire::Clients) -> Self {
        Self::test_environment(session.command(bin("sdid")))
    }

    /// [`SdidCommand::new`], run by `wrapper` (a program and its arguments
    /// that exec sdid in the same process: `unshare`, `setpriv` ...).
    pub fn wrapped_by(wrapper: &[&str]) -> Self {
        let cmd = match wrapper.split_first() {
            Some((program, args)) => {
                let mut c = Command::new(program);
                c.args(args).arg(bin("sdid"));
                c
            }
            None => Command::new(bin("sdid")),
        };
        Self::test_environment(cmd)
    }

    fn test_environment(mut cmd: Command) -> Self {
        cmd.env("RUST_LOG", "warn")
            .env_remove("INVOCATION_ID")
            .env_remove("JOURNAL_STREAM");
        Self(cmd)
    }

    /// On the bus at `address` (`--bus-address`).
    pub fn bus(mut self, address: &str) -> Self {
        self.0.args(["--bus-address", address]);
        self
    }

    /// The simulator (`--backend sim`).
    pub fn sim(mut self) -> Self {
        self.0.args(["--backend", "sim"]);
        self
    }

    /// The y4m sink writing to `path` ("-": stdout).
    pub fn y4m(mut self, path: impl AsRef<OsStr>) -> Self {
        self.0.args(["--sink", "y4m", "--y4m-path"]).arg(path);
        self
    }

    /// `--state-dir`.
    pub fn state_dir(mut self, dir: &Path) -> Self {
        self.0.arg("--state-dir").arg(dir);
        self
    }

    /// `--config`.
    pub fn config(mut self, file: &Path) -> Self {
        self.0.arg("--config").arg(file);
        self
    }

    /// More arguments.
    pub fn args<I, S>(mut self, args: I) -> Self
    where
        I: IntoIterator<Item = S>,
        S: AsRef<OsStr>,
    {
        self.0.args(args);
        self
    }

    /// The log filter (`RUST_LOG`).
    pub fn log(mut self, filter: &str) -> Self {
        self.0.env("RUST_LOG", filter);
        self
    }

    /// The `Command`, for what is left (environment, stdio, spawn).
    pub fn command(self) -> Command {
        self.0
    }
}

impl Default for SdidCommand {
    fn default() -> Self {
        Self::new()
    }
}
