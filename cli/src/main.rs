//! sdictl: command-line control of the SDI daemon, and offline tools. The
//! commands live in the library ([`sdi_cli::run`]).
#![forbid(unsafe_code)]

use std::process::ExitCode;

fn main() -> ExitCode {
    sdi_cli::main_with_args(std::env::args_os())
}
