//! A drive without an angle input (design §29, issue 35): on every motor
//! file the board boots sensorless with the angle withheld from every
//! sample, identifies the motor (resistance, inductances, gains, the flux
//! linkage on a turning field), and runs on what it measured; back on an
//! angle sensor that calibration no longer unlocks the closed loop.
//!
//! - The identified values against the motor file: resistance within 5 %,
//!   `Ld` within 10 % of the incremental inductance at the bias current,
//!   `Lq` within 10 %, the flux linkage within 5 %.
//! - A start on the identified motor (the sensorless start derived again
//!   from it, the configuration's inertia): reaches 0.3 of the top speed in
//!   the commanded direction without a fault.
//! - Switched to the encoder, the permit made without it refuses
//!   `Velocity` (`NotCalibrated`), and a closed loop that runs when the
//!   switch comes is dropped (bridge off).

use foc_bench::identify;
use foc_bench::mission::{self, Setup, Sim};
use foc_bench::motor_file::all_motor_files;
use foc_core::calibration::identification::IdentificationResult;
use foc_core::control::{BridgeCommand, Command, CommandError};

/// Identify `s` with the angle withheld; the result, and the simulation
/// left calibrated.
fn identify_without_angle(s: &Setup) -> (IdentificationResult, Sim) {
    let mut sim = Sim::new(s, s.sensorless_config(), false);
    let id =
        mission::identify_without_angle(&mut sim, s).unwrap_or_else(|e| panic!("{}: {e}", s.name));
    assert!(
        sim.cascade.current.config().angle.sensorless_only,
        "{}",
        s.name
    );
    (id.result, sim)
}

fn relative(measured: f32, truth: f64) -> f32 {
    (measured / truth as f32 - 1.0).abs()
}

#[test]
fn identified_without_an_angle_input_runs_sensorless_and_not_on_the_encoder() {
    for path in all_motor_files() {
        let s = Setup::load(&path).unwrap();
        let (r, mut sim) = identify_without_angle(&s);
        let m = &s.motor;
        let ld_true =
            m.ld_incremental_h(identify::config(&s, m.pole_pairs).inductance.bias_current_a as _);
        let errs = [
            relative(r.r_ohm, m.r_ohm),
            relative(r.ld_h, ld_true),
            relative(r.lq_h, m.lq_h),
            relative(r.flux_linkage_wb, m.flux_linkage_wb),
        ];
        println!(
            "{}: R {:.4} ohm ({:.1} %), Ld {:.1} uH ({:.1} %), Lq {:.1} uH ({:.1} %), flux {:.5} Wb ({:.1} %)",
            s.name,
            r.r_ohm,
            100.0 * errs[0],
            1e6 * r.ld_h,
            100.0 * errs[1],
            1e6 * r.lq_h,
            100.0 * errs[2],
            r.flux_linkage_wb,
            100.0 * errs[3],
        );
        for (e, bound, what) in [
            (errs[0], 0.05, "R"),
            (errs[1], 0.10, "Ld"),
            (errs[2], 0.10, "Lq"),
            (errs[3], 0.05, "flux linkage"),
        ] {
            assert!(e < bound, "{}: {what} off by {:.1} %", s.name, 100.0 * e);
        }
        // On what it measured: a start to 0.3 of the top speed.
        mission::rederive_start(&s, &mut sim);
        assert!(sim.cascade.is_calibrated(), "{}", s.name);
        let top = s.max_speed_rad_s().min(s.max_mission_speed_rad_s());
        let target = 0.3 * top;
        sim.cascade
            .command(Command::Velocity { rad_s: target })
            .unwrap();
        let n = (1.5 * s.pwm_hz()) as usize;
        for _ in 0..n {
            let mut smp = sim.sample();
            smp.angle = None;
            sim.step_with(&smp);
        }
        let fb = sim.cascade.feedback();
        assert_eq!(fb.first_fault, None, "{}", s.name);
        let speed = sim.plant.omega_m_rad_s() as f32;
        println!("  start: {speed:.1} rad/s of {target:.1}");
        assert!(
            (speed - target).abs() < 0.1 * target,
            "{}: {speed} of {target}",
            s.name
        );
        // Back on the encoder while running: dropped, and refused.
        sim.cascade.current.set_sensorless(None);
        assert!(!sim.cascade.is_calibrated(), "{}", s.name);
        assert_eq!(
            sim.cascade.command(Command::Velocity { rad_s: target }),
            Err(CommandError::NotCalibrated),
            "{}",
            s.name
        );
        assert_eq!(sim.cascade.current.active(), Command::Disable, "{}", s.name);
        sim.step();
        assert_eq!(sim.last_bridge(), BridgeCommand::SafeState, "{}", s.name);
        assert_eq!(sim.cascade.feedback().first_fault, None, "{}", s.name);
    }
}

/// A locked rotor: the field's back-EMF does not grow with its speed (or,
/// on a salient rotor, is only the saliency's), and the flux step fails
/// with `RotorStuck`, the bridge off and no permit; never a flux linkage
/// made of the inverter's voltage error or of the saliency.
#[test]
fn a_locked_rotor_fails_the_flux_step_by_name() {
    use foc_bench::plant::Mechanics;
    use foc_core::calibration::identification::Step;
    use foc_core::calibration::{CalError, CalStep};
    for path in all_motor_files() {
        let s = Setup::load(&path).unwrap();
        let mut sim = Sim::new(&s, s.sensorless_config(), false);
        sim.plant.set_mechanics(Mechanics::Locked);
        let cfg = identify::config(&s, s.motor.pole_pairs);
        let out = identify::run_without_angle(&mut sim, &s, cfg, &mut |_| {})
            .unwrap_or_else(|e| panic!("{}: {e}", s.name));
        println!("{}: {:?} in {:?}", s.name, out.step, out.stage);
        assert!(
            matches!(out.step, CalStep::Failed(CalError::RotorStuck)),
            "{}: {:?}",
            s.name,
            out.step
        );
        assert_eq!(out.stage, Step::Flux, "{}", s.name);
        assert!(!sim.cascade.is_calibrated(), "{}", s.name);
        sim.step();
        assert_eq!(sim.last_bridge(), BridgeCommand::SafeState, "{}", s.name);
    }
}

/// Power-on again with the identified calibration stored: a drive that runs
/// sensorless (angle withheld) restores it without an identification and
/// without motion, although its "sensor" would be an incremental encoder
/// (a calibration made without a sensor has no zero to lose), and starts
/// on it; the same stored calibration on a drive that reads its encoder
/// is installed but locks the closed loop (`NotCalibrated`) until an
/// identification with the sensor.
#[test]
fn a_stored_calibration_made_without_a_sensor_boots_only_sensorless() {
    use foc_core::calibration::Calibrated;
    use foc_core::drive::cascade::Cascade;
    use foc_core::drive::{AngleKind, Event};
    // One round rotor and one salient: the hub motor and the GL80.
    for name in ["hub", "gl80"] {
        let path = all_motor_files()
            .into_iter()
            .find(|p| p.to_string_lossy().contains(name))
            .unwrap();
        let s = Setup::load(&path).unwrap();
        let (_, sim) = identify_without_angle(&s);
        let c = sim.cascade.current.config();
        let stored = Calibrated::supplied(c.angle, c.current).unwrap();
        assert!(stored.angle().sensorless_only);
        for sensorless in [true, false] {
            let config = if sensorless {
                s.sensorless_config()
            } else {
                s.cascade_config()
            };
            let mut sim = Sim::new(&s, config, false);
            let mut life =
                identify::lifecycle_config(&sim, &s, identify::config(&s, s.motor.pole_pairs));
            life.angle_kind = AngleKind::Incremental;
            life.stored = Some(stored);
            sim.cascade = Cascade::from_reset(*sim.cascade.config(), life);
            let x0 = sim.plant.position_rad();
            let mut events = Vec::new();
            for _ in 0..(0.5 * s.pwm_hz()) as usize {
                let mut smp = sim.sample();
                if sensorless {
                    smp.angle = None;
                }
                sim.step_with(&smp);
                if let Some(e) = sim.cascade.last_output().and_then(|o| o.event) {
                    events.push(e);
                }
            }
            assert!(
                events.contains(&Event::CalibrationRestored),
                "{}: {events:?}",
                s.name
            );
            assert!(
                !events.contains(&Event::IdentificationStarted),
                "{}",
                s.name
            );
            assert!((sim.plant.position_rad() - x0).abs() < 1e-6, "{}", s.name);
            let top = s.max_speed_rad_s().min(s.max_mission_speed_rad_s());
            let cmd = Command::Velocity { rad_s: 0.3 * top };
            if !sensorless {
                assert_eq!(sim.cascade.command(cmd), Err(CommandError::NotCalibrated));
                continue;
            }
            sim.cascade.command(cmd).unwrap();
            for _ in 0..(1.5 * s.pwm_hz()) as usize {
                let mut smp = sim.sample();
                smp.angle = None;
                sim.step_with(&smp);
            }
            let speed = sim.plant.omega_m_rad_s() as f32;
            assert_eq!(sim.cascade.feedback().first_fault, None, "{}", s.name);
            assert!(
                (speed - 0.3 * top).abs() < 0.03 * top,
                "{}: {speed}",
                s.name
            );
        }
    }
}
