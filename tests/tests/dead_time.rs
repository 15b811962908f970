//! Dead-time compensation (design §31, issue 38) on every motor file in
//! `tests/motors/`: the plant's inverter with the board's dead time the
//! file states (`dead_time_ns`: 1 us on the 540 V interior-PM file,
//! 200 to 500 ns on the low-voltage ones; the emulated board's
//! `DEAD_TIME_NS` where a file states none) and the carrier-compared PWM
//! (the dead interval resolved per sub-step, its sign from the current
//! there).
//!
//! - Torque mode at the rated current, rotor held at 2 % of the no-load
//!   speed (`Mechanics::ConstantSpeed`): the phase current's 5th and 7th
//!   harmonics (relative to the fundamental, a DFT at the rotor's
//!   electrical angle over whole electrical turns, all three phases) and
//!   the q current's ripple, with the compensation off and on, and on a
//!   plant without dead time (what the sensor and the loop leave: the
//!   floor). The dead time's share is the harmonic phasor's distance from
//!   the floor's. Where that share is significant (5th + 7th above
//!   [`SIGNIFICANT_PCT`] of the fundamental without the compensation), the
//!   compensation must at least halve it and lower the q ripple; nowhere
//!   may it make the harmonics worse; no fault either way.
//! - Velocity mode at low speed through a reversal (free rotor), off and
//!   on: no fault, and the speed follows as well as without it.
//!
//! `cargo test -p foc-bench --test dead_time -- --nocapture` prints the
//! figures per motor file.

// `Real` is f64 or f32 by feature: casts to f64 are no-ops in one of the two.
#![allow(clippy::unnecessary_cast)]

use foc_bench::mission::{Setup, Sim};
use foc_bench::motor_file::{all_motor_files, MotorFile};
use foc_bench::plant::{Mechanics, PwmMode};
use foc_core::control::dead_time::DeadTimeCompensation;
use foc_core::control::Command;
use foc_core::drive::cascade::CascadeConfig;
use std::f64::consts::TAU;

/// The emulated board's dead time \[s\], for a file that states none.
const EMULATED_DEAD_TIME_S: f64 = foc_plant::emulated::DEAD_TIME_NS as f64 * 1e-9;

/// Share of the no-load speed the rotor is held at.
const SPEED_SHARE: f32 = 0.02;

/// Every motor file, with its board's dead time and the carrier-compared
/// inverter.
fn setups() -> Vec<(String, Setup)> {
    all_motor_files()
        .iter()
        .map(|p| {
            let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
            let f = MotorFile::load(p).unwrap();
            let mut s = Setup::from_file(&f);
            s.bench.sensors.encoder_offset_rad = 0.0;
            s.bench.pwm_mode = PwmMode::CarrierCompared;
            f.imperfections().apply_bench(&mut s.bench);
            if s.bench.dead_time_s <= 0.0 {
                s.bench.dead_time_s = EMULATED_DEAD_TIME_S as _;
            }
            (stem, s)
        })
        .collect()
}

/// The drive's configuration for `s` (the board's dead time known to it),
/// the compensation on or off.
fn config(s: &Setup, on: bool) -> CascadeConfig {
    let mut c = s.cascade_config();
    let want = DeadTimeCompensation::for_current_limit(s.bench.dead_time_s as f32, s.max_current_a);
    // `Setup::cascade_config` sets it from the bench's dead time, as the
    // firmware does from the board's.
    assert_eq!(c.current.current.dead_time, want);
    if !on {
        c.current.current.dead_time = DeadTimeCompensation::OFF;
    }
    c
}

/// Harmonic phasors of one phase current: the fundamental's amplitude
/// \[A\] and the 5th and 7th relative to it (complex, `(re, im)`).
#[derive(Debug, Clone, Copy)]
struct Phasors {
    fundamental_a: f64,
    h5: (f64, f64),
    h7: (f64, f64),
}

/// The figures of one torque-mode run.
#[derive(Debug, Clone, Copy)]
struct Figures {
    /// Per phase.
    phases: [Phasors; 3],
    /// Standard deviation of the true q current [% of the reference].
    iq_std_pct: f64,
    /// Peak-to-peak of the true q current [% of the reference].
    iq_pp_pct: f64,
    /// A fault latched during the run.
    faulted: bool,
}

impl Figures {
    /// Fundamental \[A\], mean over the phases.
    fn fundamental_a(&self) -> f64 {
        self.phases.iter().map(|p| p.fundamental_a).sum::<f64>() / 3.0
    }

    /// The 5th and 7th harmonics' amplitudes [% of the fundamental], mean
    /// over the phases; against `floor`'s phasors when given (the dead
    /// time's share).
    fn h5_h7_pct(&self, floor: Option<&Figures>) -> (f64, f64) {
        let dist =
            |a: (f64, f64), b: (f64, f64)| ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt();
        let (mut h5, mut h7) = (0.0, 0.0);
        for (k, p) in self.phases.iter().enumerate() {
            let f = floor.map_or(
                Phasors {
                    fundamental_a: 0.0,
                    h5: (0.0, 0.0),
                    h7: (0.0, 0.0),
                },
                |f| f.phases[k],
            );
            h5 += dist(p.h5, f.h5) / 3.0;
            h7 += dist(p.h7, f.h7) / 3.0;
        }
        (100.0 * h5, 100.0 * h7)
    }
}

/// Harmonic `n` of `x` sampled at electrical angles `th` (whole turns):
/// `(re, im)` of its complex amplitude.
fn harmonic(x: &[f64], th: &[f64], n: f64) -> (f64, f64) {
    let (mut re, mut im) = (0.0, 0.0);
    for (v, t) in x.iter().zip(th) {
        re += v * (n * t).cos();
        im -= v * (n * t).sin();
    }
    let k = 2.0 / x.len() as f64;
    (k * re, k * im)
}

/// The phasors of one phase, the harmonics relative to the fundamental
/// and turned into its frame (so that they compare between runs).
fn phasors(x: &[f64], th: &[f64]) -> Phasors {
    let h1 = harmonic(x, th, 1.0);
    let m1 = (h1.0 * h1.0 + h1.1 * h1.1).sqrt();
    let (c, s) = (h1.0 / m1, h1.1 / m1);
    // Divided by the fundamental (magnitude and phase): h / h1.
    let rel = |h: (f64, f64)| ((h.0 * c + h.1 * s) / m1, (h.1 * c - h.0 * s) / m1);
    Phasors {
        fundamental_a: m1,
        h5: rel(harmonic(x, th, 5.0)),
        h7: rel(harmonic(x, th, 7.0)),
    }
}

/// The plant's dead time and the drive's compensation of one run.
#[derive(Clone, Copy, Debug)]
enum Case {
    /// No dead time in the plant, no compensation: the floor.
    NoDeadTime,
    /// The board's dead time, no compensation.
    Off,
    /// The board's dead time, compensated with these values.
    On(DeadTimeCompensation),
}

/// Torque mode at the rated current, rotor held at `SPEED_SHARE` of the
/// no-load speed; settles for a quarter turn (at least 0.05 s), then
/// measures over two electrical turns.
fn torque_run(s: &Setup, case: Case) -> Figures {
    let mut s = s.clone();
    let mut c = config(&s, true);
    c.current.current.dead_time = match case {
        Case::On(dt) => dt,
        Case::Off | Case::NoDeadTime => DeadTimeCompensation::OFF,
    };
    if let Case::NoDeadTime = case {
        s.bench.dead_time_s = 0.0;
    }
    let mut sim = Sim::new_calibrated(&s, c, false);
    let w_m = SPEED_SHARE * s.max_speed_rad_s();
    sim.plant.set_mechanics(Mechanics::ConstantSpeed(w_m as _));
    let iq = s.rated_current_a.min(s.max_current_a);
    sim.cascade.command(Command::Torque { iq_a: iq }).unwrap();
    let pwm = s.bench.pwm_frequency_hz as f64;
    let w_e = w_m as f64 * s.motor.pole_pairs as f64;
    let per_turn = TAU / w_e * pwm;
    let settle = ((0.25 * per_turn) as usize).max((0.05 * pwm) as usize);
    sim.run(settle);
    let n = (2.0 * per_turn).round() as usize;
    let mut phases = [
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    ];
    let (mut th, mut iq_true) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let theta0 = sim.plant.theta_e_rad() as f64;
    for k in 0..n {
        // The currents at each period's boundary, at the rotor's angle
        // there (the speed is held: the angle is exactly linear).
        let i = sim.plant.phase_currents_a();
        for (p, v) in phases.iter_mut().zip(i) {
            p.push(v as f64);
        }
        th.push(theta0 + w_e * k as f64 / pwm);
        iq_true.push(sim.plant.iq_a() as f64);
        sim.step();
    }
    let faulted = !sim.cascade.feedback().faults.is_empty();
    let mean = iq_true.iter().sum::<f64>() / n as f64;
    let var = iq_true.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
    let (lo, hi) = iq_true
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), x| (l.min(*x), h.max(*x)));
    Figures {
        phases: [
            phasors(&phases[0], &th),
            phasors(&phases[1], &th),
            phasors(&phases[2], &th),
        ],
        iq_std_pct: 100.0 * var.sqrt() / iq as f64,
        iq_pp_pct: 100.0 * (hi - lo) / iq as f64,
        faulted,
    }
}

/// One line of figures: the harmonics as measured and, against `floor`,
/// the dead time's share.
fn print(name: &str, s: &Setup, what: &str, f: &Figures, floor: &Figures) {
    let (h5, h7) = f.h5_h7_pct(None);
    let (d5, d7) = f.h5_h7_pct(Some(floor));
    println!(
        "{name:>15} {:>4.0} ns {what:>5}: I1 {:6.3} A, 5th {:6.3} %, 7th {:6.3} % (dead time's: {:6.3} %, {:6.3} %), iq std {:6.3} %, p-p {:6.3} %{}",
        s.bench.dead_time_s * 1e9,
        f.fundamental_a(),
        h5,
        h7,
        d5,
        d7,
        f.iq_std_pct,
        f.iq_pp_pct,
        if f.faulted { ", FAULT" } else { "" }
    );
}

/// The dead time's 5th + 7th above this share of the fundamental [%]
/// without the compensation: significant (20 times the figures'
/// resolution in these runs, about 0.005 %).
const SIGNIFICANT_PCT: f64 = 0.1;

#[test]
fn low_speed_harmonics_halved_on_every_motor_file() {
    for (name, s) in setups() {
        let floor = torque_run(&s, Case::NoDeadTime);
        let off = torque_run(&s, Case::Off);
        let on = torque_run(&s, Case::On(config(&s, true).current.current.dead_time));
        print(&name, &s, "none", &floor, &floor);
        print(&name, &s, "off", &off, &floor);
        print(&name, &s, "on", &on, &floor);
        assert!(!off.faulted && !on.faulted, "{name}: a fault");
        // The torque is the same: the fundamental within 1 %.
        assert!(
            (on.fundamental_a() / off.fundamental_a() - 1.0).abs() < 0.01,
            "{name}: {} A vs {} A",
            on.fundamental_a(),
            off.fundamental_a()
        );
        let sum = |(a, b): (f64, f64)| a + b;
        let (d_off, d_on) = (
            sum(off.h5_h7_pct(Some(&floor))),
            sum(on.h5_h7_pct(Some(&floor))),
        );
        let (h_off, h_on) = (sum(off.h5_h7_pct(None)), sum(on.h5_h7_pct(None)));
        if d_off > SIGNIFICANT_PCT {
            assert!(
                d_on <= 0.5 * d_off,
                "{name}: the dead time's 5th + 7th {d_off:.3} % -> {d_on:.3} %"
            );
            assert!(
                h_on < h_off,
                "{name}: 5th + 7th {h_off:.3} % -> {h_on:.3} %"
            );
            assert!(
                on.iq_std_pct < off.iq_std_pct,
                "{name}: q ripple {:.3} % -> {:.3} %",
                off.iq_std_pct,
                on.iq_std_pct
            );
        } else {
            // Not significant here: it must not make it worse by more than
            // the figures' resolution.
            assert!(
                h_on <= h_off + 0.02,
                "{name}: 5th + 7th {h_off:.3} % -> {h_on:.3} %"
            );
        }
    }
}

/// The band's choice ([`foc_core::control::dead_time::DEFAULT_BAND_SHARE`]):
/// the figures at 1, 2, 5, 10 and 20 % of the current limit (design §31).
#[test]
#[ignore = "figures for design §31: run with --ignored --nocapture"]
fn band_sweep() {
    for (name, s) in setups() {
        let floor = torque_run(&s, Case::NoDeadTime);
        print(&name, &s, "none", &floor, &floor);
        print(&name, &s, "off", &torque_run(&s, Case::Off), &floor);
        for share in [0.01f32, 0.02, 0.05, 0.1, 0.2] {
            let dt = DeadTimeCompensation {
                dead_time_s: s.bench.dead_time_s as f32,
                band_a: share * s.max_current_a,
            };
            let f = torque_run(&s, Case::On(dt));
            print(&name, &s, &format!("{:.0}%", 100.0 * share), &f, &floor);
        }
    }
}

/// Velocity mode at low speed, free rotor: up to +4 % of the no-load
/// speed, a reversal through zero to -4 %, back to rest. No fault; the
/// worst speed error over the second half of each segment.
fn reversal(name: &str, s: &Setup, on: bool) -> f32 {
    let c = config(s, on);
    assert_eq!(
        c.current
            .current
            .dead_time
            .gains(c.current.current.ts_s)
            .is_on(),
        on
    );
    let mut sim = Sim::new_calibrated(s, c, false);
    let w = 0.04 * s.max_speed_rad_s();
    let pwm = s.bench.pwm_frequency_hz;
    let mut worst = 0.0f32;
    for (target, secs) in [(w, 0.4), (-w, 0.6), (0.0, 0.4)] {
        sim.cascade
            .command(Command::Velocity { rad_s: target })
            .unwrap();
        let n = (secs * pwm) as usize;
        for k in 0..n {
            sim.step();
            let fb = sim.cascade.feedback();
            assert!(
                fb.faults.is_empty(),
                "{name} (compensation {on}): {:?} at {target} rad/s, period {k}",
                fb.first_fault
            );
            if k > n / 2 {
                let err = (sim.plant.omega_m_rad_s() as f32 - target).abs();
                worst = worst.max(err);
            }
        }
    }
    worst
}

/// The closed loop through a reversal with the compensation on: no fault,
/// and the speed held as well as without it (within 20 % and 1 % of the
/// step).
#[test]
fn velocity_reversal_with_compensation_on_every_motor_file() {
    for (name, s) in setups() {
        let w = 0.04 * s.max_speed_rad_s();
        let off = reversal(&name, &s, false);
        let on = reversal(&name, &s, true);
        println!(
            "{name:>15}: reversal at +-{w:.2} rad/s, worst speed error in the second halves: off {off:.4} rad/s, on {on:.4} rad/s ({:.2} % / {:.2} % of the step)",
            100.0 * off / w,
            100.0 * on / w
        );
        assert!(on <= 1.2 * off + 0.01 * w, "{name}: {off} -> {on} rad/s");
    }
}

/// The emulated board as the firmware configures it (`config::cascade`:
/// the model check's dead time and the compensation from
/// `board::DEAD_TIME_NS`), on its plant (200 ns, ADC noise and offsets):
/// torque 0 held for 0.2 s, then a 5 A step, compensation off and on. No
/// fault; the model check's margins (peak residual / bound, peak
/// disturbance / envelope; a trip needs several periods over 1) printed.
#[test]
fn emulated_board_hold_and_step_stay_quiet_with_compensation() {
    use foc_bench::scope_step::{emulated_setup, MAX_CURRENT_A};
    let setup = emulated_setup();
    let pwm = setup.bench.pwm_frequency_hz as f32;
    let dead_time_s = foc_plant::emulated::DEAD_TIME_NS as f32 * 1e-9;
    for on in [false, true] {
        let mut config = CascadeConfig::for_motor(
            foc_bench::mission::control_motor(&setup.motor),
            pwm,
            MAX_CURRENT_A,
        );
        config.current.supervisor.model.dead_time_s = dead_time_s;
        if on {
            config.current.current.dead_time =
                DeadTimeCompensation::for_current_limit(dead_time_s, MAX_CURRENT_A);
        }
        let mut sim = Sim::new_calibrated(&setup, config, false);
        let o = setup.bench.sensors.current_offset_a;
        sim.set_current_offsets(foc_core::frames::Abc::new(
            o[0] as f32,
            o[1] as f32,
            o[2] as f32,
        ));
        for (iq, secs) in [(0.0, 0.2), (5.0, 0.05)] {
            sim.cascade.command(Command::Torque { iq_a: iq }).unwrap();
            for k in 0..(secs * pwm) as usize {
                sim.step();
                let fb = sim.cascade.feedback();
                assert!(
                    fb.faults.is_empty(),
                    "compensation {on}: {:?} at {iq} A, period {k}",
                    fb.first_fault
                );
            }
        }
        let m = sim.cascade.current.model_check();
        println!(
            "emulated board, compensation {on}: model check margins {:.2} / {:.2}",
            m.peak_ratio(),
            m.peak_disturbance_ratio()
        );
    }
}

/// The flux observer (design §26) beside the encoder reads the duties
/// handed to the bridge, compensation included, less the dead time's
/// error by the measured currents' signs: that is the bridge's voltage
/// with the compensation on as with it off, so its angle must be as good
/// (or better: the current it integrates is cleaner). Torque mode at the
/// rated current, rotor held at 5 % and 20 % of the no-load speed; the
/// mean and largest angle error over the last 0.15 s of 0.3 s.
#[test]
fn flux_observer_beside_the_encoder_with_compensation() {
    use foc_core::control::flux_observer::{FluxObserver, ObserverConfig};
    use foc_core::control::BridgeCommand;
    use foc_core::transforms;
    for (name, s) in setups() {
        for share in [0.05f32, 0.2] {
            let mut figures = [(0.0f32, 0.0f32); 2];
            for (k, on) in [false, true].into_iter().enumerate() {
                let c = config(&s, on);
                let mut sim = Sim::new_calibrated(&s, c, false);
                let mut obs = FluxObserver::new(ObserverConfig {
                    motor: c.current.current.motor,
                    ts_s: c.current.current.ts_s,
                    dead_time_s: c.current.supervisor.model.dead_time_s,
                    current_floor_a: c.current.supervisor.model.floor_a,
                });
                obs.set_low_speed_scaling(true);
                obs.set_flux_tracking(false);
                let w_m = share * s.max_speed_rad_s();
                sim.plant.set_mechanics(Mechanics::ConstantSpeed(w_m as _));
                let iq = s.rated_current_a.min(s.max_current_a);
                sim.cascade.command(Command::Torque { iq_a: iq }).unwrap();
                let n = (0.3 * s.pwm_hz()) as usize;
                let (mut sum, mut max, mut count) = (0.0f32, 0.0f32, 0usize);
                for p in 0..n {
                    let truth = sim.plant.theta_e();
                    let smp = sim.sample();
                    let i_ab = transforms::clarke(smp.currents.unwrap().to_abc());
                    let v_bus = smp.v_bus_v.unwrap();
                    obs.update(i_ab);
                    if p >= n / 2 {
                        let e = obs.angle().diff_radians(truth).abs();
                        sum += e;
                        max = max.max(e);
                        count += 1;
                    }
                    match sim.step_with(&smp) {
                        BridgeCommand::Duties(d) => obs.record(d, v_bus),
                        _ => obs.pause(),
                    }
                    assert!(sim.cascade.feedback().faults.is_empty(), "{name}: fault");
                }
                figures[k] = (sum / count as f32, max);
            }
            let [(off_mean, off_max), (on_mean, on_max)] = figures;
            println!(
                "{name:>15} at {:>2.0} % speed: observer angle error off {off_mean:.4} rad (max {off_max:.4}), on {on_mean:.4} rad (max {on_max:.4})",
                100.0 * share
            );
            assert!(
                on_mean <= 1.1 * off_mean + 0.002,
                "{name}: {off_mean} -> {on_mean} rad"
            );
        }
    }
}
