//! Seven-segment space-vector PWM (design §8).
//!
//! # Vectors and frame
//!
//! The six active switching states are named by the high-side states of
//! phases A B C read as a binary number (design §8):
//! U4 = 100 at 0 deg, U6 = 110 at 60, U2 = 010 at 120, U3 = 011 at 180,
//! U1 = 001 at 240, U5 = 101 at 300, each of length `2 Udc / 3`, plus the
//! zero vectors U0 = 000 and U7 = 111 ([`space_vector`] computes them).
//! The angles are those of **our** alpha/beta frame (see
//! [`crate::transforms`]: beta 90 deg ahead of phase A, towards phase B at
//! +120 deg), and the tests check them by Clarke-transforming every
//! switching state.
//!
//! # How the source's table maps onto our frame
//!
//! The source writes (design §8), with `K = sqrt(3) Ts / Udc`:
//!
//! ```text
//! U1 = U_beta
//! U2 =  (sqrt(3)/2) U_alpha - U_beta/2
//! U3 = -(sqrt(3)/2) U_alpha - U_beta/2
//! ```
//!
//! With `U_alpha = |U| cos(theta)`, `U_beta = |U| sin(theta)` in *our*
//! frame these are `U1 = |U| sin(theta)`, `U2 = |U| sin(60 deg - theta)`,
//! `U3 = -|U| sin(60 deg + theta)`, and the law-of-sines result of sector I,
//! `T4 = m T sin(60 deg - theta)`, `T6 = m T sin(theta)` with
//! `m = sqrt(3) |U| / Udc`, is exactly `T4 = K U2`, `T6 = K U1`: the
//! source's SVPWM table is written for the standard beta axis, i.e. ours,
//! **not** for the reversed beta axis of its own Clarke transform
//! (`beta_src = -beta`, design §4). It is used here unchanged with
//! our `U_beta`. In terms of the source's axis it reads `U1 = -beta_src`,
//! `U2 = (sqrt(3)/2) alpha + beta_src/2`, `U3 = -(sqrt(3)/2) alpha +
//! beta_src/2`; feeding `beta_src` into the table as printed would mirror
//! every sector (a request at +30 deg would be modulated at -30 deg). The
//! mapping test in `tests/math_props.rs` shows this.
//!
//! # Sector from signs
//!
//! `U1 = sin(theta)`, `U2 = sin(theta + 120)`, `U3 = sin(theta - 120)` (times
//! `|U|`) change sign at the six sector boundaries. With `s_i = (U_i >= 0)`:
//!
//! | s1 s2 s3 | sector | first time | second time | sequence |
//! |---|---|---|---|---|
//! | 1 1 0 (and 1 1 1 = zero vector) | I   | T4 =  K U2 | T6 =  K U1 | 0-4-6-7-7-6-4-0 |
//! | 1 0 0                           | II  | T2 = -K U2 | T6 = -K U3 | 0-2-6-7-7-6-2-0 |
//! | 1 0 1                           | III | T2 =  K U1 | T3 =  K U3 | 0-2-3-7-7-3-2-0 |
//! | 0 0 1 (and 0 0 0, impossible)   | IV  | T1 = -K U1 | T3 = -K U2 | 0-1-3-7-7-3-1-0 |
//! | 0 1 1                           | V   | T1 =  K U3 | T5 =  K U2 | 0-1-5-7-7-5-1-0 |
//! | 0 1 0                           | VI  | T4 = -K U3 | T5 = -K U1 | 0-4-5-7-7-5-4-0 |
//!
//! `U3` is computed as `-(U1 + U2)` (the same value as the source's formula,
//! since `U1 + U2 + U3 = 0`), which makes the sign pattern consistent under
//! rounding: the signs chosen for a sector are exactly the ones that make
//! both of its times `>= 0`, so every input, including the exact boundaries
//! 0, 60, ..., 360 deg (where one time is 0 and both neighbouring sectors
//! give the same duties), lands in a defined sector with non-negative
//! times. The `match` is exhaustive with no `unreachable!`.
//!
//! # Duties
//!
//! `T0 = T7 = (Ts - Tfirst - Tsecond) / 2`. In every sector the first
//! vector has one phase high and the second two, so over the sequence
//! `0-a-b-7-7-b-a-0` (each segment split in half around the centre) the
//! phase high in both active vectors is on for `T7 + Tfirst + Tsecond`, the
//! phase high only in the second for `T7 + Tsecond`, the third only during
//! `T7`. As fractions of the period:
//! `d_max = 1 - t0`, `d_mid = t0 + t_second`, `d_min = t0`.
//!
//! # Overmodulation
//!
//! When `Tfirst + Tsecond > Ts` the request lies outside the hexagon: both
//! times are scaled by `Ts / (Tfirst + Tsecond)`, which keeps their ratio
//! and so the angle, and puts the vector on the hexagon edge (`T0 = T7 = 0`);
//! [`SvpwmOutput::saturated`] is set. Non-finite input or a bus voltage that
//! is not finite and positive gives centred duties with
//! [`SvpwmOutput::invalid`] set; nothing here can panic.
//!
//! ```
//! use foc_core::frames::AlphaBeta;
//! use foc_core::svpwm::{svpwm, compare_values, Sector};
//! // 10 V at 30 deg on a 24 V bus.
//! let v = AlphaBeta::new(10.0 * 0.866_025_4, 10.0 * 0.5);
//! let out = svpwm(v, 24.0);
//! assert_eq!(out.sector, Sector::I);
//! assert!(!out.saturated && !out.invalid);
//! let [a, b, c] = out.duties;
//! assert!(a > b && b > c); // U4 (100) then U6 (110)
//! // Line-to-line average voltage equals the request: v_a - v_b = 1.5 alpha - (sqrt3/2) beta.
//! assert!(((a - b) * 24.0 - (1.5 * v.alpha - 0.866_025_4 * v.beta)).abs() < 1e-4);
//! let cmp = compare_values(out.duties, 4200);
//! assert!(cmp.iter().all(|&x| x <= 4200));
//! assert_eq!(Sector::I.sequence(), [0, 4, 6, 7, 7, 6, 4, 0]);
//! ```

use crate::frames::AlphaBeta;
use crate::{clamp, SQRT_3, SQRT_3_2};

/// SVPWM sector (design §8 table), 60 electrical degrees each, in
/// our alpha/beta frame.
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

impl Sector {
    /// All six sectors in order of angle.
    pub const ALL: [Sector; 6] = [
        Sector::I,
        Sector::II,
        Sector::III,
        Sector::IV,
        Sector::V,
        Sector::VI,
    ];

    /// Sector number 1..=6.
    pub const fn number(self) -> u8 {
        match self {
            Sector::I => 1,
            Sector::II => 2,
            Sector::III => 3,
            Sector::IV => 4,
            Sector::V => 5,
            Sector::VI => 6,
        }
    }

    /// Start angle of the sector in our frame \[deg\] (it spans 60 deg).
    pub const fn start_degrees(self) -> u16 {
        (self.number() as u16 - 1) * 60
    }

    /// `(first, second)` active vector numbers of the source's table (design
    /// §8): the first has one phase high, the second two.
    pub const fn vectors(self) -> (u8, u8) {
        match self {
            Sector::I => (4, 6),
            Sector::II => (2, 6),
            Sector::III => (2, 3),
            Sector::IV => (1, 3),
            Sector::V => (1, 5),
            Sector::VI => (4, 5),
        }
    }

    /// The seven-segment sequence of vector numbers over one period, e.g.
    /// `0-4-6-7-7-6-4-0` in sector I (design §8; the two middle 7s
    /// are the one `T7` segment split at the period centre).
    pub const fn sequence(self) -> [u8; 8] {
        let (a, b) = self.vectors();
        [0, a, b, 7, 7, b, a, 0]
    }

    /// Indices (0 = A, 1 = B, 2 = C) of the phases with the longest, middle
    /// and shortest on-time in this sector.
    pub const fn phase_order(self) -> [usize; 3] {
        match self {
            Sector::I => [0, 1, 2],
            Sector::II => [1, 0, 2],
            Sector::III => [1, 2, 0],
            Sector::IV => [2, 1, 0],
            Sector::V => [2, 0, 1],
            Sector::VI => [0, 2, 1],
        }
    }

    /// Sector of a reference vector from the signs of the source's
    /// `U1, U2, U3` (see the module docs). The zero vector is in sector I.
    /// Non-finite input gives an unspecified but defined sector.
    #[inline]
    pub fn of(v_ab: AlphaBeta) -> Sector {
        let [u1, u2, u3] = projections(v_ab);
        Sector::from_signs(u1 >= 0.0, u2 >= 0.0, u3 >= 0.0)
    }

    #[inline(always)]
    const fn from_signs(s1: bool, s2: bool, s3: bool) -> Sector {
        match (s1, s2, s3) {
            (true, true, _) => Sector::I,
            (true, false, false) => Sector::II,
            (true, false, true) => Sector::III,
            (false, false, _) => Sector::IV,
            (false, true, true) => Sector::V,
            (false, true, false) => Sector::VI,
        }
    }
}

/// The source's `[U1, U2, U3]` for a reference vector in our frame (design
/// §8): `U1 = beta`, `U2 = (sqrt3/2) alpha - beta/2`,
/// `U3 = -(sqrt3/2) alpha - beta/2`, the last computed as `-(U1 + U2)`.
#[inline(always)]
pub fn projections(v_ab: AlphaBeta) -> [f32; 3] {
    let u1 = v_ab.beta;
    let u2 = SQRT_3_2 * v_ab.alpha - 0.5 * v_ab.beta;
    [u1, u2, -(u1 + u2)]
}

/// Alpha/beta position of switching state `n` (0..=7, bits A B C) on a bus
/// of `v_bus_v` \[V\]: length `2 Udc / 3` for the six active vectors, zero for
/// U0 and U7 (design §8). Bits above the lowest three are ignored.
pub fn space_vector(n: u8, v_bus_v: f32) -> AlphaBeta {
    let pole = |bit: u8| if n & bit != 0 { v_bus_v } else { 0.0 };
    crate::transforms::clarke(crate::frames::Abc::new(pole(4), pole(2), pole(1)))
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
    /// `m = sqrt(3) |U_ref| / Udc` of the request (1.0 on the inscribed
    /// circle, `2/sqrt(3) = 1.155` at the hexagon corners; may be `inf` for
    /// an overflowing request). Reported before any scaling.
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

    /// Durations of the eight segments of [`Sector::sequence`] as fractions
    /// of the period: `[t0/2, t1/2, t2/2, t7/2, t7/2, t2/2, t1/2, t0/2]`.
    pub fn segment_times(&self) -> [f32; 8] {
        let (z, a, b) = (0.5 * self.t_zero, 0.5 * self.t_first, 0.5 * self.t_second);
        [z, a, b, z, z, b, a, z]
    }

    /// Centre-aligned compare values of [`Self::duties`] (see [`compare_values`]).
    #[inline]
    pub fn compare_values(&self, period_counts: u16) -> [u16; 3] {
        compare_values(self.duties, period_counts)
    }
}

/// Largest phase-voltage amplitude reachable without distortion
/// (inscribed circle of the hexagon): `Udc / sqrt(3)`.
#[inline]
pub fn max_linear_voltage_v(v_bus_v: f32) -> f32 {
    v_bus_v * crate::FRAC_1_SQRT_3
}

/// Modulate `v_ab` \[V\] (our frame) on a bus of `v_bus_v` \[V\] with the
/// seven-segment sector method of design §8 (see the module docs).
///
/// Never panics; every duty is in `[0, 1]` for any input.
#[inline]
pub fn svpwm(v_ab: AlphaBeta, v_bus_v: f32) -> SvpwmOutput {
    svpwm_inline(v_ab, v_bus_v)
}

/// [`svpwm`], always inlined: the current loop's copy, so that the call, the
/// register saves and the copy of the returned struct disappear there.
#[inline(always)]
pub(crate) fn svpwm_inline(v_ab: AlphaBeta, v_bus_v: f32) -> SvpwmOutput {
    if !crate::all_finite([v_ab.alpha, v_ab.beta]) || !bus_usable(v_bus_v) {
        return SvpwmOutput::NEUTRAL_INVALID;
    }
    let [u1, u2, u3] = projections(v_ab);
    let sector = Sector::from_signs(u1 >= 0.0, u2 >= 0.0, u3 >= 0.0);
    // Design §8 table without K; both are >= 0 by the sign choice.
    let (raw_first, raw_second) = raw_times(sector, u1, u2, u3);
    let k = SQRT_3 / v_bus_v; // K / Ts
    let mut t_first = k * raw_first;
    let mut t_second = k * raw_second;
    let sum = t_first + t_second;
    let mut saturated = false;
    let t_zero;
    // m = sqrt(3) |U| / Udc, with the division by Udc already done in `k`.
    let mut modulation_index = k * v_ab.magnitude();
    if sum <= 1.0 {
        t_zero = (1.0 - sum) * 0.5;
    } else if sum <= f32::MAX {
        // Overmodulation: back onto the hexagon edge, angle preserved.
        saturated = true;
        t_second /= sum; // <= 1 exactly, since t_second <= sum
        t_first = 1.0 - t_second;
        t_zero = 0.0;
    } else {
        // inf or NaN (overflowing request, or a subnormal bus making K
        // infinite): modulate the direction alone.
        // `k` may be infinite here (0 * inf = NaN): recompute m directly.
        modulation_index = SQRT_3 * v_ab.magnitude() / v_bus_v;
        let (sat, t1, t2) = direction_only(v_ab);
        saturated = sat;
        t_first = t1;
        t_second = t2;
        t_zero = (1.0 - (t1 + t2)) * 0.5;
    }
    let duties = duties_of(sector, t_zero, t_second);
    SvpwmOutput {
        duties,
        sector,
        t_first,
        t_second,
        t_zero,
        modulation_index,
        saturated,
        invalid: false,
    }
}

/// Finite and positive (false for NaN).
#[inline(always)]
fn bus_usable(v_bus_v: f32) -> bool {
    v_bus_v > 0.0 && v_bus_v <= f32::MAX
}

/// Per-sector active times of the source's table divided by `K`.
#[inline(always)]
fn raw_times(sector: Sector, u1: f32, u2: f32, u3: f32) -> (f32, f32) {
    match sector {
        Sector::I => (u2, u1),
        Sector::II => (-u2, -u3),
        Sector::III => (u1, u3),
        Sector::IV => (-u1, -u2),
        Sector::V => (u3, u2),
        Sector::VI => (-u3, -u1),
    }
}

/// Duties from the zero-vector time and the second vector's time:
/// `d_max = 1 - t0`, `d_mid = t0 + t_second`, `d_min = t0`.
#[inline(always)]
fn duties_of(sector: Sector, t_zero: f32, t_second: f32) -> [f32; 3] {
    let hi = 1.0 - t_zero;
    let mid = t_zero + t_second;
    let lo = t_zero;
    match sector {
        Sector::I => [hi, mid, lo],
        Sector::II => [mid, hi, lo],
        Sector::III => [lo, hi, mid],
        Sector::IV => [lo, mid, hi],
        Sector::V => [mid, lo, hi],
        Sector::VI => [hi, lo, mid],
    }
}

/// Hexagon-edge times for a request whose scaled times overflowed: the
/// input is pre-scaled by 1/4 (exact) so the projections cannot overflow.
/// Returns `(saturated, t_first, t_second)`.
#[cold]
#[inline(never)]
fn direction_only(v_ab: AlphaBeta) -> (bool, f32, f32) {
    let [u1, u2, u3] = projections(AlphaBeta::new(0.25 * v_ab.alpha, 0.25 * v_ab.beta));
    let sector = Sector::from_signs(u1 >= 0.0, u2 >= 0.0, u3 >= 0.0);
    let (a, b) = raw_times(sector, u1, u2, u3);
    let s = a + b;
    if s > 0.0 && s <= f32::MAX {
        let t2 = b / s;
        (true, 1.0 - t2, t2)
    } else {
        (false, 0.0, 0.0)
    }
}

/// Min-max zero-sequence injection: an independent check of [`svpwm`]
/// (design §8: the sector method's "saddle" duties equal the phase
/// voltages shifted by `-(max + min)/2`).
///
/// Inside the hexagon it gives the same duties as [`svpwm`] (tested).
/// Outside it does **not** preserve the angle: each duty is clipped to
/// `[0, 1]` on its own. Unusable input gives centred duties; NaN from an
/// overflowing request gives 0 for that phase. Never panics.
pub fn minmax(v_ab: AlphaBeta, v_bus_v: f32) -> [f32; 3] {
    if !v_ab.is_finite() || !bus_usable(v_bus_v) {
        return [0.5; 3];
    }
    let v = crate::transforms::inverse_clarke(v_ab);
    let (a, b, c) = (v.a, v.b, v.c);
    let (hi_ab, lo_ab) = if a > b { (a, b) } else { (b, a) };
    let max = if c > hi_ab { c } else { hi_ab };
    let min = if c < lo_ab { c } else { lo_ab };
    let off = -(max + min) * 0.5;
    let k = 1.0 / v_bus_v;
    let d = |x: f32| {
        let d = 0.5 + (x + off) * k;
        // NaN fails `d >= 0` and goes to 0.
        if d >= 0.0 {
            clamp(d, 0.0, 1.0)
        } else {
            0.0
        }
    };
    [d(a), d(b), d(c)]
}

/// Centre-aligned compare values for a timer period of `period_counts` = N
/// (high side on while the counter is below the compare value).
///
/// A centre-aligned timer counts `0 -> N -> 0` over one PWM period of `2N`
/// counts. Measure time `t` (in counts) from the counter's top: the counter
/// is `N - t` for `t` in `[0, N]` and `t - N` for `t` in `[N, 2N]`, so
/// `counter < cmp` holds exactly for `t` in `(N - cmp, N + cmp)`: one
/// on-interval of length `2 cmp` centred on the period centre `t = N` (the
/// counter's valley), and the duty is `2 cmp / 2N = cmp / N`. Hence
/// `cmp = round(d N)`, within `[0, N]`, with a duty error of at most
/// `1/(2N)`. All three phases are centred on the same instant, which is what
/// the seven-segment sequence `0-a-b-7-7-b-a-0` needs: U7 (all high) in the
/// middle, U0 (all low, where low-side shunts can be sampled) at the
/// counter's top. Non-finite duties give `N/2`; duties outside `[0, 1]` are
/// clamped.
#[inline]
pub fn compare_values(duties: [f32; 3], period_counts: u16) -> [u16; 3] {
    let p = period_counts as f32;
    let cv = |d: f32| -> u16 {
        // The usual case, a duty in [0, 1], costs one comparison, of
        // `|d - 0.5|` with 0.5 (NaN fails it and goes to the out-of-line
        // path with the rest). `d - 0.5` is exact for d in [0.25, 2], and
        // rounds to no less than -0.5 for d in [0, 0.25), so exactly the
        // duties in [0, 1] pass, plus negative ones so small
        // (`|d| <= 2^-25`) that `d - 0.5` rounds to -0.5: for those
        // `d N + 0.5` lies in (0.49, 0.5] (N <= 65535) and truncates to 0,
        // the value of the clamped duty 0, so the result is the same.
        let d = if (d - 0.5).abs() <= 0.5 {
            d
        } else {
            duty_out_of_range(d)
        };
        // 0 <= d <= 1 and N <= 65535 (exact in f32), so d * N <= N and
        // d * N + 0.5 <= 65535.5: the truncation gives at most N and the
        // u32 -> u16 step never cuts (the u32 cast is one `vcvt`).
        (d * p + 0.5) as u32 as u16
    };
    let [a, b, c] = duties;
    [cv(a), cv(b), cv(c)]
}

/// [`compare_values`] for a duty outside `[0, 1]`: clamped when finite,
/// centred (0.5) when infinite or NaN.
#[cold]
#[inline(never)]
fn duty_out_of_range(d: f32) -> f32 {
    if d.is_finite() {
        clamp(d, 0.0, 1.0)
    } else {
        0.5
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The one-comparison range test of [`compare_values`] gives the same
    /// compare values as clamping first, around 0, 0.5 and 1 (ulp by ulp),
    /// for tiny negative duties and for non-finite ones, at several periods.
    #[test]
    fn compare_values_match_clamped_reference() {
        let reference = |d: f32, n: u16| -> u16 {
            let d = if d.is_finite() {
                clamp(d, 0.0, 1.0)
            } else {
                0.5
            };
            (d * n as f32 + 0.5) as u32 as u16
        };
        let mut ds = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            -f32::MAX,
        ]
        .to_vec();
        for c in [
            0.0f32,
            -0.0,
            0.5,
            1.0,
            0.25,
            2.0,
            2.0f32.powi(-25),
            -(2.0f32.powi(-25)),
        ] {
            for k in 0..2000u32 {
                ds.push(f32::from_bits(c.to_bits().wrapping_add(k)));
                ds.push(f32::from_bits(c.to_bits().wrapping_sub(k)));
            }
        }
        for n in [1u16, 4200, 65535] {
            for &d in &ds {
                assert_eq!(compare_values([d; 3], n), [reference(d, n); 3], "{d:e} {n}");
            }
        }
    }

    fn at_deg(mag: f32, deg: f64) -> AlphaBeta {
        let r = deg.to_radians();
        AlphaBeta::new(mag * r.cos() as f32, mag * r.sin() as f32)
    }

    #[test]
    fn sector_from_angle() {
        for (i, s) in Sector::ALL.iter().enumerate() {
            for off in [1.0, 30.0, 59.0] {
                let deg = i as f64 * 60.0 + off;
                assert_eq!(Sector::of(at_deg(1.0, deg)), *s, "{deg}");
                assert_eq!(svpwm(at_deg(5.0, deg), 24.0).sector, *s, "{deg}");
            }
        }
    }

    #[test]
    fn sequence_has_one_switch_per_transition() {
        for s in Sector::ALL {
            let seq = s.sequence();
            for w in seq.windows(2) {
                assert!((w[0] ^ w[1]).count_ones() <= 1, "{s:?} {seq:?}");
            }
            let (a, b) = s.vectors();
            assert_eq!(a.count_ones(), 1);
            assert_eq!(b.count_ones(), 2);
        }
    }

    #[test]
    fn sector_vectors_bound_the_sector() {
        // Design §8: U4 at 0, U6 at 60, U2 at 120, U3 at 180, U1 at
        // 240, U5 at 300 deg, each 2 Udc / 3 long; a sector's two vectors
        // sit at its two ends.
        let near = |v: AlphaBeta, deg: f32| {
            let d = libm::atan2f(v.beta, v.alpha).to_degrees() - deg;
            let d = d - 360.0 * libm::roundf(d / 360.0);
            d.abs() < 1e-3
        };
        for (n, deg) in [
            (4u8, 0.0f32),
            (6, 60.0),
            (2, 120.0),
            (3, 180.0),
            (1, 240.0),
            (5, 300.0),
        ] {
            let v = space_vector(n, 1.0);
            assert!(near(v, deg), "U{n}");
            assert!((v.magnitude() - 2.0 / 3.0).abs() < 1e-6, "U{n}");
        }
        assert_eq!(space_vector(0, 1.0).magnitude(), 0.0);
        assert!(space_vector(7, 1.0).magnitude() < 1e-6);
        for s in Sector::ALL {
            let (a, b) = s.vectors();
            let start = s.start_degrees() as f32;
            let (va, vb) = (space_vector(a, 1.0), space_vector(b, 1.0));
            assert!(
                (near(va, start) && near(vb, start + 60.0))
                    || (near(vb, start) && near(va, start + 60.0)),
                "{s:?}"
            );
        }
    }

    #[test]
    fn invalid_inputs_are_centred() {
        for (v, bus) in [
            (AlphaBeta::new(f32::NAN, 0.0), 24.0),
            (AlphaBeta::new(1.0, f32::INFINITY), 24.0),
            (AlphaBeta::new(1.0, 1.0), 0.0),
            (AlphaBeta::new(1.0, 1.0), -5.0),
            (AlphaBeta::new(1.0, 1.0), f32::NAN),
            (AlphaBeta::new(1.0, 1.0), f32::INFINITY),
        ] {
            let o = svpwm(v, bus);
            assert!(o.invalid);
            assert_eq!(o.duties, [0.5; 3]);
            assert_eq!(minmax(v, bus), [0.5; 3]);
        }
    }

    #[test]
    fn zero_vector_is_centred_and_valid() {
        let o = svpwm(AlphaBeta::new(0.0, 0.0), 24.0);
        assert!(!o.invalid && !o.saturated);
        assert_eq!(o.duties, [0.5; 3]);
        assert_eq!(o.t_zero, 0.5);
        assert_eq!(o.modulation_index, 0.0);
    }

    #[test]
    fn compare_values_round_and_stay_in_range() {
        assert_eq!(compare_values([0.0, 0.5, 1.0], 4200), [0, 2100, 4200]);
        assert_eq!(compare_values([-1.0, 2.0, f32::NAN], 1000), [0, 1000, 500]);
        assert_eq!(compare_values([1.0; 3], u16::MAX), [u16::MAX; 3]);
        assert_eq!(
            compare_values([f32::INFINITY, f32::NEG_INFINITY, -f32::NAN], 1000),
            [500, 500, 500]
        );
        assert_eq!(
            compare_values([f32::MAX, -f32::MAX, -0.0], 1000),
            [1000, 0, 0]
        );
        // Same as the plain formula over a sweep of duties and periods.
        for n in [0u16, 1, 999, 4200, 65_534, u16::MAX] {
            for k in -100..=1100 {
                let d = k as f32 * 1e-3;
                let want = (d.clamp(0.0, 1.0) * n as f32 + 0.5) as u16;
                assert_eq!(compare_values([d; 3], n), [want; 3], "{d} {n}");
            }
        }
    }
}
