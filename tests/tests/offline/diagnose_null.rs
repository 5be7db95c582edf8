//! False claims on effect-free recordings: a subset of the sweep of
//! `examples/null_rate.rs` (which records the rate over 52 recordings in docs/diagnosis.md).
//!
//! On an effect-free recording a claim needs a candidate to pass its round-1 held-out test:
//! Bonferroni over the 6 candidates bounds that at `6 x test_alpha = family_alpha / 3`
//! (3.3e-5 at the default 1e-4), so this test of 12 recordings fails by chance with probability
//! at most 12 x 3.3e-5 = 4e-4 < 1e-3.

use crate::null_cases;

use taut_calib::diagnose::{DiagnoseOptions, DEFAULT_FAMILY_ALPHA};

#[test]
fn effect_free_recordings_name_nothing() {
    let o = DiagnoseOptions::default();
    assert_eq!(o.family_alpha, DEFAULT_FAMILY_ALPHA);
    // The chance-failure bound above holds only at these settings.
    assert!(12.0 * 6.0 * o.test_alpha() < 1e-3);
    let mut failures = vec![];
    for k in 0..12 {
        let d = null_cases::diagnose_case(k);
        let c = null_cases::claims(&d);
        if !c.is_empty() {
            failures.push(format!(
                "{}: {:?}",
                null_cases::describe(k),
                d.effects.iter().map(|f| format!("{}: {}", f.effect.name(), f.evidence)).collect::<Vec<_>>()
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
