//! The plant's scalar type and the few `libm` functions it needs.
//!
//! [`Real`] is `f64` by default; the `plant-f32` feature makes it `f32`
//! (faster on the Cortex-M4F, whose FPU is single precision only, at the cost
//! of accuracy in long runs). Everything in [`crate::plant`] is written against
//! this alias, so the same source builds either way.
//!
//! ```
//! use foc_plant::real::{self, Real};
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

/// Sine.
///
/// In f32 (the build that runs on the emulated Cortex-M4F) this uses
/// foc-core's table-free polynomial (worst error 1.3e-7, about 35
/// instructions) instead of `libm::sinf`, which computes in software double
/// precision on the M4F (about 1,270 instructions) and made the plant too
/// slow to run per PWM period. Only the scalar function is shared; the
/// plant's frame projections stay its own.
#[inline]
pub fn sin(x: Real) -> Real {
    #[cfg(not(feature = "plant-f32"))]
    {
        libm::sin(x)
    }
    #[cfg(feature = "plant-f32")]
    {
        foc_core::trig::sin_cos(foc_core::angle::ElectricalAngle::from_radians(x)).0
    }
}

/// Cosine (see [`sin`] for the f32 implementation).
#[inline]
pub fn cos(x: Real) -> Real {
    #[cfg(not(feature = "plant-f32"))]
    {
        libm::cos(x)
    }
    #[cfg(feature = "plant-f32")]
    {
        foc_core::trig::sin_cos(foc_core::angle::ElectricalAngle::from_radians(x)).1
    }
}
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
