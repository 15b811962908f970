//! The mission's segments: current, speed and load steps, ramps, the
//! position move, impedance mode and braking.

use super::*;
use crate::real::Real;
use foc_core::control::supervisor::SupervisorConfig;

/// The bus's least time constant on the regen ramp \[PWM periods\]
/// ([`braking_dc_link`]): `C (V_end - V_start) / I_max`.
pub const BRAKING_RAMP_PERIODS: f64 = 10.0;

/// The ESR time constant `ESR C` of the braking segment's capacitor \[s\]:
/// the ODrive v3's low-ESR aluminium electrolytics (4 x 470 uF, 15 mOhm),
/// a property of the technology rather than of the size.
pub const BRAKING_ESR_TIME_CONSTANT_S: f64 = 0.015 * 4.0 * 470e-6;

/// How [`braking_dc_link`] sizes the link (the braking summary's words).
pub const BRAKING_LINK_RULE: &str = "sized from the motor file: C the larger of a 10-period bus time constant on the regen ramp at the maximum current and the winding's energy at the maximum current taken between the chopper's switch-on voltage and the over-voltage threshold; brake resistor: the rated current at the switch-on voltage";

/// The braking segment's DC link (design §18), sized from the motor file
/// (which has no DC-link fields) and the supervisor's thresholds: `V_ov`
/// the over-voltage threshold, `V_on` the brake chopper's switch-on
/// voltage (`PowerLimitsConfig::with_brake_resistor`: the regen ramp's
/// start, 0.85 `V_ov`), `V_end` the ramp's end (0.95 `V_ov`):
///
/// - capacitance: the larger of
///   - `N T_pwm I_max / (V_end - V_on)`, `N` = [`BRAKING_RAMP_PERIODS`]:
///     the regen ramp takes the current from `I_max` to 0 over
///     `V_end - V_on`, a gain of `I_max / (V_end - V_on)` from the bus
///     voltage to its current; against `C` that loop has the time constant
///     `C (V_end - V_on) / I_max`, which must be long against the current
///     loop's few periods of delay or the bus and the current oscillate
///     (the DJI M2006 file on 260 uF: +-2 V, +-10 A, a 9-period cycle,
///     then a current-sense fault);
///   - `1.5 max(Ld, Lq) I_max^2 / (V_ov^2 - V_on^2)`: the winding's
///     magnetic energy at the maximum current, `0.75 L I_max^2`, which
///     reaches the bus when the current is dropped at once (a safe-state
///     disable; turning the current vector onto the d axis releases
///     `0.75 (Lq - Ld) I^2` of it), taken between `V_on` and `V_ov`;
///
///   either keeps the PWM ripple far below 1 % (`I_max / (8 f_pwm C)`:
///   at most 0.16 % of the bus with the supervisor's 125 % threshold);
/// - its ESR: [`BRAKING_ESR_TIME_CONSTANT_S`] / `C`;
/// - brake resistor `R = V_on / I_rated`: switched on, it takes the rated
///   phase current's worth, more than the bus current of a rated-current
///   regeneration (at most `sqrt(3)/2 I_rated` at full modulation).
///
/// The source: a battery at the file's bus voltage, 20 mOhm (the segment
/// makes it non-sinking for the stops). M153 (26 V, 60 A max, 42 A
/// rated): 12.3 mF (the ramp; the winding's 1.35 J asks 9.2 mF), 0.66
/// ohm, where the ODrive v3 it used before had 1880 uF (a 1.5-period
/// time constant, 0.28 J between 27.6 and 32.5 V) and 2 ohm (14 A, a third
/// of the rated current). The 540 V, 2.2 kW interior-PM file (Lq 51 mH,
/// 18.2 A max, 6.08 A rated): 200 uF (the winding's 12.7 J), 94 ohm
/// (3.5 kW at 574 V).
pub fn braking_dc_link(setup: &Setup, supervisor: &SupervisorConfig) -> DcLinkConfig {
    let v_bus = setup.bench.bus_voltage_v as f64;
    let t_pwm = 1.0 / setup.bench.pwm_frequency_hz as f64;
    let i_max = setup.max_current_a as f64;
    let l_max = (setup.motor.ld_h as f64).max(setup.motor.lq_h as f64);
    let v_ov = supervisor.bus_over_voltage_v as f64;
    let limits = PowerLimitsConfig::for_board(supervisor, control_motor(&setup.motor), false)
        .with_brake_resistor();
    let (v_on, v_end) = (limits.brake_on_v as f64, limits.regen_end_v as f64);
    // No (finite) thresholds: no ramp, no energy rule, the resistor sized
    // at the motor file's bus.
    let ramp_v = v_end - v_on;
    let c_ramp = if ramp_v.is_finite() && ramp_v > 0.0 {
        BRAKING_RAMP_PERIODS * t_pwm * i_max / ramp_v
    } else {
        0.0
    };
    let headroom_v2 = v_ov * v_ov - v_on * v_on;
    let c_energy = if headroom_v2.is_finite() && headroom_v2 > 0.0 {
        1.5 * l_max * i_max * i_max / headroom_v2
    } else {
        0.0
    };
    // At the least, 1 % ripple at the maximum current.
    let c_ripple = i_max * t_pwm / (8.0 * 0.01 * v_bus);
    let c_f = c_ramp.max(c_energy).max(c_ripple);
    let v_on = if v_on.is_finite() && v_on > 0.0 {
        v_on
    } else {
        v_bus
    };
    DcLinkConfig {
        c_f: c_f as Real,
        esr_ohm: (BRAKING_ESR_TIME_CONSTANT_S / c_f) as Real,
        v_source_v: setup.bench.bus_voltage_v,
        r_source_ohm: 0.02,
        i_source_max_a: Real::INFINITY,
        source: SourceKind::Sinking,
        brake_resistor_ohm: Some((v_on / setup.rated_current_a as f64) as Real),
    }
}

impl Mission<'_> {
    /// Segment 2, q-current step with the rotor locked. Returns the step \[A\].
    pub(super) fn current_step(&mut self, config: &CascadeConfig) -> f32 {
        let setup = self.setup;
        let sim = &mut self.sim;
        sim.plant.set_mechanics(Mechanics::Locked);
        let v_lin = 0.95 * setup.bench.bus_voltage_v as f32 / 3f32.sqrt();
        let kp = config.current.current.q_gains.kp_v_per_a;
        // As large as the voltage allows (the first step's voltage is about
        // Kp * I_step), so that the ADC's quantisation is small against the 2 % band.
        let i_step = (0.5 * setup.rated_current_a)
            .min(0.8 * v_lin / kp)
            .min(0.5 * setup.max_current_a);
        sim.cascade.command(Command::Torque { iq_a: 0.0 }).ok();
        sim.run(20);
        let start = sim.rows();
        sim.cascade.command(Command::Torque { iq_a: i_step }).ok();
        sim.run(secs(setup, 0.02).max(150));
        self.end_segment("current step", start);
        let sim = &mut self.sim;
        sim.cascade.command(Command::Torque { iq_a: 0.0 }).ok();
        sim.run(secs(setup, 0.005).max(50));
        sim.plant.set_mechanics(Mechanics::Free);
        // At rest before the speed step: the speed observer's disturbance
        // estimate unlearns the locked rotor (design §19).
        sim.run(secs(setup, 0.05));
        i_step
    }

    /// Segment 3a, speed step 0 -> `w1`.
    pub(super) fn speed_step(&mut self) {
        let start = self.sim.rows();
        let w1 = self.plan.w1;
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: w1 })
            .ok();
        self.run_ticking(secs(self.setup, 0.5));
        self.end_segment("speed step", start);
    }

    /// Segment 3b, ramp `w1` -> `w2`, then a hold at `w2`.
    pub(super) fn ramp(&mut self) {
        let start = self.sim.rows();
        self.velocity_ramp(self.plan.w1, self.plan.w2);
        self.run_ticking(secs(self.setup, 0.3));
        self.end_segment("ramp", start);
    }

    /// A linear velocity ramp `from` -> `to` [rad/s] over the plan's ramp
    /// time (a new command every speed-loop period), then `to` held.
    pub(super) fn velocity_ramp(&mut self, from: f32, to: f32) {
        let speed_div = self.plan.speed_div;
        let n = secs(self.setup, self.plan.t_ramp);
        for k in 0..n {
            if k % speed_div == 0 {
                let w = from + (to - from) * (k as f32 / n as f32);
                self.sim
                    .cascade
                    .command(Command::Velocity { rad_s: w })
                    .ok();
            }
            self.sim.step();
            self.progress.tick(&self.sim);
        }
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: to })
            .ok();
    }

    /// Segment 4, load step at `w2`. Returns the load [N m].
    pub(super) fn load_step(&mut self) -> f32 {
        let load = 0.4 * self.plan.kt * self.setup.rated_current_a;
        let start = self.sim.rows();
        self.sim.load_nm = load;
        self.run_ticking(secs(self.setup, 0.6));
        self.end_segment("load step", start);
        load
    }

    /// Segment 4b, load release at `w2`.
    pub(super) fn load_release(&mut self) {
        let start = self.sim.rows();
        self.sim.load_nm = 0.0;
        self.run_ticking(secs(self.setup, 0.4));
        self.end_segment("load release", start);
    }

    /// Segment 5a, stop: ramp down to rest.
    pub(super) fn stop(&mut self) {
        self.sim.load_nm = 0.0;
        let start = self.sim.rows();
        self.velocity_ramp(self.plan.w2, 0.0);
        self.run_ticking(secs(self.setup, 0.4));
        self.end_segment("stop", start);
    }

    /// Segment 5b, a speed step from rest to `w2` with the current limit
    /// lowered to `i_sat` (half what the proportional gain asks for at
    /// the step), so that the q current meets its limit, then a ramp back
    /// to rest with the limit restored.
    pub(super) fn saturated_step(&mut self) {
        let start = self.sim.rows();
        let w = self.plan.w2;
        let limits = self.sim.cascade.current.config().limits;
        self.sim
            .cascade
            .current
            .set_limits(foc_core::control::Limits {
                max_current_a: self.plan.i_sat,
                ..limits
            });
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: w })
            .ok();
        self.run_ticking(secs(self.setup, self.plan.t_sat));
        self.sim.cascade.current.set_limits(limits);
        self.end_segment("current-limited step", start);
        let start = self.sim.rows();
        self.velocity_ramp(w, 0.0);
        self.run_ticking(secs(self.setup, 0.3));
        self.end_segment("stop 2", start);
    }

    /// Segment 5c, position move of one turn. Returns the true position at
    /// its start \[rad\].
    pub(super) fn position_move(&mut self) -> f64 {
        let start = self.sim.rows();
        let p0_est = self.sim.cascade.feedback().position_rad;
        let p0_true = self.sim.true_position_rad();
        let target = p0_est + self.plan.move_rad;
        self.sim
            .cascade
            .command(Command::Position { rad: target })
            .ok();
        self.run_ticking(secs(self.setup, self.plan.t_move));
        self.end_segment("position move", start);
        p0_true
    }

    /// Segment 6, impedance (design §21): see the module docs.
    pub(super) fn impedance(&mut self) -> ImpedanceFigures {
        let setup = self.setup;
        let t_max = setup.kt() * setup.max_current_a;
        let count = std::f32::consts::TAU / setup.bench.sensors.encoder_counts_per_rev as f32;
        let kp = 0.3 * t_max / (0.25f32).max(40.0 * count);
        let j = self
            .sim
            .cascade
            .config()
            .mechanics
            .map_or(setup.motor.inertia_kg_m2 as f32, |m| m.inertia_kg_m2);
        let kd = 1.4 * (kp * j).sqrt();
        let start = self.sim.rows();
        let p = self.sim.cascade.feedback().position_rad;
        let cmd = Command::Impedance(foc_core::control::joint::Impedance {
            position_rad: p,
            velocity_rad_s: 0.0,
            kp_nm_per_rad: kp,
            kd_nm_s_per_rad: kd,
            torque_ff_nm: 0.0,
            torque_limit_nm: f32::INFINITY,
        });
        self.sim.cascade.command(cmd).ok();
        self.run_ticking(secs(setup, 0.2));
        let load = 0.3 * t_max;
        let hold = |m: &mut Self, l: f32| {
            m.sim.load_nm = l;
            m.run_ticking(secs(setup, 0.5));
            let n = secs(setup, 0.1);
            let (mut t, mut x) = (0.0, 0.0);
            for _ in 0..n {
                m.run_ticking(1);
                t += m.sim.plant.torque_nm() as f64;
                x += m.sim.true_position_rad();
            }
            (t / n as f64, x / n as f64)
        };
        let (t1, x1) = hold(self, load);
        let (t2, x2) = hold(self, -load);
        let wn = (kp as f64 / j as f64).sqrt() / 5.0;
        let cycle = secs(setup, std::f64::consts::TAU / wn);
        let ts = 1.0 / setup.bench.pwm_frequency_hz as f64;
        let (mut xs, mut vs, mut tq) = (vec![], vec![], vec![]);
        for k in 0..8 * cycle {
            self.sim.load_nm = load * (wn * k as f64 * ts).sin() as f32;
            self.run_ticking(1);
            if k >= 4 * cycle {
                xs.push(self.sim.true_position_rad());
                vs.push(self.sim.plant.omega_m_rad_s() as f64);
                tq.push(self.sim.plant.torque_nm() as f64);
            }
        }
        self.sim.load_nm = 0.0;
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .ok();
        self.run_ticking(secs(setup, 0.1));
        self.end_segment("impedance", start);
        let (b, c) = crate::metrics::fit_two(&xs, &vs, &tq);
        ImpedanceFigures {
            kp_nm_per_rad: kp as f64,
            kd_nm_s_per_rad: kd as f64,
            kp_steps: (t1 - t2) / (x2 - x1),
            kp_sine: -b,
            kd_sine: -c,
            sine_hz: wn / std::f64::consts::TAU,
        }
    }

    /// Segment 7, braking (design §18): two stops from the ramp's speed
    /// into a supply that cannot sink current, through a DC link sized
    /// from the motor file ([`braking_dc_link`]), the board's regen limit
    /// on; the first into the capacitor alone, the second with the brake
    /// resistor. Each: the DC link on a battery (it sinks the spin-up's
    /// overshoot), a spin-up, then the supply made non-sinking, the limits
    /// installed and 0 rad/s commanded. Afterwards the power limits are off
    /// again and the plant is back on its plain source.
    pub(super) fn braking(&mut self) -> BrakingSummary {
        let setup = self.setup;
        let v_src = setup.bench.bus_voltage_v;
        let supervisor = self.sim.cascade.current.config().supervisor;
        let base = braking_dc_link(setup, &supervisor);
        let resistor_ohm = base.brake_resistor_ohm.unwrap_or(Real::INFINITY);
        let limits = PowerLimitsConfig::for_board(
            &supervisor,
            self.sim.cascade.current.config().current.motor,
            false,
        );
        let w0 = self.plan.w2;
        let mut stops = Vec::new();
        // Both hard stops (0 rad/s at once).
        for (name, brake, ramp_s) in [("braking", false, 0.0), ("braking, resistor", true, 0.0)] {
            let start = self.sim.rows();
            let mut link = base;
            link.brake_resistor_ohm = brake.then_some(resistor_ohm);
            self.sim.plant.set_dc_link(Some(link));
            self.spin_to(w0);
            if let Some(l) = self.sim.plant.dc_link_mut() {
                l.source = SourceKind::NonSinking;
            }
            let cfg = if brake {
                limits.with_brake_resistor()
            } else {
                limits
            };
            self.sim.cascade.current.set_power_limits(Some(cfg));
            let stop = self.stop_figures(w0, ramp_s);
            self.sim.cascade.current.set_power_limits(None);
            self.sim.plant.set_brake(false);
            self.sim.plant.set_dc_link(None);
            self.end_segment(name, start);
            stops.push(stop);
        }
        let resistor = stops.pop().expect("two stops");
        let capacitor = stops.pop().expect("two stops");
        BrakingSummary {
            link: BRAKING_LINK_RULE,
            c_f: base.c_f as f64,
            v_source_v: v_src as f64,
            over_voltage_v: supervisor.bus_over_voltage_v as f64,
            regen_v: (limits.regen_start_v as f64, limits.regen_end_v as f64),
            from_rad_s: w0 as f64,
            capacitor,
            resistor,
            resistor_ohm: resistor_ohm as f64,
        }
    }

    /// Spin to `w0` and hold it within 2 % for 50 ms (at most
    /// [`BRAKE_SPIN_S`]).
    fn spin_to(&mut self, w0: f32) {
        let setup = self.setup;
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: w0 })
            .ok();
        // Until settled within 2 % of the speed for 50 ms (at most
        // BRAKE_SPIN_S).
        let mut settled = 0;
        for _ in 0..secs(setup, BRAKE_SPIN_S) {
            self.sim.step();
            self.progress.tick(&self.sim);
            let w = self.sim.plant.omega_m_rad_s() as f32;
            settled = if (w - w0).abs() < 0.02 * w0.abs() {
                settled + 1
            } else {
                0
            };
            if settled >= secs(setup, 0.05) {
                break;
            }
        }
    }

    /// Stop from `w0` (a ramp over `ramp_s`, or at once) with the power
    /// limits in force: the stop's figures.
    fn stop_figures(&mut self, w0: f32, ramp_s: f64) -> StopFigures {
        let setup = self.setup;
        self.sim.plant.reset_energy();
        let ke0 = self.sim.plant.kinetic_energy_j() as f64;
        let faults0: Vec<_> = self.sim.cascade.feedback().faults.iter().collect();
        let n_ramp = (ramp_s * setup.bench.pwm_frequency_hz as f64).round() as usize;
        let n = secs(setup, BRAKE_STOP_S);
        let ts = 1.0 / setup.bench.pwm_frequency_hz as f64;
        let mut stop = StopFigures {
            ramp_s,
            from_rad_s: self.sim.plant.omega_m_rad_s() as f64,
            peak_bus_v: 0.0,
            stop_s: None,
            end_rad_s: 0.0,
            kinetic_j: 0.0,
            capacitor_j: 0.0,
            resistor_j: 0.0,
            copper_j: 0.0,
            friction_j: 0.0,
            source_j: 0.0,
            regen_limited_periods: 0,
            brake_periods: 0,
            faults: Vec::new(),
        };
        for k in 0..n {
            if k <= n_ramp && k % self.plan.speed_div == 0 {
                let w = if n_ramp == 0 {
                    0.0
                } else {
                    w0 * (1.0 - k as f32 / n_ramp as f32)
                };
                self.sim
                    .cascade
                    .command(Command::Velocity { rad_s: w })
                    .ok();
            }
            self.sim.step();
            self.progress.tick(&self.sim);
            stop.peak_bus_v = stop.peak_bus_v.max(self.sim.plant.v_bus_v() as f64);
            let fb = self.sim.cascade.feedback();
            stop.regen_limited_periods += usize::from(fb.power.active == ActiveLimit::Regen);
            stop.brake_periods += usize::from(fb.power.brake_on);
            if stop.stop_s.is_none()
                && (self.sim.plant.omega_m_rad_s() as f64).abs() < 0.02 * w0 as f64
            {
                stop.stop_s = Some((k + 1) as f64 * ts);
            }
        }
        let e = *self.sim.plant.energy();
        stop.end_rad_s = self.sim.plant.omega_m_rad_s() as f64;
        stop.kinetic_j = ke0 - self.sim.plant.kinetic_energy_j() as f64;
        stop.capacitor_j = e.capacitor_j as f64;
        stop.resistor_j = e.brake_j as f64;
        stop.copper_j = e.copper_j as f64;
        stop.friction_j = e.friction_j as f64;
        stop.source_j = (e.source_out_j - e.source_in_j) as f64;
        stop.faults = self
            .sim
            .cascade
            .feedback()
            .faults
            .iter()
            .filter(|f| !faults0.contains(f))
            .map(|f| f.name().to_string())
            .collect();
        stop
    }
}
