//! `sdictl` for the integration tests: the same library entry as
//! `cli/src/main.rs`, built by `cargo test` as a bin of this package (see
//! `sdi_tests::dbus::bin` for why).

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    sdi_cli::run(sdi_cli::Cli::parse())
}
