//! The Levenberg–Marquardt iteration shared by every least-squares fit of the crate.
//!
//! ```text
//! solve     (H + lambda D) dx = g          the problem's own normal equations and damping D
//! trial     x' = x (+) dx                  the problem's own update (projection, retraction)
//! accept    F(x') < F(x)                   (or <= with `accept_ties`), lambda shrinks
//! reject    lambda grows, x stays
//! stop      gradient / small step / small cost change / iteration limit / lambda limit
//! ```
//!
//! The fits differ in their linear algebra, not in the iteration: the per-cable calibration
//! ([`crate::solver`]) solves a 4x4 system accumulated in a SIMD pass over 100 000 readings, the
//! effect models ([`dense`]) a dense system from sparse Jacobian rows, the
//! self-calibration ([`crate::selfcal::solve`]) and the bundle adjustment ([`crate::bundle`]) a
//! Schur complement over thousands of poses (the first with gauge constraints), the circle fit
//! ([`crate::init::circle`]) a 6x6 system on a sphere of normals, the rest estimate
//! ([`crate::selfcal::rest`]) a 3x3 force balance with a bounded step. Each implements
//! [`Problem`]: its cost, its damped step and its update. [`minimize`] owns everything else —
//! the damping schedule, the acceptance of a step, the stopping rules and the counting of
//! iterations — and each fit states its choices in one [`Policy`] value next to its problem.
//!
//! Two damping schedules are in use ([`Damping`]): Nielsen's rule on the gain ratio
//! (actual / predicted decrease) where the problem can predict its decrease cheaply, and fixed
//! factors otherwise. Iterations count either every solve ([`Count::Attempts`], where one
//! attempt is one pass over the data) or every accepted step with a budget of retries per step
//! ([`Count::Steps`]).

pub mod dense;

/// A least-squares problem, as far as the iteration needs to know it.
///
/// `cost` is called for the start and for every trial point; `accepted` tells the problem that
/// the last point given to `cost` is now the current one (a problem that builds its normal
/// equations in the same pass as the cost keeps them then; one that does not builds them in the
/// next `step`).
pub trait Problem {
    /// The parameters.
    type X: Clone;
    /// A proposed step, with whatever the stopping tests need of it.
    type Step;

    /// The cost at `x`. Non-finite costs are never accepted.
    fn cost(&mut self, x: &Self::X) -> f64;
    /// The point last given to [`Problem::cost`] became the current point.
    fn accepted(&mut self) {}
    /// The step from the current point `x` with damping `lambda`; `None` when the damped system
    /// is singular.
    fn step(&mut self, x: &Self::X, lambda: f64) -> Option<Self::Step>;
    /// The trial point `x (+) step` (including any projection onto the feasible set).
    fn apply(&self, x: &Self::X, step: &Self::Step) -> Self::X;

    /// Converged at the current point before any step (a gradient test).
    fn converged(&self, _x: &Self::X, _cost: f64) -> bool {
        false
    }
    /// The proposed step is below the tolerance: stop at `x` without evaluating `x (+) step`.
    fn negligible(&self, _step: &Self::Step) -> bool {
        false
    }
    /// After an accepted step from `x`: the step was negligible, stop.
    fn small_step(&self, _x: &Self::X, _step: &Self::Step) -> bool {
        false
    }
    /// After a rejected step from `x` (cost `cost`): no step can change `x` any more (round-off).
    fn at_minimum(&self, _x: &Self::X, _step: &Self::Step, _cost: f64) -> bool {
        false
    }
    /// The decrease the local quadratic model predicts for `step` (`g.dx - dx^T H dx / 2`), for
    /// [`Damping::Nielsen`] and [`CostTest::WithPredicted`].
    fn predicted_decrease(&self, _step: &Self::Step) -> f64 {
        f64::NAN
    }
}

/// How the damping moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Damping {
    /// Nielsen's rule: after an accepted step with gain ratio `rho` (actual over predicted
    /// decrease) `lambda *= max(min_factor, 1 - (2 rho - 1)^3)`; after a rejected step or a
    /// singular system `lambda *= nu`, `nu *= 2` (`nu` back to 2 at the next accepted step).
    Nielsen {
        /// Smallest factor an accepted step shrinks `lambda` by.
        min_factor: f64,
    },
    /// Fixed factors.
    Factors {
        /// Accepted step: `lambda /= down`.
        down: f64,
        /// Rejected step: `lambda *= up`.
        up: f64,
        /// Singular damped system: `lambda *= singular`.
        singular: f64,
    },
}

/// What counts as an iteration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Count {
    /// Every solve of the damped system (accepted, rejected or singular).
    Attempts,
    /// Every accepted step; a step gives up after `max_tries` rejected or singular solves.
    Steps {
        /// Retries of one step before it stops.
        max_tries: usize,
    },
}

/// The cost test after an accepted step (`act = F(x) - F(x')`, `F = F(x)`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CostTest {
    /// None.
    None,
    /// `act < tol max(F, 1e-300)`.
    Relative(f64),
    /// `act <= tol F` and the predicted decrease `<= tol F` (MINPACK's ftol).
    WithPredicted(f64),
    /// `act < tol`: for a chi-square, where a change of `tol` moves the parameters by a fixed
    /// fraction of a sigma.
    Absolute(f64),
}

/// The iteration policy of one fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Policy {
    /// Starting damping.
    pub lambda0: f64,
    /// Its schedule.
    pub damping: Damping,
    /// Floor of `lambda` after an accepted step.
    pub min_lambda: f64,
    /// Beyond this `lambda` no damping makes a step decrease the cost: stop.
    pub max_lambda: f64,
    /// Iteration limit, counted as [`Policy::count`] says.
    pub max_iterations: usize,
    /// What an iteration is.
    pub count: Count,
    /// Accept a step that leaves the cost unchanged (`F(x') <= F(x)`).
    pub accept_ties: bool,
    /// A singular damped system ends the fit ([`Stop::Singular`]) instead of raising `lambda`.
    pub singular_stops: bool,
    /// The cost test after an accepted step.
    pub cost_test: CostTest,
}

impl Policy {
    /// Fixed-factor damping (`lambda` / 3 on success, `* up` on failure, `* 10` when singular),
    /// counted per attempt, no cost test: the fields a fit changes are set after it.
    pub const fn factors(lambda0: f64, up: f64, max_iterations: usize) -> Policy {
        Policy {
            lambda0,
            damping: Damping::Factors { down: 3.0, up, singular: 10.0 },
            min_lambda: 1e-12,
            max_lambda: f64::INFINITY,
            max_iterations,
            count: Count::Attempts,
            accept_ties: false,
            singular_stops: false,
            cost_test: CostTest::None,
        }
    }
}

/// Why the iteration stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    /// [`Problem::converged`] at the current point.
    SmallGradient,
    /// A negligible step ([`Problem::negligible`], [`Problem::small_step`],
    /// [`Problem::at_minimum`]).
    SmallStep,
    /// The cost test passed.
    SmallCostChange,
    /// The iteration limit.
    MaxIterations,
    /// No step decreased the cost: `lambda` beyond its limit or the retries spent.
    NoDecrease,
    /// The damped system stayed singular (or was singular once, with
    /// [`Policy::singular_stops`]).
    Singular,
    /// The cost at the start is not finite.
    NotFinite,
}

/// The result of [`minimize`].
#[derive(Debug, Clone)]
pub struct Outcome<X> {
    /// The last accepted point.
    pub x: X,
    /// Its cost.
    pub cost: f64,
    /// Iterations, counted as the policy says.
    pub iterations: usize,
    /// Why it stopped.
    pub stop: Stop,
}

/// Levenberg–Marquardt from `x0` under `policy`.
pub fn minimize<P: Problem>(p: &mut P, x0: P::X, policy: &Policy) -> Outcome<P::X> {
    let mut x = x0;
    let mut cost = p.cost(&x);
    p.accepted();
    let done = |x, cost, iterations, stop| Outcome { x, cost, iterations, stop };
    if !cost.is_finite() {
        return done(x, cost, 0, Stop::NotFinite);
    }
    let mut lambda = policy.lambda0;
    let mut nu = 2.0;
    let (max_tries, per_attempt) = match policy.count {
        Count::Attempts => (usize::MAX, true),
        Count::Steps { max_tries } => (max_tries, false),
    };
    let mut iterations = 0;
    let mut tries = 0;
    let mut fresh = true;
    loop {
        let counts = per_attempt || fresh;
        if counts && iterations >= policy.max_iterations {
            return done(x, cost, iterations, Stop::MaxIterations);
        }
        if p.converged(&x, cost) {
            return done(x, cost, iterations, Stop::SmallGradient);
        }
        if counts {
            iterations += 1;
            tries = 0;
            fresh = false;
        }
        let Some(step) = p.step(&x, lambda) else {
            if policy.singular_stops {
                return done(x, cost, iterations, Stop::Singular);
            }
            match policy.damping {
                Damping::Nielsen { .. } => {
                    lambda *= nu;
                    nu *= 2.0;
                }
                Damping::Factors { singular, .. } => lambda *= singular,
            }
            tries += 1;
            if lambda > policy.max_lambda || tries > max_tries {
                return done(x, cost, iterations, Stop::Singular);
            }
            continue;
        };
        if p.negligible(&step) {
            return done(x, cost, iterations, Stop::SmallStep);
        }
        let xn = p.apply(&x, &step);
        let cn = p.cost(&xn);
        if cn.is_finite() && (cn < cost || (policy.accept_ties && cn <= cost)) {
            let act = cost - cn;
            let old = cost;
            match policy.damping {
                Damping::Nielsen { min_factor } => {
                    let rho = act / p.predicted_decrease(&step).max(f64::MIN_POSITIVE);
                    lambda = (lambda * (1.0 - (2.0 * rho - 1.0).powi(3)).max(min_factor)).max(policy.min_lambda);
                    nu = 2.0;
                }
                Damping::Factors { down, .. } => lambda = (lambda / down).max(policy.min_lambda),
            }
            p.accepted();
            let small = p.small_step(&x, &step);
            x = xn;
            cost = cn;
            fresh = true;
            if small {
                return done(x, cost, iterations, Stop::SmallStep);
            }
            let converged = match policy.cost_test {
                CostTest::None => false,
                CostTest::Relative(tol) => act / old.max(1e-300) < tol,
                CostTest::WithPredicted(tol) => act <= tol * old && p.predicted_decrease(&step) <= tol * old,
                CostTest::Absolute(tol) => act < tol,
            };
            if converged {
                return done(x, cost, iterations, Stop::SmallCostChange);
            }
        } else {
            if p.at_minimum(&x, &step, cost) {
                return done(x, cost, iterations, Stop::SmallStep);
            }
            match policy.damping {
                Damping::Nielsen { .. } => {
                    lambda *= nu;
                    nu *= 2.0;
                }
                Damping::Factors { up, .. } => lambda *= up,
            }
            tries += 1;
            if lambda > policy.max_lambda || tries > max_tries {
                return done(x, cost, iterations, Stop::NoDecrease);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `F(x) = 1 + (x - 3)^2 / 2` with its damped Newton step: a few accepted steps, then the
    /// cost test.
    struct Parabola;
    impl Problem for Parabola {
        type X = f64;
        type Step = f64;
        fn cost(&mut self, x: &f64) -> f64 {
            1.0 + 0.5 * (x - 3.0) * (x - 3.0)
        }
        fn step(&mut self, x: &f64, lambda: f64) -> Option<f64> {
            Some((3.0 - x) / (1.0 + lambda))
        }
        fn apply(&self, x: &f64, s: &f64) -> f64 {
            x + s
        }
    }

    #[test]
    fn a_quadratic_converges_and_stops_on_the_cost() {
        let policy = Policy { cost_test: CostTest::Relative(1e-12), ..Policy::factors(1e-3, 4.0, 50) };
        let r = minimize(&mut Parabola, 0.0, &policy);
        assert!((r.x - 3.0).abs() < 1e-9, "{}", r.x);
        assert_eq!(r.stop, Stop::SmallCostChange);
        assert!(r.iterations <= 5, "{}", r.iterations);
    }

    /// A problem whose steps never decrease the cost: the lambda limit ends it, per attempt.
    struct Uphill;
    impl Problem for Uphill {
        type X = f64;
        type Step = f64;
        fn cost(&mut self, x: &f64) -> f64 {
            -x.abs()
        }
        fn step(&mut self, _x: &f64, lambda: f64) -> Option<f64> {
            Some(1e-3 / (1.0 + lambda))
        }
        fn apply(&self, x: &f64, s: &f64) -> f64 {
            x - s
        }
    }

    #[test]
    fn no_decrease_stops_at_the_lambda_limit() {
        let policy = Policy { max_lambda: 1e3, ..Policy::factors(1.0, 10.0, 100) };
        let r = minimize(&mut Uphill, 1.0, &policy);
        assert_eq!(r.stop, Stop::NoDecrease);
        assert_eq!(r.iterations, 4);
        assert_eq!(r.x, 1.0);
    }
}
