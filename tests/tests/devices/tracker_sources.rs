//! `[tracker] sources`: the receiver takes poses only from the listed senders. A forged stream
//! from a second loopback address (and from a second port of the allowed address) is dropped
//! and counted while the allowed one is used; configurations that listen on every interface
//! without a list are refused, naming the key.

use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};
use taut_driver::tracker::{self, TrackerReceiver};
use taut_proto::devices::TrackerConfig;
use taut_proto::tracker::{format_line, PoseLine, MAX_LINE};

fn send(from: &UdpSocket, to: SocketAddr, t: f64, p: [f64; 3]) {
    let mut buf = [0u8; MAX_LINE];
    let n = format_line(&PoseLine { t, position: p, orientation: None }, &mut buf);
    from.send_to(&buf[..n], to).unwrap();
}

fn drain(rx: &mut TrackerReceiver, n: u64) {
    let t0 = Instant::now();
    while rx.stats().received < n {
        rx.poll().unwrap();
        assert!(t0.elapsed() < Duration::from_secs(5), "only {:?} of {n} datagrams arrived", rx.stats());
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn cfg(listen: &str, sources: &[&str]) -> TrackerConfig {
    TrackerConfig { sources: sources.iter().map(|s| s.to_string()).collect(), max_age_s: 0.5, ..TrackerConfig::new(listen) }
}

#[test]
fn a_forged_stream_from_another_address_is_dropped_and_counted() {
    let mut rx = TrackerReceiver::bind(&cfg("127.0.0.1:0", &["127.0.0.2"])).unwrap();
    let mut reader = rx.reader();
    let to = rx.local_addr().unwrap();
    let tracker = UdpSocket::bind("127.0.0.2:0").unwrap();
    let forger = UdpSocket::bind("127.0.0.3:0").unwrap();
    // Interleaved; the forger stamps its poses later, as one trying to win the ordering would.
    for k in 0..20 {
        let t = 100.0 + 0.01 * f64::from(k);
        send(&tracker, to, t, [0.1, 0.2, 1.5]);
        send(&forger, to, t + 0.005, [9.0, 9.0, 9.0]);
    }
    drain(&mut rx, 40);
    let s = rx.stats();
    assert_eq!((s.accepted, s.foreign, s.malformed, s.out_of_order, s.late), (20, 20, 0, 0, 0), "{s:?}");
    let p = reader.latest(Instant::now()).unwrap();
    assert_eq!((p.t, p.position), (100.19, [0.1, 0.2, 1.5]));
}

#[test]
fn address_and_port_entries_match_the_port_too() {
    let tracker = UdpSocket::bind("127.0.0.1:0").unwrap();
    let other_port = UdpSocket::bind("127.0.0.1:0").unwrap();
    let allowed = tracker.local_addr().unwrap().to_string();
    let mut rx = TrackerReceiver::bind(&cfg("127.0.0.1:0", &[allowed.as_str()])).unwrap();
    let mut reader = rx.reader();
    let to = rx.local_addr().unwrap();
    send(&other_port, to, 5.0, [7.0; 3]);
    send(&tracker, to, 1.0, [1.0; 3]);
    send(&other_port, to, 6.0, [7.0; 3]);
    send(&tracker, to, 1.01, [2.0; 3]);
    drain(&mut rx, 4);
    let s = rx.stats();
    assert_eq!((s.accepted, s.foreign), (2, 2), "{s:?}");
    assert_eq!(reader.latest(Instant::now()).unwrap().position, [2.0; 3]);
}

#[test]
fn the_receiver_thread_filters_too() {
    let (th, reader) = tracker::spawn(&cfg("127.0.0.1:0", &["127.0.0.4", "127.0.0.5"])).unwrap();
    let to = th.local_addr();
    let a = UdpSocket::bind("127.0.0.5:0").unwrap();
    let forger = UdpSocket::bind("127.0.0.6:0").unwrap();
    for k in 0..10 {
        send(&forger, to, 50.0 + f64::from(k), [9.0; 3]);
        send(&a, to, 1.0 + 0.01 * f64::from(k), [0.5; 3]);
    }
    let t0 = Instant::now();
    while reader.stats().received < 20 {
        assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", reader.stats());
        std::thread::sleep(Duration::from_millis(2));
    }
    let s = reader.stats();
    assert_eq!((s.accepted, s.foreign), (10, 10), "{s:?}");
    assert_eq!(reader.newest().unwrap().position, [0.5; 3]);
}

#[test]
fn listening_everywhere_needs_a_source_list_or_an_explicit_yes() {
    for listen in ["0.0.0.0:5005", "[::]:5005"] {
        let (key, msg) = cfg(listen, &[]).validate().unwrap_err();
        assert_eq!(key, "sources", "{listen}");
        assert!(msg.contains("every interface") && msg.contains("allow_any_source = true"), "{msg}");
        cfg(listen, &["192.168.10.20"]).validate().unwrap();
        TrackerConfig { allow_any_source: true, ..cfg(listen, &[]) }.validate().unwrap();
        // Refused at bind time too (what `taut start` and `taut probe` call).
        let e = TrackerReceiver::bind(&cfg(listen, &[])).err().unwrap();
        assert!(e.to_string().starts_with("tracker.sources:"), "{e}");
    }
    // A specific address without a list is the operator's choice of network.
    cfg("192.168.10.1:5005", &[]).validate().unwrap();
    // Entries: address or address:port, IPv4 or IPv6.
    cfg("0.0.0.0:5005", &["10.0.0.7", "10.0.0.8:5005", "fe80::1", "[fe80::2]:5005"]).validate().unwrap();
    for (bad, key) in
        [(&["tracker.local"][..], "sources[0]"), (&["10.0.0.7", "10.0.0.300"][..], "sources[1]"), (&["10.0.0.7:"][..], "sources[0]")]
    {
        assert_eq!(cfg("0.0.0.0:5005", bad).validate().unwrap_err().0, key, "{bad:?}");
    }
    let (key, _) = TrackerConfig { allow_any_source: true, ..cfg("0.0.0.0:5005", &["10.0.0.7"]) }.validate().unwrap_err();
    assert_eq!(key, "allow_any_source");
}

/// The whole robot configuration: the error names the file's table and key.
#[test]
fn a_robot_config_listening_everywhere_is_refused_with_the_key() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-hw.toml");
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains("sources = [\"192.168.10.20\"]"), "the example lists the tracker");
    taut_config::RobotConfig::from_toml_str(&text).unwrap();
    let open = text.replace("listen = \"192.168.10.1:5005\"\nsources = [\"192.168.10.20\"]", "listen = \"0.0.0.0:5005\"");
    assert_ne!(open, text);
    let e = taut_config::RobotConfig::from_toml_str(&open).unwrap_err().to_string();
    assert!(e.contains("tracker") && e.contains("sources"), "{e}");
    let explicit = open.replace("listen = \"0.0.0.0:5005\"", "listen = \"0.0.0.0:5005\"\nallow_any_source = true");
    taut_config::RobotConfig::from_toml_str(&explicit).unwrap();
}
