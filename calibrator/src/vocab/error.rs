//! The calibrator side's errors, typed: why a calibration backend gave no estimate
//! ([`BackendError`]), why the daemon did not publish an outcome ([`Rejection`]) and what went
//! wrong with the recording ([`RecorderError`]).
//!
//! They live on the calibrator thread and the control side, never in the loop, so they may carry
//! owned context (a file, a note). Each displays the message people read in `taut ctl status`,
//! the calibration notes and the telemetry; callers that react match on the variant instead.
//! Outcomes are shared as clones, so the wrapped I/O errors are reference-counted.

use crate::vocab::OutcomeKind;
use std::fmt;
use std::path::PathBuf;
use std::sync::Arc;
use taut_calib::effect_fit::EffectFitError;
use taut_calib::init::InitError;
use taut_calib::selfcal::rest::RestError;
use taut_calib::selfcal::SelfCalError;
use taut_calib::trust::Untrusted;
use taut_calib::{CalibError, Termination};
use taut_rt::motion::State;

/// Why a calibration backend ([`crate::vocab::Calibrate`]) gave no estimate.
#[derive(Debug, Clone)]
pub enum BackendError {
    /// The initial estimate from the three phases failed.
    Init(InitError),
    /// The force-aware calibration failed.
    Calib(CalibError),
    /// The calibration's solver stopped without converging.
    NotConverged(Termination),
    /// Without a tracker: no rest estimate from the force balance.
    Rest(RestError),
    /// Without a tracker: the self-calibration on the dwells failed (also: no nominal anchors).
    SelfCal(SelfCalError),
    /// The fit of anchors, offsets and effects together failed.
    EffectFit(EffectFitError),
    /// The fit with effects gave an effect outside its physical range.
    EffectOutOfRange {
        /// The parameter file's key (`ea_n`, `pulley_radius_m`, ...).
        key: String,
        /// What is wrong with its value.
        message: String,
    },
    /// The result is not a set the robot can run on (non-finite, absurd).
    Untrusted(Untrusted),
    /// The backend panicked in `initialise` (Initial) or `calibrate` (Calibration).
    Panicked(OutcomeKind),
    /// Another backend's own error.
    Other(Arc<dyn std::error::Error + Send + Sync>),
}

impl fmt::Display for BackendError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BackendError::Init(e) => e.fmt(f),
            BackendError::Calib(e) => e.fmt(f),
            BackendError::NotConverged(t) => write!(f, "the solver did not converge ({t:?})"),
            BackendError::Rest(e) => e.fmt(f),
            BackendError::SelfCal(e) => e.fmt(f),
            BackendError::EffectFit(e) => write!(f, "the fit with effects failed: {e}"),
            BackendError::EffectOutOfRange { key, message } => write!(f, "the fit with effects gave {key}: {message}"),
            BackendError::Untrusted(e) => e.fmt(f),
            BackendError::Panicked(OutcomeKind::Initial) => f.write_str("the initialisation panicked"),
            BackendError::Panicked(OutcomeKind::Calibration) => f.write_str("the calibration panicked"),
            BackendError::Other(e) => e.fmt(f),
        }
    }
}

impl std::error::Error for BackendError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            BackendError::Init(e) => Some(e),
            BackendError::Calib(e) => Some(e),
            BackendError::Rest(e) => Some(e),
            BackendError::SelfCal(e) => Some(e),
            BackendError::EffectFit(e) => Some(e),
            BackendError::Untrusted(e) => Some(e),
            BackendError::Other(e) => Some(e.as_ref()),
            BackendError::NotConverged(_) | BackendError::EffectOutOfRange { .. } | BackendError::Panicked(_) => None,
        }
    }
}

impl From<InitError> for BackendError {
    fn from(e: InitError) -> Self {
        BackendError::Init(e)
    }
}

impl From<CalibError> for BackendError {
    fn from(e: CalibError) -> Self {
        BackendError::Calib(e)
    }
}

impl From<RestError> for BackendError {
    fn from(e: RestError) -> Self {
        BackendError::Rest(e)
    }
}

impl From<SelfCalError> for BackendError {
    fn from(e: SelfCalError) -> Self {
        BackendError::SelfCal(e)
    }
}

impl From<EffectFitError> for BackendError {
    fn from(e: EffectFitError) -> Self {
        BackendError::EffectFit(e)
    }
}

impl From<Untrusted> for BackendError {
    fn from(e: Untrusted) -> Self {
        BackendError::Untrusted(e)
    }
}

/// Why a calibration outcome was not published to the loop (the running parameters stay).
/// The first group says why there was no estimate; the rest are the acceptance rules of
/// [`crate::calibrator`], each naming the value and the configuration key that decided.
#[derive(Debug, Clone)]
pub enum Rejection {
    /// The backend gave no estimate.
    Failed(BackendError),
    /// The loop left the initialisation (Initial) or the excitation (Calibration) before its end.
    Interrupted {
        /// Which data set was being collected.
        kind: OutcomeKind,
        /// The state the loop went to (faulted, stopped).
        state: State,
    },
    /// An excitation ended with no running parameters to start a calibration from.
    NoRunningParameters,
    /// A data set was complete while the backend was still busy with the previous one.
    Busy,
    /// The accepted set could not be written to the parameter directory (never run parameters
    /// that a restart would not find).
    Write {
        /// The parameter directory.
        dir: PathBuf,
        /// The error.
        error: Arc<std::io::Error>,
    },
    /// The estimate's size does not match the robot.
    CableCount {
        /// Anchors in the estimate.
        anchors: usize,
        /// Offsets in the estimate.
        offsets: usize,
        /// Cables of the robot.
        cables: usize,
    },
    /// An anchor or offset is not a finite number.
    NonFinite,
    /// The loop cannot hold the set (platform points of another count, more cables than the
    /// loop supports, or a geometry its check refuses).
    LoopCannotHold(taut_rt::GeometryError),
    /// An infinite 1-sigma or RMS although the backend called the problem observable.
    InfiniteUncertainty,
    /// An anchor moved further than is plausible from the reference (the nominal anchors for the
    /// initial estimate, with twice `daemon.max_anchor_change_m`; the running set after).
    AnchorMoved {
        /// Cable.
        cable: usize,
        /// Distance moved, m.
        moved_m: f64,
        /// The bound, m.
        bound_m: f64,
    },
    /// An offset changed by more than `daemon.max_l0_change_m` from the running set.
    OffsetChanged {
        /// Cable.
        cable: usize,
        /// Change, m.
        changed_m: f64,
        /// `daemon.max_l0_change_m`, m.
        bound_m: f64,
    },
    /// The backend found the problem badly conditioned; its note says why.
    NotObservable {
        /// The backend's note.
        note: String,
    },
    /// A 1-sigma above `daemon.max_sigma_m`.
    SigmaTooLarge {
        /// The largest 1-sigma (infinite when one is unknown), m.
        worst_m: f64,
        /// `daemon.max_sigma_m`, m.
        max_m: f64,
    },
    /// No held-out block to check the new set on.
    NoHeldout,
    /// With a tracker: the new set's held-out co-registration RMS is significantly higher than
    /// the running set's (paired test on the same readings).
    HeldoutWorse {
        /// New set, m.
        new_m: f64,
        /// Running set, m.
        old_m: f64,
        /// The tolerance it exceeds (`daemon.heldout_tolerance_m`), m.
        tolerance_m: f64,
        /// Held-out rows left out of both as tracker outliers.
        outliers: usize,
    },
    /// With a tracker: no held-out row with a pose and taut cables.
    NoUsableHeldout,
    /// Without a tracker: fewer than two held-out dwells with four taut cables.
    TooFewHeldoutDwells {
        /// Usable held-out dwells.
        usable: usize,
    },
    /// Without a tracker: the new set's length closure RMS on the held-out dwells is
    /// significantly higher than the running set's.
    HeldoutDwellsWorse {
        /// Held-out dwells compared.
        dwells: usize,
        /// New set, m.
        new_m: f64,
        /// Running set, m.
        old_m: f64,
        /// The tolerance it exceeds (`daemon.heldout_tolerance_m`), m.
        tolerance_m: f64,
    },
}

impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Rejection::Failed(e) => write!(f, "the calibration failed: {e}"),
            Rejection::Interrupted { kind, state } => write!(
                f,
                "{} interrupted: the loop went to {}",
                match kind {
                    OutcomeKind::Initial => "initialisation",
                    OutcomeKind::Calibration => "excitation",
                },
                state.name()
            ),
            Rejection::NoRunningParameters => f.write_str("no running parameters to start from"),
            Rejection::Busy => f.write_str("a calibration is already running"),
            Rejection::Write { dir, error } => write!(f, "cannot write {}: {error}", dir.display()),
            Rejection::CableCount { anchors, offsets, cables } => write!(f, "{anchors} anchors and {offsets} offsets for {cables} cables"),
            Rejection::NonFinite => f.write_str("non-finite parameters"),
            Rejection::LoopCannotHold(e) => write!(f, "the loop cannot take these parameters: {e}"),
            Rejection::InfiniteUncertainty => f.write_str("infinite uncertainty or RMS: the statistics broke down"),
            Rejection::AnchorMoved { cable, moved_m, bound_m } => {
                write!(f, "anchor {cable} moved {moved_m:.3} m, more than the plausible {bound_m:.3} m (daemon.max_anchor_change_m)")
            }
            Rejection::OffsetChanged { cable, changed_m, bound_m } => {
                write!(f, "offset {cable} changed {changed_m:.3} m, more than daemon.max_l0_change_m = {bound_m:.3} m")
            }
            Rejection::NotObservable { note } => write!(f, "observability: {note}"),
            Rejection::SigmaTooLarge { worst_m, max_m } => write!(f, "1-sigma up to {worst_m:.4} m, above daemon.max_sigma_m = {max_m} m"),
            Rejection::NoHeldout => f.write_str("no held-out data"),
            Rejection::HeldoutWorse { new_m, old_m, tolerance_m, outliers } => write!(
                f,
                "held-out co-registration RMS {:.2} mm is higher than the running parameters' {:.2} mm by more than {:.2} mm \
                 (daemon.heldout_tolerance_m) at 99.9 % confidence ({outliers} held-out rows left out as tracker outliers)",
                new_m * 1e3,
                old_m * 1e3,
                tolerance_m * 1e3
            ),
            Rejection::NoUsableHeldout => f.write_str("no usable held-out samples (tracker or taut cables missing)"),
            Rejection::TooFewHeldoutDwells { usable } => {
                write!(f, "only {usable} usable held-out dwells (at least 2 with four taut cables needed)")
            }
            Rejection::HeldoutDwellsWorse { dwells, new_m, old_m, tolerance_m } => write!(
                f,
                "held-out dwells ({dwells}): length closure RMS {:.3} mm is higher than the running parameters' {:.3} mm by more \
                 than {:.3} mm (daemon.heldout_tolerance_m) at 99.9 % confidence",
                new_m * 1e3,
                old_m * 1e3,
                tolerance_m * 1e3
            ),
        }
    }
}

impl std::error::Error for Rejection {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Rejection::Failed(e) => Some(e),
            Rejection::Write { error, .. } => Some(error.as_ref()),
            _ => None,
        }
    }
}

impl From<BackendError> for Rejection {
    fn from(e: BackendError) -> Self {
        Rejection::Failed(e)
    }
}

/// A failed write of the run's recording. The calibrator keeps running (the loop never waits
/// for the disk); the newest error is shown in the status.
#[derive(Debug, Clone)]
pub enum RecorderError {
    /// The CSV recording (`cdpr-recording v1`).
    Csv {
        /// The file.
        path: PathBuf,
        /// The error (disk full, ...).
        error: Arc<std::io::Error>,
    },
    /// The MCAP recording (its first error).
    Mcap(Arc<std::io::Error>),
}

impl fmt::Display for RecorderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RecorderError::Csv { path, error } => write!(f, "recording {}: {error}", path.display()),
            RecorderError::Mcap(e) => write!(f, "MCAP recording: {e}"),
        }
    }
}

impl std::error::Error for RecorderError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            RecorderError::Csv { error, .. } | RecorderError::Mcap(error) => Some(error.as_ref()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrator::evaluate;
    use crate::vocab::{Calibrate, CalibratorConfig, Estimate};
    use std::error::Error as _;
    use taut_config::recording::Recording;
    use taut_rt::kin::LoopParams;

    type Answer = Box<dyn FnMut(&Estimate) -> Result<Estimate, BackendError> + Send>;

    /// A backend whose calibration answers what the test says (from the running estimate).
    struct Fixed(Answer);

    impl Calibrate for Fixed {
        fn initialise(&mut self, _: &Recording) -> Result<Estimate, BackendError> {
            unreachable!("evaluate only calibrates")
        }
        fn calibrate(&mut self, _: &Recording, init: &Estimate) -> Result<Estimate, BackendError> {
            (self.0)(init)
        }
    }

    /// The daemon's checks with a tracker, the running estimate at the truth, and an excitation
    /// of 600 tracked poses (1 mm tracker noise) with every cable taut.
    fn setup() -> (CalibratorConfig, Recording, Estimate, LoopParams) {
        let cfg = taut_io::testkit::quick_config(4, &std::env::temp_dir());
        let mut c = CalibratorConfig::from_robot(&cfg);
        c.tracker = true;
        let anchors = taut_io::testkit::nominal_anchors(4);
        let l0 = vec![0.01, -0.02, 0.03, 0.0];
        let truth = LoopParams::new(1, &anchors, &l0, &c.platform);
        let mut rec = Recording::with_capacity(4, 600, true, false, false);
        let mut rng = taut_calib::synth::Rng::new(11);
        for i in 0..600 {
            let p = [rng.range(-1.5, 1.5), rng.range(-0.8, 0.8), rng.range(1.0, 2.5)];
            let l: Vec<f64> = (0..4).map(|j| truth.length(j, &p)).collect();
            let m = [p[0] + 1e-3 * rng.normal(), p[1] + 1e-3 * rng.normal(), p[2] + 1e-3 * rng.normal()];
            rec.push(f64::from(i) * 0.01, m, None, &l, Some(&[50.0; 4]), None);
        }
        let est = Estimate {
            model_consistent: None,
            geometry: taut_rt::Geometry { anchors, l0 },
            sigma: taut_rt::Sigmas { anchors: vec![[1e-4; 3]; 4], l0: vec![1e-4; 4] },
            rms_m: 1e-3,
            observable: true,
            note: "truth".into(),
            effects: Default::default(),
        };
        (c, rec, est, truth)
    }

    fn outcome(answer: Answer) -> crate::vocab::CalibrationOutcome {
        let (c, rec, est, truth) = setup();
        evaluate(&c, &mut Fixed(answer), &rec, &est, truth)
    }

    #[test]
    fn the_truth_is_accepted_without_a_rejection() {
        let o = outcome(Box::new(|init| Ok(init.clone())));
        assert!(o.accepted && o.rejection.is_none() && o.reason.is_empty(), "{}", o.reason);
    }

    #[test]
    fn a_backend_error_keeps_its_cause() {
        let o = outcome(Box::new(|_| Err(BackendError::Other(Arc::new(std::io::Error::other("disk on fire"))))));
        let r = o.rejection.as_ref().expect("rejected");
        assert!(matches!(r, Rejection::Failed(BackendError::Other(_))), "{r:?}");
        assert_eq!(o.reason, "the calibration failed: disk on fire");
        // Rejection -> BackendError -> the backend's own error.
        let inner = r.source().and_then(|e| e.source()).expect("a chain of two");
        assert_eq!(inner.to_string(), "disk on fire");
        assert!(!o.accepted && o.estimate.is_none());
    }

    #[test]
    fn a_panicking_backend_is_a_typed_failure() {
        let o = outcome(Box::new(|_| panic!("a bug in the backend")));
        assert!(matches!(o.rejection, Some(Rejection::Failed(BackendError::Panicked(OutcomeKind::Calibration)))), "{:?}", o.rejection);
        assert_eq!(o.reason, "the calibration failed: the calibration panicked");
    }

    #[test]
    fn the_acceptance_rules_name_cable_and_key() {
        let o = outcome(Box::new(|init| {
            let mut e = init.clone();
            e.geometry.anchors[2][1] += 1.0;
            Ok(e)
        }));
        match o.rejection {
            Some(Rejection::AnchorMoved { cable: 2, moved_m, bound_m }) => {
                assert!((moved_m - 1.0).abs() < 1e-12 && (bound_m - 0.5).abs() < 1e-12, "{moved_m} {bound_m}")
            }
            ref r => panic!("{r:?}"),
        }
        assert_eq!(o.reason, "anchor 2 moved 1.000 m, more than the plausible 0.500 m (daemon.max_anchor_change_m)");
        assert!(o.estimate.is_some(), "the refused estimate is kept for the status");

        let o = outcome(Box::new(|init| {
            let mut e = init.clone();
            e.geometry.l0[1] = f64::NAN;
            Ok(e)
        }));
        assert!(matches!(o.rejection, Some(Rejection::NonFinite)), "{:?}", o.rejection);

        let o = outcome(Box::new(|init| {
            let mut e = init.clone();
            e.sigma.anchors[3][0] = 0.2;
            Ok(e)
        }));
        assert!(matches!(o.rejection, Some(Rejection::SigmaTooLarge { .. })), "{:?}", o.rejection);
        assert!(o.reason.contains("daemon.max_sigma_m"), "{}", o.reason);
    }

    #[test]
    fn a_worse_set_is_refused_on_the_heldout_block() {
        // 2 cm off on one anchor: within the plausible change, far outside the tracker's noise.
        let o = outcome(Box::new(|init| {
            let mut e = init.clone();
            e.geometry.anchors[0][0] += 0.02;
            Ok(e)
        }));
        match o.rejection {
            Some(Rejection::HeldoutWorse { new_m, old_m, .. }) => assert!(new_m > 2.0 * old_m, "{new_m} {old_m}"),
            ref r => panic!("{r:?}"),
        }
        assert!(o.reason.starts_with("held-out co-registration RMS") && o.reason.contains("daemon.heldout_tolerance_m"), "{}", o.reason);
    }

    #[test]
    fn messages_are_those_people_read() {
        let e = Rejection::Interrupted { kind: OutcomeKind::Initial, state: State::Faulted };
        assert_eq!(e.to_string(), format!("initialisation interrupted: the loop went to {}", State::Faulted.name()));
        let e = Rejection::Interrupted { kind: OutcomeKind::Calibration, state: State::Stopped };
        assert!(e.to_string().starts_with("excitation interrupted"));
        let e = Rejection::OffsetChanged { cable: 1, changed_m: 0.25, bound_m: 0.1 };
        assert_eq!(e.to_string(), "offset 1 changed 0.250 m, more than daemon.max_l0_change_m = 0.100 m");
        let e = RecorderError::Csv { path: "/data/run.csv".into(), error: Arc::new(std::io::Error::other("no space left")) };
        assert_eq!(e.to_string(), "recording /data/run.csv: no space left");
        assert_eq!(e.source().map(|s| s.to_string()).as_deref(), Some("no space left"));
    }
}
