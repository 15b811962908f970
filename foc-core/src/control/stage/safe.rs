//! The safe state chosen by speed (design §30): with the bridge off
//! (faulted or disabled) above the speed where the back-EMF's
//! line-to-line peak exceeds the bus, the freewheel diodes would rectify
//! it into the bus and brake the rotor with it (uncontrolled generator
//! mode); the three low sides switched on (active short circuit) keep
//! the bus out of it instead. Released to freewheeling below 90 % of that
//! speed.

use super::*;

/// What the safe state remembers between periods.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SafeMemory {
    /// The short circuit is in force (the bridge off above the rectifying
    /// speed).
    pub short_circuit: bool,
    /// The speed judged by [rad/s, mechanical, signed] (the last one the
    /// tracker could be trusted with).
    pub trusted_speed_rad_s: f32,
    /// The bus as last read with the bridge off \[V\] (0: none yet).
    pub v_bus_off_v: f32,
}

impl SafeMemory {
    /// Freewheeling, at rest.
    pub const INIT: Self = Self {
        short_circuit: false,
        trusted_speed_rad_s: 0.0,
        v_bus_off_v: 0.0,
    };
}

/// The short circuit is released below this share of the rectifying
/// speed (hysteresis).
pub const RELEASE_SHARE: f32 = 0.9;

impl CurrentStage {
    /// The bridge command while the bridge is off: the short circuit or
    /// all switches off.
    ///
    /// - Only with a permit installed (an identified flux linkage) and the
    ///   short circuit configured ([`crate::control::field::FieldConfig::short_circuit`]).
    /// - Never when the fault forbids switching (gate driver, timer break,
    ///   PWM error): everything off.
    /// - The speed is the tracked one, as [`Self::note_speed`] last trusted
    ///   it: after an angle-sensor fault (or sensorless, with the bridge
    ///   off) the speed just before stands until the faults are cleared (a
    ///   short circuit holds the rotor braked; nothing flows once it
    ///   stops).
    /// - The bus is the one read; when it cannot be read the decision
    ///   stands.
    #[inline(always)]
    pub(super) fn safe_state(&mut self, v_bus_read_v: Option<f32>) -> BridgeCommand {
        if let Some(v) = v_bus_read_v {
            self.safe.v_bus_off_v = v;
        }
        let wanted = self.short_circuit_wanted(v_bus_read_v);
        self.safe.short_circuit = wanted;
        if wanted {
            BridgeCommand::ShortCircuit
        } else {
            BridgeCommand::SafeState
        }
    }

    #[inline(always)]
    fn short_circuit_wanted(&self, v_bus_read_v: Option<f32>) -> bool {
        if !(self.field.short_circuit() && self.state.calibrated) {
            return false;
        }
        let faults = self.supervisor.faults();
        if faults.contains(Fault::GateDriverFault) || faults.contains(Fault::PwmError) {
            return false;
        }
        let v_bus = match v_bus_read_v {
            Some(v) if v.is_finite() && v > 0.0 => v,
            _ => return self.safe.short_circuit,
        };
        let w = (self.safe.trusted_speed_rad_s * self.config.angle.pole_pairs as f32).abs();
        let on = self.field.rectifying_speed_rad_s(v_bus);
        if self.safe.short_circuit {
            w > RELEASE_SHARE * on
        } else {
            w > on
        }
    }

    /// Every period: the electrical speed the safe state judges by
    /// (`|w_e|`), taken from the tracker only while it can be trusted: no
    /// angle-sensor fault latched, and, where an observer gives the angle
    /// (sensorless, limp-home), only while the bridge runs (off, the
    /// observer pauses and its speed decays while the rotor does not).
    /// Otherwise the last trusted speed stands: an angle fault at the top
    /// speed is judged by the speed just before it. While the bridge runs
    /// the short circuit is not in force (a fresh decision when it stops).
    #[inline(always)]
    pub(super) fn note_speed(&mut self, bridge_on: bool) {
        // Running, no fault is latched and the angle is the loop's own.
        if bridge_on {
            self.safe.short_circuit = false;
            self.safe.trusted_speed_rad_s = self.tracker.velocity_rad_s();
            return;
        }
        const ANGLE_LOST: u32 = Fault::AngleSensorError.bit()
            | Fault::AngleSensorImplausible.bit()
            | Fault::AngleSensorStuck.bit()
            | Fault::ObserverLostLock.bit();
        let observer = self.sensorless.is_some() || self.state.limp_home;
        if !observer && self.supervisor.faults().0 & ANGLE_LOST == 0 {
            self.safe.trusted_speed_rad_s = self.tracker.velocity_rad_s();
        }
    }

    /// A closed-loop start with the bridge off is refused while the rotor
    /// turns above its no-load base speed (the back-EMF above the voltage
    /// the current loop can hold, design §30): the loops and the
    /// weakening would start from zero against it and lose the current
    /// (reproduced on the interior-PM file at 1.5 to 2.2 x base:
    /// over-current, the bus over its trip). The safe state (the short
    /// circuit above the rectifying speed) stays until the rotor is slower.
    /// Only on the angle sensor, with a permit (an identified flux
    /// linkage) and a bus read.
    pub(super) fn too_fast_to_start(&self) -> bool {
        let v = self.safe.v_bus_off_v;
        // Sensorless the speed with the bridge off is not known (the
        // observer pauses): not judged.
        if !(self.state.calibrated && self.sensorless.is_none() && v.is_finite() && v > 0.0) {
            return false;
        }
        let w = (self.safe.trusted_speed_rad_s * self.config.angle.pole_pairs as f32).abs();
        w > self.field.base_speed_e_rad_s(v)
    }
}
