//! Space-vector PWM (source section 8).
//!
//! PLACEHOLDER: min-max form only; the seven-segment sector implementation
//! lands with the core-math work, keeping this API.

use crate::frames::AlphaBeta;
use crate::{clamp, SQRT_3};

/// SVPWM sector (source section 8 table), 60 electrical degrees each.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Sector {
    /// 0..60 deg, vectors U4 (100) and U6 (110).
    I,
    /// 60..120 deg, U2 (010) and U6 (110).
    II,
    /// 120..180 deg, U2 (010) and U3 (011).
    III,
    /// 180..240 deg, U1 (001) and U3 (011).
    IV,
    /// 240..300 deg, U1 (001) and U5 (101).
    V,
    /// 300..360 deg, U4 (100) and U5 (101).
    VI,
}

/// Result of one modulation.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SvpwmOutput {
    /// High-side on-time of phases A, B, C as a fraction of the period, each in `[0, 1]`.
    pub duties: [f32; 3],
    /// Sector of the reference vector.
    pub sector: Sector,
    /// Time of the first active vector, fraction of the period.
    pub t_first: f32,
    /// Time of the second active vector, fraction of the period.
    pub t_second: f32,
    /// Time of each zero vector, `T0 = T7`, fraction of the period.
    pub t_zero: f32,
    /// `m = sqrt(3) |U_ref| / Udc` of the request (1.0 on the inscribed circle).
    pub modulation_index: f32,
    /// True when the request was outside the hexagon and was scaled back.
    pub saturated: bool,
    /// True when the input was unusable (non-finite, bus <= 0): duties are centred.
    pub invalid: bool,
}

impl SvpwmOutput {
    /// Centred duties (zero line-to-line voltage), flagged invalid.
    pub const NEUTRAL_INVALID: Self = Self {
        duties: [0.5; 3],
        sector: Sector::I,
        t_first: 0.0,
        t_second: 0.0,
        t_zero: 0.5,
        modulation_index: 0.0,
        saturated: false,
        invalid: true,
    };
}

/// Largest phase-voltage amplitude reachable without distortion
/// (inscribed circle of the hexagon): `Udc / sqrt(3)`.
#[inline]
pub fn max_linear_voltage_v(v_bus_v: f32) -> f32 {
    v_bus_v * crate::FRAC_1_SQRT_3
}

/// Modulate `v_ab` [V] on a bus of `v_bus_v` [V].
pub fn svpwm(v_ab: AlphaBeta, v_bus_v: f32) -> SvpwmOutput {
    if !v_ab.is_finite() || !v_bus_v.is_finite() || v_bus_v <= 0.0 {
        return SvpwmOutput::NEUTRAL_INVALID;
    }
    let duties = minmax(v_ab, v_bus_v);
    let m = SQRT_3 * v_ab.magnitude() / v_bus_v;
    SvpwmOutput {
        duties,
        sector: Sector::I,
        t_first: 0.0,
        t_second: 0.0,
        t_zero: 0.0,
        modulation_index: m,
        saturated: false,
        invalid: false,
    }
}

/// Min-max zero-sequence injection (independent check of [`svpwm`]).
pub fn minmax(v_ab: AlphaBeta, v_bus_v: f32) -> [f32; 3] {
    if !v_ab.is_finite() || !v_bus_v.is_finite() || v_bus_v <= 0.0 {
        return [0.5; 3];
    }
    let v = crate::transforms::inverse_clarke(v_ab);
    let max = v.a.max(v.b).max(v.c);
    let min = v.a.min(v.b).min(v.c);
    let off = -(max + min) * 0.5;
    let k = 1.0 / v_bus_v;
    [
        clamp(0.5 + (v.a + off) * k, 0.0, 1.0),
        clamp(0.5 + (v.b + off) * k, 0.0, 1.0),
        clamp(0.5 + (v.c + off) * k, 0.0, 1.0),
    ]
}

/// Centre-aligned compare values for a timer period of `period_counts`
/// (high side on while the counter is below the compare value).
pub fn compare_values(duties: [f32; 3], period_counts: u16) -> [u16; 3] {
    let p = period_counts as f32;
    let cv = |d: f32| -> u16 {
        let d = if d.is_finite() { clamp(d, 0.0, 1.0) } else { 0.5 };
        (d * p + 0.5) as u16
    };
    let [a, b, c] = duties;
    [cv(a), cv(b), cv(c)]
}
