//! How long one failed load-cell reading leaves a cable without a fresh tension, from the
//! RS-485 timing of the configured bus, and the check that `safety.tension_max_age_s` outlasts
//! it (a tension older than that latches `TensionStale` in the loop).
//!
//! The load-cell thread polls the cells one after the other, a round every
//! `loadcells.poll_period_s` (0: back to back). One exchange on the wire, Modbus over Serial
//! Line V1.02 2.5.1.1, reading the two registers of a cell:
//!
//! ```text
//!  | t3.5 silence | request 8 bytes | device turnaround | response 9 bytes |
//!    1.75 ms above 19200 baud, else 3.5 characters; a character is 1 start + 8 data
//!    (+ parity) + stop bits
//!  a failed try: t3.5 + request + response_timeout_s; a failed reading: retries + 1 tries
//! ```
//!
//! When cell j's reading fails in one round, its last good reading is from the round before,
//! and the next good one comes in the round after:
//!
//! ```text
//!  gap = max(P, N * good) + max(P, (N - 1) * good + (retries + 1) * failed_try)
//! ```
//!
//! with P the poll period and N the cells on the bus. `good` counts the wire time only (no device
//! turnaround, no adapter latency), so the gap is a lower bound: a `tension_max_age_s` below it
//! trips on the first lost frame with every device healthy, whatever the machine does.

use taut_proto::devices::{LoadCellBusConfig, Parity};

/// Bytes of a "read two registers" request: unit, function, address (2), quantity (2), CRC (2).
const REQUEST_BYTES: f64 = 8.0;
/// Bytes of its response: unit, function, byte count, 4 data bytes, CRC (2).
const RESPONSE_BYTES: f64 = 9.0;

/// The parts of [`one_failed_reading`], s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FailureGap {
    /// One good exchange on the wire (t3.5 + request + response).
    pub good_s: f64,
    /// One try that times out (t3.5 + request + response timeout).
    pub failed_try_s: f64,
    /// Tries of one reading (`retries + 1`).
    pub tries: u32,
    /// Cells on the bus.
    pub cells: usize,
    /// Longest time between two good readings of a cell whose reading failed once.
    pub gap_s: f64,
}

/// The shortest time one failed reading leaves a cable without a fresh tension on `bus` with
/// `cells` cells (see the module documentation).
pub fn one_failed_reading(bus: &LoadCellBusConfig, cells: usize) -> FailureGap {
    let bits = 1.0 + f64::from(bus.data_bits) + if bus.parity == Parity::None { 0.0 } else { 1.0 } + f64::from(bus.stop_bits);
    let char_s = bits / f64::from(bus.baud.max(1));
    // Modbus over Serial Line 2.5.1.1: fixed 1.75 ms above 19200 baud.
    let t35 = if bus.baud > 19_200 { 1.75e-3 } else { 3.5 * char_s };
    let good_s = t35 + (REQUEST_BYTES + RESPONSE_BYTES) * char_s;
    let failed_try_s = t35 + REQUEST_BYTES * char_s + bus.response_timeout_s;
    let tries = u32::from(bus.retries) + 1;
    let n = cells.max(1) as f64;
    let p = bus.poll_period_s;
    let gap_s = p.max(n * good_s) + p.max((n - 1.0) * good_s + f64::from(tries) * failed_try_s);
    FailureGap { good_s, failed_try_s, tries, cells, gap_s }
}

/// `Err((message))` when `tension_max_age_s` is not longer than what one failed reading can take
/// on `bus`; the message names both sides' keys and what to do.
pub fn check_tension_age(tension_max_age_s: f64, bus: &LoadCellBusConfig, cells: usize) -> Result<(), String> {
    let g = one_failed_reading(bus, cells);
    if tension_max_age_s > g.gap_s {
        return Ok(());
    }
    Err(format!(
        "{tension_max_age_s} s is shorter than one failed load-cell reading can leave a cable without a fresh tension: \
         at least {:.0} ms = {} tries (loadcells.retries = {} + 1) x {:.1} ms (loadcells.response_timeout_s = {} s + t3.5 + request at \
         loadcells.baud = {}) plus the polling of {} cells ({:.1} ms each on the wire, loadcells.poll_period_s = {} s), before any \
         device or adapter latency; so the loop would stop on the first lost frame. Raise safety.tension_max_age_s above {:.2} s, \
         or shorten loadcells.response_timeout_s or loadcells.retries",
        g.gap_s * 1e3,
        g.tries,
        bus.retries,
        g.failed_try_s * 1e3,
        bus.response_timeout_s,
        bus.baud,
        g.cells,
        g.good_s * 1e3,
        bus.poll_period_s,
        g.gap_s
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::SafetyConfig;

    #[test]
    fn wire_times_at_115200_8n1() {
        let g = one_failed_reading(&LoadCellBusConfig::new("/dev/x"), 1);
        // 10 bits per character: 86.8 us; 17 bytes = 1.476 ms + t3.5 1.75 ms.
        assert!((g.good_s - (1.75e-3 + 17.0 * 10.0 / 115_200.0)).abs() < 1e-12);
        assert_eq!(g.tries, 3);
    }

    #[test]
    fn slow_bus_uses_three_and_a_half_characters() {
        let bus = LoadCellBusConfig { baud: 9600, parity: Parity::Even, ..LoadCellBusConfig::new("/dev/x") };
        let g = one_failed_reading(&bus, 1);
        let c = 11.0 / 9600.0;
        assert!((g.good_s - (3.5 * c + 17.0 * c)).abs() < 1e-12);
    }

    #[test]
    fn defaults_tolerate_one_failed_reading_of_up_to_eight_cells() {
        let s = SafetyConfig::default();
        let bus = LoadCellBusConfig::new("/dev/x");
        for n in 1..=8 {
            assert_eq!(check_tension_age(s.tension_max_age_s, &bus, n), Ok(()), "{n} cells");
        }
    }

    #[test]
    fn old_defaults_are_refused_naming_both_keys() {
        // 50 ms timeout, 2 retries: 3 x 52.4 ms alone exceed 0.1 s.
        let bus = LoadCellBusConfig { response_timeout_s: 0.05, ..LoadCellBusConfig::new("/dev/x") };
        let e = check_tension_age(0.1, &bus, 4).unwrap_err();
        for k in ["safety.tension_max_age_s", "loadcells.response_timeout_s", "loadcells.retries"] {
            assert!(e.contains(k), "{k} not in: {e}");
        }
        assert!(check_tension_age(0.2, &bus, 4).is_ok());
    }

    #[test]
    fn a_robot_file_with_too_short_an_age_is_refused_at_load_at_the_key_line() {
        let hw = include_str!("../examples/aras-cam-hw.toml");
        assert!(crate::RobotConfig::from_toml_str(hw).is_ok(), "the hardware example is consistent");
        let bad = hw.replace("response_timeout_s = 0.02", "response_timeout_s = 0.05") + "\n[safety]\ntension_max_age_s = 0.1\n";
        let e = crate::RobotConfig::from_toml_str(&bad).unwrap_err();
        assert_eq!(e.key.as_deref(), Some("safety.tension_max_age_s"));
        let line = bad.lines().position(|l| l.starts_with("tension_max_age_s")).unwrap() + 1;
        assert_eq!(e.line, Some(line), "{e:?}");
        assert!(e.message.contains("loadcells.response_timeout_s = 0.05"), "{}", e.message);
    }

    #[test]
    fn a_slow_poll_period_counts_twice() {
        // Good reading in round k, failed in k+1, next good in k+2: two periods.
        let bus = LoadCellBusConfig { poll_period_s: 0.1, ..LoadCellBusConfig::new("/dev/x") };
        let g = one_failed_reading(&bus, 4);
        assert!((g.gap_s - 0.2).abs() < 1e-12, "{g:?}");
        assert!(check_tension_age(0.2, &bus, 4).is_err());
    }
}
