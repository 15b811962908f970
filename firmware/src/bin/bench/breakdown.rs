//! The pieces of one period, each measured alone on inputs like the
//! drive's (the stage's configuration, a rotor turning at 150 rad/s):
//! what the per-period call is made of. The pieces are the functions the
//! stage calls; their sum is less than the whole, the rest is the stage's
//! own logic (mode, limits, interpolation, timeout) and the calls between.

use super::{measure, report, Stats};
use crate::drive::{cascade, Rig};
use core::hint::black_box;
use foc_core::angle::{ElectricalAngle, MechanicalAngle};
use foc_core::control::current::{CurrentLoop, CurrentLoopInput};
use foc_core::control::estimator::{AngleTracker, SpeedObserver};
use foc_core::control::power::{PowerInputs, PowerStage};
use foc_core::control::supervisor::{Checks, Supervisor};
use foc_core::control::{drive, BridgeCommand, Feedback};
use foc_core::frames::{Abc, Dq};
use foc_core::transforms;

/// Rotor angle at step `k` while turning at 150 rad/s (mechanical).
fn rotor(k: u32) -> MechanicalAngle {
    MechanicalAngle::from_radians(150.0 * 50e-6 * k as f32)
}

/// Measures and reports the pieces; returns their sum (max column).
pub fn measure_pieces(rig: &mut Rig, baseline: u32, currents: &dyn Fn(u32) -> Abc) -> u32 {
    let cfg = cascade().current;
    let n = 64;
    let mut sum = 0u32;
    let mut add = |name: &str, s: Stats| {
        report(name, s);
        sum += s.max;
    };
    let d = rig.drive_mut();
    add(
        "  part: sensor reads (emulated board, drive::read_sample)",
        measure(
            baseline,
            n,
            &mut |_| board_support::board::sim::step_physics(),
            &mut |_| {
                black_box(drive::read_sample(
                    &mut d.currents,
                    &mut d.angle,
                    &mut d.bus,
                ));
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
            black_box(tracker.update(th));
            observer.update(th, black_box(1.0));
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
            black_box(sup.check_vector_sq(black_box(&checks), sq));
        }),
    );
    if let Some(p) = cfg.power {
        let mut power = PowerStage::new(p);
        add(
            "  part: power limits (PowerStage::step)",
            measure(baseline, n, &mut |_| {}, &mut |k| {
                black_box(power.step(
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
                ));
            }),
        );
    }
    let mut cl = CurrentLoop::new(cfg.current);
    add(
        "  part: current math and SVPWM (CurrentLoop::step)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            black_box(cl.step(black_box(&CurrentLoopInput {
                i_abc_a: currents(k),
                theta_e: ElectricalAngle::from_bits(k.wrapping_mul(0x0C00_0000)),
                omega_e_rad_s: 1050.0,
                v_bus_v: 24.0,
                i_dq_ref_a: Dq::new(0.0, 2.0),
            })));
        }),
    );
    add(
        "  part: PWM write (emulated board, drive::apply)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let x = 0.3 + 0.001 * k as f32;
            let _ = black_box(drive::apply(
                &mut d.pwm,
                BridgeCommand::Duties([x, 0.5, 0.7 - x]),
            ));
        }),
    );
    let src = rig.published;
    let mut dst = Feedback::INIT;
    add(
        "  part: publishing the whole Feedback (one copy)",
        measure(baseline, n, &mut |_| {}, &mut |_| {
            *black_box(&mut dst) = *black_box(&src);
        }),
    );
    black_box(dst);
    sum
}
