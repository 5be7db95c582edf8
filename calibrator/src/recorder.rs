//! What the calibrator thread writes and collects from the loop's samples: the
//! `cdpr-recording v1` file ([`RecordingWriter`], flushed and synced at least once a second), and the
//! data sets' rows, each with the encoder lengths and load-cell tensions interpolated to the time
//! of the row's pose (the readings and the pose arrive with their own ages).

use crate::vocab::{CalibratorConfig, RecorderError};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};
use taut_config::recording::Recording;
use taut_rt::motion::State;
use taut_rt::sample::Sample;

/// Writes samples as `cdpr-recording v1` rows as they come, flushed (and synced) at least once a
/// second, so a crash loses at most the last second.
pub struct RecordingWriter {
    pub(crate) path: PathBuf,
    pub(crate) file: std::io::BufWriter<std::fs::File>,
    pub(crate) n: usize,
    pub(crate) line: String,
    pub(crate) last_flush: Instant,
    pub(crate) tracker_max_age_s: f64,
    pub(crate) tension_max_age_s: f64,
    /// Rows written.
    pub rows: u64,
}

impl RecordingWriter {
    /// Creates the file and writes the header.
    pub fn create(path: &Path, n: usize, robot: &str, tracker_max_age_s: f64, tension_max_age_s: f64) -> std::io::Result<RecordingWriter> {
        if let Some(d) = path.parent() {
            std::fs::create_dir_all(d)?;
        }
        let mut file = std::io::BufWriter::with_capacity(1 << 16, std::fs::File::create(path)?);
        writeln!(file, "{}", taut_config::recording::MAGIC)?;
        writeln!(file, "# robot: {robot}; written by taut start; state column: motion state of the loop")?;
        let mut h = String::from("t,px,py,pz");
        for j in 0..n {
            let _ = write!(h, ",l{j}");
        }
        for j in 0..n {
            let _ = write!(h, ",f{j}");
        }
        h.push_str(",phase,state");
        writeln!(file, "{h}")?;
        file.flush()?;
        Ok(RecordingWriter {
            path: path.to_path_buf(),
            file,
            n,
            line: String::with_capacity(512),
            last_flush: Instant::now(),
            tracker_max_age_s,
            tension_max_age_s,
            rows: 0,
        })
    }

    /// The error of a failed write, naming the file.
    pub(crate) fn error(&self, e: std::io::Error) -> RecorderError {
        RecorderError::Csv { path: self.path.clone(), error: Arc::new(e) }
    }

    /// Appends one sample.
    pub fn push(&mut self, s: &Sample) -> std::io::Result<()> {
        let l = &mut self.line;
        l.clear();
        let _ = write!(l, "{:.6}", s.t);
        let pose_ok = s.pose_age_s <= self.tracker_max_age_s;
        for v in s.pose_m {
            l.push(',');
            if pose_ok && v.is_finite() {
                let _ = write!(l, "{v:.6}");
            }
        }
        for j in 0..self.n {
            l.push(',');
            if s.length_m[j].is_finite() {
                let _ = write!(l, "{:.7}", s.length_m[j]);
            }
        }
        for j in 0..self.n {
            l.push(',');
            if s.tension_age_s[j] <= self.tension_max_age_s && s.tension_n[j].is_finite() {
                let _ = write!(l, "{:.3}", s.tension_n[j]);
            }
        }
        let _ = writeln!(l, ",{},{}", s.phase, State::from_u8(s.state).name());
        self.file.write_all(l.as_bytes())?;
        self.rows += 1;
        if self.last_flush.elapsed() >= Duration::from_millis(500) {
            self.flush()?;
        }
        Ok(())
    }

    /// Flushes to the disk.
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.last_flush = Instant::now();
        self.file.flush()?;
        self.file.get_ref().sync_data()
    }
}

/// The recent encoder lengths (or load-cell tensions) with the times they were measured
/// (`t - length_age`, `t - tension_age`), to read them at the instant a tracker pose was
/// measured.
#[derive(Debug, Default)]
pub(crate) struct LengthHistory {
    pub(crate) rows: std::collections::VecDeque<([f64; taut_rt::MAX_CABLES], [f64; taut_rt::MAX_CABLES])>,
}

/// Rows kept: 128 loop cycles (a quarter of a second at 500 Hz), far more than any pose age
/// the loop accepts as fresh.
const HISTORY: usize = 128;
/// Longest extrapolation of the lengths past the newest reading, s (a few loop cycles).
const MAX_EXTRAPOLATION_S: f64 = 0.01;

impl LengthHistory {
    pub(crate) fn push(&mut self, s: &Sample, n: usize) {
        self.push_readings(s.t, &s.length_age_s, &s.length_m, n);
    }

    /// The readings `v` of a sample at `t`, each `age` old.
    pub(crate) fn push_readings(&mut self, now: f64, age: &[f64; taut_rt::MAX_CABLES], v: &[f64; taut_rt::MAX_CABLES], n: usize) {
        let mut t = [f64::NAN; taut_rt::MAX_CABLES];
        for (tj, age) in t[..n].iter_mut().zip(&age[..n]) {
            *tj = now - age.max(0.0);
        }
        if self.rows.back().is_some_and(|(tb, _)| tb[..n] == t[..n]) {
            return;
        }
        if self.rows.len() == HISTORY {
            self.rows.pop_front();
        }
        self.rows.push_back((t, *v));
    }

    /// Has every cable with readings a reading at or after `at`? Then [`LengthHistory::at`]
    /// interpolates there instead of extrapolating.
    pub(crate) fn covers(&self, n: usize, at: f64) -> bool {
        (0..n).all(|j| {
            let newest = self.rows.iter().rev().find(|(t, l)| t[j].is_finite() && l[j].is_finite());
            newest.is_none_or(|(t, _)| t[j] >= at)
        })
    }

    /// Cable `j`'s length at time `at`, interpolated between the two readings around it. A pose
    /// newer than the newest reading (measured after the last SYNC) is common: the length is
    /// extrapolated from the last two readings, up to [`MAX_EXTRAPOLATION_S`]; older than the
    /// history, the oldest reading.
    pub(crate) fn at(&self, j: usize, at: f64) -> f64 {
        self.at_within(j, at, MAX_EXTRAPOLATION_S)
    }

    /// [`LengthHistory::at`], extrapolating at most `max_extrapolation_s` past the newest
    /// reading (0: the newest reading is held).
    pub(crate) fn at_within(&self, j: usize, at: f64, max_extrapolation_s: f64) -> f64 {
        // Cable j's readings, newest first.
        let mut it = self.rows.iter().rev().filter_map(|(t, l)| (t[j].is_finite() && l[j].is_finite()).then_some((t[j], l[j])));
        let Some(mut b) = it.next() else { return f64::NAN };
        if at >= b.0 {
            return match it.next() {
                Some(a) if b.0 > a.0 && at - b.0 <= max_extrapolation_s => b.1 + (at - b.0) / (b.0 - a.0) * (b.1 - a.1),
                _ => b.1,
            };
        }
        for a in it {
            if a.0 <= at {
                return if b.0 > a.0 { a.1 + (at - a.0) / (b.0 - a.0) * (b.1 - a.1) } else { a.1 };
            }
            b = a;
        }
        b.1
    }
}

/// Longest a tracker row waits for the encoder readings after its pose's instant, s (loop
/// cycles late on a loaded machine); after that its lengths are extrapolated.
pub(crate) const MAX_PENDING_S: f64 = 0.02;

/// Longest a tracker row waits for every load cell's next reading after its pose's instant, s
/// (a polling round of four cells at 115200 baud is ~15 ms; a lost frame or a slower bus
/// more); after that a cable's tension is its newest reading.
pub(crate) const MAX_PENDING_TENSION_S: f64 = 0.1;

/// The data set a tracker row goes to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum RowSet {
    Init,
    Excitation,
}

/// Appends a sample to a data set (missing values as NaN). The encoder lengths are read at the
/// time the pose was measured (`t - pose_age`) from the recent history: a pose a few
/// milliseconds older than the lengths would be a systematic error along the motion, which
/// the anchors would absorb (a 2 ms shift doubles the anchor error of a 25 s excitation).
///
/// With a time offset `delta` in the running parameters (the encoders lag the tracker: a
/// reading at `t` is the length at `t - delta`), the lengths are read at `t_pose + delta`.
///
/// The tensions likewise, interpolated at the lengths' instant between the load cells'
/// readings around it (a cell's reading is up to a polling round old; while the platform
/// swings the tension, and with it a cable's stretch `T L / EA`, changes within a round). A
/// cable whose newest reading at the sample is older than `tension_max_age_s` has none.
pub(crate) fn push_sample(
    rec: &mut Recording,
    hist: &LengthHistory,
    tensions: &LengthHistory,
    s: &Sample,
    cfg: &CalibratorConfig,
    time_offset_s: f64,
) {
    let n = cfg.n;
    let p = if s.pose_age_s <= cfg.tracker_max_age_s { s.pose_m } else { [f64::NAN; 3] };
    let tp = s.t - s.pose_age_s.max(0.0);
    let mut l = [f64::NAN; taut_rt::MAX_CABLES];
    for (j, x) in l.iter_mut().enumerate().take(n) {
        *x = hist.at(j, tp + time_offset_s);
    }
    let mut f = [f64::NAN; taut_rt::MAX_CABLES];
    for (j, (fj, &age)) in f[..n].iter_mut().zip(&s.tension_age_s[..n]).enumerate() {
        if age <= cfg.tension_max_age_s {
            *fj = tensions.at_within(j, tp + time_offset_s, 0.0);
        }
    }
    rec.push(tp, p, None, &l[..n], Some(&f[..n]), Some(i32::from(s.phase)));
}
