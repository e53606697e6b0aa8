//! sdid: the SDI difference-camera daemon. Start-up lives in the library
//! ([`sdi_daemon::startup`]); this shell parses the command line, installs
//! logging and maps the result to an exit code.
#![forbid(unsafe_code)]

use std::process::ExitCode;

use clap::Parser;
use sdi_daemon::args::Args;
use sdi_daemon::{logging, startup};

fn main() -> ExitCode {
    let args = Args::parse();
    logging::init();
    startup::exit_code(args.into_options().and_then(startup::run))
}
