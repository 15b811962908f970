//! Encoder linearisation (design §33, issue 38) on every motor file in
//! `tests/motors/`, on a plant with the file's angle-sensor error and
//! cogging (`MotorFile::imperfections`):
//!
//! - the run (`ConfigChange::calibrate_encoder`) through the drive's
//!   lifecycle learns the correction; its time is printed;
//! - the sensor's angle error over a turn (the corrected reading against
//!   the rotor's true angle, its mean removed, peak to peak), the dyno
//!   turning the rotor at one turn per second, correction off and on;
//! - the speed ripple in velocity mode at 5 % of the no-load speed, the
//!   rotor free: the true speed's and the drive's estimate's, peak to
//!   peak over whole turns, off and on;
//! - a coarse sensor (the hub's halls) is refused; a failed run (a locked
//!   rotor) leaves the bridge off and the old correction in place.
//!
//! Each test prints its figures per motor.

use foc_bench::mission::{Setup, Sim};
use foc_bench::motor_file::{all_motor_files, MotorFile};
use foc_bench::plant::{Mechanics, Plant};
use foc_core::control::{BridgeCommand, Command, Fault, Refusal};
use foc_core::drive::{ConfigChange, Event};
use std::f64::consts::TAU;

struct Case {
    stem: String,
    setup: Setup,
    file: MotorFile,
}

fn cases() -> Vec<Case> {
    all_motor_files()
        .iter()
        .map(|p| {
            let file = MotorFile::load(p).unwrap();
            let mut setup = Setup::from_file(&file);
            setup.bench.sensors.encoder_offset_rad = 0.0;
            Case {
                stem: p.file_stem().unwrap().to_string_lossy().into_owned(),
                setup,
                file,
            }
        })
        .collect()
}

/// A calibrated drive on the plant with the file's sensor error and
/// cogging.
fn sim(c: &Case) -> Sim {
    let config = c.setup.cascade_config();
    let mut plant = Plant::new(c.setup.motor, c.setup.bench);
    c.file.imperfections().apply_plant(&mut plant);
    let mut sim = Sim::with_plant(&c.setup, plant, config, false);
    sim.cascade
        .set_calibration(&c.setup.supplied_calibration(&config));
    sim
}

/// Request the run: the correction's peak \[rad\] and the time \[s\].
fn calibrate(sim: &mut Sim, hz: f32) -> Result<(f32, f32), String> {
    sim.cascade.request(ConfigChange {
        calibrate_encoder: true,
        ..ConfigChange::default()
    });
    for _ in 0..(60.0 * hz) as usize {
        sim.step();
        let out = *sim.cascade.last_output().unwrap();
        if let Some(Err(r)) = out.change {
            return Err(format!("refused: {r:?}"));
        }
        match out.event {
            Some(Event::EncoderLinearised { peak_rad, periods }) => {
                return Ok((peak_rad, periods as f32 / hz));
            }
            Some(Event::IdentificationFailed(e, st)) => return Err(format!("{e:?} in {st:?}")),
            Some(Event::IdentificationAborted(f, st)) => return Err(format!("{f:?} in {st:?}")),
            _ => {}
        }
    }
    Err("did not finish in 60 s".into())
}

fn p2p(v: &[f64]) -> f64 {
    let max = v.iter().cloned().fold(f64::MIN, f64::max);
    let min = v.iter().cloned().fold(f64::MAX, f64::min);
    max - min
}

/// `x` wrapped into `[-pi, pi)`.
fn wrap(x: f64) -> f64 {
    (x + TAU / 2.0).rem_euclid(TAU) - TAU / 2.0
}

/// The angle error [rad] of the (corrected) reading over one turn, the
/// dyno turning the rotor at one turn per second, the bridge off.
fn angle_error(sim: &mut Sim, c: &Case) -> f64 {
    let hz = c.setup.pwm_hz() as f64;
    sim.plant.set_mechanics(Mechanics::ConstantSpeed(TAU));
    let mut v = Vec::new();
    for _ in 0..hz as usize {
        sim.step();
        let raw = sim.last_sample().angle;
        let read = sim.cascade.current.angle_correction().correct(raw);
        v.push(wrap(read.to_radians() as f64 - sim.plant.theta_m_rad()));
    }
    sim.plant.set_mechanics(Mechanics::Free);
    let first = v[0];
    let v: Vec<f64> = v.iter().map(|x| wrap(x - first)).collect();
    p2p(&v)
}

/// Speed ripple [rad/s] in velocity mode at `share` of the no-load speed
/// over the whole turns of 2 s after 1 s: (true, estimate).
fn speed_ripple(sim: &mut Sim, c: &Case, share: f32) -> (f64, f64) {
    let w = share * c.setup.max_speed_rad_s();
    let hz = c.setup.pwm_hz() as f64;
    sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
    sim.run(hz as usize);
    let turn_s = TAU / w as f64;
    let turns = (2.0 / turn_s).floor().max(1.0);
    let (mut t, mut e) = (Vec::new(), Vec::new());
    for _ in 0..(turns * turn_s * hz) as usize {
        sim.step();
        t.push(sim.plant.omega_m_rad_s());
        e.push(sim.cascade.feedback().velocity_rad_s as f64);
    }
    let fault = sim.cascade.feedback().first_fault;
    assert!(fault.is_none(), "{}: {fault:?}", c.stem);
    sim.cascade
        .command(Command::Velocity { rad_s: 0.0 })
        .unwrap();
    sim.run((0.5 * hz) as usize);
    sim.cascade.command(Command::Disable).unwrap();
    sim.run(100);
    (p2p(&t), p2p(&e))
}

fn figures(sim: &mut Sim, c: &Case, on: bool) -> [f64; 3] {
    sim.cascade.current.set_angle_correction_enabled(on);
    let a = angle_error(sim, c);
    let (t, e) = speed_ripple(sim, c, 0.05);
    [a, t, e]
}

fn coarse(c: &Case) -> bool {
    c.setup.bench.sensors.encoder_counts_per_rev / c.setup.motor.pole_pairs as u32 <= 64
}

#[test]
fn encoder_linearisation_on_every_motor_file() {
    let mut table = String::new();
    for c in cases() {
        let mut sim = sim(&c);
        let hz = c.setup.pwm_hz();
        if coarse(&c) {
            let r = calibrate(&mut sim, hz);
            assert_eq!(
                r,
                Err(format!("refused: {:?}", Refusal::Unsupported)),
                "{}",
                c.stem
            );
            println!("{}: refused (coarse angle sensor)", c.stem);
            continue;
        }
        let err = c.file.imperfections().sensor_error.unwrap();
        let (peak, secs) = calibrate(&mut sim, hz).unwrap_or_else(|e| panic!("{}: {e}", c.stem));
        let off = figures(&mut sim, &c, false);
        let on = figures(&mut sim, &c, true);
        let row = format!(
            "| {} | {:.2} / {:.2} mrad | {:.2} mrad | {:.1} s | {:.3} -> {:.3} mrad | {:.4} -> {:.4} rad/s | {:.4} -> {:.4} rad/s |",
            c.stem,
            1e3 * err.first_rad,
            1e3 * err.second_rad,
            1e3 * peak,
            secs,
            1e3 * off[0],
            1e3 * on[0],
            off[1],
            on[1],
            off[2],
            on[2],
        );
        println!("{row}");
        table.push_str(&row);
        table.push('\n');
        // The angle error falls to within two counts of the sensor, or to
        // a fifth of what it was, whichever is larger.
        let count = TAU / c.setup.bench.sensors.encoder_counts_per_rev as f64;
        assert!(
            on[0] <= (2.0 * count).max(0.2 * off[0]),
            "{}: angle error {off:?} -> {on:?}",
            c.stem
        );
    }
    println!(
        "| motor | sensor error 1st / 2nd | correction peak | run | angle error p-p | speed ripple at 5 % (true) | (estimate) |\n|---|---|---|---|---|---|---|\n{table}"
    );
}

/// A locked rotor: a named failure, the bridge off, the fault latched, no
/// correction installed.
#[test]
fn a_locked_rotor_fails_safe() {
    let c = cases()
        .into_iter()
        .find(|c| c.stem.starts_with("gl80"))
        .unwrap();
    let mut sim = sim(&c);
    sim.plant.set_mechanics(Mechanics::Locked);
    let r = calibrate(&mut sim, c.setup.pwm_hz());
    assert!(
        r.as_ref().is_err_and(|e| e.ends_with("in Encoder")),
        "{r:?}"
    );
    sim.run(10);
    // The routine's failure, or the supervisor's stuck-sensor fault first.
    let f = sim.cascade.feedback().first_fault;
    assert!(
        matches!(f, Some(Fault::CalibrationFailed | Fault::AngleSensorStuck)),
        "{f:?}"
    );
    assert_eq!(sim.last_bridge(), BridgeCommand::SafeState);
    assert!(!sim.cascade.current.angle_correction().enabled);
}
