//! Wrapping angles: electrical vs mechanical, as fractions of a turn.
//!
//! An angle is a [`U0F32`] fraction of one turn (`0 <= x < 1`), so adding
//! and subtracting wrap exactly, with no `fmod` and no drift however many
//! turns the rotor makes. Electrical and mechanical angles are distinct
//! types; the only way from one to the other is through the pole-pair count
//! (design §3: `theta_e = pole_pairs * theta_m`, modulo one turn).
//!
//! ```
//! use foc_core::angle::{MechanicalAngle, ElectricalAngle};
//! let m = MechanicalAngle::from_turns(0.3);
//! let e: ElectricalAngle = m.to_electrical(7); // 2.1 turns -> 0.1 turn
//! assert!((e.to_turns() - 0.1).abs() < 1e-6);
//! ```

use core::f32::consts::{PI, TAU};
use fixed::types::U0F32;

macro_rules! angle_type {
    ($(#[$doc:meta])* $name:ident) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub struct $name(U0F32);

        impl $name {
            /// Zero angle.
            pub const ZERO: Self = Self(U0F32::ZERO);

            /// From the raw 32-bit fraction of a turn (`2^32` = one turn).
            #[inline]
            pub const fn from_bits(bits: u32) -> Self {
                Self(U0F32::from_bits(bits))
            }
            /// The raw 32-bit fraction of a turn.
            #[inline]
            pub const fn to_bits(self) -> u32 {
                self.0.to_bits()
            }
            /// The underlying fixed-point fraction of a turn.
            #[inline]
            pub const fn to_fixed(self) -> U0F32 {
                self.0
            }
            /// From turns (any finite value; wraps into one turn).
            /// A non-finite input gives [`Self::ZERO`].
            #[inline]
            pub fn from_turns(turns: f32) -> Self {
                if !turns.is_finite() {
                    return Self::ZERO;
                }
                // Small magnitudes (typical per-period increments): scale
                // directly, exact to one LSB. Wrapping a small negative value
                // into [0, 1) first would round it to the f32 grid near 1.0
                // (6e-8 turn), i.e. a relative error of 0.4 % for a step of
                // -1e-4 rad, and a speed-dependent drift in one direction only.
                if turns > -0.5 && turns < 0.5 {
                    return Self::from_bits((turns * 4_294_967_296.0) as i32 as u32);
                }
                // Keep the fractional part in f32 first so that large inputs
                // do not lose the bits that matter, then scale to 2^32.
                let frac = turns - libm::floorf(turns); // [0, 1]
                let bits = (frac * 4_294_967_296.0) as u64; // saturating cast
                Self::from_bits(bits as u32)
            }
            /// From radians (any finite value; wraps). Non-finite gives zero;
            /// use [`Self::try_from_radians`] to detect it.
            #[inline]
            pub fn from_radians(rad: f32) -> Self {
                Self::from_turns(rad * (1.0 / TAU))
            }
            /// From radians, `None` when the input is not finite.
            #[inline]
            pub fn try_from_radians(rad: f32) -> Option<Self> {
                if rad.is_finite() {
                    Some(Self::from_radians(rad))
                } else {
                    None
                }
            }
            /// From degrees (wraps; non-finite gives zero).
            #[inline]
            pub fn from_degrees(deg: f32) -> Self {
                Self::from_turns(deg * (1.0 / 360.0))
            }
            /// Fraction of a turn in `[0, 1)`.
            #[inline]
            pub fn to_turns(self) -> f32 {
                self.to_bits() as f32 * (1.0 / 4_294_967_296.0)
            }
            /// Radians in `[0, 2 pi)` (may round up to exactly `2 pi` in f32).
            #[inline]
            pub fn to_radians(self) -> f32 {
                self.to_turns() * TAU
            }
            /// Radians in `[-pi, pi)`.
            #[inline]
            pub fn to_signed_radians(self) -> f32 {
                (self.to_bits() as i32) as f32 * (PI / 2_147_483_648.0)
            }
            /// Degrees in `[0, 360)`.
            #[inline]
            pub fn to_degrees(self) -> f32 {
                self.to_turns() * 360.0
            }
            /// `self + other`, wrapping.
            #[inline]
            #[must_use]
            pub const fn wrapping_add(self, other: Self) -> Self {
                Self::from_bits(self.to_bits().wrapping_add(other.to_bits()))
            }
            /// `self - other`, wrapping.
            #[inline]
            #[must_use]
            pub const fn wrapping_sub(self, other: Self) -> Self {
                Self::from_bits(self.to_bits().wrapping_sub(other.to_bits()))
            }
            /// Add an increment in radians (any sign), wrapping.
            #[inline]
            #[must_use]
            pub fn add_radians(self, rad: f32) -> Self {
                self.wrapping_add(Self::from_radians(rad))
            }
            /// Shortest signed difference `self - other` in radians, in `[-pi, pi)`.
            #[inline]
            pub fn diff_radians(self, other: Self) -> f32 {
                self.wrapping_sub(other).to_signed_radians()
            }
        }
    };
}

#[cfg(feature = "defmt")]
impl defmt::Format for ElectricalAngle {
    fn format(&self, f: defmt::Formatter) {
        defmt::write!(f, "{=f32} deg(e)", self.to_degrees())
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for MechanicalAngle {
    fn format(&self, f: defmt::Formatter) {
        defmt::write!(f, "{=f32} deg(m)", self.to_degrees())
    }
}

angle_type!(
    /// Electrical angle `theta_e` of the rotor d axis, measured from the
    /// phase-A axis, as a wrapping fraction of one electrical turn.
    ElectricalAngle
);
angle_type!(
    /// Mechanical rotor angle `theta_m` as a wrapping fraction of one turn.
    MechanicalAngle
);

impl MechanicalAngle {
    /// Electrical angle for a motor with `pole_pairs` pole pairs:
    /// `theta_e = pole_pairs * theta_m` modulo one turn, exact in fixed point.
    #[inline]
    pub const fn to_electrical(self, pole_pairs: u8) -> ElectricalAngle {
        ElectricalAngle::from_bits(self.to_bits().wrapping_mul(pole_pairs as u32))
    }
}

/// A mechanical position over many turns: whole turns plus a wrapping angle.
///
/// Fed with successive single-turn readings (each less than half a turn
/// apart), it counts turns exactly and never drifts.
///
/// The turn count saturates at its range: at [`i32::MAX`] (or [`i32::MIN`])
/// turns a further wrap in the same direction leaves `turns` where it is
/// (it never wraps to the other end), while `angle` keeps following the
/// readings and [`Self::update`] still returns the true change. A
/// saturated position is therefore wrong by the turns it could not count
/// (about 2^31 turns: centuries at 10 000 rpm); turning back counts down
/// from the limit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MultiTurn {
    /// Completed turns (signed).
    pub turns: i32,
    /// Angle within the turn.
    pub angle: MechanicalAngle,
}

impl MultiTurn {
    /// Position zero.
    pub const ZERO: Self = Self {
        turns: 0,
        angle: MechanicalAngle::ZERO,
    };

    /// Start at a single-turn reading.
    pub const fn new(angle: MechanicalAngle) -> Self {
        Self { turns: 0, angle }
    }

    /// Advance to a new single-turn reading, counting a turn when the
    /// reading wraps (shortest path; the count saturates at the `i32`
    /// range, see the type's docs). Returns the signed change in radians.
    pub fn update(&mut self, new: MechanicalAngle) -> f32 {
        let delta = new.wrapping_sub(self.angle).to_bits() as i32;
        let old = self.angle.to_bits();
        self.angle = new;
        if delta > 0 && new.to_bits() < old {
            self.turns = self.turns.saturating_add(1);
        } else if delta < 0 && new.to_bits() > old {
            self.turns = self.turns.saturating_sub(1);
        }
        delta as f32 * (PI / 2_147_483_648.0)
    }

    /// Position in radians (`turns * 2 pi + angle`). f32: resolution about
    /// 0.5 mrad at 1000 turns.
    pub fn to_radians(&self) -> f32 {
        self.turns as f32 * TAU + self.angle.to_radians()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wraps_both_ways() {
        let a = ElectricalAngle::from_degrees(350.0);
        let b = a.add_radians(20f32.to_radians());
        assert!((b.to_degrees() - 10.0).abs() < 1e-3);
        let c = b.add_radians(-30f32.to_radians());
        assert!((c.to_degrees() - 340.0).abs() < 1e-3);
        assert!((c.diff_radians(a).to_degrees() + 10.0).abs() < 1e-3);
    }

    #[test]
    fn small_negative_steps_are_as_exact_as_positive_ones() {
        // 10_000 steps of -+1e-4 rad must come back to the start, and each
        // must be accurate to about f32 precision of the step itself.
        for rad in [1e-4f32, 3.3e-6, 0.01] {
            let up = ElectricalAngle::from_radians(rad).to_bits() as i64;
            let down = ElectricalAngle::from_radians(-rad).to_bits() as i32 as i64;
            assert!((up + down).abs() <= 1, "{rad}: {up} vs {down}");
            let exact = rad as f64 / core::f64::consts::TAU * 4_294_967_296.0;
            assert!(((up as f64) - exact).abs() <= exact * 2.5e-7 + 1.0);
        }
        assert_eq!(ElectricalAngle::from_turns(-0.25).to_bits(), 3 << 30);
        assert_eq!(ElectricalAngle::from_turns(0.25).to_bits(), 1 << 30);
        assert_eq!(ElectricalAngle::from_turns(-0.5).to_bits(), 1 << 31);
        assert_eq!(ElectricalAngle::from_turns(2.75).to_bits(), 3 << 30);
    }

    #[test]
    fn non_finite_is_zero() {
        assert_eq!(
            ElectricalAngle::from_radians(f32::NAN),
            ElectricalAngle::ZERO
        );
        assert_eq!(ElectricalAngle::try_from_radians(f32::INFINITY), None);
    }

    #[test]
    fn electrical_from_mechanical_no_drift() {
        // 1e6 increments of a mechanical step: the electrical angle equals
        // pole_pairs times the exact mechanical sum, bit for bit.
        let step = MechanicalAngle::from_bits(123_456_789);
        let mut m = MechanicalAngle::ZERO;
        let mut e = ElectricalAngle::ZERO;
        let e_step = step.to_electrical(7);
        for _ in 0..1_000_000 {
            m = m.wrapping_add(step);
            e = e.wrapping_add(e_step);
        }
        assert_eq!(m.to_electrical(7), e);
    }

    #[test]
    fn multiturn_counts_turns() {
        let mut p = MultiTurn::ZERO;
        let step = MechanicalAngle::from_degrees(90.0);
        let mut a = MechanicalAngle::ZERO;
        for _ in 0..40 {
            a = a.wrapping_add(step);
            p.update(a);
        }
        assert_eq!(p.turns, 10);
        assert!((p.to_radians() - 3600f32.to_radians()).abs() < 1e-3);
        for _ in 0..80 {
            a = a.wrapping_sub(step);
            p.update(a);
        }
        assert_eq!(p.turns, -10);
    }

    /// At the ends of the `i32` range the count saturates instead of
    /// wrapping to the other end; the angle and the returned change still
    /// follow the readings, and turning back counts down from the limit.
    #[test]
    fn multiturn_saturates_at_its_range() {
        let quarter = MechanicalAngle::from_degrees(90.0);
        let step_rad = quarter.to_radians();
        for (start, dir) in [(i32::MAX - 1, 1i32), (i32::MIN + 1, -1)] {
            let mut p = MultiTurn {
                turns: start,
                angle: MechanicalAngle::ZERO,
            };
            let mut a = MechanicalAngle::ZERO;
            let mut turns = [0i32; 16];
            for t in turns.iter_mut() {
                a = if dir > 0 {
                    a.wrapping_add(quarter)
                } else {
                    a.wrapping_sub(quarter)
                };
                let d = p.update(a);
                assert!((d - dir as f32 * step_rad).abs() < 1e-6, "{d}");
                assert_eq!(p.angle, a);
                *t = p.turns;
            }
            let limit = if dir > 0 { i32::MAX } else { i32::MIN };
            // One turn reaches the limit, three more stay there.
            let expect_first = if dir > 0 { start } else { start - 1 };
            assert_eq!(turns[0], expect_first, "{turns:?}");
            assert!(turns[3..].iter().all(|&t| t == limit), "{turns:?}");
            assert!(p.to_radians().is_finite());
            assert_eq!(p.to_radians().signum(), dir as f32);
            // Back one turn the other way: one below the limit.
            for _ in 0..4 {
                a = if dir > 0 {
                    a.wrapping_sub(quarter)
                } else {
                    a.wrapping_add(quarter)
                };
                p.update(a);
            }
            assert_eq!(p.turns, limit - dir);
        }
    }
}
