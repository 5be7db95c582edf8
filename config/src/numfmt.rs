//! Numbers for people: a value rounded to two significant digits of its 1-sigma
//! (`19740 ± 570`, not `19737.0827 ± 565.2190`), a number without an uncertainty to four
//! significant digits (`3`, not `3.0000`), never `-0`.

/// Decimals that show a 1-sigma `s` with two significant digits (negative: round to tens,
/// hundreds, ...); `None` without a usable sigma.
fn decimals_for(s: f64) -> Option<i32> {
    (s.is_finite() && s > 0.0).then(|| 1 - s.log10().floor() as i32)
}

fn with_decimals(v: f64, d: i32) -> String {
    if d > 0 {
        let k = 10f64.powi(d);
        let r = (v * k).round() / k;
        let d = d as usize;
        // `-0.00` is zero.
        format!("{:.d$}", if r == 0.0 { 0.0 } else { r })
    } else {
        let unit = 10f64.powi(-d);
        let r = (v / unit).round() * unit;
        // `-0` is zero.
        format!("{:.0}", if r == 0.0 { 0.0 } else { r })
    }
}

/// `v` to 4 significant digits, trailing zeros dropped (`3`, `2.5`, `0.001235`): a number
/// without an uncertainty of its own.
pub fn plain(v: f64) -> String {
    if !v.is_finite() {
        return "-".into();
    }
    if v == 0.0 {
        return "0".into();
    }
    let d = (3 - v.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.d$}");
    let s = if s.contains('.') { s.trim_end_matches('0').trim_end_matches('.').to_string() } else { s };
    if s == "-0" {
        "0".into()
    } else {
        s
    }
}

/// `v` rounded to the two significant digits of its 1-sigma `s` (`3.50902` for 0.63 mm in m);
/// without a usable sigma, [`plain`].
pub fn rounded(v: f64, s: f64) -> String {
    match decimals_for(s) {
        Some(d) if v.is_finite() => with_decimals(v, d),
        _ => plain(v),
    }
}

/// A 1-sigma to two significant digits (`0.63`, `570`).
pub fn sig2(s: f64) -> String {
    match decimals_for(s) {
        Some(d) => with_decimals(s, d),
        None => plain(s),
    }
}

/// A value and its 1-sigma rounded to the sigma's two significant digits: `19740 ± 570`,
/// `1.0555 ± 0.0023`. Without a usable sigma, the value to 4 significant digits.
pub fn plus_minus(v: f64, s: f64) -> String {
    if decimals_for(s).is_none() || !v.is_finite() {
        return plain(v);
    }
    format!("{} ± {}", rounded(v, s), sig2(s))
}

#[cfg(test)]
mod plus_minus_tests {
    use super::*;

    #[test]
    fn values_are_rounded_to_their_uncertainty() {
        assert_eq!(plus_minus(19737.0827, 565.2190), "19740 ± 570");
        assert_eq!(plus_minus(1.05552, 0.0023), "1.0555 ± 0.0023");
        assert_eq!(plus_minus(0.0123456, 0.00098), "0.01235 ± 0.00098");
        assert_eq!(plus_minus(-2.71234, 0.25), "-2.71 ± 0.25");
        assert_eq!(plus_minus(2.5, f64::NAN), "2.5");
        assert_eq!(plus_minus(3.0, 0.0), "3");
        assert_eq!(rounded(3.509_023_7, 0.000_63), "3.50902");
        assert_eq!(rounded(-0.000_1, 0.25), "0.00");
        assert_eq!(rounded(-3.0, 250.0), "0");
        assert_eq!(sig2(0.8234), "0.82");
        assert_eq!(sig2(565.2), "570");
        assert_eq!(plain(1800.0), "1800");
        assert_eq!(plain(0.001_234_56), "0.001235");
        assert_eq!(plain(-0.0), "0");
    }
}
