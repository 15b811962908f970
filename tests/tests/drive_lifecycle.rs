//! The drive's lifecycle (foc-core `drive`), host-tested against the bench
//! plant: the start-up the firmware runs (offsets with the bridge off, the
//! sensor check), identification on request (success, named failure, abort
//! by an operator `Disable`, abort by a fault), configuration changes
//! (applied at a period boundary, refused whole while running) and the
//! calibration permit (revoked when the angle calibration or the current
//! loop changes without one).

use foc_bench::identify::{self, lifecycle_config, OFFSET_SAMPLES, SENSOR_CHECK_READS};
use foc_bench::mission::{Setup, Sim};
use foc_bench::plant::{Phase as PlantPhase, Plant};
use foc_core::calibration::identification::Step;
use foc_core::calibration::CalError;
use foc_core::control::stage::Sample;
use foc_core::control::{BridgeCommand, Command, CommandError, Fault, Mode};
use foc_core::drive::cascade::Cascade;
use foc_core::drive::{ConfigChange, Event, LifePhase, Refusal};
use foc_core::hal::PhaseCurrents;

fn dji() -> Setup {
    Setup::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/motors/dji-m2006.toml"
    ))
    .unwrap()
}

/// A simulation restarted from reset; `identify`: at start-up.
fn from_reset(s: &Setup, plant: Plant, identify: bool) -> Sim {
    let mut sim = Sim::with_plant(s, plant, s.cascade_config(), false);
    let mut life = lifecycle_config(&sim, s, identify::config(s, s.motor.pole_pairs));
    life.identify_at_start_up = identify;
    sim.cascade = Cascade::from_reset(*sim.cascade.config(), life);
    sim
}

/// Step until `pred` holds for the event of a period (at most `n` periods);
/// every event seen, with its period, is returned.
fn run_until(
    sim: &mut Sim,
    n: usize,
    mut each: impl FnMut(&mut Sim) -> Option<Sample>,
    pred: impl Fn(&Event) -> bool,
) -> Vec<(usize, Event)> {
    let mut seen = Vec::new();
    for k in 0..n {
        match each(sim) {
            Some(s) => sim.step_with(&s),
            None => sim.step(),
        };
        if let Some(e) = sim.cascade.last_output().and_then(|o| o.event) {
            seen.push((k + 1, e));
            if pred(&e) {
                return seen;
            }
        }
    }
    panic!("no such event in {n} periods; saw {seen:?}");
}

fn started(s: &Setup) -> Sim {
    let mut sim = from_reset(s, Plant::new(s.motor, s.bench), false);
    run_until(&mut sim, 5000, |_| None, |e| *e == Event::StartUpDone);
    sim
}

/// Started, with the bench's calibration supplied, in torque mode.
fn in_torque(s: &Setup) -> Sim {
    let mut sim = started(s);
    supply_permit(s, &mut sim);
    sim.cascade.command(Command::Torque { iq_a: 0.5 }).unwrap();
    sim.run(10);
    sim
}

/// Install the permit of the bench's true calibration.
fn supply_permit(s: &Setup, sim: &mut Sim) {
    let cfg = *sim.cascade.config();
    sim.cascade.set_calibration(&s.supplied_calibration(&cfg));
}

/// Reset -> offsets (bridge off, then installed) -> sensor check -> run,
/// disabled and uncalibrated.
#[test]
fn start_up_order() {
    let s = dji();
    let mut sim = from_reset(&s, Plant::new(s.motor, s.bench), false);
    let mut bridge_on = false;
    let seen = run_until(
        &mut sim,
        5000,
        |sim| {
            bridge_on |= sim.last_bridge() != BridgeCommand::SafeState;
            None
        },
        |e| *e == Event::StartUpDone,
    );
    let n = OFFSET_SAMPLES as usize;
    let r = SENSOR_CHECK_READS as usize;
    assert!(
        matches!(seen[0], (k, Event::OffsetsDone(_)) if k == n),
        "{seen:?}"
    );
    assert_eq!(seen[1], (n + r, Event::StartUpDone));
    assert!(!bridge_on, "the bridge was on during start-up");
    assert!(sim.current_offsets().is_some(), "offsets not installed");
    assert_eq!(sim.cascade.lifecycle().phase(), LifePhase::Run);
    let status = sim.cascade.lifecycle().status(&sim.cascade.current);
    assert!(status.running && !status.calibrated && !status.faulted);
    assert_eq!(
        sim.cascade.command(Command::Torque { iq_a: 1.0 }),
        Err(CommandError::NotCalibrated)
    );
}

/// Closed-loop commands are refused during start-up too, even with a
/// permit supplied before the offsets are known.
#[test]
fn no_closed_loop_before_start_up_ends() {
    let s = dji();
    let mut sim = from_reset(&s, Plant::new(s.motor, s.bench), false);
    supply_permit(&s, &mut sim);
    assert_eq!(
        sim.cascade.command(Command::Torque { iq_a: 1.0 }),
        Err(CommandError::NotCalibrated)
    );
    run_until(&mut sim, 5000, |_| None, |e| *e == Event::StartUpDone);
    assert!(sim.cascade.command(Command::Torque { iq_a: 1.0 }).is_ok());
}

/// Offsets far from zero: the calibration fails by name, the fault is
/// latched, the drive stays uncalibrated with the bridge off.
#[test]
fn offset_failure_latches_a_fault() {
    let s = dji();
    let mut sim = from_reset(&s, Plant::new(s.motor, s.bench), false);
    let seen = run_until(
        &mut sim,
        5000,
        |sim| {
            let mut smp = sim.sample();
            smp.currents = Some(PhaseCurrents::TwoPhase {
                a_a: 0.5 * s.max_current_a,
                b_a: 0.0,
            });
            Some(smp)
        },
        |e| matches!(e, Event::OffsetsFailed(_)),
    );
    assert_eq!(seen.len(), 1);
    sim.run(10);
    let fb = *sim.cascade.feedback();
    assert_eq!(fb.first_fault, Some(Fault::CalibrationFailed));
    assert_eq!(sim.last_bridge(), BridgeCommand::SafeState);
    assert!(
        !sim.cascade
            .lifecycle()
            .status(&sim.cascade.current)
            .calibrated
    );
}

/// The angle sensor stops answering during the sensor check.
#[test]
fn sensor_failure_latches_a_fault() {
    let s = dji();
    let mut sim = from_reset(&s, Plant::new(s.motor, s.bench), false);
    let mut k = 0;
    run_until(
        &mut sim,
        5000,
        |sim| {
            k += 1;
            let mut smp = sim.sample();
            if k > OFFSET_SAMPLES as usize + 10 {
                smp.angle = None;
            }
            Some(smp)
        },
        |e| *e == Event::SensorCheckFailed,
    );
    sim.run(2);
    assert_eq!(
        sim.cascade.feedback().first_fault,
        Some(Fault::AngleSensorError)
    );
    assert_eq!(sim.last_bridge(), BridgeCommand::SafeState);
}

/// Identification on request succeeds, installs its permit, and does not
/// resume the command the operator had posted before it.
#[test]
fn identification_on_request_succeeds_and_never_resumes_an_old_command() {
    let s = dji();
    let mut sim = started(&s);
    // An open-loop command is running before the identification...
    sim.cascade.command(Command::Disable).unwrap();
    sim.run(5);
    sim.cascade.request(ConfigChange {
        identify: true,
        ..ConfigChange::default()
    });
    sim.step();
    assert_eq!(sim.cascade.last_output().unwrap().change, Some(Ok(())));
    assert_eq!(
        sim.cascade.last_output().unwrap().event,
        Some(Event::IdentificationStarted)
    );
    let limit = (identify::TIME_LIMIT_S * s.pwm_hz()) as usize;
    let seen = run_until(
        &mut sim,
        limit,
        |_| None,
        |e| matches!(e, Event::Identified(_) | Event::IdentificationFailed(..)),
    );
    let Some((_, Event::Identified(r))) = seen.last() else {
        panic!("{seen:?}")
    };
    assert!((f64::from(r.r_ohm) / s.motor.r_ohm - 1.0).abs() < 0.05);
    assert!(sim.cascade.is_calibrated());
    sim.run(100);
    assert_eq!(sim.cascade.feedback().mode, Mode::Disabled);
    assert!(sim.cascade.command(Command::Torque { iq_a: 0.5 }).is_ok());
    sim.run(10);
    assert_eq!(sim.cascade.feedback().mode, Mode::Torque);
}

/// A disconnected phase: the identification ends in its named failure,
/// with `CalibrationFailed` latched and the bridge off.
#[test]
fn identification_named_failure() {
    let s = dji();
    let mut plant = Plant::new(s.motor, s.bench);
    plant.faults_mut().disconnected_phase = Some(PlantPhase::C);
    let mut sim = from_reset(&s, plant, true);
    let seen = run_until(
        &mut sim,
        200_000,
        |_| None,
        |e| matches!(e, Event::IdentificationFailed(..)),
    );
    assert!(
        matches!(
            seen.last(),
            Some((_, Event::IdentificationFailed(CalError::OpenPhase(_), _)))
        ),
        "{seen:?}"
    );
    assert_eq!(
        sim.cascade.feedback().first_fault,
        Some(Fault::CalibrationFailed)
    );
    assert_eq!(sim.last_bridge(), BridgeCommand::SafeState);
    assert!(!sim.cascade.is_calibrated());
}

/// An operator `Disable` aborts a running identification: bridge off at
/// once, no fault, uncalibrated, back in `Run`.
#[test]
fn identification_aborted_by_disable() {
    let s = dji();
    let mut sim = from_reset(&s, Plant::new(s.motor, s.bench), true);
    run_until(
        &mut sim,
        5000,
        |_| None,
        |e| *e == Event::IdentificationStarted,
    );
    sim.run(3000);
    assert_eq!(sim.cascade.lifecycle().phase(), LifePhase::Identify);
    assert!(matches!(sim.last_bridge(), BridgeCommand::Duties(_)));
    sim.cascade.command(Command::Disable).unwrap();
    sim.step();
    let out = *sim.cascade.last_output().unwrap();
    assert!(
        matches!(out.event, Some(Event::IdentificationAborted(None, _))),
        "{:?}",
        out.event
    );
    assert_eq!(out.bridge, BridgeCommand::SafeState);
    assert_eq!(sim.cascade.lifecycle().phase(), LifePhase::Run);
    assert!(!sim.cascade.is_calibrated());
    assert_eq!(sim.cascade.feedback().first_fault, None);
}

/// A fault during the identification (the bus-voltage reading fails)
/// aborts it with the fault latched and the bridge off in that period.
#[test]
fn identification_aborted_by_a_fault() {
    let s = dji();
    let mut sim = from_reset(&s, Plant::new(s.motor, s.bench), true);
    run_until(
        &mut sim,
        5000,
        |_| None,
        |e| *e == Event::IdentificationStarted,
    );
    sim.run(3000);
    let mut smp = sim.sample();
    smp.v_bus_v = None;
    assert_eq!(sim.step_with(&smp), BridgeCommand::SafeState);
    let out = *sim.cascade.last_output().unwrap();
    assert!(
        matches!(
            out.event,
            Some(Event::IdentificationAborted(Some(Fault::BusSenseError), _))
        ),
        "{:?}",
        out.event
    );
    assert!(!sim.cascade.is_calibrated());
}

/// A configuration change while running is refused whole: nothing
/// changes; the same change while disabled is applied at the next period.
#[test]
fn configuration_change_while_running_is_refused() {
    let s = dji();
    let mut sim = in_torque(&s);
    let before = sim.cascade.current.config().limits;
    let mut limits = before;
    limits.max_current_a = 0.5 * before.max_current_a;
    let change = ConfigChange {
        limits: Some(limits),
        dividers: Some((5, 7)),
        ..ConfigChange::default()
    };
    sim.cascade.request(change);
    sim.step();
    assert_eq!(
        sim.cascade.last_output().unwrap().change,
        Some(Err(Refusal::NotDisabled))
    );
    assert_eq!(sim.cascade.current.config().limits, before);
    let dividers = sim.cascade.lifecycle().dividers();
    assert_ne!(dividers, (5, 7));
    // Identification while running: refused as well.
    sim.cascade.request(ConfigChange {
        identify: true,
        ..ConfigChange::default()
    });
    sim.step();
    assert_eq!(
        sim.cascade.last_output().unwrap().change,
        Some(Err(Refusal::NotDisabled))
    );
    assert_eq!(sim.cascade.lifecycle().phase(), LifePhase::Run);
    // Disabled: applied whole.
    sim.cascade.command(Command::Disable).unwrap();
    sim.step();
    sim.cascade.request(change);
    sim.step();
    assert_eq!(sim.cascade.last_output().unwrap().change, Some(Ok(())));
    assert_eq!(sim.cascade.current.config().limits, limits);
    assert_eq!(sim.cascade.lifecycle().dividers(), (5, 7));
    // Invalid limits are refused whole, with the dividers in the same change.
    let mut bad = limits;
    bad.max_current_a = f32::NAN;
    sim.cascade.request(ConfigChange {
        limits: Some(bad),
        dividers: Some((3, 3)),
        ..ConfigChange::default()
    });
    sim.step();
    assert_eq!(
        sim.cascade.last_output().unwrap().change,
        Some(Err(Refusal::Unsupported))
    );
    assert_eq!(sim.cascade.lifecycle().dividers(), (5, 7));
}

/// The permit is revoked when the angle calibration changes without one,
/// when current-loop values it cannot vouch for are installed, and when an
/// identification starts; a closed-loop command then stops.
#[test]
fn permit_revoked_when_the_angle_calibration_changes() {
    let s = dji();
    let mut sim = in_torque(&s);
    // The configuration with plausible gains, for new permits below.
    let cfg = *sim.cascade.config();
    assert_eq!(sim.cascade.feedback().mode, Mode::Torque);
    let mut angle = sim.cascade.current.config().angle;
    angle.zero_offset = angle.zero_offset.add_radians(0.3);
    sim.cascade.current.set_angle_calibration(angle);
    assert!(!sim.cascade.is_calibrated());
    sim.step();
    assert_eq!(sim.cascade.feedback().mode, Mode::Disabled);
    assert_eq!(sim.last_bridge(), BridgeCommand::SafeState);

    // Gains a permit cannot vouch for (negative): the change is applied
    // but the calibration is revoked.
    sim.cascade.set_calibration(&s.supplied_calibration(&cfg));
    let mut cur = sim.cascade.current.config().current;
    cur.q_gains.kp_v_per_a = -1.0;
    sim.cascade.request(ConfigChange {
        current: Some(cur),
        ..ConfigChange::default()
    });
    sim.step();
    assert!(!sim.cascade.is_calibrated());

    // A new identification revokes the old permit at its start.
    sim.cascade.set_calibration(&s.supplied_calibration(&cfg));
    sim.cascade.request(ConfigChange {
        identify: true,
        ..ConfigChange::default()
    });
    sim.step();
    assert_eq!(sim.cascade.lifecycle().phase(), LifePhase::Identify);
    assert!(!sim.cascade.is_calibrated());
}

/// A fault found in the same period as an operator's clear (a power-stage
/// fault, a link watchdog's reaction) stays latched: the clear is performed
/// first, the bridge goes off in that period.
#[test]
fn a_fault_in_the_period_of_a_clear_stays_latched() {
    let s = dji();
    let mut sim = in_torque(&s);
    sim.cascade.clear_faults();
    sim.cascade.request(ConfigChange {
        fault: Some(Fault::CommandTimeout),
        ..ConfigChange::default()
    });
    assert_eq!(sim.step(), BridgeCommand::SafeState);
    assert_eq!(
        sim.cascade.feedback().first_fault,
        Some(Fault::CommandTimeout)
    );
}

/// Stopped during the flux step (closed loop on the provisional permit):
/// the provisional permit goes with it, closed-loop commands are refused.
#[test]
fn identification_aborted_in_the_flux_step_leaves_no_permit() {
    let s = dji();
    let mut sim = from_reset(&s, Plant::new(s.motor, s.bench), true);
    let limit = (identify::TIME_LIMIT_S * s.pwm_hz()) as usize;
    let mut k = 0;
    while sim.cascade.lifecycle().identification_step() != Some(Step::Flux) {
        sim.step();
        k += 1;
        assert!(k < limit, "no flux step");
    }
    sim.run(200);
    assert_eq!(sim.cascade.feedback().mode, Mode::Velocity);
    assert!(sim.cascade.is_calibrated(), "provisional permit installed");
    sim.cascade.command(Command::Disable).unwrap();
    sim.step();
    assert!(matches!(
        sim.cascade.last_output().unwrap().event,
        Some(Event::IdentificationAborted(None, Step::Flux))
    ));
    assert!(!sim.cascade.is_calibrated());
    assert_eq!(
        sim.cascade.command(Command::Torque { iq_a: 0.5 }),
        Err(CommandError::NotCalibrated)
    );
}

/// A calibration request refused (fault latched) does not take the
/// settings of the same change with it: they are judged on their own.
#[test]
fn a_refused_calibration_keeps_the_settings_of_its_change() {
    let s = dji();
    let mut sim = started(&s);
    sim.cascade.request(ConfigChange {
        fault: Some(Fault::CommandTimeout),
        ..ConfigChange::default()
    });
    sim.step();
    sim.cascade.request(ConfigChange {
        dividers: Some((5, 7)),
        identify: true,
        ..ConfigChange::default()
    });
    sim.step();
    assert_eq!(
        sim.cascade.last_output().unwrap().change,
        Some(Err(Refusal::Faulted))
    );
    assert_eq!(sim.cascade.lifecycle().dividers(), (5, 7));
    assert_eq!(sim.cascade.lifecycle().phase(), LifePhase::Run);
}

/// While start-up or an identification runs, the rules take only
/// `Disable` (the drive would act on anything else only later).
#[test]
fn commands_other_than_disable_are_busy_until_started() {
    let s = dji();
    let mut sim = from_reset(&s, Plant::new(s.motor, s.bench), true);
    sim.run(10);
    let limits = sim.cascade.current.config().limits;
    let status = sim.cascade.lifecycle().status(&sim.cascade.current);
    let open_loop = Command::OpenLoop {
        v_d_v: 0.5,
        v_q_v: 0.0,
        theta_e: foc_core::angle::ElectricalAngle::ZERO,
        omega_e_rad_s: 0.0,
    };
    assert_eq!(
        status.check_command(&open_loop, &limits),
        Err(CommandError::Busy)
    );
    assert_eq!(sim.cascade.command(open_loop), Err(CommandError::Busy));
    assert_eq!(status.check_command(&Command::Disable, &limits), Ok(()));
    run_until(
        &mut sim,
        5000,
        |_| None,
        |e| *e == Event::IdentificationStarted,
    );
    assert_eq!(sim.cascade.command(open_loop), Err(CommandError::Busy));
    assert!(sim.cascade.command(Command::Disable).is_ok());
}

mod stored_calibration {
    //! Identify once, boot ready (design §17): the permit an identification
    //! gave on one power-on, handed to the lifecycle at the next one as the
    //! store would, on the plant with an absolute sensor and the rotor
    //! somewhere else.
    use super::*;
    use foc_bench::plant::AngleSensorKind;
    use foc_core::calibration::Calibrated;
    use foc_core::drive::AngleKind;

    /// The emulated AS5047P's mounting offset \[rad\].
    const MOUNTING_RAD: f32 = 0.9;

    fn absolute_plant(s: &Setup, rotor_rad: f32) -> Plant {
        let mut plant = Plant::new(s.motor, s.bench);
        plant.set_angle_sensor(AngleSensorKind::Absolute {
            mounting_offset_rad: MOUNTING_RAD.into(),
        });
        plant.start_rotor_at(rotor_rad.into());
        plant
    }

    /// Power-on 1: identify from reset; the permit the stage holds after.
    fn identified_permit(s: &Setup) -> Calibrated {
        let mut sim = from_reset(s, absolute_plant(s, 0.0), true);
        let limit = ((identify::TIME_LIMIT_S + 1.0) * s.pwm_hz()) as usize;
        let seen = run_until(
            &mut sim,
            limit,
            |_| None,
            |e| matches!(e, Event::Identified(_) | Event::IdentificationFailed(..)),
        );
        assert!(
            matches!(seen.last(), Some((_, Event::Identified(_)))),
            "{seen:?}"
        );
        let c = sim.cascade.current.config();
        Calibrated::supplied(c.angle, c.current).unwrap()
    }

    /// Power-on 2: from reset with `stored`, the sensor of `kind`.
    fn boot(s: &Setup, plant: Plant, kind: AngleKind, stored: Calibrated) -> Sim {
        let mut sim = Sim::with_plant(s, plant, s.cascade_config(), false);
        let mut life = lifecycle_config(&sim, s, identify::config(s, s.motor.pole_pairs));
        life.identify_at_start_up = true;
        life.angle_kind = kind;
        life.stored = Some(stored);
        sim.cascade = Cascade::from_reset(*sim.cascade.config(), life);
        sim
    }

    #[test]
    fn an_absolute_sensor_boots_calibrated_without_motion_and_commutates_right() {
        let s = dji();
        let permit = identified_permit(&s);
        let start_rad = 2.1;
        let mut sim = boot(
            &s,
            absolute_plant(&s, start_rad),
            AngleKind::Absolute,
            permit,
        );
        let seen = run_until(
            &mut sim,
            5000,
            |_| None,
            |e| *e == Event::CalibrationRestored,
        );
        let (period, _) = *seen.last().unwrap();
        assert!(
            !seen.iter().any(|(_, e)| *e == Event::IdentificationStarted),
            "{seen:?}"
        );
        let ms = period as f64 * 1e3 / s.pwm_hz() as f64;
        assert!(ms < 100.0, "calibrated {ms} ms after reset");
        assert!(sim.cascade.is_calibrated());
        let motion = (sim.plant.position_rad() - f64::from(start_rad)).abs();
        assert!(
            motion < 0.01,
            "rotor moved {motion} rad before the first command"
        );
        // A torque command gives the torque the motor's constant says: the
        // stored zero is right although the rotor started elsewhere.
        let iq_a = 0.5 * s.max_current_a;
        sim.cascade.command(Command::Torque { iq_a }).unwrap();
        let w0 = sim.plant.omega_m_rad_s();
        let t_s = 0.02;
        sim.run((t_s * s.pwm_hz() as f64) as usize);
        let gained = sim.plant.omega_m_rad_s() - w0;
        let kt = 1.5 * f64::from(s.motor.pole_pairs) * s.motor.flux_linkage_wb;
        let ideal = kt * f64::from(iq_a) / s.motor.inertia_kg_m2 * t_s;
        assert!(
            gained > 0.8 * ideal && gained < 1.1 * ideal,
            "speed gained {gained} rad/s, rigid rotor with ideal torque {ideal}"
        );
    }

    #[test]
    fn an_incremental_encoder_does_not_trust_a_stored_zero() {
        let s = dji();
        let permit = identified_permit(&s);
        // Same motor, an incremental encoder: its zero is where the rotor
        // was at power-on, so the stored zero would be wrong by 2.1 rad.
        let mut plant = Plant::new(s.motor, s.bench);
        plant.start_rotor_at(2.1);
        let mut sim = boot(&s, plant, AngleKind::Incremental, permit);
        let seen = run_until(
            &mut sim,
            5000,
            |_| None,
            |e| *e == Event::IdentificationStarted,
        );
        assert!(!seen.iter().any(|(_, e)| *e == Event::CalibrationRestored));
        assert!(!sim.cascade.is_calibrated());
    }
}

mod mission_from_a_saved_configuration {
    //! `cargo xtask sim --save-config` / `--config`: the bench mission run
    //! once (identifying), its configuration saved as TOML, then run again
    //! from that file (no identification).
    use super::*;
    use foc_bench::mission::{run_mission, run_mission_from};

    #[test]
    fn a_saved_configuration_runs_the_mission_without_identifying() {
        let s = dji();
        let first = run_mission(&s, &mut |_| {});
        assert!(
            first.summary.failures().is_empty(),
            "{:?}",
            first.summary.failures()
        );
        let text = foc_store::text::to_toml(&first.record);
        let saved = foc_store::text::from_toml(&text).unwrap();
        assert_eq!(saved, first.record);
        assert!(saved.calibration.is_some());

        let second = run_mission_from(&s, Some(&saved), &mut |_| {}).unwrap();
        let sum = &second.summary;
        assert!(sum.restored && sum.identification.is_none());
        assert!(sum.failures().is_empty(), "{:?}", sum.failures());
        assert!(sum.align_error_deg.abs() < 1.0, "{}", sum.align_error_deg);
        assert!(
            second.trace.len() < first.trace.len() / 2,
            "no identification"
        );

        // A stored zero a quarter electrical turn off is installed as
        // stored, and the mission says it is wrong.
        let mut off = saved.clone();
        let cal = off.calibration.as_mut().unwrap();
        cal.zero_offset_e_rad =
            (cal.zero_offset_e_rad + std::f32::consts::FRAC_PI_2) % std::f32::consts::TAU;
        let third = run_mission_from(&s, Some(&off), &mut |_| {}).unwrap();
        assert!(third.summary.align_error_deg.abs() > 80.0);
        assert!(!third.summary.failures().is_empty());

        // A record made for another PWM frequency is refused.
        let mut other = saved.clone();
        other.pwm_frequency_hz += 1000;
        let e = run_mission_from(&s, Some(&other), &mut |_| {})
            .err()
            .unwrap();
        assert!(e.contains("pwm_frequency_hz"), "{e}");
    }
}
