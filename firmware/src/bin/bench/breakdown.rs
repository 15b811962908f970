//! The pieces of one period, each measured alone on inputs like the
//! drive's (the stage's configuration, a rotor turning at 150 rad/s):
//! what the per-period call is made of. The pieces are the functions the
//! stage calls; their sum is less than the whole, the rest is the stage's
//! own logic (mode, limits, interpolation, timeout) and the calls between.

use super::{measure, report, Stats};
use crate::drive::{cascade, BoardDrive, Rig};
use core::hint::black_box;
use foc_core::angle::{ElectricalAngle, MechanicalAngle};
use foc_core::control::current::{CurrentLoop, CurrentLoopInput, CurrentLoopOutput};
use foc_core::control::estimator::{AngleTracker, SpeedObserver};
use foc_core::control::flux_observer::{FluxObserver, ObserverConfig};
use foc_core::control::frozen::Readings;
use foc_core::control::hfi::{Hfi, HfiConfig};
use foc_core::control::model::{ModelCheck, Period, Verdict};
use foc_core::control::power::{PowerInputs, PowerLimiter, PowerReport};
use foc_core::control::stage::Sample;
use foc_core::control::supervisor::{Checks, Fault, Supervisor};
use foc_core::control::{io, BridgeCommand, Feedback};
use foc_core::frames::{Abc, Dq};
use foc_core::transforms;

/// Rotor angle at step `k` while turning at 150 rad/s (mechanical).
fn rotor(k: u32) -> MechanicalAngle {
    MechanicalAngle::from_radians(150.0 * 50e-6 * k as f32)
}

/// Measures and reports the pieces; returns the sum of their worst cases
/// and that of the emulated board's I/O (sensor reads and PWM write).
pub fn measure_pieces(rig: &mut Rig, baseline: u32, currents: &dyn Fn(u32) -> Abc) -> (u32, u32) {
    let cfg = cascade().current;
    let n = 64;
    let (mut sum, mut io) = (0u32, 0u32);
    let mut add = |name: &str, s: Stats| {
        report(name, s);
        sum += s.max;
        if name.contains("(emulated board") {
            io += s.max;
        }
    };
    let d = rig.drive_mut();
    add(
        "  part: sensor reads (emulated board, io::read_sample)",
        measure(
            baseline,
            n,
            &mut |_| board_support::board::sim::step_physics(),
            &mut |_| {
                black_box(read_part(black_box(&mut *d)));
            },
        ),
    );
    let mut tracker = AngleTracker::new(cfg.tracker);
    let mut observer = SpeedObserver::new(cfg.observer);
    for k in 0..200 {
        tracker.update(rotor(k));
        observer.update(rotor(k), 1.0);
    }
    add(
        "  part: estimators (AngleTracker::update + SpeedObserver::update)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let th = black_box(rotor(200 + k));
            black_box(estimators_part(
                &mut tracker,
                &mut observer,
                th,
                black_box(1.0),
            ));
        }),
    );
    let mut sup = Supervisor::new(cfg.supervisor);
    add(
        "  part: supervision (Supervisor::check_vector_sq)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let i = currents(k);
            let ab = transforms::clarke(i);
            let checks = Checks {
                i_abc_a: i,
                measured_sum_a: None,
                vector_current_a: 0.0,
                v_bus_v: black_box(24.0),
                angle_innovation_rad: black_box(0.001),
                angle_step_rad: black_box(0.0005),
                speed_rad_s: black_box(150.0),
                temperature_c: black_box(Some(40.0)),
            };
            let sq = ab.alpha * ab.alpha + ab.beta * ab.beta;
            black_box(supervision_part(
                &mut sup,
                black_box(&checks),
                black_box(sq),
            ));
        }),
    );
    let mut model = ModelCheck::new(
        cfg.current.motor,
        cfg.current.ts_s,
        cfg.supervisor.model,
        false,
    );
    let period = |k: u32| {
        let i = currents(k);
        let ab = transforms::clarke(i);
        let th = rotor(k).to_electrical(cfg.angle.pole_pairs);
        let (s, c) = foc_core::trig::sin_cos(th);
        Period {
            i_ab_a: ab,
            i_dq_a: transforms::park(ab, s, c),
            sin_cos: (s, c),
            theta_e: th,
            omega_spread_rad_s: 0.0,
            omega_e_rad_s: 150.0 * cfg.angle.pole_pairs as f32,
            unchanged_periods: 0,
        }
    };
    for k in 0..4 {
        model.record(&period(k), [0.5; 3], 24.0);
    }
    let next = core::cell::Cell::new(period(4));
    add(
        "  part: model check (ModelCheck::check + record)",
        measure(baseline, n, &mut |k| next.set(period(4 + k)), &mut |_| {
            let p = black_box(next.get());
            black_box(model_part(&mut model, &p));
        }),
    );
    // Two channels frozen (the repeat path, the longer one), one turning.
    let mut frozen = ModelCheck::new(
        cfg.current.motor,
        cfg.current.ts_s,
        cfg.supervisor.model,
        false,
    );
    let readings = |k: u32| {
        let p = period(k);
        Readings {
            channels_a: [Some(p.i_ab_a.alpha), Some(1.5), Some(-1.0)],
            i_dq_a: p.i_dq_a,
            i_ref_a: Dq::new(0.0, 2.0),
            sin_cos: p.sin_cos,
            voltage_limited: false,
        }
    };
    let next = core::cell::Cell::new(readings(0));
    add(
        "  part: frozen-channel check (ModelCheck::frozen_channel)",
        measure(baseline, n, &mut |k| next.set(readings(1 + k)), &mut |_| {
            let r = black_box(next.get());
            black_box(frozen_part(&mut frozen, &r));
        }),
    );
    let mut observer = FluxObserver::new(ObserverConfig {
        motor: cfg.current.motor,
        ts_s: cfg.current.ts_s,
        dead_time_s: cfg.supervisor.model.dead_time_s,
        current_floor_a: cfg.supervisor.model.floor_a,
    });
    for k in 0..4 {
        black_box(observer_part(&mut observer, period(k).i_ab_a));
    }
    let next = core::cell::Cell::new(period(4));
    add(
        "  part: flux observer (FluxObserver::update + record)",
        measure(baseline, n, &mut |k| next.set(period(4 + k)), &mut |_| {
            let p = black_box(next.get());
            black_box(observer_part(&mut observer, p.i_ab_a));
        }),
    );
    // The injection (design §28) needs a salient motor: this board's with
    // Lq = 1.5 Ld. Not on the sensor path: reported, not added to the sum.
    let salient = foc_core::control::MotorParams {
        lq_h: 1.5 * cfg.current.motor.ld_h,
        ..cfg.current.motor
    };
    if let Some(hc) = HfiConfig::for_motor(&salient, cfg.current.ts_s, 5.0, 2e5, 24.0) {
        let mut hfi = Hfi::new(hc);
        for k in 0..4 {
            black_box(hfi_part(&mut hfi, period(k).i_ab_a));
        }
        let next = core::cell::Cell::new(period(4));
        report(
            "  part: injection (Hfi::update + inject_v)",
            measure(baseline, n, &mut |k| next.set(period(4 + k)), &mut |_| {
                let p = black_box(next.get());
                black_box(hfi_part(&mut hfi, p.i_ab_a));
            }),
        );
    }
    if let Some(p) = cfg.power {
        let mut power = PowerLimiter::new(p);
        let mut report = PowerReport::unlimited(0.0);
        add(
            "  part: power limits (PowerLimiter::step_into)",
            measure(baseline, n, &mut |_| {}, &mut |k| {
                power_part(
                    &mut power,
                    black_box(Dq::new(0.0, 2.0 + k as f32 * 0.01)),
                    black_box(Dq::new(-0.5, 6.0)),
                    cfg.current.ts_s,
                    PowerInputs {
                        v_bus_v: black_box(Some(24.0)),
                        omega_e_rad_s: black_box(1050.0),
                        i_d_a: 0.0,
                        iq_request_a: black_box(2.0),
                        current_limit_a: 10.0,
                        winding_temperature_c: None,
                        stage_temperature_c: black_box(Some(40.0)),
                    },
                    black_box(&mut report),
                );
            }),
        );
    }
    let mut cl = CurrentLoop::new(cfg.current);
    add(
        "  part: current math and SVPWM (CurrentLoop::step)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            black_box(current_part(
                &mut cl,
                black_box(&CurrentLoopInput {
                    i_abc_a: currents(k),
                    theta_e: ElectricalAngle::from_bits(k.wrapping_mul(0x0C00_0000)),
                    omega_e_rad_s: 1050.0,
                    v_bus_v: 24.0,
                    i_dq_ref_a: Dq::new(0.0, 2.0),
                }),
            ));
        }),
    );
    add(
        "  part: PWM write (emulated board, io::apply)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let x = 0.3 + 0.001 * k as f32;
            let _ = black_box(pwm_part(&mut d.pwm, black_box([x, 0.5, 0.7 - x])));
        }),
    );
    // What a copy of the whole feedback would cost: reported, not in the
    // sum (the period writes the feedback in place, it copies nothing).
    let src = rig.published;
    let mut dst = Feedback::INIT;
    report(
        "  part: publishing the whole Feedback by copy (not done any more)",
        measure(baseline, n, &mut |_| {}, &mut |_| {
            copy_part(black_box(&mut dst), black_box(&src));
        }),
    );
    black_box(dst);
    (sum, io)
}

// Each part is called through a function of its own, never inlined into
// the measuring closure, so that its count depends on the library code
// only, not on how the bench's own code is optimised around it.

#[inline(never)]
fn read_part(d: &mut BoardDrive) -> Sample {
    io::read_sample(&mut d.currents, &mut d.angle, &mut d.bus)
}

#[inline(never)]
fn estimators_part(
    t: &mut AngleTracker,
    o: &mut SpeedObserver,
    th: MechanicalAngle,
    iq_a: f32,
) -> f32 {
    let innovation = t.update(th);
    o.update(th, iq_a);
    innovation
}

#[inline(never)]
fn supervision_part(sup: &mut Supervisor, checks: &Checks, sq: f32) -> Option<Fault> {
    sup.check_vector_sq(checks, sq)
}

#[inline(never)]
fn model_part(m: &mut ModelCheck, p: &Period) -> Verdict {
    let v = m.check(p);
    m.record(p, [0.52, 0.49, 0.49], 24.0);
    v
}

#[inline(never)]
fn observer_part(o: &mut FluxObserver, i_ab: foc_core::frames::AlphaBeta) -> (u32, f32) {
    let o = black_box(o);
    o.update(i_ab);
    o.record([0.52, 0.49, 0.49], 24.0);
    (o.angle().to_bits(), o.speed_rad_s())
}

#[inline(never)]
fn hfi_part(h: &mut Hfi, i_ab: foc_core::frames::AlphaBeta) -> (u32, f32) {
    let h = black_box(h);
    h.update(i_ab);
    (h.angle().to_bits(), h.inject_v())
}

#[inline(never)]
fn frozen_part(m: &mut ModelCheck, r: &Readings) -> bool {
    m.frozen_channel(r)
}

#[inline(never)]
fn power_part(
    p: &mut PowerLimiter,
    i: Dq,
    v: Dq,
    ts: f32,
    inputs: PowerInputs,
    r: &mut PowerReport,
) {
    p.step_into(i, v, ts, inputs, r)
}

#[inline(never)]
fn current_part(cl: &mut CurrentLoop, inp: &CurrentLoopInput) -> CurrentLoopOutput {
    cl.step(inp)
}

#[inline(never)]
fn pwm_part(pwm: &mut board_support::board::Pwm, duties: [f32; 3]) -> Result<(), Fault> {
    io::apply(pwm, BridgeCommand::Duties(duties))
}

#[inline(never)]
fn copy_part(dst: &mut Feedback, src: &Feedback) {
    *dst = *src;
}
