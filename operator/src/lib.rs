//! The operator's services: what people and tools use to watch and command a running robot.
//!
//! - [`control`] and [`ctl_server`]: the Unix control socket (`taut ctl`): requests, replies,
//!   the status and the emergency stop's urgent path.
//! - [`operator`]: the operator's side of the plugin's command and event queues.
//! - [`channels`]: samples, parameter sets and calibrator progress as MCAP / Foxglove channels.
//! - [`telemetry`]: the Foxglove WebSocket server for those channels.
//! - [`localtime`]: local time stamps for file names and status lines.
//!
//! Nothing here runs in the real-time thread: these run on the control, telemetry and
//! calibrator threads and talk to the loop through bounded queues and the urgent flag.
#![deny(missing_docs)]

pub mod channels;
pub mod control;
pub mod ctl_server;
pub mod localtime;
pub mod operator;
pub mod telemetry;
