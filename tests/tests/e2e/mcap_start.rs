//! `taut start --sim --once` records MCAP beside the CSV: the independent Python reader finds
//! every channel with its schema, and as many `/cables` messages as the CSV has rows; taut reads
//! the MCAP back as the same recording. Prints the loop's overruns and drops without a telemetry
//! client (compare telemetry_ws.rs, with one).

use std::time::Duration;
use taut_calibrator::calib_backend::TautCalib;
use taut_config::live::RecordingFormat;
use taut_config::recording::Recording;
use taut_plugin::daemon::{Daemon, DaemonOptions};
use taut_tests::mcap::{count, read_with_python};
use taut_tests::startup;

#[test]
fn start_up_mcap_has_every_channel_and_the_csv_rows() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = startup::sim_robot(dir.path());
    cfg.recording.format = RecordingFormat::Both;
    let sim = startup::build_at_rest(&cfg, 3);
    let d = Daemon::start(&cfg, sim.devices, Box::new(TautCalib::from_config(&cfg)), DaemonOptions::default()).unwrap();
    let ok = d.wait_until(Duration::from_secs(300), startup::start_up_over);
    let csv = d.recording.clone();
    let mcap = d.mcap.clone().expect("format both writes an MCAP file");
    let c = d.calib_status();
    let fault = d.loop_status().snap.fault;
    let dropped = d.loop_status().dropped;
    let handle = d.handle().clone();
    let report = d.shutdown().unwrap();
    // Every cycle the plugin ran: the periodic loop's, and those of activation and of the stop
    // (the daemon hosts a plugin; `report.cycles` counts the periodic loop only).
    let all_cycles = handle.loop_status().cycles;
    assert!(all_cycles >= report.cycles, "{all_cycles} < {}", report.cycles);
    assert!(ok, "start-up did not finish: {}", c.stage);
    assert_eq!(dropped, 0, "the calibrator side (recording, encoding, telemetry) fell behind the loop");
    assert!(fault.is_none(), "the start-up faulted: {fault:?} (stage {})", c.stage);
    if let Some(o) = c.outcomes.iter().find(|o| !o.accepted) {
        panic!("a calibration was rejected: {}", o.reason);
    }
    let accepted = c.outcomes.iter().filter(|o| o.accepted).count() as u64;
    eprintln!(
        "without a telemetry client: {} cycles, {} overruns, {dropped} samples dropped, {} samples recorded, max late {} us",
        report.cycles,
        report.overruns,
        c.samples_recorded,
        report.max_late_ns / 1000
    );

    let (a, rep_a) = Recording::load(&csv).unwrap();
    let (b, rep_b) = Recording::load(&mcap).unwrap();
    assert_eq!(rep_a.rows, rep_b.rows);
    assert_eq!(a.phase, b.phase);
    // The CSV rounds: lengths to 7 decimals, positions to 6, tensions to 3.
    for i in 0..a.len() {
        assert!((a.t[i] - b.t[i]).abs() < 1e-6);
        for (x, y) in a.lengths(i).iter().zip(b.lengths(i)) {
            assert!((x - y).abs() < 1e-6 || (x.is_nan() && y.is_nan()), "row {i}: length {x} vs {y}");
        }
        for (x, y) in a.p[i].iter().zip(&b.p[i]) {
            assert!((x - y).abs() < 1e-5 || (x.is_nan() && y.is_nan()), "row {i}: position {x} vs {y}");
        }
        for (x, y) in a.tensions(i).unwrap().iter().zip(b.tensions(i).unwrap()) {
            assert!((x - y).abs() < 1e-3 || (x.is_nan() && y.is_nan()), "row {i}: tension {x} vs {y}");
        }
    }

    let v = read_with_python(&mcap);
    assert_eq!(v["complete"], true, "{v}");
    assert!(v["json_error"].is_null(), "{v}");
    let chans = v["channels"].as_object().unwrap();
    assert_eq!(chans.len(), 9, "{v}");
    for def in taut_config::mcap::CHANNELS {
        let ch = &v["channels"][def.topic];
        assert_eq!(ch["schema"], def.schema_name, "{}", def.topic);
        assert_eq!(ch["schema_encoding"], "jsonschema");
        assert_eq!(ch["schema_is_json"], true, "{}", def.topic);
        assert!(count(&v, def.topic) > 0, "no message on {}: {v}", def.topic);
    }
    assert_eq!(count(&v, "/cables") as usize, rep_a.rows);
    // One sample per loop cycle, none dropped.
    assert_eq!(count(&v, "/cables"), all_cycles);
    assert_eq!(count(&v, "/params"), accepted, "one /params message per hot-swapped set");
    assert_eq!(count(&v, "/pose"), count(&v, "/tf"));
    assert!(count(&v, "/phase") >= 5, "{v}");
    eprintln!("channels: {}", serde_json::to_string(&v["channels"]).unwrap());
}
