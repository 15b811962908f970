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
        let p = self.pos as i64 + delta as i64;
        self.pos = p.rem_euclid(self.cpr as i64) as u32;
        delta
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
        let bits = ((self.pos as u64) << 32) / self.cpr as u64;
        MechanicalAngle::from_bits(bits as u32)
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

    proptest! {
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
