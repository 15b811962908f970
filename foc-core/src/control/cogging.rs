//! Anticogging: a q-current feed-forward from a map of the motor's
//! cogging torque over one electrical turn (design §32).
//!
//! A permanent-magnet motor's magnets pull towards the stator teeth: a
//! torque `T_cog(theta)` that repeats `lcm(slots, 2 p)` times per
//! mechanical turn, whatever the current. Rotating the rotor by one pole
//! pair maps every magnet onto the next identical one, so the cogging of an
//! ideal machine repeats every electrical turn: `2 slots / gcd(slots, 2 p)`
//! cycles per electrical turn (12 on a 36-slot, 42-pole gimbal motor).
//!
//! The map holds, for each of [`COGGING_BINS`] points of the electrical
//! turn, the q current that cancels the cogging there, `-T_cog / kt`; the
//! current stage adds it, linearly interpolated, to the q current of every
//! closed-loop mode (torque, velocity, position, impedance), so that a
//! zero-torque command makes zero shaft torque and a position hold needs
//! no integrator to fight the teeth.
//!
//! **Why one electrical turn, not one mechanical turn** (ODrive's map has
//! 3600 points per mechanical turn, moteus's 1024): the electrical angle
//! is referred to the rotor's magnets by every alignment, on every kind of
//! sensor, so the map stays valid after a power cycle on an incremental
//! encoder without an index (whose mechanical zero is wherever the rotor
//! was at power-on), and on the sensorless observers; and 512 points per
//! electrical turn resolve the cogging of a 21-pole-pair motor (12 cycles
//! per electrical turn, 42 points per cycle), where 1024 per mechanical
//! turn would give 4. What it does not capture: the differences between
//! one pole pair and the next (magnet-to-magnet variation, eccentricity),
//! which the calibration averages out. A per-mechanical-turn map needs an
//! absolute mechanical reference (an absolute sensor or the index search).
//!
//! Storage: `i16` counts of `scale_a` amperes (1 KB): the step is the
//! map's peak over 32767, 0.03 mA on a 1 A map.

use crate::angle::ElectricalAngle;

/// Points of the map per electrical turn.
pub const COGGING_BINS: usize = 512;

/// `log2(COGGING_BINS)`.
const BIN_BITS: u32 = 9;

/// Largest count of the map.
const FULL_COUNT: f32 = 32767.0;

/// The cogging map: the q current \[A\] that cancels the cogging torque at
/// each point of the electrical turn.
/// `repr(C)`: the switch and the scale, read every period, before the
/// table (the stage keeps it at its end, design §20).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct CoggingMap {
    /// Apply the feed-forward (a measured map can be kept but switched
    /// off).
    pub enabled: bool,
    /// Amperes per count of [`Self::table`] (finite, `>= 0`).
    pub scale_a: f32,
    /// The feed-forward over electrical angles `k / COGGING_BINS` to
    /// `(k + 1) / COGGING_BINS` turns (its value at the centre), in counts
    /// of `scale_a`.
    pub table: [i16; COGGING_BINS],
}

/// Why a map was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CoggingMapError {
    /// The scale is negative or not finite.
    BadScale,
    /// A value given to [`CoggingMap::from_amps`] is not finite.
    NotFinite,
    /// The map's peak is above the current limit it is checked against.
    TooLarge,
}

impl CoggingMap {
    /// No map: zero everywhere, off.
    pub const EMPTY: Self = Self {
        enabled: false,
        scale_a: 0.0,
        table: [0; COGGING_BINS],
    };

    /// A map from amperes per point (quantised to the peak over 32767),
    /// enabled.
    pub fn from_amps(amps: &[f32; COGGING_BINS]) -> Result<Self, CoggingMapError> {
        let mut peak = 0.0f32;
        for a in amps {
            if !a.is_finite() {
                return Err(CoggingMapError::NotFinite);
            }
            peak = peak.max(a.abs());
        }
        let scale_a = scale_for_peak(peak);
        let mut map = Self {
            enabled: true,
            scale_a,
            table: [0; COGGING_BINS],
        };
        if scale_a > 0.0 {
            for (t, a) in map.table.iter_mut().zip(amps) {
                *t = count_of(*a, scale_a);
            }
        }
        Ok(map)
    }

    /// The feed-forward at point `k` \[A\] (`k` modulo the bins).
    #[inline]
    pub fn amps_at(&self, k: usize) -> f32 {
        self.table.get(k % COGGING_BINS).copied().unwrap_or(0) as f32 * self.scale_a
    }

    /// The map's largest magnitude \[A\].
    pub fn peak_a(&self) -> f32 {
        let c = self
            .table
            .iter()
            .map(|t| (*t as i32).unsigned_abs())
            .max()
            .unwrap_or(0);
        c as f32 * self.scale_a
    }

    /// Check the map before it is installed: a usable scale, and a peak
    /// within `max_current_a` (a map as large as the current limit is a
    /// measurement gone wrong, not cogging).
    pub fn check(&self, max_current_a: f32) -> Result<(), CoggingMapError> {
        if !(self.scale_a.is_finite() && self.scale_a >= 0.0) {
            return Err(CoggingMapError::BadScale);
        }
        // No count can exceed the scale's bound: within the limit, no scan
        // (the check runs in the interrupt when a calibration pass ends).
        if self.bound_a() <= max_current_a {
            return Ok(());
        }
        if self.peak_a() > max_current_a {
            return Err(CoggingMapError::TooLarge);
        }
        Ok(())
    }

    /// The largest feed-forward the table can hold at its scale \[A\] (any
    /// count, `-32768` included): a bound on [`Self::peak_a`] without its
    /// scan.
    pub fn bound_a(&self) -> f32 {
        -(i16::MIN as f32) * self.scale_a
    }

    /// The current of a full count \[A\]: the peak of a map scaled to its
    /// peak ([`Self::from_amps`], the calibration's), without the scan of
    /// [`Self::peak_a`].
    pub fn full_scale_a(&self) -> f32 {
        FULL_COUNT * self.scale_a
    }

    /// The feed-forward q current \[A\] at `theta_e` (0 when off), linear
    /// between the two nearest points.
    #[inline(always)]
    pub fn iq_a(&self, theta_e: ElectricalAngle) -> f32 {
        if !self.enabled {
            return 0.0;
        }
        // Point k holds the mean over its bin, whose centre is half a bin
        // on: interpolate between the centres (without the shift, the map
        // lagged by half a bin, 4 deg of a 12-cycle cogging).
        let bits = theta_e.to_bits().wrapping_sub(1 << (31 - BIN_BITS));
        let k = (bits >> (32 - BIN_BITS)) as usize;
        // The fraction between point k and k + 1, from the next 16 bits.
        let frac = ((bits >> (16 - BIN_BITS)) & 0xFFFF) as f32 * (1.0 / 65536.0);
        let a = self.table.get(k).copied().unwrap_or(0) as f32;
        let b = self.table.get((k + 1) % COGGING_BINS).copied().unwrap_or(0) as f32;
        (a + (b - a) * frac) * self.scale_a
    }
}

/// The scale \[A per count\] of a map whose largest magnitude is
/// `peak_a` \[A\] (as [`CoggingMap::from_amps`] chooses it).
pub(crate) fn scale_for_peak(peak_a: f32) -> f32 {
    peak_a / FULL_COUNT
}

/// `a` \[A\] in counts of `scale_a` (`> 0`), as [`CoggingMap::from_amps`]
/// quantises it.
pub(crate) fn count_of(a: f32, scale_a: f32) -> i16 {
    round_count(a / scale_a)
}

/// `x` rounded to the nearest count within `+-32767`.
fn round_count(x: f32) -> i16 {
    let r = if x >= 0.0 { x + 0.5 } else { x - 0.5 };
    // Saturating float-to-int cast; the clamp keeps the table symmetric.
    (r as i32).clamp(-(FULL_COUNT as i32), FULL_COUNT as i32) as i16
}

/// The point of the map an electrical angle falls in.
#[inline]
pub fn bin_of(theta_e: ElectricalAngle) -> usize {
    (theta_e.to_bits() >> (32 - BIN_BITS)) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sine(cycles: f32, amp: f32) -> [f32; COGGING_BINS] {
        let mut a = [0.0; COGGING_BINS];
        for (k, v) in a.iter_mut().enumerate() {
            // The point's value is its bin's centre's.
            let th = core::f32::consts::TAU * (k as f32 + 0.5) / COGGING_BINS as f32;
            *v = amp * libm::sinf(cycles * th);
        }
        a
    }

    #[test]
    fn interpolates_between_points_and_wraps() {
        let m = CoggingMap::from_amps(&sine(12.0, 0.4)).unwrap();
        assert!((m.peak_a() - 0.4).abs() < 1e-3);
        for i in 0..4096u32 {
            let th = ElectricalAngle::from_bits(i.wrapping_mul(1_048_573));
            let x = core::f32::consts::TAU * th.to_bits() as f32 / 4_294_967_296.0;
            let want = 0.4 * libm::sinf(12.0 * x);
            // 42 points per cycle: linear interpolation within 0.3 %.
            assert!((m.iq_a(th) - want).abs() < 0.003 * 0.4 + 1e-4, "{i}");
        }
        // Across the wrap: angle 0 is halfway between the last point's
        // centre and the first's.
        let mid = 0.5 * (m.amps_at(COGGING_BINS - 1) + m.amps_at(0));
        assert!((m.iq_a(ElectricalAngle::ZERO) - mid).abs() < 1e-4);
    }

    #[test]
    fn off_is_zero_and_bad_input_is_refused() {
        let mut m = CoggingMap::from_amps(&sine(6.0, 1.0)).unwrap();
        m.enabled = false;
        assert_eq!(m.iq_a(ElectricalAngle::from_bits(1 << 28)), 0.0);
        let mut nan = sine(6.0, 1.0);
        nan[7] = f32::NAN;
        assert_eq!(CoggingMap::from_amps(&nan), Err(CoggingMapError::NotFinite));
        let m = CoggingMap::from_amps(&sine(6.0, 2.0)).unwrap();
        assert_eq!(m.check(1.0), Err(CoggingMapError::TooLarge));
        assert_eq!(m.check(3.0), Ok(()));
        let bad = CoggingMap {
            scale_a: f32::NAN,
            ..m
        };
        assert_eq!(bad.check(3.0), Err(CoggingMapError::BadScale));
        let zero = CoggingMap::from_amps(&[0.0; COGGING_BINS]).unwrap();
        assert_eq!(zero.iq_a(ElectricalAngle::from_bits(12345)), 0.0);
    }
}
