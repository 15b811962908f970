//! Closed-loop tests: the real `foc-core` cascade on the bench plant (one
//! period of computation delay through the plant's shadow register, PWM
//! averaged over the period), deterministic (no sensor noise).

// `Real` is f64 or f32 by feature: casts to f64 are no-ops in one of the two.
#![allow(clippy::unnecessary_cast)]

use foc_bench::metrics;
use foc_bench::mission::{self, Setup, Sim};
use foc_bench::motor_file::MotorFile;
use foc_bench::plant::{EncoderFault, Mechanics, Phase, PhaseShort, SensorConfig};
use foc_core::control::{BridgeCommand, Command, Fault};
use foc_core::drive::cascade::CascadeConfig;
use foc_core::frames::Abc;
use foc_core::transforms;
use std::path::PathBuf;

fn motor_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("motors")
        .join(name)
}

/// A motor file's setup with the encoder zero on the d axis (the controller's
/// default calibration is then exact).
fn setup(name: &str) -> Setup {
    let f = MotorFile::load(motor_path(name)).unwrap();
    let mut s = Setup::from_file(&f);
    s.bench.sensors.encoder_offset_rad = 0.0;
    s
}

/// q-current step with the source's tuning on a locked rotor, ideal sensors.
/// Returns (overshoot %, 2 % settling in PWM periods) of the true current at
/// the sample instants, counted from the period the reference changes.
fn current_step(name: &str, pwm_hz: f64) -> (f64, Option<usize>) {
    let mut s = setup(name);
    s.bench.pwm_frequency_hz = pwm_hz;
    s.bench.sensors = SensorConfig::ideal();
    let config = s.cascade_config();
    // The gains are the technical optimum: Kp = L/(3 Ts), Ki = R/(3 Ts).
    let ts = 1.0 / pwm_hz as f32;
    let g = config.current.current.q_gains;
    let (l, r) = (s.motor.lq_h as f32, s.motor.r_ohm as f32);
    assert!((g.kp_v_per_a - l / (3.0 * ts)).abs() <= 1e-4 * g.kp_v_per_a);
    assert!((g.ki_v_per_a_s - r / (3.0 * ts)).abs() <= 1e-4 * g.ki_v_per_a_s);
    let mut sim = Sim::new_calibrated(&s, config, true);
    sim.plant.set_mechanics(Mechanics::Locked);
    sim.cascade.command(Command::Torque { iq_a: 0.0 }).unwrap();
    sim.run(20);
    // Within the linear range: the first voltage Kp * step is 60 % of it.
    let v_lin = 0.95 * s.bench.bus_voltage_v as f32 / 3f32.sqrt();
    let step = (0.6 * v_lin / g.kp_v_per_a).min(0.5 * s.max_current_a);
    let start = sim.rows();
    sim.cascade.command(Command::Torque { iq_a: step }).unwrap();
    sim.run(200);
    let tr = sim.trace().unwrap();
    let iq = &tr.column("iq_true_a").unwrap()[start..];
    let id = &tr.column("id_true_a").unwrap()[start..];
    assert!(
        id.iter().all(|d| d.abs() < 0.02 * step as f64),
        "id moved during a q step"
    );
    assert!(tr.column("vq_v").unwrap()[start..]
        .iter()
        .all(|v| (*v as f32) < v_lin));
    (
        metrics::overshoot_percent(iq, 0.0, step as f64),
        metrics::settling_index(iq, 0.0, step as f64, 0.02),
    )
}

/// Design §11: about 4.3 % overshoot. The discrete loop (one period
/// of delay, zero-order hold over the period) is slightly better damped than
/// the continuous `1.5 Ts` lag it is designed on.
#[test]
fn q_current_step_technical_optimum_15_and_20_khz() {
    for (motor, hz) in [
        ("m153-source.toml", 15_000.0),
        ("m153-source.toml", 20_000.0),
    ] {
        let (os, ts) = current_step(motor, hz);
        println!("{motor} at {hz} Hz: overshoot {os:.2} %, 2 % settling {ts:?} periods");
        assert!(
            (os - 4.3).abs() <= 1.5,
            "{motor} {hz} Hz: overshoot {os:.2} %"
        );
        let ts = ts.expect("settles");
        assert!(ts <= 12, "{motor} {hz} Hz: settling {ts} periods");
    }
}

/// With an electrical time constant of only 2-3 periods (`R Ts / L` = 0.36
/// to 0.48) the PI zero placed at `R/L` in continuous time no longer cancels
/// the discrete plant pole exactly: the step is better damped than the
/// technical optimum (measured 2.1 %). It must still settle within 12 periods
/// and stay below the optimum's overshoot.
#[test]
fn q_current_step_fast_electrical_time_constant() {
    for hz in [15_000.0, 20_000.0] {
        let (os, ts) = current_step("dji-m2006.toml", hz);
        println!("dji-m2006 at {hz} Hz: overshoot {os:.2} %, 2 % settling {ts:?} periods");
        assert!(os < 4.3 + 1.5, "overshoot {os:.2} %");
        assert!(ts.expect("settles") <= 12);
    }
}

fn running(name: &str, w: f32) -> Sim {
    let s = setup(name);
    let mut sim = Sim::new_calibrated(&s, s.cascade_config(), false);
    sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
    sim.run((0.4 * s.bench.pwm_frequency_hz) as usize);
    assert!(
        (sim.plant.omega_m_rad_s() as f32 - w).abs() < 0.02 * w,
        "not at speed: {}",
        sim.plant.omega_m_rad_s()
    );
    sim
}

/// Velocity step: settles in +-2 % within 120 ms with at most 40 %
/// overshoot (PI with its zero at a quarter of the 20 Hz bandwidth, no
/// reference filter); a load step of 30 % of the rated torque dips the speed
/// by 0.3 to 1.5 times `T / (J wc)` and leaves less than 0.1 % error after 0.4 s.
#[test]
fn speed_step_and_load_rejection() {
    let s = setup("gl80-kv30.toml");
    let f = s.bench.pwm_frequency_hz;
    let mut sim = Sim::new_calibrated(&s, s.cascade_config(), true);
    let w = 20.0f32;
    sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
    sim.run((0.4 * f) as usize);
    let tr = sim.trace().unwrap();
    let speed = tr.column("speed_rad_s").unwrap();
    let os = metrics::overshoot_percent(speed, 0.0, w as f64);
    let ts = metrics::settling_index(speed, 0.0, w as f64, 0.02).expect("settles") as f64 / f;
    println!(
        "speed step {w} rad/s: overshoot {os:.1} %, settling {:.1} ms",
        ts * 1e3
    );
    assert!(os < 40.0, "overshoot {os}");
    assert!(ts < 0.12, "settling {ts} s");
    let load = 0.3 * s.kt() * s.rated_current_a;
    let start = sim.rows();
    sim.load_nm = load;
    sim.run((0.4 * f) as usize);
    let tr = sim.trace().unwrap();
    let after = &tr.column("speed_rad_s").unwrap()[start..];
    let dip = after.iter().fold(0.0f64, |m, v| m.max(w as f64 - v));
    let err = metrics::steady_state_error(after, w as f64, (0.05 * f) as usize);
    println!("load step {load:.3} N m: dip {dip:.2} rad/s, steady error {err:.4} rad/s");
    // A PI speed loop of bandwidth wc on inertia J dips by about T / (J wc).
    let c = sim.cascade.config().speed;
    let wc = c.kp_a_per_rad_s * s.kt() / s.motor.inertia_kg_m2 as f32;
    let scale = (load / (s.motor.inertia_kg_m2 as f32 * wc)) as f64;
    println!("T/(J wc) = {scale:.2} rad/s");
    assert!(dip > 0.3 * scale && dip < 1.5 * scale, "dip {dip}");
    assert!(err.abs() < 1e-3 * w as f64, "steady error {err}");
}

/// Position move of 3 rad: within 2 encoder counts of the target 0.6 s after
/// the command, with the peak speed below 1.4 times the trajectory limit
/// (measured: 1.3 times; the speed loop lags the trapezoid's corners).
#[test]
fn position_move_reaches_target() {
    let s = setup("gl80-kv30.toml");
    let f = s.bench.pwm_frequency_hz;
    let config = s.cascade_config();
    let mut sim = Sim::new_calibrated(&s, config, false);
    sim.cascade.command(Command::Position { rad: 0.0 }).unwrap();
    sim.run((0.05 * f) as usize);
    let p0 = sim.true_position_rad();
    let target = sim.cascade.feedback().position_rad + 3.0;
    sim.cascade
        .command(Command::Position { rad: target })
        .unwrap();
    let mut w_max: f64 = 0.0;
    for _ in 0..(0.6 * f) as usize {
        sim.step();
        w_max = w_max.max(sim.plant.omega_m_rad_s().abs() as f64);
    }
    let moved = sim.true_position_rad() - p0;
    println!(
        "peak speed {w_max:.2} rad/s, limit {}",
        config.position.max_velocity_rad_s
    );
    let count = std::f64::consts::TAU / s.bench.sensors.encoder_counts_per_rev as f64;
    println!(
        "moved {moved:.5} rad (error {:.5} rad = {:.2} counts), peak speed {w_max:.2} rad/s",
        3.0 - moved,
        (3.0 - moved) / count
    );
    assert!((moved - 3.0).abs() < 2.0 * count, "moved {moved}");
    assert!(w_max < 1.4 * config.position.max_velocity_rad_s as f64);
}

/// The speed and position figures before issue 18 (`cargo xtask sim --all`
/// on main at 5b20272, the PLL-fed one-degree-of-freedom PI): motor file,
/// speed dip after the load step and rise after its release [rad/s],
/// position 2 % settling \[ms\].
const BEFORE_ISSUE_18: [(&str, f64, f64, f64); 5] = [
    ("cute-q85sx-hub", 27.708, 27.386, 115.2),
    ("dji-m2006", 22.494, 22.499, 90.5),
    ("gl80-kv30", 8.764, 8.763, 224.6),
    ("hkc-cheetah", 79.939, 79.911, 99.4),
    ("m153-source", 18.897, 15.367, 539.9),
];

/// Issue 18's figures on one mission (design §19): speed steps within and
/// beyond the current limit, load step and release against the figures
/// before, the speed estimate at the fastest acceleration, and the
/// position move no slower. The hub motor's 48-count hall-class sensor
/// (0.13 rad per count) gets the looser bounds its resolution allows.
fn check_speed_figures(stem: &str, s: &Setup, m: &mission::MissionSummary) {
    let sp = &m.speed;
    let hall = foc_bench::identify::hall_class(s);
    let (est_err, acc) = sp.fastest_estimate_error();
    println!(
        "{stem}: step overshoot {:.2} % (settling {:?} ms); current-limited step {:.2} % ({:.1} ms on the limit, settling {:?} ms); \
         dip {:.3} rise {:.3} rad/s (recovery {:?} / {:?} ms); estimate error at {acc:.0} rad/s^2: {est_err:.2} %; position {:?} ms, error {:.5} rad",
        m.speed_overshoot_percent,
        m.speed_settling_ms,
        sp.sat_overshoot_percent,
        sp.sat_limited_ms,
        sp.sat_settling_ms,
        m.load_dip_rad_s,
        sp.release_rise_rad_s,
        m.load_recovery_ms,
        sp.release_recovery_ms,
        m.position_settling_ms,
        m.position_final_error_rad,
    );
    assert!(m.speed_overshoot_percent <= 2.0, "{stem}: step overshoot");
    assert!(m.speed_settling_ms.is_some(), "{stem}: step settling");
    // At least 0.5 ms on the limit (GL80 with MTPA: 0.8 ms, its reluctance
    // torque accelerating it faster than `id = 0` did, 1.7 ms).
    assert!(
        sp.sat_limited_ms > 0.5,
        "{stem}: the current limit was not active"
    );
    assert!(
        sp.sat_overshoot_percent <= 5.0,
        "{stem}: current-limited overshoot"
    );
    assert!(
        sp.sat_settling_ms.is_some(),
        "{stem}: current-limited settling"
    );
    assert!(m.load_recovery_ms.is_some() && sp.release_recovery_ms.is_some());
    assert!(
        est_err <= if hall { 15.0 } else { 2.0 },
        "{stem}: estimate error {est_err} %"
    );
    // Motor files added after issue 18 (the 2.2 kW IPM, issue 32) have no
    // figures from before to hold.
    let Some(&(_, dip, rise, pos_ms)) = BEFORE_ISSUE_18.iter().find(|b| b.0 == stem) else {
        println!("{stem}: no figures from before issue 18 to compare");
        return;
    };
    assert!(
        m.load_dip_rad_s <= dip,
        "{stem}: dip {} > {dip}",
        m.load_dip_rad_s
    );
    assert!(
        sp.release_rise_rad_s <= rise,
        "{stem}: rise {} > {rise}",
        sp.release_rise_rad_s
    );
    // No slower: within 0.5 % (the gl80's trapezoid ends 0.3 % later).
    // Not for the hall-sensor hub motor: one of its counts (0.131 rad) is
    // wider than the 2 % band of the move (0.126 rad), so where the rotor
    // comes to rest inside a count decides its settling time (75.8 ms
    // before issue 32, 217.8 ms after a 0.6 % more accurate Lq; final
    // error -0.41 and -0.76 counts).
    let p = m.position_settling_ms.expect("position settles");
    if hall {
        println!("{stem}: position settling {p} ms (not compared: a count is wider than the band)");
    } else {
        assert!(p <= 1.005 * pos_ms, "{stem}: position {p} ms > {pos_ms}");
    }
}

/// The mission passes its criteria for every motor file, and reaches the
/// speed and position figures of issue 18 ([`check_speed_figures`]).
#[test]
fn mission_passes_for_every_motor_file() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("motors");
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            let s = Setup::load(&p).unwrap();
            let r = mission::run_mission(&s, &mut |_| {});
            let fails = r.summary.failures();
            assert!(fails.is_empty(), "{}: {fails:?}", p.display());
            assert!(r.summary.align_error_deg.abs() < 40.0);
            let stem = p.file_stem().unwrap().to_str().unwrap();
            check_speed_figures(stem, &s, &r.summary);
            n += 1;
        }
    }
    assert!(n >= 5);
}

/// Before its first identification the drive knows nothing of the rotor's
/// mechanics: the speed observer has no model (the tracker's loop) and the
/// speed loop no feed-forward, on the gains of a guessed inertia (design
/// §19; `CascadeConfig::for_motor`, 1e-5 kg m^2). On the light M2006
/// (3e-6 kg m^2) that guess makes the gain 3.3 times too large; a step and
/// a hold stay stable: no fault, never above 1.3 times the step, the last
/// 0.2 s within 1 % peak to peak (a feed-forward of the guessed inertia
/// against a disturbance learnt without a model made a limit cycle of
/// about +-600 rad/s here).
#[test]
fn unidentified_drive_is_stable_with_too_large_a_guessed_inertia() {
    let s = setup("dji-m2006.toml");
    let mut cfg = s.unidentified_config();
    let guess = CascadeConfig::for_motor(
        mission::control_motor(&s.motor),
        s.pwm_hz(),
        s.max_current_a,
    );
    cfg.speed = guess.speed;
    assert_eq!(cfg.current.observer.accel_per_a_rad_s2, 0.0);
    assert_eq!(cfg.speed.accel_ff_a_per_rad_s2, 0.0);
    let mut sim = Sim::new_calibrated(&s, cfg, false);
    let w = 0.2 * s.max_mission_speed_rad_s().min(0.6 * s.max_speed_rad_s());
    sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
    let f = s.pwm_hz() as f64;
    let n = (1.0 * f) as usize;
    let (mut peak, mut lo, mut hi) = (0.0f64, f64::INFINITY, f64::NEG_INFINITY);
    for k in 0..n {
        sim.step();
        let v = sim.plant.omega_m_rad_s();
        peak = peak.max(v);
        if k > n - (0.2 * f) as usize {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    println!("step {w:.1} rad/s, peak {peak:.2}, last 0.2 s {lo:.2} .. {hi:.2} rad/s");
    let fault = sim.cascade.feedback().first_fault;
    assert!(fault.is_none(), "{fault:?}");
    assert!(peak < 1.3 * w as f64, "peak {peak}");
    assert!(hi - lo < 0.01 * w as f64, "{lo} .. {hi}");
}

/// Runs the M2006 (7 pole pairs, 20 kHz) up a ramp to half its no-load
/// speed (1417 rad/s: w_e Ts = 0.50 rad, 12.6 periods per electrical turn,
/// the 1.5-period delay is 42 deg electrical), holds it, then takes a load
/// step of 40 % of the rated torque. Returns (peak |id| \[A\] of the true
/// current, the first fault if any).
fn high_speed_run(delay_compensation_periods: f32) -> (f64, Option<Fault>) {
    let s = setup("dji-m2006.toml");
    let mut c = s.cascade_config();
    c.current.current.delay_compensation_periods = delay_compensation_periods;
    let mut sim = Sim::new_calibrated(&s, c, true);
    let f = s.bench.pwm_frequency_hz as f32;
    let w = 0.5 * s.max_speed_rad_s();
    let accel = 0.3 * s.kt() * s.max_current_a / s.motor.inertia_kg_m2 as f32;
    let n = (w / accel * f) as usize;
    for k in 0..n {
        if k % 10 == 0 {
            let ramp = w * k as f32 / n as f32;
            // Refused once a fault latched (the uncompensated run trips).
            sim.cascade.command(Command::Velocity { rad_s: ramp }).ok();
        }
        sim.step();
    }
    sim.cascade.command(Command::Velocity { rad_s: w }).ok();
    sim.run((0.2 * f) as usize);
    sim.load_nm = 0.4 * s.kt() * s.rated_current_a;
    sim.run((0.2 * f) as usize);
    let fault = sim.cascade.feedback().first_fault;
    if fault.is_none() {
        assert!((sim.plant.omega_m_rad_s() as f32 - w).abs() < 0.01 * w);
    }
    let id = sim.trace().unwrap().column("id_true_a").unwrap();
    (id.iter().fold(0.0f64, |m, v| m.max(v.abs())), fault)
}

/// Computation-delay compensation (inverse Park at `theta_e + 1.5 w_e Ts`):
/// at half the no-load speed of the M2006 id stays within 0.15 A (5 % of
/// the rated current; measured 0.08 A) through the ramp and the load step.
/// Without it the voltage lags by 42 deg electrical, d and q couple and the
/// current loop oscillates until it trips (measured: id peak 10.9 A,
/// `OverCurrentPhase`, during the ramp; since the current-sense
/// plausibility check, `CurrentSenseError` first: the loop cannot track).
#[test]
fn delay_compensation_keeps_id_near_zero_at_high_speed() {
    let (with, fault) = high_speed_run(1.5);
    println!("with compensation: peak |id| {with:.3} A, fault {fault:?}");
    let (without, fault0) = high_speed_run(0.0);
    println!("without compensation: peak |id| {without:.3} A, fault {fault0:?}");
    assert_eq!(fault, None);
    assert!(with < 0.15, "peak |id| {with} A with compensation");
    assert!(
        fault0.is_some() || without > 1.0,
        "expected the uncompensated loop to fail: peak |id| {without} A"
    );
}

/// Step until `visible(sample)`; that very step must return the safe state
/// and latch one of `expected`, the plant's next period must have the
/// bridge off, and no fault may latch before. Returns the periods waited.
fn trips_at_once(
    sim: &mut Sim,
    max_periods: usize,
    expected: &[Fault],
    visible: impl Fn(&Sim) -> bool,
) -> usize {
    for k in 0..max_periods {
        let vis = visible(sim);
        let b = sim.step();
        let fb = *sim.cascade.feedback();
        if vis {
            assert_eq!(b, BridgeCommand::SafeState, "not safe in the same period");
            let f = fb.first_fault.expect("fault latched");
            assert!(
                expected.contains(&f),
                "latched {f:?}, expected {expected:?}"
            );
            sim.step();
            assert!(!sim.plant.bridge_enabled(), "bridge still on");
            // Latched: stays off.
            sim.run(10);
            assert!(!sim.plant.bridge_enabled());
            return k;
        }
        assert!(
            fb.first_fault.is_none(),
            "tripped early: {:?}",
            fb.first_fault
        );
        assert!(matches!(b, BridgeCommand::Duties(_)));
    }
    panic!("fault never became visible");
}

#[test]
fn phase_short_trips_over_current_at_once() {
    let mut sim = running("m153-source.toml", 10.0);
    let lim = sim.cascade.config().current.supervisor;
    sim.plant.faults_mut().phase_short = Some(PhaseShort {
        a: Phase::A,
        b: Phase::B,
        r_ohm: 0.01,
    });
    let k = trips_at_once(
        &mut sim,
        200,
        &[Fault::OverCurrentPhase, Fault::OverCurrentVector],
        |s| {
            let i = s.last_sample().currents.to_abc();
            let over = [i.a, i.b, i.c]
                .iter()
                .any(|x| x.abs() > lim.max_phase_current_a);
            over || transforms::clarke(Abc::new(i.a, i.b, i.c)).magnitude()
                > lim.max_vector_current_a
        },
    );
    println!("phase short visible after {k} periods");
}

#[test]
fn bus_sag_trips_under_voltage_at_once() {
    let mut sim = running("m153-source.toml", 10.0);
    let lim = sim.cascade.config().current.supervisor;
    sim.plant.faults_mut().bus_sag_v = 0.5 * sim.plant.config().bus_voltage_v;
    trips_at_once(&mut sim, 10, &[Fault::BusUnderVoltage], |s| {
        s.last_sample().v_bus_v < lim.bus_under_voltage_v
    });
}

#[test]
fn encoder_jump_trips_implausible_angle_at_once() {
    let mut sim = running("m153-source.toml", 10.0);
    let lim = sim
        .cascade
        .config()
        .current
        .supervisor
        .max_angle_innovation_rad;
    let cpr = sim.plant.config().sensors.encoder_counts_per_rev;
    sim.plant.faults_mut().encoder = EncoderFault::Jump((cpr / 6) as i32); // 1.05 rad
    let prev = std::cell::Cell::new(sim.last_sample().angle);
    trips_at_once(&mut sim, 10, &[Fault::AngleSensorImplausible], |s| {
        let a = s.last_sample().angle;
        let jump = a.diff_radians(prev.get()).abs() > lim;
        prev.set(a);
        jump
    });
}

/// A stuck encoder at speed. The frozen reading captures the rotor (the
/// controller's current vector freezes with it and brakes the rotor to a
/// stop a fraction of a turn on) and the tracker follows the reading, so
/// the innovation check never sees it. The stall check would (the reading
/// still for its 20 ms window while the speed loop demands half the
/// current limit: 548 periods = 36.5 ms on the M153 before design §24);
/// the model check (design §24) sees the currents stop following the
/// model under the still reading first and names the angle. Detection
/// within 50 ms of the injection; the bridge is commanded safe in the
/// very step that latches, is off in the plant's next period and stays off.
#[test]
fn encoder_stuck_at_speed_trips_angle_sensor_stuck() {
    let w = 25.0;
    let mut sim = running("m153-source.toml", w);
    let f = sim.plant.config().pwm_frequency_hz;
    sim.plant.faults_mut().encoder = EncoderFault::Stuck;
    let p0 = sim.true_position_rad();
    let frozen = sim.last_sample().angle;
    let mut latched_at = None;
    for k in 0..(0.05 * f) as usize {
        let b = sim.step();
        if let Some(fault) = sim.cascade.feedback().first_fault {
            assert_eq!(fault, Fault::AngleSensorStuck);
            assert_eq!(b, BridgeCommand::SafeState, "not safe in the same period");
            latched_at = Some(k);
            break;
        }
        assert!(matches!(b, BridgeCommand::Duties(_)));
    }
    let moved = sim.true_position_rad() - p0;
    let k = latched_at.expect("stuck encoder never tripped");
    let ms = k as f64 / f as f64 * 1e3;
    println!("stuck encoder at {w} rad/s: tripped after {k} periods ({ms:.1} ms), rotor moved {moved:.3} rad");
    assert_eq!(sim.last_sample().angle, frozen, "the reading was frozen");
    // Within 50 ms (the stall check's window alone: 20 ms).
    assert!(ms < 50.0, "{ms} ms");
    sim.step();
    assert!(!sim.plant.bridge_enabled());
    sim.run(100);
    assert!(!sim.plant.bridge_enabled());
}

/// The stall check does not trip on speed reversals through zero (the
/// reading pauses only for the turnaround), nor
/// while holding a position against a load at 70 % of the current limit.
#[test]
fn stuck_check_does_not_trip_on_reversal_or_holding_against_load() {
    let s = setup("gl80-kv30.toml");
    let f = s.bench.pwm_frequency_hz;
    let mut sim = Sim::new_calibrated(&s, s.cascade_config(), false);
    for w in [20.0f32, -20.0, 20.0, 0.0] {
        sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
        sim.run((0.2 * f) as usize);
        assert_eq!(sim.cascade.feedback().first_fault, None, "at {w} rad/s");
    }
    let p = sim.cascade.feedback().position_rad;
    sim.cascade.command(Command::Position { rad: p }).unwrap();
    sim.load_nm = 0.7 * s.kt() * s.max_current_a;
    sim.run((0.5 * f) as usize);
    assert_eq!(sim.cascade.feedback().first_fault, None);
    assert!(sim.cascade.iq_ref_a().abs() > 0.5 * s.max_current_a);
}

#[test]
fn nan_current_trips_non_finite_at_once() {
    let mut sim = running("m153-source.toml", 10.0);
    sim.plant.faults_mut().nan_current = Some(Phase::B);
    trips_at_once(&mut sim, 10, &[Fault::NonFinite], |s| {
        !s.last_sample().currents.to_abc().is_finite()
    });
    // Clearing while the fault persists trips again at once.
    sim.cascade.clear_faults();
    sim.step();
    assert_eq!(sim.last_bridge(), BridgeCommand::SafeState);
    // Fault gone: clear, command, and the bridge runs again.
    sim.plant.faults_mut().nan_current = None;
    sim.run(1);
    sim.cascade.clear_faults();
    sim.run(1);
    sim.cascade
        .command(Command::Velocity { rad_s: 0.0 })
        .unwrap();
    sim.run(3);
    assert!(sim.plant.bridge_enabled());
}
