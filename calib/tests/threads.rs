//! The calibration on several threads (`CalibOptions::threads`) gives the one-thread results bit
//! for bit: the gathered readings, the initialisation, the force-aware and the unweighted
//! calibration with their held-out figures and notes, and the Cramér–Rao bound.

use taut_calib::{calibrate, init, metrics, synth, CalibOptions, RobustLoss};

#[test]
fn threads_give_the_one_thread_results() {
    let (mut rec, _) = synth::bench_recording(8000);
    let n = rec.n_cables;
    // A cable with readings too weak for the refusal level would end the run: keep them all,
    // but give cable 2 a larger noise so that its notes differ from the others'.
    for i in (0..rec.len()).step_by(7) {
        rec.l[i * n + 2] += 0.004 * if i % 2 == 0 { 1.0 } else { -1.0 };
    }
    let b = vec![[0.0; 3]; n];
    let text = |threads: usize, force_aware: bool| {
        let opts = CalibOptions { threads, force_aware, weak_sigma_m: 2e-4, ..CalibOptions::default() };
        let start = init::initialise(&rec, &b, &opts).expect("initialisation");
        let cal = calibrate(&rec, &b, &start.params, &opts).expect("calibration");
        let least_squares =
            calibrate(&rec, &b, &start.params, &CalibOptions { loss: RobustLoss::None, ..opts.clone() }).expect("least squares");
        let crb = metrics::cramer_rao(&rec, &b, &cal.params, &opts);
        format!("{:?}\n{cal:?}\n{least_squares:?}\n{crb:?}", start.params)
    };
    for force_aware in [true, false] {
        let one = text(1, force_aware);
        assert!(one.contains("weakly determined"), "the notes are exercised");
        for threads in [2, 3, 8] {
            assert_eq!(text(threads, force_aware), one, "{threads} threads, force-aware {force_aware}");
        }
    }
}

#[test]
fn the_first_failing_cable_is_reported_as_with_one_thread() {
    let (mut rec, init) = synth::bench_recording(2000);
    let n = rec.n_cables;
    // Cables 1 and 3 lose all their readings: cable 1's error, whichever thread finishes first.
    for i in 0..rec.len() {
        rec.l[i * n + 1] = f64::NAN;
        rec.l[i * n + 3] = f64::NAN;
    }
    let b = vec![[0.0; 3]; n];
    let run = |threads| format!("{:?}", calibrate(&rec, &b, &init, &CalibOptions { threads, ..CalibOptions::default() }));
    let one = run(1);
    assert!(one.contains("TooFewReadings { cable: 1"), "{one}");
    for threads in [2, 4] {
        assert_eq!(run(threads), one);
    }
}

/// The readings gathered once and shared (`initialise_gathered`, `calibrate_gathered`,
/// `cramer_rao_gathered`, as `taut calibrate` runs them) give what each function gives on its own.
#[test]
fn readings_gathered_once_give_the_same() {
    let (rec, _) = synth::bench_recording(6000);
    let b = vec![[0.0; 3]; rec.n_cables];
    for threads in [1, 2] {
        let opts = CalibOptions { threads, ..CalibOptions::default() };
        let start = init::initialise(&rec, &b, &opts).expect("initialisation");
        let cal = calibrate(&rec, &b, &start.params, &opts).expect("calibration");
        let crb = metrics::cramer_rao(&rec, &b, &cal.params, &opts);
        let mut data = taut_calib::noise::gather(&rec, &b, &opts, taut_calib::Weighting::of(&rec, &opts));
        let start2 = init::initialise_gathered(&rec, &b, &opts, &data).expect("initialisation");
        let cal2 = taut_calib::calibrate_gathered(&rec, &b, &start2.params, &opts, &mut data).expect("calibration");
        let crb2 = metrics::cramer_rao_gathered(&rec, &cal2.params, &opts, &mut data);
        assert_eq!(
            format!("{:?}\n{cal2:?}\n{crb2:?}", start2.params),
            format!("{:?}\n{cal:?}\n{crb:?}", start.params),
            "{threads} threads"
        );
    }
}
