//! Live telemetry over the Foxglove WebSocket protocol: a client subscribes to every advertised
//! channel during the simulated start-up and receives each of them; the loop's overruns and
//! drops are printed (compare mcap_start.rs, the same start-up without a client).

use std::collections::BTreeMap;
use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use taut_calibrator::calib_backend::TautCalib;
use taut_plugin::daemon::{Daemon, DaemonOptions};
use tungstenite::client::IntoClientRequest;
use tungstenite::Message;

type Ws = tungstenite::WebSocket<TcpStream>;

/// The handshake's error, boxed (tungstenite's error is large).
fn connect(addr: SocketAddr, subprotocol: Option<&str>) -> Result<Ws, Box<tungstenite::Error>> {
    let stream = TcpStream::connect(addr).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let mut req = format!("ws://{addr}/").into_client_request().unwrap();
    if let Some(p) = subprotocol {
        req.headers_mut().insert("Sec-WebSocket-Protocol", p.parse().unwrap());
    }
    match tungstenite::client(req, stream) {
        Ok((ws, resp)) => {
            assert_eq!(resp.headers().get("Sec-WebSocket-Protocol").unwrap(), "foxglove.websocket.v1");
            Ok(ws)
        }
        Err(tungstenite::HandshakeError::Failure(e)) => Err(Box::new(e)),
        Err(e) => panic!("handshake: {e}"),
    }
}

fn text(ws: &mut Ws) -> serde_json::Value {
    match ws.read().unwrap() {
        Message::Text(t) => serde_json::from_str(t.as_str()).unwrap(),
        m => panic!("expected a text message, got {m:?}"),
    }
}

/// Reads serverInfo and advertise, subscribes to every channel (subscription id = 100 + channel
/// id), then counts messages per topic until `stop`.
fn subscribe_all(ws: &mut Ws) -> BTreeMap<u32, String> {
    let info = text(ws);
    assert_eq!(info["op"], "serverInfo");
    let adv = text(ws);
    assert_eq!(adv["op"], "advertise");
    let mut topics = BTreeMap::new();
    let mut subs = Vec::new();
    for c in adv["channels"].as_array().unwrap() {
        assert_eq!(c["encoding"], "json");
        assert_eq!(c["schemaEncoding"], "jsonschema");
        serde_json::from_str::<serde_json::Value>(c["schema"].as_str().unwrap()).expect("the schema is JSON");
        let id = c["id"].as_u64().unwrap() as u32;
        topics.insert(100 + id, c["topic"].as_str().unwrap().to_string());
        subs.push(serde_json::json!({"id": 100 + id, "channelId": id}));
    }
    ws.send(Message::text(serde_json::json!({"op": "subscribe", "subscriptions": subs}).to_string())).unwrap();
    topics
}

fn count_until(ws: &mut Ws, topics: &BTreeMap<u32, String>, stop: &AtomicBool) -> BTreeMap<String, u64> {
    ws.get_mut().set_read_timeout(Some(Duration::from_millis(200))).unwrap();
    let mut got: BTreeMap<String, u64> = BTreeMap::new();
    while !stop.load(Ordering::Relaxed) {
        match ws.read() {
            Ok(Message::Binary(b)) => {
                assert_eq!(b[0], 0x01, "messageData opcode");
                let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
                let topic = topics.get(&sub).unwrap_or_else(|| panic!("unknown subscription {sub}"));
                serde_json::from_slice::<serde_json::Value>(&b[13..]).unwrap_or_else(|e| panic!("{topic}: {e}"));
                *got.entry(topic.clone()).or_default() += 1;
            }
            Ok(Message::Close(_)) => break,
            Ok(_) => {}
            Err(tungstenite::Error::Io(e)) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(_) => break,
        }
    }
    got
}

#[test]
fn a_client_receives_every_channel_during_the_start_up() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = taut_tests::startup::sim_robot(dir.path());
    cfg.telemetry.enabled = true;
    cfg.telemetry.port = 0;
    let sim = taut_tests::startup::build_at_rest(&cfg, 3);
    let d = Daemon::start(&cfg, sim.devices, Box::new(TautCalib::from_config(&cfg)), DaemonOptions::default()).unwrap();
    let addr = d.telemetry.expect("telemetry enabled");
    assert!(addr.ip().is_loopback());

    // Refused without the subprotocol.
    assert!(connect(addr, None).is_err());

    let mut ws = connect(addr, Some("foxglove.websocket.v1")).unwrap();
    let topics = subscribe_all(&mut ws);
    assert_eq!(topics.len(), 9);
    let stop = Arc::new(AtomicBool::new(false));
    let s2 = stop.clone();
    let client = std::thread::spawn(move || count_until(&mut ws, &topics, &s2));

    let ok = d.wait_until(Duration::from_secs(300), taut_tests::startup::start_up_over);
    // Let the last frames through before stopping the client.
    std::thread::sleep(Duration::from_millis(500));
    let c = d.calib_status();
    let fault = d.loop_status().snap.fault;
    let dropped = d.loop_status().dropped;
    let stats = d.telemetry_stats.clone().unwrap();
    stop.store(true, Ordering::Relaxed);
    let got = client.join().unwrap();
    let report = d.shutdown().unwrap();
    assert!(ok, "start-up did not finish: {}", c.stage);
    assert_eq!(dropped, 0, "the calibrator side (recording, encoding, telemetry) fell behind the loop");
    assert!(fault.is_none(), "the start-up faulted: {fault:?} (stage {})", c.stage);
    if let Some(o) = c.outcomes.iter().find(|o| !o.accepted) {
        panic!("a calibration was rejected: {}", o.reason);
    }
    eprintln!(
        "with a telemetry client: {} cycles, {} overruns, {dropped} samples dropped, {} samples recorded, max late {} us; received {:?}; server sent {}, slow drops {}",
        report.cycles,
        report.overruns,
        c.samples_recorded,
        report.max_late_ns / 1000,
        got,
        stats.sent.load(Ordering::Relaxed),
        stats.slow_dropped.load(Ordering::Relaxed)
    );
    for def in taut_config::mcap::CHANNELS {
        assert!(got.get(def.topic).copied().unwrap_or(0) > 0, "no message on {}: {got:?}", def.topic);
    }
    assert_eq!(got["/params"] as usize, c.outcomes.iter().filter(|o| o.accepted).count());
    // Every sample reached the client unless the queue was full (counted, never waited on).
    assert!(got["/cables"] > c.samples_recorded / 2, "{} of {}", got["/cables"], c.samples_recorded);
}
