//! The brake chopper: the brake resistor switched on above a bus voltage,
//! with hysteresis and a duty lock-out.

use super::*;

/// Brake-chopper hysteresis on the bus voltage (state; thresholds in
/// [`PowerLimitsConfig`]): on at `V_bus >= brake_on_v`, off again at
/// `V_bus <= brake_off_v`.
///
/// A missing or non-finite reading switches it *off*: a resistor switched
/// on without knowing the bus could discharge a healthy bus into itself
/// until it burns. (A motor coasting with its bridge off can still pump
/// the bus through the body diodes; the supervisor's over-voltage fault
/// and the bus-sense fault are the reaction there.)
///
/// ```
/// use foc_core::control::power::{BrakeChopper, PowerLimitsConfig};
/// use foc_core::control::{supervisor::SupervisorConfig, MotorParams};
/// let motor = MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 40e-6, lq_h: 40e-6, flux_linkage_wb: 0.004 };
/// let cfg = PowerLimitsConfig::for_board(&SupervisorConfig::default(), motor, false).with_brake_resistor();
/// let mut b = BrakeChopper::new();
/// let dt = 50e-6;
/// assert!(!b.step(&cfg, Some(24.0), dt, false));
/// assert!(b.step(&cfg, Some(cfg.brake_on_v), dt, false));
/// assert!(b.step(&cfg, Some(cfg.brake_on_v - 0.1), dt, false)); // hysteresis
/// assert!(!b.step(&cfg, Some(f32::NAN), dt, false));
/// // A supply that holds the bus above the thresholds: on for at most
/// // `brake_max_on_s`, then locked out until the bus falls below
/// // `brake_off_v`.
/// let n = (cfg.brake_max_on_s / dt) as usize + 2;
/// let on = (0..n).filter(|_| b.step(&cfg, Some(cfg.brake_on_v + 1.0), dt, false)).count();
/// assert!(on < n && b.is_locked_out());
/// assert!(!b.step(&cfg, Some(cfg.brake_off_v - 0.1), dt, false));
/// assert!(b.step(&cfg, Some(cfg.brake_on_v), dt, false));
/// // While the motor regenerates, the guard does not count.
/// let on = (0..n).filter(|_| b.step(&cfg, Some(cfg.brake_on_v + 1.0), dt, true)).count();
/// assert_eq!(on, n);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BrakeChopper {
    pub(super) on: bool,
    /// Leaky count of the time on while the motor did not regenerate \[s\].
    pub(super) on_s: f32,
    /// Locked out by the guard until the bus falls below `brake_off_v`.
    pub(super) locked: bool,
}

impl BrakeChopper {
    /// Off.
    pub const fn new() -> Self {
        Self {
            on: false,
            on_s: 0.0,
            locked: false,
        }
    }

    /// Off, guard released.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Whether the chopper is on.
    pub const fn is_on(&self) -> bool {
        self.on
    }

    /// Whether the guard has locked it out (see
    /// [`PowerLimitsConfig::brake_max_on_s`]; released when the bus falls
    /// below `brake_off_v`).
    pub const fn is_locked_out(&self) -> bool {
        self.locked
    }

    /// One bus reading \[V\] after `dt_s`, and whether the motor
    /// regenerates (its electrical power is negative: the chopper then
    /// takes the motor's energy, not the supply's); returns whether the
    /// chopper is on.
    pub fn step(
        &mut self,
        cfg: &PowerLimitsConfig,
        v_bus_v: Option<f32>,
        dt_s: f32,
        regenerating: bool,
    ) -> bool {
        let v = match v_bus_v {
            Some(v) if v.is_finite() => v,
            _ => {
                self.on = false;
                return false;
            }
        };
        // NaN thresholds (unsanitized) compare false: off, never on.
        if self.locked && v <= cfg.brake_off_v {
            self.locked = false;
            self.on_s = 0.0;
        }
        let want = if self.on {
            v > cfg.brake_off_v
        } else {
            v >= cfg.brake_on_v
        };
        self.on = want && !self.locked;
        if self.on && !regenerating {
            self.on_s += dt_s;
            // NaN or negative guard time (unsanitized): lock out at once.
            if self.on_s.is_nan() || self.on_s > cfg.brake_max_on_s || cfg.brake_max_on_s.is_nan() {
                self.on = false;
                self.locked = true;
            }
        } else if self.on_s > 0.0 {
            let left = self.on_s - 0.1 * dt_s;
            self.on_s = if left > 0.0 { left } else { 0.0 };
        }
        self.on
    }
}
