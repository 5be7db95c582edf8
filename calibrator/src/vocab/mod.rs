//! The calibrator's vocabulary: what it is configured with ([`CalibratorConfig`]), what a
//! backend returns ([`Estimate`], through the [`Calibrate`] trait), what became of a run
//! ([`CalibrationOutcome`], [`OutcomeKind`], and in [`error`] why a set was refused), what it reports to
//! the operator ([`CalibStatus`]), how an excitation is split into training and held-out rows
//! ([`HeldoutBlocks`]) and where its samples and results may also go ([`RunOutputs`]).
//!
//! These are the types the operator's services, the plugin and the calibrator's own modules
//! share. This module imports nothing from the rest of the crate, so every other module depends
//! on it and it on none of them.

pub mod error;

pub use error::{BackendError, RecorderError, Rejection};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use taut_calib::design::Prediction;
use taut_config::params::ParamsFile;
use taut_config::recording::Recording;
use taut_rt::sample::Sample;
use taut_rt::{Geometry, Sigmas};

/// A parameter estimate from the calibration backend.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Anchors and encoder offsets, m.
    pub geometry: Geometry,
    /// 1-sigma of the anchors and offsets, m (NaN if unknown).
    pub sigma: Sigmas,
    /// Co-registration RMS on the data it was fitted to, m.
    pub rms_m: f64,
    /// False when the backend found the problem badly conditioned (with `note` saying why).
    pub observable: bool,
    /// Method and diagnostics, for people.
    pub note: String,
    /// The modelled effects' values (empty: the ideal model).
    pub effects: taut_config::params::Effects,
    /// Whether the held-out residual of the calibration is what the noise model predicts
    /// (`taut_calib::consistency`; `None`: not tested, e.g. an initial estimate or without a
    /// tracker). False does not refuse the set: the note says so and names `taut diagnose`.
    pub model_consistent: Option<bool>,
}

/// The calibration backend (`taut-calib` in the daemon; tests may use their own).
pub trait Calibrate: Send {
    /// Initial estimate from the three-phase recording (it has a `phase` column).
    fn initialise(&mut self, rec: &Recording) -> Result<Estimate, BackendError>;
    /// Calibration from an excitation recording, starting at `init`. The recording is the
    /// training part only: the daemon keeps its own held-out block.
    fn calibrate(&mut self, rec: &Recording, init: &Estimate) -> Result<Estimate, BackendError>;
}

/// Kind of calibration outcome.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutcomeKind {
    /// The initial estimate from the three phases.
    Initial,
    /// A calibration from an excitation run.
    Calibration,
}

/// What became of one calibration.
#[derive(Debug, Clone)]
pub struct CalibrationOutcome {
    /// Calibration run (0: start-up).
    pub run: u16,
    /// Initial estimate or calibration.
    pub kind: OutcomeKind,
    /// Published to the loop.
    pub accepted: bool,
    /// Why not (None when accepted).
    pub rejection: Option<Rejection>,
    /// The rejection's message, for people and the JSON status (empty when accepted).
    pub reason: String,
    /// Version written, when accepted.
    pub version: u64,
    /// The estimate, if the backend produced one.
    pub estimate: Option<Estimate>,
    /// Held-out RMS of the new set, m (NaN for the initial estimate), tracker outliers left out.
    pub heldout_rms_new_m: f64,
    /// Held-out RMS of the running set, m (over the same rows).
    pub heldout_rms_old_m: f64,
    /// Held-out rows left out of both RMS values and the test as tracker outliers
    /// ([`crate::heldout`]).
    pub heldout_outliers: usize,
    /// Held-out rows with a pose and a taut cable, outliers included (0 without a check, and
    /// for the held-out dwells without a tracker).
    pub heldout_rows: usize,
    /// Held-out RMS of the new and the running set with the outliers kept, m (NaN without a
    /// held-out check).
    pub heldout_rms_with_outliers_m: [f64; 2],
    /// Samples in the data set.
    pub samples: usize,
    /// Wild values found in the data set and excluded ([`taut_calib::screen`]), one line each.
    pub data_problems: Vec<String>,
}

/// The calibrator's progress, shared with the control thread (never with the loop).
#[derive(Debug, Clone, Default)]
pub struct CalibStatus {
    /// What it is doing: `waiting`, `collecting-init`, `initialising`, `collecting-excitation`,
    /// `calibrating`, `idle`.
    pub stage: String,
    /// Samples written to the recording.
    pub samples_recorded: u64,
    /// Samples in the data set being collected.
    pub dataset_samples: usize,
    /// The recording's path.
    pub recording: Option<PathBuf>,
    /// Every outcome so far, oldest first.
    pub outcomes: Vec<CalibrationOutcome>,
    /// The parameters in force (as written).
    pub current: Option<ParamsFile>,
    /// The newest recorder error (disk full...), if any.
    pub recorder_error: Option<RecorderError>,
    /// The start-up excitation and its predicted uncertainty.
    pub excitation: Option<ExcitationPlan>,
}

/// Shared handle on the calibrator's status.
pub type SharedCalibStatus = Arc<Mutex<CalibStatus>>;

/// What the calibrator needs from the configuration.
#[derive(Debug, Clone)]
pub struct CalibratorConfig {
    /// Robot name for parameter files.
    pub robot: String,
    /// Number of cables.
    pub n: usize,
    /// Platform points.
    pub platform: Vec<[f64; 3]>,
    /// The swivel-pulley axes, unit vectors (`[[cable]] pulley_axis`): the loop's inverse
    /// kinematics turns a modelled pulley about them.
    pub pulley_axis: Vec<[f64; 3]>,
    /// Nominal anchors, if configured (bounds for the initial estimate).
    pub nominal: Option<Vec<[f64; 3]>>,
    /// Data directory.
    pub data_dir: PathBuf,
    /// Every k-th sample goes into a data set.
    pub decimation: usize,
    /// Held-out fraction.
    pub heldout_fraction: f64,
    /// Loose threshold for the co-registration comparison, N.
    pub min_tension_n: f64,
    /// Validation bounds, m.
    pub max_anchor_change_m: f64,
    /// Validation bounds, m.
    pub max_l0_change_m: f64,
    /// Validation bounds, m.
    pub max_sigma_m: f64,
    /// How much higher the new set's held-out RMS may be (`daemon.heldout_tolerance_m`), m.
    pub heldout_tolerance_m: f64,
    /// Tracker age limit: older poses are recorded as missing, s.
    pub tracker_max_age_s: f64,
    /// Tension age limit: older tensions are recorded as missing, s.
    pub tension_max_age_s: f64,
    /// False for the start-up without a tracker (`motion.startup = "dwell"`): the data sets are
    /// the recorded dwells, and the held-out check is on held-out dwells
    /// ([`crate::notracker::heldout_dwells`]).
    pub tracker: bool,
    /// The excitation's predicted uncertainty (`crate::excite`), for the calibration's note.
    pub excitation: Option<ExcitationPlan>,
}

/// How the daemon splits an excitation recorded with a tracker into training and held-out rows.
///
/// The recording is cut into [`HeldoutBlocks::BLOCKS`] consecutive segments and the last
/// `heldout_fraction` of each is held out, so the held-out rows are spread over the whole path
/// like the training rows: a single block at the end could hold out one face of a designed
/// tour, and the check would compare the two sets on that face only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeldoutBlocks {
    rows: usize,
    fraction: f64,
}

impl HeldoutBlocks {
    /// Number of time blocks the held-out rows are spread over.
    pub const BLOCKS: usize = 8;

    /// The split of `rows` rows holding out `fraction` of them (`calibration.heldout_fraction`).
    pub fn new(rows: usize, fraction: f64) -> Self {
        HeldoutBlocks { rows, fraction: fraction.clamp(0.0, 1.0) }
    }

    fn segment(&self, b: usize) -> std::ops::Range<usize> {
        let (train, held) = taut_calib::design::heldout_block(self.rows, self.fraction, Self::BLOCKS, b);
        train.start..held.end
    }

    /// First held-out row of segment `b` (the excitation design counts the same rows).
    fn held_start(&self, b: usize) -> usize {
        taut_calib::design::heldout_block(self.rows, self.fraction, Self::BLOCKS, b).1.start
    }

    /// The training rows, as ranges in time order.
    pub fn training(&self) -> Vec<std::ops::Range<usize>> {
        (0..Self::BLOCKS).map(|b| self.segment(b).start..self.held_start(b)).filter(|r| !r.is_empty()).collect()
    }

    /// The held-out rows, as ranges in time order.
    pub fn heldout(&self) -> Vec<std::ops::Range<usize>> {
        (0..Self::BLOCKS).map(|b| self.held_start(b)..self.segment(b).end).filter(|r| !r.is_empty()).collect()
    }

    /// Where row `i` goes: `(true, k)` for the `k`-th held-out row, `(false, k)` for the `k`-th
    /// training row.
    pub fn part_of(&self, i: usize) -> (bool, usize) {
        let (mut train, mut held) = (0, 0);
        for b in 0..Self::BLOCKS {
            let (s, h) = (self.segment(b), self.held_start(b));
            if i < h {
                return (false, train + i - s.start);
            }
            if i < s.end {
                return (true, held + i - h);
            }
            train += h - s.start;
            held += s.end - h;
        }
        (true, held)
    }

    /// The training and the held-out recordings of `rec` (which has `rows` rows).
    pub fn split(&self, rec: &Recording) -> (Recording, Recording) {
        (rec.gather(&self.training()), rec.gather(&self.heldout()))
    }
}

/// What the start-up excitation will be, and the uncertainty it should leave.
#[derive(Debug, Clone, PartialEq)]
pub struct ExcitationPlan {
    /// The path: `"designed tour"` (a closed tour of waypoints chosen by [`taut_calib::design`])
    /// or `"lissajous"`.
    pub path: &'static str,
    /// Waypoints of the tour (0 for the Lissajous curve).
    pub waypoints: usize,
    /// The calibration's predicted uncertainty along the path (at the nominal geometry).
    pub predicted: Option<Prediction>,
    /// Why the designed path is not used (empty when it is).
    pub note: String,
}

impl ExcitationPlan {
    /// The predicted worst anchor 1-sigma, m (NaN without a prediction).
    pub fn predicted_worst_m(&self) -> f64 {
        self.predicted.as_ref().map_or(f64::NAN, Prediction::worst_anchor_sigma_m)
    }

    /// One line for people.
    pub fn summary(&self) -> String {
        let p = self.predicted_worst_m();
        let pred = if p.is_finite() { format!("predicted worst anchor 1-sigma {:.2} mm", p * 1e3) } else { "no prediction".into() };
        let mut s = format!("excitation: {} ({} waypoints), {pred}", self.path, self.waypoints);
        if !self.note.is_empty() {
            s.push_str(&format!(" ({})", self.note));
        }
        s
    }
}

/// Where the calibrator also sends every sample, published parameter set and stage (the MCAP
/// recording and the live telemetry, `taut_operator::channels::FrameSinks`). Called on the
/// calibrator thread.
pub trait RunOutputs: Send {
    /// A loop sample.
    fn sample(&mut self, s: &Sample);
    /// A published parameter set.
    fn params(&mut self, p: &ParamsFile);
    /// The calibrator's stage and sample count, and the newest outcome if there is one.
    fn calibrator(&mut self, stage: &str, samples: u64, outcome: Option<&CalibrationOutcome>);
    /// Called when the calibrator is idle: time to close a chunk that is due.
    fn tick(&mut self);
    /// The first write error since the last call, if any.
    fn take_error(&mut self) -> Option<std::io::Error>;
    /// Flushes and closes what was written.
    fn finish(&mut self);
}
