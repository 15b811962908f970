//! Property tests of the seven-segment SVPWM (design §8).
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::frames::{Abc, AlphaBeta};
use foc_core::svpwm::{compare_values, minmax, space_vector, svpwm, Sector, SvpwmOutput};
use foc_core::transforms;
use foc_core::SQRT_3;
use proptest::prelude::*;

/// Largest minus smallest phase voltage of a request: the request is inside
/// the hexagon exactly when this is <= Udc.
fn spread(v: AlphaBeta) -> f32 {
    let p = transforms::inverse_clarke(v);
    let m = p.a.max(p.b).max(p.c);
    let n = p.a.min(p.b).min(p.c);
    m - n
}

fn from_polar(mag: f32, rad: f64) -> AlphaBeta {
    AlphaBeta::new(mag * rad.cos() as f32, mag * rad.sin() as f32)
}

/// A request at `rad` scaled to `frac` of the hexagon boundary in that direction.
fn hexagon_fraction(rad: f64, frac: f32, v_bus: f32) -> AlphaBeta {
    let unit = from_polar(1.0, rad);
    let s = spread(unit);
    from_polar(frac * v_bus / s, rad)
}

/// The average voltage vector the duties produce (Clarke of the pole
/// voltages; the common mode drops out).
fn produced(out: &SvpwmOutput, v_bus: f32) -> AlphaBeta {
    let [a, b, c] = out.duties;
    transforms::clarke(Abc::new(a * v_bus, b * v_bus, c * v_bus))
}

/// Duties integrated from the segment sequence and segment times, using the
/// switch states of the vector numbers (bit 2 = A, bit 1 = B, bit 0 = C).
fn duties_from_sequence(out: &SvpwmOutput) -> [f32; 3] {
    let seq = out.sector.sequence();
    let times = out.segment_times();
    let mut d = [0.0f32; 3];
    for (n, t) in seq.iter().zip(times.iter()) {
        for (ph, bit) in [4u8, 2, 1].iter().enumerate() {
            if n & bit != 0 {
                d[ph] += t;
            }
        }
    }
    d
}

fn any_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        proptest::num::f32::ANY,
        -1e3f32..1e3,
        Just(0.0f32),
        Just(-0.0f32),
        Just(f32::MAX),
        Just(f32::MIN),
        Just(f32::MIN_POSITIVE),
        Just(1e-45f32),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Inside the hexagon: average line-to-line voltages equal the requested
    /// ones, the sector method equals min-max injection (the "saddle"), the
    /// segment bookkeeping is consistent, nothing is flagged.
    #[test]
    fn inside_hexagon(rad in -7.0f64..7.0, frac in 0.0f32..0.999, v_bus in 1.0f32..600.0) {
        let v = hexagon_fraction(rad, frac, v_bus);
        let out = svpwm(v, v_bus);
        prop_assert!(!out.saturated && !out.invalid, "{out:?}");
        let want = transforms::inverse_clarke(v);
        let [a, b, c] = out.duties;
        let tol = 2e-6 * v_bus;
        prop_assert!(((a - b) * v_bus - (want.a - want.b)).abs() < tol * 4.0, "{out:?}");
        prop_assert!(((b - c) * v_bus - (want.b - want.c)).abs() < tol * 4.0, "{out:?}");
        prop_assert!(((c - a) * v_bus - (want.c - want.a)).abs() < tol * 4.0, "{out:?}");
        let mm = minmax(v, v_bus);
        for (d, m) in out.duties.iter().zip(mm) {
            prop_assert!((d - m).abs() < 2e-6, "{out:?} vs {mm:?}");
        }
        let total = out.t_first + out.t_second + 2.0 * out.t_zero;
        prop_assert!((total - 1.0).abs() < 1e-6);
        prop_assert!(out.t_first >= 0.0 && out.t_second >= 0.0 && out.t_zero >= 0.0);
        let seq = duties_from_sequence(&out);
        for (s, d) in seq.iter().zip(out.duties) {
            prop_assert!((s - d).abs() < 1e-6, "{seq:?} vs {out:?}");
        }
        let m = SQRT_3 * v.magnitude() / v_bus;
        prop_assert!((out.modulation_index - m).abs() <= 1e-5 * (1.0 + m));
        prop_assert!(out.modulation_index <= 2.0 / SQRT_3 + 1e-5);
        // The phase order of the sector holds.
        let [hi, mid, lo] = out.sector.phase_order();
        prop_assert!(out.duties[hi] >= out.duties[mid] && out.duties[mid] >= out.duties[lo]);
        // Active times follow the law of sines of design §8:
        // T_first = m sin(60 - phi), T_second = m sin(phi) within the sector,
        // with phi measured from the sector's first-vector edge.
        let (first, _) = out.sector.vectors();
        let edge = space_vector(first, 1.0);
        let edge_rad = (edge.beta as f64).atan2(edge.alpha as f64);
        let mut phi = (v.beta as f64).atan2(v.alpha as f64) - edge_rad;
        phi = phi.rem_euclid(std::f64::consts::TAU);
        if phi > std::f64::consts::PI { phi = std::f64::consts::TAU - phi; }
        let m64 = m as f64;
        let t_a = m64 * (std::f64::consts::FRAC_PI_3 - phi).sin();
        let t_b = m64 * phi.sin();
        prop_assert!((out.t_first as f64 - t_a).abs() < 1e-5, "{out:?} phi {phi}");
        prop_assert!((out.t_second as f64 - t_b).abs() < 1e-5, "{out:?} phi {phi}");
    }

    /// The sector is the one whose 60 degree span contains the angle.
    #[test]
    fn sector_matches_angle(deg in 0.0f64..360.0, mag in 1e-3f32..100.0) {
        let within = deg % 60.0;
        prop_assume!(within > 1e-4 && within < 60.0 - 1e-4);
        let out = svpwm(from_polar(mag, deg.to_radians()), 300.0);
        prop_assert_eq!(out.sector.start_degrees() as f64, (deg / 60.0).floor() * 60.0);
    }

    /// Every duty is in [0, 1] and finite for ANY input, compare values are
    /// within [0, N], and unusable input is flagged and centred.
    #[test]
    fn duties_always_in_range(al in any_f32(), be in any_f32(), bus in any_f32(), n in any::<u16>()) {
        let v = AlphaBeta::new(al, be);
        let out = svpwm(v, bus);
        for d in out.duties {
            prop_assert!(d.is_finite() && (0.0..=1.0).contains(&d), "{v:?} {bus} -> {out:?}");
        }
        for t in [out.t_first, out.t_second, out.t_zero] {
            prop_assert!(t.is_finite() && (0.0..=1.0).contains(&t), "{v:?} {bus} -> {out:?}");
        }
        prop_assert!(!out.modulation_index.is_nan());
        let usable = v.is_finite() && bus.is_finite() && bus > 0.0;
        prop_assert_eq!(out.invalid, !usable);
        if !usable {
            prop_assert_eq!(out.duties, [0.5; 3]);
        }
        for d in minmax(v, bus) {
            prop_assert!((0.0..=1.0).contains(&d));
        }
        for c in out.compare_values(n) {
            prop_assert!(c <= n);
        }
    }

    /// Overmodulation: scaled back onto the hexagon edge with the angle
    /// preserved, flagged saturated.
    #[test]
    fn overmodulation_preserves_angle(rad in -7.0f64..7.0, over in 1.001f32..1e6, v_bus in 1.0f32..600.0) {
        let v = hexagon_fraction(rad, over, v_bus);
        let out = svpwm(v, v_bus);
        prop_assert!(out.saturated && !out.invalid, "{out:?}");
        prop_assert!(out.t_zero == 0.0);
        prop_assert!((out.t_first + out.t_second - 1.0).abs() < 1e-6);
        let p = produced(&out, v_bus);
        let want = (v.beta as f64).atan2(v.alpha as f64);
        let got = (p.beta as f64).atan2(p.alpha as f64);
        let mut d = (got - want).rem_euclid(std::f64::consts::TAU);
        if d > std::f64::consts::PI { d -= std::f64::consts::TAU; }
        prop_assert!(d.abs() < 2e-5, "angle error {d}");
        // On the hexagon boundary: max - min duty is 1.
        let mx = out.duties.iter().cloned().fold(f32::MIN, f32::max);
        let mn = out.duties.iter().cloned().fold(f32::MAX, f32::min);
        prop_assert!((mx - mn - 1.0).abs() < 1e-6);
        prop_assert!(out.modulation_index > 1.0);
    }

    /// Huge (overflowing) requests and tiny buses take the direction-only
    /// path and still preserve the angle.
    #[test]
    fn overflowing_requests_preserve_angle(rad in -7.0f64..7.0, mag in 1e37f32..3e38, bus in prop_oneof![Just(1e-45f32), 1e-30f32..1.0]) {
        let v = from_polar(mag, rad);
        prop_assume!(v.is_finite());
        let out = svpwm(v, bus);
        prop_assert!(out.saturated && !out.invalid);
        let p = produced(&out, 1.0);
        let want = (v.beta as f64).atan2(v.alpha as f64);
        let got = (p.beta as f64).atan2(p.alpha as f64);
        let mut d = (got - want).rem_euclid(std::f64::consts::TAU);
        if d > std::f64::consts::PI { d -= std::f64::consts::TAU; }
        prop_assert!(d.abs() < 2e-5, "angle error {d}");
    }

    /// Near every sector boundary (within a few ulps of the angle) the duties
    /// are continuous and equal min-max.
    #[test]
    fn near_boundaries(k in 0u32..=6, delta in -1e-6f64..1e-6, frac in 0.01f32..0.999) {
        let rad = (k as f64 * 60.0).to_radians() + delta;
        let v = hexagon_fraction(rad, frac, 48.0);
        let out = svpwm(v, 48.0);
        prop_assert!(!out.invalid && !out.saturated);
        let mm = minmax(v, 48.0);
        for (d, m) in out.duties.iter().zip(mm) {
            prop_assert!((d - m).abs() < 2e-6, "{out:?} vs {mm:?}");
        }
    }

    /// Centre-aligned compare values (see `compare_values`): simulate the
    /// triangle counter 0 -> N -> 0 sampled at half-count instants, with the
    /// high side on while counter < compare. The on-interval is one block
    /// centred on the period centre and its length matches the duty to
    /// within one count.
    #[test]
    fn compare_values_are_centred(duty in 0.0f32..=1.0, n in 1u16..3000) {
        let [cmp, _, _] = compare_values([duty, 0.5, 0.5], n);
        prop_assert!(cmp <= n);
        let nn = n as f64;
        let mut first = None;
        let mut last = None;
        let mut count = 0u32;
        for i in 0..(2 * n as u32) {
            let t = i as f64 + 0.5; // time from the counter's top, in counts
            let counter = (nn - t).abs();
            if counter < cmp as f64 {
                first.get_or_insert(t);
                last = Some(t);
                count += 1;
            }
        }
        prop_assert_eq!(count, 2 * cmp as u32);
        if let (Some(f), Some(l)) = (first, last) {
            prop_assert_eq!(l - f + 1.0, count as f64, "one contiguous block");
            prop_assert!(((f + l) / 2.0 - nn).abs() < 1e-9, "centred on N");
            prop_assert!(f - 0.5 >= 0.0 && l + 0.5 <= 2.0 * nn);
        }
        let realised = count as f64 / (2.0 * nn);
        prop_assert!((realised - duty as f64).abs() <= 0.5 / nn + 1e-6);
    }
}

/// Exactly on the boundaries 0, 60, ..., 360 degrees (built from the space
/// vectors themselves, and with +-0.0 beta on the alpha axis): a defined
/// sector, one active time zero, correct line-to-line voltages, and the
/// same duties as min-max.
#[test]
fn exact_sector_boundaries() {
    let v_bus = 24.0f32;
    let mut cases: Vec<AlphaBeta> = Vec::new();
    for n in 1..=6u8 {
        let e = space_vector(n, 1.0);
        for frac in [1e-6f32, 0.25, 0.5, 0.9, 0.999] {
            // Space vectors are 2/3 Udc long, i.e. at the hexagon's corners.
            cases.push(AlphaBeta::new(
                e.alpha * frac * v_bus,
                e.beta * frac * v_bus,
            ));
        }
    }
    for x in [1.0f32, 10.0, 15.99] {
        for b in [0.0f32, -0.0] {
            cases.push(AlphaBeta::new(x, b));
            cases.push(AlphaBeta::new(-x, b));
        }
    }
    for v in cases {
        let out = svpwm(v, v_bus);
        assert!(!out.invalid && !out.saturated, "{v:?} {out:?}");
        assert!(
            out.t_first.abs() < 1e-6 || out.t_second.abs() < 1e-6,
            "one time is zero on a boundary: {v:?} {out:?}"
        );
        let want = transforms::inverse_clarke(v);
        let [a, b, c] = out.duties;
        assert!(
            ((a - b) * v_bus - (want.a - want.b)).abs() < 1e-4,
            "{v:?} {out:?}"
        );
        assert!(
            ((b - c) * v_bus - (want.b - want.c)).abs() < 1e-4,
            "{v:?} {out:?}"
        );
        let mm = minmax(v, v_bus);
        for (d, m) in out.duties.iter().zip(mm) {
            assert!((d - m).abs() < 2e-6, "{v:?} {out:?} {mm:?}");
        }
    }
    // 0 and 360 degrees are the same vector and land in sector I.
    assert_eq!(svpwm(AlphaBeta::new(5.0, 0.0), v_bus).sector, Sector::I);
    assert_eq!(svpwm(AlphaBeta::new(5.0, -0.0), v_bus).sector, Sector::I);
}

/// At the hexagon corners the request is exactly one active vector for the
/// whole period (m = 2/sqrt3): duties are 0/1 per the vector's bits.
#[test]
fn corners_apply_one_vector() {
    let v_bus = 10.0;
    for n in 1..=6u8 {
        let e = space_vector(n, v_bus);
        let out = svpwm(e, v_bus);
        assert!(!out.invalid);
        for (ph, bit) in [4u8, 2, 1].iter().enumerate() {
            let want = if n & bit != 0 { 1.0 } else { 0.0 };
            assert!((out.duties[ph] - want).abs() < 1e-5, "U{n}: {out:?}");
        }
        assert!((out.modulation_index - 2.0 / SQRT_3).abs() < 1e-5);
    }
}

/// The duty waveform over one electrical turn is the "saddle": equal to the
/// sine plus a triangular common-mode term, and its peak on the inscribed
/// circle (m = 1) is exactly 1.
#[test]
fn saddle_shape() {
    let v_bus = 1.0;
    let amp = v_bus / SQRT_3; // m = 1
    let mut peak = 0.0f32;
    let mut trough = 1.0f32;
    for i in 0..3600 {
        let rad = (i as f64 / 10.0).to_radians();
        let out = svpwm(from_polar(amp, rad), v_bus);
        let a = out.duties[0];
        peak = peak.max(a);
        trough = trough.min(a);
        // Common mode = mean duty - 0.5 is a triangle of amplitude amp/4 at 3x.
        let cm = (out.duties.iter().sum::<f32>() / 3.0 - 0.5) / v_bus;
        assert!(cm.abs() <= amp / 4.0 + 1e-5, "{i}: {cm}");
        assert!(!out.saturated);
    }
    assert!(
        (peak - 1.0).abs() < 1e-5 && trough.abs() < 1e-5,
        "{peak} {trough}"
    );
}
