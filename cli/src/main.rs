//! `taut`: robot-side software for suspended cable-driven parallel robots.
//!
//! A thin binary over the library crates: argument parsing, tables for people, JSON for programs.
//! `main` only maps errors to exit codes; each subcommand lives in its own module.

mod calibrate;
mod ctl;
#[cfg(feature = "sim")]
mod demo;
mod diagnose;
mod export;
mod figures;
mod generated;
mod heap;
mod html;
mod notracker;
mod outputs;
mod plot;
mod probe;
mod report;
#[cfg(feature = "sim")]
mod simulate;
mod start;

use clap::{CommandFactory, Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "taut", version, about = "Cable robot calibration and control", long_about = None)]
struct Cli {
    /// Say more (`taut start`: also every change of the calibrator's stage).
    #[arg(short, long, global = true, action = clap::ArgAction::Count, conflicts_with = "quiet")]
    verbose: u8,
    /// Say less (`taut start`: no log lines for people, only warnings and the results; `taut
    /// ctl`: no progress lines).
    #[arg(short, long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a robot, record its initialisation and excitation, calibrate it, print the results.
    #[cfg(feature = "sim")]
    Demo(demo::DemoArgs),
    /// Write a recording (cdpr-recording v1) of a simulated robot.
    #[cfg(feature = "sim")]
    Simulate(simulate::SimulateArgs),
    /// Calibrate anchors and encoder offsets from any recording (CSV or MCAP), real or simulated.
    Calibrate(calibrate::CalibrateArgs),
    /// Run the robot's controller: start-up calibration, hot-swap, operation (--sim: simulated robot).
    Start(start::StartArgs),
    /// Talk to a running `taut start`: status, watch, move, recalibrate, stop, estop, reset, params, outcome.
    Ctl(ctl::CtlArgs),
    /// Find the physics the ideal model leaves out: name it, model it, show the fit improve.
    Diagnose(diagnose::DiagnoseArgs),
    /// Find every CAN drive, configure its PDOs, print nodes, states, positions and the bus load.
    Probe(probe::ProbeArgs),
    /// Convert a recording (cdpr-recording v1) to MCAP for Foxglove, PlotJuggler and rosbag2.
    Export(export::ExportArgs),
    /// Print a shell completion script: taut completions bash > /etc/bash_completion.d/taut.
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
    /// Print the manual page (roff): taut man > taut.1; man ./taut.1. With --dir: write taut.1
    /// and one page per subcommand (taut-ctl.1, ...) there.
    Man {
        /// Write every page into this directory instead of taut.1 to stdout.
        #[arg(long)]
        dir: Option<std::path::PathBuf>,
    },
}

/// The `taut` command line as clap sees it (for completions, the man page and their tests).
pub fn command() -> clap::Command {
    Cli::command()
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let verbosity: i8 = if cli.quiet { -1 } else { cli.verbose.min(3) as i8 };
    let result = match cli.command {
        #[cfg(feature = "sim")]
        Command::Demo(a) => demo::run(&a),
        #[cfg(feature = "sim")]
        Command::Simulate(a) => simulate::run(&a),
        Command::Calibrate(a) => calibrate::run(&a),
        Command::Start(a) => start::run(&a, verbosity),
        Command::Ctl(a) => ctl::run(&a, verbosity),
        Command::Diagnose(a) => diagnose::run(&a),
        Command::Probe(a) => probe::run(&a),
        Command::Export(a) => export::run(&a),
        Command::Completions { shell } => {
            use std::io::Write;
            std::io::stdout().write_all(&generated::completions(shell)).map_err(Into::into)
        }
        Command::Man { dir: None } => clap_mangen::Man::new(command()).render(&mut std::io::stdout()).map_err(Into::into),
        Command::Man { dir: Some(d) } => generated::man_pages().and_then(|pages| {
            for (name, bytes) in pages {
                let p = d.join(name);
                taut_config::write_atomic(&p, &bytes).map_err(|e| anyhow::anyhow!("writing {}: {e}", p.display()))?;
            }
            Ok(())
        }),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
