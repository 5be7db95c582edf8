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
    Ok(())
}
