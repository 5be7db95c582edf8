//! The tension side in the running robot: a `taut-params v4` file with load-cell gains and
//! friction given to the daemon (`taut start --params`) on a site whose cells have those gains
//! and whose guides that friction. The daemon's fit leaves them alone (it has no force balance
//! to fit them on), every published estimate carries them to the loop, and the start-up
//! calibration's rewrite of the parameter file keeps the keys.

use taut_calibrator::calib_backend::TautCalib;
use taut_calibrator::vocab::OutcomeKind;
use taut_config::params::{Effects, ParamsFile};
use taut_sim::Physics;
use taut_simrig::{self as simrig, RunOptions, SimOptions};

#[test]
fn a_v4_file_with_gains_and_friction_survives_the_calibrations_rewrite() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = taut_tests::startup::sim_robot(dir.path());
    let n = cfg.cables.len();
    let gains: Vec<f64> = (0..n).map(|j| [1.03, 0.98, 1.01, 0.97][j % 4]).collect();
    let mu_theta = 0.1;
    let effects = Effects {
        loadcell_gain: Some(gains.clone()),
        loadcell_gain_sigma: Some(vec![0.002; n]),
        friction_mu_theta: Some(vec![mu_theta; n]),
        friction_mu_theta_sigma: Some(vec![0.01; n]),
        ..Effects::default()
    };
    let geometry = taut_calib::Geometry { anchors: cfg.anchors().unwrap(), l0: vec![0.0; n] };
    let file = ParamsFile { version: 1, effects: effects.clone(), ..ParamsFile::from_geometry(&geometry, &taut_calib::Sigmas::unknown(n)) };
    // As `taut start --params` reads it.
    let file = ParamsFile::parse(std::path::Path::new("given.toml"), &file.to_text().unwrap()).unwrap();
    let calib = TautCalib::from_config(&cfg).with_params(&file);
    assert!(calib.effects().is_empty(), "nothing to fit: {:?}", calib.effects());

    let physics = Physics { loadcell_gain: Some(gains), friction_mu_theta: Some(mu_theta), ..Physics::default() };
    let so = SimOptions { seed: 1, physics, ..Default::default() };
    let run = simrig::run_startup(
        &cfg,
        taut_tests::startup::rest_p0(&cfg, &so),
        &so,
        RunOptions { recording: taut_plugin::RecordingPath::Default, ..Default::default() },
        Box::new(calib),
        |_, _| false,
    )
    .unwrap();
    let (l, c) = (&run.loop_status, &run.calib_status);
    assert!(run.finished && l.snap.fault.is_none(), "start-up: state {:?}, fault {:?}, stage {}", l.snap.state, l.snap.fault, c.stage);
    for kind in [OutcomeKind::Initial, OutcomeKind::Calibration] {
        let o = c.outcomes.iter().find(|o| o.kind == kind && o.accepted).unwrap_or_else(|| panic!("{kind:?} accepted: {:?}", c.outcomes));
        let est = o.estimate.as_ref().unwrap();
        assert_eq!(
            (&est.effects.loadcell_gain, &est.effects.friction_mu_theta),
            (&effects.loadcell_gain, &effects.friction_mu_theta),
            "{kind:?}"
        );
    }
    let current = ParamsFile::load(dir.path().join("data/params/current.toml")).unwrap();
    assert_eq!(current.format, taut_config::params::FORMAT);
    assert!(current.version > file.version);
    for (got, want) in [
        (&current.effects.loadcell_gain, &effects.loadcell_gain),
        (&current.effects.loadcell_gain_sigma, &effects.loadcell_gain_sigma),
        (&current.effects.friction_mu_theta, &effects.friction_mu_theta),
        (&current.effects.friction_mu_theta_sigma, &effects.friction_mu_theta_sigma),
    ] {
        assert_eq!(got, want);
    }
}
