//! Several virtual drives on one transport endpoint, stepped by the caller or on their own
//! thread in wall-clock time.

use super::{DriveParams, VirtualDrive};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use taut_proto::can::Filter;
use taut_proto::can::{CanTransport, Frame, TransportError};
use taut_proto::canopen::NodeId;

/// Several virtual drives on one transport endpoint.
pub struct DriveRack<T: CanTransport> {
    bus: T,
    drives: Vec<VirtualDrive>,
    /// Transport errors seen (the rack keeps going).
    pub transport_errors: u64,
}

impl<T: CanTransport> DriveRack<T> {
    /// Drives `drives` on `bus`.
    pub fn new(bus: T, drives: Vec<VirtualDrive>) -> Self {
        DriveRack { bus, drives, transport_errors: 0 }
    }

    /// Drives with default parameters for the given node ids.
    pub fn with_nodes(bus: T, nodes: &[NodeId]) -> Self {
        Self::new(bus, nodes.iter().map(|&n| VirtualDrive::new(DriveParams::new(n))).collect())
    }

    /// The drives.
    pub fn drives(&mut self) -> &mut [VirtualDrive] {
        &mut self.drives
    }

    /// The drive with node id `n`.
    pub fn drive(&mut self, n: NodeId) -> Option<&mut VirtualDrive> {
        self.drives.iter_mut().find(|d| d.node_id() == n)
    }

    /// The transport.
    pub fn transport(&mut self) -> &mut T {
        &mut self.bus
    }

    /// Receives everything waiting, runs every drive's timers, sends what they produced.
    pub fn step(&mut self, now: Instant) {
        loop {
            match self.bus.try_recv() {
                Ok(Some(f)) => {
                    for d in &mut self.drives {
                        d.on_frame(&f, now);
                    }
                }
                Ok(None) => break,
                Err(TransportError::Bus(_)) => self.transport_errors += 1,
                Err(_) => {
                    self.transport_errors += 1;
                    break;
                }
            }
        }
        for d in &mut self.drives {
            d.poll(now);
            while let Some(f) = d.poll_tx() {
                if self.bus.send(&f).is_err() {
                    self.transport_errors += 1;
                }
            }
        }
    }

    /// When a drive's timers next need a [`step`](Self::step).
    pub fn next_deadline(&self) -> Option<Instant> {
        self.drives.iter().filter_map(VirtualDrive::next_deadline).min()
    }
}

/// Acceptance filters for a rack of these node ids on a virtual bus: NMT, SYNC, and each
/// node's RPDOs and SDO requests, as a drive's CAN controller would filter.
pub fn rack_filters(nodes: &[NodeId]) -> Vec<Filter> {
    // NMT, SYNC, and every heartbeat (0x700..0x77F): the heartbeat consumer needs the master's.
    let mut f = vec![Filter::exact(0x000), Filter::exact(0x080), Filter { id: 0x700, mask: 0x780, extended: false }];
    for &n in nodes {
        for base in [0x200u16, 0x300, 0x400, 0x500, 0x600] {
            f.push(Filter::exact(base + u16::from(n)));
        }
    }
    f
}

/// A rack running on its own thread in wall-clock time.
pub struct RackHandle {
    drives: Arc<Mutex<Vec<VirtualDrive>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl RackHandle {
    /// Runs `f` on the drives (fault injection, reading state) between two steps.
    pub fn with<R>(&self, f: impl FnOnce(&mut [VirtualDrive]) -> R) -> R {
        let mut g = self.drives.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut g)
    }

    /// Runs `f` on the drive with node id `n`.
    pub fn with_drive<R>(&self, n: NodeId, f: impl FnOnce(&mut VirtualDrive) -> R) -> Option<R> {
        self.with(|ds| ds.iter_mut().find(|d| d.node_id() == n).map(f))
    }

    /// Stops the thread.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        // Relaxed is enough: the flag carries no data, and join() below synchronises.
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for RackHandle {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Runs `drives` on `bus` on a new thread until the handle is stopped or dropped. The thread
/// wakes on every frame and at least every millisecond.
pub fn spawn_rack<T: CanTransport + Send + 'static>(mut bus: T, drives: Vec<VirtualDrive>) -> RackHandle {
    let drives = Arc::new(Mutex::new(drives));
    let stop = Arc::new(AtomicBool::new(false));
    let (d2, s2) = (drives.clone(), stop.clone());
    let thread = std::thread::Builder::new()
        .name("virtual-drives".into())
        .spawn(move || {
            while !s2.load(Ordering::Relaxed) {
                let deadline = Instant::now() + Duration::from_millis(1);
                let first = bus.recv_deadline(deadline);
                let now = Instant::now();
                let mut ds = d2.lock().unwrap_or_else(|e| e.into_inner());
                let deliver = |f: Frame, ds: &mut Vec<VirtualDrive>| {
                    for d in ds.iter_mut() {
                        d.on_frame(&f, now);
                    }
                };
                if let Ok(Some(f)) = first {
                    deliver(f, &mut ds);
                    while let Ok(Some(f)) = bus.try_recv() {
                        deliver(f, &mut ds);
                    }
                }
                for d in ds.iter_mut() {
                    d.poll(now);
                    while let Some(f) = d.poll_tx() {
                        let _ = bus.send(&f);
                    }
                }
            }
        })
        .expect("spawning the virtual drive thread");
    RackHandle { drives, stop, thread: Some(thread) }
}
