//! The boundary refuses what it must, with a code and a message: NULL pointers, bad
//! configuration (file, line, key), a stale options struct, calls in the wrong lifecycle state,
//! a wrong cable count; malformed readings are flagged and taken as missing; plugin-owned
//! devices that cannot be brought up fail `taut_activate`, which can be retried.

use std::ffi::CString;
use std::ptr::{null, null_mut};
use taut::*;

fn last_error() -> String {
    let mut buf = vec![0u8; 2048];
    let n = unsafe { taut_last_error(buf.as_mut_ptr().cast(), buf.len()) };
    String::from_utf8_lossy(&buf[..n.min(buf.len() - 1)]).into_owned()
}

const CONFIG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../config/examples/aras-cam-sim.toml");

fn configure(devices: u32, dir: &std::path::Path) -> (*mut TautPlugin, TautError) {
    let cfg = CString::new(CONFIG).unwrap();
    let data = CString::new(dir.to_str().unwrap()).unwrap();
    let mut o = unsafe { std::mem::zeroed::<TautOptions>() };
    let mut h = null_mut();
    unsafe {
        assert_eq!(taut_options_init(&mut o), TautError::Ok);
        o.devices = devices;
        o.data_dir = data.as_ptr();
        let e = taut_configure(cfg.as_ptr(), TAUT_CONFIG_PATH, &o, &mut h);
        (h, e)
    }
}

#[test]
fn null_pointers_are_errors_with_a_message() {
    unsafe {
        assert_eq!(taut_activate(null_mut()), TautError::NullPointer);
        assert!(last_error().contains("taut_activate: the handle is NULL"), "{}", last_error());
        assert_eq!(taut_update(null_mut(), 0.0, 0.002, null(), null_mut()), TautError::NullPointer);
        assert_eq!(taut_status(null(), null_mut()), TautError::NullPointer);
        assert_eq!(taut_poll_event(null(), null_mut()), TautError::NullPointer);
        assert_eq!(taut_configure(null(), TAUT_CONFIG_PATH, null(), null_mut()), TautError::NullPointer);
        let mut h = null_mut();
        assert_eq!(taut_configure(null(), TAUT_CONFIG_PATH, null(), &mut h), TautError::NullPointer);
        assert_eq!(taut_cleanup(null_mut()), TautError::Ok);
        // Asking for the length only.
        assert_eq!(taut_last_error(null_mut(), 0), "taut_configure: config is NULL".len());
    }
}

#[test]
fn a_bad_configuration_names_the_line_and_key() {
    let text = CString::new("[robot]\nname = \"x\"\nmass_kg = \"heavy\"\n").unwrap();
    let mut h = null_mut();
    let e = unsafe { taut_configure(text.as_ptr(), TAUT_CONFIG_TEXT, null(), &mut h) };
    assert_eq!(e, TautError::Config);
    assert!(h.is_null());
    let m = last_error();
    assert!(m.contains(":3") && m.contains("mass_kg"), "{m}");
    let e = unsafe { taut_configure(text.as_ptr(), 7, null(), &mut h) };
    assert_eq!(e, TautError::InvalidArgument);
    assert!(last_error().contains("config_kind 7"), "{}", last_error());
    let missing = CString::new("/nonexistent/robot.toml").unwrap();
    assert_eq!(unsafe { taut_configure(missing.as_ptr(), TAUT_CONFIG_PATH, null(), &mut h) }, TautError::Config);
    assert!(last_error().contains("/nonexistent/robot.toml"), "{}", last_error());
}

#[test]
fn a_stale_options_struct_and_an_unknown_mode_are_refused() {
    let cfg = CString::new(CONFIG).unwrap();
    let mut o = unsafe { std::mem::zeroed::<TautOptions>() };
    unsafe { taut_options_init(&mut o) };
    o.struct_size -= 8;
    let mut h = null_mut();
    assert_eq!(unsafe { taut_configure(cfg.as_ptr(), TAUT_CONFIG_PATH, &o, &mut h) }, TautError::InvalidArgument);
    assert!(last_error().contains("struct_size"), "{}", last_error());
    unsafe { taut_options_init(&mut o) };
    o.devices = 9;
    assert_eq!(unsafe { taut_configure(cfg.as_ptr(), TAUT_CONFIG_PATH, &o, &mut h) }, TautError::InvalidArgument);
    assert!(last_error().contains("options.devices = 9"), "{}", last_error());
}

#[test]
fn lifecycle_order_cable_count_and_malformed_readings() {
    let dir = tempfile::tempdir().unwrap();
    let (h, e) = configure(TAUT_DEVICES_HOST, dir.path());
    assert_eq!(e, TautError::Ok, "{}", last_error());
    let mut inp = TautInputs { n_cables: 4, ..TautInputs::default() };
    let mut cmd = TautCommands::default();
    let mut st = TautStatus::default();
    unsafe {
        assert_eq!(taut_update(h, 0.0, 0.002, &inp, &mut cmd), TautError::WrongState);
        assert!(last_error().contains("activate first"), "{}", last_error());
        // The lifecycle is checked before the inputs.
        let zero = TautInputs { n_cables: 0, ..TautInputs::default() };
        assert_eq!(taut_update(h, 0.0, 0.002, &zero, &mut cmd), TautError::WrongState, "{}", last_error());
        assert_eq!(taut_deactivate(h), TautError::WrongState);
        assert_eq!(taut_status(h, &mut st), TautError::Ok);
        assert_eq!(st.lifecycle, TautLifecycle::Inactive as u8);
        assert_eq!(taut_activate(h), TautError::Ok);
        assert_eq!(taut_activate(h), TautError::WrongState);
        assert_eq!(taut_status(h, &mut st), TautError::Ok);
        assert_eq!(st.lifecycle, TautLifecycle::Active as u8);
        // Plugin-owned calls on a host-owned plugin.
        assert_eq!(taut_update(h, 0.0, 0.002, null(), &mut cmd), TautError::NullPointer);
        inp.n_cables = 3;
        assert_eq!(taut_update(h, 0.0, 0.002, &inp, &mut cmd), TautError::InvalidArgument);
        assert!(last_error().contains("n_cables is 3, the configuration has 4"), "{}", last_error());
        inp.n_cables = 4;
        assert_eq!(taut_update(h, f64::NAN, 0.002, &inp, &mut cmd), TautError::InvalidArgument);
        // A fresh length that is not finite and an unknown drive code: flagged, taken as missing.
        inp.length_m[1] = f64::NAN;
        inp.length_age_s[1] = 0.0;
        cmd.bad_input = 0;
        assert_eq!(taut_update(h, 0.0, 0.002, &inp, &mut cmd), TautError::Ok);
        assert_eq!(cmd.bad_input, 1);
        assert!(last_error().contains("length_m[1]"), "{}", last_error());
        assert_eq!(cmd.n_cables, 4);
        inp.length_age_s[1] = f64::INFINITY;
        inp.drive[2] = 17;
        assert_eq!(taut_update(h, 0.002, 0.002, &inp, &mut cmd), TautError::Ok);
        assert_eq!(cmd.bad_input, 1);
        assert!(last_error().contains("drive[2] = 17"), "{}", last_error());
        inp.drive[2] = 0;
        assert_eq!(taut_update(h, 0.004, 0.002, &inp, &mut cmd), TautError::Ok);
        assert_eq!(cmd.bad_input, 0);
        // The first cycles ask for the drives to be enabled.
        assert_eq!(cmd.request, TautDriveRequest::Enable as u8);
        assert_eq!(taut_params(h, &mut std::mem::zeroed()), TautError::Refused);
        assert_eq!(taut_request_recalibration(h), TautError::Refused);
        assert!(last_error().contains("refused"), "{}", last_error());
        assert_eq!(taut_deactivate(h), TautError::Ok);
        assert_eq!(taut_update(h, 0.006, 0.002, &inp, &mut cmd), TautError::WrongState);
        assert_eq!(taut_cleanup(h), TautError::Ok);
    }
}

#[test]
fn plugin_owned_devices_that_cannot_come_up_fail_activate_which_can_be_retried() {
    let dir = tempfile::tempdir().unwrap();
    // The example names vcan0; this test makes sure the interface does not exist.
    let text = std::fs::read_to_string(CONFIG).unwrap().replace("interface = \"vcan0\"", "interface = \"taut-none0\"");
    let path = dir.path().join("robot.toml");
    std::fs::write(&path, text).unwrap();
    let cfg = CString::new(path.to_str().unwrap()).unwrap();
    let data = CString::new(dir.path().to_str().unwrap()).unwrap();
    let mut o = unsafe { std::mem::zeroed::<TautOptions>() };
    let mut h = null_mut();
    unsafe {
        taut_options_init(&mut o);
        o.devices = TAUT_DEVICES_PLUGIN;
        o.data_dir = data.as_ptr();
        assert_eq!(taut_configure(cfg.as_ptr(), TAUT_CONFIG_PATH, &o, &mut h), TautError::Ok, "{}", last_error());
        for _ in 0..2 {
            assert_eq!(taut_activate(h), TautError::Device);
            assert!(last_error().contains("taut-none0"), "{}", last_error());
        }
        let mut st = TautStatus::default();
        assert_eq!(taut_status(h, &mut st), TautError::Ok);
        assert_eq!(st.lifecycle, TautLifecycle::Inactive as u8);
        let inp = TautInputs::default();
        assert_eq!(taut_update(h, 0.0, 0.002, &inp, null_mut()), TautError::WrongState);
        assert_eq!(taut_cleanup(h), TautError::Ok);
    }
}

#[test]
fn motion_state_names_are_static_strings() {
    let name = |s: u8| unsafe { std::ffi::CStr::from_ptr(taut_motion_state_name(s)) }.to_str().unwrap();
    assert_eq!(name(0), "idle");
    assert_eq!(name(2), "init-phase");
    assert_eq!(name(5), "operate");
    assert_eq!(name(200), "unknown");
}
