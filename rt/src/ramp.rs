//! Bumpless transfer: when the source of the commanded lengths changes (new parameters, or
//! switching from holding encoder lengths to inverse kinematics), the jump between the old and
//! the new command is not applied at once but faded out over a configured time.
//!
//! With `Δ_j` the jump at the switch and `s = t / T`, the command is
//! `new_j(t) + Δ_j (1 - (3s² - 2s³))`: continuous in value and in speed, with the largest
//! per-cycle change from the ramp `1.5 |Δ_j| dt / T`.

use crate::MAX_CABLES;

/// A fading length offset, and the largest per-cycle change of the commands while it fades.
#[derive(Debug, Clone, Copy)]
pub struct Ramp {
    offset: [f64; MAX_CABLES],
    duration_s: f64,
    s: f64,
    active: bool,
    last: [f64; MAX_CABLES],
    have_last: bool,
    /// Largest per-cycle change of any commanded length while a ramp was active, m (since
    /// construction or the last [`Ramp::reset_max`]).
    pub max_step_m: f64,
}

impl Ramp {
    /// A ramp that fades over `duration_s`.
    pub fn new(duration_s: f64) -> Ramp {
        Ramp { offset: [0.0; MAX_CABLES], duration_s, s: 1.0, active: false, last: [0.0; MAX_CABLES], have_last: false, max_step_m: 0.0 }
    }

    /// True while an offset is fading.
    pub fn active(&self) -> bool {
        self.active
    }

    /// Fraction of the fade done, 0..=1.
    pub fn progress(&self) -> f64 {
        self.s
    }

    /// Forgets the largest step seen.
    pub fn reset_max(&mut self) {
        self.max_step_m = 0.0;
    }

    /// Starts fading from `previous` (what was commanded last cycle) to `next` (the new source's
    /// command for this cycle).
    pub fn start(&mut self, n: usize, previous: &[f64; MAX_CABLES], next: &[f64; MAX_CABLES]) {
        for j in 0..n {
            let d = previous[j] - next[j];
            self.offset[j] = if d.is_finite() { d } else { 0.0 };
        }
        self.s = 0.0;
        self.active = true;
        self.last = *previous;
        self.have_last = true;
    }

    /// Applies the fading offset to this cycle's command `cmd` in place and advances by `dt_s`.
    /// Only cables with `measured[j]` (the position-mode ones) count towards `max_step_m`.
    pub fn apply(&mut self, n: usize, dt_s: f64, cmd: &mut [f64; MAX_CABLES], measured: &[bool; MAX_CABLES]) {
        if !self.active {
            return;
        }
        self.s = (self.s + dt_s / self.duration_s).min(1.0);
        let w = 1.0 - self.s * self.s * (3.0 - 2.0 * self.s);
        for j in 0..n {
            cmd[j] += self.offset[j] * w;
            if self.have_last && measured[j] {
                let step = (cmd[j] - self.last[j]).abs();
                if step > self.max_step_m {
                    self.max_step_m = step;
                }
            }
            self.last[j] = cmd[j];
        }
        self.have_last = true;
        if self.s >= 1.0 {
            self.active = false;
            self.have_last = false;
        }
    }

    /// Stops any fade at once (a safety reaction takes over the commands).
    pub fn cancel(&mut self) {
        self.active = false;
        self.have_last = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fade_is_bounded_and_ends_at_the_new_command() {
        let dt = 0.002;
        let mut r = Ramp::new(2.0);
        let prev = [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let next = [1.05, 1.98, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        r.start(3, &prev, &next);
        let mut steps = 0;
        while r.active() {
            let mut c = next;
            r.apply(3, dt, &mut c, &[true; MAX_CABLES]);
            steps += 1;
        }
        assert_eq!(steps, 1000);
        let bound = 1.5 * 0.05 * dt / 2.0;
        assert!(r.max_step_m <= bound * 1.001, "{} > {bound}", r.max_step_m);
        assert!(r.max_step_m > bound * 0.99);
        let mut c = next;
        r.apply(3, dt, &mut c, &[true; MAX_CABLES]);
        assert_eq!(c, next);
    }
}
