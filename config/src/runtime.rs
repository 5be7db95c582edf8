//! Runtime sections of the robot configuration, read by `taut start`: the real-time loop (`[rt]`),
//! the guided start-up motion (`[motion]`), the safety limits (`[safety]`) and the daemon
//! (`[daemon]`). Every table and every key is optional; the defaults suit the example robots.
//!
//! ```toml
//! [rt]
//! rate_hz = 500            # loop rate; 1000 works
//! priority = 80            # SCHED_FIFO priority (1..=99); needs LimitRTPRIO or CAP_SYS_NICE
//! cpu = 1                  # optional: pin the loop thread to this CPU
//! lock_memory = true       # mlockall(MCL_CURRENT | MCL_FUTURE)
//!
//! [motion]
//! init_reel_m = -0.5       # each phase reels its cable in by 0.5 m, then back out
//! init_reel_speed_m_s = 0.05
//! excitation_s = 60
//! workspace_min_m = [-1.5, -0.8, 1.0]
//! workspace_max_m = [1.5, 0.8, 2.5]
//!
//! [safety]
//! max_tension_n = 400
//!
//! [daemon]
//! socket = "/run/taut/taut.sock"
//! data_dir = "/var/lib/taut"
//! ```
//!
//! Each `validate` returns `(key, message)` for the first bad field; [`crate::RobotConfig`] adds the
//! file, the line and the table name.

use serde::{Deserialize, Serialize};

/// The `[rt]` table: the real-time loop thread.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RtConfig {
    /// Loop rate, Hz.
    pub rate_hz: f64,
    /// `SCHED_FIFO` priority of the loop thread, 1..=99; 0 keeps the normal scheduler.
    pub priority: i32,
    /// CPU to pin the loop thread to (optional).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cpu: Option<usize>,
    /// Lock all memory (`mlockall`) before the loop starts.
    pub lock_memory: bool,
    /// Capacity of the sample ring buffer (loop -> calibrator), samples.
    pub ring_capacity: usize,
    /// Capacity of the command queue (control -> loop), commands.
    pub command_capacity: usize,
}

impl Default for RtConfig {
    fn default() -> Self {
        RtConfig { rate_hz: 500.0, priority: 80, cpu: None, lock_memory: true, ring_capacity: 16_384, command_capacity: 64 }
    }
}

impl RtConfig {
    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if !(self.rate_hz.is_finite() && (1.0..=10_000.0).contains(&self.rate_hz)) {
            return Err(("rate_hz".into(), format!("must be a loop rate in 1..=10000 Hz, got {}", self.rate_hz)));
        }
        if !(0..=99).contains(&self.priority) {
            return Err((
                "priority".into(),
                format!("must be a SCHED_FIFO priority in 1..=99 (0: normal scheduler), got {}", self.priority),
            ));
        }
        if self.ring_capacity < 16 {
            return Err(("ring_capacity".into(), format!("must be at least 16 samples, got {}", self.ring_capacity)));
        }
        if self.command_capacity == 0 {
            return Err(("command_capacity".into(), "must be at least 1".into()));
        }
        Ok(())
    }
}

/// The `[motion]` table: the guided start-up motion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionConfig {
    /// Longest wait for all drives to reach "operation enabled", s.
    pub enable_timeout_s: f64,
    /// The three initialisation phases, each `[held_a, held_b, reeled]` (cable indices). Every
    /// other cable follows in torque mode.
    #[serde(deserialize_with = "crate::exact::triples")]
    pub init_phases: Vec<[usize; 3]>,
    /// Length by which the reeled cable's commanded length changes in a phase, m (negative: reel
    /// in). The cable then returns to where it started.
    pub init_reel_m: f64,
    /// Speed of the reeled cable, m/s.
    pub init_reel_speed_m_s: f64,
    /// Acceleration of the reeled cable at the start and end of its reel, m/s² (a trapezoidal
    /// speed profile). A swinging platform on elastic cables needs it: a step in speed jerks the
    /// platform and the followers go slack.
    pub init_reel_accel_m_s2: f64,
    /// Tension of the follower cables during the phases (torque mode), N.
    pub init_follower_tension_n: f64,
    /// Pause between phases with every cable held, s.
    pub init_settle_s: f64,
    /// The initialisation phases check the wiring (default): the encoders' changes against
    /// the tracked motion and the load cells against the statics, with the nominal anchors; a
    /// swapped drive or load cell or an inverted encoder stops the robot with the cause named
    /// (`taut_rt::wiring`). Needs nominal anchors. `false`: not checked (a stand-in robot
    /// whose load cells do not measure the cables).
    pub init_wiring_check: bool,
    /// Duration of the excitation trajectory, s.
    pub excitation_s: f64,
    /// Largest speed of the platform on the excitation trajectory, m/s.
    pub excitation_speed_m_s: f64,
    /// Lower corner of the workspace box, m, tracker frame. Default: derived from the nominal
    /// anchors (middle half of their footprint, 1 m to 3 m below them).
    #[serde(skip_serializing_if = "Option::is_none", deserialize_with = "crate::exact::opt_three")]
    pub workspace_min_m: Option<[f64; 3]>,
    /// Upper corner of the workspace box, m.
    #[serde(skip_serializing_if = "Option::is_none", deserialize_with = "crate::exact::opt_three")]
    pub workspace_max_m: Option<[f64; 3]>,
    /// Time over which a change of the commanded lengths caused by new parameters is ramped in, s.
    pub swap_ramp_s: f64,
    /// Speed of operator moves, m/s.
    pub move_speed_m_s: f64,
    /// The start-up routine: `"three-phase"` (the guided phases and an excitation, needs the
    /// tracker) or `"dwell"` (dwell poses chosen from the nominal geometry, calibrated without a
    /// tracker). Not given: three-phase; `taut start` on hardware without `[tracker]` runs dwell.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub startup: Option<Startup>,
    /// Dwell poses of the tracker-free start-up and recalibration.
    pub dwell_poses: usize,
    /// Time the platform is held still and recorded at each dwell pose, s.
    pub dwell_s: f64,
    /// Time the platform is held before a dwell is recorded (it settles after the move), s.
    pub dwell_settle_s: f64,
    /// Largest platform speed between dwell poses, m/s (the robot moves with its nominal
    /// geometry, a few cm off: slowly).
    pub dwell_speed_m_s: f64,
    /// Tare dwells of the tracker-free start-up (at most `dwell_poses`): at that many dwell
    /// poses the platform stays after its dwell with the followers at zero tension (slack, the
    /// other cables hold it) while their load cells read their offsets; they fix the frame's
    /// tilt, which the dwells alone confound with the load-cell offsets. 0: none.
    pub dwell_tares: usize,
    /// The tares rotate through every cable (4-cable robots; default): a position-controlled
    /// cable's tare ramps it to zero tension while the three others (the follower in position
    /// mode, holding its length) hold the platform, so every load cell reads its own offset and
    /// the tilt is fixed by gravity alone. `false`: only the followers are tared.
    pub dwell_tare_each_cable: bool,
    /// The excitation is a tour of the workspace box's corners designed from the nominal anchors
    /// for the smallest predicted anchor uncertainty (`taut_calib::design`, default); `false`:
    /// the fixed Lissajous curve. With `[calibration] effects` modelled the Lissajous curve is
    /// used either way (the design covers anchors and offsets only).
    pub design_excitation: bool,
    /// Rate of the tracker's poses, Hz: the number of samples the design's predicted
    /// uncertainty counts on.
    pub tracker_rate_hz: f64,
}

/// The start-up routine (`motion.startup`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Startup {
    /// Three guided phases, then the excitation; the tracker is needed.
    ThreePhase,
    /// Dwell poses without a tracker (self-calibration from the encoders and load cells).
    Dwell,
}

/// Most dwell poses a plan may have (the loop holds them in a fixed-size table).
pub const MAX_DWELL_POSES: usize = 64;

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig {
            enable_timeout_s: 5.0,
            init_phases: vec![[0, 1, 2], [1, 2, 0], [2, 0, 1]],
            init_reel_m: -0.5,
            init_reel_speed_m_s: 0.1,
            init_reel_accel_m_s2: 0.5,
            init_follower_tension_n: 10.0,
            init_settle_s: 0.5,
            init_wiring_check: true,
            excitation_s: 60.0,
            excitation_speed_m_s: 0.3,
            workspace_min_m: None,
            workspace_max_m: None,
            swap_ramp_s: 2.0,
            move_speed_m_s: 0.2,
            startup: None,
            dwell_poses: 24,
            dwell_s: 1.5,
            dwell_settle_s: 1.0,
            dwell_speed_m_s: 0.15,
            dwell_tares: 4,
            dwell_tare_each_cable: true,
            design_excitation: true,
            tracker_rate_hz: 100.0,
        }
    }
}

impl MotionConfig {
    /// Checks the values for a robot of `n_cables`; returns the bad key and what is wrong.
    pub fn validate(&self, n_cables: usize) -> Result<(), (String, String)> {
        if self.init_phases.len() != 3 {
            return Err(("init_phases".into(), format!("the initialisation has three phases, got {}", self.init_phases.len())));
        }
        for (k, ph) in self.init_phases.iter().enumerate() {
            if ph.iter().any(|&c| c >= n_cables) || ph[0] == ph[1] || ph[1] == ph[2] || ph[0] == ph[2] {
                return Err((
                    format!("init_phases[{k}]"),
                    format!("must name three different cables [held, held, reeled] below {n_cables}, got {ph:?}"),
                ));
            }
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        for (k, v) in [
            ("enable_timeout_s", self.enable_timeout_s),
            ("init_reel_speed_m_s", self.init_reel_speed_m_s),
            ("init_reel_accel_m_s2", self.init_reel_accel_m_s2),
            ("excitation_s", self.excitation_s),
            ("excitation_speed_m_s", self.excitation_speed_m_s),
            ("swap_ramp_s", self.swap_ramp_s),
            ("move_speed_m_s", self.move_speed_m_s),
            ("dwell_speed_m_s", self.dwell_speed_m_s),
            ("tracker_rate_hz", self.tracker_rate_hz),
        ] {
            if !positive(v) {
                return Err((k.into(), format!("must be a positive number, got {v}")));
            }
        }
        if !(self.init_reel_m.is_finite() && self.init_reel_m != 0.0 && self.init_reel_m.abs() < 5.0) {
            return Err(("init_reel_m".into(), format!("must be a non-zero length under 5 m, got {}", self.init_reel_m)));
        }
        if !(self.dwell_s.is_finite() && self.dwell_s >= 1.0) {
            return Err(("dwell_s".into(), format!("must be at least 1 s (a dwell is averaged over its readings), got {}", self.dwell_s)));
        }
        if !(10..=MAX_DWELL_POSES).contains(&self.dwell_poses) {
            return Err((
                "dwell_poses".into(),
                format!("must be 10 to {MAX_DWELL_POSES} (fewer do not determine the geometry), got {}", self.dwell_poses),
            ));
        }
        if self.dwell_tares > self.dwell_poses {
            return Err((
                "dwell_tares".into(),
                format!("must be at most dwell_poses ({}): each tare follows a dwell, got {}", self.dwell_poses, self.dwell_tares),
            ));
        }
        for (k, v) in [
            ("init_follower_tension_n", self.init_follower_tension_n),
            ("init_settle_s", self.init_settle_s),
            ("dwell_settle_s", self.dwell_settle_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((k.into(), format!("must be a finite non-negative number, got {v}")));
            }
        }
        match (self.workspace_min_m, self.workspace_max_m) {
            (Some(lo), Some(hi)) => {
                if (0..3).any(|i| !(lo[i].is_finite() && hi[i].is_finite() && lo[i] < hi[i])) {
                    return Err(("workspace_max_m".into(), format!("must be above workspace_min_m on every axis, got {lo:?} .. {hi:?}")));
                }
            }
            (None, None) => {}
            _ => return Err(("workspace_min_m".into(), "give both workspace_min_m and workspace_max_m, or neither".into())),
        }
        Ok(())
    }
}

/// The `[safety]` table: limits checked in every cycle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetyConfig {
    /// Largest allowed tension of any cable, N (hold when exceeded).
    pub max_tension_n: f64,
    /// A cable with less tension than this is loose, N (the reeled cable of an initialisation
    /// phase must not go loose).
    pub loose_tension_n: f64,
    /// A tension reading older than this is stale, s.
    pub tension_max_age_s: f64,
    /// A tracker pose older than this is stale, s (only while the tracker is needed: the
    /// initialisation and the excitation).
    pub tracker_max_age_s: f64,
    /// Largest commanded cable speed, m/s.
    pub max_cable_speed_m_s: f64,
    /// How far outside the workspace box the platform may be before the loop holds, m.
    pub workspace_margin_m: f64,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        SafetyConfig {
            max_tension_n: 500.0,
            loose_tension_n: 1.0,
            // One failed load-cell reading (3 tries of 22 ms at the bus defaults) plus the
            // polling of up to 8 cells is at least 116 ms on the wire (crate::loadcell_timing);
            // 0.15 s outlasts one lost frame, not two readings lost in a row.
            tension_max_age_s: 0.15,
            tracker_max_age_s: 0.1,
            max_cable_speed_m_s: 1.0,
            workspace_margin_m: 0.3,
        }
    }
}

impl SafetyConfig {
    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        for (k, v) in [
            ("max_tension_n", self.max_tension_n),
            ("tension_max_age_s", self.tension_max_age_s),
            ("tracker_max_age_s", self.tracker_max_age_s),
            ("max_cable_speed_m_s", self.max_cable_speed_m_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err((k.into(), format!("must be a positive number, got {v}")));
            }
        }
        for (k, v) in [("loose_tension_n", self.loose_tension_n), ("workspace_margin_m", self.workspace_margin_m)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((k.into(), format!("must be a finite non-negative number, got {v}")));
            }
        }
        if self.loose_tension_n >= self.max_tension_n {
            return Err(("loose_tension_n".into(), format!("must be below max_tension_n ({} N)", self.max_tension_n)));
        }
        Ok(())
    }
}

/// The `[daemon]` table: files and the control socket of `taut start`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DaemonConfig {
    /// Unix domain socket for `taut ctl` (created with mode 0660).
    pub socket: String,
    /// Directory for recordings and parameter files (`params/` history, `current.toml`).
    pub data_dir: String,
    /// Every how many fresh tracker poses one goes into the calibrator's data set (the recording
    /// keeps every loop sample).
    pub calib_decimation: usize,
    /// A new anchor may move at most this far from the running one to be accepted, m.
    pub max_anchor_change_m: f64,
    /// A new encoder offset may change at most this much to be accepted, m.
    pub max_l0_change_m: f64,
    /// Largest accepted 1-sigma of any anchor coordinate or offset, m.
    pub max_sigma_m: f64,
    /// A new set is refused when its held-out RMS (co-registration with a tracker, length
    /// closure without) is higher than the running set's by more than this, with 99.9 %
    /// confidence (one-sided); it is the effect size that matters, so a set as good as the
    /// running one is not refused by chance. m, >= 0 (0: any significant increase refuses).
    pub heldout_tolerance_m: f64,
}

impl Default for DaemonConfig {
    fn default() -> Self {
        DaemonConfig {
            socket: "/run/taut/taut.sock".into(),
            data_dir: "/var/lib/taut".into(),
            calib_decimation: 1,
            max_anchor_change_m: 0.5,
            max_l0_change_m: 0.5,
            max_sigma_m: 0.01,
            // At the 1.5 mm tracker floor 0.1 mm of RMS is an added model error of
            // sqrt(1.6^2 - 1.5^2) = 0.56 mm per cable: well below what a failed calibration adds.
            heldout_tolerance_m: 1e-4,
        }
    }
}

impl DaemonConfig {
    /// Checks the values; returns the bad key and what is wrong.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.socket.trim().is_empty() {
            return Err(("socket".into(), "must be a path, e.g. \"/run/taut/taut.sock\"".into()));
        }
        if self.data_dir.trim().is_empty() {
            return Err(("data_dir".into(), "must be a directory path, e.g. \"/var/lib/taut\"".into()));
        }
        if self.calib_decimation == 0 {
            return Err(("calib_decimation".into(), "must be at least 1".into()));
        }
        for (k, v) in [
            ("max_anchor_change_m", self.max_anchor_change_m),
            ("max_l0_change_m", self.max_l0_change_m),
            ("max_sigma_m", self.max_sigma_m),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err((k.into(), format!("must be a positive length in m, got {v}")));
            }
        }
        if !(self.heldout_tolerance_m.is_finite() && (0.0..=0.01).contains(&self.heldout_tolerance_m)) {
            return Err((
                "heldout_tolerance_m".into(),
                format!("must be a length in m in [0, 0.01] (default 0.0001), got {}", self.heldout_tolerance_m),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        RtConfig::default().validate().unwrap();
        MotionConfig::default().validate(4).unwrap();
        SafetyConfig::default().validate().unwrap();
        DaemonConfig::default().validate().unwrap();
    }

    #[test]
    fn bad_values_name_the_key() {
        let r = RtConfig { priority: 120, ..Default::default() };
        assert_eq!(r.validate().unwrap_err().0, "priority");
        let m = MotionConfig { init_phases: vec![[0, 1, 2], [1, 1, 0], [2, 0, 1]], ..Default::default() };
        assert_eq!(m.validate(4).unwrap_err().0, "init_phases[1]");
        assert_eq!(MotionConfig::default().validate(2).unwrap_err().0, "init_phases[0]");
        let s = SafetyConfig { loose_tension_n: 600.0, ..Default::default() };
        assert_eq!(s.validate().unwrap_err().0, "loose_tension_n");
        let d = DaemonConfig { calib_decimation: 0, ..Default::default() };
        assert_eq!(d.validate().unwrap_err().0, "calib_decimation");
        for bad in [-1e-4, f64::NAN, 0.5] {
            let d = DaemonConfig { heldout_tolerance_m: bad, ..Default::default() };
            assert_eq!(d.validate().unwrap_err().0, "heldout_tolerance_m", "{bad}");
        }
        let t = MotionConfig { dwell_poses: 10, dwell_tares: 11, ..Default::default() };
        let e = t.validate(4).unwrap_err();
        assert_eq!(e.0, "dwell_tares");
        assert!(e.1.contains("dwell_poses (10)"), "{}", e.1);
    }

    #[test]
    fn partial_tables_parse() {
        let m: MotionConfig = toml::from_str("excitation_s = 20\nworkspace_min_m = [0,0,0]\nworkspace_max_m = [1,1,1]").unwrap();
        assert_eq!(m.excitation_s, 20.0);
        assert_eq!(m.init_reel_m, -0.5);
        m.validate(3).unwrap();
        assert!(toml::from_str::<RtConfig>("rate = 3").is_err());
    }
}
