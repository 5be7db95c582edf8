//! Live telemetry: the channels of the MCAP recording ([`taut_config::mcap`]) served over the
//! Foxglove WebSocket protocol (`foxglove.websocket.v1`), so Foxglove's "Open connection" shows a
//! running start-up live.
//!
//! One thread, sync `tungstenite` on non-blocking sockets, fed by the calibrator thread through
//! a bounded queue ([`crate::channels::FrameSinks`]): neither the loop nor the calibrator waits
//! on a client. A client with more than [`MAX_CLIENT_BACKLOG`] bytes queued is disconnected.
//!
//! Protocol (server side, <https://github.com/foxglove/ws-protocol>):
//! ```text
//! handshake: Sec-WebSocket-Protocol: foxglove.websocket.v1 (refused without it)
//! -> {"op":"serverInfo","name":"taut",...}            text, once
//! -> {"op":"advertise","channels":[{id,topic,encoding:"json",schemaName,schema,schemaEncoding:"jsonschema"}]}
//! <- {"op":"subscribe","subscriptions":[{"id":S,"channelId":C}]}
//! <- {"op":"unsubscribe","subscriptionIds":[S]}
//! -> binary: 0x01 | subscription id u32 LE | log time ns u64 LE | JSON payload
//! ```

use crate::channels::Frame;
use std::collections::BTreeMap;
use std::io::ErrorKind;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use taut_config::mcap::{Topic, CHANNELS};
use tungstenite::handshake::server::{ErrorResponse, Request, Response};
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message, WebSocket};

/// The WebSocket subprotocol of the Foxglove protocol.
pub const SUBPROTOCOL: &str = "foxglove.websocket.v1";

/// Bytes queued for one client before it is dropped as too slow.
pub const MAX_CLIENT_BACKLOG: usize = 8 << 20;

/// Frames queued between the calibrator and the server.
pub const QUEUE_FRAMES: usize = 8192;

/// Longest a new connection may take for its handshake.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(2);

/// Counters, readable from other threads.
#[derive(Debug, Default)]
pub struct TelemetryStats {
    /// Clients connected now.
    pub clients: AtomicU64,
    /// Connections accepted since start.
    pub accepted: AtomicU64,
    /// Connections refused (handshake failed, too many clients).
    pub refused: AtomicU64,
    /// Messages sent to clients.
    pub sent: AtomicU64,
    /// Clients dropped because they did not keep up.
    pub slow_dropped: AtomicU64,
}

/// A bound server, not yet running.
pub struct TelemetryServer {
    listener: TcpListener,
    rx: crossbeam_channel::Receiver<Frame>,
    max_clients: usize,
    /// Counters.
    pub stats: Arc<TelemetryStats>,
    /// The address it listens on (with the port the system chose for port 0).
    pub addr: SocketAddr,
}

struct Client {
    ws: WebSocket<TcpStream>,
    /// channel id -> subscription ids.
    subs: BTreeMap<u16, Vec<u32>>,
    gone: bool,
}

fn channel_id(t: Topic) -> u16 {
    t as u16 + 1
}

/// Binds `addr`; returns the server and the sender its frames come through.
pub fn bind(addr: SocketAddr, max_clients: usize) -> std::io::Result<(TelemetryServer, crossbeam_channel::Sender<Frame>)> {
    let listener = TcpListener::bind(addr)?;
    listener.set_nonblocking(true)?;
    let addr = listener.local_addr()?;
    let (tx, rx) = crossbeam_channel::bounded(QUEUE_FRAMES);
    Ok((TelemetryServer { listener, rx, max_clients, stats: Arc::default(), addr }, tx))
}

fn server_info() -> String {
    serde_json::json!({"op": "serverInfo", "name": "taut", "capabilities": [], "supportedEncodings": ["json"],
        "metadata": {"robot_software": "taut"}, "sessionId": format!("{}", std::process::id())})
    .to_string()
}

fn advertise() -> String {
    let channels: Vec<_> = Topic::ALL
        .iter()
        .map(|&t| {
            let d = &CHANNELS[t as usize];
            serde_json::json!({"id": channel_id(t), "topic": d.topic, "encoding": "json", "schemaName": d.schema_name,
                "schema": d.schema, "schemaEncoding": "jsonschema"})
        })
        .collect();
    serde_json::json!({"op": "advertise", "channels": channels}).to_string()
}

/// True for the errors that only mean "not now" on a non-blocking socket.
fn would_block(e: &tungstenite::Error) -> bool {
    matches!(e, tungstenite::Error::Io(io) if io.kind() == ErrorKind::WouldBlock)
}

impl TelemetryServer {
    /// Serves until `quit` is set.
    pub fn run(self, quit: Arc<AtomicBool>) {
        let mut clients: Vec<Client> = Vec::new();
        // The newest frame of each channel sent on change (drives, phase, faults, params,
        // calibrator): a client that subscribes later gets it at once, as a latched topic.
        let mut latched: BTreeMap<u16, Frame> = BTreeMap::new();
        let cfg = WebSocketConfig::default().write_buffer_size(0).max_write_buffer_size(MAX_CLIENT_BACKLOG).max_message_size(Some(1 << 20));
        // Acquire: pairs with the daemon's Release store; only ends the loop.
        while !quit.load(Ordering::Acquire) {
            self.accept(&mut clients, cfg);
            for c in clients.iter_mut() {
                for (sub, ch) in self.read_client(c) {
                    if let Some(f) = latched.get(&ch) {
                        self.send(c, sub, f);
                    }
                }
            }
            clients.retain(|c| !c.gone);
            match self.rx.recv_timeout(Duration::from_millis(20)) {
                Ok(f) => {
                    for f in std::iter::once(f).chain(self.rx.try_iter().take(4096)) {
                        self.fan_out(&mut clients, &f);
                        if matches!(f.topic, Topic::Drives | Topic::Phase | Topic::Faults | Topic::Params | Topic::Calibrator) {
                            latched.insert(channel_id(f.topic), f);
                        }
                    }
                }
                Err(crossbeam_channel::RecvTimeoutError::Timeout) => {}
                Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
            }
            clients.retain_mut(|c| match c.ws.flush() {
                Ok(()) => true,
                Err(e) if would_block(&e) => true,
                Err(_) => false,
            });
            // Relaxed: a statistic.
            self.stats.clients.store(clients.len() as u64, Ordering::Relaxed);
        }
        for mut c in clients {
            let _ = c.ws.close(None);
            let _ = c.ws.flush();
        }
        self.stats.clients.store(0, Ordering::Relaxed);
    }

    fn accept(&self, clients: &mut Vec<Client>, cfg: WebSocketConfig) {
        while let Ok((stream, _)) = self.listener.accept() {
            // Relaxed: statistics.
            if clients.len() >= self.max_clients {
                self.stats.refused.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            match handshake(stream, cfg) {
                Ok(mut ws) => {
                    // A send that would block stays queued in the socket's buffer: go on.
                    let mut ok = ws.send(Message::text(server_info()));
                    if ok.as_ref().map_or_else(would_block, |_| true) {
                        ok = ws.send(Message::text(advertise()));
                    }
                    match ok {
                        Ok(()) => {}
                        Err(e) if would_block(&e) => {}
                        Err(_) => {
                            self.stats.refused.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                    }
                    self.stats.accepted.fetch_add(1, Ordering::Relaxed);
                    clients.push(Client { ws, subs: BTreeMap::new(), gone: false });
                }
                Err(_) => {
                    self.stats.refused.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }

    /// Reads what the client sent (marks it gone when it left); returns the new subscriptions
    /// as (subscription id, channel id).
    fn read_client(&self, c: &mut Client) -> Vec<(u32, u16)> {
        let mut new = Vec::new();
        while !c.gone {
            match c.ws.read() {
                Ok(Message::Text(t)) => new.extend(on_request(c, t.as_str())),
                Ok(Message::Close(_)) => c.gone = true,
                Ok(_) => {}
                Err(e) if would_block(&e) => break,
                Err(_) => c.gone = true,
            }
        }
        if c.gone {
            new.clear();
        }
        new
    }

    fn fan_out(&self, clients: &mut [Client], f: &Frame) {
        let ch = channel_id(f.topic);
        for c in clients.iter_mut() {
            let Some(subs) = c.subs.get(&ch) else { continue };
            for sub in subs.clone() {
                if !self.send(c, sub, f) {
                    break;
                }
            }
        }
    }

    /// One messageData frame to one subscription; false when the client can take no more.
    fn send(&self, c: &mut Client, sub: u32, f: &Frame) -> bool {
        let mut b = Vec::with_capacity(13 + f.data.len());
        b.push(0x01);
        b.extend_from_slice(&sub.to_le_bytes());
        b.extend_from_slice(&f.log_time_ns.to_le_bytes());
        b.extend_from_slice(&f.data);
        match c.ws.write(Message::binary(b)) {
            // Relaxed: statistics. A write that would block is queued in the socket's buffer.
            Ok(()) => {
                self.stats.sent.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(e) if would_block(&e) => {
                self.stats.sent.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(e) => {
                if matches!(e, tungstenite::Error::WriteBufferFull(_)) {
                    // Too slow: dropped rather than ever waited on.
                    self.stats.slow_dropped.fetch_add(1, Ordering::Relaxed);
                }
                c.subs.clear();
                c.gone = true;
                false
            }
        }
    }
}

// tungstenite's error and its handshake callback's error response are large by its design; they
// live on the telemetry thread only, once per connection.
#[allow(clippy::result_large_err)]
fn handshake(stream: TcpStream, cfg: WebSocketConfig) -> Result<WebSocket<TcpStream>, HandshakeError> {
    stream.set_nonblocking(false).map_err(HandshakeError::Socket)?;
    stream.set_read_timeout(Some(HANDSHAKE_TIMEOUT)).map_err(HandshakeError::Socket)?;
    stream.set_write_timeout(Some(HANDSHAKE_TIMEOUT)).map_err(HandshakeError::Socket)?;
    let _ = stream.set_nodelay(true);
    let callback = |req: &Request, mut resp: Response| -> Result<Response, ErrorResponse> {
        let offered = req
            .headers()
            .get_all("Sec-WebSocket-Protocol")
            .iter()
            .filter_map(|v| v.to_str().ok())
            .any(|v| v.split(',').any(|p| p.trim() == SUBPROTOCOL));
        if !offered {
            let mut e = ErrorResponse::new(Some(format!(
                "taut telemetry speaks the Foxglove WebSocket protocol: request subprotocol {SUBPROTOCOL}"
            )));
            *e.status_mut() = tungstenite::http::StatusCode::BAD_REQUEST;
            return Err(e);
        }
        resp.headers_mut().insert("Sec-WebSocket-Protocol", tungstenite::http::HeaderValue::from_static(SUBPROTOCOL));
        Ok(resp)
    };
    let ws = tungstenite::accept_hdr_with_config(stream, callback, Some(cfg)).map_err(|e| match e {
        tungstenite::HandshakeError::Failure(e) => HandshakeError::WebSocket(e),
        tungstenite::HandshakeError::Interrupted(_) => HandshakeError::Incomplete,
    })?;
    ws.get_ref().set_nonblocking(true).map_err(HandshakeError::Socket)?;
    Ok(ws)
}

/// Why a connection was refused during the handshake (counted in [`TelemetryStats`]).
#[derive(Debug)]
enum HandshakeError {
    /// The socket's mode or timeouts could not be set.
    Socket(std::io::Error),
    /// The WebSocket handshake failed: no Foxglove subprotocol (answered 400), a malformed
    /// request, a timeout.
    WebSocket(tungstenite::Error),
    /// The blocking handshake returned unfinished (the socket was not blocking).
    Incomplete,
}

impl std::fmt::Display for HandshakeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HandshakeError::Socket(e) => write!(f, "telemetry client socket: {e}"),
            HandshakeError::WebSocket(e) => write!(f, "telemetry WebSocket handshake: {e}"),
            HandshakeError::Incomplete => f.write_str("telemetry WebSocket handshake did not complete"),
        }
    }
}

impl std::error::Error for HandshakeError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            HandshakeError::Socket(e) => Some(e),
            HandshakeError::WebSocket(e) => Some(e),
            HandshakeError::Incomplete => None,
        }
    }
}

/// A subscribe or unsubscribe request; anything else (or malformed) is ignored, as the protocol
/// allows for unknown operations.
fn on_request(c: &mut Client, text: &str) -> Vec<(u32, u16)> {
    let mut new = Vec::new();
    let Ok(v) = serde_json::from_str::<serde_json::Value>(text) else { return new };
    match v.get("op").and_then(|o| o.as_str()) {
        Some("subscribe") => {
            for s in v.get("subscriptions").and_then(|s| s.as_array()).into_iter().flatten() {
                let (Some(id), Some(ch)) = (s.get("id").and_then(|x| x.as_u64()), s.get("channelId").and_then(|x| x.as_u64())) else {
                    continue;
                };
                let (Ok(id), Ok(ch)) = (u32::try_from(id), u16::try_from(ch)) else { continue };
                if (1..=Topic::ALL.len() as u16).contains(&ch) {
                    let subs = c.subs.entry(ch).or_default();
                    if !subs.contains(&id) && subs.len() < 16 {
                        subs.push(id);
                        new.push((id, ch));
                    }
                }
            }
        }
        Some("unsubscribe") => {
            for id in v.get("subscriptionIds").and_then(|s| s.as_array()).into_iter().flatten().filter_map(|x| x.as_u64()) {
                for subs in c.subs.values_mut() {
                    subs.retain(|&s| u64::from(s) != id);
                }
            }
        }
        _ => {}
    }
    new
}
