//! Real SocketCAN on `vcan0`/`vcan1`, through the `socketcan` crate and
//! can-utils.
//!
//! Runs for real inside the QEMU VM of `tests/vcan/run`; on a host without
//! the interfaces every test prints a skip message and passes (unless
//! `TAUT_VCAN_REQUIRED=1`). Under TCG emulation timing means nothing, so the
//! tests only check behaviour and every wait is generous. Ordering is made
//! deterministic with "fence" frames instead of sleeps where possible.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::thread;
use std::time::{Duration, Instant};

use socketcan::dump::Reader as DumpReader;
use socketcan::errors::{ErrorCause, CAN_ERR_ACK, CAN_ERR_BUSOFF};
use socketcan::{
    CanAnyFrame, CanErrorFrame, CanFilter, CanFrame, CanSocket, EmbeddedFrame, ExtendedId, Frame, Id, Socket, SocketOptions, StandardId,
};
use taut_tests::vcan;

const VCAN0: &str = "vcan0";
const VCAN1: &str = "vcan1";
/// Upper bound for anything that should arrive "immediately" (TCG is slow).
const RX_WAIT: Duration = Duration::from_secs(20);
/// Fence frame id: sent after the frames under test; once it arrives,
/// everything sent before it on the same socket has been delivered too.
const FENCE_ID: u16 = 0x7F0;

fn sid(id: u16) -> Id {
    Id::Standard(StandardId::new(id).expect("valid standard id"))
}

fn eid(id: u32) -> Id {
    Id::Extended(ExtendedId::new(id).expect("valid extended id"))
}

fn data_frame(id: Id, data: &[u8]) -> CanFrame {
    CanFrame::new(id, data).expect("valid data frame")
}

fn open(iface: &str) -> CanSocket {
    CanSocket::open(iface).unwrap_or_else(|e| panic!("open {iface}: {e}"))
}

fn read(sock: &CanSocket, what: &str) -> CanFrame {
    sock.read_frame_timeout(RX_WAIT).unwrap_or_else(|e| panic!("waiting for {what}: {e}"))
}

fn send_fence(sock: &CanSocket) {
    sock.write_frame(&data_frame(sid(FENCE_ID), &[0xFE])).expect("send fence");
}

fn is_fence(f: &CanFrame) -> bool {
    matches!(f, CanFrame::Data(_)) && f.id() == sid(FENCE_ID)
}

/// Reads frames until the fence arrives; returns what came before it.
fn read_until_fence(sock: &CanSocket, what: &str) -> Vec<CanFrame> {
    let mut got = Vec::new();
    loop {
        let f = read(sock, what);
        if is_fence(&f) {
            return got;
        }
        got.push(f);
        assert!(got.len() < 10_000, "{what}: no fence after 10000 frames");
    }
}

/// The comparable content of a frame: (raw id with flags, dlc, data).
fn key(f: &CanFrame) -> (u32, bool, bool, usize, Vec<u8>) {
    (f.id_word(), f.is_extended(), f.is_remote_frame(), f.dlc(), f.data().to_vec())
}

#[test]
fn standard_and_extended_frames_roundtrip() {
    let Some(iface) = vcan::iface_or_skip(VCAN0, "standard_and_extended_frames_roundtrip") else {
        return;
    };
    let tx = open(iface);
    let rx = open(iface);

    let sent = vec![
        data_frame(sid(0x123), &[1, 2, 3]),
        data_frame(sid(0x7FF), &[0xFF, 0, 0x55, 0xAA, 1, 2, 3, 4]),
        data_frame(sid(0x000), &[]),
        data_frame(eid(0x1ABC_DEF0), &[0xDE, 0xAD, 0xBE, 0xEF]),
        data_frame(eid(0x0000_0001), &[9; 8]),
        data_frame(eid(0x1FFF_FFFF), &[]),
        CanFrame::new_remote(sid(0x321), 4).expect("remote frame"),
        CanFrame::new_remote(eid(0x0012_3456), 0).expect("remote frame"),
    ];
    for f in &sent {
        tx.write_frame(f).unwrap_or_else(|e| panic!("send {f:?}: {e}"));
    }
    let got: Vec<CanFrame> = (0..sent.len()).map(|_| read(&rx, "echoed frame")).collect();

    assert_eq!(
        got.iter().map(key).collect::<Vec<_>>(),
        sent.iter().map(key).collect::<Vec<_>>(),
        "frames must arrive unchanged and in order"
    );
    assert!(got[3].is_extended() && !got[0].is_extended());
    assert!(matches!(got[6], CanFrame::Remote(_)));

    // The sender does not see its own frames by default...
    assert!(tx.read_frame_timeout(Duration::from_millis(200)).is_err());
    // ...but does with CAN_RAW_RECV_OWN_MSGS.
    tx.set_recv_own_msgs(true).expect("recv own msgs");
    let own = data_frame(sid(0x042), &[0x42]);
    tx.write_frame(&own).expect("send own");
    assert_eq!(key(&read(&tx, "own frame")), key(&own));
    assert_eq!(key(&read(&rx, "own frame on rx")), key(&own));
}

#[test]
fn receive_timeout_expires_then_frames_still_arrive() {
    let Some(iface) = vcan::iface_or_skip(VCAN0, "receive_timeout_expires_then_frames_still_arrive") else {
        return;
    };
    let tx = open(iface);
    let rx = open(iface);

    // Poll-based timeout of the crate.
    let err = rx.read_frame_timeout(Duration::from_millis(100)).expect_err("nothing was sent, the read must time out");
    assert_eq!(err.kind(), std::io::ErrorKind::TimedOut, "{err}");

    // SO_RCVTIMEO based timeout: a plain blocking read returns EAGAIN.
    rx.set_read_timeout(Duration::from_millis(100)).expect("set read timeout");
    let start = Instant::now();
    let err = rx.read_frame().expect_err("read must time out");
    assert!(
        matches!(err.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut),
        "unexpected error kind {:?}: {err}",
        err.kind()
    );
    // Behavioural bound only: it must not hang forever.
    assert!(start.elapsed() < Duration::from_secs(60));

    // The socket is still usable afterwards.
    rx.set_read_timeout(RX_WAIT).expect("set read timeout");
    let f = data_frame(sid(0x55), &[5]);
    tx.write_frame(&f).expect("send");
    assert_eq!(key(&rx.read_frame().expect("frame after timeout")), key(&f));
}

#[test]
fn error_frames_reach_only_sockets_that_enable_them() {
    let Some(iface) = vcan::iface_or_skip(VCAN0, "error_frames_reach_only_sockets_that_enable_them") else {
        return;
    };
    let tx = open(iface);
    let rx_all = open(iface);
    let rx_none = open(iface);
    let rx_ack_only = open(iface);
    rx_all.set_error_filter_accept_all().expect("error filter");
    assert_eq!(rx_all.error_filter().expect("read error filter"), 0x1FFF_FFFF /* CAN_ERR_MASK */);
    rx_ack_only.set_error_filter(CAN_ERR_ACK).expect("error filter");

    // vcan has no controller that would raise errors, but a raw socket may
    // inject an error frame; the CAN core routes it by error mask.
    let err = CanErrorFrame::new_error(CAN_ERR_BUSOFF, &[]).expect("error frame");
    tx.write_frame(&err).expect("send error frame");
    send_fence(&tx);

    let got = read_until_fence(&rx_all, "error frame");
    assert_eq!(got.len(), 1, "expected exactly the error frame, got {got:?}");
    match got[0] {
        CanFrame::Error(e) => {
            assert_ne!(e.error_bits() & CAN_ERR_BUSOFF, 0, "{e:?}");
            assert_eq!(*e.into_error().first(), ErrorCause::BusOff);
        }
        other => panic!("expected an error frame, got {other:?}"),
    }

    let got = read_until_fence(&rx_none, "fence on socket without error mask");
    assert!(got.is_empty(), "error frames must be filtered by default: {got:?}");
    let got = read_until_fence(&rx_ack_only, "fence on socket with ACK-only mask");
    assert!(got.is_empty(), "bus-off must not pass an ACK-only mask: {got:?}");
}

#[test]
fn id_filters_select_frames() {
    let Some(iface) = vcan::iface_or_skip(VCAN0, "id_filters_select_frames") else {
        return;
    };
    let tx = open(iface);
    // Mask includes CAN_EFF_FLAG: the filter tells standard from extended.
    let rx_strict = open(iface);
    rx_strict
        .set_filters(&[
            CanFilter::new(0x100, 0x7FF | CAN_EFF_FLAG),
            CanFilter::new(FENCE_ID as u32, 0x7FF | CAN_EFF_FLAG),
            CanFilter::new(0x1800_0001 | CAN_EFF_FLAG, 0x1FFF_FFFF | CAN_EFF_FLAG),
        ])
        .expect("set filters");
    // Mask without CAN_EFF_FLAG: 0x100 matches the standard *and* the
    // extended id 0x100 (kernel semantics, easy to get wrong in a master).
    let rx_loose = open(iface);
    rx_loose.set_filters(&[CanFilter::new(0x100, 0x7FF), CanFilter::new(FENCE_ID as u32, 0x7FF | CAN_EFF_FLAG)]).expect("set filters");

    for (id, data) in [
        (sid(0x0FF), &[1u8][..]),
        (sid(0x100), &[2]),
        (sid(0x101), &[3]),
        (eid(0x1800_0001), &[4]),
        (eid(0x0000_0100), &[5]), // same numeric id as the SFF filter, but EFF
        (eid(0x1800_0002), &[6]),
    ] {
        tx.write_frame(&data_frame(id, data)).expect("send");
    }
    send_fence(&tx);
    let ids = |sock: &CanSocket, what: &str| -> Vec<Id> { read_until_fence(sock, what).iter().map(|f| f.id()).collect() };
    assert_eq!(ids(&rx_strict, "strictly filtered frames"), vec![sid(0x100), eid(0x1800_0001)]);
    assert_eq!(ids(&rx_loose, "loosely filtered frames"), vec![sid(0x100), eid(0x100)]);
}

/// `CAN_EFF_FLAG` from `<linux/can.h>`.
const CAN_EFF_FLAG: u32 = 0x8000_0000;

#[test]
fn vcan0_and_vcan1_are_separate_buses() {
    let Some([a, b]) = vcan::ifaces_or_skip([VCAN0, VCAN1], "vcan0_and_vcan1_are_separate_buses") else {
        return;
    };
    let tx_a = open(a);
    let rx_a = open(a);
    let tx_b = open(b);
    let rx_b = open(b);

    tx_b.write_frame(&data_frame(sid(0x0B0), &[0xB])).expect("send on b");
    tx_a.write_frame(&data_frame(sid(0x0A0), &[0xA])).expect("send on a");
    send_fence(&tx_a);
    send_fence(&tx_b);

    let on_a: Vec<Id> = read_until_fence(&rx_a, "vcan0").iter().map(|f| f.id()).collect();
    let on_b: Vec<Id> = read_until_fence(&rx_b, "vcan1").iter().map(|f| f.id()).collect();
    assert_eq!(on_a, vec![sid(0x0A0)]);
    assert_eq!(on_b, vec![sid(0x0B0)]);
}

// ---- can-utils -------------------------------------------------------------

fn wait_child(child: &mut Child, timeout: Duration, what: &str) -> std::process::ExitStatus {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(st) = child.try_wait().expect("try_wait") {
            return st;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what} did not finish within {timeout:?}");
        }
        thread::sleep(Duration::from_millis(20));
    }
}

/// Runs a can-utils tool to completion; panics with its output on failure.
fn run_tool(tool: &Path, args: &[&str]) {
    let out = Command::new(tool).args(args).stdin(Stdio::null()).output().unwrap_or_else(|e| panic!("run {}: {e}", tool.display()));
    assert!(
        out.status.success(),
        "{} {args:?} failed ({}): {}{}",
        tool.display(),
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Number of CAN receivers registered on `iface` (from /proc/net/can).
/// `None` if the kernel does not expose the lists.
fn can_receivers(iface: &str) -> Option<usize> {
    let dir = Path::new("/proc/net/can");
    let mut n = 0;
    let mut seen = false;
    for entry in fs::read_dir(dir).ok()? {
        let path = entry.ok()?.path();
        if !path.file_name().and_then(|s| s.to_str()).is_some_and(|s| s.starts_with("rcvlist_")) {
            continue;
        }
        seen = true;
        let text = fs::read_to_string(&path).ok()?;
        n += text.lines().filter(|l| l.split_whitespace().next() == Some(iface) && !l.contains("no entry")).count();
    }
    seen.then_some(n)
}

/// Waits until a receiver beyond `before` is registered on `iface` (i.e. a
/// spawned candump has bound its socket).
fn wait_for_new_receiver(iface: &str, before: Option<usize>, child: &mut Child) {
    let Some(before) = before else {
        // No /proc/net/can: fall back to a grace period.
        thread::sleep(Duration::from_secs(3));
        return;
    };
    let deadline = Instant::now() + RX_WAIT;
    while can_receivers(iface).unwrap_or(0) <= before {
        if let Some(st) = child.try_wait().expect("try_wait") {
            panic!("candump exited early: {st}");
        }
        assert!(Instant::now() < deadline, "candump never bound to {iface}");
        thread::sleep(Duration::from_millis(20));
    }
}

fn candump_log(dir: &Path) -> PathBuf {
    let logs: Vec<PathBuf> = fs::read_dir(dir)
        .expect("read temp dir")
        .map(|e| e.expect("dir entry").path())
        .filter(|p| p.file_name().and_then(|s| s.to_str()).is_some_and(|s| s.starts_with("candump") && s.ends_with(".log")))
        .collect();
    assert_eq!(logs.len(), 1, "expected one candump log file, found {logs:?}");
    logs.into_iter().next().unwrap()
}

#[test]
fn cangen_frames_seen_by_candump_log_and_socket() {
    const TEST: &str = "cangen_frames_seen_by_candump_log_and_socket";
    const N: usize = 50;
    let Some(iface) = vcan::iface_or_skip(VCAN0, TEST) else {
        return;
    };
    let (Some(candump), Some(cangen)) = (vcan::tool_or_skip("candump", TEST), vcan::tool_or_skip("cangen", TEST)) else {
        return;
    };
    let rx = open(iface);
    rx.set_filters(&[CanFilter::new(0x42A, 0x7FF)]).expect("filter");
    let dir = tempfile::tempdir().expect("tempdir");

    // candump -l: log to candump-<date>.log in the cwd; -n: exit after N frames.
    let before = can_receivers(iface);
    let mut dump = Command::new(&candump)
        .args(["-l", "-n", &N.to_string(), &format!("{iface},42A:7FF")])
        .current_dir(dir.path())
        .stdin(Stdio::null())
        // candump chats on stdout ("Enabling Logfile ..."); keep libtest's
        // output clean.
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn candump");
    wait_for_new_receiver(iface, before, &mut dump);

    // Fixed id 0x42A, 8 bytes, incrementing payload, 1 ms gap.
    run_tool(&cangen, &[iface, "-n", &N.to_string(), "-I", "42A", "-L", "8", "-D", "i", "-g", "1"]);

    let from_socket: Vec<CanFrame> = (0..N).map(|_| read(&rx, "cangen frame")).collect();
    let st = wait_child(&mut dump, RX_WAIT * 3, "candump -n");
    assert!(st.success(), "candump failed: {st}");

    let log = candump_log(dir.path());
    let records: Vec<_> = DumpReader::from_file(&log)
        .expect("open candump log")
        .collect::<Result<Vec<_>, _>>()
        .unwrap_or_else(|e| panic!("parse {}: {e:?}", log.display()));
    assert_eq!(records.len(), N, "candump log lines");

    for (i, (rec, f)) in records.iter().zip(&from_socket).enumerate() {
        assert_eq!(rec.device, iface);
        let CanAnyFrame::Normal(logged) = rec.frame else {
            panic!("record {i}: unexpected frame {:?}", rec.frame);
        };
        assert_eq!(key(&logged.into()), key(f), "record {i}: log vs socket");
        assert_eq!(f.id(), sid(0x42A));
        assert_eq!(f.dlc(), 8);
        // -D i: the first byte counts up.
        assert_eq!(f.data()[0], from_socket[0].data()[0].wrapping_add(i as u8), "record {i}: incrementing payload");
    }
}

#[test]
fn cansend_frames_reach_socket() {
    const TEST: &str = "cansend_frames_reach_socket";
    let Some(iface) = vcan::iface_or_skip(VCAN0, TEST) else {
        return;
    };
    let Some(cansend) = vcan::tool_or_skip("cansend", TEST) else {
        return;
    };
    let rx = open(iface);
    for arg in ["123#DEADBEEF", "1ABCDEF0#0102", "321#R"] {
        run_tool(&cansend, &[iface, arg]);
    }
    let got: Vec<_> = (0..3).map(|_| key(&read(&rx, "cansend frame"))).collect();
    assert_eq!(
        got,
        vec![
            key(&data_frame(sid(0x123), &[0xDE, 0xAD, 0xBE, 0xEF])),
            key(&data_frame(eid(0x1ABC_DEF0), &[1, 2])),
            key(&CanFrame::new_remote(sid(0x321), 0).unwrap()),
        ]
    );
}
