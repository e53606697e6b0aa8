//! sdid: the SDI difference-camera daemon. Start-up lives in the library
//! ([`sdi_daemon::startup`]); this shell parses the command line, installs
//! logging and maps the result to an exit code.

use std::process::ExitCode;

use clap::Parser;
use sdi_daemon::args::Args;
use sdi_daemon::{logging, startup};

fn main() -> ExitCode {
    // `sdid --pipewire-camera SPEC`: the PipeWire camera process sdid starts.
    #[cfg(feature = "pipewire")]
    if let Some(code) = sdi_daemon::pipewire_camera::server::run_if_asked() {
        return code;
    }
    let args = Args::parse();
    logging::init();
    startup::exit_code(args.into_options().and_then(startup::run))
}
