//! Property tests of `control::power` (design §18, issue 17): the q-current
//! window keeps the steady-state bus power and bus current within every
//! configured limit at its ends and inside, always contains 0, shrinks
//! monotonically with the bus voltage (regen ramp) and the temperatures
//! (derating), answers `[0, 0]` to every missing or non-finite input, and a
//! sanitized configuration never turns a NaN into "unlimited"; the winding
//! model converges to `ambient + R_th P` with its time constant; the brake
//! chopper's hysteresis.
//!
//! The power at a q-current is recomputed here independently from the dq
//! voltages (`P = 1.5 (v_d i_d + v_q i_q)`, `v_d = R i_d - w_e L_q i_q`,
//! `v_q = R i_q + w_e (L_d i_d + psi)`) in f64. Tolerance: the window's roots
//! are f32, so a limit holds within `1e-4` of the largest term of the power
//! balance plus 1 mW.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::control::power::{
    iq_window, ActiveLimit, BrakeChopper, IqWindow, PowerInputs, PowerLimitsConfig,
    ThermalEstimate, COPPER_TEMPCO_PER_K, THERMAL_MAX_C,
};
use foc_core::control::supervisor::SupervisorConfig;
use foc_core::control::MotorParams;
use foc_core::frames::Dq;
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

type Check = Result<(), TestCaseError>;

const INF: f32 = f32::INFINITY;

fn motor() -> impl Strategy<Value = MotorParams> {
    (
        1u8..20,
        0.01f32..2.0,
        1e-5f32..5e-3,
        1e-5f32..5e-3,
        1e-3f32..0.1,
    )
        .prop_map(
            |(pole_pairs, r_ohm, ld_h, lq_h, flux_linkage_wb)| MotorParams {
                pole_pairs,
                r_ohm,
                ld_h,
                lq_h,
                flux_linkage_wb,
            },
        )
}

/// A limit: off one time in four, else in `[lo, hi)` (0 sometimes).
fn limit(lo: f32, hi: f32) -> BoxedStrategy<f32> {
    prop_oneof![1 => Just(INF), 1 => Just(0.0f32), 4 => lo..hi].boxed()
}

/// A configuration with the regen and thermal windows off unless set.
fn limits_config() -> impl Strategy<Value = PowerLimitsConfig> {
    (
        motor(),
        limit(0.1, 50.0),
        limit(0.1, 50.0),
        limit(1.0, 2000.0),
        limit(1.0, 2000.0),
    )
        .prop_map(|(m, i_mot, i_regen, p_mot, p_regen)| {
            let mut c = base(m);
            c.bus_current_motoring_max_a = i_mot;
            c.bus_current_regen_max_a = i_regen;
            c.power_motoring_max_w = p_mot;
            c.power_regen_max_w = p_regen;
            c
        })
}

/// Every limit off.
fn base(m: MotorParams) -> PowerLimitsConfig {
    let mut c = PowerLimitsConfig::for_board(&SupervisorConfig::default(), m, false);
    c.regen_start_v = INF;
    c.regen_end_v = INF;
    c.winding_derate_start_c = INF;
    c.winding_derate_end_c = INF;
    c
}

fn inputs() -> impl Strategy<Value = PowerInputs> {
    (
        1.0f32..80.0,
        prop_oneof![1 => Just(0.0f32), 6 => -8000.0f32..8000.0],
        prop_oneof![2 => Just(0.0f32), 1 => -10.0f32..10.0],
        prop_oneof![1 => Just(0.0f32), 8 => 0.1f32..60.0],
        -20.0f32..200.0,
    )
        .prop_map(|(v, w, id, i_lim, t)| PowerInputs {
            v_bus_v: Some(v),
            omega_e_rad_s: w,
            i_d_a: id,
            iq_request_a: 0.0,
            current_limit_a: i_lim,
            winding_temperature_c: Some(t),
            stage_temperature_c: None,
        })
}

/// Independent steady-state power \[W\] and the size of its largest term.
fn power(c: &PowerLimitsConfig, inp: &PowerInputs, iq: f32) -> (f64, f64) {
    let m = &c.motor;
    let t = inp.winding_temperature_c.unwrap() as f64;
    let r = m.r_ohm as f64 * (1.0 + COPPER_TEMPCO_PER_K as f64 * (t - 20.0));
    let (w, id, iq) = (inp.omega_e_rad_s as f64, inp.i_d_a as f64, iq as f64);
    let vd = r * id - w * m.lq_h as f64 * iq;
    let vq = r * iq + w * (m.ld_h as f64 * id + m.flux_linkage_wb as f64);
    let p = 1.5 * (vd * id + vq * iq);
    let scale = 1.5 * (r * (id * id + iq * iq) + (w * m.flux_linkage_wb as f64 * iq).abs())
        + 1.5 * (w * (m.ld_h - m.lq_h) as f64 * id * iq).abs();
    (p, scale)
}

/// `lo + (hi - lo) t` in f64 (f32 cancels: `-59.7 + 59.7` is off by an
/// ulp of 59.7, which at a large back-EMF is a visible power), back to
/// f32; exact at `t = 0` and `t = 1`.
fn lerp(lo: f32, hi: f32, t: f64) -> f32 {
    (lo as f64 + (hi as f64 - lo as f64) * t) as f32
}

fn tol(scale: f64) -> f64 {
    1e-4 * scale + 1e-3
}

/// The power limits `(P_mot, P_regen)` \[W\] of a configuration at a voltage.
fn power_limits(c: &PowerLimitsConfig, v: f32) -> (f64, f64) {
    let v = v as f64;
    let mot = (c.power_motoring_max_w as f64).min(v * c.bus_current_motoring_max_a as f64);
    let regen = (c.power_regen_max_w as f64).min(v * c.bus_current_regen_max_a as f64);
    (mot, regen)
}

/// Every limit holds at `iq` (the loss of `i_d` alone may exceed the
/// motoring limit: 0 always stays in the window).
fn check_power_at(c: &PowerLimitsConfig, inp: &PowerInputs, iq: f32) -> Check {
    let (p, scale) = power(c, inp, iq);
    let (p0, _) = power(c, inp, 0.0);
    let v = inp.v_bus_v.unwrap();
    let (mot, regen) = power_limits(c, v);
    let t = tol(scale);
    prop_assert!(p <= mot.max(p0) + t, "iq {iq}: P {p} > {mot}");
    prop_assert!(p >= -regen - t, "iq {iq}: P {p} < -{regen}");
    // The bus current: the same limits divided by V_bus.
    let i_bus = p / v as f64;
    let vt = t / v as f64;
    prop_assert!(i_bus <= (c.bus_current_motoring_max_a as f64).max(p0 / v as f64) + vt);
    prop_assert!(i_bus >= -(c.bus_current_regen_max_a as f64) - vt);
    Ok(())
}

fn check_shape(w: &IqWindow, i_lim: f32) -> Check {
    prop_assert!(w.min_a <= 0.0 && w.max_a >= 0.0, "{w:?}");
    prop_assert!(w.min_a >= -i_lim && w.max_a <= i_lim, "{w:?}");
    prop_assert!((0.0..=1.0).contains(&w.factor), "{w:?}");
    prop_assert!(w.contains(0.0));
    Ok(())
}

fn missing(w: &IqWindow) -> Check {
    prop_assert_eq!(*w, IqWindow::zero(ActiveLimit::MissingSensor));
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3000))]

    /// The window's ends and 16 points inside keep power and bus current
    /// within the limits; the window contains 0 and lies within the
    /// current limit; an end cut by a power or bus-current limit sits *on*
    /// that limit (the window is not narrower than it needs to be).
    #[test]
    fn power_and_bus_current_limits_hold(c in limits_config(), inp in inputs()) {
        let c = c.sanitized();
        let w = iq_window(&c, &inp);
        check_shape(&w, inp.current_limit_a)?;
        for k in 0..=16 {
            let x = k as f32 / 16.0;
            check_power_at(&c, &inp, w.min_a * x)?;
            check_power_at(&c, &inp, w.max_a * x)?;
        }
        let (mot, regen) = power_limits(&c, inp.v_bus_v.unwrap());
        for (end, by) in [(w.min_a, w.min_by), (w.max_a, w.max_by)] {
            let (p, scale) = power(&c, &inp, end);
            let want = match by {
                ActiveLimit::PowerMotoring | ActiveLimit::BusCurrentMotoring => {
                    mot.max(power(&c, &inp, 0.0).0)
                }
                ActiveLimit::PowerRegen | ActiveLimit::BusCurrentRegen => -regen,
                _ => continue,
            };
            // At 0 the limit is the loss of i_d (0 stays in the window).
            if end != 0.0 {
                prop_assert!((p - want).abs() <= tol(scale), "{by:?} at {end}: P {p}, limit {want}");
            }
        }
        // `active` and `factor` describe the tighter end.
        if inp.current_limit_a > 0.0 {
            let tight = w.max_a.min(-w.min_a);
            prop_assert!((w.factor - tight / inp.current_limit_a).abs() < 1e-6);
            if w.factor < 1.0 {
                prop_assert!(w.active == w.min_by || w.active == w.max_by);
                prop_assert_ne!(w.active, ActiveLimit::None);
            } else {
                prop_assert_eq!(w.active, ActiveLimit::None);
            }
        }
    }

    /// Regen ramp: no effect below `regen_start_v`; at and above
    /// `regen_end_v` no regenerative current (the regenerating end at 0
    /// with `i_d = 0`); between, the regenerating end and the largest
    /// regenerative power inside the window fall monotonically with the
    /// bus voltage while the motoring end stays.
    #[test]
    fn regen_ramp(
        m in motor(),
        p_regen in limit(1.0, 2000.0),
        p_mot in limit(1.0, 2000.0),
        mut inp in inputs(),
        start in 20.0f32..50.0,
        span in 0.5f32..10.0,
        xs in proptest::collection::vec(0.0f32..1.0, 2..12),
    ) {
        let mut off = base(m);
        off.power_regen_max_w = p_regen;
        off.power_motoring_max_w = p_mot;
        let mut c = off;
        c.regen_start_v = start;
        c.regen_end_v = start + span;
        let c = c.sanitized();
        inp.i_d_a = 0.0;
        // Below the start: identical to the ramp switched off.
        inp.v_bus_v = Some(start * 0.8);
        prop_assert_eq!(iq_window(&c, &inp), iq_window(&off, &inp));
        inp.v_bus_v = Some(start);
        prop_assert_eq!(iq_window(&c, &inp), iq_window(&off, &inp));
        // At and above the end: nothing regenerates.
        for v in [start + span, start + span + 1.0] {
            inp.v_bus_v = Some(v);
            let w = iq_window(&c, &inp);
            check_shape(&w, inp.current_limit_a)?;
            for k in 0..=16 {
                let iq = lerp(w.min_a, w.max_a, k as f64 / 16.0);
                let (p, scale) = power(&c, &inp, iq);
                prop_assert!(p >= -tol(scale), "v {v}, iq {iq}: P {p}");
            }
            let regen_end = if inp.omega_e_rad_s > 0.0 { w.min_a } else { w.max_a };
            if inp.omega_e_rad_s != 0.0 {
                prop_assert_eq!(regen_end, 0.0);
            }
        }
        // Between: monotonic.
        let mut vs: Vec<f32> = xs.iter().map(|x| start + span * x).collect();
        vs.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let mut last: Option<(IqWindow, f64)> = None;
        for v in vs {
            inp.v_bus_v = Some(v);
            let w = iq_window(&c, &inp);
            check_shape(&w, inp.current_limit_a)?;
            // The largest regenerative power inside: at an end or at the
            // parabola's vertex `-b / (2 a)` (`i_d = 0`).
            let t = inp.winding_temperature_c.unwrap() as f64;
            let r = m.r_ohm as f64 * (1.0 + COPPER_TEMPCO_PER_K as f64 * (t - 20.0));
            let vertex = -(inp.omega_e_rad_s as f64 * m.flux_linkage_wb as f64) / (2.0 * r);
            let mut peak = 0.0f64;
            for iq in [w.min_a as f64, w.max_a as f64, vertex] {
                if iq >= w.min_a as f64 && iq <= w.max_a as f64 {
                    peak = peak.max(-power(&c, &inp, iq as f32).0);
                }
            }
            if let Some((lw, lpeak)) = last {
                prop_assert!(w.min_a >= lw.min_a && w.max_a <= lw.max_a, "{v}: {w:?} after {lw:?}");
                if inp.omega_e_rad_s > 0.0 {
                    prop_assert_eq!(w.max_a, lw.max_a);
                } else if inp.omega_e_rad_s < 0.0 {
                    prop_assert_eq!(w.min_a, lw.min_a);
                }
                prop_assert!(peak <= lpeak + 1e-3 + 1e-4 * lpeak, "{v}: {peak} after {lpeak}");
            }
            last = Some((w, peak));
        }
    }

    /// d-axis braking: only while braking is asked (the request opposes
    /// the speed) and the bus is in the regen ramp; `-(1 - s)` times the
    /// cap, growing with the bus voltage; the current vector within the
    /// limit; at and above `regen_end_v` no net power into the bus, and
    /// still braking torque where the copper loss pays for it.
    #[test]
    fn d_axis_braking(
        m in motor(),
        mut inp in inputs(),
        start in 20.0f32..50.0,
        span in 0.5f32..10.0,
        cap in prop_oneof![Just(f32::INFINITY), 0.1f32..50.0],
        xs in proptest::collection::vec(0.0f32..1.2, 2..12),
    ) {
        let mut c = base(m);
        c.regen_start_v = start;
        c.regen_end_v = start + span;
        c.regen_id_max_a = cap;
        let c = c.sanitized();
        inp.i_d_a = 0.0;
        let i_lim = inp.current_limit_a;
        let w_e = inp.omega_e_rad_s;
        // Not braking (request along the speed, or none): no d-current.
        for req in [0.0, w_e.signum() * 5.0] {
            inp.iq_request_a = req;
            inp.v_bus_v = Some(start + span);
            prop_assert_eq!(iq_window(&c, &inp).id_a, 0.0);
        }
        inp.iq_request_a = -w_e.signum() * 5.0;
        // Below the start: none.
        inp.v_bus_v = Some(start);
        prop_assert_eq!(iq_window(&c, &inp).id_a, 0.0);
        let mut vs: Vec<f32> = xs.iter().map(|x| start + span * x).collect();
        vs.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let mut last_id = 0.0f32;
        for v in vs {
            inp.v_bus_v = Some(v);
            let w = iq_window(&c, &inp);
            check_shape(&w, i_lim)?;
            let s = c.regen_factor(v);
            // Braking regenerates only above the speed where the back-EMF's
            // power exceeds the q-current's copper loss.
            let r_t = c.r_at_ohm(inp.winding_temperature_c.unwrap());
            // (Against the q-current the ramp admits: s of the limit.)
            let admitted = 5.0f32.min(s * i_lim);
            let regenerates = (w_e * m.flux_linkage_wb).abs() > r_t * admitted;
            if w_e != 0.0 {
                let want = if regenerates { -(1.0 - s) * cap.min(i_lim) } else { 0.0 };
                prop_assert!((w.id_a - want).abs() <= 1e-5 * (1.0 + want.abs()), "{v}: {} vs {want}", w.id_a);
            }
            prop_assert!(w.id_a <= 0.0 && w.id_a <= last_id + 1e-6, "{v}: {} after {last_id}", w.id_a);
            last_id = w.id_a;
            // The vector within the limit at both ends.
            for iq in [w.min_a, w.max_a] {
                prop_assert!((iq * iq + w.id_a * w.id_a).sqrt() <= i_lim * (1.0 + 1e-5) + 1e-6);
            }
            if v >= start + span && w_e != 0.0 && regenerates {
                let with_id = PowerInputs { i_d_a: w.id_a, ..inp };
                for k in 0..=16 {
                    let iq = lerp(w.min_a, w.max_a, k as f64 / 16.0);
                    let (p, scale) = power(&c, &with_id, iq);
                    prop_assert!(p >= -tol(scale), "v {v}, iq {iq}: P {p}");
                }
                // Braking torque is left where the winding's copper loss
                // pays for it (and the current limit leaves room).
                let regen_end = if w_e > 0.0 { -w.min_a } else { w.max_a };
                let t = inp.winding_temperature_c.unwrap() as f64;
                let r = m.r_ohm as f64 * (1.0 + COPPER_TEMPCO_PER_K as f64 * (t - 20.0));
                let free = (w_e as f64 * (m.flux_linkage_wb as f64 + (m.ld_h - m.lq_h) as f64 * w.id_a as f64)).abs();
                let room = (i_lim * i_lim - w.id_a * w.id_a).max(0.0).sqrt() as f64;
                if r > 0.0 && w.id_a < -0.1 && free > 0.0 {
                    // The zero-power current: the smaller root of
                    // 1.5 r m^2 - 1.5 |w psi_eff| m + 1.5 r id^2 = 0, or
                    // the vertex where there is none.
                    let (a, b, c) = (r, free, r * (w.id_a as f64).powi(2));
                    let disc = b * b - 4.0 * a * c;
                    let keep = if disc >= 0.0 { 2.0 * c / (b + disc.sqrt()) } else { b / (2.0 * a) };
                    let expect = keep.min(room);
                    prop_assert!(regen_end as f64 >= expect * (1.0 - 1e-3) - 1e-4, "v {v}: {regen_end} vs {expect}");
                }
            }
        }
    }

    /// Derating: the window shrinks monotonically with either
    /// temperature, is untouched at or below the start and `[0, 0]` at the
    /// end, and reports the derating that cut it.
    #[test]
    fn derating_monotonic(
        m in motor(),
        mut inp in inputs(),
        start in 40.0f32..120.0,
        span in 1.0f32..40.0,
        mut ts in proptest::collection::vec(0.0f32..200.0, 2..10),
        stage in any::<bool>(),
    ) {
        let mut c = base(m);
        let off = c;
        if stage {
            c.stage_derate_start_c = start;
            c.stage_derate_end_c = start + span;
        } else {
            c.winding_derate_start_c = start;
            c.winding_derate_end_c = start + span;
        }
        let c = c.sanitized();
        let set = |inp: &mut PowerInputs, t: f32| {
            if stage {
                inp.stage_temperature_c = Some(t);
            } else {
                inp.winding_temperature_c = Some(t);
            }
        };
        let why = if stage { ActiveLimit::StageTemperature } else { ActiveLimit::WindingTemperature };
        set(&mut inp, start);
        let mut off_inp = inp;
        off_inp.stage_temperature_c = None;
        prop_assert_eq!(iq_window(&c, &inp), iq_window(&off, &off_inp));
        set(&mut inp, start + span);
        let w = iq_window(&c, &inp);
        prop_assert_eq!((w.min_a, w.max_a, w.factor), (0.0, 0.0, if inp.current_limit_a > 0.0 { 0.0 } else { 1.0 }));
        if inp.current_limit_a > 0.0 {
            prop_assert_eq!(w.active, why);
        }
        ts.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let mut last: Option<IqWindow> = None;
        for t in ts {
            set(&mut inp, t);
            let w = iq_window(&c, &inp);
            check_shape(&w, inp.current_limit_a)?;
            let k = if stage { c.stage_factor(t) } else { c.winding_factor(t) };
            prop_assert!((0.0..=1.0).contains(&k));
            prop_assert!(w.max_a <= k * inp.current_limit_a && -w.min_a <= k * inp.current_limit_a);
            if let Some(lw) = last {
                prop_assert!(w.min_a >= lw.min_a && w.max_a <= lw.max_a, "{t}: {w:?} after {lw:?}");
            }
            last = Some(w);
        }
    }

    /// Any missing, NaN or infinite input gives `[0, 0]` with
    /// `MissingSensor`, whatever the configuration.
    #[test]
    fn invalid_inputs_give_zero(
        c in limits_config(),
        inp in inputs(),
        which in 0usize..7,
        bad in prop_oneof![Just(f32::NAN), Just(INF), Just(-INF)],
    ) {
        let mut c = c.sanitized();
        c.stage_derate_start_c = 80.0;
        c.stage_derate_end_c = 90.0;
        let mut inp = inp;
        inp.stage_temperature_c = Some(30.0);
        prop_assert_ne!(iq_window(&c, &inp).active, ActiveLimit::MissingSensor);
        match which {
            0 => inp.v_bus_v = Some(bad),
            1 => inp.v_bus_v = None,
            2 => inp.omega_e_rad_s = bad,
            3 => inp.i_d_a = bad,
            4 => inp.current_limit_a = bad,
            5 => inp.winding_temperature_c = if bad.is_nan() { None } else { Some(bad) },
            _ => inp.stage_temperature_c = if bad.is_nan() { None } else { Some(bad) },
        }
        missing(&iq_window(&c, &inp))?;
    }

    /// A NaN in any limit or threshold, sanitized, gives the same window
    /// as its safe value (0 for a limit, "past the end" for a window) and
    /// never a wider one than that; unsanitized, it is never wider either.
    /// Arbitrary (also unsanitized) configurations never give a window
    /// that is NaN, misses 0 or exceeds the current limit.
    #[test]
    fn nan_configuration_is_never_unlimited(
        c in limits_config(),
        inp in inputs(),
        field in 0usize..10,
        junk in proptest::collection::vec(
            prop_oneof![Just(f32::NAN), Just(INF), Just(-INF), Just(-1.0f32), -1e3f32..1e3], 15),
    ) {
        let mut inp = inp;
        inp.stage_temperature_c = Some(50.0);
        let set = |c: &mut PowerLimitsConfig, x: f32| match field {
            0 => c.bus_current_motoring_max_a = x,
            1 => c.bus_current_regen_max_a = x,
            2 => c.power_motoring_max_w = x,
            3 => c.power_regen_max_w = x,
            4 => c.regen_end_v = x,
            5 => c.regen_start_v = x,
            6 => c.winding_derate_end_c = x,
            7 => c.winding_derate_start_c = x,
            8 => c.stage_derate_end_c = x,
            _ => c.stage_derate_start_c = x,
        };
        let (mut with_nan, mut with_safe) = (c, c);
        set(&mut with_nan, f32::NAN);
        if field < 4 {
            set(&mut with_safe, 0.0);
        } else {
            // A window's safe value: always past its end (both thresholds).
            let sibling = if field % 2 == 0 { field + 1 } else { field - 1 };
            set(&mut with_safe, f32::NEG_INFINITY);
            let mut other = with_safe;
            match sibling {
                4 => other.regen_end_v = f32::NEG_INFINITY,
                5 => other.regen_start_v = f32::NEG_INFINITY,
                6 => other.winding_derate_end_c = f32::NEG_INFINITY,
                7 => other.winding_derate_start_c = f32::NEG_INFINITY,
                8 => other.stage_derate_end_c = f32::NEG_INFINITY,
                _ => other.stage_derate_start_c = f32::NEG_INFINITY,
            }
            with_safe = other;
        }
        let w_safe = iq_window(&with_safe.sanitized(), &inp);
        prop_assert_eq!(iq_window(&with_nan.sanitized(), &inp), w_safe);
        let w_raw = iq_window(&with_nan, &inp);
        prop_assert!(w_raw.min_a >= w_safe.min_a && w_raw.max_a <= w_safe.max_a, "{w_raw:?} vs {w_safe:?}");
        // A NaN derating or regen threshold: nothing at all, or nothing
        // regenerative.
        if field >= 6 && inp.current_limit_a > 0.0 {
            prop_assert_eq!((w_safe.min_a, w_safe.max_a), (0.0, 0.0));
        }
        // Arbitrary fields everywhere.
        let mut j = c;
        for (k, x) in junk.iter().enumerate() {
            match k {
                0 => j.bus_current_motoring_max_a = *x,
                1 => j.bus_current_regen_max_a = *x,
                2 => j.power_motoring_max_w = *x,
                3 => j.power_regen_max_w = *x,
                4 => j.regen_end_v = *x,
                5 => j.regen_start_v = *x,
                6 => j.winding_derate_end_c = *x,
                7 => j.winding_derate_start_c = *x,
                8 => j.stage_derate_end_c = *x,
                9 => j.stage_derate_start_c = *x,
                10 => j.thermal_resistance_k_per_w = *x,
                11 => j.thermal_time_constant_s = *x,
                12 => j.ambient_c = *x,
                13 => j.brake_on_v = *x,
                _ => j.brake_off_v = *x,
            }
        }
        for cfg in [j, j.sanitized()] {
            let w = iq_window(&cfg, &inp);
            check_shape(&w, inp.current_limit_a)?;
            let mut t = ThermalEstimate::at_ambient(&cfg);
            for _ in 0..10 {
                let x = t.step(&cfg, Dq::new(1.0, 20.0), 0.5);
                prop_assert!(x.is_finite() && x <= THERMAL_MAX_C);
            }
            let mut b = BrakeChopper::new();
            prop_assert!(!b.step(&cfg, Some(f32::NAN), 50e-6, false));
        }
        let s = j.sanitized();
        prop_assert_eq!(s, s.sanitized());
        prop_assert!(s.brake_off_v <= s.brake_on_v || s.brake_on_v.is_nan());
        // The sanitized brake switches on only at a finite, positive
        // voltage and off at a positive one: never on at every voltage.
        prop_assert!(s.brake_on_v == INF || (s.brake_on_v.is_finite() && s.brake_on_v > 0.0));
        prop_assert!(s.brake_off_v > 0.0);
        let mut b = BrakeChopper::new();
        prop_assert!(s.brake_on_v == INF || !b.step(&s, Some(0.5 * s.brake_off_v), 50e-6, false));
        // And the board defaults with a resistor from such a supervisor.
        let sup = SupervisorConfig {
            bus_over_voltage_v: junk[0],
            ..SupervisorConfig::default()
        };
        let d = PowerLimitsConfig::for_board(&sup, c.motor, false).with_brake_resistor();
        prop_assert!(d.brake_on_v == INF || (d.brake_on_v.is_finite() && d.brake_on_v > 0.0 && d.brake_off_v > 0.0), "{d:?}");
    }

    /// An invalid motor model: no current.
    #[test]
    fn invalid_model_gives_zero(c in limits_config(), inp in inputs(), which in 0usize..5,
                                bad in prop_oneof![Just(f32::NAN), Just(INF), Just(-INF)]) {
        let mut c = c.sanitized();
        match which {
            0 => c.motor.r_ohm = bad,
            1 => c.motor.r_ohm = -0.1,
            2 => c.motor.ld_h = bad,
            3 => c.motor.lq_h = bad,
            _ => c.motor.flux_linkage_wb = bad,
        }
        prop_assert_eq!(iq_window(&c, &inp), IqWindow::zero(ActiveLimit::InvalidModel));
    }

    /// The chopper against a reference hysteresis, NaN and `None` off.
    #[test]
    fn chopper_hysteresis(
        on in 20.0f32..60.0,
        band in 0.0f32..5.0,
        vs in proptest::collection::vec(
            prop_oneof![8 => (10.0f32..70.0).prop_map(Some), 1 => Just(Some(f32::NAN)), 1 => Just(None)],
            1..100),
    ) {
        let mut c = base(MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 4e-5, lq_h: 4e-5, flux_linkage_wb: 0.004 });
        c.brake_on_v = on;
        c.brake_off_v = on - band;
        let c = c.sanitized();
        let mut b = BrakeChopper::new();
        let mut want = false;
        // Periods of 1 ms against the 1 s guard: never reached here.
        for v in vs {
            want = match v {
                Some(v) if v.is_finite() => if want { v > on - band } else { v >= on },
                _ => false,
            };
            prop_assert_eq!(b.step(&c, v, 1e-3, false), want, "{:?}", v);
            prop_assert_eq!(b.is_on(), want);
        }
    }

    /// The guard: on at most `brake_max_on_s` while nothing regenerates,
    /// then locked out until the bus falls below `brake_off_v`; a supply
    /// that sags under the resistor and recovers (the chopper cycling) is
    /// caught too; regeneration is not counted.
    #[test]
    fn chopper_guard(
        on in 20.0f32..60.0,
        band in 0.1f32..5.0,
        max_on in 0.0f32..0.2,
        above in 0.0f32..10.0,
        duty in 2usize..10,
    ) {
        let mut c = base(MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 4e-5, lq_h: 4e-5, flux_linkage_wb: 0.004 });
        c.brake_on_v = on;
        c.brake_off_v = on - band;
        c.brake_max_on_s = max_on;
        let c = c.sanitized();
        let dt = 1e-3;
        let mut b = BrakeChopper::new();
        let mut on_run = 0usize;
        for _ in 0..400 {
            if b.step(&c, Some(on + above), dt, false) {
                on_run += 1;
            }
        }
        prop_assert!(on_run as f32 * dt <= max_on + 1e-6, "{on_run} periods");
        prop_assert!(b.is_locked_out());
        // Still above the off threshold: stays locked.
        prop_assert!(!b.step(&c, Some(on - 0.5 * band), dt, false));
        // Below it: released, and on again above `on`.
        prop_assert!(!b.step(&c, Some(on - 2.0 * band), dt, false));
        prop_assert!(!b.is_locked_out());
        prop_assert_eq!(b.step(&c, Some(on), dt, false), max_on >= dt);
        // Cycling: on for `duty` periods, then the bus sags below the off
        // threshold for one period, again and again: still caught.
        let mut b = BrakeChopper::new();
        let mut on_total = 0usize;
        for k in 0..4000 {
            let v = if k % (duty + 1) == duty { on - 2.0 * band } else { on + above };
            on_total += usize::from(b.step(&c, Some(v), dt, false));
            if b.is_locked_out() {
                break;
            }
        }
        prop_assert!(b.is_locked_out(), "cycling at {duty}/{} not caught", duty + 1);
        prop_assert!(on_total as f32 * dt <= 2.0 * max_on + 10.0 * dt, "{on_total}");
        // Regenerating: never counted, never locked.
        let mut b = BrakeChopper::new();
        for _ in 0..400 {
            prop_assert!(b.step(&c, Some(on + above), dt, true));
        }
    }
}

fn motor_small() -> MotorParams {
    MotorParams {
        pole_pairs: 7,
        r_ohm: 0.1,
        ld_h: 40e-6,
        lq_h: 40e-6,
        flux_linkage_wb: 0.004,
    }
}

/// The winding model against the closed form: with
/// `P(T) = P_20 (1 + alpha (T - 20))` the model is linear,
/// `tau dT/dt = T_amb + R_th P_20 (1 - 20 alpha) - (1 - R_th P_20 alpha) T`,
/// so `T -> T_ss = (T_amb + k (1 - 20 alpha)) / (1 - k alpha)` (`k = R_th
/// P_20`) with the time constant `tau / (1 - k alpha)`. Both within 2 %.
#[test]
fn thermal_converges_with_its_time_constant() {
    for (i_a, r_th, tau, dt) in [
        (10.0f32, 2.0f32, 60.0f32, 1e-3f32),
        (20.0, 1.0, 10.0, 1e-2),
        (5.0, 4.0, 30.0, 0.05),
        (0.0, 2.0, 60.0, 1e-2),
    ] {
        let mut c = base(motor_small());
        c.thermal_resistance_k_per_w = r_th;
        c.thermal_time_constant_s = tau;
        c.ambient_c = 25.0;
        let c = c.sanitized();
        let alpha = COPPER_TEMPCO_PER_K as f64;
        let p20 = 1.5 * 0.1 * (i_a as f64).powi(2);
        let k = r_th as f64 * p20;
        let t_ss = (25.0 + k * (1.0 - 20.0 * alpha)) / (1.0 - k * alpha);
        let tau_eff = tau as f64 / (1.0 - k * alpha);
        let mut t = ThermalEstimate::at_ambient(&c);
        let i = Dq::new(0.0, i_a);
        let n_tau = (tau_eff / dt as f64).round() as usize;
        for _ in 0..n_tau {
            t.step(&c, i, dt);
        }
        let rise = t_ss - 25.0;
        let at_tau = t.temperature_c() as f64 - 25.0;
        let want = rise * (1.0 - (-1.0f64).exp());
        assert!(
            (at_tau - want).abs() <= 0.02 * rise.max(1e-9) + 1e-4,
            "{i_a} A: at tau {at_tau}, want {want}"
        );
        for _ in 0..(9 * n_tau) {
            t.step(&c, i, dt);
        }
        let fin = t.temperature_c() as f64 - 25.0;
        assert!(
            (fin - rise).abs() <= 0.02 * rise.max(1e-9) + 1e-3,
            "{i_a} A: final {fin}, want {rise}"
        );
        // Cooling back with the plain time constant (no loss).
        let hot = t.temperature_c() as f64 - 25.0;
        let n = (tau as f64 / dt as f64).round() as usize;
        for _ in 0..n {
            t.step(&c, Dq::ZERO, dt);
        }
        let cooled = t.temperature_c() as f64 - 25.0;
        assert!((cooled - hot * (-1.0f64).exp()).abs() <= 0.02 * hot.max(1e-9) + 1e-3);
    }
}

/// Non-finite inputs keep the estimate and mark it invalid for that step;
/// a runaway saturates; a huge step lands on the target.
#[test]
fn thermal_nan_and_saturation() {
    let c = PowerLimitsConfig::for_board(&SupervisorConfig::default(), motor_small(), false);
    let mut t = ThermalEstimate::at_ambient(&c);
    t.step(&c, Dq::new(0.0, 10.0), 1.0);
    let before = t.temperature_c();
    for (i, dt) in [
        (Dq::new(f32::NAN, 0.0), 1.0),
        (Dq::new(0.0, f32::INFINITY), 1.0),
        (Dq::new(0.0, 1.0), f32::NAN),
        (Dq::new(0.0, 1.0), -1.0),
        (Dq::new(0.0, 1.0), f32::INFINITY),
    ] {
        assert_eq!(t.step(&c, i, dt), before);
        assert!(!t.is_valid());
        assert_eq!(t.checked_temperature_c(), None);
    }
    assert_eq!(t.invalid_steps(), 5);
    // No current while the estimate is invalid.
    let inp = PowerInputs {
        v_bus_v: Some(24.0),
        omega_e_rad_s: 100.0,
        i_d_a: 0.0,
        iq_request_a: 0.0,
        current_limit_a: 10.0,
        winding_temperature_c: t.checked_temperature_c(),
        stage_temperature_c: None,
    };
    assert_eq!(
        iq_window(&c, &inp),
        IqWindow::zero(ActiveLimit::MissingSensor)
    );
    t.step(&c, Dq::new(0.0, 10.0), 1e-3);
    assert!(t.is_valid());
    // Runaway (copper's tempco): saturates.
    for _ in 0..200 {
        t.step(&c, Dq::new(0.0, 1e4), 10.0);
    }
    assert!(t.temperature_c() > THERMAL_MAX_C - 0.01 && t.temperature_c() <= THERMAL_MAX_C);
    // A step far longer than tau lands on the target.
    let mut u = ThermalEstimate::at_ambient(&c);
    u.step(&c, Dq::ZERO, 1e9);
    assert!((u.temperature_c() - c.ambient_c).abs() < 1e-3);
    // The derating then holds the current at 0.
    let inp = PowerInputs {
        winding_temperature_c: t.checked_temperature_c(),
        ..inp
    };
    let w = iq_window(&c, &inp);
    assert_eq!((w.min_a, w.max_a), (0.0, 0.0));
    assert_eq!(w.active, ActiveLimit::WindingTemperature);
}

/// The board defaults: the regen window below the over-voltage threshold
/// and above the under-voltage one, the stage derating ending below the
/// over-temperature fault, nothing limited at a nominal operating point.
#[test]
fn board_defaults() {
    let sup = SupervisorConfig::default();
    let c = PowerLimitsConfig::for_board(&sup, motor_small(), true);
    assert!(c.regen_start_v > sup.bus_under_voltage_v);
    assert!(c.regen_start_v < c.regen_end_v && c.regen_end_v < sup.bus_over_voltage_v);
    assert!(c.stage_derate_start_c < c.stage_derate_end_c);
    assert!(c.stage_derate_end_c < sup.max_temperature_c);
    assert_eq!(c, c.sanitized());
    let b = c.with_brake_resistor();
    assert!(b.brake_off_v < b.brake_on_v && b.brake_on_v <= b.regen_start_v);
    let inp = PowerInputs {
        v_bus_v: Some(24.0),
        omega_e_rad_s: 3000.0,
        i_d_a: 0.0,
        iq_request_a: 0.0,
        current_limit_a: 10.0,
        winding_temperature_c: Some(60.0),
        stage_temperature_c: Some(40.0),
    };
    let w = iq_window(&c, &inp);
    assert_eq!(
        (w.min_a, w.max_a, w.active, w.factor),
        (-10.0, 10.0, ActiveLimit::None, 1.0)
    );
    // A stage sensor configured but missing: no current.
    let w = iq_window(
        &c,
        &PowerInputs {
            stage_temperature_c: None,
            ..inp
        },
    );
    assert_eq!(w, IqWindow::zero(ActiveLimit::MissingSensor));
    // Clamp helper: NaN -> 0.
    let w = iq_window(&c, &inp);
    assert_eq!(w.clamp(f32::NAN), 0.0);
    assert_eq!(w.clamp(20.0), 10.0);
}

/// A worked example: 24 V, 100 W motoring / 50 W regenerating, 2 A from
/// and 1 A into the supply, at 2000 rad/s electrical (8 V back-EMF).
#[test]
fn worked_example() {
    let mut c = base(motor_small());
    c.power_motoring_max_w = 100.0;
    c.power_regen_max_w = 50.0;
    c.bus_current_motoring_max_a = 2.0; // 48 W at 24 V: tighter
    c.bus_current_regen_max_a = 1.0; // 24 W at 24 V: tighter
    let c = c.sanitized();
    let inp = PowerInputs {
        v_bus_v: Some(24.0),
        omega_e_rad_s: 2000.0,
        i_d_a: 0.0,
        iq_request_a: 0.0,
        current_limit_a: 10.0,
        winding_temperature_c: Some(20.0),
        stage_temperature_c: None,
    };
    let w = iq_window(&c, &inp);
    // 0.15 iq^2 + 12 iq = 48 -> iq = 3.8178; = -24 -> iq = -2.0527.
    assert!((w.max_a - 3.817_8).abs() < 1e-3, "{w:?}");
    assert!((w.min_a + 2.052_7).abs() < 1e-3, "{w:?}");
    assert_eq!(w.max_by, ActiveLimit::BusCurrentMotoring);
    assert_eq!(w.min_by, ActiveLimit::BusCurrentRegen);
    assert_eq!(w.active, ActiveLimit::BusCurrentRegen);
    assert!((w.factor - 0.205_27).abs() < 1e-4);
}
