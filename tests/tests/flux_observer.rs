//! The sensorless flux observer (design §26, issue 35, first part) run
//! beside the encoder on every motor file in `tests/motors/`: the drive
//! runs on its encoder; the observer sees only what a sensorless drive
//! would (the currents read, the duties handed to the bridge, the bus
//! read) and its angle is held against the plant's true one.
//!
//! Per motor file, with the plant's resistance as identified and 30 %
//! higher (a warm winding the drive does not know of): velocity steps from standstill to 0.1 of the top
//! speed, down to 0.05 and 0.02, up to 0.2, 0.5 and 0.9, a reversal to
//! -0.5 and a rated load step there. It prints the angle error at steady
//! speed per step (the segment's last fifth), the largest error while the
//! speed changes, the speed error, and the flux linkage in use.
//! Asserted with the resistance as identified: at steady speed from 0.1
//! of the top speed up, the angle
//! within [`STEADY_LIMIT_RAD`] and the speed within 2 %; while the speed
//! changes (at the current limit) above that speed, within
//! [`ACCEL_LIMIT_RAD`]. The drive itself runs on its encoder: running on
//! the observer, and starting without a sensor, are later parts.

use foc_bench::mission::{Setup, Sim};
use foc_bench::motor_file::all_motor_files;
use foc_bench::plant::Plant;
use foc_core::control::flux_observer::{FluxObserver, ObserverConfig};
use foc_core::control::{BridgeCommand, Command};
use foc_core::transforms;

/// Largest angle error at steady speed [rad, electrical] (about 3 deg).
const STEADY_LIMIT_RAD: f32 = 0.05;
/// Largest angle error while accelerating at the current limit [rad].
const ACCEL_LIMIT_RAD: f32 = 0.15;

struct Run {
    sim: Sim,
    obs: FluxObserver,
    /// The same observer without the flux linkage's tracking.
    fixed: FluxObserver,
    pole_pairs: f32,
    /// Periods the observer has agreed with the rotor's angle.
    agree: u32,
    ts_s: f32,
}

impl Run {
    /// The drive and the observer know the motor file's values; the plant's
    /// resistance is `r_factor` times it (a warm winding), its flux linkage
    /// `psi_factor` times it (a warm magnet).
    fn new(s: &Setup, r_factor: f64, psi_factor: f64) -> Self {
        let config = s.cascade_config();
        let plant_motor = foc_bench::plant::MotorParams {
            r_ohm: s.motor.r_ohm * r_factor,
            flux_linkage_wb: s.motor.flux_linkage_wb * psi_factor,
            ..s.motor
        };
        let mut sim = Sim::with_plant(s, Plant::new(plant_motor, s.bench), config, false);
        sim.cascade
            .set_calibration(&s.supplied_calibration(&config));
        let obs = FluxObserver::new(ObserverConfig {
            motor: config.current.current.motor,
            ts_s: config.current.current.ts_s,
            dead_time_s: config.current.supervisor.model.dead_time_s,
            current_floor_a: config.current.supervisor.model.floor_a,
        });
        let mut obs = obs;
        // As beside a sensor in the drive (`Sensorless::set_agrees_with_sensor`).
        obs.set_low_speed_scaling(true);
        let mut fixed = obs;
        fixed.set_flux_tracking(false);
        Self {
            sim,
            obs,
            fixed,
            pole_pairs: f32::from(s.motor.pole_pairs),
            agree: 0,
            ts_s: config.current.current.ts_s,
        }
    }

    /// One period; returns the angle error [rad] and the speed error
    /// [rad/s, electrical] of the observer at the sample's instant, and the
    /// angle error of the one without tracking.
    fn step(&mut self) -> (f32, f32, f32) {
        let truth = self.sim.plant.theta_e();
        let w_e = self.sim.plant.omega_m_rad_s() as f32 * self.pole_pairs;
        let smp = self.sim.sample();
        let i_ab = transforms::clarke(smp.currents.unwrap().to_abc());
        let v_bus = smp.v_bus_v.unwrap();
        self.obs.update(i_ab);
        self.fixed.update(i_ab);
        // As beside a sensor (limp-home): the flux linkage is tracked once
        // the observer has agreed with the rotor's angle (0.5 rad) for
        // 5 ms.
        let apart = self.obs.angle().diff_radians(truth).abs() >= 0.5;
        self.agree = if apart { 0 } else { self.agree + 1 };
        self.obs.set_locked(self.agree as f32 * self.ts_s >= 5e-3);
        let err = (
            self.obs.angle().diff_radians(truth),
            self.obs.speed_rad_s() - w_e,
            self.fixed.angle().diff_radians(truth),
        );
        match self.sim.step_with(&smp) {
            BridgeCommand::Duties(d) => {
                self.obs.record(d, v_bus);
                self.fixed.record(d, v_bus);
            }
            BridgeCommand::SafeState | BridgeCommand::ShortCircuit => {
                self.obs.pause();
                self.fixed.pause();
            }
        }
        err
    }
}

/// What one velocity segment showed: the largest angle error while the
/// speed was changing and over the segment's last 20 %, the mean speed
/// error there (relative), the speed reached [rad/s, mechanical].
struct Segment {
    moving_rad: f32,
    steady_rad: f32,
    /// The steady error without the flux linkage's tracking.
    steady_fixed_rad: f32,
    steady_speed_rel: f32,
    speed_rad_s: f32,
}

fn segment(run: &mut Run, s: &Setup, to: f32, load_nm: f32, from: f32) -> Segment {
    run.sim.load_nm = load_nm;
    run.sim
        .cascade
        .command(Command::Velocity { rad_s: to })
        .unwrap();
    let accel = s.kt() * s.max_current_a / s.motor.inertia_kg_m2 as f32;
    let t = 2.0 * (to - from).abs() / accel + 0.1;
    let n = (t.min(0.6) * s.pwm_hz()) as usize;
    let top = s.max_speed_rad_s().min(s.max_mission_speed_rad_s());
    let (mut moving, mut steady, mut steady_fixed) = (0.0f32, 0.0f32, 0.0f32);
    let (mut sum_we, mut sum_w) = (0.0f32, 0.0f32);
    for k in 0..n {
        let (e, we, e_fixed) = run.step();
        assert!(run.sim.cascade.feedback().first_fault.is_none(), "fault");
        let w = run.sim.plant.omega_m_rad_s() as f32;
        if k * 5 >= n * 4 {
            steady = steady.max(e.abs());
            steady_fixed = steady_fixed.max(e_fixed.abs());
            sum_we += we;
            sum_w += w * run.pole_pairs;
        } else if w.abs() >= 0.1 * top {
            // While the speed changes: judged above a tenth of the top
            // speed (the start from standstill is a later part's).
            moving = moving.max(e.abs());
        }
    }
    Segment {
        moving_rad: moving,
        steady_rad: steady,
        steady_fixed_rad: steady_fixed,
        steady_speed_rel: (sum_we / sum_w).abs(),
        speed_rad_s: run.sim.plant.omega_m_rad_s() as f32,
    }
}

#[test]
fn observer_follows_the_rotor_on_every_motor_file() {
    let mut failures = Vec::new();
    for (p, r_factor, psi_factor) in all_motor_files()
        .into_iter()
        .flat_map(|p| [(p.clone(), 1.0, 1.0), (p.clone(), 1.3, 1.0), (p, 1.0, 0.9)])
    {
        let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
        let mut s = Setup::load(&p).unwrap();
        s.bench.sensors.encoder_offset_rad = 0.0;
        let top = s.max_speed_rad_s().min(s.max_mission_speed_rad_s());
        let rated_load = s.kt() * s.rated_current_a;
        let mut run = Run::new(&s, r_factor, psi_factor);
        let mut from = 0.0;
        let mut tracked_at_speed = false;
        let stem = format!("{stem} (plant R x{r_factor}, flux linkage x{psi_factor})");
        let mut line = format!("{stem}:");
        let segments = [
            (0.1, 0.0),
            (0.05, 0.0),
            (0.02, 0.0),
            (0.2, 0.0),
            (0.5, 0.0),
            (0.9, 0.0),
            (-0.5, 0.0),
            (-0.5, -rated_load),
        ];
        for (f, load) in segments {
            let to = f * top;
            let seg = segment(&mut run, &s, to, load, from);
            line += &format!(
                " [{f:+} top{}: {:.1} rad/s, steady {:.4} rad (untracked {:.4}), speed {:.2} %, moving {:.4} rad]",
                if load != 0.0 { ", rated load" } else { "" },
                seg.speed_rad_s,
                seg.steady_rad,
                seg.steady_fixed_rad,
                100.0 * seg.steady_speed_rel,
                seg.moving_rad
            );
            // Steady speed asserted from a tenth of the top speed up; below
            // it printed (the observer's low-speed figures).
            // With the resistance 30 % off the figures are printed only: a
            // warm winding the observer does not know of costs the angle at
            // the current limit (design §26: resistance tracking is a later
            // part).
            // A warm magnet: judged once the flux linkage has been tracked
            // at half the top speed.
            let judged = f64::from(f).abs() >= 0.1
                && r_factor == 1.0
                && (psi_factor == 1.0 || tracked_at_speed);
            if judged && (seg.steady_rad > STEADY_LIMIT_RAD || seg.steady_speed_rel > 0.02) {
                failures.push(format!("{stem} at {f} of top speed: steady"));
            }
            let nominal = r_factor == 1.0 && psi_factor == 1.0;
            if (nominal || judged) && seg.moving_rad > ACCEL_LIMIT_RAD {
                failures.push(format!("{stem} towards {f} of top speed: accelerating"));
            }
            from = to;
            tracked_at_speed |= f >= 0.5;
        }
        let psi = (s.motor.flux_linkage_wb * psi_factor) as f32;
        let tracked = run.obs.flux_linkage_wb();
        line += &format!(" flux linkage in use {tracked:.5} Wb (true {psi:.5})");
        // The warm magnet: tracked to within 2 %.
        if psi_factor != 1.0 && (tracked - psi).abs() > 0.02 * psi {
            failures.push(format!("{stem}: flux linkage {tracked} vs {psi}"));
        }
        println!("{line}");
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
