//! The incremental encoder's index search at start-up (design §33, issue
//! 38) on every motor file with a fine encoder in `tests/motors/`: the
//! stored calibration (its electrical zero referred to the index) comes
//! back after a reset wherever the rotor stopped, once the drive has
//! turned the rotor to the index; a missing index is a named failure.
//!
//! The plant's index mark is where the encoder read 0 when the stored
//! calibration was made (the bench's encoder powered up with the rotor at
//! 0 and `encoder_offset_rad`), so the stored permit is the bench's
//! supplied calibration.

use foc_bench::mission::{Setup, Sim};
use foc_bench::motor_file::all_motor_files;
use foc_bench::plant::Plant;
use foc_core::calibration::identification::Step;
use foc_core::calibration::index::IndexSearchConfig;
use foc_core::calibration::CalError;
use foc_core::control::{BridgeCommand, Command, CommandError, Fault};
use foc_core::drive::cascade::Cascade;
use foc_core::drive::{AngleKind, Event, LifePhase, LifecycleConfig};
use std::f64::consts::TAU;

fn setups() -> Vec<(String, Setup)> {
    all_motor_files()
        .iter()
        .map(|p| {
            let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
            (stem, Setup::load(p).unwrap())
        })
        .collect()
}

/// A drive from reset with the bench's calibration stored and the index
/// search on, the rotor at `start_rad`, the index mark where the stored
/// calibration's reading is 0 (or none).
fn boot(s: &Setup, start_rad: f64, mark: bool, direction: i8) -> Sim {
    let config = s.cascade_config();
    let mut plant = Plant::new(s.motor, s.bench);
    plant.start_rotor_at(start_rad as _);
    if mark {
        plant.set_encoder_index(Some(s.bench.sensors.encoder_offset_rad));
    }
    let mut sim = Sim::with_plant(s, plant, config, false);
    let life = LifecycleConfig {
        offsets: None,
        sensor_check_reads: 10,
        identification: None,
        identify_at_start_up: false,
        speed_divider: config.rates.speed_divider,
        position_divider: config.rates.position_divider,
        angle_kind: AngleKind::Incremental,
        stored: Some(s.supplied_calibration(&config)),
    };
    sim.cascade = Cascade::from_reset(config, life);
    let search = IndexSearchConfig {
        direction,
        ..IndexSearchConfig::new(
            0.5 * s.rated_current_a,
            s.motor.r_ohm as f32,
            s.motor.pole_pairs,
            s.pwm_hz(),
        )
    };
    sim.cascade.lifecycle_mut().set_index_search(Some(search));
    sim
}

/// Runs start-up: the events seen, until it ends or `secs` pass.
fn start_up(sim: &mut Sim, secs: f32, hz: f32) -> Vec<Event> {
    let mut events = Vec::new();
    for _ in 0..(secs * hz) as usize {
        let index = sim.last_sample().index;
        sim.cascade.set_index(index);
        sim.step();
        if let Some(e) = sim.cascade.last_output().and_then(|o| o.event) {
            events.push(e);
        }
        if sim.cascade.lifecycle().phase() == LifePhase::Run {
            break;
        }
    }
    events
}

/// The drive's electrical angle against the rotor's [rad, electrical].
fn angle_error(sim: &Sim) -> f64 {
    let d = sim.cascade.feedback().theta_e.to_radians() as f64 - sim.plant.theta_e_rad();
    (d + TAU / 2.0).rem_euclid(TAU) - TAU / 2.0
}

fn fine(s: &Setup) -> bool {
    s.bench.sensors.encoder_counts_per_rev / s.motor.pole_pairs as u32 > 64
}

#[test]
fn the_stored_zero_applies_after_the_index_wherever_the_rotor_stopped() {
    for (stem, s) in setups().into_iter().filter(|(_, s)| fine(s)) {
        let hz = s.pwm_hz();
        let count_e =
            TAU / s.bench.sensors.encoder_counts_per_rev as f64 * s.motor.pole_pairs as f64;
        for (start, dir) in [(0.3, 1i8), (2.9, 1), (5.1, -1)] {
            let mut sim = boot(&s, start, true, dir);
            let events = start_up(&mut sim, 30.0, hz);
            let travel = events.iter().find_map(|e| match e {
                Event::IndexFound { travel_rad } => Some(*travel_rad),
                _ => None,
            });
            let travel = travel.unwrap_or_else(|| panic!("{stem} from {start}: {events:?}"));
            assert!(
                events.contains(&Event::CalibrationRestored),
                "{stem} from {start}: {events:?}"
            );
            // At most a turn and a quarter, in the configured direction.
            assert!(travel.abs() <= 1.25 * TAU as f32 + 0.1, "{stem}: {travel}");
            assert!(travel * dir as f32 > 0.0, "{stem}: {travel} against {dir}");
            sim.run(10);
            let err = angle_error(&sim);
            assert!(
                err.abs() < 3.0 * count_e,
                "{stem} from {start}: {err} rad(e)"
            );
            // The closed loop runs on it.
            let w = 0.1 * s.max_speed_rad_s();
            sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
            sim.run((0.5 * hz) as usize);
            let fb = sim.cascade.feedback();
            assert!(fb.first_fault.is_none(), "{stem}: {:?}", fb.first_fault);
            assert!(
                (sim.plant.omega_m_rad_s() as f32 - w).abs() < 0.1 * w,
                "{stem}"
            );
            println!(
                "{stem}: from {start:.1} rad ({dir:+}): index after {travel:+.3} rad, angle error {:.4} rad(e), {w:.1} rad/s reached",
                err
            );
        }
    }
}

#[test]
fn a_missing_index_is_a_named_failure() {
    let (stem, s) = setups()
        .into_iter()
        .find(|(n, _)| n.starts_with("gl80"))
        .unwrap();
    let mut sim = boot(&s, 1.0, false, 1);
    let events = start_up(&mut sim, 60.0, s.pwm_hz());
    assert!(
        events.contains(&Event::IdentificationFailed(
            CalError::IndexNotFound,
            Step::IndexSearch
        )),
        "{stem}: {events:?}"
    );
    sim.run(3);
    assert_eq!(
        sim.cascade.feedback().first_fault,
        Some(Fault::CalibrationFailed)
    );
    assert_eq!(sim.last_bridge(), BridgeCommand::SafeState);
    // The stored zero is not taken: no closed loop.
    sim.cascade.clear_faults();
    sim.run(5);
    assert_eq!(
        sim.cascade.command(Command::Velocity { rad_s: 1.0 }),
        Err(CommandError::NotCalibrated)
    );
    // The rotor moved at most the search's bound.
    assert!((sim.plant.position_rad() - 1.0).abs() < 1.25 * TAU + 0.5);
}
