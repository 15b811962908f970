//! Quadrature encoder position from a wrapping 16-bit hardware counter.
//!
//! The timer counts edges (x4) modulo 2^16, which is generally not a
//! multiple of the encoder's counts per turn. [`EncoderTracker`] therefore
//! accumulates signed 16-bit deltas into a position modulo `cpr` (read at
//! least once per 2^15 counts of motion), and re-zeroes it when an index
//! pulse was captured.
//!
//! ```
//! use board_support::logic::encoder::EncoderTracker;
//! let mut e = EncoderTracker::new(8192);
//! e.update(65535); // one count backwards from 0
//! assert_eq!(e.position(), 8191);
//! e.index_at(65535 - 10); // the index passed 10 counts ago (captured counter value)
//! assert_eq!(e.position(), 10);
//! ```

use foc_core::angle::MechanicalAngle;

/// Position tracking for a quadrature encoder on a 16-bit counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncoderTracker {
    cpr: u32,
    last_count: u16,
    /// Position in counts, `0..cpr`.
    pos: u32,
    /// True once an index pulse has set the zero.
    indexed: bool,
}

impl EncoderTracker {
    /// Tracker for `cpr` counts per turn (x4 edges; at least 1).
    pub const fn new(cpr: u32) -> Self {
        Self {
            cpr: if cpr == 0 { 1 } else { cpr },
            last_count: 0,
            pos: 0,
            indexed: false,
        }
    }

    /// Counts per turn.
    pub const fn cpr(&self) -> u32 {
        self.cpr
    }

    /// Change the counts per turn (keeps the position modulo the new value).
    pub fn set_cpr(&mut self, cpr: u32) {
        self.cpr = cpr.max(1);
        self.pos %= self.cpr;
    }

    /// Feed the raw counter value; returns the signed change in counts.
    pub fn update(&mut self, count: u16) -> i16 {
        let delta = count.wrapping_sub(self.last_count) as i16;
        self.last_count = count;
        self.pos = Self::advance(self.pos, delta, self.cpr);
        delta
    }

    /// `(pos + delta) mod cpr` for `pos < cpr`, without 64-bit division
    /// (a software routine of about 100 instructions on the M4, every
    /// period): one correction when `|delta| < cpr`, else a 32-bit
    /// remainder (hardware `udiv`) of values below 2^16 (design §20).
    #[inline]
    fn advance(pos: u32, delta: i16, cpr: u32) -> u32 {
        let d = u32::from(delta.unsigned_abs());
        if delta >= 0 {
            if d < cpr {
                // pos + d < 2 cpr; in u64 so that no cpr can overflow it.
                let s = u64::from(pos) + u64::from(d);
                let c = u64::from(cpr);
                (if s >= c { s - c } else { s }) as u32
            } else {
                // cpr <= d < 2^15, so pos + d < 2^16.
                (pos + d) % cpr
            }
        } else if d <= pos {
            pos - d
        } else {
            // (pos - d) mod cpr = -(d - pos) mod cpr.
            let m = (d - pos) % cpr;
            if m == 0 {
                0
            } else {
                cpr - m
            }
        }
    }

    /// The index pulse was seen when the counter read `captured`: make that
    /// position zero (call after [`Self::update`] with the current count).
    pub fn index_at(&mut self, captured: u16) {
        let since = self.last_count.wrapping_sub(captured) as i16;
        self.pos = (since as i64).rem_euclid(self.cpr as i64) as u32;
        self.indexed = true;
    }

    /// True once an index pulse has defined the zero.
    pub const fn is_indexed(&self) -> bool {
        self.indexed
    }

    /// Position in counts, `0..cpr`.
    pub const fn position(&self) -> u32 {
        self.pos
    }

    /// Position as a mechanical angle.
    pub fn angle(&self) -> MechanicalAngle {
        MechanicalAngle::from_bits(Self::turn_fraction_bits(self.pos, self.cpr))
    }

    /// `floor(pos 2^32 / cpr)` for `pos < cpr`: for `cpr <= 2^16` as two
    /// steps of long division in base 2^16 with 32-bit hardware division
    /// (exact, the same bits as the 64-bit division, which is a software
    /// routine on the M4); beyond, the 64-bit division.
    #[inline]
    fn turn_fraction_bits(pos: u32, cpr: u32) -> u32 {
        if cpr <= 1 << 16 {
            let hi = pos << 16; // pos < 2^16
            let (q1, r1) = (hi / cpr, hi % cpr);
            let q2 = (r1 << 16) / cpr; // r1 < cpr <= 2^16
            (q1 << 16) | q2
        } else {
            ((u64::from(pos) << 32) / u64::from(cpr)) as u32
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn wraps_both_ways() {
        let mut e = EncoderTracker::new(1000);
        for c in (0u32..=70_000).step_by(100) {
            e.update(c as u16);
        }
        assert_eq!(e.position(), 0); // 70_000 % 1000
        e.update((70_000u32 - 1_500) as u16);
        assert_eq!(e.position(), 500);
        assert!((e.angle().to_turns() - 0.5).abs() < 1e-6);
    }

    /// The reference the 32-bit arithmetic replaces (64-bit, exact).
    fn advance_i64(pos: u32, delta: i16, cpr: u32) -> u32 {
        (pos as i64 + delta as i64).rem_euclid(cpr as i64) as u32
    }

    #[test]
    fn angle_and_advance_match_the_64_bit_arithmetic_at_the_edges() {
        for cpr in [
            1u32,
            2,
            3,
            48,
            4095,
            4096,
            32_767,
            32_768,
            32_769,
            65_535,
            65_536,
            65_537,
            1 << 24,
            u32::MAX,
        ] {
            for pos in [0, 1, cpr / 2, cpr.saturating_sub(2), cpr - 1] {
                let pos = pos.min(cpr - 1);
                let bits = ((pos as u64) << 32) / cpr as u64;
                assert_eq!(
                    EncoderTracker::turn_fraction_bits(pos, cpr),
                    bits as u32,
                    "{pos}/{cpr}"
                );
                for delta in [i16::MIN, -32_767, -1, 0, 1, 32_767, i16::MAX] {
                    assert_eq!(
                        EncoderTracker::advance(pos, delta, cpr),
                        advance_i64(pos, delta, cpr),
                        "{pos} {delta} {cpr}"
                    );
                }
            }
        }
    }

    proptest! {
        #[test]
        fn angle_and_advance_match_the_64_bit_arithmetic(cpr in 1u32..=u32::MAX, pos in any::<u32>(), delta in any::<i16>()) {
            let pos = pos % cpr;
            let bits = ((pos as u64) << 32) / cpr as u64;
            prop_assert_eq!(EncoderTracker::turn_fraction_bits(pos, cpr), bits as u32);
            prop_assert_eq!(EncoderTracker::advance(pos, delta, cpr), advance_i64(pos, delta, cpr));
        }

        #[test]
        fn angle_and_advance_match_for_encoder_resolutions(cpr in 1u32..=70_000, pos in any::<u32>(), delta in any::<i16>()) {
            let pos = pos % cpr;
            let bits = ((pos as u64) << 32) / cpr as u64;
            prop_assert_eq!(EncoderTracker::turn_fraction_bits(pos, cpr), bits as u32);
            prop_assert_eq!(EncoderTracker::advance(pos, delta, cpr), advance_i64(pos, delta, cpr));
        }

        #[test]
        fn matches_true_position(steps in prop::collection::vec(-20_000i32..20_000, 1..50), cpr in 1u32..100_000) {
            let mut e = EncoderTracker::new(cpr);
            let mut truth: i64 = 0;
            for s in steps {
                truth += s as i64;
                e.update(truth.rem_euclid(65_536) as u16);
                prop_assert_eq!(e.position() as i64, truth.rem_euclid(cpr as i64));
            }
        }
    }
}
