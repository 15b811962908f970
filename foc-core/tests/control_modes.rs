//! The cascade against a simple PMSM plant: every mode, bumpless
//! transfers, faults and the safe state, and no panic for any input.
//!
//! The plant here is deliberately minimal (ideal inverter, Euler steps,
//! no noise); the full bench with dead time, quantisation and noise lives in
//! the `foc-bench` crate. Its abc<->dq projection is written with
//! `cos(theta - 2pi/3)` sums, independently of `foc_core::transforms`.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use core::f32::consts::{PI, TAU};
use foc_core::angle::{ElectricalAngle, MechanicalAngle};
use foc_core::calibration::Calibrated;
use foc_core::control::stage::{CurrentStage, Sample, TimeoutReaction};
use foc_core::control::{
    BridgeCommand, Command, CommandError, CommandSlot, Fault, Mode, MotorParams,
};
use foc_core::drive::cascade::{Cascade, CascadeConfig};
use foc_core::frames::Abc;
use foc_core::hal::PhaseCurrents;
use proptest::prelude::*;

const PWM_HZ: f32 = 20_000.0;
const V_BUS: f32 = 24.0;

fn motor() -> MotorParams {
    MotorParams {
        pole_pairs: 7,
        r_ohm: 0.5,
        ld_h: 400e-6,
        lq_h: 400e-6,
        flux_linkage_wb: 0.01,
    }
}

struct Plant {
    id: f32,
    iq: f32,
    w_m: f32,
    th_m: f32, // unwrapped [rad]
    j: f32,
    b: f32,
    load_nm: f32,
    duties: [f32; 3], // applied during the current period
    enabled: bool,
}

impl Plant {
    fn new(th_m: f32) -> Self {
        Self {
            id: 0.0,
            iq: 0.0,
            w_m: 0.0,
            th_m,
            j: 2e-5,
            b: 1e-5,
            load_nm: 0.0,
            duties: [0.5; 3],
            enabled: false,
        }
    }

    fn sample(&self) -> Sample {
        let m = motor();
        let th = m.pole_pairs as f32 * self.th_m;
        let ph = |o: f32| self.id * (th - o).cos() - self.iq * (th - o).sin();
        Sample {
            currents: Some(PhaseCurrents::ThreePhase(Abc::new(
                ph(0.0),
                ph(2.0 * PI / 3.0),
                ph(-2.0 * PI / 3.0),
            ))),
            angle: Some(MechanicalAngle::from_radians(self.th_m)),
            v_bus_v: Some(V_BUS),
            temperature_c: None,
        }
    }

    /// Advance one PWM period with the duties latched at its start.
    fn advance(&mut self) {
        let m = motor();
        let p = m.pole_pairs as f32;
        let n = 20;
        let dt = 1.0 / PWM_HZ / n as f32;
        for _ in 0..n {
            let th = p * self.th_m;
            let (vd, vq) = if self.enabled {
                let mean = (self.duties[0] + self.duties[1] + self.duties[2]) / 3.0;
                let offs = [0.0, 2.0 * PI / 3.0, -2.0 * PI / 3.0];
                let mut vd = 0.0;
                let mut vq = 0.0;
                for (d, o) in self.duties.iter().zip(offs) {
                    let v = (d - mean) * V_BUS;
                    vd += v * (th - o).cos();
                    vq -= v * (th - o).sin();
                }
                (vd * 2.0 / 3.0, vq * 2.0 / 3.0)
            } else {
                // Bridge off at low speed: no current path (back-EMF < bus).
                self.id = 0.0;
                self.iq = 0.0;
                (0.0, 0.0)
            };
            let we = p * self.w_m;
            if self.enabled {
                let did = (vd - m.r_ohm * self.id + we * m.lq_h * self.iq) / m.ld_h;
                let diq =
                    (vq - m.r_ohm * self.iq - we * (m.ld_h * self.id + m.flux_linkage_wb)) / m.lq_h;
                self.id += did * dt;
                self.iq += diq * dt;
            }
            let te = 1.5 * p * m.flux_linkage_wb * self.iq;
            let dw = (te - self.b * self.w_m - self.load_nm) / self.j;
            self.w_m += dw * dt;
            self.th_m += self.w_m * dt;
        }
    }

    fn apply(&mut self, b: BridgeCommand) {
        match b {
            BridgeCommand::SafeState => self.enabled = false,
            BridgeCommand::ShortCircuit => {
                self.duties = [0.0; 3];
                self.enabled = true;
            }
            BridgeCommand::Duties(d) => {
                assert!(d.iter().all(|x| (0.0..=1.0).contains(x)), "{d:?}");
                self.duties = d;
                self.enabled = true;
            }
        }
    }
}

fn config() -> CascadeConfig {
    let mut c = CascadeConfig::for_motor_with_inertia(motor(), PWM_HZ, 8.0, 2e-5);
    c.position.max_velocity_rad_s = 60.0;
    c.position.max_acceleration_rad_s2 = 2000.0;
    c
}

/// The plant's sensor reads the rotor's d axis: the configuration's zero
/// offset is exact, supplied as the calibration.
fn permit(c: &CascadeConfig) -> Calibrated {
    Calibrated::supplied(c.current.angle, c.current.current).unwrap()
}

fn calibrated(c: CascadeConfig) -> Cascade {
    let mut cascade = Cascade::new(c);
    cascade.set_calibration(&permit(&c));
    cascade
}

fn cascade() -> Cascade {
    calibrated(config())
}

/// Run `periods` periods; the duties computed from the sample of period k
/// are applied in period k+1 (one-period computation delay).
fn run(c: &mut Cascade, p: &mut Plant, periods: usize, mut each: impl FnMut(&Cascade, &Plant)) {
    for _ in 0..periods {
        let s = p.sample();
        let b = c.step(&s);
        p.advance();
        p.apply(b);
        each(c, p);
    }
}

fn secs(s: f32) -> usize {
    (s * PWM_HZ) as usize
}

#[test]
fn torque_mode_tracks_iq_with_zero_id() {
    let (mut c, mut p) = (cascade(), Plant::new(0.3));
    p.j = 1.0; // locked-ish rotor
    c.command(Command::Torque { iq_a: 2.0 }).unwrap();
    run(&mut c, &mut p, 100, |_, _| {});
    assert!((p.iq - 2.0).abs() < 0.02, "iq = {}", p.iq);
    assert!(p.id.abs() < 0.02, "id = {}", p.id);
    assert_eq!(c.feedback().mode, Mode::Torque);
    // Negative torque too.
    c.command(Command::Torque { iq_a: -3.0 }).unwrap();
    run(&mut c, &mut p, 100, |_, _| {});
    assert!((p.iq + 3.0).abs() < 0.03, "iq = {}", p.iq);
}

#[test]
fn velocity_mode_reaches_target_and_rejects_load() {
    let (mut c, mut p) = (cascade(), Plant::new(1.0));
    c.command(Command::Velocity { rad_s: 150.0 }).unwrap();
    run(&mut c, &mut p, secs(0.3), |_, _| {});
    assert!((p.w_m - 150.0).abs() < 1.5, "w = {}", p.w_m);
    assert!((c.feedback().velocity_rad_s - p.w_m).abs() < 1.0);
    p.load_nm = 0.05;
    run(&mut c, &mut p, secs(0.3), |_, _| {});
    assert!((p.w_m - 150.0).abs() < 1.5, "after load w = {}", p.w_m);
    // Backwards.
    c.command(Command::Velocity { rad_s: -80.0 }).unwrap();
    run(&mut c, &mut p, secs(0.4), |_, _| {});
    assert!((p.w_m + 80.0).abs() < 1.5, "w = {}", p.w_m);
}

#[test]
fn position_mode_moves_and_settles() {
    let (mut c, mut p) = (cascade(), Plant::new(0.2));
    c.command(Command::Position { rad: 0.2 }).unwrap();
    run(&mut c, &mut p, secs(0.05), |_, _| {});
    let start = c.feedback().position_rad;
    let target = start + 12.0;
    c.command(Command::Position { rad: target }).unwrap();
    let mut max_w: f32 = 0.0;
    run(&mut c, &mut p, secs(0.6), |_, p| {
        max_w = max_w.max(p.w_m.abs())
    });
    assert!(
        (c.feedback().position_rad - target).abs() < 0.01,
        "{} vs {target}",
        c.feedback().position_rad
    );
    assert!(p.w_m.abs() < 0.5);
    // The trajectory limited the speed (60 rad/s) with a small margin.
    assert!(max_w < 66.0, "max speed {max_w}");
}

#[test]
fn open_loop_voltage_aligns_rotor() {
    // Rotor 40 electrical degrees off; a d-axis voltage at theta_e = 0 pulls
    // the d axis onto phase A.
    let (mut c, mut p) = (cascade(), Plant::new((40.0f32 / 7.0).to_radians()));
    p.b = 2e-4; // some damping
    c.command(Command::OpenLoop {
        v_d_v: 1.0,
        v_q_v: 0.0,
        theta_e: ElectricalAngle::ZERO,
        omega_e_rad_s: 0.0,
    })
    .unwrap();
    run(&mut c, &mut p, secs(1.0), |_, _| {});
    let th_e = ElectricalAngle::from_radians(7.0 * p.th_m).to_signed_radians();
    assert!(
        th_e.abs().to_degrees() < 1.0,
        "rotor at {} deg(e)",
        th_e.to_degrees()
    );
    assert!((p.id - 1.0 / motor().r_ohm).abs() < 0.05, "id = {}", p.id);
}

#[test]
fn open_loop_rotating_angle_spins_rotor() {
    let (mut c, mut p) = (cascade(), Plant::new(0.0));
    p.b = 2e-4;
    let w_e = 2.0 * TAU * 7.0; // 2 rev/s mechanical
    c.command(Command::OpenLoop {
        v_d_v: 1.5,
        v_q_v: 0.0,
        theta_e: ElectricalAngle::ZERO,
        omega_e_rad_s: w_e,
    })
    .unwrap();
    run(&mut c, &mut p, secs(1.5), |_, _| {});
    assert!((p.w_m - w_e / 7.0).abs() < 0.5, "w = {}", p.w_m);
}

#[test]
fn torque_to_velocity_is_bumpless() {
    let (mut c, mut p) = (cascade(), Plant::new(0.0));
    c.command(Command::Torque { iq_a: 0.5 }).unwrap();
    run(&mut c, &mut p, secs(0.05), |_, _| {});
    let w_now = c.feedback().velocity_rad_s;
    let iq_before = c.feedback().i_dq_ref_a.q;
    c.command(Command::Velocity { rad_s: w_now }).unwrap();
    let mut max_jump: f32 = 0.0;
    let mut prev = iq_before;
    run(&mut c, &mut p, 40, |c, _| {
        let q = c.feedback().i_dq_ref_a.q;
        max_jump = max_jump.max((q - prev).abs());
        prev = q;
    });
    assert!(
        max_jump < 0.1,
        "iq_ref jumped by {max_jump} A at the mode change"
    );
}

#[test]
fn open_loop_to_torque_is_bumpless_in_voltage() {
    let (mut c, mut p) = (cascade(), Plant::new(0.0));
    p.j = 1.0;
    c.command(Command::OpenLoop {
        v_d_v: 0.0,
        v_q_v: 1.0,
        theta_e: ElectricalAngle::ZERO,
        omega_e_rad_s: 0.0,
    })
    .unwrap();
    run(&mut c, &mut p, 200, |_, _| {});
    let v_before = c.feedback().v_dq_v;
    let iq_now = p.iq;
    c.command(Command::Torque { iq_a: iq_now }).unwrap();
    run(&mut c, &mut p, 1, |_, _| {});
    let v_after = c.feedback().v_dq_v;
    assert!(
        (v_after.q - v_before.q).abs() < 0.05 && (v_after.d - v_before.d).abs() < 0.05,
        "{v_before:?} -> {v_after:?}"
    );
}

/// Run to a steady torque-mode state, then corrupt one sample with `bad`.
/// Returns the bridge command for that sample.
fn fault_with(bad: impl Fn(&mut Sample)) -> (Cascade, BridgeCommand) {
    let (mut c, mut p) = (cascade(), Plant::new(0.0));
    p.j = 1.0;
    c.command(Command::Torque { iq_a: 1.0 }).unwrap();
    run(&mut c, &mut p, 50, |_, _| {});
    let mut s = p.sample();
    bad(&mut s);
    let b = c.step(&s);
    (c, b)
}

#[test]
fn each_fault_gives_safe_state_in_the_same_period() {
    type Case = (Fault, fn(&mut Sample));
    let cases: [Case; 10] = [
        (Fault::OverCurrentPhase, |s| {
            s.currents = Some(PhaseCurrents::ThreePhase(Abc::new(13.0, -6.5, -6.5)))
        }),
        (Fault::NonFinite, |s| {
            s.currents = Some(PhaseCurrents::TwoPhase {
                a_a: f32::NAN,
                b_a: 0.0,
            })
        }),
        (Fault::CurrentSenseError, |s| s.currents = None),
        (Fault::AngleSensorError, |s| s.angle = None),
        (Fault::BusSenseError, |s| s.v_bus_v = None),
        (Fault::BusUnderVoltage, |s| s.v_bus_v = Some(5.0)),
        (Fault::BusOverVoltage, |s| s.v_bus_v = Some(40.0)),
        (Fault::CurrentSumMismatch, |s| {
            s.currents = Some(PhaseCurrents::ThreePhase(Abc::new(1.0, 1.0, 0.5)))
        }),
        (Fault::AngleSensorImplausible, |s| {
            let a = s.angle.unwrap();
            s.angle = Some(a.add_radians(1.0))
        }),
        // A slip well under the 0.5 rad mechanical innovation limit, but
        // 0.35 rad electrical at 7 pole pairs.
        (Fault::AngleSensorImplausible, |s| {
            let a = s.angle.unwrap();
            s.angle = Some(a.add_radians(0.05))
        }),
    ];
    for (fault, bad) in cases {
        let (c, b) = fault_with(bad);
        assert_eq!(b, BridgeCommand::SafeState, "{fault:?}");
        assert_eq!(c.feedback().first_fault, Some(fault));
        assert_eq!(c.feedback().mode, Mode::Disabled);
    }
    // Nearby normal values do not trip.
    let near: [fn(&mut Sample); 4] = [
        |s| s.v_bus_v = Some(9.0),
        |s| s.v_bus_v = Some(29.0),
        // An angle step under the 0.3 rad electrical step limit (7 pole
        // pairs: 0.04 rad mechanical); 0.05 rad mechanical is a slip (below).
        |s| {
            let a = s.angle.unwrap();
            s.angle = Some(a.add_radians(0.035))
        },
        |s| s.currents = Some(PhaseCurrents::ThreePhase(Abc::new(1.0, -0.5, -0.1))),
    ];
    for bad in near {
        let (c, b) = fault_with(bad);
        assert!(
            matches!(b, BridgeCommand::Duties(_)),
            "{:?}",
            c.feedback().faults
        );
    }
}

#[test]
fn fault_latches_until_cleared_and_rejects_commands() {
    let (mut c, _) = fault_with(|s| s.v_bus_v = Some(40.0));
    let mut p = Plant::new(0.0);
    p.j = 1.0;
    run(&mut c, &mut p, 10, |c, p| {
        assert!(!p.enabled);
        assert_eq!(c.feedback().mode, Mode::Disabled);
    });
    assert_eq!(
        c.command(Command::Torque { iq_a: 1.0 }),
        Err(CommandError::Faulted)
    );
    c.clear_faults();
    run(&mut c, &mut p, 1, |_, _| {});
    assert!(c.feedback().faults.is_empty());
    assert_eq!(
        c.feedback().mode,
        Mode::Disabled,
        "clear alone must not restart"
    );
    c.command(Command::Torque { iq_a: 1.0 }).unwrap();
    run(&mut c, &mut p, 5, |_, p| assert!(p.enabled));
}

/// A command posted right after `clear_faults` (the clear not yet taken
/// effect) is accepted: the next step clears, then runs the command.
#[test]
fn command_after_a_pending_clear_is_accepted() {
    let (mut c, _) = fault_with(|s| s.v_bus_v = Some(40.0));
    let mut p = Plant::new(0.0);
    p.j = 1.0;
    run(&mut c, &mut p, 3, |_, _| {});
    assert!(c.feedback().first_fault.is_some());
    c.clear_faults();
    assert_eq!(c.command(Command::Torque { iq_a: 1.0 }), Ok(()));
    let b = c.step(&p.sample());
    assert!(matches!(b, BridgeCommand::Duties(_)), "{b:?}");
    assert!(c.feedback().faults.is_empty());
    assert_eq!(c.feedback().active, Command::Torque { iq_a: 1.0 });
    // Once the clear is consumed, a new fault refuses commands again.
    c.report_fault(Fault::LoopOverrun);
    assert_eq!(
        c.command(Command::Torque { iq_a: 1.0 }),
        Err(CommandError::Faulted)
    );
    // A fault that persists trips again in the very step of the clear.
    c.clear_faults();
    c.command(Command::Torque { iq_a: 1.0 }).unwrap();
    let mut s = p.sample();
    s.v_bus_v = Some(40.0);
    assert_eq!(c.step(&s), BridgeCommand::SafeState);
    assert_eq!(c.feedback().first_fault, Some(Fault::BusOverVoltage));
}

#[test]
fn overrun_and_command_timeout() {
    let (mut c, mut p) = (cascade(), Plant::new(0.0));
    c.command(Command::Torque { iq_a: 0.5 }).unwrap();
    run(&mut c, &mut p, 5, |_, _| {});
    c.report_fault(Fault::LoopOverrun);
    assert_eq!(c.step(&p.sample()), BridgeCommand::SafeState);

    let mut cfg = config();
    cfg.current.command_timeout_periods = 100;
    cfg.current.timeout_reaction = TimeoutReaction::Disable;
    let mut c = calibrated(cfg);
    let mut p = Plant::new(0.0);
    c.command(Command::Velocity { rad_s: 20.0 }).unwrap();
    run(&mut c, &mut p, 100, |_, p| assert!(p.enabled));
    run(&mut c, &mut p, 1, |_, _| {});
    assert_eq!(c.feedback().first_fault, Some(Fault::CommandTimeout));

    cfg.current.timeout_reaction = TimeoutReaction::Stop;
    let mut c = calibrated(cfg);
    let mut p = Plant::new(0.0);
    c.command(Command::Velocity { rad_s: 50.0 }).unwrap();
    run(&mut c, &mut p, 2000, |_, _| {});
    assert_eq!(c.feedback().active, Command::Velocity { rad_s: 0.0 });
    assert!(c.feedback().faults.is_empty());
}

/// Without a calibration permit the closed-loop modes are locked (refused
/// by the cascade and by the stage itself), open loop and disable are not;
/// the permit unlocks them, a hand-set angle calibration locks them again.
#[test]
fn closed_loop_needs_a_calibration_permit() {
    let cfg = config();
    let mut c = Cascade::new(cfg);
    assert!(!c.is_calibrated());
    for cmd in [
        Command::Torque { iq_a: 1.0 },
        Command::Velocity { rad_s: 10.0 },
        Command::Position { rad: 1.0 },
    ] {
        assert_eq!(c.command(cmd), Err(CommandError::NotCalibrated), "{cmd:?}");
    }
    let mut p = Plant::new(0.0);
    p.j = 1.0;
    let ol = Command::OpenLoop {
        v_d_v: 0.5,
        v_q_v: 0.0,
        theta_e: ElectricalAngle::ZERO,
        omega_e_rad_s: 0.0,
    };
    c.command(ol).unwrap();
    run(&mut c, &mut p, 5, |c, p| {
        assert!(p.enabled);
        assert_eq!(c.feedback().mode, Mode::OpenLoop);
    });
    c.command(Command::Disable).unwrap();
    run(&mut c, &mut p, 2, |_, p| assert!(!p.enabled));

    // The stage refuses too when a closed-loop command reaches it directly
    // (the firmware's command slot does not go through `Cascade::command`).
    let mut stage = CurrentStage::new(cfg.current);
    let mut slot = CommandSlot::INIT;
    slot.post(Command::Torque { iq_a: 1.0 });
    let (b, fb) = stage.step(&slot, 0.0, &p.sample());
    assert_eq!(b, BridgeCommand::SafeState);
    assert_eq!(fb.mode, Mode::Disabled);
    assert_eq!(stage.rejected_commands(), 1);
    permit(&cfg).apply_to(&mut stage);
    slot.post(Command::Torque { iq_a: 1.0 });
    let (b, fb) = stage.step(&slot, 0.0, &p.sample());
    assert!(matches!(b, BridgeCommand::Duties(_)));
    assert_eq!(fb.mode, Mode::Torque);

    // With the permit: unlocked.
    c.set_calibration(&permit(&cfg));
    assert!(c.is_calibrated());
    c.command(Command::Torque { iq_a: 1.0 }).unwrap();
    run(&mut c, &mut p, 5, |c, p| {
        assert!(p.enabled);
        assert_eq!(c.feedback().mode, Mode::Torque);
    });
    // A hand-set angle calibration revokes it: bridge off, locked again.
    let mut angle = cfg.current.angle;
    angle.zero_offset = ElectricalAngle::from_degrees(30.0);
    c.current.set_angle_calibration(angle);
    assert!(!c.is_calibrated());
    run(&mut c, &mut p, 1, |c, p| {
        assert!(!p.enabled);
        assert_eq!(c.feedback().mode, Mode::Disabled);
    });
    assert_eq!(
        c.command(Command::Velocity { rad_s: 1.0 }),
        Err(CommandError::NotCalibrated)
    );
}

/// Uncalibrated, a command timeout in open loop cannot stop or hold (both
/// closed-loop): it disables with `CommandTimeout`.
#[test]
fn timeout_in_open_loop_without_calibration_disables() {
    let mut cfg = config();
    cfg.current.command_timeout_periods = 10;
    cfg.current.timeout_reaction = TimeoutReaction::Stop;
    let mut c = Cascade::new(cfg);
    let mut p = Plant::new(0.0);
    c.command(Command::OpenLoop {
        v_d_v: 0.5,
        v_q_v: 0.0,
        theta_e: ElectricalAngle::ZERO,
        omega_e_rad_s: 10.0,
    })
    .unwrap();
    run(&mut c, &mut p, 12, |_, _| {});
    assert_eq!(c.feedback().first_fault, Some(Fault::CommandTimeout));
    assert!(!p.enabled);
}

#[test]
fn invalid_commands_are_refused_and_change_nothing() {
    let mut c = cascade();
    c.command(Command::Torque { iq_a: 1.0 }).unwrap();
    assert_eq!(
        c.command(Command::Torque { iq_a: f32::NAN }),
        Err(CommandError::NonFinite)
    );
    assert_eq!(
        c.command(Command::Torque { iq_a: 9.0 }),
        Err(CommandError::CurrentOutOfRange)
    );
    assert_eq!(
        c.command(Command::Velocity {
            rad_s: f32::INFINITY
        }),
        Err(CommandError::NonFinite)
    );
    assert_eq!(
        c.command(Command::Position { rad: 1e9 }),
        Err(CommandError::PositionOutOfRange)
    );
    let mut p = Plant::new(0.0);
    run(&mut c, &mut p, 2, |_, _| {});
    assert_eq!(c.feedback().active, Command::Torque { iq_a: 1.0 });
}

fn any_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        -50.0f32..50.0,
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        Just(f32::MAX),
        Just(-f32::MAX),
        Just(0.0),
        any::<f32>(),
    ]
}

fn any_sample() -> impl Strategy<Value = Sample> {
    (
        any_f32(),
        any_f32(),
        any_f32(),
        any::<bool>(),
        prop::option::of(any::<u32>()),
        prop::option::of(any_f32()),
        prop::option::of(any_f32()),
    )
        .prop_map(|(a, b, cc, three, angle, vbus, temp)| Sample {
            currents: Some(if three {
                PhaseCurrents::ThreePhase(Abc::new(a, b, cc))
            } else {
                PhaseCurrents::TwoPhase { a_a: a, b_a: b }
            }),
            angle: angle.map(MechanicalAngle::from_bits),
            v_bus_v: vbus,
            temperature_c: temp,
        })
}

fn any_command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::Disable),
        any_f32().prop_map(|x| Command::Torque { iq_a: x }),
        any_f32().prop_map(|x| Command::Velocity { rad_s: x }),
        any_f32().prop_map(|x| Command::Position { rad: x }),
        (any_f32(), any_f32(), any::<u32>(), any_f32()).prop_map(|(d, q, t, w)| {
            Command::OpenLoop {
                v_d_v: d,
                v_q_v: q,
                theta_e: ElectricalAngle::from_bits(t),
                omega_e_rad_s: w,
            }
        }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Any sequence of samples and commands: no panic, duties always in
    /// [0, 1], and a non-finite or failed measurement always gives the safe
    /// state in that same period.
    #[test]
    fn no_panic_and_safe_for_any_input(
        steps in prop::collection::vec((any_sample(), prop::option::of(any_command())), 1..60)
    ) {
        let mut c = cascade();
        for (s, cmd) in steps {
            if let Some(cmd) = cmd {
                let _ = c.command(cmd);
            }
            let b = c.step(&s);
            let bad = match s.currents {
                Some(cur) => !cur.to_abc().is_finite(),
                None => true,
            } || s.angle.is_none()
                || s.v_bus_v.is_none_or(|v| !v.is_finite())
                || s.temperature_c.is_some_and(|t| !t.is_finite());
            match b {
                BridgeCommand::Duties(d) => {
                    prop_assert!(!bad, "unsafe output for a bad sample");
                    prop_assert!(d.iter().all(|x| (0.0..=1.0).contains(x)), "{:?}", d);
                }
                BridgeCommand::SafeState | BridgeCommand::ShortCircuit => {}
            }
        }
    }
}
