//! `sdid` for the integration tests: the same library start-up as
//! `daemon/src/main.rs`, built by `cargo test` as a bin of this package (see
//! `sdi_tests::dbus::bin` for why).

use std::process::ExitCode;

use clap::Parser;
use sdi_daemon::args::Args;
use sdi_daemon::{logging, startup};

fn main() -> ExitCode {
    let args = Args::parse();
    logging::init();
    startup::exit_code(args.into_options().and_then(startup::run))
}
