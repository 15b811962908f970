//! Sine and cosine of a wrapping angle for the current loop.
//!
//! PLACEHOLDER implementation via libm (slow on the M4F); replaced by a fast
//! polynomial in the core-math work.

use crate::angle::ElectricalAngle;

/// `(sin(theta), cos(theta))`.
#[inline]
pub fn sin_cos(theta: ElectricalAngle) -> (f32, f32) {
    let r = theta.to_signed_radians();
    (libm::sinf(r), libm::cosf(r))
}
