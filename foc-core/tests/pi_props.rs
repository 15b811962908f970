//! Property tests of the PI controller (design §6): bounds, sign,
//! anti-windup.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::pi::{AntiWindup, Pi, PiConfig};
use proptest::prelude::*;

/// The anti-windup `kind`: 0 clamp, 1 back-calculation with `kb_per_s`,
/// 2 (or more) the matched back-calculation.
fn anti_windup(kind: u8, kb_per_s: f32) -> AntiWindup {
    match kind {
        0 => AntiWindup::Clamp,
        1 => AntiWindup::BackCalculation { kb_per_s },
        _ => AntiWindup::MatchedBackCalculation,
    }
}

/// Any anti-windup kind (see [`anti_windup`]).
fn kind() -> impl Strategy<Value = u8> {
    0u8..3
}

fn config() -> impl Strategy<Value = PiConfig> {
    (
        0.0f32..100.0,
        0.0f32..1e5,
        1e-6f32..1e-2,
        -100.0f32..100.0,
        0.0f32..100.0,
        kind(),
        0.0f32..1e5,
    )
        .prop_map(|(kp, ki, ts, lo, width, kind, kb)| PiConfig {
            kp,
            ki_per_s: ki,
            ts_s: ts,
            out_min: lo,
            out_max: lo + width,
            anti_windup: anti_windup(kind, kb),
        })
}

fn signal() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => -1e3f32..1e3,
        1 => -1e30f32..1e30,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(f32::NEG_INFINITY),
    ]
}

/// Steps until the output is `<= 0` after the error turns to `-x`.
fn steps_to_reverse(pi: &mut Pi, x: f32, cap: u32) -> u32 {
    for k in 1..=cap {
        if pi.step_error(-x, pi.config.out_min, pi.config.out_max) <= 0.0 {
            return k;
        }
    }
    cap + 1
}

/// Saturate with error `e` until the output first hits the upper limit,
/// then hold `extra` more steps there.
fn saturate(pi: &mut Pi, e: f32, extra: u32) {
    let hi = pi.config.out_max;
    for _ in 0..1_000_000 {
        if pi.step_error(e, pi.config.out_min, hi) >= hi {
            break;
        }
    }
    for _ in 0..extra {
        pi.step_error(e, pi.config.out_min, hi);
    }
}

proptest! {
    /// The integrator and the output never leave the limits, for any gains,
    /// limits, signals (also NaN and infinities) and limits that move per step.
    #[test]
    fn integrator_and_output_stay_bounded(
        cfg in config(),
        steps in proptest::collection::vec((signal(), signal(), any::<bool>(), 0.0f32..1.0), 1..300),
    ) {
        let mut pi = Pi::new(cfg);
        for (sp, meas, moving, shrink) in steps {
            let (lo, hi) = if moving {
                // A moving limit inside the configured one (e.g. a voltage circle).
                let mid = 0.5 * (cfg.out_min + cfg.out_max);
                (mid + (cfg.out_min - mid) * shrink, mid + (cfg.out_max - mid) * shrink)
            } else {
                (cfg.out_min, cfg.out_max)
            };
            let u = if moving { pi.step_error(sp - meas, lo, hi) } else { pi.step(sp, meas) };
            prop_assert!(u.is_finite() && u >= lo && u <= hi, "u {u} not in [{lo}, {hi}]");
            prop_assert_eq!(u, pi.state.output);
            let i = pi.state.integral;
            prop_assert!(i.is_finite() && i >= lo && i <= hi, "integral {i} not in [{lo}, {hi}]");
        }
    }

    /// e = setpoint - measurement: a positive error gives a positive output
    /// from rest, a negative one a negative output, and a constant positive
    /// error never makes the output decrease.
    #[test]
    fn response_sign(kp in 0.0f32..100.0, ki in 0.0f32..1e5, ts in 1e-6f32..1e-2,
                     limit in 0.1f32..100.0, e in 1e-3f32..100.0, kind in kind(), kb in 0.0f32..1e4) {
        prop_assume!(kp * e + ki * ts * e > 1e-6);
        let cfg = PiConfig { kp, ki_per_s: ki, ts_s: ts, out_min: -limit, out_max: limit,
                             anti_windup: anti_windup(kind, kb) };
        let mut pos = Pi::new(cfg);
        let mut neg = Pi::new(cfg);
        let mut last = pos.step(e, 0.0);
        prop_assert!(last > 0.0);
        prop_assert!(neg.step(0.0, e) < 0.0, "measurement above setpoint must push down");
        for _ in 0..200 {
            let u = pos.step(e, 0.0);
            prop_assert!(u >= last, "output decreased under positive error: {last} -> {u}");
            last = u;
        }
    }

    /// No windup: the time to reverse after a saturation does not grow
    /// with its duration (it is bounded by the integrator's range), with
    /// every anti-windup method. With `Clamp` the integrator is frozen at
    /// saturation, so a very long saturation recovers as fast as a short
    /// one; with back-calculation it settles at `hi - kp e + ki e / kb`
    /// (clamped), with the matched one at `hi`, so 100k and 400k steps of
    /// saturation recover alike.
    #[test]
    fn no_windup_after_long_saturation(kp in 0.01f32..10.0, ki in 100.0f32..1e4, ts in 1e-4f32..1e-3,
                                       hi in 1.0f32..50.0, e in 1.0f32..100.0, x in 0.1f32..10.0,
                                       kind in kind(), kb_rel in 1.0f32..10.0) {
        let cfg = PiConfig { kp, ki_per_s: ki, ts_s: ts, out_min: -hi, out_max: hi,
                             anti_windup: anti_windup(kind, kb_rel * ki / kp) };
        let bound = (2.0 * hi / (ki * ts * x)) as u32 + 2;
        let run = |extra: u32| {
            let mut pi = Pi::new(cfg);
            saturate(&mut pi, e, extra);
            steps_to_reverse(&mut pi, x, bound + 10)
        };
        let (n_short, n_long, n_longer) = (run(1), run(100_000), run(400_000));
        prop_assert!(n_longer <= bound, "{n_longer} > bound {bound}");
        prop_assert!(n_longer <= n_long + 1 + n_long / 100, "400k {n_longer} vs 100k {n_long}");
        if kind == 0 {
            prop_assert!(n_long <= n_short + 1, "clamp: long {n_long} vs short {n_short}");
        }
    }

    /// The matched back-calculation: in every step, saturated or not (and
    /// with limits that move), the integrator is the same first-order lag
    /// of the output the step returned, `I = I' + g (u - I')` with
    /// `g = ki ts / (kp + ki ts)` and `I'` the last integrator clamped
    /// into this step's limits (for gains `>= 0`; up to rounding).
    #[test]
    fn matched_integrator_is_a_lag_of_the_output(
        kp in 0.0f32..100.0, ki in 0.0f32..1e5, ts in 1e-6f32..1e-2,
        lo in -100.0f32..100.0, width in 0.0f32..100.0,
        steps in proptest::collection::vec((-1e3f32..1e3, any::<bool>(), 0.0f32..1.0), 1..300),
    ) {
        let cfg = PiConfig { kp, ki_per_s: ki, ts_s: ts, out_min: lo, out_max: lo + width,
                             anti_windup: AntiWindup::MatchedBackCalculation };
        let mut pi = Pi::new(cfg);
        let g = cfg.matched_tracking_gain();
        prop_assert!((0.0..=1.0).contains(&g));
        let expected_g = (ki * ts) as f64 / (kp as f64 + (ki * ts) as f64);
        if expected_g.is_finite() {
            prop_assert!((g as f64 - expected_g).abs() <= 1e-6, "{g} vs {expected_g}");
        }
        for (e, moving, shrink) in steps {
            let (mut l, mut h) = (cfg.out_min, cfg.out_max);
            if moving {
                let mid = 0.5 * (l + h);
                (l, h) = (mid + (l - mid) * shrink, mid + (h - mid) * shrink);
            }
            let i_prev = pi.state.integral.clamp(l, h);
            let u = pi.step_error(e, l, h);
            let want = i_prev + g * (u - i_prev);
            let tol = 1e-4 * (1.0 + l.abs() + h.abs());
            prop_assert!((pi.state.integral - want).abs() <= tol,
                "I {} vs {want} (I' {i_prev}, u {u}, saturated {})",
                pi.state.integral, pi.state.saturated);
        }
    }
}

/// The same scenario against a PI without anti-windup (integrator only
/// bounded by f32): it takes thousands of times longer to reverse, which is
/// the defect the limits and anti-windup prevent.
#[test]
fn windup_reference_is_slow_ours_are_fast() {
    let (kp, ki, ts, hi) = (0.5f32, 500.0f32, 1e-4f32, 10.0f32);
    let sat_steps = 20_000u32;
    // Naive: I += ki ts e, u = clamp(kp e + I).
    let mut i_naive = 0.0f32;
    for _ in 0..sat_steps {
        i_naive += ki * ts * 100.0;
    }
    let mut naive_steps = 0u32;
    loop {
        naive_steps += 1;
        i_naive -= ki * ts; // error -1
        let u = (i_naive - kp).clamp(-hi, hi);
        if u <= 0.0 || naive_steps > 10_000_000 {
            break;
        }
    }
    for aw in [
        AntiWindup::Clamp,
        AntiWindup::BackCalculation { kb_per_s: ki / kp },
        AntiWindup::MatchedBackCalculation,
    ] {
        let cfg = PiConfig {
            kp,
            ki_per_s: ki,
            ts_s: ts,
            out_min: -hi,
            out_max: hi,
            anti_windup: aw,
        };
        let mut pi = Pi::new(cfg);
        for _ in 0..sat_steps {
            pi.step_error(100.0, -hi, hi);
        }
        assert_eq!(pi.state.output, hi);
        assert!(pi.state.saturated);
        let ours = steps_to_reverse(&mut pi, 1.0, 1_000_000);
        // Bounded integrator: at most (hi + kp)/(ki ts) = 210 steps.
        assert!(ours <= 210, "{aw:?}: {ours}");
        assert!(
            naive_steps > 1000 * ours,
            "{aw:?}: naive {naive_steps} vs {ours}"
        );
    }
}

/// Bumpless preload and reset.
#[test]
fn preload_and_reset() {
    let mut pi = Pi::new(PiConfig {
        kp: 1.0,
        ki_per_s: 10.0,
        ts_s: 1e-3,
        out_min: -5.0,
        out_max: 5.0,
        anti_windup: AntiWindup::Clamp,
    });
    pi.preload(3.0);
    assert_eq!(pi.step(0.0, 0.0), 3.0);
    pi.preload(50.0);
    assert_eq!(pi.step(0.0, 0.0), 5.0);
    pi.preload(f32::NAN);
    assert_eq!(pi.step(0.0, 0.0), 0.0);
    pi.step(1.0, 0.0);
    pi.reset();
    assert_eq!(pi.state.integral, 0.0);
    assert_eq!(pi.state.output, 0.0);
}

/// Any f32 a configuration field might hold by mistake: NaN, the
/// infinities, both zeros, negative, huge, tiny, and ordinary values.
fn any_field() -> impl Strategy<Value = f32> {
    prop_oneof![
        2 => Just(f32::NAN),
        2 => Just(f32::INFINITY),
        2 => Just(f32::NEG_INFINITY),
        2 => Just(0.0f32),
        1 => Just(-0.0f32),
        1 => Just(f32::MAX),
        1 => Just(-f32::MAX),
        1 => Just(f32::MIN_POSITIVE),
        3 => -1e3f32..0.0,
        4 => 0.0f32..1e3,
        1 => 1e-7f32..1e-2,
        1 => -1e38f32..1e38,
    ]
}

fn any_config() -> impl Strategy<Value = PiConfig> {
    (
        (any_field(), any_field(), any_field()),
        (any_field(), any_field()),
        kind(),
        any_field(),
    )
        .prop_map(|((kp, ki, ts), (lo, hi), kind, kb)| PiConfig {
            kp,
            ki_per_s: ki,
            ts_s: ts,
            out_min: lo,
            out_max: hi,
            anti_windup: anti_windup(kind, kb),
        })
}

/// The limits are usable: finite and ordered.
fn usable_limits(lo: f32, hi: f32) -> bool {
    lo.is_finite() && hi.is_finite() && lo <= hi
}

/// The gains are usable: finite `kp`, finite `ts >= 0`, finite `ki ts`.
fn usable_gains(c: &PiConfig) -> bool {
    c.kp.is_finite() && c.ts_s.is_finite() && c.ts_s >= 0.0 && (c.ki_per_s * c.ts_s).is_finite()
}

/// A finite signal, ordinary or extreme (products with the gains may
/// overflow).
fn finite_signal() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => -1e3f32..1e3,
        1 => -f32::MAX..f32::MAX,
        1 => Just(0.0f32),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Whatever the configuration (NaN, infinities, zero, negative values
    /// in every field): `Pi::new` makes it usable, a usable one is kept as
    /// it is, and every step (finite or non-finite signals, limits moving
    /// inside the configured ones) returns a finite value inside the
    /// configured limits, and inside the given limits when those are
    /// usable; unusable gains give a constant neutral output.
    #[test]
    fn any_config_gives_bounded_finite_outputs(
        cfg in any_config(),
        preload in any_field(),
        steps in proptest::collection::vec((finite_signal(), signal(), any::<bool>(), 0.0f32..1.0), 1..100),
    ) {
        let mut pi = Pi::new(cfg);
        let c = pi.config;
        prop_assert_eq!(c, cfg.sanitized());
        prop_assert!(usable_limits(c.out_min, c.out_max), "{c:?}");
        prop_assert!(usable_gains(&c), "{c:?}");
        if usable_limits(cfg.out_min, cfg.out_max) {
            // Never outside the limits it was given.
            prop_assert!(c.out_min >= cfg.out_min && c.out_max <= cfg.out_max, "{cfg:?} -> {c:?}");
        } else {
            prop_assert_eq!((c.out_min, c.out_max), (0.0, 0.0));
        }
        if usable_limits(cfg.out_min, cfg.out_max) && usable_gains(&cfg) {
            let bits = |p: &PiConfig| (p.kp.to_bits(), p.ki_per_s.to_bits(), p.ts_s.to_bits(),
                                       p.out_min.to_bits(), p.out_max.to_bits());
            prop_assert_eq!(bits(&c), bits(&cfg), "a usable configuration is kept");
        }
        let neutral = c.out_min.max(0.0).min(c.out_max);
        pi.preload(preload);
        for (e, meas, moving, shrink) in steps {
            let (lo, hi) = if moving {
                let mid = 0.5 * c.out_min + 0.5 * c.out_max;
                (mid + (c.out_min - mid) * shrink, mid + (c.out_max - mid) * shrink)
            } else {
                (c.out_min, c.out_max)
            };
            let u = if moving { pi.step_error(e - meas, lo, hi) } else { pi.step(e, meas) };
            prop_assert!(u.is_finite() && u >= lo && u <= hi, "u {u} not in [{lo}, {hi}] for {cfg:?}");
            prop_assert!(u >= c.out_min && u <= c.out_max);
            let i = pi.state.integral;
            prop_assert!(i.is_finite() && i >= lo && i <= hi, "integral {i} for {cfg:?}");
            if !usable_gains(&cfg) {
                prop_assert_eq!(u, neutral, "neutralised: {:?}", cfg);
            }
        }
    }

    /// `set_config` on a running controller: the same guarantees; unusable
    /// gains stop it holding its last output (neutral at once).
    #[test]
    fn set_config_any_config_gives_bounded_finite_outputs(
        cfg in any_config(),
        errors in proptest::collection::vec(finite_signal(), 1..50),
    ) {
        let mut pi = Pi::new(PiConfig {
            kp: 1.0, ki_per_s: 1e3, ts_s: 1e-3, out_min: -10.0, out_max: 10.0,
            anti_windup: AntiWindup::Clamp,
        });
        for _ in 0..20 {
            pi.step(5.0, 0.0);
        }
        pi.set_config(cfg);
        let c = pi.config;
        prop_assert_eq!(c, cfg.sanitized());
        if !usable_gains(&cfg) {
            prop_assert_eq!(c.out_min, c.out_max);
            prop_assert_eq!(pi.state.integral, c.out_min);
            prop_assert_eq!(pi.state.output, c.out_min);
        }
        for e in errors {
            let u = pi.step(e, 0.0);
            prop_assert!(u.is_finite() && u >= c.out_min && u <= c.out_max, "u {u} for {cfg:?}");
            if !usable_gains(&cfg) {
                prop_assert_eq!(u, c.out_min);
            }
        }
    }

    /// A configuration and an integrator written straight into the public
    /// fields (not sanitised): `step_error` still never returns NaN or an
    /// infinity (0 for unusable limits); when that configuration is usable
    /// as it is and the integrator finite, it also stays within the step's
    /// limits.
    #[test]
    fn raw_fields_never_give_nan(
        cfg in any_config(),
        integral in any_field(),
        steps in proptest::collection::vec((signal(), any_field(), any_field()), 1..50),
    ) {
        let mut pi = Pi::new(cfg);
        pi.config = cfg;
        pi.state.integral = integral;
        let checked = cfg.sanitized() == cfg && integral.is_finite();
        for (e, lo, hi) in steps {
            let u = pi.step_error(e, lo, hi);
            prop_assert!(u.is_finite(), "u {u} for {cfg:?}");
            if !usable_limits(lo, hi) {
                // State left as it was.
                prop_assert_eq!(u, 0.0);
                continue;
            }
            prop_assert!(pi.state.integral.is_finite());
            if checked {
                prop_assert!(u >= lo && u <= hi, "u {u} not in [{lo}, {hi}] for {cfg:?}");
                let i = pi.state.integral;
                prop_assert!(i >= lo && i <= hi, "integral {i} for {cfg:?}");
            }
            prop_assert_eq!(u.to_bits(), pi.state.output.to_bits());
            prop_assert!(pi.step(e, 0.0).is_finite());
        }
    }
}

/// The neutralisation, field by field: each unusable value on an otherwise
/// good configuration.
#[test]
fn unusable_fields_are_neutralised() {
    let good = PiConfig {
        kp: 2.0,
        ki_per_s: 100.0,
        ts_s: 1e-3,
        out_min: 1.0,
        out_max: 5.0,
        anti_windup: AntiWindup::BackCalculation { kb_per_s: 50.0 },
    };
    assert_eq!(good.sanitized(), good);
    // A legitimate reverse-acting controller and a zero sample time: kept.
    let reverse = PiConfig {
        kp: -2.0,
        ki_per_s: -100.0,
        ..good
    };
    assert_eq!(reverse.sanitized(), reverse);
    let no_time = PiConfig { ts_s: 0.0, ..good };
    assert_eq!(no_time.sanitized(), no_time);
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        for cfg in [
            PiConfig { kp: bad, ..good },
            PiConfig {
                ki_per_s: bad,
                ..good
            },
            PiConfig { ts_s: bad, ..good },
        ] {
            let c = cfg.sanitized();
            assert_eq!((c.kp, c.ki_per_s), (0.0, 0.0), "{cfg:?}");
            // Limits 1..5: the neutral value is the limit nearest 0.
            assert_eq!((c.out_min, c.out_max), (1.0, 1.0), "{cfg:?}");
            let mut pi = Pi::new(cfg);
            pi.preload(4.0);
            assert_eq!(pi.step(100.0, 0.0), 1.0);
            // Through step_error: that value, clamped into the step's limits.
            assert_eq!(pi.step_error(-3.0, -2.0, 2.0), 1.0);
            assert_eq!(pi.step_error(-3.0, -0.5, 0.5), 0.5);
        }
        for cfg in [
            PiConfig {
                out_min: bad,
                ..good
            },
            PiConfig {
                out_max: bad,
                ..good
            },
        ] {
            let c = cfg.sanitized();
            assert_eq!((c.out_min, c.out_max), (0.0, 0.0), "{cfg:?}");
            assert_eq!((c.kp, c.ki_per_s), (2.0, 100.0));
            assert_eq!(Pi::new(cfg).step(1.0, 0.0), 0.0);
        }
    }
    // Inverted limits.
    let inverted = PiConfig {
        out_min: 5.0,
        out_max: 1.0,
        ..good
    };
    assert_eq!(Pi::new(inverted).step(1.0, 0.0), 0.0);
    // A negative sample time, and a product ki ts that overflows.
    for cfg in [
        PiConfig {
            ts_s: -1e-3,
            ..good
        },
        PiConfig {
            ki_per_s: 1e30,
            ts_s: 1e30,
            ..good
        },
    ] {
        let c = cfg.sanitized();
        assert_eq!(
            (c.kp, c.ki_per_s, c.out_min, c.out_max),
            (0.0, 0.0, 1.0, 1.0)
        );
        assert!(c.ts_s.is_finite() && c.ts_s >= 0.0);
    }
    // A NaN tracking gain: no tracking, the rest kept.
    let nan_kb = PiConfig {
        anti_windup: AntiWindup::BackCalculation { kb_per_s: f32::NAN },
        ..good
    };
    let c = nan_kb.sanitized();
    assert_eq!(c.anti_windup, AntiWindup::BackCalculation { kb_per_s: 0.0 });
    assert_eq!(
        (c.kp, c.ki_per_s, c.out_min, c.out_max),
        (2.0, 100.0, 1.0, 5.0)
    );
}

/// A NaN integrator written directly into the state, with a NaN error or
/// not: never a NaN output (0; the integrator follows).
#[test]
fn nan_integrator_written_directly_gives_no_nan() {
    let mut pi = Pi::new(PiConfig {
        kp: 1.0,
        ki_per_s: 10.0,
        ts_s: 1e-3,
        out_min: -2.0,
        out_max: 5.0,
        anti_windup: AntiWindup::Clamp,
    });
    pi.state.integral = f32::NAN;
    assert_eq!(pi.step(f32::NAN, 0.0), 0.0);
    assert_eq!(pi.state.integral, 0.0);
    pi.state.integral = f32::NAN;
    assert_eq!(pi.step(1.0, 0.0), 0.0);
    assert_eq!(pi.state.integral, 0.0);
    // Then it runs normally again.
    assert!(pi.step(1.0, 0.0) > 0.0);
}

/// Back-calculation with a zero tracking gain when `kp e` overflows
/// (`0 * inf`): the integrator takes the output, the active limit, so both
/// stay within limits that exclude 0.
#[test]
fn back_calculation_overflow_stays_in_limits() {
    let mut pi = Pi::new(PiConfig {
        kp: 1e30,
        ki_per_s: 10.0,
        ts_s: 1e-3,
        out_min: 1.0,
        out_max: 5.0,
        anti_windup: AntiWindup::BackCalculation { kb_per_s: 0.0 },
    });
    for e in [1e30f32, -1e30, f32::MAX, 1.0] {
        let u = pi.step_error(e, 1.0, 5.0);
        assert!((1.0..=5.0).contains(&u), "{e}: {u}");
        let i = pi.state.integral;
        assert!((1.0..=5.0).contains(&i), "{e}: integral {i}");
    }
}
