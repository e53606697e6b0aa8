//! sdictl: command-line control of the SDI daemon, and offline tools, as a
//! library: the `sdictl` binary is [`Cli`] parsed and handed to [`run`].
//!
//! Each subcommand lives in its own module; adding one is a variant here and a
//! line in [`run`]'s dispatch.
#![forbid(unsafe_code)]

mod atomic_file;
mod exit;
mod offline;
mod online;
mod output_name;
mod stdout;
mod view;

use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "sdictl",
    version,
    about = "Snapshot difference imaging control and offline tools"
)]
pub struct Cli {
    #[command(flatten)]
    bus: online::BusArgs,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Simulate a scene through a mode pipeline and write the frames (.npy) and one display frame (.png).
    Sim(offline::sim::SimArgs),
    /// Separate I+ and I- offline from a recording (.sdirec) or an .npy stack (section 6: M1, M2, M3, Skellam ML).
    Separate(offline::separate::SeparateArgs),
    /// Offline reports on simulator data.
    #[command(subcommand)]
    Report(Report),
    /// The OPT8241-CDK board, offline.
    #[command(subcommand)]
    Board(Board),
    #[command(flatten)]
    Online(online::OnlineCommand),
    /// Print shell completions (bash, zsh, fish, elvish, powershell).
    Completions { shell: clap_complete::Shell },
    /// Print the man page (roff) generated from these definitions.
    Man,
}

#[derive(Debug, Subcommand)]
enum Report {
    /// Error against run time of every separation estimator (I+, I- recovery).
    Separation(offline::separation_report::SeparationReportArgs),
    /// Variance against intensity, snapshot vs two-shot, and the ratio of the low-light intercepts (section 5.5).
    Noise(offline::noise_report::NoiseReportArgs),
}

#[derive(Debug, Subcommand)]
enum Board {
    /// Print the exact register sequence sdid performs to open and configure the board (or why the board cannot do it).
    Plan(offline::board_plan::BoardPlanArgs),
}

/// Parses `args` (the program name first) and runs them. A command line
/// clap refuses exits 2 as clap says (help and version print as usual);
/// under `--json` its message is also the JSON error object on stdout, as
/// for every other refusal.
pub fn main_with_args<I, T>(args: I) -> ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let args: Vec<std::ffi::OsString> = args.into_iter().map(Into::into).collect();
    match Cli::try_parse_from(&args) {
        Ok(cli) => run(cli),
        Err(e) if !e.use_stderr() => {
            // --help, --version: text on stdout, exit 0.
            let _ = e.print();
            ExitCode::SUCCESS
        }
        Err(e) => {
            if json_asked(&args) {
                let message = e.kind().as_str().map_or_else(
                    || e.to_string().trim().to_owned(),
                    |kind| format!("{kind}: {}", first_line(&e.to_string())),
                );
                exit::report_usage_json(&message);
            }
            let _ = e.print();
            ExitCode::from(exit::Outcome::Invalid.exit_code())
        }
    }
}

/// Whether `--json` is among the options (before a `--`): clap refused
/// the line, so it is looked for by hand.
fn json_asked(args: &[std::ffi::OsString]) -> bool {
    args.iter()
        .skip(1)
        .take_while(|a| *a != "--")
        .any(|a| a == "--json")
}

/// clap's message without its "error: " prefix and usage lines.
fn first_line(text: &str) -> &str {
    let line = text.lines().next().unwrap_or_default();
    line.strip_prefix("error: ").unwrap_or(line).trim()
}

/// Runs one parsed command line; the exit code follows `exit`'s table.
pub fn run(cli: Cli) -> ExitCode {
    let json = cli.bus.json;
    let result = match cli.command {
        Command::Sim(args) => offline::sim::run(args, json),
        Command::Separate(args) => offline::separate::run(args, json),
        Command::Report(Report::Noise(args)) => offline::noise_report::run(&args, json),
        Command::Report(Report::Separation(args)) => {
            offline::separation_report::run_cli(&args, json)
        }
        Command::Board(Board::Plan(args)) => offline::board_plan::run(&args, json),
        Command::Online(cmd) => return online::run(cmd, cli.bus),
        // Both generators write to memory first: clap_complete panics on a
        // failed write, and stdout.rs says what a failed stdout means.
        Command::Completions { shell } => {
            let mut text = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "sdictl", &mut text);
            stdout::write_all(&text).map_err(exit::CliError::from)
        }
        Command::Man => {
            let mut text = Vec::new();
            clap_mangen::Man::new(Cli::command())
                .render(&mut text)
                .map_err(|e| exit::CliError::Runtime(e.to_string()))
                .and_then(|()| stdout::write_all(&text).map_err(exit::CliError::from))
        }
    };
    // Under --json every refusal is also the JSON error object on stdout.
    exit::report(result, json)
}
