//! Property tests of the PI controller (design §6): bounds, sign,
//! anti-windup.

use foc_core::pi::{AntiWindup, Pi, PiConfig};
use proptest::prelude::*;

fn anti_windup(kind: bool, kb_per_s: f32) -> AntiWindup {
    if kind {
        AntiWindup::Clamp
    } else {
        AntiWindup::BackCalculation { kb_per_s }
    }
}

fn config() -> impl Strategy<Value = PiConfig> {
    (
        0.0f32..100.0,
        0.0f32..1e5,
        1e-6f32..1e-2,
        -100.0f32..100.0,
        0.0f32..100.0,
        any::<bool>(),
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
                     limit in 0.1f32..100.0, e in 1e-3f32..100.0, kind in any::<bool>(), kb in 0.0f32..1e4) {
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
    /// either anti-windup method. With `Clamp` the integrator is frozen at
    /// saturation, so a very long saturation recovers as fast as a short
    /// one; with back-calculation it settles at `hi - kp e + ki e / kb`
    /// (clamped), so 100k and 400k steps of saturation recover alike.
    #[test]
    fn no_windup_after_long_saturation(kp in 0.01f32..10.0, ki in 100.0f32..1e4, ts in 1e-4f32..1e-3,
                                       hi in 1.0f32..50.0, e in 1.0f32..100.0, x in 0.1f32..10.0,
                                       kind in any::<bool>(), kb_rel in 1.0f32..10.0) {
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
        if kind {
            prop_assert!(n_long <= n_short + 1, "clamp: long {n_long} vs short {n_short}");
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
