//! SI (rotor frame) <-> CiA 402 units, saturating, NaN-safe.
//!
//! Positions and velocities: [`INC_PER_REV`] increments per rotor
//! revolution. Torques and currents: per mille of the rated value; the rated
//! current is the drive's current limit ([`Limits::max_current_a`]), the
//! rated torque `kt` times it. Every conversion to an integer rounds to
//! nearest, saturates at the type's range and maps NaN to 0; every
//! conversion to SI is finite.
//!
//! ```
//! use foc_canopen::cia402::units::{inc_to_rad, rad_to_inc};
//! assert_eq!(rad_to_inc(core::f32::consts::PI), 32_768);
//! assert_eq!(rad_to_inc(f32::NAN), 0);
//! assert_eq!(rad_to_inc(1e30), i32::MAX);
//! assert!((inc_to_rad(65_536) - core::f32::consts::TAU).abs() < 1e-6);
//! ```

use core::f32::consts::TAU;

use foc_core::control::Limits;

use super::INC_PER_REV;

/// Radians per increment.
pub const RAD_PER_INC: f32 = TAU / INC_PER_REV as f32;
/// Increments per radian.
pub const INC_PER_RAD: f32 = INC_PER_REV as f32 / TAU;

/// Round to nearest and saturate to `i32` (NaN: 0).
pub fn sat_i32(x: f32) -> i32 {
    if x.is_nan() {
        return 0;
    }
    // `as` saturates at the range (and infinities) by definition.
    if x >= 0.0 {
        (x + 0.5) as i32
    } else {
        (x - 0.5) as i32
    }
}

/// Round to nearest and saturate to `i16` (NaN: 0).
pub fn sat_i16(x: f32) -> i16 {
    let v = sat_i32(x);
    if v > i32::from(i16::MAX) {
        i16::MAX
    } else if v < i32::from(i16::MIN) {
        i16::MIN
    } else {
        v as i16
    }
}

/// Increments (or increments/s, /s^2) to radians (rad/s, rad/s^2).
pub fn inc_to_rad(inc: i32) -> f32 {
    inc as f32 * RAD_PER_INC
}

/// An unsigned increment quantity (windows, profile velocities) to SI.
pub fn uinc_to_rad(inc: u32) -> f32 {
    inc as f32 * RAD_PER_INC
}

/// Radians (rad/s) to increments (inc/s): rounded, saturated, NaN -> 0.
pub fn rad_to_inc(rad: f32) -> i32 {
    sat_i32(rad * INC_PER_RAD)
}

/// The rated current \[A\]: the drive's current limit (0 when not a finite
/// positive value: every torque then converts to 0 A).
pub fn rated_current_a(limits: &Limits) -> f32 {
    let i = limits.max_current_a;
    if i.is_finite() && i > 0.0 {
        i
    } else {
        0.0
    }
}

/// The rated torque [mN m] (0x6076): `kt` x rated current, saturated.
pub fn rated_torque_mnm(kt_nm_per_a: f32, limits: &Limits) -> u32 {
    let t = kt_nm_per_a * rated_current_a(limits) * 1000.0;
    if t.is_finite() && t > 0.0 {
        t as u32
    } else {
        0
    }
}

/// The rated current \[mA\] (0x6075).
pub fn rated_current_ma(limits: &Limits) -> u32 {
    (rated_current_a(limits) * 1000.0) as u32
}

/// Per mille of the rated value to amps (q current): torque and current
/// share the factor since `T = kt iq`.
pub fn permille_to_amps(permille: f32, rated_a: f32) -> f32 {
    let a = permille * 0.001 * rated_a;
    if a.is_finite() {
        a
    } else {
        0.0
    }
}

/// Amps (q current) to per mille of the rated value (0 when the rated value
/// is 0 or the current not finite).
pub fn amps_to_permille(a: f32, rated_a: f32) -> i16 {
    if rated_a > 0.0 {
        sat_i16(a / rated_a * 1000.0)
    } else {
        0
    }
}

/// Volts to millivolts (negative and NaN: 0, saturating).
pub fn volts_to_mv(v: f32) -> u32 {
    let mv = v * 1000.0;
    if mv.is_nan() || mv <= 0.0 {
        0
    } else {
        mv as u32
    }
}

/// `x` if finite, else 0.
pub fn finite_or_zero(x: f32) -> f32 {
    if x.is_finite() {
        x
    } else {
        0.0
    }
}

/// `x` clamped to `[-limit, limit]` (`limit` >= 0 finite; NaN x: 0).
pub fn clamp_abs(x: f32, limit: f32) -> f32 {
    let x = finite_or_zero(x);
    if x > limit {
        limit
    } else if x < -limit {
        -limit
    } else {
        x
    }
}

/// `x` clamped to `[lo, hi]` without the panics of `f32::clamp` (NaN
/// bounds are ignored, a NaN `x` gives `lo` when finite, else 0).
pub fn clamp_range(x: f32, lo: f32, hi: f32) -> f32 {
    if x.is_nan() {
        return if lo.is_finite() { lo } else { 0.0 };
    }
    if x > hi {
        hi
    } else if x < lo {
        lo
    } else {
        x
    }
}
