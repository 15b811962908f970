//! Property tests of the public configuration constructors and setters that
//! take floats: fed NaN, infinities, zero, negative, huge and tiny values
//! (each field drawn from a mix of sensible and such values), the objects
//! they configure, stepped with *finite* inputs, never panic and never
//! return NaN or infinite outputs; the current loop's duties stay in
//! `[0, 1]`.
//!
//! Covered: `tuning::{technical_optimum, bandwidth, technical_optimum_dq,
//! bandwidth_dq}`, `CurrentPiGains::pi_config`, `Pi::new`, `Pi::set_config`,
//! `CurrentLoopConfig::technical_optimum` (and its public fields),
//! `calibration::gains::current_loop_config`, `CurrentLoop::{new,
//! set_config}`, `SpeedLoopConfig::from_bandwidth`, `SpeedLoop::{new,
//! set_config}`, `AngleTrackerConfig::with_bandwidth`, `AngleTracker::{new,
//! set_config}`, `PositionLoopConfig` (all fields), `PositionLoop::{new,
//! set_config}`, `Trapezoid::plan`, `Rates::for_pwm`,
//! `CascadeConfig::{for_motor, for_motor_with_inertia}` with `Cascade::new`
//! and `Calibrated::supplied`, `CurrentStage::{set_limits,
//! set_current_config}` on a running cascade, `OffsetLimits`, and the
//! calibration routines' `*Config::new` (`IdentificationConfig`,
//! `ResistanceConfig`, `InductanceConfig`, `AlignmentConfig`, `FluxConfig`).
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::angle::{ElectricalAngle, MechanicalAngle};
use foc_core::calibration::alignment::{Alignment, AlignmentConfig};
use foc_core::calibration::flux::{FluxConfig, FluxLinkage};
use foc_core::calibration::identification::{Identification, IdentificationConfig};
use foc_core::calibration::inductance::{Inductance, InductanceConfig};
use foc_core::calibration::offsets::{OffsetCalibrator, OffsetLimits, OffsetStep};
use foc_core::calibration::resistance::{PhaseResistance, ResistanceConfig};
use foc_core::calibration::{CalInput, CalStep, Calibrated, ClosedLoopFeedback};
use foc_core::control::current::{CurrentLoop, CurrentLoopConfig, CurrentLoopInput};
use foc_core::control::estimator::{AngleTracker, AngleTrackerConfig};
use foc_core::control::joint::Impedance;
use foc_core::control::position::{PositionLoop, PositionLoopConfig};
use foc_core::control::speed::{SpeedLoop, SpeedLoopConfig};
use foc_core::control::stage::Sample;
use foc_core::control::trajectory::Trapezoid;
use foc_core::control::Fault;
use foc_core::control::{BridgeCommand, Command, Feedback, Limits, MotorParams, Rates};
use foc_core::drive::cascade::{Cascade, CascadeConfig};
use foc_core::frames::{Abc, Dq};
use foc_core::hal::PhaseCurrents;
use foc_core::pi::{AntiWindup, Pi, PiConfig};
use foc_core::tuning;
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

type Check = Result<(), TestCaseError>;

/// A value a configuration should never get, but might: NaN, the
/// infinities, both zeros, negative, extreme.
fn bad() -> impl Strategy<Value = f32> {
    prop_oneof![
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        Just(0.0f32),
        Just(-0.0f32),
        -1e3f32..-1e-6,
        Just(-1.0f32),
        Just(f32::MAX),
        Just(-f32::MAX),
        Just(f32::MIN_POSITIVE),
        Just(1e-30f32),
        Just(1e30f32),
    ]
}

/// A field: sensible in `[lo, hi)` two times in three, [`bad`] otherwise.
fn field(lo: f32, hi: f32) -> BoxedStrategy<f32> {
    prop_oneof![2 => lo..hi, 1 => bad()].boxed()
}

fn motor() -> impl Strategy<Value = MotorParams> {
    (
        prop_oneof![4 => 1u8..30, 1 => Just(0u8), 1 => Just(255u8)],
        field(0.01, 2.0),
        field(1e-5, 5e-3),
        field(1e-5, 5e-3),
        field(1e-3, 0.1),
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

fn good_motor() -> MotorParams {
    MotorParams {
        pole_pairs: 7,
        r_ohm: 0.1,
        ld_h: 50e-6,
        lq_h: 60e-6,
        flux_linkage_wb: 0.005,
    }
}

fn anti_windup(kind: bool, kb: f32) -> AntiWindup {
    if kind {
        AntiWindup::Clamp
    } else {
        AntiWindup::BackCalculation { kb_per_s: kb }
    }
}

fn fin(x: f32) -> bool {
    x.is_finite()
}

/// No `NaN` or `inf` in a value's debug form (for result types of every
/// shape).
fn debug_finite(x: &impl core::fmt::Debug) -> bool {
    let s = format!("{x:?}");
    !s.contains("NaN") && !s.contains("inf")
}

/// Checks a feedback: every float finite. Known defects (outside this
/// change; see `known_defect_stage_limits_not_finite`): with a non-finite
/// `Limits::max_current_a` the published `current_limit_a` echoes it and
/// the q-current reference of the velocity and position modes becomes
/// infinite (the supervisor then latches `NonFinite`: bridge off), so
/// those two are only checked when that limit is finite.
fn check_feedback(fb: &Feedback, max_current_a: f32, what: &str) -> Check {
    if max_current_a.is_finite() {
        prop_assert!(
            fin(fb.current_limit_a) && fin(fb.i_dq_ref_a.d) && fin(fb.i_dq_ref_a.q),
            "{what}: feedback {fb:?}"
        );
    }
    let xs = [
        fb.position_rad,
        fb.velocity_rad_s,
        fb.i_dq_a.d,
        fb.i_dq_a.q,
        fb.v_dq_v.d,
        fb.v_dq_v.q,
        fb.v_bus_v,
        fb.duties[0],
        fb.duties[1],
        fb.duties[2],
    ];
    prop_assert!(xs.iter().all(|x| fin(*x)), "{what}: feedback {fb:?}");
    prop_assert!(debug_finite(&fb.active), "{what}: active {:?}", fb.active);
    Ok(())
}

fn check_bridge(b: BridgeCommand, what: &str) -> Check {
    if let BridgeCommand::Duties(d) = b {
        prop_assert!(
            d.iter().all(|x| fin(*x) && (0.0..=1.0).contains(x)),
            "{what}: duties {d:?}"
        );
    }
    Ok(())
}

/// The configurations of a known defect of `CurrentLoop` (outside this
/// change; see `known_defect_current_loop_nan_voltage`): a non-finite
/// decoupling feed-forward (decoupling on with a non-finite or overflowing
/// `Ld`, `Lq` or flux linkage), or a `max_modulation` that is not finite,
/// negative, or so large that the voltage limit overflows, makes the
/// reported `v_dq_v` / `v_ab_v` NaN, with `invalid: true` and centred
/// duties (safe).
fn current_loop_known_defect(cfg: &CurrentLoopConfig, inp: &CurrentLoopInput) -> bool {
    let m = &cfg.motor;
    let w = inp.omega_e_rad_s.abs();
    let ff_bad = cfg.decoupling
        && !(w * (m.lq_h.abs() + m.ld_h.abs()) * 100.0 + w * m.flux_linkage_wb.abs()).is_finite();
    let v_max = cfg.max_modulation * inp.v_bus_v;
    ff_bad || !(v_max * v_max).is_finite() || cfg.max_modulation < 0.0
}

/// The plans of a known defect of `Trapezoid::plan` (outside this change;
/// see `known_defect_trapezoid_overflow`): an extreme (finite, positive)
/// acceleration limit overflows the plan: with `a_max * |target - p0|`
/// infinite the positions overflow; with a tiny one the braking time is
/// infinite and the samples at large times NaN. For the distances and
/// speeds of these tests, `a_max` outside `[1e-10, 1e30]`.
fn trapezoid_known_defect(a_max: f32) -> bool {
    a_max.is_finite() && a_max > 0.0 && !(1e-10..=1e30).contains(&a_max)
}

/// Finite current-loop inputs.
fn cl_input() -> impl Strategy<Value = CurrentLoopInput> {
    (
        (-50.0f32..50.0, -50.0f32..50.0, -50.0f32..50.0),
        any::<u32>(),
        prop_oneof![3 => -5e3f32..5e3, 1 => -1e6f32..1e6],
        prop_oneof![4 => 5.0f32..60.0, 1 => -10.0f32..100.0],
        (-50.0f32..50.0, -50.0f32..50.0),
    )
        .prop_map(|((a, b, c), th, w, vbus, (idr, iqr))| CurrentLoopInput {
            i_abc_a: Abc::new(a, b, c),
            theta_e: ElectricalAngle::from_bits(th),
            omega_e_rad_s: w,
            v_bus_v: vbus,
            i_dq_ref_a: Dq::new(idr, iqr),
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    /// The tuning rules and `pi_config`, through `Pi::new` and
    /// `Pi::set_config`: finite outputs within the controller's limits.
    #[test]
    fn tuning_rules_to_pi(
        l in field(1e-5, 5e-3), l2 in field(1e-5, 5e-3), r in field(0.01, 2.0),
        ts in field(1e-5, 1e-3), wc in field(10.0, 1e4), limit in field(1.0, 50.0),
        kind in any::<bool>(), kb in field(0.0, 1e4),
        errors in proptest::collection::vec(-1e3f32..1e3, 1..50),
    ) {
        let dq = tuning::technical_optimum_dq(l, l2, r, ts);
        let dq_bw = tuning::bandwidth_dq(l, l2, r, wc);
        let wc_to = tuning::technical_optimum_wc_rad_s(ts);
        for g in [
            tuning::technical_optimum(l, r, ts),
            tuning::bandwidth(l, r, wc),
            tuning::bandwidth(l, r, wc_to),
            dq.d, dq.q, dq_bw.d, dq_bw.q,
        ] {
            let aw = if kind {
                AntiWindup::BackCalculation { kb_per_s: g.back_calculation_gain_per_s() }
            } else {
                anti_windup(false, kb)
            };
            let cfg = g.pi_config(ts, limit, aw);
            let mut a = Pi::new(cfg);
            let mut b = Pi::new(PiConfig { kp: 1.0, ki_per_s: 10.0, ts_s: 1e-3, out_min: -1.0,
                                           out_max: 1.0, anti_windup: AntiWindup::Clamp });
            b.step(1.0, 0.0);
            b.set_config(cfg);
            for pi in [&mut a, &mut b] {
                let (lo, hi) = (pi.config.out_min, pi.config.out_max);
                for &e in &errors {
                    let u = pi.step(e, 0.0);
                    prop_assert!(fin(u) && u >= lo && u <= hi, "{g:?} {cfg:?}: {u}");
                }
            }
        }
    }

    /// `CurrentLoopConfig::technical_optimum` (or
    /// `calibration::gains::current_loop_config`) on any motor and PWM
    /// frequency, with any `max_modulation`, delay compensation and
    /// anti-windup, through `CurrentLoop::new` or `set_config` on a running
    /// loop: finite outputs, duties in [0, 1].
    #[test]
    fn current_loop_from_any_config(
        m in motor(), pwm in field(1e3, 1e5),
        max_mod in prop_oneof![2 => 0.1f32..1.0, 1 => bad()],
        delay in prop_oneof![2 => 0.0f32..4.0, 1 => bad()],
        decoupling in any::<bool>(), kind in any::<bool>(), kb in field(0.0, 1e4),
        how in 0u8..3,
        inputs in proptest::collection::vec((cl_input(), 0u8..10), 1..60),
    ) {
        let mut cfg = if how == 2 {
            match foc_core::calibration::gains::current_loop_config(m, 1.0 / pwm) {
                Ok(c) => c,
                Err(_) => CurrentLoopConfig::technical_optimum(m, pwm),
            }
        } else {
            CurrentLoopConfig::technical_optimum(m, pwm)
        };
        cfg.max_modulation = max_mod;
        cfg.delay_compensation_periods = delay;
        cfg.decoupling = decoupling;
        cfg.anti_windup = anti_windup(kind, kb);
        let mut cl = if how == 1 {
            let mut cl = CurrentLoop::new(CurrentLoopConfig::technical_optimum(good_motor(), 20e3));
            for (inp, _) in &inputs {
                cl.step(inp);
            }
            cl.set_config(cfg);
            cl
        } else {
            CurrentLoop::new(cfg)
        };
        for (inp, what) in &inputs {
            let out = match what {
                0 => cl.step_voltage(inp.i_abc_a, inp.theta_e, inp.i_dq_ref_a, inp.v_bus_v),
                1 => {
                    // Bumpless entry from an open-loop voltage.
                    cl.preload(inp.i_dq_ref_a, Dq::new(inp.i_abc_a.a, inp.i_abc_a.b), inp.omega_e_rad_s);
                    cl.step(inp)
                }
                _ => cl.step(inp),
            };
            let ctx = format!("{cfg:?} {inp:?} (what {what})");
            prop_assert!(out.duties.iter().all(|d| fin(*d) && (0.0..=1.0).contains(d)),
                         "{ctx}: duties {:?}", out.duties);
            prop_assert!(debug_finite(&out.i_dq_a), "{ctx}: {out:?}");
            if out.invalid {
                // Safe: centred duties.
                prop_assert_eq!(out.duties, [0.5; 3], "{}", ctx);
            }
            if !current_loop_known_defect(&cfg, inp) {
                prop_assert!(debug_finite(&out.v_dq_v) && debug_finite(&out.v_ab_v), "{ctx}: {out:?}");
            }
            prop_assert!(fin(cl.integrators().d) && fin(cl.integrators().q), "{ctx}");
        }
    }

    /// `SpeedLoopConfig::from_bandwidth` through `SpeedLoop::new` or
    /// `set_config`: finite q-current references within the configured
    /// limit (0 for a non-finite one).
    #[test]
    fn speed_loop_from_any_config(
        j in field(1e-6, 1e-2), kt in field(1e-3, 1.0), bw in field(1.0, 1e3),
        ts in field(1e-5, 1e-2), limit in field(0.1, 50.0), set_later in any::<bool>(),
        steps in proptest::collection::vec(
            (-1e3f32..1e3, -1e3f32..1e3, -20.0f32..20.0, prop_oneof![Just(f32::INFINITY), -1.0f32..60.0], 0u8..8),
            1..80),
    ) {
        let cfg = SpeedLoopConfig::from_bandwidth(j, kt, bw, ts, limit);
        let mut s = if set_later {
            let mut s = SpeedLoop::new(SpeedLoopConfig::from_bandwidth(1e-5, 0.05, 100.0, 1e-3, 5.0));
            for _ in 0..10 {
                s.step(100.0, 0.0, 0.0);
            }
            s.set_config(cfg);
            s
        } else {
            SpeedLoop::new(cfg)
        };
        let bound = if limit.is_finite() { limit.abs() } else { 0.0 };
        for (w_ref, w_est, ff, lim, what) in steps {
            if what == 0 {
                s.preload(ff);
            }
            let iq = if what == 1 { s.step(w_ref, w_est, ff) } else { s.step_within(w_ref, w_est, ff, lim) };
            prop_assert!(fin(iq), "{cfg:?}: {iq}");
            prop_assert!(iq.abs() <= bound * (1.0 + 1e-6) + 1e-30, "{cfg:?}: |{iq}| > {bound}");
        }
    }

    /// `AngleTrackerConfig::with_bandwidth` through `AngleTracker::new` or
    /// `set_config`: finite innovation, velocity and position.
    #[test]
    fn angle_tracker_from_any_config(
        bw in field(1.0, 1e4), ts in field(1e-5, 1e-2), set_later in any::<bool>(),
        start in any::<u32>(),
        steps in proptest::collection::vec(prop_oneof![3 => -50_000_000i32..50_000_000, 1 => any::<i32>()], 1..200),
    ) {
        let cfg = AngleTrackerConfig::with_bandwidth(bw, ts);
        let mut t = AngleTracker::new(AngleTrackerConfig::with_bandwidth(500.0, 5e-5));
        if set_later {
            for k in 0..20u32 {
                t.update(MechanicalAngle::from_bits(k.wrapping_mul(1 << 20)));
            }
            t.set_config(cfg);
        } else {
            t = AngleTracker::new(cfg);
        }
        let mut a = MechanicalAngle::from_bits(start);
        for d in steps {
            a = a.wrapping_add(MechanicalAngle::from_bits(d as u32));
            let e = t.update(a);
            prop_assert!(fin(e) && fin(t.velocity_rad_s()) && fin(t.innovation_rad()), "{cfg:?}");
            prop_assert!(fin(t.position().to_radians()), "{cfg:?}");
            let _ = (t.angle(), t.angle_at_reading());
        }
    }

    /// `PositionLoopConfig` with any field, through `PositionLoop::new` or
    /// `set_config`, and `Trapezoid::plan` with any limits: finite velocity
    /// references, feed-forward and trajectory points.
    #[test]
    fn position_loop_from_any_config(
        ts in field(1e-4, 1e-2), kp in field(0.1, 100.0), v_max in field(1.0, 1e3),
        a_max in field(1.0, 1e4), ff in field(0.0, 1e-2), set_later in any::<bool>(),
        p0 in -1e3f32..1e3, v0 in -1e2f32..1e2, target in -1e3f32..1e3,
        meas in proptest::collection::vec((-1e3f32..1e3, 0u8..20), 1..100),
    ) {
        let cfg = PositionLoopConfig {
            ts_s: ts,
            kp_per_s: kp,
            max_velocity_rad_s: v_max,
            max_acceleration_rad_s2: a_max,
            accel_ff_a_per_rad_s2: ff,
        };
        let mut p = if set_later {
            let mut p = PositionLoop::new(PositionLoopConfig {
                ts_s: 1e-3, kp_per_s: 20.0, max_velocity_rad_s: 50.0,
                max_acceleration_rad_s2: 500.0, accel_ff_a_per_rad_s2: 0.0,
            });
            p.start_move(0.0, 0.0, 1.0);
            p.step(0.0);
            p.set_config(cfg);
            p
        } else {
            PositionLoop::new(cfg)
        };
        p.start_move(p0, v0, target);
        for (x, what) in meas {
            if what == 0 {
                p.retarget(x);
            }
            let w = p.step(x);
            let r = p.reference();
            prop_assert!(fin(w), "{cfg:?}: w {w}");
            prop_assert!(fin(p.current_feed_forward_a()), "{cfg:?}");
            if !trapezoid_known_defect(a_max) {
                // (A retarget starts from the reference: a non-finite one
                // would make the target non-finite too.)
                prop_assert!(fin(r.position) && fin(r.velocity) && fin(r.acceleration), "{cfg:?}: {r:?}");
                prop_assert!(fin(p.target()), "{cfg:?}: target {}", p.target());
            }
            let _ = p.trajectory_done();
        }
        // The trajectory alone, sampled over (and past) its duration.
        let tr = Trapezoid::plan(p0, v0, target, v_max, a_max);
        let d = tr.duration_s();
        prop_assert!(!d.is_nan(), "plan({p0}, {v0}, {target}, {v_max}, {a_max}): duration {d}");
        let span = if d.is_finite() { d * 1.2 + 1e-3 } else { 10.0 };
        for k in 0..=50 {
            let pt = tr.sample(span * k as f32 / 50.0);
            if trapezoid_known_defect(a_max) {
                continue;
            }
            prop_assert!(fin(pt.position) && fin(pt.velocity) && fin(pt.acceleration),
                         "plan({p0}, {v0}, {target}, {v_max}, {a_max}) at {k}: {pt:?}");
        }
    }

    /// `CascadeConfig::for_motor` / `for_motor_with_inertia` (and so
    /// `Rates::for_pwm`) on any motor, PWM frequency, current limit and
    /// inertia, through `Cascade::new` (calibrated when
    /// `Calibrated::supplied` accepts the values), any command, finite
    /// samples: duties in [0, 1], finite feedback.
    #[test]
    fn cascade_from_any_config(
        m in motor(), pwm in field(1e3, 1e5), max_current in field(0.5, 50.0),
        inertia in field(1e-6, 1e-2), with_inertia in any::<bool>(),
        cmd in 0u8..5, target in -20.0f32..20.0,
        samples in proptest::collection::vec((-10.0f32..10.0, -10.0f32..10.0, -3_000_000i32..3_000_000, 10.0f32..30.0), 1..150),
    ) {
        let cfg = if with_inertia {
            CascadeConfig::for_motor_with_inertia(m, pwm, max_current, inertia)
        } else {
            CascadeConfig::for_motor(m, pwm, max_current)
        };
        let rates = Rates::for_pwm(pwm);
        prop_assert!(rates.speed_divider >= 1 && rates.position_divider >= 1);
        let mut c = Cascade::new(cfg);
        if let Ok(permit) = Calibrated::supplied(cfg.current.angle, cfg.current.current) {
            c.set_calibration(&permit);
        }
        let command = match cmd {
            0 => Command::Disable,
            1 => Command::Torque { iq_a: target },
            2 => Command::Velocity { rad_s: 10.0 * target },
            3 => Command::Position { rad: target },
            _ => Command::OpenLoop {
                v_d_v: 0.1 * target,
                v_q_v: 0.0,
                theta_e: ElectricalAngle::ZERO,
                omega_e_rad_s: 5.0 * target,
            },
        };
        let _ = c.command(command);
        let mut angle = MechanicalAngle::ZERO;
        for (k, (a, b, d, vbus)) in samples.into_iter().enumerate() {
            angle = angle.wrapping_add(MechanicalAngle::from_bits(d as u32));
            let sample = Sample {
                currents: Some(PhaseCurrents::ThreePhase(Abc::new(a, b, -a - b))),
                angle: Some(angle),
                v_bus_v: Some(vbus),
                temperature_c: None,
            };
            let ctx = format!("for_motor({m:?}, {pwm}, {max_current}, {inertia}) {command:?} period {k}");
            check_bridge(c.step(&sample), &ctx)?;
            check_feedback(c.feedback(), cfg.current.limits.max_current_a, &ctx)?;
            prop_assert!(fin(c.iq_ref_a()), "{ctx}: iq_ref {}", c.iq_ref_a());
        }
        // Over-current protection: 10 kA in phase A is far over any
        // limit below 1 kA. Known defect (outside this change; see
        // `known_defect_for_motor_nan_current_disables_over_current`): a NaN
        // or infinite `max_current_a` turns the protection off.
        let over = Sample {
            currents: Some(PhaseCurrents::ThreePhase(Abc::new(1e4, -5e3, -5e3))),
            angle: Some(angle),
            v_bus_v: Some(24.0),
            temperature_c: None,
        };
        let b = c.step(&over);
        check_bridge(b, "over-current")?;
        if max_current < 1e3 || max_current == f32::NEG_INFINITY {
            // Off, or the active short circuit (design §30) where it is
            // configured and the back-EMF would rectify into the bus (a
            // flux linkage of 1e30 Wb does at any speed).
            let shorted = b == BridgeCommand::ShortCircuit
                && c.current.field().short_circuit();
            prop_assert!(b == BridgeCommand::SafeState || shorted,
                         "for_motor({:?}, {}, {}): {:?} {:?}",
                         m, pwm, max_current, b, c.feedback());
        }
    }

    /// The stage's setters on a running, calibrated cascade: any `Limits`
    /// (`set_limits`), then any current-loop configuration
    /// (`set_current_config`), commands accepted or not: duties in [0, 1],
    /// finite feedback.
    #[test]
    fn stage_setters_with_any_values(
        max_current in field(0.5, 50.0), max_velocity in field(10.0, 1e4),
        min_pos in field(-1e5, -1.0), max_pos in field(1.0, 1e5),
        ol_v in field(1.0, 60.0), ol_w in field(10.0, 1e4),
        m in motor(), pwm in field(1e3, 1e5), change_current in any::<bool>(),
        cmd in 0u8..5, target in -1e3f32..1e3,
    ) {
        let cfg = CascadeConfig::for_motor(good_motor(), 20e3, 10.0);
        let mut c = Cascade::new(cfg);
        let permit = Calibrated::supplied(cfg.current.angle, cfg.current.current).unwrap();
        c.set_calibration(&permit);
        let _ = c.command(Command::Torque { iq_a: 1.0 });
        let sample = |k: u32| Sample {
            currents: Some(PhaseCurrents::TwoPhase { a_a: 0.5, b_a: -0.25 }),
            angle: Some(MechanicalAngle::from_bits(k.wrapping_mul(1 << 22))),
            v_bus_v: Some(24.0),
            temperature_c: None,
        };
        for k in 0..20 {
            c.step(&sample(k));
        }
        let limits = Limits {
            max_current_a: max_current,
            max_velocity_rad_s: max_velocity,
            min_position_rad: min_pos,
            max_position_rad: max_pos,
            max_open_loop_voltage_v: ol_v,
            max_open_loop_omega_e_rad_s: ol_w,
            max_kp_nm_per_rad: ol_w,
            max_kd_nm_s_per_rad: ol_v,
        };
        c.current.set_limits(limits);
        if change_current {
            c.current.set_current_config(CurrentLoopConfig::technical_optimum(m, pwm));
        }
        let command = match cmd {
            0 => Command::Torque { iq_a: target },
            1 => Command::Velocity { rad_s: target },
            2 => Command::Position { rad: target },
            3 => Command::Impedance(Impedance {
                position_rad: target, velocity_rad_s: target * 0.1,
                kp_nm_per_rad: target.abs(), kd_nm_s_per_rad: target.abs() * 0.01,
                torque_ff_nm: target * 0.001, torque_limit_nm: target.abs(),
            }),
            _ => Command::OpenLoop { v_d_v: target * 0.01, v_q_v: 0.0,
                                     theta_e: ElectricalAngle::ZERO, omega_e_rad_s: target },
        };
        let _ = c.command(command);
        for k in 20..150 {
            let ctx = format!("{limits:?} {} {command:?} period {k}",
                              if change_current { format!("{m:?} {pwm}") } else { String::new() });
            check_bridge(c.step(&sample(k)), &ctx)?;
            check_feedback(c.feedback(), limits.max_current_a, &ctx)?;
        }
    }

    /// The calibration routines' configuration constructors: stepped with
    /// finite measurements (a crude, resistive "motor"), every request is
    /// finite (open-loop voltages, velocity references) and so is every
    /// result; failing is fine.
    #[test]
    fn calibration_configs_from_any_values(
        pp in prop_oneof![4 => 1u8..30, 1 => Just(0u8)], pwm in field(1e3, 1e5),
        current in field(0.1, 20.0), v_max in field(1.0, 48.0), r in field(0.01, 2.0),
        v in field(0.1, 10.0), which in 0u8..5, periods in 1usize..3000,
    ) {
        fn run<T: core::fmt::Debug>(name: &str, periods: usize,
                                    mut step: impl FnMut(&CalInput) -> CalStep<T>) -> Check {
            let mut inp = CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0);
            for k in 0..periods {
                let out = step(&inp);
                match &out {
                    CalStep::Apply { v_dq, theta_e } => {
                        prop_assert!(fin(v_dq.d) && fin(v_dq.q), "{name} period {k}: {out:?}");
                        // A resistive motor of 1 ohm, the sensor turning with the voltage.
                        let (s, c) = theta_e.to_radians().sin_cos();
                        let ia = v_dq.d * c - v_dq.q * s;
                        let ib = v_dq.d * (c * -0.5 + s * 0.866) - v_dq.q * (-s * 0.5 + c * 0.866);
                        inp.i_abc_a = Abc::new(ia, ib, -ia - ib);
                        inp.angle = MechanicalAngle::from_bits(theta_e.to_bits() / 7);
                        inp.closed_loop = None;
                    }
                    CalStep::Velocity { rad_s } => {
                        prop_assert!(fin(*rad_s), "{name} period {k}: {out:?}");
                        inp.angle = inp.angle.wrapping_add(MechanicalAngle::from_bits((*rad_s * 1e3) as i32 as u32));
                        inp.closed_loop = Some(ClosedLoopFeedback {
                            v_dq_v: Dq::new(0.0, 0.01 * rad_s),
                            i_dq_a: Dq::new(0.0, 0.1),
                            velocity_rad_s: *rad_s,
                            theta_e: Default::default(),
                        });
                    }
                    CalStep::Torque { iq_a } => {
                        prop_assert!(fin(*iq_a), "{name} period {k}: {out:?}");
                        // A rotor accelerating with the current.
                        let w = inp.closed_loop.map_or(0.0, |f| f.velocity_rad_s) + 0.05 * iq_a;
                        inp.angle = inp.angle.wrapping_add(MechanicalAngle::from_bits((w * 1e3) as i32 as u32));
                        inp.closed_loop = Some(ClosedLoopFeedback {
                            v_dq_v: Dq::new(0.0, 0.01 * w),
                            i_dq_a: Dq::new(0.0, *iq_a),
                            velocity_rad_s: w,
                            theta_e: Default::default(),
                        });
                    }
                    CalStep::Done(_) => {
                        prop_assert!(debug_finite(&out), "{name} period {k}: {out:?}");
                        break;
                    }
                    CalStep::Failed(_) => break,
                }
            }
            Ok(())
        }
        match which {
            0 => {
                let mut c = Identification::new(IdentificationConfig::new(pp, pwm, current, v_max));
                run("Identification", periods, |i| c.step(i))?;
            }
            1 => {
                let mut c = PhaseResistance::new(ResistanceConfig::new(pwm, current, v_max));
                run("PhaseResistance", periods, |i| c.step(i))?;
            }
            2 => {
                let mut c = Inductance::new(InductanceConfig::new(pwm, current, v_max));
                run("Inductance", periods, |i| c.step(i))?;
            }
            3 => {
                let mut c = Alignment::new(AlignmentConfig::new(pp, pwm, v, current));
                run("Alignment", periods, |i| c.step(i))?;
            }
            _ => {
                let mut c = FluxLinkage::new(FluxConfig::new(pp, pwm, r, current));
                run("FluxLinkage", periods, |i| c.step(i))?;
            }
        }
    }

    /// `OffsetLimits` with any values: `Done` only with finite offsets.
    #[test]
    fn offset_limits_from_any_values(
        samples in prop_oneof![Just(0u32), 1u32..64],
        max_offset in field(0.01, 2.0), max_noise in field(0.001, 0.5),
        readings in proptest::collection::vec((-1.0f32..1.0, prop_oneof![4 => -1.0f32..1.0, 1 => -f32::MAX..f32::MAX]), 1..80),
    ) {
        let limits = OffsetLimits { samples, max_offset_a: max_offset, max_noise_a: max_noise };
        let mut cal = OffsetCalibrator::new(limits);
        for (a, b) in readings {
            match cal.step(Abc::new(a, b, 0.5 * a)) {
                OffsetStep::Done(o) => {
                    prop_assert!(o.is_finite(), "{limits:?}: {o:?}");
                    prop_assert!(limits.is_valid());
                    prop_assert!(o.to_array().iter().all(|x| x.abs() <= max_offset));
                }
                OffsetStep::Failed(_) | OffsetStep::InProgress => {}
            }
        }
    }
}

// Known defects outside this change (found by the properties above, which
// skip exactly these cases and check the safe outputs there). Each test
// states the correct behaviour: ignored until fixed, run with
// `cargo test -p foc-core --test config_props -- --ignored`.

/// `CurrentStage` with a non-finite `Limits::max_current_a` (from
/// `CascadeConfig::for_motor(_, _, NaN)` or `CurrentStage::set_limits`)
/// used to publish a NaN `current_limit_a`, and `Command::validate`
/// accepted any finite torque (`|iq| > NaN` is false); with `-inf` the
/// velocity modes' q reference became `clamp(iq, inf, -inf) = inf`. Now
/// the limit becomes 0 and the validation refuses under a NaN limit.
#[test]
fn non_finite_current_limit_refuses_and_stays_safe() {
    let cfg = CascadeConfig::for_motor(good_motor(), 20e3, f32::NAN);
    let mut c = Cascade::new(cfg);
    let permit = Calibrated::supplied(cfg.current.angle, cfg.current.current).unwrap();
    c.set_calibration(&permit);
    let sample = Sample {
        currents: Some(PhaseCurrents::TwoPhase { a_a: 0.0, b_a: 0.0 }),
        angle: Some(MechanicalAngle::ZERO),
        v_bus_v: Some(24.0),
        temperature_c: None,
    };
    c.step(&sample);
    assert!(
        c.feedback().current_limit_a.is_finite(),
        "{:?}",
        c.feedback()
    );
    assert!(
        c.command(Command::Torque { iq_a: 1e6 }).is_err(),
        "a 1 MA torque command accepted under a NaN current limit"
    );
    let cfg = CascadeConfig::for_motor(good_motor(), 20e3, 10.0);
    let mut c = Cascade::new(cfg);
    c.set_calibration(&Calibrated::supplied(cfg.current.angle, cfg.current.current).unwrap());
    c.current.set_limits(Limits {
        max_current_a: f32::NEG_INFINITY,
        ..cfg.current.limits
    });
    c.command(Command::Velocity { rad_s: 1.0 }).unwrap();
    for _ in 0..20 {
        c.step(&sample);
        let fb = c.feedback();
        assert!(
            fb.i_dq_ref_a.q.is_finite() && fb.first_fault.is_none(),
            "{fb:?}"
        );
    }
}

/// `CascadeConfig::for_motor` with a NaN (or `+inf`) `max_current_a`
/// used to make the supervisor's limits NaN, and `|i| > NaN` never trips:
/// 1 kA in a phase kept the bridge on. Now the stage's current limit is 0
/// (torque refused) and the supervisor's current limits are 0 (any
/// current trips).
#[test]
fn nan_current_limit_keeps_over_current_protection() {
    for lim in [f32::NAN, f32::INFINITY] {
        let cfg = CascadeConfig::for_motor(good_motor(), 20e3, lim);
        let mut c = Cascade::new(cfg);
        c.set_calibration(&Calibrated::supplied(cfg.current.angle, cfg.current.current).unwrap());
        assert!(c.command(Command::Torque { iq_a: 1.0 }).is_err());
        let over = Sample {
            currents: Some(PhaseCurrents::ThreePhase(Abc::new(1000.0, -500.0, -500.0))),
            angle: Some(MechanicalAngle::ZERO),
            v_bus_v: Some(24.0),
            temperature_c: None,
        };
        assert_eq!(
            c.step(&over),
            BridgeCommand::SafeState,
            "max_current_a {lim}"
        );
        assert_eq!(c.feedback().first_fault, Some(Fault::OverCurrentPhase));
    }
}

/// `control/current.rs`, `CurrentLoop::step` / `step_voltage`: with
/// decoupling on and a non-finite `Ld`, `Lq` or flux linkage, the
/// feed-forward is NaN and so are the reported `v_dq_v` and `v_ab_v`
/// (`invalid: true`, duties centred: safe); the same with a negative or
/// non-finite `max_modulation` (`step_voltage`: `k = v_max / 0`).
#[test]
#[ignore = "known defect in control/current.rs: NaN voltages from unusable motor values / max_modulation"]
fn known_defect_current_loop_nan_voltage() {
    let motor = MotorParams {
        lq_h: f32::NAN,
        ..good_motor()
    };
    let inp = CurrentLoopInput {
        i_abc_a: Abc::new(0.0, 0.0, 0.0),
        theta_e: ElectricalAngle::ZERO,
        omega_e_rad_s: 0.0,
        v_bus_v: 5.0,
        i_dq_ref_a: Dq::ZERO,
    };
    let mut cl = CurrentLoop::new(CurrentLoopConfig::technical_optimum(motor, 1e3));
    let out = cl.step(&inp);
    assert!(out.v_dq_v.d.is_finite() && !out.invalid, "{out:?}");
    let mut cfg = CurrentLoopConfig::technical_optimum(good_motor(), 1e3);
    cfg.max_modulation = -f32::MAX;
    let mut cl = CurrentLoop::new(cfg);
    let out = cl.step_voltage(inp.i_abc_a, inp.theta_e, Dq::ZERO, 5.0);
    assert!(out.v_dq_v.d.is_finite(), "{out:?}");
}

/// `control/trajectory.rs`, `Trapezoid::plan` with an extreme but finite
/// acceleration limit: `a_max = f32::MAX` overflows `a_max * distance`
/// (positions become infinite); `a_max = f32::MIN_POSITIVE` with a
/// braking start makes the braking time infinite (the sample at a large
/// time is NaN). Through `PositionLoop` (`ts_s = f32::MAX`) the reference
/// and, after a retarget, the target become non-finite.
#[test]
#[ignore = "known defect in control/trajectory.rs: overflow with extreme a_max"]
fn known_defect_trapezoid_overflow() {
    let tr = Trapezoid::plan(0.0, 0.0, 796.1537, f32::MAX, f32::MAX);
    let d = tr.duration_s();
    for k in 0..=50 {
        let pt = tr.sample(d * k as f32 / 50.0);
        assert!(pt.position.is_finite(), "at {k}/50 of {d}: {pt:?}");
    }
    let tr = Trapezoid::plan(0.0, -50.088913, 0.0, 309.0948, f32::MIN_POSITIVE);
    let pt = tr.sample(f32::MAX);
    assert!(pt.position.is_finite(), "{pt:?}");
    let mut p = PositionLoop::new(PositionLoopConfig {
        ts_s: f32::MAX,
        kp_per_s: 0.1,
        max_velocity_rad_s: 309.0948,
        max_acceleration_rad_s2: f32::MIN_POSITIVE,
        accel_ff_a_per_rad_s2: 0.0,
    });
    p.start_move(0.0, -50.088913, 0.0);
    p.step(0.0);
    p.step(0.0);
    assert!(p.reference().position.is_finite(), "{:?}", p.reference());
}
