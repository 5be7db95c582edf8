//! The false-claim rate of `taut diagnose` on effect-free simulated recordings (issue 14): 3-,
//! 4- and 8-cable robots and the 20 m outdoor robot, three noise levels, many seeds. Prints
//! one line per recording, then per candidate effect the false claims and the round-1 p-values
//! in the tail (against the count a uniform p would give), and the measured rate with its 95 %
//! confidence interval beside the nominal family rate.
//!
//! ```text
//! cargo run --profile test -p taut-tests --example null_rate -- [recordings, default 52]
//! ```
//!
//! `NULL_VARIANT` (`sim`, `no-outliers`, `no-loose`, `clean`, `ideal`, `ideal-ar1`, `sim-ar1`; see
//! `support/null_cases.rs`) changes what the recordings are made of, to split the causes of a
//! tail; `NULL_FIRST` starts at another case; `NULL_BEFORE=1` runs the held-out test without the
//! current model's estimation error (`DiagnoseOptions::estimation_error` off); `NULL_TENSION=1` runs
//! the tension side too (the platform's mass given: one family with the tension effects), and
//! each line then also lists the tension effects named (inertia is in every simulated recording,
//! so only a gain or a friction is a false claim). Each line ends with the six round-1 p-values.

#[path = "../tests/support/null_cases.rs"]
mod null_cases;

use taut_calib::diagnose::{Effect, DEFAULT_FAMILY_ALPHA};

/// Two-sided 95 % interval of a binomial proportion `k / n`: Clopper-Pearson for `k = 0`
/// (`[0, 1 - 0.025^(1/n)]`, exact), Wilson otherwise.
fn interval(k: usize, n: usize) -> (f64, f64) {
    let nf = n.max(1) as f64;
    if k == 0 {
        return (0.0, 1.0 - 0.025f64.powf(1.0 / nf));
    }
    let (p, z) = (k as f64 / nf, 1.959_964);
    let c = (p + z * z / (2.0 * nf)) / (1.0 + z * z / nf);
    let h = z / (1.0 + z * z / nf) * (p * (1.0 - p) / nf + z * z / (4.0 * nf * nf)).sqrt();
    (c - h, c + h)
}

fn main() {
    let count: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(52);
    let first: usize = std::env::var("NULL_FIRST").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
    let variant_name = std::env::var("NULL_VARIANT").unwrap_or_else(|_| "sim".into());
    let variant = null_cases::Variant::parse(&variant_name).unwrap_or_else(|| panic!("NULL_VARIANT {variant_name}: unknown"));
    let estimation_error = std::env::var("NULL_BEFORE").map_or(true, |v| v != "1");
    println!("variant {variant:?}, cases {first}..{}, estimation error counted: {estimation_error}", first + count);
    let t0 = std::time::Instant::now();
    let mut with_claims = 0;
    let mut smallest_p = f64::INFINITY;
    let lib = Effect::FITTED;
    // Per candidate: claims, round-1 tests, and round-1 p below the test's level, 1e-3, 1e-2, 0.05.
    let mut claims_of = vec![0usize; lib.len()];
    let mut tests_of = vec![0usize; lib.len()];
    let mut tail_of = vec![[0usize; 4]; lib.len()];
    let mut alpha = 0.0;
    let (mut tension_false, mut tension_min_p) = (0usize, 1.0f64);
    for k in first..first + count {
        let t = std::time::Instant::now();
        let d = null_cases::diagnose_with(k, variant, estimation_error);
        let c = null_cases::claims(&d);
        let round1: Vec<(Effect, f64)> =
            d.tests.iter().filter(|t| t.round == 1).filter_map(|t| t.test.map(|x| (t.effect, x.p_value))).collect();
        if let Some(t) = d.tests.first() {
            alpha = t.alpha;
        }
        for &(e, p) in &round1 {
            let q = lib.iter().position(|x| *x == e).expect("in the library");
            tests_of[q] += 1;
            for (s, lim) in [alpha, 1e-3, 1e-2, 0.05].iter().enumerate() {
                tail_of[q][s] += usize::from(p < *lim);
            }
        }
        for e in &c {
            if let Some(q) = lib.iter().position(|x| x == e) {
                claims_of[q] += 1;
            }
        }
        if let Some(td) = &d.tension {
            let named: Vec<&str> = td.effects.iter().map(|f| f.effect.name()).collect();
            let false_claims = td.effects.iter().filter(|f| f.effect != taut_calib::diagnose::TensionEffect::Inertia).count();
            tension_false += usize::from(false_claims > 0);
            let min_p = td
                .tests
                .iter()
                .filter(|t| t.effect != taut_calib::diagnose::TensionEffect::Inertia)
                .filter_map(|t| t.test)
                .map(|t| t.p_value)
                .fold(1.0, f64::min);
            tension_min_p = tension_min_p.min(min_p);
            println!("    tension side: named {named:?}, smallest gain/friction p {min_p:.1e}");
        }
        let p = round1.iter().map(|x| x.1).fold(f64::INFINITY, f64::min);
        let arg = round1.iter().find(|x| x.1 == p).map_or("-", |x| x.0.name());
        smallest_p = smallest_p.min(p);
        if !c.is_empty() {
            with_claims += 1;
        }
        println!(
            "{k:3} {:32} claims {:?}  smallest round-1 p {:.1e} ({arg})  held-out {:.3} mm  ({:.1} s)  p1 {}",
            null_cases::describe(k),
            c.iter().map(|e| e.name()).collect::<Vec<_>>(),
            p,
            d.final_fit.heldout_rms_m * 1e3,
            t.elapsed().as_secs_f64(),
            lib.iter()
                .map(|e| round1.iter().find(|x| x.0 == *e).map_or("-".to_string(), |x| format!("{:.3e}", x.1)))
                .collect::<Vec<_>>()
                .join(" ")
        );
    }
    println!("per candidate (round 1; a uniform p gives n x level below each level):");
    println!(
        "{:13} {:>7} {:>6} {:>16} {:>14} {:>14} {:>14}",
        "candidate", "claims", "tests", "p < level", "p < 1e-3", "p < 0.01", "p < 0.05"
    );
    for (q, e) in lib.iter().enumerate() {
        let n = tests_of[q] as f64;
        let (lo, hi) = interval(claims_of[q], count);
        println!(
            "{:13} {:>7} {:>6} {:>8} ({:.1e}) {:>7} ({:>4.2}) {:>7} ({:>4.1}) {:>7} ({:>4.1})   claim rate 95 % CI [{lo:.3}, {hi:.3}]",
            e.name(),
            claims_of[q],
            tests_of[q],
            tail_of[q][0],
            n * alpha,
            tail_of[q][1],
            n * 1e-3,
            tail_of[q][2],
            n * 1e-2,
            tail_of[q][3],
            n * 0.05
        );
    }
    let tests: usize = tests_of.iter().sum();
    let below: usize = tail_of.iter().map(|t| t[3]).sum();
    println!(
        "round-1 tests: {below} of {tests} with p < 0.05 ({:.1} %); smallest p {smallest_p:.1e}; level of each test {alpha:.1e}",
        100.0 * below as f64 / tests.max(1) as f64
    );
    let (lo, hi) = interval(with_claims, count);
    println!(
        "{with_claims} of {count} effect-free recordings with a claim (measured rate {:.4}, 95 % CI [{lo:.4}, {hi:.4}]); nominal family rate {:.0e} per recording (bound on a claim in round 1: {:.1e}); {:.0} s",
        with_claims as f64 / count as f64,
        DEFAULT_FAMILY_ALPHA,
        alpha * lib.len() as f64,
        t0.elapsed().as_secs_f64()
    );
    if std::env::var("NULL_TENSION").is_ok_and(|v| v == "1") {
        println!(
            "tension side: {tension_false} of {count} recordings named a gain or a friction; smallest gain/friction p {tension_min_p:.1e} (level {alpha:.1e})"
        );
    }
}
