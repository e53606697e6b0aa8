//! sdictl: command-line control of the SDI daemon, and offline tools. The
//! commands live in the library ([`sdi_cli::run`]).
#![forbid(unsafe_code)]

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    sdi_cli::run(sdi_cli::Cli::parse())
}
