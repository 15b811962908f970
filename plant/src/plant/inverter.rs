//! The inverter: each leg's drive over a sub-step (PWM, dead time, the
//! freewheel diodes), the bus and the terminal voltages it makes.

use super::*;

/// Per-phase state of the bridge while it is disabled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Diode {
    /// Not conducting.
    Open,
    /// High-side diode (terminal at the bus, current out of the motor).
    High,
    /// Low-side diode (terminal at 0 V, current into the motor).
    Low,
}

/// How one phase terminal is driven over a sub-step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Leg {
    /// Connected to the bus a fraction `h` of the time, else to 0 V.
    Bus(Real),
    /// Not connected (current held at zero).
    Open,
}

/// Fractions of the window `[u0, u1]` (fractions of the period) during which
/// a phase with duty `d` and dead time `delta` (fraction of the period) has
/// its high side on and its low side on; the rest is dead time.
///
/// Centre-aligned: the ideal high pulse is `[0.5 - d/2, 0.5 + d/2]`; each
/// rising edge (high side at the pulse start, low side at its end) is delayed
/// by `delta`.
pub fn phase_fractions(d: Real, delta: Real, u0: Real, u1: Real) -> (Real, Real) {
    let overlap = |a: Real, b: Real| -> Real {
        let lo = if a > u0 { a } else { u0 };
        let hi = if b < u1 { b } else { u1 };
        if hi > lo {
            hi - lo
        } else {
            0.0
        }
    };
    if d >= 1.0 {
        return (u1 - u0, 0.0);
    }
    if d <= 0.0 {
        return (0.0, u1 - u0);
    }
    let on = 0.5 - 0.5 * d;
    let off = 0.5 + 0.5 * d;
    let high = overlap(on + delta, off);
    let low = overlap(0.0, on) + overlap(off + delta, 1.0);
    (high, low)
}

impl Plant {
    /// Drive of each phase over the sub-step `[u0, u1]` (fractions of the period).
    pub(super) fn drives(&self, u0: Real, u1: Real, i_abc: [Real; 3]) -> [Leg; 3] {
        let mut out = [Leg::Open; 3];
        let delta = self.cfg.dead_time_s * self.cfg.pwm_frequency_hz;
        for k in 0..3 {
            out[k] = if self.enabled {
                let (a, b) = match self.cfg.pwm_mode {
                    PwmMode::Averaged => (0.0, 1.0),
                    PwmMode::CarrierCompared => (u0, u1),
                };
                let (high, low) = phase_fractions(self.applied[k] as Real, delta, a, b);
                let dead = (b - a) - high - low;
                let dead_high = if i_abc[k] > 0.0 {
                    0.0
                } else if i_abc[k] < 0.0 {
                    dead
                } else {
                    0.5 * dead
                };
                Leg::Bus((high + dead_high) / (b - a))
            } else {
                match self.diodes[k] {
                    Diode::Open => Leg::Open,
                    Diode::High => Leg::Bus(1.0),
                    Diode::Low => Leg::Bus(0.0),
                }
            };
        }
        if let Some(p) = self.faults.disconnected_phase {
            out[p.index()] = Leg::Open;
        }
        out
    }

    /// Source voltage after the injected sag.
    pub(super) fn source_v(&self) -> Real {
        match &self.dc_link {
            Some(d) => d.v_source_v - self.faults.bus_sag_v,
            None => self.cfg.bus_voltage_v - self.faults.bus_sag_v,
        }
    }

    /// Bus voltage with no load current: the source's, or the capacitor's.
    pub(super) fn open_circuit_bus_v(&self) -> Real {
        match self.dc_link {
            Some(_) => self.v_cap,
            None => self.source_v(),
        }
    }

    /// The bus at capacitor voltage `v_cap` (ignored without a DC link),
    /// given drives and phase currents.
    pub(super) fn bus(&self, v_cap: Real, drives: &[Leg; 3], i_abc: [Real; 3]) -> BusSolution {
        match &self.dc_link {
            None => BusSolution {
                v_bus: self.bus_voltage(drives, i_abc),
                ..BusSolution::default()
            },
            Some(dc) => {
                let mut i_dc = 0.0;
                for k in 0..3 {
                    if let Leg::Bus(h) = drives[k] {
                        i_dc += h * i_abc[k];
                    }
                }
                let g_brake = match dc.brake_resistor_ohm {
                    Some(r) if self.brake_on && r > 0.0 => 1.0 / r,
                    _ => 0.0,
                };
                power::solve_bus(
                    dc,
                    v_cap,
                    self.source_v(),
                    i_dc,
                    self.short_conductance(drives),
                    g_brake,
                )
            }
        }
    }

    /// Conductance a phase short adds between the bus rails, `(h_a - h_b)^2 / r`.
    pub(super) fn short_conductance(&self, drives: &[Leg; 3]) -> Real {
        match self.faults.phase_short {
            Some(s) if s.r_ohm > 0.0 => match (drives[s.a.index()], drives[s.b.index()]) {
                (Leg::Bus(ha), Leg::Bus(hb)) => (ha - hb) * (ha - hb) / s.r_ohm,
                _ => 0.0,
            },
            _ => 0.0,
        }
    }

    /// Bus voltage with source resistance, given drives and phase currents.
    pub(super) fn bus_voltage(&self, drives: &[Leg; 3], i_abc: [Real; 3]) -> Real {
        let mut i_dc = 0.0;
        for k in 0..3 {
            if let Leg::Bus(h) = drives[k] {
                i_dc += h * i_abc[k];
            }
        }
        let rs = self.cfg.source_resistance_ohm;
        // A short adds (h_a - h_b)^2 V_bus / r: solve the linear equation for V_bus.
        let g_short = self.short_conductance(drives);
        (self.source_v() - rs * i_dc) / (1.0 + rs * g_short)
    }

    /// Extra DC current drawn by a phase short.
    pub(super) fn short_dc_current(&self, drives: &[Leg; 3], v_bus: Real) -> Real {
        match self.faults.phase_short {
            Some(s) if s.r_ohm > 0.0 => match (drives[s.a.index()], drives[s.b.index()]) {
                (Leg::Bus(ha), Leg::Bus(hb)) => (ha - hb) * (ha - hb) * v_bus / s.r_ohm,
                _ => 0.0,
            },
            _ => 0.0,
        }
    }

    /// Current in the short from leg `a` to leg `b` \[A\] (0 without a short).
    pub(super) fn short_current(&self, drives: &[Leg; 3], v_bus: Real) -> Real {
        match self.faults.phase_short {
            Some(s) if s.r_ohm > 0.0 => match (drives[s.a.index()], drives[s.b.index()]) {
                (Leg::Bus(ha), Leg::Bus(hb)) => (ha - hb) * v_bus / s.r_ohm,
                _ => 0.0,
            },
            _ => 0.0,
        }
    }

    /// Terminal voltages seen by the motor (a short ties its two terminals).
    pub(super) fn motor_terminal_v(&self, drives: &[Leg; 3], v_bus: Real) -> [Real; 3] {
        let mut v = [0.0; 3];
        for k in 0..3 {
            if let Leg::Bus(h) = drives[k] {
                v[k] = h * v_bus;
            }
        }
        if let Some(s) = self.faults.phase_short {
            let (a, b) = (s.a.index(), s.b.index());
            if let (Leg::Bus(_), Leg::Bus(_)) = (drives[a], drives[b]) {
                let m = 0.5 * (v[a] + v[b]);
                v[a] = m;
                v[b] = m;
            }
        }
        v
    }

    /// Terminal voltage of open phase `z`, from the constraint `di_z/dt = 0`
    /// (one open phase) or the star point (all open: back-EMF about the mean).
    pub(super) fn open_terminal_voltage(&self, z: usize, drives: &[Leg; 3], v_bus: Real) -> Real {
        let m = &self.motor;
        let th_e = self.theta_e_rad();
        let we = self.omega_e_rad_s();
        let e = PHASE_AXIS.map(|phi| -we * m.flux_linkage_wb * real::sin(th_e - phi));
        let open = drives.iter().filter(|d| matches!(d, Leg::Open)).count();
        if open >= 2 {
            // No current: terminals float at star point + EMF; the star point is
            // set by the conducting phase (if any), else by the bus midpoint.
            let v = self.motor_terminal_v(drives, v_bus);
            let star = match drives.iter().position(|d| matches!(d, Leg::Bus(_))) {
                Some(k) => v[k] - e[k],
                None => 0.5 * v_bus,
            };
            return star + e[z];
        }
        // One open phase: recompute the multiplier of `deriv` at the present state.
        let d = self.deriv(
            [self.id, self.iq, self.omega_m, self.theta_m, self.v_cap],
            drives,
            0,
        );
        let (c, s) = (
            real::cos(th_e - PHASE_AXIS[z]),
            real::sin(th_e - PHASE_AXIS[z]),
        );
        let (ad, aq) = (c, -s);
        let (gd, gq) = (ad / m.ld_incremental_h(self.id), aq / m.lq_h);
        let (add, adq) = (-we * s, -we * c);
        let den = ad * gd + aq * gq;
        let mu = -(ad * d.id + aq * d.iq + add * self.id + adq * self.iq) / den;
        // `d` was computed with the open terminal at 0 V; the open terminal adds
        // (2/3) v_z a_z to v_dq, i.e. mu = (2/3) v_z. Zero sequence cancels, so
        // v_z is referred to the same rail as the driven terminals.
        let _ = v_bus;
        1.5 * mu
    }

    /// Diode state machine for the disabled bridge.
    pub(super) fn update_diodes(&mut self, i_abc: [Real; 3]) {
        for k in 0..3 {
            self.diodes[k] = if i_abc[k] > I_ZERO_A {
                Diode::Low
            } else if i_abc[k] < -I_ZERO_A {
                Diode::High
            } else {
                Diode::Open
            };
        }
        if let Some(p) = self.faults.disconnected_phase {
            self.diodes[p.index()] = Diode::Open;
        }
        let open = self.diodes.iter().filter(|d| **d == Diode::Open).count();
        let v_bus = self.open_circuit_bus_v();
        let drives = self.drives(0.0, 1.0, i_abc);
        if open == 3 {
            // All open: conduction starts when the line-to-line EMF exceeds the bus.
            let th_e = self.theta_e_rad();
            let we = self.omega_e_rad_s();
            let e = PHASE_AXIS.map(|phi| -we * self.motor.flux_linkage_wb * real::sin(th_e - phi));
            let (mut hi, mut lo) = (0, 0);
            for k in 0..3 {
                if e[k] > e[hi] {
                    hi = k;
                }
                if e[k] < e[lo] {
                    lo = k;
                }
            }
            let disconnected = self.faults.disconnected_phase.map(Phase::index);
            if e[hi] - e[lo] > v_bus && Some(hi) != disconnected && Some(lo) != disconnected {
                self.diodes[hi] = Diode::High;
                self.diodes[lo] = Diode::Low;
            }
        } else if open == 1 {
            if let Some(z) = self.diodes.iter().position(|d| *d == Diode::Open) {
                if Some(z) != self.faults.disconnected_phase.map(Phase::index) {
                    let vz = self.open_terminal_voltage(z, &drives, v_bus);
                    if vz > v_bus {
                        self.diodes[z] = Diode::High;
                    } else if vz < 0.0 {
                        self.diodes[z] = Diode::Low;
                    }
                }
            }
        }
    }
}
