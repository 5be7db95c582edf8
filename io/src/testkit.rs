//! A kinematic stand-in robot for unit tests, the allocation test and the loop benchmarks: the
//! platform sits where the position-controlled cables put it (Gauss-Newton on the true
//! geometry), drives follow commands perfectly, tensions are whatever the test sets. No physics
//! and no I/O: the simulator is `taut-sim`.

use taut_rt::io::{CableCommand, DeviceFault, Devices, DriveRequest, DriveStatus, Inputs, Outputs};
use taut_rt::kin::LoopParams;
use taut_rt::MAX_CABLES;

/// Faults a test can inject.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Injected {
    /// Stop updating the tensions (load cells silent).
    pub loadcells_silent: bool,
    /// Stop updating the pose (tracker gone).
    pub tracker_gone: bool,
    /// Report this device fault every cycle.
    pub fault: Option<DeviceFault>,
    /// Add this to every tension, N.
    pub tension_bias_n: f64,
}

/// The stand-in robot.
pub struct KinematicRobot {
    /// True geometry.
    pub truth: LoopParams,
    /// Platform position, m.
    pub p: [f64; 3],
    /// Encoder lengths, m.
    pub len: [f64; MAX_CABLES],
    /// Tension of every taut cable, N.
    pub tension_n: f64,
    /// Injected faults.
    pub inject: Injected,
    enabled: bool,
    last_tension_t: f64,
    last_pose_t: f64,
    tension: [f64; MAX_CABLES],
}

impl KinematicRobot {
    /// A robot with geometry `truth`, platform at `p`.
    pub fn new(truth: LoopParams, p: [f64; 3]) -> KinematicRobot {
        let mut len = [0.0; MAX_CABLES];
        truth.lengths(&p, &mut len);
        KinematicRobot {
            truth,
            p,
            len,
            tension_n: 30.0,
            inject: Injected::default(),
            enabled: false,
            last_tension_t: 0.0,
            last_pose_t: 0.0,
            tension: [30.0; MAX_CABLES],
        }
    }

    /// Moves the platform so that the cables in position mode have the commanded lengths
    /// (least squares, a few Gauss-Newton steps, fixed size).
    fn settle(&mut self, out: &Outputs) {
        let n = self.truth.n;
        for _ in 0..3 {
            let mut jtj = [[0.0; 3]; 3];
            let mut jtr = [0.0; 3];
            let mut rows = 0;
            for j in 0..n {
                if let CableCommand::Position(l) = out.cable[j] {
                    let a = self.truth.anchors[j];
                    let b = self.truth.platform[j];
                    let d = [self.p[0] + b[0] - a[0], self.p[1] + b[1] - a[1], self.p[2] + b[2] - a[2]];
                    let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                    let r = l - (norm + self.truth.l0[j]);
                    let g = [d[0] / norm, d[1] / norm, d[2] / norm];
                    for u in 0..3 {
                        jtr[u] += g[u] * r;
                        for v in 0..3 {
                            jtj[u][v] += g[u] * g[v];
                        }
                    }
                    rows += 1;
                }
            }
            if rows < 3 {
                return;
            }
            for (u, row) in jtj.iter_mut().enumerate() {
                row[u] += 1e-9;
            }
            if let Some(dx) = solve3(&jtj, &jtr) {
                for (x, d) in self.p.iter_mut().zip(dx) {
                    *x += d;
                }
            }
        }
    }
}

fn solve3(a: &[[f64; 3]; 3], b: &[f64; 3]) -> Option<[f64; 3]> {
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    if d.abs() < 1e-15 {
        return None;
    }
    let mut x = [0.0; 3];
    for (c, xc) in x.iter_mut().enumerate() {
        let mut m = *a;
        for r in 0..3 {
            m[r][c] = b[r];
        }
        *xc = det(&m) / d;
    }
    Some(x)
}

impl Devices for KinematicRobot {
    fn read(&mut self, now: f64, inp: &mut Inputs) {
        let n = self.truth.n;
        if !self.inject.loadcells_silent {
            self.last_tension_t = now;
            for j in 0..n {
                self.tension[j] = self.tension_n + self.inject.tension_bias_n;
            }
        }
        if !self.inject.tracker_gone {
            self.last_pose_t = now;
            inp.pose_m = self.p;
        }
        inp.pose_age_s = now - self.last_pose_t;
        for j in 0..n {
            inp.length_m[j] = self.len[j];
            inp.length_age_s[j] = 0.0;
            inp.tension_n[j] = self.tension[j];
            inp.tension_age_s[j] = now - self.last_tension_t;
            inp.drive[j] = if self.enabled { DriveStatus::Enabled } else { DriveStatus::Disabled };
        }
        inp.fault = self.inject.fault;
        if let Some(DeviceFault::Emcy { .. }) = self.inject.fault {
            inp.drive[0] = DriveStatus::Fault;
        }
    }

    fn write(&mut self, _now: f64, out: &Outputs) {
        self.enabled = out.request == DriveRequest::Enable;
        if !self.enabled {
            return;
        }
        self.settle(out);
        let n = self.truth.n;
        let mut geo = [0.0; MAX_CABLES];
        self.truth.lengths(&self.p, &mut geo);
        self.len[..n].copy_from_slice(&geo[..n]);
    }
}

/// A configuration of `n` cables (4 or 8 suit a 7 m x 3.5 m x 4 m frame) with quick motions, for
/// tests and benchmarks; `data_dir` and `socket` under `dir`. Without the phases' wiring check:
/// the kinematic stand-in's load cells read one tension, set by the test, for every cable.
pub fn quick_config(n: usize, dir: &std::path::Path) -> taut_config::RobotConfig {
    use std::fmt::Write as _;
    let mut t = String::from("[robot]\nname = \"test\"\nmass_kg = 3.0\n");
    for (j, a) in nominal_anchors(n).iter().enumerate() {
        let _ = write!(t, "[[cable]]\nanchor = [{}, {}, {}]\n[cable.loadcell]\nunit_id = {}\n", a[0], a[1], a[2], j + 1);
    }
    let _ = write!(
        t,
        "[loadcells]\nport = \"/dev/null\"\n[rt]\nrate_hz = 500\npriority = 0\nlock_memory = false\n\
         [motion]\ninit_reel_m = -0.1\ninit_reel_speed_m_s = 0.2\ninit_settle_s = 0.1\nexcitation_s = 3.0\n\
         init_wiring_check = false\n\
         excitation_speed_m_s = 0.5\nswap_ramp_s = 0.5\n[daemon]\nsocket = \"{}\"\ndata_dir = \"{}\"\n",
        dir.join("taut.sock").display(),
        dir.join("data").display()
    );
    taut_config::RobotConfig::from_toml_str(&t).expect("quick_config is valid")
}

/// Nominal anchors of `n` cables: four top corners of a 7 m x 3.5 m x 4 m frame, then (for
/// n > 4) the mid-points of its long sides and so on.
pub fn nominal_anchors(n: usize) -> Vec<[f64; 3]> {
    let corners = [
        [3.5, -1.75, 4.0],
        [3.5, 1.75, 4.0],
        [-3.5, 1.75, 4.0],
        [-3.5, -1.75, 4.0],
        [0.0, -1.75, 4.0],
        [0.0, 1.75, 4.0],
        [3.5, 0.0, 3.9],
        [-3.5, 0.0, 3.9],
    ];
    corners[..n].to_vec()
}

/// "True" parameters for a test: the nominal anchors moved by up to `err_m` and offsets of a few
/// centimetres.
pub fn truth_params(n: usize, err_m: f64) -> LoopParams {
    let mut a = nominal_anchors(n);
    for (j, aj) in a.iter_mut().enumerate() {
        let s = [((j * 7 + 1) % 5) as f64 / 4.0 - 0.5, ((j * 3 + 2) % 5) as f64 / 4.0 - 0.5, ((j * 11 + 3) % 5) as f64 / 4.0 - 0.5];
        for i in 0..3 {
            aj[i] += 2.0 * err_m * s[i];
        }
    }
    let l0: Vec<f64> = (0..n).map(|j| 0.02 * j as f64 - 0.03).collect();
    LoopParams::new(0, &a, &l0, &vec![[0.0; 3]; n])
}
