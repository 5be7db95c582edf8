//! `taut ctl`: talk to a running `taut start` over its control socket.

use anyhow::{anyhow, bail, Result};
use std::path::PathBuf;
use std::time::Duration;

/// Arguments of `taut ctl`.
#[derive(clap::Args)]
pub struct CtlArgs {
    /// Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock.
    #[arg(long)]
    socket: Option<PathBuf>,
    /// Robot configuration to take the socket path from.
    #[arg(long)]
    config: Option<PathBuf>,
    /// status | recalibrate | stop | estop | reset | params | move X Y Z
    // Negative coordinates (`move -1 0 2`) are values, not options.
    #[arg(required = true, num_args = 1.., allow_negative_numbers = true)]
    request: Vec<String>,
}

/// Runs `taut ctl`.
pub fn run(a: &CtlArgs) -> Result<()> {
    let socket = match (&a.socket, &a.config) {
        (Some(s), _) => s.clone(),
        (None, Some(c)) => PathBuf::from(taut_config::RobotConfig::load(c).map_err(|e| anyhow!("{e}"))?.daemon.socket),
        (None, None) => PathBuf::from(taut_config::runtime::DaemonConfig::default().socket),
    };
    let req = a.request.join(" ");
    let reply = taut_rt_core::control::request(&socket, &req, Duration::from_secs(5)).map_err(|e| {
        use std::io::ErrorKind::{ConnectionRefused, NotFound};
        match e.kind() {
            // Nothing serves the socket: the daemon is not running, or this is not its socket.
            NotFound | ConnectionRefused => anyhow!("{}: {e} (is `taut start` running? give --socket or --config)", socket.display()),
            // It is running: say what went wrong without suggesting otherwise.
            _ => anyhow!("{}: {e}", socket.display()),
        }
    })?;
    println!("{}", serde_json::to_string_pretty(&reply)?);
    if reply.get("ok").and_then(|v| v.as_bool()) != Some(true) {
        bail!("{}", reply.get("error").and_then(|v| v.as_str()).unwrap_or("request refused"));
    }
    if req == "reset" {
        return wait_for_reset(&socket);
    }
    Ok(())
}

/// A reset runs in the loop (fault reset, re-enable): waits for its outcome and says it, with
/// the reason when it was refused (exit status 1).
fn wait_for_reset(socket: &std::path::Path) -> Result<()> {
    let t0 = std::time::Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(100));
        let st =
            taut_rt_core::control::request(socket, "status", Duration::from_secs(5)).map_err(|e| anyhow!("{}: {e}", socket.display()))?;
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
