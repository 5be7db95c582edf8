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
    for k in 0..count {
        let t = std::time::Instant::now();
        let d = null_cases::diagnose_case(k);
        let c = null_cases::claims(&d);
        // The smallest round-1 p-value of the candidates whose predictions do not use the
        // readings' own noise (time offset and backlash do; their claims also need a visible
        // length change).
        let p = d
            .tests
            .iter()
            .filter(|t| t.round == 1 && !matches!(t.effect, Effect::TimeOffset | Effect::Backlash))
            .filter_map(|t| t.test.map(|x| x.p_value))
            .fold(f64::INFINITY, f64::min);
        smallest_p = smallest_p.min(p);
        if !c.is_empty() {
            with_claims += 1;
        }
        println!(
            "{k:3} {:32} claims {:?}  smallest p (elasticity, sag, pulley, scale) {:.1e}  held-out {:.3} mm  ({:.1} s)",
            null_cases::describe(k),
            c.iter().map(|e| e.name()).collect::<Vec<_>>(),
            p,
            d.final_fit.heldout_rms_m * 1e3,
            t.elapsed().as_secs_f64()
        );
    }
    println!(
        "{with_claims} of {count} effect-free recordings with a claim (measured rate {:.3}); nominal family rate {:.0e} per recording; {:.0} s",
        with_claims as f64 / count as f64,
        DEFAULT_FAMILY_ALPHA,
        t0.elapsed().as_secs_f64()
    );
}
