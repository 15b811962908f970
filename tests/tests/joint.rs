//! Robot-joint features on the bench (design §21, issue 20): the impedance
//! mode's stiffness and damping measured on the plant, a feed-forward
//! torque holding a load, 1 kHz impedance commands through a 20:1 gear,
//! homing to an end stop from either side, travel limits against a
//! commanded overrun, and bad input refused. Every motor file of
//! `tests/motors/` runs every test; each prints its figures.
//!
//! Measured on the plant, not on the drive's own signals: the motor's
//! torque is the plant's electromagnetic torque from its true currents,
//! positions and velocities are the plant's true ones.

// The plant's `Real` is f64 or f32 by feature: a cast to f64 is a no-op in
// one of the two.
#![allow(clippy::unnecessary_cast)]

use foc_bench::metrics;
use foc_bench::mission::{Setup, Sim};
use foc_core::control::homing::{EndStop, HomingError, HomingMethod};
use foc_core::control::joint::{Impedance, JointError, OutputFrame};
use foc_core::control::{BridgeCommand, Command, CommandError, Fault, Mode};
use std::f64::consts::TAU;
use std::path::PathBuf;

fn motor_files() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("motors");
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    v
}

fn setups() -> Vec<Setup> {
    motor_files()
        .iter()
        .map(|p| Setup::load(p).unwrap())
        .collect()
}

/// Largest torque the current limit gives [N m, rotor].
fn torque_max(s: &Setup) -> f32 {
    s.kt() * s.max_current_a
}

/// One encoder count \[rad\].
fn count_rad(s: &Setup) -> f32 {
    std::f32::consts::TAU / s.bench.sensors.encoder_counts_per_rev as f32
}

/// Stiffness and damping for a motor (rotor frame): 30 % of the torque
/// limit deflects the rotor by 0.25 rad or 40 counts (whichever is more),
/// and the damping ratio with the rotor's inertia is 0.7.
fn gains(s: &Setup) -> (f32, f32) {
    let deflection = (0.25f32).max(40.0 * count_rad(s));
    let kp = 0.3 * torque_max(s) / deflection;
    let j = s.motor.inertia_kg_m2 as f32;
    (kp, 2.0 * 0.7 * (kp * j).sqrt())
}

/// The homing back-off: 0.5 rad or 20 counts, whichever is more.
fn backoff(s: &Setup) -> f32 {
    (0.5f32).max(20.0 * count_rad(s))
}

fn periods(s: &Setup, seconds: f64) -> usize {
    (seconds * s.bench.pwm_frequency_hz as f64).round() as usize
}

fn impedance(p: f32, v: f32, kp: f32, kd: f32, ff: f32) -> Command {
    Command::Impedance(Impedance {
        position_rad: p,
        velocity_rad_s: v,
        kp_nm_per_rad: kp,
        kd_nm_s_per_rad: kd,
        torque_ff_nm: ff,
        torque_limit_nm: f32::INFINITY,
    })
}

/// A calibrated drive on the bench, settled for 20 ms in torque mode at 0 A.
fn joint_sim(s: &Setup) -> Sim {
    let mut sim = Sim::new_calibrated(s, s.cascade_config(), false);
    sim.cascade.command(Command::Torque { iq_a: 0.0 }).unwrap();
    sim.run(periods(s, 0.02));
    sim
}

/// The drive's position minus the plant's true one \[rad\] (the encoder's
/// frame and the first reading's turn; constant up to the resolution).
fn frame_offset(sim: &Sim) -> f64 {
    sim.cascade.feedback().position_rad as f64 - sim.true_position_rad()
}

/// Mean motor torque [N m] and true position \[rad\] over `n` periods.
fn mean_torque_and_position(sim: &mut Sim, n: usize) -> (f64, f64) {
    let (mut t, mut p) = (0.0, 0.0);
    for _ in 0..n {
        sim.step();
        t += sim.plant.torque_nm() as f64;
        p += sim.true_position_rad();
    }
    (t / n as f64, p / n as f64)
}

/// Stiffness from two load steps, and stiffness and damping from a
/// sinusoidal load at the spring's natural frequency, both as the motor's
/// torque against the true position and velocity.
#[test]
fn stiffness_within_5_percent_and_damping_within_10_percent_on_every_motor() {
    println!("motor | kp set | kp steps | kp sine | kd set | kd sine");
    for s in setups() {
        let (kp, kd) = gains(&s);
        let mut sim = joint_sim(&s);
        let p0 = sim.cascade.feedback().position_rad;
        sim.cascade
            .command(impedance(p0, 0.0, kp, kd, 0.0))
            .unwrap();
        sim.run(periods(&s, 0.2));
        // Small steps: +-30 % of the torque limit as a load.
        let load = 0.3 * torque_max(&s);
        let step = |sim: &mut Sim, l: f32| {
            sim.load_nm = l;
            sim.run(periods(&s, 0.5));
            mean_torque_and_position(sim, periods(&s, 0.1))
        };
        let (t1, x1) = step(&mut sim, load);
        let (t2, x2) = step(&mut sim, -load);
        let kp_steps = (t1 - t2) / (x2 - x1);
        // A sinusoidal load at a fifth of the natural frequency (the
        // damping's velocity is the 80 Hz angle tracker's, which lags by
        // about 6 degrees there), 4 cycles settling, 4 measured.
        let wn = (kp as f64 / s.motor.inertia_kg_m2 as f64).sqrt() / 5.0;
        let n_cycle = periods(&s, TAU / wn);
        let ts = 1.0 / s.bench.pwm_frequency_hz as f64;
        let (mut xs, mut vs, mut ts_nm) = (vec![], vec![], vec![]);
        for k in 0..8 * n_cycle {
            sim.load_nm = load * (wn * k as f64 * ts).sin() as f32;
            sim.step();
            if k >= 4 * n_cycle {
                xs.push(sim.true_position_rad());
                vs.push(sim.plant.omega_m_rad_s() as f64);
                ts_nm.push(sim.plant.torque_nm() as f64);
            }
        }
        let (b, c) = metrics::fit_two(&xs, &vs, &ts_nm);
        let (kp_sine, kd_sine) = (-b, -c);
        println!(
            "{} | {kp:.4} | {kp_steps:.4} | {kp_sine:.4} | {kd:.3e} | {kd_sine:.3e}",
            s.name
        );
        let fb = sim.cascade.feedback();
        assert_eq!(fb.mode, Mode::Impedance, "{}: {:?}", s.name, fb.first_fault);
        let rel = |m: f64, set: f32| (m / set as f64 - 1.0).abs();
        assert!(
            rel(kp_steps, kp) < 0.05,
            "{}: kp {kp_steps} vs {kp}",
            s.name
        );
        assert!(rel(kp_sine, kp) < 0.05, "{}: kp {kp_sine} vs {kp}", s.name);
        assert!(rel(kd_sine, kd) < 0.10, "{}: kd {kd_sine} vs {kd}", s.name);
    }
}

/// kp = kd = 0 with the feed-forward torque equal to a constant load: the
/// rotor stays (drift under 0.05 rad or 2 counts in 1 s); the same load
/// without the feed-forward moves it more than ten times as far. The drive
/// holds the load in torque mode first (the switch blends from that
/// current: bumpless).
#[test]
fn feed_forward_torque_alone_holds_a_constant_load() {
    println!("motor | load [N m] | drift with T_ff [rad] | drift without [rad]");
    for s in setups() {
        let load = 0.3 * torque_max(&s);
        let drift = |ff: f32| {
            let mut sim = joint_sim(&s);
            sim.cascade
                .command(Command::Torque {
                    iq_a: load / s.kt(),
                })
                .unwrap();
            sim.load_nm = load;
            sim.run(periods(&s, 0.05));
            let p0 = sim.cascade.feedback().position_rad;
            sim.cascade
                .command(impedance(p0, 0.0, 0.0, 0.0, ff))
                .unwrap();
            let x0 = sim.true_position_rad();
            let mut worst = 0.0f64;
            for _ in 0..periods(&s, 1.0) {
                sim.step();
                worst = worst.max((sim.true_position_rad() - x0).abs());
                if sim.cascade.feedback().mode != Mode::Impedance {
                    break;
                }
            }
            worst
        };
        let (held, free) = (drift(load), drift(0.0));
        let bound = (0.05f64).max(2.0 * count_rad(&s) as f64);
        println!("{} | {load:.3} | {held:.4} | {free:.2}", s.name);
        assert!(held < bound, "{}: drift {held} rad", s.name);
        assert!(
            free > 10.0 * bound,
            "{}: without T_ff only {free} rad",
            s.name
        );
    }
}

/// A host sends impedance commands at 1 kHz in the output frame of a
/// 20:1 gear: `p = A (1 - cos wt)` with its velocity and the inertia's
/// feed-forward torque, A = 0.5 rad at the output (10 rad at the rotor),
/// w for a rotor speed of at most 30 % of the motor's highest and an
/// acceleration of at most 30 % of what the current limit gives, and at
/// most 2 Hz. The output follows
/// within 0.01 rad (or 2 counts at the output) at every period after the
/// first 0.1 s, plus the error the motor's Coulomb friction leaves against
/// the stiffness (`Fc / kp` at the rotor, `/ g` at the output: 26 mrad on
/// the geared hub motor with its 48-count sensor and soft gains, under
/// 0.3 mrad on the others).
#[test]
fn commands_at_1_khz_through_a_20_to_1_gear_track_a_sinusoid() {
    println!("motor | w [rad/s] | max error [mrad, output] | rms [mrad]");
    let g = 20.0f32;
    for s in setups() {
        let (kp, kd) = gains(&s);
        let mut sim = joint_sim(&s);
        let p0 = sim.cascade.feedback().position_rad;
        let frame = OutputFrame::new(g, p0).unwrap();
        let off = frame_offset(&sim);
        let a_out = 0.5f64;
        let v_max = 0.3 * s.max_speed_rad_s().min(s.max_mission_speed_rad_s()) as f64;
        let a_rotor = a_out * g as f64;
        let acc_max = 0.3 * torque_max(&s) as f64 / s.motor.inertia_kg_m2 as f64;
        let w = (v_max / a_rotor)
            .min((acc_max / a_rotor).sqrt())
            .min(TAU * 2.0);
        let j_out = s.motor.inertia_kg_m2 as f64 * (g as f64).powi(2);
        let every = periods(&s, 1e-3);
        let ts = 1.0 / s.bench.pwm_frequency_hz as f64;
        let n = periods(&s, (TAU / w).min(3.0));
        let (mut worst, mut sq, mut m) = (0.0f64, 0.0f64, 0usize);
        for k in 0..n {
            let t = k as f64 * ts;
            if k % every == 0 {
                let out = Impedance {
                    position_rad: (a_out * (1.0 - (w * t).cos())) as f32,
                    velocity_rad_s: (a_out * w * (w * t).sin()) as f32,
                    kp_nm_per_rad: frame.stiffness_to_output(kp),
                    kd_nm_s_per_rad: frame.stiffness_to_output(kd),
                    torque_ff_nm: (j_out * a_out * w * w * (w * t).cos()) as f32,
                    torque_limit_nm: f32::INFINITY,
                };
                let rotor = frame.impedance_to_rotor(&out);
                sim.cascade.command(Command::Impedance(rotor)).unwrap();
            }
            sim.step();
            if t >= 0.1 {
                let truth = frame.position_to_output((sim.true_position_rad() + off) as f32);
                // The reference at the end of this period.
                let r = a_out * (1.0 - (w * (t + ts)).cos());
                let e = truth as f64 - r;
                worst = worst.max(e.abs());
                sq += e * e;
                m += 1;
            }
        }
        let rms = (sq / m as f64).sqrt();
        println!(
            "{} | {w:.2} | {:.3} | {:.3}",
            s.name,
            1e3 * worst,
            1e3 * rms
        );
        let fb = sim.cascade.feedback();
        assert_eq!(fb.mode, Mode::Impedance, "{}: {:?}", s.name, fb.first_fault);
        let friction = s.motor.coulomb_friction_nm as f64 / (kp as f64 * g as f64);
        let bound = (0.01f64).max(2.0 * count_rad(&s) as f64 / g as f64) + friction;
        assert!(worst < bound, "{}: error {worst} rad", s.name);
    }
}

/// A stiff end stop on the plant (a spring of 20 x the torque limit per
/// radian with critical damping) 3 rad from the start, above and below:
/// homing finds it within its deflection under the homing current plus
/// two counts, and never asks for more than the homing current.
#[test]
fn homing_finds_an_end_stop_from_either_side_within_the_homing_current() {
    println!(
        "motor | side | stop [rad] | found [rad] | error [mrad] | peak iq ref [A] | I_home [A]"
    );
    for s in setups() {
        for dir in [1.0f32, -1.0] {
            let mut sim = joint_sim(&s);
            let off = frame_offset(&sim);
            let stop_true = sim.true_position_rad() + 3.0 * dir as f64;
            let k_stop = 20.0 * torque_max(&s) as f64;
            let c_stop = 2.0 * (k_stop * s.motor.inertia_kg_m2 as f64).sqrt();
            let i_home = 0.3 * s.max_current_a;
            let e = EndStop {
                velocity_rad_s: 2.0 * dir,
                current_a: i_home,
                detect_fraction: 0.7,
                confirm_s: 0.02,
                // The search's and back-off's spring gives the homing
                // current over this distance: 20 counts at least, or on a
                // coarse sensor it limit-cycles across the count edges.
                backoff_rad: backoff(&s),
                max_travel_rad: 10.0,
            };
            sim.cascade
                .start_homing(HomingMethod::EndStop(e), 0.0)
                .unwrap();
            let mut peak = 0.0f32;
            for _ in 0..periods(&s, 8.0) {
                let x = sim.true_position_rad();
                let pen = (x - stop_true) * dir as f64;
                sim.load_nm = if pen > 0.0 {
                    (k_stop * (x - stop_true) + c_stop * sim.plant.omega_m_rad_s() as f64) as f32
                } else {
                    0.0
                };
                sim.step();
                peak = peak.max(sim.cascade.feedback().i_dq_ref_a.q.abs());
                if !sim.cascade.is_homing() {
                    break;
                }
            }
            assert_eq!(sim.cascade.homing_result(), Some(Ok(())), "{}", s.name);
            let frame = sim.cascade.joint().frame;
            let found = frame.rotor_at_zero_rad() as f64 - off;
            let tol = torque_max(&s) as f64 * 0.3 / k_stop + 2.0 * count_rad(&s) as f64;
            println!(
                "{} | {dir:+} | {stop_true:.4} | {found:.4} | {:.2} | {peak:.3} | {i_home:.3}",
                s.name,
                1e3 * (found - stop_true)
            );
            assert!(
                (found - stop_true).abs() < tol,
                "{}: {found} vs {stop_true}",
                s.name
            );
            assert!(peak <= i_home * 1.0001, "{}: {peak} A", s.name);
            // Holding after the back-off (gear 1:1, home at the stop).
            let fb = *sim.cascade.feedback();
            assert_eq!(fb.mode, Mode::Impedance, "{}", s.name);
            let out = frame.position_to_output(fb.position_rad);
            let b = backoff(&s);
            assert!(
                (out + b * dir).abs() < 0.1 * b + count_rad(&s),
                "{}: held at {out}",
                s.name
            );
        }
    }
}

/// Travel limits of +-1 rad at the output of a 20:1 gear (+-20 rad at the
/// rotor): a velocity command towards the upper end at 40 % of the motor's
/// highest speed and a torque command towards the lower end at half the
/// current limit both stop at the end, inside the fault margin, without a
/// fault; an impedance target beyond the range is refused; a load above
/// the torque limit that pushes the rotor past the margin trips
/// `TravelLimit`.
#[test]
fn travel_limits_hold_against_a_commanded_overrun() {
    println!("motor | highest [rad, output] | lowest [rad, output] | margin [rad, output]");
    for s in setups() {
        let mut sim = joint_sim(&s);
        let p0 = sim.cascade.feedback().position_rad;
        let mut setup = *sim.cascade.joint();
        setup.frame = OutputFrame::new(20.0, p0).unwrap();
        setup.travel_out_rad = Some((-1.0, 1.0));
        sim.cascade.set_joint(setup).unwrap();
        sim.run(1);
        assert_eq!(sim.cascade.last_output().unwrap().change, Some(Ok(())));
        let margin_out = setup.travel.fault_margin_rad / 20.0;
        let f = setup.frame;
        let speed = 0.4 * s.max_speed_rad_s().min(s.max_mission_speed_rad_s());
        sim.cascade
            .command(Command::Velocity { rad_s: speed })
            .unwrap();
        let mut hi = f32::MIN;
        for _ in 0..periods(&s, 1.0 + 25.0 / speed as f64) {
            sim.step();
            hi = hi.max(f.position_to_output(sim.cascade.feedback().position_rad));
        }
        let end_hi = f.position_to_output(sim.cascade.feedback().position_rad);
        sim.cascade
            .command(Command::Torque {
                iq_a: -0.5 * s.max_current_a,
            })
            .unwrap();
        let mut lo = f32::MAX;
        for _ in 0..periods(&s, 2.0) {
            sim.step();
            lo = lo.min(f.position_to_output(sim.cascade.feedback().position_rad));
        }
        let end_lo = f.position_to_output(sim.cascade.feedback().position_rad);
        println!("{} | {hi:.4} | {lo:.4} | {margin_out:.4}", s.name);
        let fb = *sim.cascade.feedback();
        assert!(fb.first_fault.is_none(), "{}: {:?}", s.name, fb.first_fault);
        assert!(
            hi <= 1.0 + margin_out && lo >= -1.0 - margin_out,
            "{}",
            s.name
        );
        assert!(end_hi > 0.95, "{}: stopped at {end_hi}", s.name);
        assert!(end_lo < -0.95, "{}: stopped at {end_lo}", s.name);
        // An impedance target beyond the range: refused.
        let beyond = f.position_to_rotor(1.2);
        assert_eq!(
            sim.cascade.command(impedance(beyond, 0.0, 0.0, 0.0, 0.0)),
            Err(CommandError::PositionOutOfRange)
        );
        // Pushed past the margin by a load the current limit cannot hold
        // (towards the lower end, where the rotor rests): the fault,
        // bridge off.
        sim.load_nm = 1.2 * torque_max(&s);
        for _ in 0..periods(&s, 2.0) {
            sim.step();
            if sim.cascade.feedback().first_fault.is_some() {
                break;
            }
        }
        let fb = *sim.cascade.feedback();
        assert_eq!(fb.first_fault, Some(Fault::TravelLimit), "{}", s.name);
        sim.step();
        assert_eq!(sim.last_bridge(), BridgeCommand::SafeState, "{}", s.name);
    }
}

/// NaN, negative or too large gains, a bad gear ratio, a travel range out
/// of order and homing settings out of range: refused with their error,
/// and the drive keeps what it had.
#[test]
fn bad_joint_input_is_refused_and_changes_nothing() {
    let s = &setups()[0];
    let mut sim = joint_sim(s);
    let p0 = sim.cascade.feedback().position_rad;
    let (kp, kd) = gains(s);
    let good = impedance(p0, 0.0, kp, kd, 0.0);
    sim.cascade.command(good).unwrap();
    sim.run(10);
    let l = sim.cascade.current.config().limits;
    let Command::Impedance(g) = good else {
        unreachable!()
    };
    let bad: [(Impedance, CommandError); 7] = [
        (
            Impedance {
                kp_nm_per_rad: f32::NAN,
                ..g
            },
            CommandError::NonFinite,
        ),
        (
            Impedance {
                position_rad: f32::NAN,
                ..g
            },
            CommandError::NonFinite,
        ),
        (
            Impedance {
                torque_ff_nm: f32::INFINITY,
                ..g
            },
            CommandError::NonFinite,
        ),
        (
            Impedance {
                kp_nm_per_rad: -1.0,
                ..g
            },
            CommandError::StiffnessOutOfRange,
        ),
        (
            Impedance {
                kd_nm_s_per_rad: -1e-6,
                ..g
            },
            CommandError::DampingOutOfRange,
        ),
        (
            Impedance {
                kd_nm_s_per_rad: 2.0 * l.max_kd_nm_s_per_rad,
                ..g
            },
            CommandError::DampingOutOfRange,
        ),
        (
            Impedance {
                torque_limit_nm: -0.5,
                ..g
            },
            CommandError::CurrentOutOfRange,
        ),
    ];
    for (c, e) in bad {
        assert_eq!(sim.cascade.command(Command::Impedance(c)), Err(e), "{c:?}");
    }
    let joint = *sim.cascade.joint();
    let mut wrong = joint;
    wrong.travel_out_rad = Some((1.0, -1.0));
    assert_eq!(sim.cascade.set_joint(wrong), Err(JointError::Travel));
    assert_eq!(OutputFrame::new(0.0, 0.0), None);
    assert_eq!(OutputFrame::new(f32::NAN, 0.0), None);
    assert_eq!(OutputFrame::new(20.0, f32::INFINITY), None);
    let e = EndStop {
        velocity_rad_s: f32::NAN,
        current_a: 1.0,
        detect_fraction: 0.7,
        confirm_s: 0.02,
        backoff_rad: 0.5,
        max_travel_rad: 10.0,
    };
    assert_eq!(
        sim.cascade.start_homing(HomingMethod::EndStop(e), 0.0),
        Err(HomingError::Invalid(CommandError::NonFinite))
    );
    let too_much = EndStop {
        velocity_rad_s: 2.0,
        current_a: 2.0 * s.max_current_a,
        ..e
    };
    assert_eq!(
        sim.cascade
            .start_homing(HomingMethod::EndStop(too_much), 0.0),
        Err(HomingError::Invalid(CommandError::CurrentOutOfRange))
    );
    sim.run(10);
    assert_eq!(sim.cascade.feedback().active, good);
    assert_eq!(*sim.cascade.joint(), joint);
    assert!(!sim.cascade.is_homing());
}

/// Entering impedance mode from velocity mode at speed (the set-point at
/// the rotor's position and velocity) and leaving it for velocity mode
/// again: the q-current reference moves by at most 5 % of the current
/// limit per period. The command timeout in impedance mode: damping only
/// (kp = 0) first, then the bridge off with `CommandTimeout`.
#[test]
fn impedance_entry_and_exit_are_bumpless_and_a_timeout_damps_then_disables() {
    println!("motor | largest step of iq ref entering / leaving [A] | limit [A]");
    for s in setups() {
        let (kp, kd) = gains(&s);
        let mut cfg = s.cascade_config();
        let timeout = periods(&s, 0.05) as u32;
        cfg.current.command_timeout_periods = timeout;
        let mut sim = Sim::new_calibrated(&s, cfg, false);
        let w = 0.2 * s.max_speed_rad_s().min(s.max_mission_speed_rad_s());
        // Commands every 10 ms keep the command timeout away.
        for _ in 0..30 {
            sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
            sim.run(periods(&s, 0.01));
        }
        let largest_step = |sim: &mut Sim, n: usize| {
            let mut last = sim.cascade.feedback().i_dq_ref_a.q;
            let mut worst = 0.0f32;
            for _ in 0..n {
                sim.step();
                let now = sim.cascade.feedback().i_dq_ref_a.q;
                worst = worst.max((now - last).abs());
                last = now;
            }
            worst
        };
        let fb = *sim.cascade.feedback();
        let hold = Impedance {
            position_rad: fb.position_rad,
            velocity_rad_s: w,
            kp_nm_per_rad: kp,
            kd_nm_s_per_rad: kd,
            torque_ff_nm: 0.0,
            torque_limit_nm: f32::INFINITY,
        };
        sim.cascade.command(Command::Impedance(hold)).unwrap();
        let entering = largest_step(&mut sim, periods(&s, 0.03));
        sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
        let leaving = largest_step(&mut sim, periods(&s, 0.03));
        println!(
            "{} | {entering:.3} / {leaving:.3} | {}",
            s.name, s.max_current_a
        );
        assert!(entering <= 0.05 * s.max_current_a, "{}: {entering}", s.name);
        assert!(leaving <= 0.05 * s.max_current_a, "{}: {leaving}", s.name);
        // Timeout: no new command.
        sim.cascade.command(Command::Impedance(hold)).unwrap();
        sim.run(timeout as usize + 3);
        match sim.cascade.feedback().active {
            Command::Impedance(i) => {
                assert_eq!(i.kp_nm_per_rad, 0.0);
                assert_eq!(i.kd_nm_s_per_rad, kd);
                assert_eq!(i.torque_ff_nm, 0.0);
            }
            a => panic!("{}: {a:?}", s.name),
        }
        sim.run(timeout as usize + 3);
        let fb = sim.cascade.feedback();
        assert_eq!(fb.first_fault, Some(Fault::CommandTimeout), "{}", s.name);
        assert_eq!(sim.last_bridge(), BridgeCommand::SafeState);
    }
}
