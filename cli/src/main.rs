//! sdictl: command-line control of the SDI daemon, and offline tools.
//!
//! Each subcommand lives in its own module; adding one is a variant here and a
//! line in `main`'s dispatch.

mod atomic_file;
mod exit;
mod offline;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "sdictl",
    version,
    about = "Snapshot difference imaging control and offline tools"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Simulate a scene through a mode pipeline and write the frames (.npy) and one display frame (.png).
    Sim(offline::sim::SimArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Sim(args) => offline::sim::run(args),
    };
    exit::report(result)
}
