//! `taut export REC.csv --mcap OUT.mcap`, and `taut calibrate` reading MCAP as it reads CSV; the
//! files checked with the independent Python reader; hostile MCAP input gets clear errors.

use crate::hostile;
use std::path::Path;

use hostile::taut_bin;
use std::process::Command;
use taut_config::recording::Recording;
use taut_tests::mcap::{count, read_with_python};

fn taut(args: &[&str]) -> std::process::Output {
    Command::new(taut_bin()).args(args).output().unwrap()
}

fn simulate(dir: &Path) -> std::path::PathBuf {
    let csv = dir.join("rec.csv");
    let o = taut(&["simulate", "-o", csv.to_str().unwrap(), "--duration", "30", "--rate", "50", "--seed", "4"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    csv
}

#[test]
fn export_converts_a_csv_recording_and_calibrate_reads_both_alike() {
    let dir = tempfile::tempdir().unwrap();
    let csv = simulate(dir.path());
    // Named .csv on purpose: the format is told by the first bytes, not the extension.
    let out = dir.path().join("as-mcap.csv");
    let o = taut(&["export", csv.to_str().unwrap(), "--mcap", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, _) = Recording::load(&csv).unwrap();
    let (b, rep) = Recording::load(&out).unwrap();
    assert_eq!(rep.rows, a.len());
    // The same recording, value for value (JSON keeps every bit of an f64).
    assert_eq!(a.t, b.t);
    assert_eq!(a.l, b.l);
    assert_eq!(
        a.f.as_ref().map(|f| f.iter().map(|x| x.to_bits()).collect::<Vec<_>>()),
        b.f.as_ref().map(|f| f.iter().map(|x| x.to_bits()).collect::<Vec<_>>())
    );
    assert_eq!(a.phase, b.phase);
    for (p, q) in a.p.iter().zip(&b.p) {
        assert!(p.iter().zip(q).all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan())));
    }

    let v = read_with_python(&out);
    assert_eq!(v["complete"], true, "{v}");
    assert!(v["json_error"].is_null(), "{v}");
    assert_eq!(count(&v, "/cables") as usize, a.len());
    let with_pose = a.p.iter().filter(|p| p.iter().all(|x| x.is_finite())).count() as u64;
    assert_eq!(count(&v, "/pose"), with_pose);
    assert_eq!(count(&v, "/tf"), with_pose);
    assert_eq!(v["channels"]["/pose"]["schema"], "foxglove.PoseInFrame");
    assert_eq!(v["channels"]["/tf"]["schema"], "foxglove.FrameTransform");
    assert_eq!(v["channels"]["/scene"]["schema"], "foxglove.SceneUpdate");
    for (topic, c) in v["channels"].as_object().unwrap() {
        assert_eq!(c["schema_encoding"], "jsonschema", "{topic}");
        assert_eq!(c["message_encoding"], "json", "{topic}");
        assert_eq!(c["schema_is_json"], true, "{topic}: the schema is not valid JSON");
    }
    assert_eq!(v["metadata"]["taut"]["format"], "taut-mcap v1");

    // calibrate: the same answer from either file.
    let ja = dir.path().join("a.json");
    let jb = dir.path().join("b.json");
    let oa = taut(&["calibrate", csv.to_str().unwrap(), "--json", ja.to_str().unwrap()]);
    assert!(oa.status.success(), "{}", String::from_utf8_lossy(&oa.stderr));
    let ob = taut(&["calibrate", out.to_str().unwrap(), "--json", jb.to_str().unwrap()]);
    assert!(ob.status.success(), "{}", String::from_utf8_lossy(&ob.stderr));
    let ra: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&ja).unwrap()).unwrap();
    let rb: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&jb).unwrap()).unwrap();
    assert_eq!(ra["anchors_m"], rb["anchors_m"]);
    assert!(ra["anchors_m"].is_array(), "{ra}");
}

#[test]
fn hostile_mcap_input_is_refused_with_the_file_and_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let csv = simulate(dir.path());
    let good = dir.path().join("good.mcap");
    let o = taut(&["export", csv.to_str().unwrap(), "--mcap", good.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let bytes = std::fs::read(&good).unwrap();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("magic-only.mcap", taut_config::mcap::MAGIC.to_vec(), "MCAP"),
        ("truncated.mcap", bytes[..bytes.len() * 2 / 3].to_vec(), "ends in the middle"),
        (
            "flipped.mcap",
            {
                let mut b = bytes.clone();
                let k = b.len() / 2;
                b[k] ^= 0x55;
                b
            },
            "MCAP",
        ),
        // Files `fuzz/run mcap_read` found, on which the mcap crate's readers panicked (the
        // first and the last even in release builds): a record whose length is near 2^64, a
        // record that runs past the end of its chunk, an attachment shorter than its header.
        (
            "record-longer-than-file.mcap",
            std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/../fuzz/seeds/mcap_read/record-longer-than-file.mcap")).unwrap(),
            "ends in the middle of a record",
        ),
        (
            "chunk-record-past-chunk-end.mcap",
            std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/../fuzz/seeds/mcap_read/chunk-record-past-chunk-end.mcap")).unwrap(),
            "damaged MCAP file",
        ),
        (
            "attachment-shorter-than-its-header.mcap",
            std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/../fuzz/seeds/mcap_read/attachment-shorter-than-its-header.mcap")).unwrap(),
            "MCAP",
        ),
    ];
    for (name, b, want) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, b).unwrap();
        let o = taut(&["calibrate", p.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{name} accepted");
        assert!(err.contains(name) && err.contains(want), "{name}: {err}");
    }
    // A valid MCAP file that taut did not write: no metadata, a /cables channel of another schema.
    let p = dir.path().join("foreign.mcap");
    {
        let mut w = mcap::Writer::new(std::io::BufWriter::new(std::fs::File::create(&p).unwrap())).unwrap();
        let s = w.add_schema("sensor_msgs/JointState", "ros2msg", b"float64[] position").unwrap();
        let c = w.add_channel(s, "/cables", "cdr", &Default::default()).unwrap();
        let h = mcap::records::MessageHeader { channel_id: c, sequence: 0, log_time: 0, publish_time: 0 };
        w.write_to_known_channel(&h, &[0, 1, 2, 3]).unwrap();
        w.finish().unwrap();
    }
    let o = taut(&["diagnose", p.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("foreign.mcap") && err.contains("not written by taut"), "{err}");
}
