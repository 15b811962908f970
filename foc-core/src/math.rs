//! Scalar math helpers used across the crate: the `sqrt(3)` constants, a
//! `no_std` square root that is fast on the Cortex-M4F, a one-comparison
//! finiteness test and clamps made of plain comparisons (no `fminf` /
//! `fmaxf` library calls). Everything here is total: no input panics.
//!
//! ```
//! use foc_core::math::{clamp, sqrtf};
//! assert_eq!(clamp(2.0, -1.0, 1.0), 1.0);
//! assert!((sqrtf(2.0) - 1.414_213_5).abs() < 1e-6);
//! assert_eq!(sqrtf(f32::NAN), 0.0);
//! ```

/// `sqrt(3)`.
pub const SQRT_3: f32 = 1.732_050_8;
/// `1 / sqrt(3)`.
pub const FRAC_1_SQRT_3: f32 = 0.577_350_26;
/// `2 / sqrt(3)`.
pub const FRAC_2_SQRT_3: f32 = 1.154_700_5;
/// `sqrt(3) / 2`.
pub const SQRT_3_2: f32 = 0.866_025_4;

/// Square root usable in `no_std`, fast on the Cortex-M4F, never panics.
///
/// `x <= 0`, `-0.0` and NaN give `0.0`; `+inf` gives `+inf`. Relative error
/// below `1e-6` for every other input (tested against f64 over normal and
/// subnormal inputs; measured worst 8.8e-8, about one ulp).
///
/// Why not `libm::sqrtf`: on `thumbv7em-none-eabihf` it does **not** compile
/// to `vsqrt.f32`. libm 0.2.16 has hardware paths only for x86 (SSE2),
/// aarch64 and wasm; on ARMv7E-M it runs its generic integer digit-by-digit
/// routine (about 60 instructions of code with branches and a loop, checked
/// with `llvm-objdump` on a release LTO build). `f32::sqrt` is not available
/// in `core` on stable, and `foc-core` forbids `unsafe` (so no `asm!`).
///
/// Method: the classic bit-trick initial guess of `1/sqrt(x)` (3.4 %),
/// two Newton steps on `1/sqrt(x)` (4.5e-6), then one Newton correction of
/// the root itself, `s + (y/2)(x - s^2)`, which also removes most of the
/// rounding error: about 30 instructions on the normal-input path
/// (if-converted, no division, no branch taken; from the disassembly),
/// against libm's software routine.
#[inline]
pub fn sqrtf(x: f32) -> f32 {
    if (f32::MIN_POSITIVE..=f32::MAX).contains(&x) {
        sqrtf_normal(x)
    } else {
        sqrtf_special(x)
    }
}

/// `sqrt(x)` for a normal, positive, finite `x`.
#[inline(always)]
fn sqrtf_normal(x: f32) -> f32 {
    let half_x = 0.5 * x;
    let mut y = f32::from_bits(0x5F37_5A86_u32.wrapping_sub(x.to_bits() >> 1));
    y = y * (1.5 - half_x * y * y);
    y = y * (1.5 - half_x * y * y);
    let s = x * y;
    s + 0.5 * y * (x - s * s)
}

/// Zero, negative, NaN, infinite and subnormal inputs (off the hot path).
#[cold]
#[inline(never)]
fn sqrtf_special(x: f32) -> f32 {
    if x > 0.0 && x < f32::MIN_POSITIVE {
        // Subnormal: scale into the normal range by 2^64, root, scale back by 2^-32.
        sqrtf_normal(x * 18_446_744_073_709_551_616.0) * (1.0 / 4_294_967_296.0)
    } else if x == f32::INFINITY {
        x
    } else {
        0.0
    }
}

/// True when every value is finite, with one comparison: the values are
/// summed, each scaled by `2^-8` (at most 16 of them, so a sum of finite
/// values stays far below `f32::MAX` whatever the rounding), and the sum
/// `s` is finite exactly
/// when every value is (an infinity or NaN makes it infinite or NaN);
/// `s - s == 0` tests that. About one multiply-add per value, instead of a
/// bit test and a branch each.
#[inline(always)]
pub(crate) fn all_finite<const N: usize>(xs: [f32; N]) -> bool {
    const { assert!(N <= 16) };
    let mut s = 0.0f32;
    for x in xs {
        s += x * (1.0 / 256.0);
    }
    #[allow(clippy::eq_op)] // NaN - NaN and inf - inf are NaN: on purpose.
    let finite = s - s == 0.0;
    finite
}

/// Clamp `x` to `[lo, hi]` with plain comparisons (no `fminf`/`fmaxf` calls,
/// which cost a library call each on the Cortex-M4F). A NaN `x` fails both
/// comparisons and is returned unchanged: callers that may see NaN check
/// `is_finite` first.
#[inline(always)]
pub fn clamp(x: f32, lo: f32, hi: f32) -> f32 {
    if x < lo {
        lo
    } else if x > hi {
        hi
    } else {
        x
    }
}

/// [`clamp`] for limits known to be ordered (`lo <= hi`, neither NaN), as
/// two independent selections: `max(x, lo)` then `min(_, hi)`. Same result
/// as [`clamp`] there, NaN `x` included (returned unchanged); each step is a
/// compare and a conditional move, with no branch.
#[inline(always)]
pub(crate) fn clamp_ordered(x: f32, lo: f32, hi: f32) -> f32 {
    let y = if x < lo { lo } else { x };
    if y > hi {
        hi
    } else {
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    extern crate std;

    fn rel_err(x: f32) -> f64 {
        let want = (x as f64).sqrt();
        ((sqrtf(x) as f64) - want).abs() / want
    }

    #[test]
    fn sqrt_relative_error_over_all_exponents() {
        // Every 97th bit pattern of the positive finite floats (normal and
        // subnormal), about 22 million values.
        let mut worst = 0.0f64;
        let mut bits = 1u32;
        while bits < 0x7F80_0000 {
            let e = rel_err(f32::from_bits(bits));
            if e > worst {
                worst = e;
            }
            bits += 97;
        }
        std::println!("sqrtf worst relative error {worst:e}");
        assert!(worst < 1e-6, "worst {worst:e}");
    }

    #[test]
    fn sqrt_exact_squares_and_special_values() {
        for k in 1..=4096u32 {
            let r = k as f32;
            let got = sqrtf(r * r);
            assert!((got - r).abs() <= r * 2.4e-7, "{k}: {got}");
        }
        assert_eq!(sqrtf(0.0), 0.0);
        assert_eq!(sqrtf(-0.0), 0.0);
        assert_eq!(sqrtf(-1.0), 0.0);
        assert_eq!(sqrtf(f32::NEG_INFINITY), 0.0);
        assert_eq!(sqrtf(f32::NAN), 0.0);
        assert_eq!(sqrtf(f32::INFINITY), f32::INFINITY);
        assert!(rel_err(f32::MAX) < 1e-6);
        assert!(rel_err(f32::MIN_POSITIVE) < 1e-6);
        assert!(rel_err(f32::from_bits(1)) < 1e-6);
    }

    #[test]
    fn all_finite_matches_is_finite() {
        let vals = [
            0.0,
            -0.0,
            1.0,
            -3.5,
            f32::MAX,
            -f32::MAX,
            f32::MIN_POSITIVE,
            f32::from_bits(1),
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
        ];
        for a in vals {
            for b in vals {
                for c in vals {
                    let want = a.is_finite() && b.is_finite() && c.is_finite();
                    assert_eq!(all_finite([a, b, c]), want, "{a} {b} {c}");
                }
            }
        }
        assert!(all_finite([f32::MAX; 7]));
        assert!(all_finite([-f32::MAX; 16]));
        assert!(all_finite([f32::MAX; 16]));
        assert!(!all_finite([f32::MAX, f32::MAX, f32::INFINITY]));
        assert!(all_finite::<0>([]));
    }

    #[test]
    fn clamp_plain() {
        assert_eq!(clamp(2.0, -1.0, 1.0), 1.0);
        assert_eq!(clamp(-2.0, -1.0, 1.0), -1.0);
        assert_eq!(clamp(0.25, -1.0, 1.0), 0.25);
        assert!(clamp(f32::NAN, -1.0, 1.0).is_nan());
    }

    #[test]
    fn clamp_ordered_matches_clamp() {
        let vals = [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            3.0,
            f32::MAX,
            -f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        for x in vals {
            for lo in vals {
                for hi in vals {
                    // Ordered limits only (NaN limits fail the comparison).
                    if lo.partial_cmp(&hi).is_none_or(|o| o.is_gt()) {
                        continue;
                    }
                    let (a, b) = (clamp(x, lo, hi), clamp_ordered(x, lo, hi));
                    assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()));
                }
            }
        }
    }
}
