//! The control socket's server: one thread, one `poll(2)` loop over non-blocking sockets.
//!
//! # Why one polling thread
//!
//! A request costs microseconds, so one thread never falls behind on honest work; what it must
//! never do is wait on a client. With non-blocking sockets and the only sleep in `poll`, a slow
//! or flooding client costs one poll entry and one fixed buffer. A pool of N blocking workers
//! would be starved by N slow clients; a thread per client lets anyone create threads.
//!
//! # Rules, each with the bound it gives
//!
//! - At most [`ServerLimits::max_connections`] connections; accepting one more closes the one
//!   idle longest (oldest last activity), so a flood of idle clients cannot lock the operator
//!   out. Memory: the cap times one line buffer and one reply.
//! - A request line is at most [`ServerLimits::max_line`] bytes, read into a buffer allocated at
//!   accept; a longer line gets an error and the connection is closed.
//! - A request must arrive complete within [`ServerLimits::deadline`] of the connection's start
//!   or of the previous reply (several requests per connection are fine); otherwise an error
//!   and the connection is closed. A byte-per-second client is dropped at its deadline.
//! - Each round reads at most one buffer from and answers at most one request of each
//!   connection; `estop` and `stop` lines of every connection go first. The estop flag is one
//!   atomic store ([`Urgent`]), waiting on no queue, lock or loop.
//! - Replies are written without blocking. A connection does not get its next request answered
//!   until its last reply has gone out; a client that does not read is closed at its deadline.
//! - After EOF from the client (a half-closed socket) a pending partial line is answered as a
//!   request, then the connection is closed.
//!
//! Counters of all of this are in the `control` part of the `status` reply.

use crate::control::{parse_request, ControlLinks, Request, RequestError};
use serde_json::{json, Value};
use std::io::Read;
use std::os::fd::AsRawFd;
use std::os::unix::fs::PermissionsExt;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use taut_rt::urgent::Urgent;

/// Limits of the control server.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServerLimits {
    /// Longest request line, bytes (without the line end).
    pub max_line: usize,
    /// Time a client has to send a complete request (from connecting or from the last reply).
    pub deadline: Duration,
    /// Most connections at once; one more closes the one idle longest.
    pub max_connections: usize,
}

impl Default for ServerLimits {
    fn default() -> Self {
        // 256 connections of 4 KiB: at most ~1 MiB of request buffers, and well under the usual
        // 1024 open files (the daemon's own files and devices need a few dozen).
        ServerLimits { max_line: 4096, deadline: Duration::from_secs(2), max_connections: 256 }
    }
}

/// What the server has done so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServerStats {
    /// Connections accepted.
    pub accepted: u64,
    /// Connections open now.
    pub open: u64,
    /// Requests answered (valid or not).
    pub requests: u64,
    /// Estop and stop requests answered.
    pub urgent: u64,
    /// Requests refused as malformed (unknown verb, not text, bad numbers...).
    pub malformed: u64,
    /// Connections closed for a line over the limit.
    pub too_long: u64,
    /// Connections closed at their deadline.
    pub timed_out: u64,
    /// Idle connections closed to make room for a new one.
    pub evicted: u64,
}

impl ServerStats {
    fn json(&self, limits: &ServerLimits) -> Value {
        json!({
            "accepted": self.accepted, "open": self.open, "requests": self.requests, "urgent": self.urgent,
            "malformed": self.malformed, "too_long": self.too_long, "timed_out": self.timed_out, "evicted": self.evicted,
            "max_connections": limits.max_connections, "max_line": limits.max_line, "deadline_s": limits.deadline.as_secs_f64(),
        })
    }
}

struct Conn {
    stream: UnixStream,
    /// Bytes of the request being received; capacity `max_line + 1` (the line end), fixed.
    buf: Vec<u8>,
    /// Reply being sent, and how much of it has gone.
    out: Vec<u8>,
    out_pos: usize,
    deadline: Instant,
    last_active: Instant,
    /// The client shut its side (read returned 0).
    eof: bool,
    /// Close once `out` has gone.
    closing: bool,
    /// Close now (a write or read error).
    dead: bool,
}

impl Conn {
    fn pending_out(&self) -> bool {
        self.out_pos < self.out.len()
    }

    fn has_line(&self) -> bool {
        self.buf.contains(&b'\n')
    }

    fn wants_read(&self) -> bool {
        !self.eof && !self.closing && !self.dead && !self.pending_out() && self.buf.len() < self.buf.capacity() && !self.has_line()
    }

    /// One non-blocking read into the free part of the line buffer.
    fn read_some(&mut self) {
        let start = self.buf.len();
        let cap = self.buf.capacity();
        // Within capacity: no allocation.
        self.buf.resize(cap, 0);
        match self.stream.read(&mut self.buf[start..]) {
            Ok(0) => {
                self.buf.truncate(start);
                self.eof = true;
            }
            Ok(n) => self.buf.truncate(start + n),
            Err(e) => {
                self.buf.truncate(start);
                if !matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) {
                    self.dead = true;
                }
            }
        }
    }

    fn queue(&mut self, v: &Value) {
        self.out.clear();
        self.out_pos = 0;
        // Serialising a Value into a Vec cannot fail.
        let _ = serde_json::to_writer(&mut self.out, v);
        self.out.push(b'\n');
    }

    /// Writes as much of the reply as the socket takes now. MSG_NOSIGNAL: a client that went
    /// away is an EPIPE error here, never a SIGPIPE for the daemon.
    fn flush(&mut self, now: Instant, deadline: Duration) {
        while self.pending_out() && !self.dead {
            let rest = &self.out[self.out_pos..];
            // SAFETY: a valid buffer of `rest.len()` bytes and an open socket for the call.
            let r = unsafe { libc::send(self.stream.as_raw_fd(), rest.as_ptr().cast(), rest.len(), libc::MSG_NOSIGNAL) };
            if r >= 0 {
                self.out_pos += r as usize;
            } else {
                let e = std::io::Error::last_os_error();
                match e.kind() {
                    std::io::ErrorKind::WouldBlock => return,
                    std::io::ErrorKind::Interrupted => {}
                    _ => self.dead = true,
                }
            }
        }
        if !self.pending_out() && !self.out.is_empty() {
            // Reply gone: the client has a new deadline for its next request.
            self.out.clear();
            self.out_pos = 0;
            self.deadline = now + deadline;
            self.last_active = now;
        }
    }
}

/// The control server; runs on its own thread ([`run`](Self::run)).
pub struct ControlServer {
    listener: UnixListener,
    path: PathBuf,
    links: ControlLinks,
    limits: ServerLimits,
    stats: ServerStats,
}

impl ControlServer {
    /// Binds the socket at `path` (replacing a stale one) with mode 0660. A socket someone
    /// answers on means another daemon: refused, nothing touched.
    pub fn bind(path: &Path, links: ControlLinks, limits: ServerLimits) -> std::io::Result<ControlServer> {
        if let Some(d) = path.parent() {
            std::fs::create_dir_all(d)?;
        }
        if path.exists() {
            // A socket nobody answers on is left over from a crash; a live one means a second daemon.
            if UnixStream::connect(path).is_ok() {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::AddrInUse,
                    format!("{} is in use: is taut start already running?", path.display()),
                ));
            }
            std::fs::remove_file(path)?;
        }
        let listener = UnixListener::bind(path)?;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))?;
        listener.set_nonblocking(true)?;
        Ok(ControlServer { listener, path: path.to_path_buf(), links, limits, stats: ServerStats::default() })
    }

    /// The estop/stop flags the server sets.
    pub fn urgent(&self) -> Arc<Urgent> {
        self.links.urgent.clone()
    }

    /// Serves until `quit`; removes the socket file at the end.
    pub fn run(mut self, quit: Arc<AtomicBool>) {
        let mut conns: Vec<Conn> = Vec::with_capacity(self.limits.max_connections);
        let mut fds: Vec<libc::pollfd> = Vec::with_capacity(self.limits.max_connections + 1);
        let mut ready: Vec<(usize, Result<Request, RequestError>)> = Vec::with_capacity(self.limits.max_connections);
        let mut accept_paused_until: Option<Instant> = None;
        // Relaxed: only ends the serving; no data is handed over with it.
        while !quit.load(Ordering::Relaxed) {
            let now = Instant::now();
            let listen = accept_paused_until.is_none_or(|t| now >= t);
            fds.clear();
            fds.push(libc::pollfd { fd: self.listener.as_raw_fd(), events: if listen { libc::POLLIN } else { 0 }, revents: 0 });
            let mut work_now = false;
            let mut next = now + Duration::from_millis(50);
            for c in &conns {
                let mut ev = 0;
                if c.wants_read() {
                    ev |= libc::POLLIN;
                }
                if c.pending_out() {
                    ev |= libc::POLLOUT;
                }
                fds.push(libc::pollfd { fd: c.stream.as_raw_fd(), events: ev, revents: 0 });
                // A buffered line (pipelined requests) or a half-closed client is work for now.
                work_now |= !c.pending_out() && (c.has_line() || c.eof || c.closing || c.dead || c.buf.len() == c.buf.capacity());
                next = next.min(c.deadline);
            }
            if let Some(t) = accept_paused_until {
                next = next.min(t);
            }
            let timeout_ms = if work_now { 0 } else { next.saturating_duration_since(now).as_millis().min(50) as i32 + 1 };
            // SAFETY: `fds` is a valid array of `fds.len()` pollfds for the duration of the call.
            let r = unsafe { libc::poll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, timeout_ms) };
            if r < 0 {
                // EINTR (or nothing to wait on): go round again.
                continue;
            }
            let now = Instant::now();
            for (c, fd) in conns.iter_mut().zip(&fds[1..]) {
                let re = fd.revents;
                if re & libc::POLLOUT != 0 {
                    c.flush(now, self.limits.deadline);
                }
                if re & (libc::POLLIN | libc::POLLHUP | libc::POLLERR) != 0 && c.wants_read() {
                    c.read_some();
                }
                if re & libc::POLLNVAL != 0 {
                    c.dead = true;
                }
            }
            if fds[0].revents & libc::POLLIN != 0 {
                accept_paused_until = self.accept(&mut conns, now);
            }
            // Counted before answering, so a status reply includes its own connection.
            self.stats.open = conns.len() as u64;

            // At most one request per connection this round.
            ready.clear();
            for (i, c) in conns.iter_mut().enumerate() {
                if c.pending_out() || c.closing || c.dead {
                    continue;
                }
                if let Some(k) = c.buf.iter().position(|&b| b == b'\n') {
                    let line = c.buf[..k].strip_suffix(b"\r").unwrap_or(&c.buf[..k]);
                    ready.push((i, parse_request(line)));
                    c.buf.drain(..=k);
                    c.last_active = now;
                } else if c.buf.len() == c.buf.capacity() {
                    self.stats.too_long += 1;
                    c.queue(&json!({"ok": false, "error": format!("request line longer than {} bytes; closing the connection", self.limits.max_line)}));
                    c.closing = true;
                } else if c.eof {
                    if c.buf.is_empty() {
                        c.closing = true;
                    } else {
                        // Half-closed after a line without its line end: that is the request.
                        let line = std::mem::take(&mut c.buf);
                        ready.push((i, parse_request(&line)));
                        c.buf = line;
                        c.buf.clear();
                        c.closing = true;
                    }
                }
            }
            // Estop and stop first, from every connection, then the rest in order.
            for pass in [true, false] {
                for (i, req) in &ready {
                    let urgent = matches!(req, Ok(r) if r.is_urgent());
                    if urgent != pass {
                        continue;
                    }
                    let reply = self.answer(req);
                    let c = &mut conns[*i];
                    c.queue(&reply);
                    c.flush(now, self.limits.deadline);
                }
            }

            // Deadlines: a request not complete in time, or a reply the client does not read.
            for c in conns.iter_mut() {
                if now >= c.deadline && !c.dead {
                    self.stats.timed_out += 1;
                    if !c.pending_out() {
                        let d = self.limits.deadline.as_secs_f64();
                        c.queue(&json!({"ok": false, "error": format!("no complete request line within {d} s; closing the connection")}));
                        c.flush(now, self.limits.deadline);
                    }
                    c.dead = true;
                }
            }
            conns.retain(|c| !(c.dead || (c.closing && !c.pending_out())));
            self.stats.open = conns.len() as u64;
            // The operator's bookkeeping: events, goals, the return after a recalibration, the
            // log lines (microseconds; at least every 50 ms).
            self.links.tick();
        }
        drop(conns);
        let _ = std::fs::remove_file(&self.path);
    }

    fn answer(&mut self, req: &Result<Request, RequestError>) -> Value {
        self.stats.requests += 1;
        match req {
            Ok(r) => {
                if r.is_urgent() {
                    self.stats.urgent += 1;
                }
                let mut v = self.links.handle(*r);
                if *r == Request::Status {
                    v["control"] = self.stats.json(&self.limits);
                }
                v
            }
            Err(e) => {
                self.stats.malformed += 1;
                json!({"ok": false, "error": e.to_string()})
            }
        }
    }

    /// Accepts what is waiting (at most a round's worth); returns a time to pause accepting
    /// until when out of file descriptors.
    fn accept(&mut self, conns: &mut Vec<Conn>, now: Instant) -> Option<Instant> {
        for _ in 0..64 {
            match self.listener.accept() {
                Ok((stream, _)) => {
                    if stream.set_nonblocking(true).is_err() {
                        continue;
                    }
                    if conns.len() >= self.limits.max_connections {
                        self.evict_one(conns, now);
                    }
                    self.stats.accepted += 1;
                    let mut c = Conn {
                        stream,
                        buf: Vec::with_capacity(self.limits.max_line + 1),
                        out: Vec::new(),
                        out_pos: 0,
                        deadline: now + self.limits.deadline,
                        last_active: now,
                        eof: false,
                        closing: false,
                        dead: false,
                    };
                    // A client usually sends its line right after connecting: take it this round.
                    c.read_some();
                    conns.push(c);
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return None,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    // EMFILE/ENFILE and the like: free a slot and pause accepting briefly, rather
                    // than spin on a listener that stays readable.
                    if matches!(e.raw_os_error(), Some(libc::EMFILE) | Some(libc::ENFILE)) {
                        self.evict_one(conns, now);
                    }
                    return Some(now + Duration::from_millis(20));
                }
            }
        }
        None
    }

    /// Closes the connection idle longest (it is told why, if it listens).
    fn evict_one(&mut self, conns: &mut Vec<Conn>, now: Instant) {
        let Some((i, _)) = conns.iter().enumerate().min_by_key(|(_, c)| c.last_active) else {
            return;
        };
        let mut c = conns.swap_remove(i);
        self.stats.evicted += 1;
        if !c.pending_out() {
            let n = self.limits.max_connections;
            c.queue(&json!({"ok": false, "error": format!("too many connections (at most {n}); closing the one idle longest")}));
            c.flush(now, self.limits.deadline);
        }
    }
}

impl std::ops::Drop for ControlServer {
    fn drop(&mut self) {
        // Also when the daemon fails to start after binding: no socket file is left behind.
        let _ = std::fs::remove_file(&self.path);
    }
}
