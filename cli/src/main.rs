//! sdictl: command-line control of the SDI daemon, and offline tools.

mod offline;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(name = "sdictl", about = "Control snapshot difference imaging")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Offline reports on simulator data.
    #[command(subcommand)]
    Report(Report),
}

#[derive(Debug, Subcommand)]
enum Report {
    /// Error against run time of every separation estimator (I+, I- recovery).
    Separation(offline::report::SeparationReportArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Report(Report::Separation(args)) => offline::report::run(&args).map(|_| ()),
    };
    if let Err(e) = result {
        eprintln!("sdictl: {e}");
        std::process::exit(1);
    }
}
