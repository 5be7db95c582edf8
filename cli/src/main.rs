//! `taut`: robot-side software for suspended cable-driven parallel robots.
//!
//! A thin binary over the library crates: argument parsing, tables for people, JSON for programs.
//! `main` only maps errors to exit codes; each subcommand lives in its own module.

mod calibrate;
mod ctl;
mod demo;
mod diagnose;
mod export;
mod figures;
mod heap;
mod html;
mod notracker;
mod outputs;
mod plot;
mod probe;
mod report;
mod simulate;
mod start;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "taut", version, about = "Cable robot calibration and control", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a robot, record its initialisation and excitation, calibrate it, print the results.
    Demo(demo::DemoArgs),
    /// Write a recording (cdpr-recording v1) of a simulated robot.
    Simulate(simulate::SimulateArgs),
    /// Calibrate anchors and encoder offsets from any recording, real or simulated.
    Calibrate(calibrate::CalibrateArgs),
    /// Run the robot's controller: start-up calibration, hot-swap, operation (--sim: simulated robot).
    Start(start::StartArgs),
    /// Talk to a running `taut start`: status | recalibrate | stop | estop | reset | params | move X Y Z.
    Ctl(ctl::CtlArgs),
    /// Find the physics the ideal model leaves out: name it, model it, show the fit improve.
    Diagnose(diagnose::DiagnoseArgs),
    /// Find every CAN drive, configure its PDOs, print nodes, states, positions and the bus load.
    Probe(probe::ProbeArgs),
    /// Convert a recording (cdpr-recording v1) to MCAP for Foxglove, PlotJuggler and rosbag2.
    Export(export::ExportArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo(a) => demo::run(&a),
        Command::Simulate(a) => simulate::run(&a),
        Command::Calibrate(a) => calibrate::run(&a),
        Command::Start(a) => start::run(&a),
        Command::Ctl(a) => ctl::run(&a),
        Command::Diagnose(a) => diagnose::run(&a),
        Command::Probe(a) => probe::run(&a),
        Command::Export(a) => export::run(&a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
