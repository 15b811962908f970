//! The motor's equations integrated over a PWM period (sub-steps between
//! switching events, RK4).

use super::*;

/// Derivative of the integrated state and its energy integrands.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Deriv {
    pub(super) id: Real,
    pub(super) iq: Real,
    pub(super) omega: Real,
    pub(super) theta: Real,
    pub(super) p_supply: Real,
    pub(super) p_copper: Real,
    pub(super) p_shaft: Real,
    /// Power of the cogging torque on the rotor `T_cog w`.
    pub(super) p_cogging: Real,
    pub(super) p_friction: Real,
    pub(super) p_load: Real,
    pub(super) p_short: Real,
    pub(super) i_dc: Real,
    /// Capacitor voltage derivative (DC link only).
    pub(super) v_cap: Real,
    /// Power at the source terminals `V i_source`.
    pub(super) p_source: Real,
    /// Power dissipated inside the source.
    pub(super) p_source_loss: Real,
    /// Power into the capacitor `v_C i_C`.
    pub(super) p_cap: Real,
    /// Power in the ESR.
    pub(super) p_esr: Real,
    /// Power in the brake resistor.
    pub(super) p_brake: Real,
    pub(super) i_source: Real,
    pub(super) i_brake: Real,
}

/// What one sub-step integrated.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct SubstepOut {
    pub(super) e_in: Real,
    pub(super) q_dc: Real,
    pub(super) vt: [Real; 3],
    pub(super) copper_j: Real,
    pub(super) q_source: Real,
    pub(super) q_brake: Real,
}

/// What a period's sub-steps integrated, summed over the period.
#[derive(Clone, Copy, Debug)]
struct PeriodSums {
    /// Energy from the supply \[J\].
    e_in: Real,
    /// Charge through the DC link \[C\].
    q_dc: Real,
    /// Terminal voltages, each sub-step's divided by their number \[V\].
    v_term: [Real; 3],
    /// Bus voltage at each sub-step's end, summed \[V\].
    v_bus_sum: Real,
    /// Energy into the winding's copper \[J\].
    e_copper: Real,
    /// Charge from the source \[C\].
    q_source: Real,
    /// Charge through the brake resistor \[C\].
    q_brake: Real,
    /// The power stage's losses at each sub-step's end, summed \[W\].
    p_stage_sum: Real,
}

pub(super) fn add(x: [Real; 5], d: &Deriv, h: Real) -> [Real; 5] {
    [
        x[0] + h * d.id,
        x[1] + h * d.iq,
        x[2] + h * d.omega,
        x[3] + h * d.theta,
        x[4] + h * d.v_cap,
    ]
}

/// The motor's torque on the rotor: the electromagnetic `te` plus the
/// cogging torque `t_cog` where modelled \[N m\] (`te` itself without,
/// bit for bit).
fn with_cogging(te: Real, t_cog: Option<Real>) -> Real {
    match t_cog {
        Some(t) => te + t,
        None => te,
    }
}

impl Plant {
    /// Simulate one PWM period and return what the controller samples at its end.
    ///
    /// `duties` (high-side on fraction per phase, clamped to `[0, 1]`, NaN
    /// centred) take effect after [`BenchConfig::compute_delay_periods`];
    /// `bridge_enabled = false` puts the bridge in high impedance at once.
    /// `load_torque_nm` opposes positive rotation.
    pub fn step_period(
        &mut self,
        duties: [f32; 3],
        bridge_enabled: bool,
        load_torque_nm: f32,
    ) -> Measurements {
        self.apply_inputs(duties, bridge_enabled, load_torque_nm);

        let n = self.cfg.substeps.max(1);
        let t_period = self.cfg.period_s();
        let dt = t_period / n as Real;
        let sums = self.integrate_period(n, dt);
        self.store_period_averages(&sums, n, t_period);
        self.step_temperatures(&sums, n, t_period);
        self.time_s += t_period as f64;
        let m = self.sample();
        self.period += 1;
        m
    }

    /// The period's inputs: the cleaned duties through the compute delay,
    /// the bridge state (the diodes reset on a change) and the load torque.
    #[inline]
    fn apply_inputs(&mut self, duties: [f32; 3], bridge_enabled: bool, load_torque_nm: f32) {
        let clean = duties.map(|d| {
            if d.is_finite() {
                d.clamp(0.0, 1.0)
            } else {
                0.5
            }
        });
        if self.cfg.compute_delay_periods == 0 {
            self.applied = clean;
        } else {
            self.applied = self.pending;
            self.pending = clean;
        }
        if bridge_enabled != self.enabled {
            self.diodes = [Diode::Open; 3];
        }
        self.enabled = bridge_enabled;
        self.load_nm = load_torque_nm as Real;
    }

    /// The period's `n` sub-steps of `dt`, and what they integrated.
    #[inline]
    fn integrate_period(&mut self, n: u32, dt: Real) -> PeriodSums {
        let mut e_in = 0.0;
        let mut q_dc = 0.0;
        let mut v_term = [0.0; 3];
        let mut v_bus_sum = 0.0;
        let (mut e_copper, mut q_source, mut q_brake, mut p_stage_sum) = (0.0, 0.0, 0.0, 0.0);
        for j in 0..n {
            let u0 = j as Real / n as Real;
            let u1 = (j + 1) as Real / n as Real;
            let out = self.substep(u0, u1, dt);
            e_in += out.e_in;
            q_dc += out.q_dc;
            v_bus_sum += self.v_bus;
            for k in 0..3 {
                v_term[k] += out.vt[k] / n as Real;
            }
            e_copper += out.copper_j;
            q_source += out.q_source;
            q_brake += out.q_brake;
            if let Some(st) = &self.stage_thermal {
                p_stage_sum += st.loss_w(
                    self.phase_currents_a(),
                    self.v_bus,
                    self.cfg.pwm_frequency_hz,
                    self.enabled,
                );
            }
        }
        PeriodSums {
            e_in,
            q_dc,
            v_term,
            v_bus_sum,
            e_copper,
            q_source,
            q_brake,
            p_stage_sum,
        }
    }

    /// The period's averages from its `n` sub-steps' `sums` over
    /// `t_period`: bus voltage, input power, DC current, terminal voltages
    /// and, with a DC link, the source's and brake's currents.
    #[inline]
    fn store_period_averages(&mut self, sums: &PeriodSums, n: u32, t_period: Real) {
        self.v_bus_avg = sums.v_bus_sum / n as Real;
        self.p_in_avg = sums.e_in / t_period;
        self.i_dc_avg = sums.q_dc / t_period;
        self.v_terminal_avg = sums.v_term;
        if self.dc_link.is_some() {
            self.i_source_avg = sums.q_source / t_period;
            self.i_brake_avg = sums.q_brake / t_period;
        }
    }

    /// The winding's and the power stage's temperatures over the period
    /// (where modelled), from its `n` sub-steps' `sums` over `t_period`.
    #[inline]
    fn step_temperatures(&mut self, sums: &PeriodSums, n: u32, t_period: Real) {
        if let Some(w) = self.winding_thermal {
            self.t_winding_c = power::thermal_step(
                self.t_winding_c,
                w.ambient_c,
                sums.e_copper / t_period,
                w.r_th_k_per_w,
                w.tau_s,
                t_period,
            );
        }
        if let Some(st) = self.stage_thermal {
            self.t_stage_c = power::thermal_step(
                self.t_stage_c,
                st.ambient_c,
                sums.p_stage_sum / n as Real,
                st.r_th_k_per_w,
                st.tau_s,
                t_period,
            );
        }
    }

    /// One RK4 sub-step.
    pub(super) fn substep(&mut self, u0: Real, u1: Real, dt: Real) -> SubstepOut {
        let i_abc = self.phase_currents_a();
        if !self.enabled {
            self.update_diodes(i_abc);
        }
        let drives = self.drives(u0, u1, i_abc);
        let open = drives.iter().filter(|d| matches!(d, Leg::Open)).count();

        let x0 = [self.id, self.iq, self.omega_m, self.theta_m, self.v_cap];
        let f = |x: [Real; 5]| self.deriv(x, &drives, open);
        let k1 = f(x0);
        let k2 = f(add(x0, &k1, 0.5 * dt));
        let k3 = f(add(x0, &k2, 0.5 * dt));
        let k4 = f(add(x0, &k3, dt));
        let w = |a: Real, b: Real, c: Real, d: Real| (a + 2.0 * b + 2.0 * c + d) * dt / 6.0;
        let id = self.id + w(k1.id, k2.id, k3.id, k4.id);
        let iq = self.iq + w(k1.iq, k2.iq, k3.iq, k4.iq);
        let omega = self.omega_m + w(k1.omega, k2.omega, k3.omega, k4.omega);
        let theta = self.theta_m + w(k1.theta, k2.theta, k3.theta, k4.theta);
        let v_cap = self.v_cap + w(k1.v_cap, k2.v_cap, k3.v_cap, k4.v_cap);
        self.energy.supply_j += w(k1.p_supply, k2.p_supply, k3.p_supply, k4.p_supply);
        self.energy.copper_j += w(k1.p_copper, k2.p_copper, k3.p_copper, k4.p_copper);
        self.energy.shaft_j += w(k1.p_shaft, k2.p_shaft, k3.p_shaft, k4.p_shaft);
        self.energy.cogging_j += w(k1.p_cogging, k2.p_cogging, k3.p_cogging, k4.p_cogging);
        self.energy.friction_j += w(k1.p_friction, k2.p_friction, k3.p_friction, k4.p_friction);
        self.energy.load_j += w(k1.p_load, k2.p_load, k3.p_load, k4.p_load);
        self.energy.short_j += w(k1.p_short, k2.p_short, k3.p_short, k4.p_short);
        let e_in = w(k1.p_supply, k2.p_supply, k3.p_supply, k4.p_supply);
        let q_dc = w(k1.i_dc, k2.i_dc, k3.i_dc, k4.i_dc);
        let copper_j = w(k1.p_copper, k2.p_copper, k3.p_copper, k4.p_copper);
        let (q_source, q_brake) = if self.dc_link.is_some() {
            self.v_cap = v_cap;
            self.dc_link_energy([&k1, &k2, &k3, &k4], dt)
        } else {
            (0.0, 0.0)
        };

        let omega = self.stiction(omega, id, iq, theta);
        let (th, turns) = real::wrap_tau(theta);
        self.theta_m = th;
        self.turns += turns;
        self.omega_m = omega;

        let (id, iq) = self.constrain_currents(&drives, open, id, iq);
        self.id = id;
        self.iq = iq;

        // Bus and terminal voltages at the end of the sub-step (for outputs).
        let v_bus = self.bus(self.v_cap, &drives, self.phase_currents_a()).v_bus;
        self.v_bus = v_bus;
        let vt = self.terminal_voltages(&drives, v_bus);
        SubstepOut {
            e_in,
            q_dc,
            vt,
            copper_j,
            q_source,
            q_brake,
        }
    }

    /// The DC link's energies over a sub-step (RK4 weights of the four
    /// stages `k`); the charge through the source and the brake resistor.
    fn dc_link_energy(&mut self, k: [&Deriv; 4], dt: Real) -> (Real, Real) {
        let [k1, k2, k3, k4] = k;
        let w = |a: Real, b: Real, c: Real, d: Real| (a + 2.0 * b + 2.0 * c + d) * dt / 6.0;
        let out = |p: Real| if p > 0.0 { p } else { 0.0 };
        let e = &mut self.energy;
        e.source_out_j += w(
            out(k1.p_source),
            out(k2.p_source),
            out(k3.p_source),
            out(k4.p_source),
        );
        e.source_in_j += w(
            out(-k1.p_source),
            out(-k2.p_source),
            out(-k3.p_source),
            out(-k4.p_source),
        );
        e.source_loss_j += w(
            k1.p_source_loss,
            k2.p_source_loss,
            k3.p_source_loss,
            k4.p_source_loss,
        );
        e.capacitor_j += w(k1.p_cap, k2.p_cap, k3.p_cap, k4.p_cap);
        e.esr_j += w(k1.p_esr, k2.p_esr, k3.p_esr, k4.p_esr);
        e.brake_j += w(k1.p_brake, k2.p_brake, k3.p_brake, k4.p_brake);
        let q_source = w(k1.i_source, k2.i_source, k3.i_source, k4.i_source);
        let q_brake = w(k1.i_brake, k2.i_brake, k3.i_brake, k4.i_brake);
        (q_source, q_brake)
    }

    /// Coulomb friction and stiction: the speed `omega` does not cross zero
    /// while the motor's torque (electromagnetic at `id`, `iq` plus cogging
    /// at `theta_m`) is within the friction.
    fn stiction(&self, omega: Real, id: Real, iq: Real, theta_m: Real) -> Real {
        if matches!(self.mechanics, Mechanics::Free)
            && self.motor.coulomb_friction_nm > 0.0
            && ((self.omega_m > 0.0 && omega < 0.0) || (self.omega_m < 0.0 && omega > 0.0))
        {
            let te = self.motor.torque_nm(id, iq);
            let t_motor = with_cogging(te, self.cogging.map(|c| c.torque_nm(theta_m)));
            if (t_motor - self.load_nm).abs() <= self.motor.coulomb_friction_nm {
                return 0.0;
            }
        }
        omega
    }

    /// Constraints on the dq currents: open phases carry no current; a
    /// diode stops at zero current.
    fn constrain_currents(
        &self,
        drives: &[Leg; 3],
        open: usize,
        mut id: Real,
        mut iq: Real,
    ) -> (Real, Real) {
        let th_e = self.theta_e_rad();
        if open >= 2 {
            id = 0.0;
            iq = 0.0;
        } else {
            let mut n_crossed = 0;
            for k in 0..3 {
                let (c, s) = (
                    real::cos(th_e - PHASE_AXIS[k]),
                    real::sin(th_e - PHASE_AXIS[k]),
                );
                let ik = id * c - iq * s;
                let crossed = match (drives[k], self.enabled, self.diodes[k]) {
                    (Leg::Open, _, _) => true,
                    (_, false, Diode::High) => ik > 0.0,
                    (_, false, Diode::Low) => ik < 0.0,
                    _ => false,
                };
                if crossed {
                    // Remove the phase-k component: a_k = (c, -s) in dq, |a_k| = 1.
                    id -= ik * c;
                    iq += ik * s;
                    n_crossed += 1;
                }
            }
            if n_crossed >= 2 {
                id = 0.0;
                iq = 0.0;
            }
        }
        (id, iq)
    }

    /// The terminal voltages at the end of a sub-step on the bus `v_bus`.
    fn terminal_voltages(&self, drives: &[Leg; 3], v_bus: Real) -> [Real; 3] {
        let mut vt = [0.0; 3];
        for k in 0..3 {
            vt[k] = match drives[k] {
                Leg::Bus(h) => h * v_bus,
                Leg::Open => self.open_terminal_voltage(k, drives, v_bus),
            };
        }
        vt
    }

    /// State derivative. `x = [id, iq, omega_m, theta_m, v_cap]`.
    pub(super) fn deriv(&self, x: [Real; 5], drives: &[Leg; 3], open: usize) -> Deriv {
        let m = &self.motor;
        let r_ohm = self.winding_resistance_ohm();
        let [id0, iq0, omega, theta, v_cap] = x;
        let p = m.pole_pairs as Real;
        let th_e = p * theta;
        let we = p * omega;
        let (id, iq) = if open >= 2 { (0.0, 0.0) } else { (id0, iq0) };
        let mut cs = [(0.0, 0.0); 3];
        let mut i_abc = [0.0; 3];
        for k in 0..3 {
            let c = real::cos(th_e - PHASE_AXIS[k]);
            let s = real::sin(th_e - PHASE_AXIS[k]);
            cs[k] = (c, s);
            i_abc[k] = id * c - iq * s;
        }
        let bus = self.bus(v_cap, drives, i_abc);
        let v_bus = bus.v_bus;
        let v = self.motor_terminal_v(drives, v_bus);
        let (mut vd, mut vq) = (0.0, 0.0);
        for k in 0..3 {
            if let Leg::Bus(_) = drives[k] {
                vd += (2.0 / 3.0) * v[k] * cs[k].0;
                vq -= (2.0 / 3.0) * v[k] * cs[k].1;
            }
        }
        let (mut did, mut diq) = if m.d_saturation.fraction == 0.0 {
            // Without saturation, in the order it always was (the default
            // plant stays bit for bit what it was).
            (
                (vd - r_ohm * id + we * m.lq_h * iq) / m.ld_h,
                (vq - r_ohm * iq - we * m.ld_h * id - we * m.flux_linkage_wb) / m.lq_h,
            )
        } else {
            (
                (vd - r_ohm * id + we * m.lq_h * iq) / m.ld_incremental_h(id),
                (vq - r_ohm * iq - we * m.d_flux_wb(id)) / m.lq_h,
            )
        };
        if open >= 2 {
            did = 0.0;
            diq = 0.0;
        } else if open == 1 {
            (did, diq) = self.open_phase_held(drives, &cs, we, (id, iq), (did, diq));
        }
        let te = if open >= 2 { 0.0 } else { m.torque_nm(id, iq) };
        let t_cog = self.cogging.map(|c| c.torque_nm(theta));
        let domega = self.acceleration(with_cogging(te, t_cog), omega);
        let mut i_dc = 0.0;
        for k in 0..3 {
            if let Leg::Bus(h) = drives[k] {
                i_dc += h * i_abc[k];
            }
        }
        let i_short = self.short_current(drives, v_bus);
        let p_short = match self.faults.phase_short {
            Some(s) => i_short * i_short * s.r_ohm,
            None => 0.0,
        };
        let copper = r_ohm * (i_abc[0] * i_abc[0] + i_abc[1] * i_abc[1] + i_abc[2] * i_abc[2]);
        let friction = if matches!(self.mechanics, Mechanics::Free) {
            m.viscous_friction_nm_s_per_rad * omega * omega + m.coulomb_friction_nm * omega.abs()
        } else {
            0.0
        };
        let link = self.link_deriv(&bus, v_bus, v_cap);
        Deriv {
            id: did,
            iq: diq,
            omega: domega,
            theta: omega,
            // Supply power: motor legs plus the short (both fed from the bus).
            p_supply: v_bus * (i_dc + self.short_dc_current(drives, v_bus)),
            p_copper: copper,
            p_shaft: te * omega,
            p_cogging: t_cog.map_or(0.0, |t| t * omega),
            p_friction: friction,
            p_load: self.load_nm * omega,
            p_short,
            i_dc: i_dc + self.short_dc_current(drives, v_bus),
            ..link
        }
    }

    /// With one phase open: its terminal voltage solved so that its current
    /// stays 0, the dq current derivatives `(did, diq)` corrected.
    fn open_phase_held(
        &self,
        drives: &[Leg; 3],
        cs: &[(Real, Real); 3],
        we: Real,
        (id, iq): (Real, Real),
        (mut did, mut diq): (Real, Real),
    ) -> (Real, Real) {
        let m = &self.motor;
        if let Some(z) = drives.iter().position(|d| matches!(d, Leg::Open)) {
            let (c, s) = cs[z];
            let (ad, aq) = (c, -s);
            let (gd, gq) = (ad / m.ld_incremental_h(id), aq / m.lq_h);
            let (add, adq) = (-we * s, -we * c);
            let den = ad * gd + aq * gq;
            let mu = -(ad * did + aq * diq + add * id + adq * iq) / den;
            did += mu * gd;
            diq += mu * gq;
        }
        (did, diq)
    }

    /// The rotor's acceleration under the motor's torque `te`
    /// (electromagnetic plus cogging) at `omega` (viscous and Coulomb
    /// friction, stiction, the load; 0 when held).
    fn acceleration(&self, te: Real, omega: Real) -> Real {
        let m = &self.motor;
        match self.mechanics {
            Mechanics::Free => {
                let tc = if omega > 0.0 {
                    m.coulomb_friction_nm
                } else if omega < 0.0 {
                    -m.coulomb_friction_nm
                } else {
                    // Stiction: friction cancels the net torque up to its limit.
                    let net = te - self.load_nm;
                    net.clamp(-m.coulomb_friction_nm, m.coulomb_friction_nm)
                };
                (te - m.viscous_friction_nm_s_per_rad * omega - tc - self.load_nm) / m.inertia_kg_m2
            }
            Mechanics::Locked | Mechanics::ConstantSpeed(_) => 0.0,
        }
    }

    /// The DC link's terms (capacitor, source, ESR, brake) of the
    /// derivative; zero without a DC link.
    fn link_deriv(&self, bus: &BusSolution, v_bus: Real, v_cap: Real) -> Deriv {
        match &self.dc_link {
            Some(dc) => Deriv {
                v_cap: bus.i_cap / dc.c_f,
                p_source: v_bus * bus.i_source,
                p_source_loss: (self.source_v() - v_bus) * bus.i_source,
                p_cap: v_cap * bus.i_cap,
                p_esr: dc.esr_ohm * bus.i_cap * bus.i_cap,
                p_brake: v_bus * bus.i_brake,
                i_source: bus.i_source,
                i_brake: bus.i_brake,
                ..Deriv::default()
            },
            None => Deriv::default(),
        }
    }
}
