//! Sine and cosine of a wrapping angle for the current loop.
//!
//! The Park and inverse Park transforms (design §5 and §7) need
//! `sin(theta_e)` and `cos(theta_e)` once per PWM period. `libm::sinf` /
//! `cosf` cost about 1,270 instructions each on the Cortex-M4F (they compute
//! in f64, in software), so [`sin_cos`] uses:
//!
//! 1. **Exact quadrant reduction in integer arithmetic.** The angle is a
//!    `u32` fraction of a turn. Adding `2^29` (1/8 turn) and taking the top
//!    two bits gives the nearest quadrant `q` (0..3); the low 30 bits minus
//!    `2^29` give the signed remainder `r` in `[-2^29, 2^29)`, i.e. `u = r / 2^32`
//!    in `[-1/8, 1/8)` of a turn (`[-45, 45)` degrees). No rounding happens
//!    here, whatever the angle, so there is no drift and no large-argument
//!    problem.
//! 2. **Two short minimax polynomials in `u` (turns)**, fitted on
//!    `[-1/8, 1/8]` with Lawson-weighted least squares for minimum absolute
//!    error:
//!    `sin(2 pi u) = u (S0 + S1 u^2 + S2 u^4 + S3 u^6)` (approximation error
//!    1.2e-9) and `cos(2 pi u) = 1 + u^2 (C1 + C2 u^2 + C3 u^4)` (3.2e-8;
//!    the constant is pinned to exactly 1 so that `cos(0) = 1`).
//! 3. **Quadrant fix-up by symmetry**: swap sin/cos when `q` is odd, flip
//!    signs via the f32 sign bit.
//!
//! Cost: one int-to-float conversion, 5 `vmul` + 6 `vmla` (multiply-add)
//! and a handful of integer operations: 33 straight-line instructions for
//! the body on `thumbv7em-none-eabihf` (release, LTO; counted in the
//! `llvm-objdump` disassembly), no branches, no library calls, no panics.
//!
//! Accuracy (measured against f64 `sin`/`cos`): worst absolute error
//! **1.05e-7** over every `2^12`-th bit pattern of the turn, 2^20 random
//! angles and the 2^16 patterns around every multiple of 45 degrees (the
//! default tests), and **1.27e-7** over every 16th bit pattern (2^28
//! angles, an `#[ignore]`d test). That is about two f32 ulps at 1.0: the
//! polynomial error itself is below 4e-8, the rest is f32 rounding. The
//! asserted bound is [`SIN_COS_MAX_ABS_ERROR`].
//! Outputs never exceed 1 in magnitude, and the results at multiples of 90
//! degrees are exact (`0` and `+-1`).
//!
//! ```
//! use foc_core::angle::ElectricalAngle;
//! use foc_core::trig::sin_cos;
//! let (s, c) = sin_cos(ElectricalAngle::from_degrees(30.0));
//! assert!((s - 0.5).abs() < 1e-6);
//! assert!((c - 0.866_025_4).abs() < 1e-6);
//! let (s, c) = sin_cos(ElectricalAngle::from_bits(1 << 30)); // exactly 90 deg
//! assert_eq!((s, c.abs()), (1.0, 0.0));
//! ```

use crate::angle::ElectricalAngle;

/// Upper bound of `|sin_cos(theta) - (sin, cos)(theta)|` over all angles,
/// as asserted by the tests (measured worst case 1.27e-7, rounded up).
pub const SIN_COS_MAX_ABS_ERROR: f32 = 2.0e-7;

// sin(2 pi u) / u as a polynomial in u^2, u in [-1/8, 1/8] turn.
// 6.283185 (one ulp below 2 pi: the minimax value, not TAU).
const S0: f32 = f32::from_bits(0x40C9_0FDA);
const S1: f32 = -41.34163;
const S2: f32 = 81.58813;
const S3: f32 = -75.24007;
// (cos(2 pi u) - 1) / u^2 as a polynomial in u^2.
const C1: f32 = -19.739168;
const C2: f32 = 64.923225;
const C3: f32 = -83.66592;

/// `(sin(theta), cos(theta))` of an electrical angle, fast and branch-free
/// (see the module docs for method and accuracy: worst absolute error
/// below [`SIN_COS_MAX_ABS_ERROR`]).
#[inline]
pub fn sin_cos(theta: ElectricalAngle) -> (f32, f32) {
    sin_cos_bits(theta.to_bits())
}

/// `(sin, cos)` of `bits / 2^32` turns; the raw form of [`sin_cos`], usable
/// directly with any 32-bit wrapping angle (e.g. a mechanical one).
#[inline]
pub fn sin_cos_bits(bits: u32) -> (f32, f32) {
    // Nearest quadrant and the exact signed remainder (integer arithmetic).
    let shifted = bits.wrapping_add(1 << 29);
    let q = shifted >> 30; // 0..=3
    let r = (shifted & 0x3FFF_FFFF) as i32 - (1 << 29); // [-2^29, 2^29)
    let u = r as f32 * (1.0 / 4_294_967_296.0); // turns, [-1/8, 1/8)
    let y = u * u;
    let s = u * (S0 + y * (S1 + y * (S2 + y * S3)));
    let c = 1.0 + y * (C1 + y * (C2 + y * C3));
    // Rotate by q quarter turns: q=0 (s, c), q=1 (c, -s), q=2 (-s, -c), q=3 (-c, s).
    let (s, c) = if q & 1 == 0 { (s, c) } else { (c, s) };
    let sin_sign = (q & 2) << 30; // negate sin for q = 2, 3
    let cos_sign = (q.wrapping_add(1) & 2) << 30; // negate cos for q = 1, 2
    (
        f32::from_bits(s.to_bits() ^ sin_sign),
        f32::from_bits(c.to_bits() ^ cos_sign),
    )
}

/// Largest `|delta|` \[rad\] that [`rotate_small`] accepts: its truncation
/// error there is below `1.3e-8` (see [`rotate_small`]).
pub const SMALL_ROTATION_MAX_RAD: f32 = 0.25;

/// `(sin(theta + delta), cos(theta + delta))` from `(sin(theta),
/// cos(theta))` and a small `delta` \[rad\], `|delta| <=`
/// [`SMALL_ROTATION_MAX_RAD`], without a second [`sin_cos`]: the angle-sum
/// formulas with Taylor polynomials of `sin(delta)` (to `delta^5`) and
/// `cos(delta)` (to `delta^6`). Truncation error below `|delta|^7 / 5040`
/// and `|delta|^8 / 40320`, i.e. at most `1.2e-8` at `|delta| = 0.25`;
/// with f32 rounding the result is within `4e-7` of the exact rotation of
/// the inputs (tested), comparable to [`SIN_COS_MAX_ABS_ERROR`]. `delta = 0`
/// returns values equal to the inputs.
///
/// About 14 instructions (against about 40 for [`sin_cos`]). The caller
/// checks the range; outside it the result degrades (it is not clamped).
///
/// ```
/// use foc_core::angle::ElectricalAngle;
/// use foc_core::trig::{rotate_small, sin_cos};
/// let th = ElectricalAngle::from_degrees(40.0);
/// let (s, c) = rotate_small(sin_cos(th), 0.1);
/// let (s2, c2) = sin_cos(th.add_radians(0.1));
/// assert!((s - s2).abs() < 4e-7 && (c - c2).abs() < 4e-7);
/// ```
#[inline(always)]
pub fn rotate_small((sin, cos): (f32, f32), delta: f32) -> (f32, f32) {
    let d2 = delta * delta;
    // sin d = d (1 - d^2/6 + d^4/120), cos d = 1 - d^2/2 + d^4/24 - d^6/720.
    let sd = delta + delta * d2 * (-1.0 / 6.0 + d2 * (1.0 / 120.0));
    let cd_m1 = d2 * (-0.5 + d2 * (1.0 / 24.0 + d2 * (-1.0 / 720.0)));
    // sin(t + d) = s cos d + c sin d, cos(t + d) = c cos d - s sin d, with
    // cos d = 1 + cd_m1 so that d = 0 gives (s, c) exactly.
    (
        sin + (sin * cd_m1 + cos * sd),
        cos + (cos * cd_m1 - sin * sd),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    extern crate std;

    fn err_at(bits: u32) -> f64 {
        let (s, c) = sin_cos_bits(bits);
        let t = bits as f64 * (core::f64::consts::TAU / 4_294_967_296.0);
        let es = (s as f64 - t.sin()).abs();
        let ec = (c as f64 - t.cos()).abs();
        if es > ec {
            es
        } else {
            ec
        }
    }

    #[test]
    fn sweep_every_4096th_pattern() {
        let mut worst = 0.0f64;
        let mut worst_bits = 0u32;
        for k in 0..(1u32 << 20) {
            let bits = k << 12;
            let e = err_at(bits);
            if e > worst {
                worst = e;
                worst_bits = bits;
            }
        }
        std::println!("sin_cos worst abs error {worst:e} at bits {worst_bits:#010x}");
        assert!(worst < SIN_COS_MAX_ABS_ERROR as f64, "worst {worst:e}");
        assert!(worst < 1e-4);
    }

    /// Every 16th bit pattern of the turn (2^28 angles; a few seconds in
    /// release): `cargo test -p foc-core --release --lib -- --ignored`.
    #[test]
    #[ignore]
    fn sweep_every_16th_pattern() {
        let mut worst = 0.0f64;
        let mut worst_bits = 0u32;
        for k in 0..(1u32 << 28) {
            let bits = k << 4;
            let e = err_at(bits);
            if e > worst {
                worst = e;
                worst_bits = bits;
            }
        }
        std::println!("sin_cos worst abs error {worst:e} at bits {worst_bits:#010x}");
        assert!(worst < SIN_COS_MAX_ABS_ERROR as f64, "worst {worst:e}");
    }

    #[test]
    fn dense_around_octant_boundaries() {
        // The reduction switches quadrant at odd multiples of 45 deg and the
        // polynomials are evaluated at their ends there.
        let mut worst = 0.0f64;
        for oct in 0u32..8 {
            let centre = oct << 29;
            for d in 0u32..(1 << 15) {
                for bits in [centre.wrapping_add(d), centre.wrapping_sub(d)] {
                    let e = err_at(bits);
                    if e > worst {
                        worst = e;
                    }
                }
            }
        }
        assert!(worst < SIN_COS_MAX_ABS_ERROR as f64, "worst {worst:e}");
    }

    #[test]
    fn random_patterns() {
        // xorshift32: deterministic but covers all bit positions.
        let mut x: u32 = 0x1234_5678;
        let mut worst = 0.0f64;
        for _ in 0..(1 << 20) {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let e = err_at(x);
            if e > worst {
                worst = e;
            }
        }
        assert!(worst < SIN_COS_MAX_ABS_ERROR as f64, "worst {worst:e}");
    }

    #[test]
    fn exact_at_quarter_turns_and_bounded() {
        assert_eq!(sin_cos_bits(0), (0.0, 1.0));
        let (s, c) = sin_cos_bits(1 << 30);
        assert_eq!((s, c.abs()), (1.0, 0.0));
        let (s, c) = sin_cos_bits(2 << 30);
        assert_eq!((s.abs(), c), (0.0, -1.0));
        let (s, c) = sin_cos_bits(3 << 30);
        assert_eq!((s, c.abs()), (-1.0, 0.0));
        let mut x: u32 = 0xDEAD_BEEF;
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let (s, c) = sin_cos_bits(x);
            assert!(s.abs() <= 1.0 && c.abs() <= 1.0);
            assert!(((s * s + c * c) - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn signs_per_quadrant() {
        for deg in [10.0f32, 100.0, 190.0, 280.0] {
            let (s, c) = sin_cos(ElectricalAngle::from_degrees(deg));
            let r = (deg as f64).to_radians();
            assert_eq!(s > 0.0, r.sin() > 0.0, "{deg}");
            assert_eq!(c > 0.0, r.cos() > 0.0, "{deg}");
        }
    }

    /// `rotate_small` against f64 over angles and deltas up to the limit;
    /// `delta = 0` is exact.
    #[test]
    fn small_rotation_accuracy() {
        let mut worst = 0.0f64;
        let mut x: u32 = 0x0BAD_F00D;
        for k in 0..200_000u32 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let d = SMALL_ROTATION_MAX_RAD * ((k % 2001) as f32 / 1000.0 - 1.0);
            let sc = sin_cos_bits(x);
            let (s, c) = rotate_small(sc, d);
            // Exact rotation of the (approximate) inputs.
            let (s0, c0) = (sc.0 as f64, sc.1 as f64);
            let (sd, cd) = ((d as f64).sin(), (d as f64).cos());
            let es = (s as f64 - (s0 * cd + c0 * sd)).abs();
            let ec = (c as f64 - (c0 * cd - s0 * sd)).abs();
            worst = worst.max(es).max(ec);
            assert_eq!(rotate_small(sc, 0.0), sc);
        }
        std::println!("rotate_small worst abs error {worst:e}");
        assert!(worst < 4e-7, "worst {worst:e}");
    }
}
