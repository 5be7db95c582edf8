//! The false-claim rate of `taut diagnose` on effect-free simulated recordings (issue 14): 3-,
//! 4- and 8-cable robots and the 20 m outdoor robot, three noise levels, many seeds. Prints
//! one line per recording and the measured rate beside the nominal family rate.
//!
//! ```text
//! cargo run --profile test -p taut-tests --example null_rate -- [recordings, default 52]
//! ```

#[path = "../tests/support/null_cases.rs"]
mod null_cases;

use taut_calib::diagnose::{Effect, DEFAULT_FAMILY_ALPHA};

fn main() {
    let count: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(52);
    let t0 = std::time::Instant::now();
    let mut with_claims = 0;
    let mut smallest_p = f64::INFINITY;
    // Round-1 p-values of all six candidates: under the null about 5 % of them fall below 0.05.
    let (mut tests, mut below_5pct) = (0usize, 0usize);
    for k in 0..count {
        let t = std::time::Instant::now();
        let d = null_cases::diagnose_case(k);
        let c = null_cases::claims(&d);
        let round1: Vec<(Effect, f64)> =
            d.tests.iter().filter(|t| t.round == 1).filter_map(|t| t.test.map(|x| (t.effect, x.p_value))).collect();
        let p = round1.iter().map(|x| x.1).fold(f64::INFINITY, f64::min);
        let arg = round1.iter().find(|x| x.1 == p).map_or("-", |x| x.0.name());
        tests += round1.len();
        below_5pct += round1.iter().filter(|x| x.1 < 0.05).count();
        smallest_p = smallest_p.min(p);
        if !c.is_empty() {
            with_claims += 1;
        }
        println!(
            "{k:3} {:32} claims {:?}  smallest round-1 p {:.1e} ({arg})  held-out {:.3} mm  ({:.1} s)",
            null_cases::describe(k),
            c.iter().map(|e| e.name()).collect::<Vec<_>>(),
            p,
            d.final_fit.heldout_rms_m * 1e3,
            t.elapsed().as_secs_f64()
        );
    }
    println!(
        "round-1 tests: {below_5pct} of {tests} with p < 0.05 ({:.1} %); smallest p {smallest_p:.1e}",
        100.0 * below_5pct as f64 / tests.max(1) as f64
    );
    println!(
        "{with_claims} of {count} effect-free recordings with a claim (measured rate {:.3}); nominal family rate {:.0e} per recording; {:.0} s",
        with_claims as f64 / count as f64,
        DEFAULT_FAMILY_ALPHA,
        t0.elapsed().as_secs_f64()
    );
}
