//! Dead-time generator encoding for the advanced-control timers (TIM1/TIM8).
//!
//! `TIMx_BDTR.DTG[7:0]` encodes the dead time in four ranges (RM0090 F405
//! section 17.4.18, RM0390 F446 section 16.4.18, RM0368 F401 section 12.4.18),
//! in units of `t_DTS` (= the timer kernel clock period with `CR1.CKD = 0`):
//!
//! | `DTG[7:5]` | dead time                     | ticks       | step |
//! |------------|-------------------------------|-------------|------|
//! | `0xx`      | `DTG[7:0]`                    | 0 ..= 127   | 1    |
//! | `10x`      | `(64 + DTG[5:0]) * 2`         | 128 ..= 254 | 2    |
//! | `110`      | `(32 + DTG[4:0]) * 8`         | 256 ..= 504 | 8    |
//! | `111`      | `(32 + DTG[4:0]) * 16`        | 512 ..= 1008| 16   |
//!
//! [`encode_dead_time`] rounds *up*: the encoded dead time is never shorter
//! than requested and less than one step longer, except when the request is
//! beyond 1008 ticks, where it saturates (and says so).
//!
//! ```
//! use board_support::logic::dead_time::{encode_dead_time, decode_dtg};
//! // 168 MHz timer clock, 120 ns -> 21 ticks (125 ns).
//! let dt = encode_dead_time(168_000_000, 120);
//! assert_eq!(dt.dtg, 21);
//! assert_eq!(decode_dtg(dt.dtg), 21);
//! assert!(!dt.saturated);
//! ```

/// Largest dead time the generator can produce, in `t_DTS` ticks.
pub const MAX_DEAD_TIME_TICKS: u16 = 1008;

/// An encoded dead time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeadTime {
    /// Value for `BDTR.DTG[7:0]`.
    pub dtg: u8,
    /// Dead time actually produced, in timer ticks (`t_DTS`).
    pub ticks: u16,
    /// Dead time actually produced [ns], rounded up.
    pub ns: u32,
    /// True when the request exceeded [`MAX_DEAD_TIME_TICKS`] and was clamped
    /// (the only case where the result is shorter than requested).
    pub saturated: bool,
}

/// Dead time in ticks produced by a `DTG` value.
pub const fn decode_dtg(dtg: u8) -> u16 {
    let d = dtg as u16;
    if d & 0x80 == 0 {
        d
    } else if d & 0xC0 == 0x80 {
        (64 + (d & 0x3F)) * 2
    } else if d & 0xE0 == 0xC0 {
        (32 + (d & 0x1F)) * 8
    } else {
        (32 + (d & 0x1F)) * 16
    }
}

/// Smallest `DTG` value whose dead time is at least `ticks` (saturating at
/// `0xFF` = 1008 ticks). Returns `(dtg, saturated)`.
pub const fn dtg_for_ticks(ticks: u32) -> (u8, bool) {
    if ticks <= 127 {
        (ticks as u8, false)
    } else if ticks <= 254 {
        let n = ticks.div_ceil(2) - 64; // 0..=63
        (0x80 | n as u8, false)
    } else if ticks <= 504 {
        let n = ticks.div_ceil(8) - 32; // 0..=31 (255 -> 256)
        (0xC0 | n as u8, false)
    } else if ticks <= 1008 {
        let n = ticks.div_ceil(16) - 32; // 0..=31 (505 -> 512)
        (0xE0 | n as u8, false)
    } else {
        (0xFF, true)
    }
}

/// Ticks of a clock of `clk_hz` covering at least `ns` nanoseconds.
pub const fn ns_to_ticks_ceil(clk_hz: u32, ns: u32) -> u64 {
    (ns as u64 * clk_hz as u64).div_ceil(1_000_000_000)
}

/// Encode a dead time of at least `ns` nanoseconds for a timer whose
/// `t_DTS` clock is `dts_clk_hz` (the timer clock with `CR1.CKD = 0`).
///
/// A zero clock gives a zero dead time (nothing sensible to encode).
pub const fn encode_dead_time(dts_clk_hz: u32, ns: u32) -> DeadTime {
    if dts_clk_hz == 0 {
        return DeadTime {
            dtg: 0,
            ticks: 0,
            ns: 0,
            saturated: ns > 0,
        };
    }
    let want = ns_to_ticks_ceil(dts_clk_hz, ns);
    let want32 = if want > u32::MAX as u64 {
        u32::MAX
    } else {
        want as u32
    };
    let (dtg, saturated) = dtg_for_ticks(want32);
    let ticks = decode_dtg(dtg);
    let ns_actual = (ticks as u64 * 1_000_000_000).div_ceil(dts_clk_hz as u64) as u32;
    DeadTime {
        dtg,
        ticks,
        ns: ns_actual,
        saturated,
    }
}

/// Step (resolution) in ticks of the range a `DTG` value belongs to.
pub const fn dtg_step_ticks(dtg: u8) -> u16 {
    if dtg & 0x80 == 0 {
        1
    } else if dtg & 0xC0 == 0x80 {
        2
    } else if dtg & 0xE0 == 0xC0 {
        8
    } else {
        16
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn range_boundaries() {
        assert_eq!(dtg_for_ticks(0), (0, false));
        assert_eq!(dtg_for_ticks(127), (127, false));
        assert_eq!(decode_dtg(dtg_for_ticks(128).0), 128);
        assert_eq!(decode_dtg(dtg_for_ticks(129).0), 130);
        assert_eq!(decode_dtg(dtg_for_ticks(254).0), 254);
        assert_eq!(decode_dtg(dtg_for_ticks(255).0), 256);
        assert_eq!(decode_dtg(dtg_for_ticks(504).0), 504);
        assert_eq!(decode_dtg(dtg_for_ticks(505).0), 512);
        assert_eq!(decode_dtg(dtg_for_ticks(1008).0), 1008);
        assert_eq!(dtg_for_ticks(1009), (0xFF, true));
        assert_eq!(decode_dtg(0xFF), MAX_DEAD_TIME_TICKS);
    }

    #[test]
    fn known_values() {
        // ODrive v3: 20 clocks at 168 MHz ~ 119 ns.
        let dt = encode_dead_time(168_000_000, 119);
        assert_eq!(dt.ticks, 20);
        // 1 us at 180 MHz = 180 ticks -> range 2, exact.
        let dt = encode_dead_time(180_000_000, 1000);
        assert_eq!(dt.ticks, 180);
        assert_eq!(dt.dtg, 0x80 | (90 - 64));
        assert_eq!(encode_dead_time(84_000_000, 0).ticks, 0);
        assert!(encode_dead_time(180_000_000, 100_000).saturated);
        assert!(encode_dead_time(0, 10).saturated);
    }

    #[test]
    fn every_dtg_decodes_monotonically_within_ranges() {
        // Re-encoding a decoded value gives the same dead time back.
        for dtg in 0..=255u8 {
            let t = decode_dtg(dtg);
            assert_eq!(decode_dtg(dtg_for_ticks(t as u32).0), t);
        }
    }

    proptest! {
        #[test]
        fn never_shorter_and_within_one_step(clk in 1_000_000u32..=200_000_000, ns in 0u32..=20_000) {
            let dt = encode_dead_time(clk, ns);
            let want_exact = ns as f64 * clk as f64 / 1e9; // ticks
            let got = dt.ticks as f64;
            if dt.saturated {
                prop_assert_eq!(dt.ticks, MAX_DEAD_TIME_TICKS);
                prop_assert!(want_exact > MAX_DEAD_TIME_TICKS as f64);
            } else {
                prop_assert!(got + 1e-9 >= want_exact, "shorter: {} < {}", got, want_exact);
                let step = dtg_step_ticks(dt.dtg) as f64;
                prop_assert!(got - want_exact < step + 1e-9, "more than a step: {} vs {}", got, want_exact);
                prop_assert!(dt.ns >= ns);
            }
        }
    }
}
