//! The wild-value screen: single readings that cannot be measurements of the robot, found
//! before any fitting, reported with where they are, and excluded. One place, used by
//! `taut calibrate`, `taut diagnose` ([`crate::diagnose::diagnose`]) and the daemon's
//! calibrator alike.
//!
//! # What is wild
//!
//! - **Encoder spike**: one length reading far from what its neighbours in time predict (a
//!   corrupted frame, a bit flip: `1e308` in a 3 m cable). Excluded.
//! - **Encoder jump**: a step that stays (an encoder that lost counts, a cable that slipped on
//!   its drum). The readings *before* the step are re-referenced by the step's local estimate,
//!   so the encoder offset the calibration finds is the one the encoder reads with *now*, after
//!   the lost counts: what the robot will run with. Excluding one side instead would throw away
//!   up to half of the cable's readings, and the estimate of the step has a standard deviation
//!   of about half the encoder noise (a local cubic fit over 8 + 8 readings), far below the
//!   tracker noise that dominates the calibration.
//! - **Impossible tension**: not finite (`inf`), negative beyond the load cell's noise below
//!   its zero level, or above a physical maximum. The reading (length and tension) is
//!   excluded: without a tension it cannot be told taut from loose.
//! - **Tracker jump**: a position far from the path its neighbours imply (any axis). The row is
//!   excluded. A step that stays (the tracker re-registered) excludes the shorter side.
//! - Any length or position beyond 1 km, or tension beyond 10 MN, is absurd without a test (the
//!   largest cable robot built, FAST's feed cabin, spans 600 m; a 40 mm steel rope breaks at
//!   about 1 MN): this also keeps the arithmetic below from overflowing.
//!
//! `NaN` is a missing value, not a wild one: the readers and the calibration skip it already.
//!
//! The test checks its own premise: the scale from every other reading must be within 1.5x of
//! the scale from every reading (with the sampling resolving the motion, both are the noise; an
//! unresolved motion's interpolation error grows with the 4th power of the spacing). A channel
//! that fails (a 4 Hz recording of a fast robot) is only checked for absurd values.
//!
//! The scale is never below the channel's quantum (its smallest change between two readings):
//! a quantised encoder that stands still has a MAD of zero. Runs of four or more identical
//! encoder readings (frozen, or held still) are not tested either: their end is no jump.
//!
//! A slack cable's encoder (tension below twice `min_tension_n`, and two readings either side)
//! follows its winch, which may change speed within a sample, not the geometry: those readings
//! are only checked for absurd values. The calibration and the diagnosis exclude them anyway, so
//! a moderate spike there changes nothing; a jump hidden in a slack stretch is not found by
//! this local test. Without tensions slack cannot be seen, and a winch's sudden payout may be
//! reported as a jump.
//!
//! # The test
//!
//! For each reading `y_i` of a channel (one cable's encoder, one tracker axis, one load cell)
//! the prediction `ŷ_i` is the cubic (Lagrange) interpolation through the two nearest present
//! readings on either side, at their actual times (no more than 8 rows and 5 median sample
//! intervals apart). With independent noise of standard deviation `σ` and a motion that is
//! smooth over those five samples (a cubic's error is `O(dt^4)`: under 0.2 µm for 1 m/s^2 at
//! 100 Hz), `z_i = (y_i - ŷ_i) / sqrt(1 + Σ w_k^2)` is `N(0, σ^2)`. `σ` is the recording's
//! own: `1.4826 median |z|` over the channel (robust: the wild values do not move it; the
//! residual motion, if the sampling is too slow for the motion, enters it and makes the test
//! less sensitive, never trigger-happy).
//!
//! A reading is flagged when `|z_i| > k σ`, with `k` from a Bonferroni bound over the `N`
//! tests of the whole recording (every channel, every sample):
//!
//! ```text
//! P(any flag | clean recording, Gaussian noise) <= N * P(|Z| > k) = FALSE_ALARM = 1e-3
//! k = Φ^-1(1 - FALSE_ALARM / (2 N)) * (1 + 3.3 / sqrt(N_channel))
//! ```
//!
//! (`k` = 5.4-5.8 for 10^4-10^5 samples x 4 cables); the second factor is three standard errors
//! of the MAD scale estimate, so an unlucky scale does not raise the rate. A negative tension is
//! impossible when it is below `min(0, z0) - k σ_T`, with `z0` the load cell's zero level
//! (median of its readings below `min_tension_n`, i.e. of the loose cable; 0 when there are
//! fewer than 20) and `σ_T` its noise from the same interpolation residual.
//!
//! A flagged reading is then classified by a local fit: over up to 8 present readings either
//! side, a cubic in time plus either one excluded reading (a spike, at the flagged sample or a
//! neighbour), a step (at one of the four boundaries around it) or a kink (a change of slope at
//! one of five readings around it). All have the same degrees of freedom, so the smallest
//! residual sum of squares decides. A kink is motion (backlash taken up, a winch reversing),
//! not a wild value: those readings are left alone. The largest flag is
//! handled first and its neighbours are re-tested without it (a 1e308 must not make its
//! neighbours look wild), until no reading is beyond `k σ`.
//!
//! Measured (`tests` below, `tests/tests/hostile_wild_values.rs`): no flag on 60 clean
//! synthetic recordings (three geometries, two noise levels, 50 and 100 Hz) nor on 17 clean
//! simulator recordings (ARAS-CAM, three cables); spikes of 1.5 k σ and up are found at their
//! row, as are `1e308`, `1e160`, `-1e308`, `inf`, 2 mm-5 cm spikes, 5 mm-2 cm jumps, impossible
//! tensions and tracker jumps. Known limits: a slack cable's readings are only checked for
//! absurd values; on the 20 m outdoor robot (sag of heavy cables following the tension) a few
//! readings per recording are taken for spikes and excluded; with the backlash of the simulator
//! one reading in 4000.

use std::fmt;
use taut_config::recording::Recording;

/// Probability that a clean recording (Gaussian noise, smooth motion) has any flag.
pub const FALSE_ALARM: f64 = 1e-3;
/// A length or position beyond this magnitude is absurd, m.
pub const ABSURD_M: f64 = 1e3;
/// A tension beyond this magnitude is absurd, N.
pub const ABSURD_N: f64 = 1e7;

/// Options of [`screen`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScreenOptions {
    /// Probability of any flag on a clean recording (Bonferroni over every test).
    pub false_alarm: f64,
    /// Readings below this tension are loose, N (sets the load cells' zero level).
    pub min_tension_n: f64,
    /// The largest tension a load cell can physically read, N (e.g. its range), if known.
    pub max_tension_n: Option<f64>,
    /// Classify encoder steps as jumps and re-reference them, and tracker steps as a
    /// re-registration whose shorter side is excluded. Off, a step's readings are taken for
    /// spikes (a few excluded) and nothing is shifted or dropped: the daemon's data sets
    /// (lengths interpolated at the pose time of a tracker slower than the loop, poses dated
    /// by their age on a loop that may be late) show steps of a few mm that are neither lost
    /// counts nor a re-registration, and dropping the shorter side of one would drop whole
    /// phases of the start-up's initial data set.
    pub jumps: bool,
    /// Threads the channels may be screened on ([`crate::par`]; the findings are the same).
    pub threads: usize,
}

impl ScreenOptions {
    /// The default false-alarm rate and no configured tension maximum, on the caller's thread.
    pub fn new(min_tension_n: f64) -> Self {
        ScreenOptions { false_alarm: FALSE_ALARM, min_tension_n, max_tension_n: None, jumps: true, threads: 1 }
    }
}

/// What kind of wild value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WildKind {
    /// One encoder reading far from its neighbours (or absurd / not finite).
    EncoderSpike,
    /// An encoder step that stays.
    EncoderJump,
    /// A tension that cannot be: not finite, negative beyond noise, above the maximum.
    ImpossibleTension,
    /// A tracker position far from the path of its neighbours.
    TrackerJump,
}

impl WildKind {
    /// Short machine-readable name.
    pub fn name(self) -> &'static str {
        match self {
            WildKind::EncoderSpike => "encoder-spike",
            WildKind::EncoderJump => "encoder-jump",
            WildKind::ImpossibleTension => "impossible-tension",
            WildKind::TrackerJump => "tracker-jump",
        }
    }
}

/// What was done about a wild value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    /// The reading (or the row, for the tracker) is excluded.
    Excluded,
    /// The readings before the step were shifted by this much, m, onto the later reference.
    ReReferenced {
        /// Added to every earlier reading of the cable, m.
        by_m: f64,
        /// Rows re-referenced.
        rows: usize,
    },
    /// Rows excluded (the shorter side of a tracker step).
    RowsExcluded {
        /// First row excluded.
        first: usize,
        /// Rows excluded.
        rows: usize,
    },
}

/// One wild value and where it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WildValue {
    /// Kind.
    pub kind: WildKind,
    /// Row of the recording (0-based data row; for a jump the first row at the new level).
    pub row: usize,
    /// Time of that row, s.
    pub t: f64,
    /// Cable (encoder, load cell), or `None` for the tracker.
    pub cable: Option<usize>,
    /// Tracker axis (0 = x), for a tracker jump.
    pub axis: Option<usize>,
    /// The value read (m or N); for a jump, the step, m.
    pub value: f64,
    /// What the neighbours predict (m or N; the threshold for a tension below zero; NaN when
    /// the value is absurd and no prediction was needed).
    pub expected: f64,
    /// Distance from the prediction in noise sigmas (infinite when not finite or absurd).
    pub sigmas: f64,
    /// What was done.
    pub action: Action,
}

impl fmt::Display for WildValue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let axis = ["x", "y", "z"];
        let who = match (self.cable, self.axis) {
            (Some(j), _) => taut_config::cable_name(j),
            (None, Some(a)) => format!("tracker {}", axis[a.min(2)]),
            (None, None) => "tracker".to_string(),
        };
        write!(f, "row {} (t = {:.3} s), {who}: ", self.row, self.t)?;
        let sig = if self.sigmas.is_finite() { format!("{:.1} noise sigmas", self.sigmas) } else { "absurd".to_string() };
        match self.kind {
            WildKind::EncoderSpike | WildKind::TrackerJump => {
                let what = if self.kind == WildKind::EncoderSpike { "encoder reading" } else { "position" };
                write!(f, "{what} {} m", plain(self.value))?;
                if self.expected.is_finite() {
                    write!(f, " where its neighbours give {:.4} m", self.expected)?;
                }
                write!(f, " ({sig})")?;
            }
            WildKind::EncoderJump => write!(f, "encoder steps by {:+.2} mm and stays ({sig})", self.value * 1e3)?,
            WildKind::ImpossibleTension => {
                write!(f, "tension {} N", plain(self.value))?;
                if self.expected.is_finite() {
                    write!(f, " (limit {:.2} N)", self.expected)?;
                }
                write!(f, ", impossible ({sig})")?;
            }
        }
        match self.action {
            Action::Excluded => write!(f, "; excluded"),
            Action::ReReferenced { by_m, rows } => {
                write!(f, "; the {rows} earlier readings re-referenced by {:+.2} mm to the encoder's later count", by_m * 1e3)
            }
            Action::RowsExcluded { first, rows } => write!(f, "; rows {first}..{} (the shorter side) excluded", first + rows - 1),
        }
    }
}

/// A read value as people write it: 4 decimals (0.1 mm, 0.1 mN) where that is a sensible
/// number (`1.0555`, not `1.05552e0`), scientific notation only for the absurd (`1e308`).
fn plain(v: f64) -> String {
    if v.is_finite() && v.abs() < 1e6 {
        format!("{v:.4}")
    } else {
        format!("{v:e}")
    }
}

/// What [`screen`] found.
#[derive(Debug, Clone)]
pub struct Screen {
    /// The wild values, in the order: encoders, load cells, tracker; each by row.
    pub findings: Vec<WildValue>,
    /// The recording with wild readings set missing (NaN) and jumps re-referenced; `None` when
    /// nothing was found (use the original).
    pub cleaned: Option<Recording>,
    /// Rows whose tracker position the screen removed (not a dropout of the tracker).
    pub removed_rows: Vec<bool>,
    /// Number of tests (the Bonferroni count).
    pub tests: usize,
    /// The threshold used, in noise sigmas (before the per-channel scale correction).
    pub threshold_sigmas: f64,
}

impl Screen {
    /// The recording to calibrate from: the cleaned one, or `rec` when nothing was wild.
    pub fn recording<'a>(&'a self, rec: &'a Recording) -> &'a Recording {
        self.cleaned.as_ref().unwrap_or(rec)
    }
}

/// Upper tail of the standard normal, `P(Z > x)`, for `x >= 0` (relative error < 1.2e-7:
/// Numerical Recipes' Chebyshev fit of erfc).
pub fn normal_sf(x: f64) -> f64 {
    let z = x / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.5 * z);
    let p = -z * z - 1.26551223
        + t * (1.00002368
            + t * (0.37409196
                + t * (0.09678418
                    + t * (-0.18628806 + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
    0.5 * t * p.exp()
}

/// `k` with `P(Z > k) = p` (bisection; `p` in (0, 0.5)).
pub fn normal_upper_quantile(p: f64) -> f64 {
    let (mut lo, mut hi) = (0.0f64, 40.0f64);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if normal_sf(mid) > p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// A time grid with the interpolation weights of its fast path, computed once for every channel
/// sampled on it (the encoders, tracker axes and load cells share the recording's times; the
/// decimated channels share every other time): row `i`'s cubic through rows `i-2, i-1, i+1, i+2`
/// when those four are linked in time (`gap`). A channel uses them where its own readings and
/// segments allow, and gets the same bits as [`Channel::lagrange`] (the same function computes them).
struct Grid {
    t: Vec<f64>,
    gap: f64,
    /// Lagrange weights of the four nodes, per row (zeros where not `linked`).
    w: Vec<[f64; 4]>,
    /// `sqrt(1 + sum w^2)`, the prediction's noise relative to one reading's.
    norm: Vec<f64>,
    /// The four neighbours exist and each is within `gap` of the next towards `i`.
    linked: Vec<bool>,
    /// Every other time of this grid with twice the gap (the decimated test), when made.
    half: Option<Box<Grid>>,
}

impl Grid {
    fn new(t: Vec<f64>, gap: f64) -> Grid {
        let m = t.len();
        let (mut w, mut norm, mut linked) = (vec![[0.0; 4]; m], vec![f64::NAN; m], vec![false; m]);
        let link = |k: usize, prev: usize| (t[k] - t[prev]).abs() <= gap;
        for i in 2..m.saturating_sub(2) {
            if link(i - 1, i) && link(i - 2, i - 1) && link(i + 1, i) && link(i + 2, i + 1) {
                let (wi, w2) = lagrange_weights(t[i], [t[i - 2], t[i - 1], t[i + 1], t[i + 2]]);
                w[i] = wi;
                norm[i] = (1.0 + w2).sqrt();
                linked[i] = true;
            }
        }
        Grid { t, gap, w, norm, linked, half: None }
    }

    /// Every other time, twice the gap.
    fn decimated(&self) -> Grid {
        Grid::new(self.t.iter().step_by(2).copied().collect(), 2.0 * self.gap)
    }

    /// The grid of `t` with its decimated grid ([`Grid::decimated`]), shared by every channel
    /// screened on it (the two made at once when there are `threads`).
    fn with_half(t: &[f64], gap: f64, threads: usize) -> Grid {
        let (mut grid, half) =
            crate::par::join(threads, || Grid::new(t.to_vec(), gap), || Grid::new(t.iter().step_by(2).copied().collect(), 2.0 * gap));
        grid.half = Some(Box::new(half));
        grid
    }
}

/// Lagrange weights `w_p = prod_q (ti - t_q) / prod_q (t_p - t_q)`, q != p, of the cubic through
/// the times `tk` at `ti`, and `sum w_p^2`.
#[inline]
#[allow(clippy::needless_range_loop)]
fn lagrange_weights(ti: f64, tk: [f64; 4]) -> ([f64; 4], f64) {
    // A single division for all four: this runs for every row of a grid (and for every reading
    // off the fast path).
    let mut num = [1.0f64; 4];
    let mut den = [1.0f64; 4];
    for p in 0..4 {
        for q in 0..4 {
            if p != q {
                num[p] *= ti - tk[q];
                den[p] *= tk[p] - tk[q];
            }
        }
    }
    let inv = 1.0 / (den[0] * den[1] * den[2] * den[3]);
    let others = [den[1] * den[2] * den[3], den[0] * den[2] * den[3], den[0] * den[1] * den[3], den[0] * den[1] * den[2]];
    let (mut w, mut w2) = ([0.0; 4], 0.0);
    for p in 0..4 {
        w[p] = num[p] * others[p] * inv;
        w2 += w[p] * w[p];
    }
    (w, w2)
}

/// One series (an encoder, a tracker axis, a load cell) being screened.
struct Channel<'a> {
    t: &'a [f64],
    /// The grid of `t` (its fast-path weights).
    grid: &'a Grid,
    y: Vec<f64>,
    /// Excluded (wild) or missing.
    out: Vec<bool>,
    /// Largest time between neighbours used by a prediction, s.
    gap: f64,
    /// Segment of each row (the phase column, when there is one): predictions do not cross
    /// from one phase of the experiment to the next, where the motion may restart elsewhere.
    seg: &'a [i32],
}

const REACH: usize = 8;

impl Channel<'_> {
    fn new<'a>(grid: &'a Grid, y: Vec<f64>, seg: &'a [i32]) -> Channel<'a> {
        let out = y.iter().map(|v| v.is_nan()).collect();
        Channel { t: &grid.t, grid, y, out, gap: grid.gap, seg }
    }

    /// Up to `want` present neighbours of `i` on one side, nearest first.
    fn side(&self, i: usize, up: bool, want: usize, buf: &mut [usize; REACH]) -> usize {
        let m = self.y.len();
        let (mut cnt, mut prev) = (0, i);
        for d in 1..=REACH {
            let k = if up {
                if i + d >= m {
                    break;
                }
                i + d
            } else {
                if d > i {
                    break;
                }
                i - d
            };
            if self.out[k] {
                continue;
            }
            if !((self.t[k] - self.t[prev]).abs() <= self.gap) || self.seg.get(k) != self.seg.get(i) {
                break;
            }
            buf[cnt] = k;
            cnt += 1;
            prev = k;
            if cnt == want {
                break;
            }
        }
        cnt
    }

    /// `(prediction, z)` at `i` from two present neighbours either side (or four on one side at an
    /// end); NaN if there are not.
    // The node loops index four small arrays together; iterator chains would hide the formula.
    #[allow(clippy::needless_range_loop)]
    fn z(&self, i: usize) -> (f64, f64) {
        let (mut a, mut b) = ([0; REACH], [0; REACH]);
        if self.out[i] {
            return (f64::NAN, f64::NAN);
        }
        // Almost every reading: its four nearest rows are present and linked, the nodes `side`
        // would find (checked in the same order, with the same comparisons).
        // The time links and the weights are the grid's; the segments are the channel's.
        if self.grid.linked[i] && !(self.out[i - 2] | self.out[i - 1] | self.out[i + 1] | self.out[i + 2]) {
            let same = |k: usize| self.seg.get(k) == self.seg.get(i);
            if same(i - 1) && same(i - 2) && same(i + 1) && same(i + 2) {
                let (w, y) = (&self.grid.w[i], &self.y);
                let pred = 0.0 + w[0] * y[i - 2] + w[1] * y[i - 1] + w[2] * y[i + 1] + w[3] * y[i + 2];
                if !pred.is_finite() {
                    return (f64::NAN, f64::NAN);
                }
                return (pred, (y[i] - pred) / self.grid.norm[i]);
            }
        }
        let (na, nb) = (self.side(i, false, 2, &mut a), self.side(i, true, 2, &mut b));
        // At an end of the recording or a gap: extrapolate from four on the other side (the
        // normalisation below accounts for the larger weights, so the test stays exact).
        let nodes = if na == 2 && nb == 2 {
            [a[1], a[0], b[0], b[1]]
        } else if na < 2 && self.side(i, true, 4, &mut b) == 4 {
            [b[0], b[1], b[2], b[3]]
        } else if nb < 2 && self.side(i, false, 4, &mut a) == 4 {
            [a[3], a[2], a[1], a[0]]
        } else {
            return (f64::NAN, f64::NAN);
        };
        self.lagrange(i, nodes)
    }

    /// `(prediction, z)` at `i` by the cubic through `nodes`.
    #[inline]
    #[allow(clippy::needless_range_loop)]
    fn lagrange(&self, i: usize, nodes: [usize; 4]) -> (f64, f64) {
        let (w, w2) = lagrange_weights(self.t[i], nodes.map(|k| self.t[k]));
        let mut pred = 0.0;
        for p in 0..4 {
            pred += w[p] * self.y[nodes[p]];
        }
        if !pred.is_finite() {
            return (f64::NAN, f64::NAN);
        }
        (pred, (self.y[i] - pred) / (1.0 + w2).sqrt())
    }
}

/// A local fit: cubic in time (centred and scaled) over `idx`, optionally without the reading
/// at position `drop`, optionally with a step starting at position `step`. Returns the residual
/// sum of squares, the prediction at position `at`, and the step.
fn local_fit(ch: &Channel, idx: &[usize], drop: Option<usize>, step: Option<usize>, at: usize) -> (f64, f64, f64) {
    local_fit_with(ch, idx, drop, step, None, at)
}

/// [`local_fit`], optionally with a kink (a change of slope, `max(0, t - t_k)`) at position
/// `kink` instead of a step.
fn local_fit_with(
    ch: &Channel,
    idx: &[usize],
    drop: Option<usize>,
    step: Option<usize>,
    kink: Option<usize>,
    at: usize,
) -> (f64, f64, f64) {
    use nalgebra::{SMatrix, SVector};
    let t0 = ch.t[idx[idx.len() / 2]];
    let span = idx.iter().map(|&k| (ch.t[k] - t0).abs()).fold(1e-9, f64::max);
    let basis = |p: usize| -> SVector<f64, 5> {
        let u = (ch.t[idx[p]] - t0) / span;
        SVector::from([
            1.0,
            u,
            u * u,
            u * u * u,
            match (step, kink) {
                (Some(s), _) if p >= s => 1.0,
                (_, Some(k)) => (u - (ch.t[idx[k]] - t0) / span).max(0.0),
                _ => 0.0,
            },
        ])
    };
    let mut a = SMatrix::<f64, 5, 5>::zeros();
    let mut g = SVector::<f64, 5>::zeros();
    let y0 = ch.y[idx[idx.len() / 2]];
    for p in 0..idx.len() {
        if Some(p) == drop {
            continue;
        }
        let r = basis(p);
        a += r * r.transpose();
        g += r * (ch.y[idx[p]] - y0);
    }
    if step.is_none() && kink.is_none() {
        a[(4, 4)] = 1.0;
    }
    let Some(c) = a.lu().solve(&g) else {
        return (f64::INFINITY, f64::NAN, 0.0);
    };
    let mut rss = 0.0;
    for p in 0..idx.len() {
        if Some(p) != drop {
            rss += (ch.y[idx[p]] - y0 - basis(p).dot(&c)).powi(2);
        }
    }
    let mut b = basis(at);
    b[4] = 0.0;
    (rss, y0 + b.dot(&c) + if step.is_some_and(|s| at >= s) { c[4] } else { 0.0 }, c[4])
}

/// A channel event.
enum Event {
    /// Reading at row excluded: (row, value, expected, sigmas).
    Spike(usize, f64, f64, f64),
    /// Step starting at row: (row, step, sigmas).
    Step(usize, f64, f64),
}

/// The channel's noise scale (robust) and the `z` of every reading.
fn scale(ch: &Channel, zs: &mut [f64], floor: f64) -> (f64, usize) {
    let (mad, tested) = mad_scale(ch, zs);
    (floored(mad, &ch.y, floor), tested)
}

/// `1.4826 median |z|` over the channel's finite `z` (NaN when there is none) and how many there
/// are; fills `zs`. Without the floor of [`floored`], so that two floors can share it.
fn mad_scale(ch: &Channel, zs: &mut [f64]) -> (f64, usize) {
    // |z| as bits: without a sign bit, the integers' order is `total_cmp`'s, so the median is
    // the same element, selected by integer comparisons.
    let mut a: Vec<u64> = Vec::with_capacity(zs.len());
    for (i, z) in zs.iter_mut().enumerate() {
        *z = ch.z(i).1;
        if z.is_finite() {
            a.push(z.abs().to_bits());
        }
    }
    if a.is_empty() {
        return (f64::NAN, 0);
    }
    let k = a.len() / 2;
    (1.4826 * f64::from_bits(*a.select_nth_unstable(k).1), a.len())
}

/// The scale `mad` no lower than `floor` nor than the quantum of the values `y`; NaN stays NaN
/// (no reading could be tested).
fn floored(mad: f64, y: &[f64], floor: f64) -> f64 {
    if mad.is_nan() {
        return f64::NAN;
    }
    // A quantised channel that mostly stands still has a MAD of zero: one quantum is then the
    // smallest change that can be told from none.
    let quantum = y.windows(2).map(|w| (w[1] - w[0]).abs()).filter(|d| *d > 0.0 && d.is_finite()).fold(f64::INFINITY, f64::min);
    let floor = if quantum.is_finite() { floor.max(quantum) } else { floor };
    mad.max(floor)
}

/// Screens one channel: absurd values first, then the iterative local test. `thr` is in the
/// channel's sigmas. Steps are allowed when `steps`.
fn screen_channel(
    ch: &mut Channel,
    absurd: f64,
    floor: f64,
    thr_of: impl Fn(usize) -> f64,
    steps: bool,
    quiet: &[bool],
    tension: Option<(&[f64], f64)>,
) -> (Vec<Event>, usize) {
    let m = ch.y.len();
    let mut ev = vec![];
    for i in 0..m {
        let v = ch.y[i];
        if !v.is_nan() && !(v.abs() <= absurd) {
            ch.out[i] = true;
            ev.push(Event::Spike(i, v, f64::NAN, f64::INFINITY));
        }
    }
    let mut zs = vec![f64::NAN; m];
    let (s, tested) = scale(ch, &mut zs, floor);
    if !s.is_finite() || tested < 20 {
        return (ev, tested);
    }
    // The test assumes the sampling resolves the motion: then interpolating from every other
    // reading gives the same noise scale (z is normalised), while unresolved motion grows with
    // the 4th power of the spacing. If the decimated scale is more than 1.5x, this channel's
    // local test would judge the motion, not the readings: only absurd values are flagged.
    let own;
    let half_grid = match ch.grid.half.as_deref() {
        Some(h) => h,
        None => {
            own = ch.grid.decimated();
            &own
        }
    };
    let yd: Vec<f64> = (0..m).step_by(2).map(|i| if ch.out[i] { f64::NAN } else { ch.y[i] }).collect();
    let sd: Vec<i32> = (0..m).step_by(2).map(|i| ch.seg.get(i).copied().unwrap_or(0)).collect();
    let half = Channel::new(half_grid, yd, if ch.seg.is_empty() { &[] } else { &sd });
    let (s2, _) = scale(&half, &mut vec![f64::NAN; half_grid.t.len()], floor);
    if !(s2 <= 1.5 * s) {
        return (ev, tested);
    }
    let thr = thr_of(tested) * s;
    let mut cand: Vec<usize> = (0..m).filter(|&i| zs[i].abs() > thr).collect();
    let mut seen = vec![];
    // Rows where an event is explained by motion (a kink, a burst) or by the tension (`quiet`).
    let mut explained: Vec<bool> = (0..m).map(|i| quiet.get(i).copied().unwrap_or(false)).collect();
    for _ in 0..m {
        cand.retain(|&i| zs[i].abs() > thr && !ch.out[i] && !explained[i]);
        let Some(&i) = cand.iter().max_by(|&&a, &&b| zs[a].abs().total_cmp(&zs[b].abs())) else {
            break;
        };
        // The window: up to REACH present readings either side.
        let (mut lo, mut hi) = ([0; REACH], [0; REACH]);
        let nl = ch.side(i, false, REACH, &mut lo);
        let nh = ch.side(i, true, REACH, &mut hi);
        let mut idx: Vec<usize> = lo[..nl].iter().rev().copied().collect();
        let pi = idx.len();
        idx.push(i);
        idx.extend_from_slice(&hi[..nh]);
        // At the end of a segment (a phase starts, a slack stretch ends) the motion's start
        // cannot be told from a spike by a one-sided fit: only far beyond the threshold there.
        if (nl < 3 || nh < 3) && zs[i].abs() <= 10.0 * thr {
            explained[i] = true;
            continue;
        }
        let mut best: (f64, Option<usize>, Option<usize>) = (f64::INFINITY, Some(pi), None);
        if idx.len() >= 8 {
            // One-sided (at an end) the fit cannot tell which reading is off: the flagged one.
            let (d0, d1) = if nl < 3 || nh < 3 { (pi, pi) } else { (pi.saturating_sub(1), (pi + 1).min(idx.len() - 1)) };
            for d in d0..=d1 {
                let r = local_fit(ch, &idx, Some(d), None, d).0;
                if r < best.0 {
                    best = (r, Some(d), None);
                }
            }
            // Repeating the same reading twice means its step did not remove it: a spike then.
            if steps && !seen.contains(&i) && nl >= 4 && nh >= 4 {
                for st in pi.saturating_sub(1)..=(pi + 2).min(idx.len() - 1) {
                    let r = local_fit(ch, &idx, None, Some(st), st).0;
                    if r < best.0 {
                        best = (r, None, Some(st));
                    }
                }
            }
            // A change of slope (backlash taken up, a winch reversing, stick-slip) is motion,
            // not a wild value: when a kink fits the window better than any spike or step, the
            // readings around it are left alone.
            if nl >= 3 && nh >= 3 {
                let kinked = (pi.saturating_sub(2)..=(pi + 2).min(idx.len() - 1))
                    .any(|k| local_fit_with(ch, &idx, None, None, Some(k), k).0 < best.0);
                if kinked {
                    for &k in &idx[pi.saturating_sub(3)..(pi + 4).min(idx.len())] {
                        explained[k] = true;
                    }
                    continue;
                }
            }
        }
        seen.push(i);
        // A jump of lost counts is one isolated step. Another event within reach of an
        // accepted step means a burst of fast motion (backlash taken up over a few samples),
        // not a jump: the step is undone and the readings left alone.
        let near_step = ev.iter().rposition(|e| matches!(e, Event::Step(r, _, _) if r.abs_diff(i) <= REACH));
        if let Some(k) = near_step {
            if let Event::Step(r, d, _) = ev.remove(k) {
                for y in ch.y[..r].iter_mut() {
                    *y -= d;
                }
                for x in r.saturating_sub(REACH)..(r + REACH + 1).min(m) {
                    explained[x] = true;
                }
                for x in r.saturating_sub(REACH + 2)..(r + REACH + 3).min(m) {
                    zs[x] = ch.z(x).1;
                }
            }
            for &k in &idx {
                explained[k] = true;
            }
            continue;
        }
        // Lost counts leave the tension as it was; a step that comes with a step of the tension
        // (more than 3 of its noise sigmas, medians of the window's two sides) is the cable's
        // stretch or sag following the tension.
        if let ((_, _, Some(st)), Some((f, s_t))) = (best, tension) {
            let med = |r: &[usize]| {
                let mut v: Vec<f64> = r.iter().map(|&k| f[k]).filter(|x| x.is_finite()).collect();
                if v.is_empty() {
                    return f64::NAN;
                }
                let h = v.len() / 2;
                *v.select_nth_unstable_by(h, |a, b| a.total_cmp(b)).1
            };
            let dt = med(&idx[st..]) - med(&idx[..st]);
            if !(dt.abs() <= 3.0 * s_t) {
                for &k in &idx {
                    explained[k] = true;
                }
                continue;
            }
        }
        let touched = match best {
            (_, _, Some(st)) => {
                let (_, _, d) = local_fit(ch, &idx, None, Some(st), st);
                let row = idx[st];
                for k in 0..row {
                    ch.y[k] += d;
                }
                // The step's sigmas: against the noise of the local estimate.
                ev.push(Event::Step(row, d, d.abs() / s));
                row
            }
            (_, Some(d), _) => {
                let row = idx[d];
                let expected = if idx.len() >= 8 { local_fit(ch, &idx, Some(d), None, d).1 } else { ch.z(row).0 };
                ev.push(Event::Spike(row, ch.y[row], expected, zs[row].abs() / s));
                ch.out[row] = true;
                row
            }
            _ => unreachable!("a spike or a step"),
        };
        for k in touched.saturating_sub(REACH + 2)..(touched + REACH + 3).min(m) {
            zs[k] = ch.z(k).1;
            if zs[k].abs() > thr && !cand.contains(&k) && !explained[k] {
                cand.push(k);
            }
        }
    }
    (ev, tested)
}

/// Segments of cable `j`'s encoder readings for the local test: runs of taut readings within a
/// phase. A reading of a slack cable, and the two readings either side of a slack stretch, get
/// a segment of their own (not tested, no prediction across them): there the encoder follows
/// the winch paying out or reeling in, not the geometry, and a winch can change speed within
/// one sample. The calibration excludes those readings anyway.
fn encoder_segments(rec: &Recording, j: usize, phase: &[i32], min_tension_n: f64) -> Vec<i32> {
    let (n, m) = (rec.n_cables, rec.len());
    let mut skip: Vec<bool> = match &rec.f {
        Some(f) => (0..m).map(|i| f[i * n + j] < 2.0 * min_tension_n).collect(),
        None => vec![false; m],
    };
    // Runs of four or more identical readings: frozen (found and reported by the diagnosis's
    // data-quality pass) or held still; their end is not a jump of the encoder.
    let mut i = 0;
    while i < m {
        let v = rec.l[i * n + j];
        let mut e = i + 1;
        while e < m && rec.l[e * n + j] == v {
            e += 1;
        }
        if e - i >= 4 {
            skip[i..e].iter_mut().for_each(|x| *x = true);
        }
        i = e;
    }
    let near = |i: usize| skip[i.saturating_sub(2)..(i + 3).min(m)].iter().any(|x| *x);
    let mut out = Vec::with_capacity(m);
    let mut run = 0i32;
    for i in 0..m {
        let ph = phase.get(i).copied().unwrap_or(0);
        if near(i) {
            out.push(-1 - i as i32);
            continue;
        }
        if i > 0 && (out[i - 1] < 0 || phase.get(i - 1).copied().unwrap_or(0) != ph) {
            run += 1;
        }
        out.push(run);
    }
    out
}

/// Screens `rec`: see the module documentation.
pub fn screen(rec: &Recording, opts: &ScreenOptions) -> Screen {
    let n = rec.n_cables;
    let m = rec.len();
    let dt = {
        let mut d: Vec<f64> = rec.t.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.0).collect();
        if d.is_empty() {
            f64::NAN
        } else {
            let k = d.len() / 2;
            d.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
            d[k]
        }
    };
    let gap = if dt.is_finite() { 5.0 * dt } else { f64::INFINITY };
    let seg: &[i32] = rec.phase.as_deref().unwrap_or(&[]);
    // Every channel is sampled on the recording's times, decimated on every other one.
    let grid = Grid::with_half(&rec.t, gap, opts.threads);
    // The Bonferroni count: every reading of every channel (encoders, tracker axes, load cells).
    let tests = m * (n + 3 + if rec.f.is_some() { n } else { 0 });
    let k = normal_upper_quantile(opts.false_alarm / (2.0 * tests.max(1) as f64));
    let thr_of = |nc: usize| k * (1.0 + 3.3 / (nc.max(1) as f64).sqrt());
    let mut findings = vec![];
    // Cloned when the first reading is excluded or shifted: a clean recording is not copied.
    let mut cleaned: Option<Recording> = None;
    let mut changed = false;
    // The channels are screened independently (on `opts.threads` threads); what they found is
    // applied below in the order of one thread: encoders, load cells, tracker.
    //
    // Rows where a load cell's tension changes faster than its noise allows (its own local
    // test, two rows either side): the encoder's unstretched length follows the tension
    // (stretch, sag), so an encoder event there is physics, not a wild value.
    // The load cells' `z` are computed once: the tension-quiet mask here and the load-cell
    // screen below (the same readings excluded, so the same `z`) differ only in the quantum
    // floor (taken with and without the absurd values), applied to the shared MAD.
    let tension = |j: usize| {
        let f = rec.f.as_ref()?;
        let ch = Channel::new(&grid, (0..m).map(|i| f[i * n + j]).map(|v| if v.abs() <= ABSURD_N { v } else { f64::NAN }).collect(), seg);
        let mut zs = vec![f64::NAN; m];
        let (mad, nc) = mad_scale(&ch, &mut zs);
        let s = floored(mad, &ch.y, 1e-3);
        let thr = thr_of(nc) * s;
        let ev: Vec<bool> = zs.iter().map(|z| z.abs() > thr).collect();
        let quiet: Vec<bool> = (0..m).map(|i| ev[i.saturating_sub(2)..(i + 3).min(m)].iter().any(|x| *x)).collect();
        Some((quiet, (ch.y, s), (mad, nc)))
    };
    let tracker = |a: usize| {
        let mut ch = Channel::new(&grid, rec.p.iter().map(|p| p[a]).collect(), seg);
        screen_channel(&mut ch, ABSURD_M, 1e-7, thr_of, opts.jumps, &[], None).0
    };
    // A load cell's impossible tensions: (row, value, limit, sigmas), from its own column and
    // the MAD of its `z` only.
    let impossible = |j: usize, f: &[f64], (mad, nc): (f64, usize)| {
        let col: Vec<f64> = (0..m).map(|i| f[i * n + j]).collect();
        let s = floored(mad, &col, 1e-3);
        let mut loose: Vec<f64> = col.iter().copied().filter(|v| v.is_finite() && v.abs() <= ABSURD_N && *v < opts.min_tension_n).collect();
        let z0 = if loose.len() >= 20 {
            let k = loose.len() / 2;
            *loose.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
        } else {
            0.0
        };
        let low = if s.is_finite() { z0.min(0.0) - thr_of(nc) * s } else { f64::NEG_INFINITY };
        let high = opts.max_tension_n.filter(|h| *h > 0.0).unwrap_or(ABSURD_N).min(ABSURD_N);
        let mut bad_rows = vec![];
        for (i, &v) in col.iter().enumerate() {
            if v.is_nan() {
                continue;
            }
            let (bad, limit) = if !(v.abs() <= ABSURD_N) || v > high {
                (true, high)
            } else if v < low {
                (true, low)
            } else {
                (false, 0.0)
            };
            if bad {
                let sigmas = if v.is_finite() && v.abs() <= ABSURD_N && s > 0.0 { (v - z0.min(0.0)).abs() / s } else { f64::INFINITY };
                bad_rows.push((i, v, limit, sigmas));
            }
        }
        bad_rows
    };
    // Cable `j`: its load cell's `z` (which its encoder's test needs), its encoder, its
    // impossible tensions. One piece per cable and one per tracker axis, the cables (the longer
    // pieces) first, so that the threads end together.
    let cable = |j: usize| {
        let (quiet, col, mad) = match tension(j) {
            Some((quiet, col, mad)) => (quiet, Some(col), Some(mad)),
            None => (vec![], None, None),
        };
        let eseg = encoder_segments(rec, j, seg, opts.min_tension_n);
        let mut ch = Channel::new(&grid, (0..m).map(|i| rec.l[i * n + j]).collect(), &eseg);
        let (ev, _) = screen_channel(&mut ch, ABSURD_M, 1e-7, thr_of, opts.jumps, &quiet, col.as_ref().map(|(c, s)| (&c[..], *s)));
        let bad_rows = match (&rec.f, mad) {
            (Some(f), Some(mad)) => impossible(j, f, mad),
            _ => vec![],
        };
        ((ev, ch.y, ch.out), bad_rows)
    };
    let mut tracker_events = Vec::with_capacity(3);
    let mut encoders = Vec::with_capacity(n);
    let mut impossible_rows = Vec::with_capacity(n);
    for piece in crate::par::map(opts.threads, n + 3, |k| if k < n { Ok(cable(k)) } else { Err(tracker(k - n)) }) {
        match piece {
            Ok((enc, bad)) => {
                encoders.push(enc);
                impossible_rows.push(bad);
            }
            Err(ev) => tracker_events.push(ev),
        }
    }
    // Encoders.
    for (j, (ev, y, out)) in encoders.into_iter().enumerate() {
        for e in ev {
            changed = true;
            match e {
                Event::Spike(i, v, ex, s) => findings.push(WildValue {
                    kind: WildKind::EncoderSpike,
                    row: i,
                    t: rec.t[i],
                    cable: Some(j),
                    axis: None,
                    value: v,
                    expected: ex,
                    sigmas: s,
                    action: Action::Excluded,
                }),
                Event::Step(i, d, s) => findings.push(WildValue {
                    kind: WildKind::EncoderJump,
                    row: i,
                    t: rec.t[i],
                    cable: Some(j),
                    axis: None,
                    value: d,
                    expected: f64::NAN,
                    sigmas: s,
                    action: Action::ReReferenced { by_m: d, rows: i },
                }),
            }
        }
        if changed {
            let cleaned = cleaned.get_or_insert_with(|| rec.clone());
            for i in 0..m {
                cleaned.l[i * n + j] = if out[i] { f64::NAN } else { y[i] };
            }
        }
    }
    // Load cells.
    if rec.f.is_some() {
        for (j, bad_rows) in impossible_rows.into_iter().enumerate() {
            for (i, v, limit, sigmas) in bad_rows {
                changed = true;
                findings.push(WildValue {
                    kind: WildKind::ImpossibleTension,
                    row: i,
                    t: rec.t[i],
                    cable: Some(j),
                    axis: None,
                    value: v,
                    expected: limit,
                    sigmas,
                    action: Action::Excluded,
                });
                let cleaned = cleaned.get_or_insert_with(|| rec.clone());
                if let Some(cf) = cleaned.f.as_mut() {
                    cf[i * n + j] = f64::NAN;
                }
                cleaned.l[i * n + j] = f64::NAN;
            }
        }
    }
    // Tracker.
    let mut removed_rows = vec![false; m];
    for (a, ev) in tracker_events.into_iter().enumerate() {
        for e in ev {
            changed = true;
            match e {
                Event::Spike(i, v, ex, s) => {
                    if !removed_rows[i] {
                        findings.push(WildValue {
                            kind: WildKind::TrackerJump,
                            row: i,
                            t: rec.t[i],
                            cable: None,
                            axis: Some(a),
                            value: v,
                            expected: ex,
                            sigmas: s,
                            action: Action::Excluded,
                        });
                    }
                    removed_rows[i] = true;
                }
                Event::Step(i, d, s) => {
                    let (first, rows) = if i < m - i { (0, i) } else { (i, m - i) };
                    findings.push(WildValue {
                        kind: WildKind::TrackerJump,
                        row: i,
                        t: rec.t[i],
                        cable: None,
                        axis: Some(a),
                        value: d,
                        expected: f64::NAN,
                        sigmas: s,
                        action: Action::RowsExcluded { first, rows },
                    });
                    removed_rows[first..first + rows].iter_mut().for_each(|r| *r = true);
                }
            }
        }
    }
    for (i, r) in removed_rows.iter().enumerate() {
        if *r {
            cleaned.get_or_insert_with(|| rec.clone()).p[i] = [f64::NAN; 3];
        }
    }
    findings.sort_by_key(|w| (w.cable.is_none(), w.kind == WildKind::ImpossibleTension, w.cable, w.kind.name(), w.row));
    Screen { findings, cleaned: changed.then(|| cleaned.unwrap_or_else(|| rec.clone())), removed_rows, tests, threshold_sigmas: k }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{self, Rng};
    use crate::Params;

    #[test]
    fn quantile_inverts_the_tail() {
        for p in [1e-3, 1e-6, 1e-9, 1e-12] {
            let k = normal_upper_quantile(p);
            assert!((normal_sf(k) / p - 1.0).abs() < 1e-4, "{p} {k}");
        }
        assert!((normal_upper_quantile(0.025) - 1.959964).abs() < 1e-5);
    }

    /// A smooth synthetic recording: the platform on a random sum of sinusoids (Lissajous-like,
    /// up to `speed` m/s) inside the robot, Gaussian tracker, encoder and load-cell noise,
    /// tensions that vary smoothly with a few loose stretches near zero.
    pub(crate) fn smooth(truth: &Params, m: usize, rate: f64, tracker_sigma: f64, enc_sigma: f64, seed: u64) -> Recording {
        let n = truth.n_cables();
        let mut rng = Rng::new(seed);
        let c: [f64; 3] = std::array::from_fn(|k| truth.anchors.iter().map(|a| a[k]).sum::<f64>() / n as f64);
        let span: [f64; 3] = [1.0, 0.8, 0.6];
        let comps: Vec<[(f64, f64, f64); 3]> =
            (0..3).map(|_| std::array::from_fn(|k| (span[k] / 3.0, rng.range(0.1, 0.6), rng.range(0.0, 6.3)))).collect();
        let mut rec = Recording::with_capacity(n, m, true, false, false);
        let (mut l, mut f) = (vec![0.0; n], vec![0.0; n]);
        let off: Vec<f64> = (0..n).map(|_| 0.5 * rng.normal()).collect();
        let ph: Vec<f64> = (0..n).map(|_| rng.range(0.0, 6.3)).collect();
        for i in 0..m {
            let t = i as f64 / rate;
            let mut p = [c[0], c[1], 0.4 * c[2]];
            for comp in &comps {
                for k in 0..3 {
                    let (a, w, phi) = comp[k];
                    p[k] += a * (w * t + phi).sin();
                }
            }
            for j in 0..n {
                let rho = crate::model::norm(crate::model::sub(p, truth.anchors[j]));
                l[j] = rho + truth.l0[j] + enc_sigma * rng.normal();
                let tension = 25.0 * (0.3 * t + ph[j]).sin() + 20.0;
                f[j] = tension.max(0.0) + off[j] + 0.3 * rng.normal();
            }
            let pm: [f64; 3] = std::array::from_fn(|k| p[k] + tracker_sigma * rng.normal());
            rec.push(t, pm, None, &l, Some(&f), None);
        }
        rec
    }

    fn geometries() -> Vec<Params> {
        let big = Params {
            anchors: vec![[10.0, -10.0, 12.0], [10.0, 10.0, 12.0], [-10.0, 10.0, 12.0], [-10.0, -10.0, 12.0]],
            l0: vec![1.0, -2.0, 0.5, 3.0],
        };
        vec![synth::aras_cam(), synth::tri3(), big]
    }

    /// The stated false-alarm rate is 1e-3 per recording: over 60 clean recordings (three
    /// geometries, two noise levels, 50 and 100 Hz) no flag at all is expected (P(any) <= 6%).
    #[test]
    fn no_flag_on_sixty_clean_recordings() {
        let mut total = 0;
        for (g, truth) in geometries().iter().enumerate() {
            for s in 0..20u64 {
                let (ts, es, rate) = if s % 2 == 0 { (1.5e-3, 5e-5, 100.0) } else { (0.5e-3, 2e-5, 50.0) };
                let rec = smooth(truth, 3000, rate, ts, es, 1000 * g as u64 + s);
                let sc = screen(&rec, &ScreenOptions::new(3.0));
                assert!(
                    sc.findings.is_empty(),
                    "geometry {g} seed {s}: {:#?}",
                    sc.findings.iter().map(|w| w.to_string()).collect::<Vec<_>>()
                );
                assert!(sc.cleaned.is_none());
                total += 1;
            }
        }
        assert_eq!(total, 60);
    }

    #[test]
    fn finds_spikes_from_a_few_thresholds_up_and_absurd_values_at_their_row() {
        let truth = synth::aras_cam();
        let clean = smooth(&truth, 3000, 100.0, 1.5e-3, 5e-5, 77);
        let base = screen(&clean, &ScreenOptions::new(3.0));
        assert!(base.findings.is_empty());
        let k = base.threshold_sigmas;
        // Encoder noise scale of the interpolation residual is the encoder sigma.
        for (q, v) in [(0usize, 1.5 * k * 5e-5), (1, 4.0 * k * 5e-5), (2, 0.05), (3, 1e308), (1, 1e160), (2, -1e308), (0, f64::INFINITY)] {
            let mut rec = clean.clone();
            let row = 1234 + 17 * q;
            let n = rec.n_cables;
            if v.abs() < 1.0 {
                rec.l[row * n + q] += v;
            } else {
                rec.l[row * n + q] = v;
            }
            let sc = screen(&rec, &ScreenOptions::new(3.0));
            assert_eq!(sc.findings.len(), 1, "{v:e}: {:#?}", sc.findings.iter().map(|w| w.to_string()).collect::<Vec<_>>());
            let w = sc.findings[0];
            assert_eq!((w.kind, w.row, w.cable), (WildKind::EncoderSpike, row, Some(q)), "{w}");
            let c = sc.cleaned.as_ref().unwrap();
            assert!(c.l[row * n + q].is_nan());
            let others = (0..rec.l.len()).filter(|&x| x != row * n + q).all(|x| c.l[x] == clean.l[x]);
            assert!(others, "only the wild reading changes");
        }
    }

    #[test]
    fn spikes_at_the_ends_of_the_recording_are_found() {
        let truth = synth::tri3();
        let mut rec = smooth(&truth, 2000, 100.0, 1.5e-3, 5e-5, 80);
        let n = rec.n_cables;
        // Cables taut at the ends (a slack cable's encoder is not tested locally).
        let f = rec.f.clone().unwrap();
        let taut = |rows: std::ops::Range<usize>| (0..n).find(|&j| rows.clone().all(|i| f[i * n + j] > 10.0)).unwrap();
        let (a, b) = (taut(0..6), taut(1994..2000));
        rec.l[a] += 0.05;
        rec.l[1999 * n + b] -= 0.05;
        let sc = screen(&rec, &ScreenOptions::new(3.0));
        let mut got: Vec<(usize, Option<usize>)> = sc.findings.iter().map(|w| (w.row, w.cable)).collect();
        got.sort();
        assert_eq!(got, vec![(0, Some(a)), (1999, Some(b))], "{:#?}", sc.findings);
    }

    #[test]
    fn a_jump_is_re_referenced_onto_the_later_count() {
        let truth = synth::aras_cam();
        let clean = smooth(&truth, 3000, 100.0, 1.5e-3, 5e-5, 78);
        let mut rec = clean.clone();
        let n = rec.n_cables;
        for i in 2000..3000 {
            rec.l[i * n + 2] += 0.02;
        }
        let sc = screen(&rec, &ScreenOptions::new(3.0));
        assert_eq!(sc.findings.len(), 1, "{:#?}", sc.findings);
        let w = sc.findings[0];
        assert_eq!((w.kind, w.row, w.cable), (WildKind::EncoderJump, 2000, Some(2)), "{w}");
        assert!((w.value - 0.02).abs() < 1e-4, "{w}");
        let c = sc.cleaned.unwrap();
        // Earlier readings moved onto the later reference to the step's local precision.
        assert!((c.l[1000 * n + 2] - (clean.l[1000 * n + 2] + 0.02)).abs() < 1e-4);
        assert_eq!(c.l[2500 * n + 2], rec.l[2500 * n + 2]);
    }

    #[test]
    fn tracker_jump_and_impossible_tensions() {
        let truth = synth::tri3();
        let clean = smooth(&truth, 3000, 100.0, 1.5e-3, 5e-5, 79);
        let mut rec = clean.clone();
        let n = rec.n_cables;
        rec.p[700][1] = 1e308;
        rec.p[1500][2] += 0.03;
        let f = rec.f.as_mut().unwrap();
        f[900 * n + 1] = f64::INFINITY;
        f[1100 * n] = -50.0;
        f[1300 * n + 2] = 1e200;
        let sc = screen(&rec, &ScreenOptions::new(3.0));
        let got: Vec<(WildKind, usize, Option<usize>)> = sc.findings.iter().map(|w| (w.kind, w.row, w.cable)).collect();
        assert_eq!(
            got,
            vec![
                (WildKind::ImpossibleTension, 1100, Some(0)),
                (WildKind::ImpossibleTension, 900, Some(1)),
                (WildKind::ImpossibleTension, 1300, Some(2)),
                (WildKind::TrackerJump, 700, None),
                (WildKind::TrackerJump, 1500, None),
            ],
            "{:#?}",
            sc.findings.iter().map(|w| w.to_string()).collect::<Vec<_>>()
        );
        let c = sc.cleaned.unwrap();
        assert!(c.p[700][0].is_nan() && c.p[1500][0].is_nan() && c.l[900 * n + 1].is_nan());
        assert!(sc.removed_rows[700] && !sc.removed_rows[701]);
    }

    /// A tracker step that stays: with `jumps` the shorter side is excluded (a re-registered
    /// tracker); without (the daemon's data sets) at most the readings at the step are, so a
    /// start-up's earlier phases keep their poses.
    #[test]
    fn a_tracker_step_drops_its_shorter_side_only_with_jumps() {
        let truth = synth::tri3();
        let clean = smooth(&truth, 3000, 100.0, 1.5e-3, 5e-5, 83);
        let mut rec = clean.clone();
        for p in &mut rec.p[1200..] {
            p[0] += 0.03;
        }
        let sc = screen(&rec, &ScreenOptions::new(3.0));
        let steps: Vec<Action> = sc.findings.iter().filter(|w| w.kind == WildKind::TrackerJump).map(|w| w.action).collect();
        assert_eq!(steps, vec![Action::RowsExcluded { first: 0, rows: 1200 }], "{:#?}", sc.findings);
        let daemon = screen(&rec, &ScreenOptions { jumps: false, ..ScreenOptions::new(3.0) });
        let dropped = daemon.removed_rows.iter().filter(|r| **r).count();
        assert!(dropped <= 4, "{dropped} rows dropped: {:#?}", daemon.findings);
        assert!(daemon.findings.iter().all(|w| w.action == Action::Excluded && w.row.abs_diff(1200) <= 2), "{:#?}", daemon.findings);
    }

    /// The channels on several threads find the same, in the same order, and clean the same
    /// readings (bit for bit), with every kind of wild value in one recording.
    #[test]
    fn threads_find_the_same() {
        let truth = synth::aras_cam();
        let clean = smooth(&truth, 3000, 100.0, 1.5e-3, 5e-5, 81);
        let mut rec = clean.clone();
        let n = rec.n_cables;
        rec.l[400 * n + 1] = 1e308;
        rec.l[1234 * n + 3] += 0.05;
        for i in 2000..3000 {
            rec.l[i * n + 2] += 0.02;
        }
        rec.p[700][1] = 1e308;
        rec.p[1500][2] += 0.03;
        let f = rec.f.as_mut().unwrap();
        f[900 * n + 1] = f64::INFINITY;
        f[1100 * n] = -50.0;
        let show = |sc: &Screen| format!("{:?} {:?} {:?} {} {}", sc.findings, sc.cleaned, sc.removed_rows, sc.tests, sc.threshold_sigmas);
        for r in [&clean, &rec] {
            let one = screen(r, &ScreenOptions::new(3.0));
            for threads in [2, 3, 16] {
                assert_eq!(show(&screen(r, &ScreenOptions { threads, ..ScreenOptions::new(3.0) })), show(&one), "{threads} threads");
            }
        }
        assert!(screen(&rec, &ScreenOptions { threads: 2, ..ScreenOptions::new(3.0) }).findings.len() >= 6);
    }
}
