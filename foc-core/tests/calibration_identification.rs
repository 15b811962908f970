//! Identification routines against a simple PMSM plant written here,
//! independently of foc-core's transforms.
//!
//! The plant integrates the stator flux linkage in the stationary frame
//! (`d lambda / dt = v - R i`, `i = L(theta)^-1 (lambda - psi e_theta)`, f64,
//! 20 sub-steps per PWM period), projects phase quantities with
//! `cos(theta - k 2 pi / 3)` directly, has a rotor with inertia, viscous and
//! Coulomb friction, optional per-phase resistance, dead-time voltage error
//! (`-V_dt sign(i_x)` per phase), an open phase, swapped or negated current
//! sensing, a quantised (14-bit) noisy angle sensor with an offset and a
//! direction, and a one-period computation delay: the command returned in
//! period k is applied during period k+1.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::angle::MechanicalAngle;
use foc_core::calibration::alignment::{Alignment, AlignmentConfig};
use foc_core::calibration::flux::{FluxConfig, FluxLinkage};
use foc_core::calibration::identification::{Identification, IdentificationConfig, Step};
use foc_core::calibration::inductance::{Inductance, InductanceConfig};
use foc_core::calibration::resistance::{PhaseResistance, ResistanceConfig};
use foc_core::calibration::{CalError, CalInput, CalStep, Calibrated, ClosedLoopFeedback, Phase};
use foc_core::control::current::CurrentLoopConfig;
use foc_core::control::stage::{AngleCalibration, Sample};
use foc_core::control::{BridgeCommand, Command, MotorParams};
use foc_core::drive::cascade::CalibratedCascade;
use foc_core::drive::cascade::CascadeConfig;
use foc_core::frames::Abc;
use foc_core::hal::PhaseCurrents;
use std::f64::consts::{PI, TAU};

#[derive(Clone, Copy, Debug)]
struct Motor {
    p: u8,
    r: f64,
    ld: f64,
    lq: f64,
    psi: f64,
    j: f64,
    visc: f64,
    coulomb: f64,
    pwm_hz: f64,
    v_bus: f64,
}

/// DJI M2006-like (motor side), 20 kHz.
fn m2006() -> Motor {
    Motor {
        p: 7,
        r: 0.461,
        ld: 64.22e-6,
        lq: 64.22e-6,
        psi: 6.6e-4,
        j: 3e-6,
        visc: 1e-7,
        coulomb: 0.0005,
        pwm_hz: 20_000.0,
        v_bus: 24.0,
    }
}

/// GL80 KV30-like (salient), 20 kHz.
fn gl80() -> Motor {
    Motor {
        p: 21,
        r: 1.13,
        ld: 0.57e-3,
        lq: 0.82e-3,
        psi: 0.00875,
        j: 4e-4,
        visc: 5e-5,
        coulomb: 0.01,
        pwm_hz: 20_000.0,
        v_bus: 24.0,
    }
}

/// Low-R, high-flux (the source's M153 operating point), 15 kHz.
fn m153() -> Motor {
    Motor {
        p: 4,
        r: 0.05,
        ld: 0.5e-3,
        lq: 0.5e-3,
        psi: 0.124,
        j: 5e-3,
        visc: 2e-3,
        coulomb: 0.3,
        pwm_hz: 15_000.0,
        v_bus: 26.0,
    }
}

/// Small-inductance outrunner, 40 kHz.
fn hkc() -> Motor {
    Motor {
        p: 21,
        r: 0.105,
        ld: 30e-6,
        lq: 30e-6,
        psi: 0.0024,
        j: 6e-5,
        visc: 1e-5,
        coulomb: 0.005,
        pwm_hz: 40_000.0,
        v_bus: 24.0,
    }
}

struct Plant {
    m: Motor,
    r_phase: [f64; 3],
    lam: [f64; 2],
    theta_m: f64,
    omega_m: f64,
    pending_v: [f64; 3],
    v_dead: f64,
    open_phase: Option<usize>,
    swap_bc_sense: bool,
    negate_sense: bool,
    sensor_reversed: bool,
    sensor_offset_turns: f64,
    sensor_frozen: bool,
    sense_noise_a: f64,
    angle_noise_lsb: f64,
    stop_m: Option<(f64, f64)>,
    rng: u64,
}

impl Plant {
    fn new(m: Motor) -> Self {
        Self {
            m,
            r_phase: [m.r; 3],
            lam: [m.psi * 0.3f64.cos(), m.psi * 0.3f64.sin()],
            theta_m: 0.3 / m.p as f64,
            omega_m: 0.0,
            pending_v: [0.0; 3],
            v_dead: 0.0,
            open_phase: None,
            swap_bc_sense: false,
            negate_sense: false,
            sensor_reversed: false,
            sensor_offset_turns: 0.0,
            sensor_frozen: false,
            sense_noise_a: 0.0,
            angle_noise_lsb: 0.0,
            stop_m: None,
            rng: 0x1234_5678_9abc_def0,
        }
    }

    fn ts(&self) -> f64 {
        1.0 / self.m.pwm_hz
    }

    fn theta_e(&self) -> f64 {
        self.m.p as f64 * self.theta_m
    }

    fn uniform(&mut self) -> f64 {
        self.rng = self
            .rng
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((self.rng >> 11) as f64) / ((1u64 << 53) as f64)
    }

    /// Roughly Gaussian, unit standard deviation.
    fn gauss(&mut self) -> f64 {
        (0..12).map(|_| self.uniform()).sum::<f64>() - 6.0
    }

    /// Stator current (alpha, beta) from the flux state.
    fn current_ab(&self) -> [f64; 2] {
        let th = self.theta_e();
        let (s, c) = th.sin_cos();
        let pm = [self.lam[0] - self.m.psi * c, self.lam[1] - self.m.psi * s];
        match self.open_phase {
            None => {
                let ld_ = c * pm[0] + s * pm[1];
                let lq_ = -s * pm[0] + c * pm[1];
                let (id, iq) = (ld_ / self.m.ld, lq_ / self.m.lq);
                [c * id - s * iq, s * id + c * iq]
            }
            Some(k) => {
                // Only a current perpendicular to the open phase's axis.
                let ax = k as f64 * TAU / 3.0 + PI / 2.0;
                let w = [ax.cos(), ax.sin()];
                let wd = w[0] * c + w[1] * s;
                let wq = -w[0] * s + w[1] * c;
                let lw = self.m.ld * wd * wd + self.m.lq * wq * wq;
                let iw = (w[0] * pm[0] + w[1] * pm[1]) / lw;
                [w[0] * iw, w[1] * iw]
            }
        }
    }

    fn phase_currents(&self) -> [f64; 3] {
        let i = self.current_ab();
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let a = k as f64 * TAU / 3.0;
            *o = i[0] * a.cos() + i[1] * a.sin();
        }
        out
    }

    /// Phase voltages for `v_dq` at `theta` (own projection).
    fn phase_voltages(v_d: f64, v_q: f64, theta: f64) -> [f64; 3] {
        let mut v = [0.0; 3];
        for (k, o) in v.iter_mut().enumerate() {
            let a = theta - k as f64 * TAU / 3.0;
            *o = v_d * a.cos() - v_q * a.sin();
        }
        v
    }

    fn measure(&mut self) -> (Abc, MechanicalAngle, f32) {
        let mut i = self.phase_currents();
        if self.swap_bc_sense {
            i.swap(1, 2);
        }
        if self.negate_sense {
            i = i.map(|x| -x);
        }
        let n = self.sense_noise_a;
        let abc = Abc::new(
            (i[0] + n * self.gauss()) as f32,
            (i[1] + n * self.gauss()) as f32,
            (i[2] + n * self.gauss()) as f32,
        );
        let dir = if self.sensor_reversed { -1.0 } else { 1.0 };
        let theta = if self.sensor_frozen {
            0.0
        } else {
            self.theta_m
        };
        let turns = dir * theta / TAU + self.sensor_offset_turns;
        let lsb = (turns * 16384.0 + self.angle_noise_lsb * self.gauss()).round();
        let bits = ((lsb.rem_euclid(16384.0)) as u32) << 18;
        (abc, MechanicalAngle::from_bits(bits), self.m.v_bus as f32)
    }

    fn input(&mut self) -> CalInput {
        let (i, a, v) = self.measure();
        CalInput::open_loop(i, a, v)
    }

    /// Advance one PWM period with the pending phase voltages, then make
    /// `next` pending (one-period computation delay).
    fn advance(&mut self, next: [f64; 3]) {
        const SUB: usize = 20;
        let dt = self.ts() / SUB as f64;
        let v = self.pending_v;
        for _ in 0..SUB {
            let i_ab = self.current_ab();
            let mut iph = [0.0; 3];
            for (k, o) in iph.iter_mut().enumerate() {
                let a = k as f64 * TAU / 3.0;
                *o = i_ab[0] * a.cos() + i_ab[1] * a.sin();
            }
            // Dead-time error and resistive drops per phase, then Clarke.
            let mut u = [0.0; 3];
            for k in 0..3 {
                let dead = -self.v_dead * (iph[k] / 0.02).clamp(-1.0, 1.0);
                u[k] = v[k] + dead - self.r_phase[k] * iph[k];
            }
            let ua = (2.0 * u[0] - u[1] - u[2]) / 3.0;
            let ub = (u[1] - u[2]) / 3f64.sqrt();
            self.lam[0] += dt * ua;
            self.lam[1] += dt * ub;
            // Mechanics.
            let (s, c) = self.theta_e().sin_cos();
            let id = c * i_ab[0] + s * i_ab[1];
            let iq = -s * i_ab[0] + c * i_ab[1];
            let p = self.m.p as f64;
            let torque = 1.5 * p * (self.m.psi * iq + (self.m.ld - self.m.lq) * id * iq);
            let net = torque - self.m.visc * self.omega_m;
            if self.omega_m == 0.0 && net.abs() <= self.m.coulomb {
                // Stiction.
            } else {
                let dir = if self.omega_m != 0.0 {
                    self.omega_m.signum()
                } else {
                    net.signum()
                };
                let w = self.omega_m + dt * (net - dir * self.m.coulomb) / self.m.j;
                self.omega_m = if w * dir < 0.0 { 0.0 } else { w };
            }
            // Lambda is the total flux: moving the magnet changes the
            // current through `lambda - psi e_theta` (that is the back-EMF).
            self.theta_m += dt * self.omega_m;
            if let Some((lo, hi)) = self.stop_m {
                if self.theta_m > hi || self.theta_m < lo {
                    self.theta_m = self.theta_m.clamp(lo, hi);
                    self.omega_m = 0.0;
                }
            }
        }
        self.pending_v = next;
    }

    /// Apply an open-loop step's voltage (or zero).
    fn apply_step<T>(&mut self, s: &CalStep<T>) {
        let next = match s.voltage() {
            Some((v, th)) => Self::phase_voltages(v.d as f64, v.q as f64, th.to_radians() as f64),
            None => [0.0; 3],
        };
        self.advance(next);
    }
}

/// Step a routine on the plant until it finishes.
fn run<T: Copy + std::fmt::Debug>(
    plant: &mut Plant,
    mut step: impl FnMut(&CalInput) -> CalStep<T>,
    max_periods: usize,
) -> (CalStep<T>, usize) {
    for k in 0..max_periods {
        let inp = plant.input();
        let s = step(&inp);
        if s.is_finished() {
            return (s, k);
        }
        plant.apply_step(&s);
    }
    panic!("routine did not finish in {max_periods} periods");
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

fn res_cfg(m: &Motor, i: f32) -> ResistanceConfig {
    ResistanceConfig::new(m.pwm_hz as f32, i, 8.0)
}

#[test]
fn resistance_recovered_with_dead_time_and_noise() {
    for (m, i) in [(m2006(), 3.0), (gl80(), 3.0), (m153(), 10.0), (hkc(), 8.0)] {
        let mut plant = Plant::new(m);
        plant.v_dead = 0.3;
        plant.sense_noise_a = 0.02;
        let mut r = PhaseResistance::new(res_cfg(&m, i));
        let (s, n) = run(&mut plant, |x| r.step(x), 400_000);
        let CalStep::Done(res) = s else {
            panic!("{m:?}: {s:?}")
        };
        let e = rel(res.r_ohm as f64, m.r);
        println!(
            "R {:.4} ohm (true {:.4}): err {:.2} %, per angle {:?}, offset {:.3} V, {:.2} s",
            res.r_ohm,
            m.r,
            100.0 * e,
            res.r_per_angle_ohm,
            res.v_offset_v,
            n as f64 / m.pwm_hz
        );
        assert!(e < 0.05, "{m:?}: {res:?}");
        // The dead-time drop shows up in the intercept, not in R.
        assert!(res.v_offset_v > 0.1, "{res:?}");
    }
}

#[test]
fn resistance_failures_are_named() {
    let m = m2006();
    let cfg = res_cfg(&m, 3.0);
    // One phase disconnected: no current at that phase's angle.
    for (k, phase) in [(0usize, Phase::A), (1, Phase::B), (2, Phase::C)] {
        let mut plant = Plant::new(m);
        plant.open_phase = Some(k);
        let mut r = PhaseResistance::new(cfg);
        let (s, _) = run(&mut plant, |x| r.step(x), 400_000);
        assert_eq!(s, CalStep::Failed(CalError::OpenPhase(phase)), "open {k}");
    }
    // Current-sense phases B and C swapped; sense sign negated.
    for swap in [true, false] {
        let mut plant = Plant::new(m);
        plant.swap_bc_sense = swap;
        plant.negate_sense = !swap;
        let mut r = PhaseResistance::new(cfg);
        let (s, _) = run(&mut plant, |x| r.step(x), 400_000);
        assert_eq!(
            s,
            CalStep::Failed(CalError::CurrentSenseMismatch),
            "swap {swap}"
        );
    }
    // One winding 30 % higher.
    let mut plant = Plant::new(m);
    plant.r_phase[1] *= 1.3;
    let mut r = PhaseResistance::new(cfg);
    let (s, _) = run(&mut plant, |x| r.step(x), 400_000);
    assert_eq!(s, CalStep::Failed(CalError::PhaseImbalance));
    // NaN current part way: a failure, never a panic; it stays failed.
    let mut plant = Plant::new(m);
    let mut r = PhaseResistance::new(cfg);
    let mut k = 0;
    let (s, _) = run(
        &mut plant,
        |x| {
            k += 1;
            let mut x = *x;
            if k == 3000 {
                x.i_abc_a.b = f32::NAN;
            }
            r.step(&x)
        },
        10_000,
    );
    assert_eq!(s, CalStep::Failed(CalError::InvalidInput));
    let inp = CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0);
    assert_eq!(r.step(&inp), CalStep::Failed(CalError::InvalidInput));
}

#[test]
fn inductance_recovered_d_and_q() {
    for (m, i) in [(m2006(), 3.0), (gl80(), 3.0), (m153(), 10.0), (hkc(), 8.0)] {
        let mut plant = Plant::new(m);
        plant.v_dead = 0.3;
        plant.sense_noise_a = 0.02;
        let mut l = Inductance::new(InductanceConfig::new(m.pwm_hz as f32, i, 8.0));
        let (s, n) = run(&mut plant, |x| l.step(x), 400_000);
        let CalStep::Done(res) = s else {
            panic!("{m:?}: {s:?}")
        };
        let (ed, eq) = (rel(res.ld_h as f64, m.ld), rel(res.lq_h as f64, m.lq));
        println!(
            "Ld {:.3e} (true {:.3e}) err {:.2} %, Lq {:.3e} (true {:.3e}) err {:.2} %, {:.2} s",
            res.ld_h,
            m.ld,
            100.0 * ed,
            res.lq_h,
            m.lq,
            100.0 * eq,
            n as f64 / m.pwm_hz
        );
        assert!(ed < 0.05 && eq < 0.05, "{m:?}: {res:?}");
    }
}

fn align_cfg(m: &Motor, p: u8, i: f32) -> AlignmentConfig {
    let mut c = AlignmentConfig::new(p, m.pwm_hz as f32, (m.r * i as f64) as f32 + 0.3, 3.0 * i);
    c.max_voltage_v = 8.0;
    c.speed_e_rad_s = sweep_speed(m);
    c
}

/// Open-loop sweep speed [rad/s, electrical]: the back-EMF `w_e psi` must
/// stay well below the alignment voltage (about `R i`), else the rotor
/// cannot follow the field. The low-R, high-flux motor needs a slow sweep.
fn sweep_speed(m: &Motor) -> f32 {
    if m.psi > 0.05 {
        0.25 * std::f32::consts::TAU
    } else {
        2.0 * std::f32::consts::TAU
    }
}

fn run_alignment(
    plant: &mut Plant,
    cfg: AlignmentConfig,
) -> CalStep<foc_core::calibration::alignment::AlignmentResult> {
    let mut a = Alignment::new(cfg);
    run(plant, |x| a.step(x), 4_000_000).0
}

#[test]
fn alignment_finds_zero_direction_and_pole_pairs() {
    for (m, i) in [
        (m2006(), 3.0f32),
        (gl80(), 3.0),
        (m153(), 10.0),
        (hkc(), 8.0),
    ] {
        for reversed in [false, true] {
            let mut plant = Plant::new(m);
            plant.v_dead = 0.3;
            plant.sense_noise_a = 0.02;
            plant.angle_noise_lsb = 1.0;
            plant.sensor_reversed = reversed;
            plant.sensor_offset_turns = 0.3141;
            let s = run_alignment(&mut plant, align_cfg(&m, m.p, i));
            let CalStep::Done(res) = s else {
                panic!("{m:?} rev {reversed}: {s:?}")
            };
            assert_eq!(res.calibration.reversed, reversed);
            assert_eq!(res.calibration.pole_pairs, m.p);
            assert_eq!(
                ((res.measured_pole_pairs_x100 as f32) / 100.0).round() as u8,
                m.p
            );
            // Check the calibration against the true rotor angle at several
            // positions: electrical(mechanical(raw)) must equal p theta_m.
            let mut worst = 0.0f64;
            for k in 0..50 {
                plant.theta_m = k as f64 * 0.37;
                let (_, raw, _) = plant.measure();
                let cal = res.calibration;
                let e = cal.electrical(cal.mechanical(raw)).to_radians() as f64;
                let truth = (plant.theta_e()).rem_euclid(TAU);
                let mut d = (e - truth).rem_euclid(TAU);
                if d > PI {
                    d -= TAU;
                }
                worst = worst.max(d.abs());
            }
            println!(
                "p {} rev {reversed}: zero error {:.3} deg(e) worst, lag {:.2} deg(e), consistency {:.3}",
                m.p,
                worst.to_degrees(),
                (res.lag_e_rad as f64).to_degrees(),
                res.consistency
            );
            assert!(worst.to_degrees() < 2.0, "{m:?}: {worst}");
        }
    }
}

#[test]
fn alignment_failures_are_named() {
    let m = m2006();
    // Wrong pole pairs configured.
    let mut plant = Plant::new(m);
    let s = run_alignment(&mut plant, align_cfg(&m, 4, 3.0));
    assert_eq!(
        s,
        CalStep::Failed(CalError::PolePairMismatch {
            configured: 4,
            measured_x100: 700
        })
    );
    // Expected direction stated, sensor reversed.
    let mut plant = Plant::new(m);
    plant.sensor_reversed = true;
    let mut cfg = align_cfg(&m, m.p, 3.0);
    cfg.expected_reversed = Some(false);
    assert_eq!(
        run_alignment(&mut plant, cfg),
        CalStep::Failed(CalError::SensorReversed)
    );
    // ... and the same stated direction passes with a forward sensor.
    let mut plant = Plant::new(m);
    assert!(matches!(run_alignment(&mut plant, cfg), CalStep::Done(_)));
    // Frozen sensor.
    let mut plant = Plant::new(m);
    plant.sensor_frozen = true;
    assert_eq!(
        run_alignment(&mut plant, align_cfg(&m, m.p, 3.0)),
        CalStep::Failed(CalError::SensorNoMotion)
    );
    // Rotor blocked after part of the forward sweep.
    let mut plant = Plant::new(m);
    let start = plant.theta_m;
    plant.stop_m = Some((start - 10.0, start + 2.2 * TAU / m.p as f64));
    assert_eq!(
        run_alignment(&mut plant, align_cfg(&m, m.p, 3.0)),
        CalStep::Failed(CalError::RotorStuck)
    );
    // NaN bus voltage.
    let mut plant = Plant::new(m);
    let mut a = Alignment::new(align_cfg(&m, m.p, 3.0));
    let mut inp = plant.input();
    inp.v_bus_v = f32::NAN;
    assert_eq!(a.step(&inp), CalStep::Failed(CalError::InvalidInput));
}

/// Drive a cascade built from `permit` on the plant for a Velocity request.
struct ClosedLoop {
    drive: Option<CalibratedCascade>,
    last: Option<Command>,
    fb: Option<ClosedLoopFeedback>,
}

impl ClosedLoop {
    fn new() -> Self {
        Self {
            drive: None,
            last: None,
            fb: None,
        }
    }

    /// One period of a Velocity request: returns the phase voltages.
    fn velocity(
        &mut self,
        plant: &mut Plant,
        permit: &Calibrated,
        rad_s: f32,
        inp: &CalInput,
    ) -> [f64; 3] {
        self.closed(plant, permit, Command::Velocity { rad_s }, inp)
    }

    /// One period of a closed-loop request: returns the phase voltages.
    fn closed(
        &mut self,
        plant: &mut Plant,
        permit: &Calibrated,
        cmd: Command,
        inp: &CalInput,
    ) -> [f64; 3] {
        let m = plant.m;
        let drive = self.drive.get_or_insert_with(|| {
            // The speed loop is the caller's: tuned from the motor's
            // nominal data (inertia and an approximate torque constant).
            let nominal = MotorParams {
                pole_pairs: m.p,
                r_ohm: m.r as f32,
                ld_h: m.ld as f32,
                lq_h: m.lq as f32,
                flux_linkage_wb: m.psi as f32,
            };
            let mut cfg =
                CascadeConfig::for_motor_with_inertia(nominal, m.pwm_hz as f32, 20.0, m.j as f32);
            cfg.current.supervisor.max_current_sum_a = 5.0;
            cfg.current.supervisor.bus_over_voltage_v = 60.0;
            cfg.current.limits.max_velocity_rad_s = 1.0e5;
            CalibratedCascade::new(cfg, permit)
        });
        if self.last != Some(cmd) {
            drive.command(cmd).unwrap();
            self.last = Some(cmd);
        }
        let sample = Sample {
            currents: Some(PhaseCurrents::ThreePhase(inp.i_abc_a)),
            angle: Some(inp.angle),
            v_bus_v: Some(inp.v_bus_v),
            temperature_c: None,
        };
        let bridge = drive.step(&sample);
        let fb = drive.feedback();
        assert!(fb.first_fault.is_none(), "{:?}", fb.first_fault);
        self.fb = Some(ClosedLoopFeedback {
            v_dq_v: fb.v_dq_v,
            i_dq_a: fb.i_dq_a,
            velocity_rad_s: fb.velocity_rad_s,
            theta_e: fb.theta_e,
        });
        match bridge {
            BridgeCommand::Duties(d) => d.map(|x| (x as f64 - 0.5) * m.v_bus),
            BridgeCommand::SafeState => [0.0; 3],
            BridgeCommand::ShortCircuit => [-0.5 * m.v_bus; 3],
        }
    }
}

#[test]
fn flux_linkage_from_two_speeds() {
    for m in [m2006(), gl80(), m153(), hkc()] {
        let mut plant = Plant::new(m);
        plant.v_dead = 0.2;
        plant.sense_noise_a = 0.02;
        // Calibrated with the true values (this test is about the flux step).
        let angle = AngleCalibration {
            pole_pairs: m.p,
            zero_offset: foc_core::angle::ElectricalAngle::ZERO,
            reversed: false,
            sensor_counts_per_rev: 0,
            sensorless_only: false,
        };
        let motor = MotorParams {
            pole_pairs: m.p,
            r_ohm: m.r as f32,
            ld_h: m.ld as f32,
            lq_h: m.lq as f32,
            flux_linkage_wb: 0.0,
        };
        let permit = Calibrated::supplied(
            angle,
            CurrentLoopConfig::technical_optimum(motor, m.pwm_hz as f32),
        )
        .unwrap();
        let mut cfg = FluxConfig::new(m.p, m.pwm_hz as f32, m.r as f32, 30.0);
        cfg.ld_h = m.ld as f32;
        let mut f = FluxLinkage::new(cfg);
        let mut cl = ClosedLoop::new();
        let mut out = None;
        for _ in 0..400_000 {
            let mut inp = plant.input();
            inp.closed_loop = cl.fb;
            match f.step(&inp) {
                CalStep::Velocity { rad_s } => {
                    let v = cl.velocity(&mut plant, &permit, rad_s, &inp);
                    plant.advance(v);
                }
                CalStep::Apply { .. } => panic!("flux asks for velocity only"),
                done => {
                    out = Some(done);
                    break;
                }
            }
        }
        let Some(CalStep::Done(res)) = out else {
            panic!("{m:?}: {out:?}")
        };
        let e = rel(res.flux_linkage_wb as f64, m.psi);
        println!(
            "psi {:.5} (true {:.5}) err {:.2} % at {:?} rad/s",
            res.flux_linkage_wb,
            m.psi,
            100.0 * e,
            res.speeds_rad_s
        );
        assert!(e < 0.10, "{m:?}: {res:?}");
    }
}

/// The whole sequencer, driven as the bench will: one call per period.
fn identify(
    m: Motor,
    plant: &mut Plant,
    cfg: IdentificationConfig,
) -> (
    CalStep<foc_core::calibration::identification::Identified>,
    Identification,
) {
    let mut id = Identification::new(cfg);
    let mut cl = ClosedLoop::new();
    for _ in 0..6_000_000 {
        let mut inp = plant.input();
        inp.closed_loop = cl.fb;
        let step = id.step(&inp);
        match step {
            CalStep::Apply { .. } => plant.apply_step(&step),
            CalStep::Velocity { rad_s } => {
                let permit = id.permit().expect("permit before velocity");
                let v = cl.velocity(plant, &permit, rad_s, &inp);
                plant.advance(v);
            }
            CalStep::Torque { iq_a } => {
                let permit = id.permit().expect("permit before torque");
                let v = cl.closed(plant, &permit, Command::Torque { iq_a }, &inp);
                plant.advance(v);
            }
            _ => return (step, id),
        }
    }
    panic!("{m:?}: identification did not finish");
}

#[test]
fn sequencer_identifies_motors() {
    for (m, i, vmax) in [
        (m2006(), 3.0f32, 6.0f32),
        (gl80(), 3.0, 10.0),
        (hkc(), 8.0, 6.0),
        (m153(), 10.0, 6.0),
    ] {
        let mut plant = Plant::new(m);
        plant.v_dead = 0.25;
        plant.sense_noise_a = 0.02;
        plant.angle_noise_lsb = 1.0;
        plant.sensor_reversed = true;
        plant.sensor_offset_turns = 0.71;
        let mut cfg = IdentificationConfig::new(m.p, m.pwm_hz as f32, i, vmax);
        cfg.alignment.speed_e_rad_s = sweep_speed(&m);
        let (s, id) = identify(m, &mut plant, cfg);
        let CalStep::Done(done) = s else {
            panic!("{m:?}: {s:?} in {:?}", id.current_step())
        };
        let r = done.result;
        println!(
            "p {}: R {:.2} %, Ld {:.2} %, Lq {:.2} %, psi {:.2} %",
            m.p,
            100.0 * rel(r.r_ohm as f64, m.r),
            100.0 * rel(r.ld_h as f64, m.ld),
            100.0 * rel(r.lq_h as f64, m.lq),
            100.0 * rel(r.flux_linkage_wb as f64, m.psi)
        );
        assert!(rel(r.r_ohm as f64, m.r) < 0.05);
        assert!(rel(r.ld_h as f64, m.ld) < 0.05 && rel(r.lq_h as f64, m.lq) < 0.05);
        assert!(rel(r.flux_linkage_wb as f64, m.psi) < 0.10);
        assert!(r.angle.reversed);
        assert_eq!(r.pole_pairs, m.p);
        assert_eq!(id.current_step(), Step::Done);
        // The permit carries the measured gains (technical optimum).
        let c = done.permit.current_config();
        let ts = 1.0 / m.pwm_hz as f32;
        assert!((c.d_gains.kp_v_per_a - r.ld_h / (3.0 * ts)).abs() < 1e-3 * c.d_gains.kp_v_per_a);
        assert!(
            (c.q_gains.ki_v_per_a_s - r.r_ohm / (3.0 * ts)).abs() < 1e-3 * c.q_gains.ki_v_per_a_s
        );
        assert_eq!(c.motor.flux_linkage_wb, r.flux_linkage_wb);
        assert_eq!(done.permit.angle(), r.angle);
    }
}

#[test]
fn sequencer_reports_failing_stage() {
    let m = m2006();
    // Wrong pole pairs: fails in the alignment, after R and L.
    let mut plant = Plant::new(m);
    let cfg = IdentificationConfig::new(5, m.pwm_hz as f32, 3.0, 6.0);
    let (s, id) = identify(m, &mut plant, cfg);
    assert!(
        matches!(s, CalStep::Failed(CalError::PolePairMismatch { configured: 5, measured_x100 }) if (690..=710).contains(&measured_x100)),
        "{s:?}"
    );
    assert_eq!(id.current_step(), Step::Alignment);
    assert!(id.resistance().is_some());
    assert!(id.permit().is_none(), "no permit without a valid alignment");
    // Open phase C: fails in the resistance stage.
    let mut plant = Plant::new(m);
    plant.open_phase = Some(2);
    let (s, id) = identify(
        m,
        &mut plant,
        IdentificationConfig::new(m.p, m.pwm_hz as f32, 3.0, 6.0),
    );
    assert_eq!(s, CalStep::Failed(CalError::OpenPhase(Phase::C)));
    assert_eq!(id.current_step(), Step::Resistance);
    // NaN current during the inductance stage.
    let mut id = Identification::new(IdentificationConfig::new(m.p, m.pwm_hz as f32, 3.0, 6.0));
    let mut plant = Plant::new(m);
    let mut last = None;
    for _ in 0..1_000_000 {
        let mut inp = plant.input();
        if id.current_step() == Step::Inductance {
            inp.i_abc_a.a = f32::NAN;
        }
        let s = id.step(&inp);
        if s.is_finished() {
            last = Some(s);
            break;
        }
        plant.apply_step(&s);
    }
    assert_eq!(last, Some(CalStep::Failed(CalError::InvalidInput)));
    assert_eq!(id.current_step(), Step::Inductance);
}
