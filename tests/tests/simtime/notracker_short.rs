//! End to end without a tracker, the short plan (16 poses of 2.5 s, settle 0.3 s, 0.5 m/s mean
//! speed, 8 tares rotating through the cables: under two minutes): the start-up rests, dwells,
//! calibrates and hot-swaps (checks in `notracker::start_on`), in simulated time. Its worst-anchor
//! 1-sigma is ~2.3 mm, too wide for a 3 mm bound: that acceptance runs the example's plan in
//! `notracker_3mm`. The recalibration over the control socket (real time): the ignored
//! `recalibrates_without_a_tracker`.

use crate::notracker;

use notracker::{report, start, start_on, Plan};

#[test]
fn starts_without_a_tracker_dwells_calibrates_and_hot_swaps() {
    report(3, &start_on(3, Plan::Short, false, true));
}

/// A second site (seed 5: other anchors, offsets and load-cell offsets).
#[test]
fn starts_without_a_tracker_on_another_site() {
    report(5, &start_on(5, Plan::Short, false, true));
}

/// The short plan on the dynamic plant: the platform swings after every move and the rests
/// begin while it swings. With the cables' datasheet stiffness (0.9 MN +- 0.15 MN, truth 1 MN)
/// the calibration models their stretch: the start-up completes, fits to its noise (chi-square),
/// calibrates within its own sigmas and hot-swaps (seeds 1-5: chi2/dof 0.89-1.34, worst anchor
/// 1.7-5.1 mm; without the stretch 5.2-10.2 and 4.9-7.4 mm). Its 3 mm is open (issue 28: the
/// short plan's sigma is ~3 mm).
#[test]
fn starts_without_a_tracker_on_the_dynamic_plant() {
    report(1, &notracker::start_on_plant(1, Plan::Short, false, true, true));
}

/// Seeds 1-5 on the dynamic plant, each seed's failure reported and the loop going on:
/// `cargo test -p taut-tests --test simtime notracker_short::dynamic_seeds -- --ignored --nocapture`.
#[test]
#[ignore]
fn dynamic_seeds() {
    let failed: Vec<u64> = (1..=5)
        .filter(|&seed| {
            std::panic::catch_unwind(|| report(seed, &notracker::start_on_plant(seed, Plan::Short, false, true, true))).is_err()
        })
        .collect();
    assert!(failed.is_empty(), "seeds {failed:?} failed");
}

/// `ctl recalibrate` without a tracker visits the dwells again (about 80 s more; the loop's
/// side is also checked by `motion::tests::dwell_startup_runs_the_plan_and_recalibrates`).
#[test]
#[ignore]
fn recalibrates_without_a_tracker() {
    start(4, Plan::Short, true);
}

/// Seeds 1-5 with the test's plan:
/// `cargo test -p taut-tests --test simtime notracker::seeds -- --ignored --nocapture`.
#[test]
#[ignore]
fn seeds() {
    for seed in 1..=5 {
        report(seed, &start_on(seed, Plan::Short, false, true));
    }
}
