//! The plant's scalar type and the few `libm` functions it needs.
//!
//! [`Real`] is `f64` by default; the `plant-f32` feature makes it `f32`
//! (faster on the Cortex-M4F, whose FPU is single precision only, at the cost
//! of accuracy in long runs). Everything in [`crate::plant`] is written against
//! this alias, so the same source builds either way.
//!
//! ```
//! use foc_bench::real::{self, Real};
//! let x: Real = 0.5;
//! assert!((real::sin(x) - 0.479_425_5).abs() < 1e-6);
//! ```

/// Scalar used by the plant integrator.
#[cfg(not(feature = "plant-f32"))]
pub type Real = f64;
/// Scalar used by the plant integrator.
#[cfg(feature = "plant-f32")]
pub type Real = f32;

/// `pi` in [`Real`].
#[cfg(not(feature = "plant-f32"))]
pub const PI: Real = core::f64::consts::PI;
/// `pi` in [`Real`].
#[cfg(feature = "plant-f32")]
pub const PI: Real = core::f32::consts::PI;

/// `2 pi` in [`Real`].
pub const TAU: Real = 2.0 * PI;
/// `2 pi / 3` in [`Real`].
pub const TWO_PI_3: Real = 2.0 * PI / 3.0;

macro_rules! unary {
    ($(#[$doc:meta])* $name:ident, $f64:ident, $f32:ident) => {
        $(#[$doc])*
        #[inline]
        pub fn $name(x: Real) -> Real {
            #[cfg(not(feature = "plant-f32"))]
            {
                libm::$f64(x)
            }
            #[cfg(feature = "plant-f32")]
            {
                libm::$f32(x)
            }
        }
    };
}

unary!(
    /// Sine.
    sin, sin, sinf
);
unary!(
    /// Cosine.
    cos, cos, cosf
);
unary!(
    /// Exponential.
    exp, exp, expf
);
unary!(
    /// Square root.
    sqrt, sqrt, sqrtf
);
unary!(
    /// Floor.
    floor, floor, floorf
);

/// `x` wrapped into `[0, 2 pi)` together with the number of whole turns removed.
#[inline]
pub fn wrap_tau(x: Real) -> (Real, i64) {
    let turns = floor(x / TAU);
    let mut r = x - turns * TAU;
    let mut t = turns as i64;
    if r >= TAU {
        r -= TAU;
        t += 1;
    }
    if r < 0.0 {
        r += TAU;
        t -= 1;
    }
    (r, t)
}

/// Sign as -1, 0 or +1.
#[inline]
pub fn signum0(x: Real) -> Real {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}
