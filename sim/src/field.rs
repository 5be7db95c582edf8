//! Recordings shaped like a real robot's logger makes them: short, slow, irregularly sampled,
//! with stale rows, a 6-DoF platform and no tensions.
//!
//! The physics is the scenario's ([`crate::simulate`] on a fine time grid); only the sampling is
//! the logger's:
//!
//! - rows at about `rate_hz`, each interval drawn uniformly in `(1 +- jitter) / rate_hz` and
//!   snapped to the fine grid (`grid_hz`);
//! - a fraction `stale_fraction` of the rows are **stale**: the logger wrote the new tracker pose
//!   but repeated the previous row's encoder readings (every cable), as a logger does whose
//!   encoder values arrive later than its tracker's;
//! - the platform's orientation is recorded (quaternion columns) and its attachment points are
//!   off its centre (6-DoF), no tension columns, no phase column.
//!
//! A time offset (`physics.time_offset_s`) is applied by the simulator in continuous time, so it
//! need not be a multiple of the grid.

use rand::Rng;
use taut_config::recording::Recording;
use taut_config::RobotConfig;

use crate::scenario::{try_simulate, Scenario, SimRun};
use crate::{rng, SimError};

/// Random stream of the logger's sampling (row times, stale rows).
const STREAM_LOGGER: u64 = 7;

/// How the logger samples the robot.
#[derive(Debug, Clone, PartialEq)]
pub struct Logger {
    /// Rows in the recording.
    pub rows: usize,
    /// Mean row rate, Hz.
    pub rate_hz: f64,
    /// Each interval is uniform in `(1 - jitter, 1 + jitter) / rate_hz` (0: regular).
    pub jitter: f64,
    /// Fraction of rows whose encoder readings repeat the previous row's.
    pub stale_fraction: f64,
    /// The simulation's fine time grid, Hz: row times are multiples of its interval.
    pub grid_hz: f64,
}

impl Default for Logger {
    /// The shape of a real 4-cable field recording: 1,000 rows at about 4 Hz, intervals
    /// 0.5-1.5 x the mean, 9 % stale rows, times on a 50 Hz grid.
    fn default() -> Self {
        Logger { rows: 1000, rate_hz: 4.0, jitter: 0.5, stale_fraction: 0.09, grid_hz: 50.0 }
    }
}

/// A logger's recording and what it hides.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldRun {
    /// The recording as the logger wrote it.
    pub recording: Recording,
    /// The fine-grid simulation it was sampled from (truth, true poses).
    pub sim: SimRun,
    /// Per row: the grid sample it was taken at.
    pub grid_rows: Vec<usize>,
    /// Per row: its encoder readings are the previous row's (stale).
    pub stale: Vec<bool>,
}

/// A 4-cable robot with a 6-DoF platform: anchors at the top corners of a 4 m x 3 m x 3 m
/// frame, a 5 kg platform whose attachment points are the corners of a 0.3 m x 0.2 m plate.
pub fn field_robot() -> RobotConfig {
    let anchors = [[2.0, -1.5, 3.0], [2.0, 1.5, 3.0], [-2.0, 1.5, 3.0], [-2.0, -1.5, 3.0]];
    let points = [[0.15, -0.1, 0.0], [0.15, 0.1, 0.0], [-0.15, 0.1, 0.0], [-0.15, -0.1, 0.0]];
    let mut cfg = RobotConfig::point_mass(4);
    cfg.robot.name = "field-4".into();
    cfg.robot.mass_kg = 5.0;
    for ((c, a), b) in cfg.cables.iter_mut().zip(anchors).zip(points) {
        c.anchor = Some(a);
        c.platform_point = b;
    }
    cfg
}

/// The scenario of a field recording: [`field_robot`], no initialisation motion, no loose
/// excursions, the platform's orientation recorded, no tensions; the excitation long enough for
/// `logger` (with a margin for the jitter).
pub fn field_scenario(seed: u64, logger: &Logger) -> Scenario {
    let mut s = Scenario::aras_cam(seed);
    s.robot = field_robot();
    s.three_phase = None;
    s.loose_fraction = 0.0;
    s.site_error_m = 0.05;
    s.with_tensions = false;
    s.with_orientation = true;
    s.rate_hz = logger.grid_hz;
    s.duration_s = (logger.rows as f64 + 2.0) * (1.0 + logger.jitter) / logger.rate_hz;
    s
}

/// Simulates `s` on its grid (`s.rate_hz`, which must be `logger.grid_hz`) and samples it as
/// `logger` does (seeded by `s.seed`).
pub fn try_field_recording(s: &Scenario, logger: &Logger) -> Result<FieldRun, SimError> {
    let valid = logger.rate_hz > 0.0
        && logger.grid_hz >= logger.rate_hz
        && (0.0..1.0).contains(&logger.jitter)
        && (0.0..1.0).contains(&logger.stale_fraction);
    if !valid || logger.rows < 2 || (s.rate_hz - logger.grid_hz).abs() > 1e-9 * logger.grid_hz {
        return Err(SimError::BadScenario(
            "logger: rows >= 2, 0 < rate_hz <= grid_hz = the scenario's rate_hz, jitter and stale_fraction in [0, 1)",
        ));
    }
    let sim = try_simulate(s)?;
    let fine = &sim.recording;
    let n = fine.n_cables;
    let mut r = rng(s.seed, STREAM_LOGGER);
    let step = logger.grid_hz / logger.rate_hz;
    let mut grid_rows = Vec::with_capacity(logger.rows);
    let mut at = 0.0f64;
    while grid_rows.len() < logger.rows {
        let k = at.round() as usize;
        if k >= fine.len() {
            return Err(SimError::BadScenario("logger: the simulation is too short for the rows asked"));
        }
        if grid_rows.last() != Some(&k) {
            grid_rows.push(k);
        }
        at += step * r.gen_range(1.0 - logger.jitter..=1.0 + logger.jitter);
    }
    let mut rec = Recording::with_capacity(n, logger.rows, false, true, false);
    rec.comments.push(format!(
        " simulated by taut-sim and sampled as a logger: robot {}, seed {}, {} rows at ~{} Hz (intervals +-{:.0} %), {:.0} % stale rows",
        s.robot.robot.name,
        s.seed,
        logger.rows,
        logger.rate_hz,
        100.0 * logger.jitter,
        100.0 * logger.stale_fraction
    ));
    let mut stale = Vec::with_capacity(logger.rows);
    let mut l = vec![0.0; n];
    for (i, &k) in grid_rows.iter().enumerate() {
        let is_stale = i > 0 && r.gen_bool(logger.stale_fraction);
        if !is_stale {
            l.copy_from_slice(fine.lengths(k));
        }
        stale.push(is_stale);
        let q = fine.q.as_ref().map(|q| q[k]);
        rec.push(fine.t[k], fine.p[k], q, &l, None, None);
    }
    Ok(FieldRun { recording: rec, sim, grid_rows, stale })
}

/// [`try_field_recording`] of [`field_scenario`] with `physics`.
///
/// # Panics
/// If it cannot be simulated (the message says why).
pub fn field_recording(seed: u64, physics: crate::Physics, logger: &Logger) -> FieldRun {
    let mut s = field_scenario(seed, logger);
    s.physics = physics;
    try_field_recording(&s, logger).unwrap_or_else(|e| panic!("field recording seed {seed}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The logger's shape: rows, mean rate, irregular intervals, stale rows that repeat every
    /// encoder while the tracker moves, orientation columns, no tensions; the same seed gives
    /// the same recording.
    #[test]
    fn a_field_recording_has_the_loggers_shape() {
        let logger = Logger { rows: 400, ..Logger::default() };
        let run = field_recording(3, crate::Physics::ideal(), &logger);
        let rec = &run.recording;
        assert_eq!(rec.len(), 400);
        assert!(rec.f.is_none() && rec.phase.is_none() && rec.q.is_some());
        let dts: Vec<f64> = rec.t.windows(2).map(|w| w[1] - w[0]).collect();
        let mean = dts.iter().sum::<f64>() / dts.len() as f64;
        assert!((mean - 0.25).abs() < 0.02, "mean interval {mean}");
        let (lo, hi) = dts.iter().fold((f64::MAX, 0.0f64), |(a, b), &d| (a.min(d), b.max(d)));
        assert!(lo < 0.16 && hi > 0.34, "intervals {lo}-{hi} s");
        let k = run.stale.iter().filter(|&&s| s).count();
        assert!((20..=55).contains(&k), "{k} stale rows of 400");
        for i in 1..rec.len() {
            assert_eq!(run.stale[i], rec.lengths(i) == rec.lengths(i - 1), "row {i}");
        }
        // (Debug text: the tracker's dropouts are NaN, which `==` never matches.)
        let again = field_recording(3, crate::Physics::ideal(), &logger);
        assert!(format!("{run:?}") == format!("{again:?}"), "the same seed gave another recording");
    }
}
