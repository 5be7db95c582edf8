//! Wall-clock instants as people read them: local time in ISO 8601, with the offset from UTC
//! (`2026-11-29T04:10:05+01:00`), for reports and log lines; and the basic form without
//! separators that a file name can carry (`20261129T041005+0100`), which sorts by time.

use std::time::{SystemTime, UNIX_EPOCH};

/// Broken-down local time of `t` and its offset from UTC in seconds (UTC when the C library
/// cannot say).
fn local(t: SystemTime) -> ([i64; 6], i64) {
    let secs = match t.duration_since(UNIX_EPOCH) {
        Ok(d) => d.as_secs() as i64,
        Err(e) => -(e.duration().as_secs() as i64),
    };
    let tt = secs as libc::time_t;
    // SAFETY: `localtime_r` writes into the `tm` we own and reads `tt`; both outlive the call.
    // A zeroed `tm` is a valid value of the plain C struct.
    let mut tm: libc::tm = unsafe { std::mem::zeroed() };
    let ok = unsafe { !libc::localtime_r(&tt, &mut tm).is_null() };
    if ok {
        let f = [tm.tm_year as i64 + 1900, tm.tm_mon as i64 + 1, tm.tm_mday as i64, tm.tm_hour as i64, tm.tm_min as i64, tm.tm_sec as i64];
        return (f, tm.tm_gmtoff as i64);
    }
    (utc(secs), 0)
}

/// Civil date and time in UTC of a Unix time (Howard Hinnant's days-from-civil, inverted).
fn utc(secs: i64) -> [i64; 6] {
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    [y, m, d, rem / 3600, rem % 3600 / 60, rem % 60]
}

fn offset(off: i64, colon: bool) -> String {
    let sign = if off < 0 { '-' } else { '+' };
    let a = off.abs();
    if colon {
        format!("{sign}{:02}:{:02}", a / 3600, a % 3600 / 60)
    } else {
        format!("{sign}{:02}{:02}", a / 3600, a % 3600 / 60)
    }
}

/// `t` as local ISO 8601 with the offset: `2026-11-29T04:10:05+01:00`.
pub fn iso8601(t: SystemTime) -> String {
    let ([y, mo, d, h, mi, s], off) = local(t);
    format!("{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}{}", offset(off, true))
}

/// `t` as local ISO 8601 in the basic format, for file names: `20261129T041005+0100`.
pub fn iso8601_basic(t: SystemTime) -> String {
    let ([y, mo, d, h, mi, s], off) = local(t);
    format!("{y:04}{mo:02}{d:02}T{h:02}{mi:02}{s:02}{}", offset(off, false))
}

/// The current time as [`iso8601`].
pub fn now() -> String {
    iso8601(SystemTime::now())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn utc_civil_dates() {
        assert_eq!(utc(0), [1970, 1, 1, 0, 0, 0]);
        assert_eq!(utc(951_782_400), [2000, 2, 29, 0, 0, 0]);
        assert_eq!(utc(1_795_921_205), [2026, 11, 29, 3, 0, 5]);
        assert_eq!(utc(-1), [1969, 12, 31, 23, 59, 59]);
    }

    #[test]
    fn local_time_agrees_with_utc_and_its_offset() {
        for secs in [0u64, 951_782_400, 1_795_921_205, 1_800_000_000] {
            let t = UNIX_EPOCH + Duration::from_secs(secs);
            let (f, off) = local(t);
            assert!(off.abs() <= 14 * 3600 && off % 60 == 0, "offset {off} s");
            assert_eq!(f, utc(secs as i64 + off), "{secs}");
            let s = iso8601(t);
            assert_eq!(s.len(), 25, "{s}");
            assert_eq!(&s[10..11], "T");
            let b = iso8601_basic(t);
            assert_eq!(b.len(), 20, "{b}");
            assert!(!b.contains(':'), "{b}");
        }
    }
}
