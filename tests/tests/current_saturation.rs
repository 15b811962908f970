//! Issue 18, current loop: after a saturated period the q and d currents
//! settle as fast as they would unsaturated.
//!
//! The real `foc-core` cascade on the bench plant (one period of
//! computation delay, PWM averaged over the period), rotor locked, ideal
//! sensors, for every motor file in `motors/`: a q-current step whose first
//! periods are on the voltage limit (the step's first PI output
//! `(kp + ki Ts) I` is 1.6 or 2 times the voltage circle, with the bus
//! lowered where the motor's current limit would not allow such a step at
//! its nominal bus) reaches and stays within 2 % of the step in at most 12
//! PWM periods, with the d current staying small. The step within the
//! circle keeps its figures (2 % in at most 12 periods, about the technical
//! optimum's 4.3 % overshoot) bit for bit: the anti-windup never acts there.
//!
//! Each case also prints the figures with conditional integration
//! (`AntiWindup::Clamp`, the default before), for comparison.

// `Real` is f64 or f32 by feature: casts to f64 are no-ops in one of the two.
#![allow(clippy::unnecessary_cast)]

use foc_bench::metrics;
use foc_bench::mission::{Setup, Sim};
use foc_bench::motor_file::MotorFile;
use foc_bench::plant::{Mechanics, SensorConfig};
use foc_core::control::current::DEFAULT_ANTI_WINDUP;
use foc_core::control::{BridgeCommand, Command};
use foc_core::drive::cascade::CascadeConfig;
use foc_core::pi::AntiWindup;
use std::path::PathBuf;

/// Every motor file, sorted.
fn motor_files() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("motors");
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("motors/")
        .map(|e| e.expect("dir entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    assert!(v.len() >= 5, "{v:?}");
    v
}

/// A motor file's setup on ideal sensors (the loop's dynamics, not the
/// sensors', are under test), encoder zero on the d axis, bus `bus_v`.
fn setup(path: &PathBuf, bus_v: f64) -> Setup {
    let f = MotorFile::load(path).expect("motor file");
    let mut s = Setup::from_file(&f);
    s.bench.sensors = SensorConfig::ideal();
    s.bench.sensors.encoder_offset_rad = 0.0;
    s.bench.bus_voltage_v = bus_v as _;
    s
}

/// The bench configuration (supervisor limits follow the bus) with the
/// anti-windup `aw` (`None`: the default). The decoupling takes its speed
/// from the angle tracker, which sees only the sensor (on a locked rotor
/// the torque-fed speed observer's model is wrong for a moment; it does not
/// reach the current loop).
///
/// MTPA is off (design §30): these are q steps with `id = 0` held, the d
/// current the measure of the cross-coupling.
fn config(s: &Setup, aw: Option<AntiWindup>) -> CascadeConfig {
    let mut c = s.cascade_config();
    c.current.field.mtpa = false;
    if let Some(aw) = aw {
        c.current.current.anti_windup = aw;
    }
    c
}

/// The figures of one q-current step.
#[derive(Clone, Copy, Debug, PartialEq)]
struct StepFigures {
    /// Step \[A\].
    step_a: f64,
    /// Bus \[V\].
    bus_v: f64,
    /// Consecutive periods on the voltage limit from the step on.
    saturated: usize,
    /// Overshoot [% of the step] of the true q current.
    overshoot_pct: f64,
    /// 2 % settling [PWM periods] of the true q current (to the end of the
    /// run: it reaches the band and stays).
    settling: Option<usize>,
    /// The same into 1 % (printed only: it shows the slow tail).
    settling_1pct: Option<usize>,
    /// Largest true d current \[A\].
    id_max_a: f64,
}

/// A q-current step `step_a` from 0 on a locked rotor at bus `bus_v`, with
/// the anti-windup `aw` (`None`: the default). Counted from the period the
/// reference changes, over 400 periods, at the sample instants.
fn q_step(path: &PathBuf, bus_v: f64, step_a: f32, aw: Option<AntiWindup>) -> StepFigures {
    let s = setup(path, bus_v);
    let mut sim = Sim::new_calibrated(&s, config(&s, aw), true);
    sim.plant.set_mechanics(Mechanics::Locked);
    sim.cascade.command(Command::Torque { iq_a: 0.0 }).unwrap();
    sim.run(20);
    let start = sim.rows();
    sim.cascade
        .command(Command::Torque { iq_a: step_a })
        .unwrap();
    let mut saturated = 0;
    for k in 0..400 {
        let bridge = sim.step();
        assert!(
            matches!(bridge, BridgeCommand::Duties(_)),
            "{path:?}: {bridge:?}"
        );
        if sim.cascade.feedback().voltage_limited && saturated == k {
            saturated += 1;
        }
    }
    let fb = sim.cascade.feedback();
    assert!(fb.first_fault.is_none(), "{path:?}: {:?}", fb.first_fault);
    let tr = sim.trace().unwrap();
    let iq = &tr.column("iq_true_a").unwrap()[start..];
    let id = &tr.column("id_true_a").unwrap()[start..];
    let iq_ref = &tr.column("iq_ref_a").unwrap()[start..];
    assert!(
        iq_ref.iter().all(|r| *r == step_a as f64),
        "the reference is the step"
    );
    let step = step_a as f64;
    StepFigures {
        step_a: step,
        bus_v,
        saturated,
        overshoot_pct: metrics::overshoot_percent(iq, 0.0, step),
        settling: metrics::settling_index(iq, 0.0, step, 0.02),
        settling_1pct: metrics::settling_index(iq, 0.0, step, 0.01),
        id_max_a: id.iter().fold(0.0f64, |m, v| m.max(v.abs())),
    }
}

/// The q PI's gains and period for a setup: `(kp, ki Ts, R)`.
fn q_gains(s: &Setup) -> (f32, f32, f32) {
    let c = s.cascade_config().current.current;
    (
        c.q_gains.kp_v_per_a,
        c.q_gains.ki_v_per_a_s * c.ts_s,
        s.motor.r_ohm as f32,
    )
}

/// The saturated case for `ratio` (first PI output over the circle): the
/// step `I` and the bus. `I` is the step whose first PI output
/// `(kp + ki Ts) I` is `ratio` times the nominal bus's circle, but at most
/// half the motor's current limit; the bus is then set so that the circle
/// is `(kp + ki Ts) I / ratio`, but at least `1.15 R I` (the current must
/// be reachable with room to spare: on the DJI M2006 `kp` is below `R`, so
/// there the first output is only 1.26 `R I` and the saturation shorter).
fn saturated_case(path: &PathBuf, ratio: f32) -> (f32, f64) {
    let nominal = MotorFile::load(path).expect("motor file").bus_voltage_v as f64;
    let s = setup(path, nominal);
    let (kp, ki_ts, r) = q_gains(&s);
    let k0 = kp + ki_ts;
    let circle = |bus: f32| 0.95 * bus / 3f32.sqrt();
    let step = (ratio * circle(nominal as f32) / k0).min(0.5 * s.max_current_a);
    let v = (k0 * step / ratio).max(1.15 * r * step);
    (step, (v * 3f32.sqrt() / 0.95) as f64)
}

fn show(name: &str, what: &str, f: &StepFigures) -> String {
    format!(
        "{name:<20} {what:<28} step {:6.2} A at {:5.2} V: {} periods saturated, \
         overshoot {:5.2} %, 2 % settling {:?} periods (1 %: {:?}), |id| <= {:.4} A",
        f.step_a, f.bus_v, f.saturated, f.overshoot_pct, f.settling, f.settling_1pct, f.id_max_a
    )
}

/// The target: a q-current step whose first two or more periods
/// are on the voltage limit settles into 2 % within 12 periods (and into
/// 1 % within 16) on every motor file, overshoot within the technical
/// optimum's, d current below 2 % of the step.
#[test]
fn saturated_q_step_settles_within_12_periods_on_every_motor() {
    assert_eq!(
        setup(&motor_files()[0], 24.0)
            .cascade_config()
            .current
            .current
            .anti_windup,
        DEFAULT_ANTI_WINDUP
    );
    let mut failures = Vec::new();
    for path in motor_files() {
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        for ratio in [1.6f32, 2.0] {
            let (step, bus) = saturated_case(&path, ratio);
            let f = q_step(&path, bus, step, None);
            let before = q_step(&path, bus, step, Some(AntiWindup::Clamp));
            println!("{}", show(&name, &format!("{ratio}x circle, default"), &f));
            println!(
                "{}",
                show(&name, &format!("{ratio}x circle, clamp (before)"), &before)
            );
            // 1 % as well, within a few periods of the unsaturated step's
            // 9 to 13: the tail conditional integration leaves on the M153
            // (about 1 %, decaying with L/R) stays inside 2 %, not 1 %.
            let ok = f.saturated >= 2
                && f.settling.is_some_and(|n| n <= 12)
                && f.settling_1pct.is_some_and(|n| n <= 16)
                && f.overshoot_pct < 4.3 + 1.5
                && f.id_max_a < 0.02 * f.step_a;
            if !ok {
                failures.push(format!("{name} {ratio}x: {f:?}"));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The step within the circle (first voltage `kp I` at 60 % of it, as in
/// `closed_loop.rs`, at the nominal bus): never saturated, the same figures
/// bit for bit with the default and with conditional integration, 2 %
/// within 12 periods and the technical optimum's overshoot (4.3 %, less on
/// the DJI M2006 whose `R Ts / L` is large).
#[test]
fn unsaturated_q_step_is_unchanged_on_every_motor() {
    let mut failures = Vec::new();
    for path in motor_files() {
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let nominal = MotorFile::load(&path).expect("motor file").bus_voltage_v as f64;
        let s = setup(&path, nominal);
        let (kp, _, _) = q_gains(&s);
        let circle = 0.95 * nominal as f32 / 3f32.sqrt();
        let step = (0.6 * circle / kp).min(0.5 * s.max_current_a);
        let f = q_step(&path, nominal, step, None);
        let before = q_step(&path, nominal, step, Some(AntiWindup::Clamp));
        println!("{}", show(&name, "within the circle, default", &f));
        assert_eq!(f, before, "{name}: the anti-windup acted within the circle");
        let ok = f.saturated == 0
            && f.settling.is_some_and(|n| n <= 12)
            && f.overshoot_pct < 4.3 + 1.5
            && f.id_max_a < 0.02 * f.step_a;
        if !ok {
            failures.push(format!("{name}: {f:?}"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
