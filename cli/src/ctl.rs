//! `taut ctl`: talk to a running `taut start` over its control socket.

use anyhow::{anyhow, bail, Result};
use serde_json::Value;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use taut_operator::control::{request, status_text};
use taut_operator::operator::{GoalView, MoveWait};

/// Arguments of `taut ctl`.
#[derive(clap::Args)]
#[command(after_help = "The simulated robot of `taut start --sim` listens on taut-sim-data/taut.sock in the directory it was \
                        started from: `taut ctl --socket taut-sim-data/taut.sock status`.")]
pub struct CtlArgs {
    /// Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the
    /// robot's), else, when that does not exist, the simulated robot's taut-sim-data/taut.sock
    /// in the current directory.
    #[arg(long, global = true)]
    socket: Option<PathBuf>,
    /// Robot configuration to take the socket path from (`daemon.socket`).
    #[arg(long, global = true)]
    config: Option<PathBuf>,
    /// Print the daemon's JSON replies instead of the summaries for people.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    request: Request,
}

/// What to ask the daemon.
#[derive(clap::Subcommand)]
enum Request {
    /// State, goal, calibration (parameter version, worst 1-sigma), drives, load cells, tracker,
    /// faults, loop health.
    Status,
    /// Follow what happens (states, phases, faults, parameter swaps, calibration outcomes,
    /// goals, resets, loop health), one line per event, until the daemon stops or Ctrl-C.
    Watch {
        /// Start from this event number (default: the next one; 1: everything still kept).
        #[arg(long)]
        from: Option<u64>,
    },
    /// Move the platform to X Y Z (m) in a straight line at `motion.move_speed_m_s`.
    #[command(allow_negative_numbers = true)]
    Move {
        /// X, m.
        x: f64,
        /// Y, m.
        y: f64,
        /// Z, m.
        z: f64,
        /// Wait until the platform arrives (tracker within --tolerance of the goal), or the
        /// move is refused, interrupted or stopped by a fault; print the final error. Exit
        /// status 1 unless it arrived.
        #[arg(long)]
        wait: bool,
        /// Arrival tolerance for --wait, mm.
        #[arg(long, default_value_t = 5.0, value_name = "MM")]
        tolerance: f64,
        /// Give up waiting after this many seconds.
        #[arg(long, default_value_t = 120.0, value_name = "S")]
        timeout: f64,
    },
    /// Run the excitation again, recalibrate, hot-swap if better; the platform is brought back
    /// to where it was (status and log say where it stopped if it could not be).
    Recalibrate {
        /// Wait for the calibration's outcome and the platform's return; exit status 1 if it did
        /// not get back.
        #[arg(long)]
        wait: bool,
        /// Give up waiting after this many seconds.
        #[arg(long, default_value_t = 600.0, value_name = "S")]
        timeout: f64,
    },
    /// Controlled stop: hold, disable the drives, end the daemon.
    Stop,
    /// Emergency stop: quick stop, latched until `reset`.
    Estop,
    /// Clear a latched safety reaction and re-enable the drives holding where they stand; waits
    /// for the outcome.
    Reset,
    /// The parameters in force: anchors, encoder offsets, their 1-sigma.
    Params,
    /// One calibration outcome in full (estimate, sigmas, every data problem); `status` lists the
    /// newest with their numbers.
    Outcome {
        /// The outcome's number (1 is the first).
        #[arg(value_parser = clap::value_parser!(u64).range(1..))]
        n: u64,
    },
}

/// Where `taut start --sim` puts its socket when nothing else is configured.
const SIM_SOCKET: &str = "taut-sim-data/taut.sock";

fn socket_of(a: &CtlArgs, verbosity: i8) -> Result<PathBuf> {
    Ok(match (&a.socket, &a.config) {
        (Some(s), _) => s.clone(),
        (None, Some(c)) => PathBuf::from(taut_config::RobotConfig::load(c).map_err(|e| anyhow!("{e}"))?.daemon.socket),
        (None, None) => {
            let robot = PathBuf::from(taut_config::runtime::DaemonConfig::default().socket);
            // No robot's daemon here, but the simulated robot started from this directory: use
            // its socket, and say so.
            if !robot.exists() && Path::new(SIM_SOCKET).exists() {
                if verbosity >= 0 {
                    eprintln!("taut ctl: no {}; using the simulated robot's {SIM_SOCKET} (give --socket to choose)", robot.display());
                }
                PathBuf::from(SIM_SOCKET)
            } else {
                robot
            }
        }
    })
}

/// One request; the reply, or an error that says whether anything serves the socket.
fn ask(socket: &Path, req: &str) -> Result<Value> {
    request(socket, req, Duration::from_secs(5)).map_err(|e| {
        use std::io::ErrorKind::{ConnectionRefused, NotFound};
        match e.kind() {
            // Nothing serves the socket: the daemon is not running, or this is not its socket.
            NotFound | ConnectionRefused => anyhow!(
                "{}: {e} (is `taut start` running? give --socket or --config; the simulated robot's is taut-sim-data/taut.sock)",
                socket.display()
            ),
            // It is running: say what went wrong without suggesting otherwise.
            _ => anyhow!("{}: {e}", socket.display()),
        }
    })
}

/// The reply, refused requests as errors.
fn ask_ok(socket: &Path, req: &str) -> Result<Value> {
    let reply = ask(socket, req)?;
    if reply.get("ok").and_then(Value::as_bool) != Some(true) {
        bail!("{}", reply.get("error").and_then(|v| v.as_str()).unwrap_or("request refused"));
    }
    Ok(reply)
}

fn print_json(v: &Value) -> Result<()> {
    println!("{}", serde_json::to_string_pretty(v)?);
    Ok(())
}

/// Runs `taut ctl`.
pub fn run(a: &CtlArgs, verbosity: i8) -> Result<()> {
    let socket = socket_of(a, verbosity)?;
    let s = socket.as_path();
    match &a.request {
        Request::Status => {
            let v = ask_ok(s, "status")?;
            if a.json {
                print_json(&v)
            } else {
                print!("{}", status_text(&v));
                Ok(())
            }
        }
        Request::Watch { from } => watch(s, *from, a.json),
        Request::Move { x, y, z, wait, tolerance, timeout } => {
            if !(tolerance.is_finite() && *tolerance > 0.0) {
                bail!("--tolerance {tolerance}: give a positive distance in mm");
            }
            if !(timeout.is_finite() && *timeout > 0.0) {
                bail!("--timeout {timeout}: give a positive number of seconds");
            }
            let v = ask_ok(s, &format!("move {x} {y} {z}"))?;
            let goal = v["goal"].as_u64().ok_or_else(|| anyhow!("the daemon's reply names no goal: {v}"))?;
            if a.json && !wait {
                return print_json(&v);
            }
            if verbosity >= 0 {
                println!("goal #{goal}: moving to ({x:.3}, {y:.3}, {z:.3}) m");
            }
            if *wait {
                wait_for_goal(s, goal, tolerance * 1e-3, Duration::from_secs_f64(*timeout), a.json)
            } else {
                Ok(())
            }
        }
        Request::Recalibrate { wait, timeout } => {
            if !(timeout.is_finite() && *timeout > 0.0) {
                bail!("--timeout {timeout}: give a positive number of seconds");
            }
            let before = ask_ok(s, "status")?["calibration"]["outcomes_total"].as_u64().unwrap_or(0);
            let v = ask_ok(s, "recalibrate")?;
            if a.json && !wait {
                return print_json(&v);
            }
            println!("recalibrate: {}", v["message"].as_str().unwrap_or("accepted"));
            if !wait {
                println!("follow it with `taut ctl watch`; the outcome and the return are in `taut ctl status`");
                return Ok(());
            }
            wait_for_recalibration(s, before, Duration::from_secs_f64(*timeout))
        }
        Request::Stop | Request::Estop | Request::Params => {
            let req = match &a.request {
                Request::Stop => "stop",
                Request::Estop => "estop",
                _ => "params",
            };
            let v = ask_ok(s, req)?;
            if a.json {
                return print_json(&v);
            }
            if req == "params" {
                print!("{}", taut_operator::control::params_text(&v));
                return Ok(());
            }
            println!("{req}: accepted");
            Ok(())
        }
        Request::Outcome { n } => {
            let v = ask_ok(s, &format!("outcome {n}"))?;
            print_json(&v)
        }
        Request::Reset => {
            let v = ask_ok(s, "reset")?;
            if a.json {
                print_json(&v)?;
            }
            wait_for_reset(s)
        }
    }
}

/// `watch`: asks for the journal every 200 ms (the daemon keeps the last 512
/// events), prints each event once, in order; says when events were lost.
fn watch(socket: &Path, from: Option<u64>, json: bool) -> Result<()> {
    let st = ask_ok(socket, "status")?;
    let mut next = from.unwrap_or_else(|| st["events_next"].as_u64().unwrap_or(1));
    if !json {
        println!("{}", status_text(&st).lines().next().unwrap_or_default());
    }
    loop {
        let v = match request(socket, &format!("events {next}"), Duration::from_secs(5)) {
            Ok(v) => v,
            Err(e) => {
                // A daemon that shuts down while it answers resets the connection or breaks the
                // pipe: that is its stop too, not the watcher's error.
                use std::io::ErrorKind::{BrokenPipe, ConnectionRefused, ConnectionReset, NotFound, UnexpectedEof};
                if matches!(e.kind(), NotFound | ConnectionRefused | UnexpectedEof | ConnectionReset | BrokenPipe) {
                    println!("-- the daemon has stopped ({e})");
                    return Ok(());
                }
                bail!("{}: {e}", socket.display());
            }
        };
        if v["ok"] != true {
            bail!("{}", v["error"].as_str().unwrap_or("events refused"));
        }
        if let Some(lost) = v["lost"].as_u64().filter(|l| *l > 0) {
            println!("-- {lost} events were no longer kept");
        }
        let mut out = std::io::stdout().lock();
        for e in v["events"].as_array().into_iter().flatten() {
            let written = if json {
                writeln!(out, "{e}")
            } else {
                writeln!(out, "[{:>9.3} s] {}", e["t_s"].as_f64().unwrap_or(0.0), e["text"].as_str().unwrap_or(""))
            };
            // The reader went away (`taut ctl watch | head`): that is the end, not an error.
            if written.and_then(|()| out.flush()).is_err() {
                return Ok(());
            }
        }
        drop(out);
        let more = v["events"].as_array().is_some_and(|a| a.len() == taut_operator::operator::EVENTS_PER_REPLY);
        next = v["next"].as_u64().unwrap_or(next);
        if !more {
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

/// `move --wait`: follows the goal in `status` until it ends; exit status 1 unless it arrived.
fn wait_for_goal(socket: &Path, goal: u64, tolerance_m: f64, timeout: Duration, json: bool) -> Result<()> {
    let t0 = Instant::now();
    let mut w = MoveWait::new(goal, tolerance_m);
    loop {
        let st = ask_ok(socket, "status")?;
        if let Some(end) = w.observe(&GoalView::from_status(&st)) {
            if json {
                print_json(&serde_json::json!({"goal": goal, "outcome": end.name(), "error_m": end.error_m(), "message": end.describe()}))?;
            } else {
                println!("goal #{goal}: {}", end.describe());
            }
            if end.arrived() {
                return Ok(());
            }
            bail!("goal #{goal} did not arrive: {}", end.describe());
        }
        if t0.elapsed() > timeout {
            let g = &st["goal"];
            bail!(
                "goal #{goal}: still under way after {:.0} s ({:.1} mm to go); see `taut ctl status`",
                timeout.as_secs_f64(),
                g["remaining_m"].as_f64().unwrap_or(f64::NAN) * 1e3
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// `recalibrate --wait`: until the recalibration's outcome is in and the platform is back (or
/// stopped elsewhere, or a fault).
fn wait_for_recalibration(socket: &Path, outcomes_before: u64, timeout: Duration) -> Result<()> {
    let t0 = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(200));
        let st = ask_ok(socket, "status")?;
        let r = &st["recalibrate"];
        let c = &st["calibration"];
        let outcome_in = c["outcomes_total"].as_u64().unwrap_or(0) > outcomes_before;
        let stage = r["stage"].as_str().unwrap_or("");
        if let Some(m) = st["fault"]["message"].as_str() {
            bail!("recalibration stopped by a safety reaction: {m}; see `taut ctl status`");
        }
        if stage == "stopped" || (outcome_in && stage == "returned") {
            if let Some(o) = c["outcomes"].as_array().and_then(|a| a.last()).filter(|_| outcome_in) {
                let verdict = if o["accepted"] == true {
                    format!(
                        "accepted as parameters v{} (worst 1-sigma {:.2} mm)",
                        o["version"],
                        o["worst_sigma_m"].as_f64().unwrap_or(f64::NAN) * 1e3
                    )
                } else {
                    format!("rejected: {}", o["reason"].as_str().unwrap_or(""))
                };
                println!("outcome #{}: {verdict}", o["n"]);
            }
            let text = status_text(&st);
            if let Some(l) = text.lines().find(|l| l.starts_with("recalibrate")) {
                println!("{l}");
            }
            if stage == "stopped" {
                bail!("the platform did not return: {}", r["why"].as_str().unwrap_or("see `taut ctl status`"));
            }
            return Ok(());
        }
        if t0.elapsed() > timeout {
            bail!("the recalibration has not finished after {:.0} s (stage {stage:?}); see `taut ctl status`", timeout.as_secs_f64());
        }
    }
}

/// A reset runs in the loop (fault reset, re-enable): waits for its outcome and says it, with
/// the reason when it was refused (exit status 1).
fn wait_for_reset(socket: &Path) -> Result<()> {
    let t0 = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(100));
        let st = ask(socket, "status")?;
        // The loop takes the request within a cycle; from then on the state is "resetting"
        // until the reset is done or refused.
        if st["state"] == "resetting" {
            if t0.elapsed() > Duration::from_secs(60) {
                bail!("the reset has not finished after 60 s; see `taut ctl status`");
            }
            continue;
        }
        let last = &st["reset"]["last"];
        match last["outcome"].as_str() {
            Some("done") => {
                println!(
                    "reset: done, holding (largest per-cycle step {:.3} mm)",
                    st["reset"]["reenable_step_m"].as_f64().unwrap_or(0.0) * 1e3
                );
                return Ok(());
            }
            Some("refused") => bail!("reset refused: {}", last["message"].as_str().unwrap_or("see `taut ctl status`")),
            _ => bail!("no reset outcome reported; see `taut ctl status`"),
        }
    }
}
