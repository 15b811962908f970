//! Power-stage protection as *limits before faults* (design §18, issue 17):
//! a regenerative-power limit as the bus voltage rises towards the
//! over-voltage threshold, bus-current and power limits for motoring and
//! regeneration, thermal derating (a winding temperature model and the
//! measured power-stage temperature) and a brake-chopper hysteresis. Pure
//! math: no hardware, no allocation, no panics; every non-finite or missing
//! input gives the safe answer (no current, chopper off).
//!
//! The result is a q-current *window* `[min_a, max_a]` ([`IqWindow`]) that
//! the current stage clamps the q-current reference to (after the speed
//! loop, before the current loop), with the limit that set it
//! ([`ActiveLimit`]) and by how much ([`IqWindow::factor`]) for the
//! feedback and telemetry.
//!
//! # The math (short derivation; design §18)
//!
//! **Power balance.** With an ideal (lossless) inverter the bus power equals
//! the electrical power into the motor, in the amplitude-invariant dq frame
//! `P = 1.5 (v_d i_d + v_q i_q)` \[W\]. In steady state (no `L di/dt`)
//!
//! ```text
//! v_d = R i_d - w_e L_q i_q
//! v_q = R i_q + w_e (L_d i_d + psi)
//! P(i_q) = 1.5 R (i_d^2 + i_q^2) + 1.5 w_e (psi + (L_d - L_q) i_d) i_q
//!        = a i_q^2 + b i_q + c,   a = 1.5 R,  b = 1.5 w_e psi_eff,  c = 1.5 R i_d^2
//! ```
//!
//! copper loss plus mechanical power. This module solves that quadratic
//! *exactly* (numerically stable root forms, no cancellation): there is no
//! approximation beyond the steady-state model itself. `P > 0` is motoring
//! (drawn from the supply), `P < 0` regeneration; the bus current is
//! `I_bus = P / V_bus`. `R` is corrected for the winding temperature:
//! `R(T) = R_20 (1 + 0.00393 (T - 20))` (copper).
//!
//! *Error of the model* (what the tests cannot see): the `L di/dt` terms
//! (the magnetic energy `0.75 (L_d i_d^2 + L_q i_q^2)`, exchanged once per
//! current step, e.g. 3 mJ at 40 uH and 10 A: transient only); inverter
//! conduction and switching losses (not modelled: the supply delivers that
//! much *more* than the limit in motoring and receives that much *less* in
//! regeneration, which is the safe side there); parameter errors
//! (`dP = 1.5 dR i^2 + 1.5 w_e dpsi i_q`). A first-order alternative,
//! `i_q = P / (1.5 w_e psi)`, would ignore the copper loss: its relative
//! error is `R i_q / (w_e psi)`, unbounded near standstill, which is why the
//! quadratic is solved instead.
//!
//! **Power limits.** The allowed bus power is `[-P_regen, P_mot]` with
//! `P_mot = min(power_motoring_max_w, V_bus bus_current_motoring_max_a)` and
//! `P_regen = min(power_regen_max_w, V_bus bus_current_regen_max_a)`. The
//! set `{i_q : P(i_q) <= P_mot}` is the interval between the two roots of
//! `P = P_mot` (one on each side of 0); `{i_q : P(i_q) >= -P_regen}` is the
//! outside of the interval between the roots of `P = -P_regen` (both on the
//! regenerating side, `i_q w_e psi_eff < 0`). The window is the interval
//! *around 0* inside both, so every `i_q` in it keeps the steady-state power
//! within the limits. (Consequence at low speed: beyond the current of the
//! largest regenerative power, `w_e psi_eff / (2 R)`, braking is dissipative
//! again (plugging, `P > 0`); that region lies beyond a forbidden gap and is
//! not offered. When the regenerative peak `b^2 / (4 a) - c` crosses
//! `P_regen` (speed rising) the regenerating end moves from the current
//! limit to that current in one step: a window cannot hold the gap.)
//!
//! **Regen limit on the bus voltage.** With `s(V)` falling linearly from 1
//! at `regen_start_v` to 0 at `regen_end_v`, the regenerating end of the
//! window (after every other limit) is multiplied by `s(V_bus)`. The largest
//! regenerative power inside the window then falls continuously and
//! monotonically to 0 at `regen_end_v` (at high speed, where `P` is nearly
//! linear in `i_q`, it falls linearly with `V_bus`); the window shrinks
//! monotonically with `V_bus`, and nothing changes below `regen_start_v`.
//! Scaling the current rather than a power keeps the limit continuous in
//! `V_bus` (the variable it regulates) and works with the power limits
//! switched off.
//!
//! **Thermal derating.** `k = min(k_winding, k_stage)`, each falling linearly
//! from 1 at its `*_derate_start_c` to 0 at its `*_derate_end_c`; both ends
//! of the current limit are multiplied by `k`. The winding temperature is
//! [`ThermalEstimate`]'s first-order model: copper loss
//! `P_cu = 1.5 R(T) (i_d^2 + i_q^2)`, `tau dT/dt = T_amb + R_th P_cu - T`,
//! integrated with a backward-Euler step (stable for any `dt`).
//!
//! **Brake chopper.** [`BrakeChopper`]: on at `V_bus >= brake_on_v`, off at
//! `V_bus <= brake_off_v`, off on a missing or non-finite reading.
//!
//! ```
//! use foc_core::control::power::{iq_window, ActiveLimit, PowerInputs, PowerLimitsConfig};
//! use foc_core::control::supervisor::SupervisorConfig;
//! use foc_core::control::MotorParams;
//! let motor = MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 40e-6, lq_h: 40e-6, flux_linkage_wb: 0.004 };
//! let cfg = PowerLimitsConfig::for_board(&SupervisorConfig::default(), motor, false).sanitized();
//! let mut inputs = PowerInputs {
//!     v_bus_v: Some(24.0),
//!     omega_e_rad_s: 2000.0,
//!     i_d_a: 0.0,
//!     iq_request_a: 0.0,
//!     current_limit_a: 10.0,
//!     winding_temperature_c: Some(40.0),
//!     stage_temperature_c: None,
//! };
//! let w = iq_window(&cfg, &inputs);
//! assert_eq!((w.min_a, w.max_a, w.active), (-10.0, 10.0, ActiveLimit::None));
//! // The bus near the over-voltage threshold: no regenerative current.
//! inputs.v_bus_v = Some(cfg.regen_end_v);
//! let w = iq_window(&cfg, &inputs);
//! assert_eq!((w.min_a, w.max_a, w.active), (0.0, 10.0, ActiveLimit::Regen));
//! // Braking asked (q-current against the speed): the d-axis braking
//! // current turns the vector (up to the current limit at `regen_end_v`)
//! // and keeps the braking that the winding's copper loss pays for.
//! inputs.iq_request_a = -5.0;
//! let w = iq_window(&cfg, &inputs);
//! assert_eq!(w.id_a, -10.0);
//! assert_eq!(w.max_a, 0.0);
//! // A missing bus reading: no current at all.
//! inputs.v_bus_v = None;
//! assert_eq!(iq_window(&cfg, &inputs).max_a, 0.0);
//! ```
//!
//! Files: this one the configuration and its derating ramps; `window` the
//! q-current window; `thermal` the winding-temperature estimate; `chopper`
//! the brake chopper; `limiter` the per-period [`PowerLimiter`].

mod chopper;
mod limiter;
mod thermal;
mod window;

pub use chopper::*;
pub use limiter::*;
pub use thermal::*;
pub use window::*;

use crate::control::supervisor::SupervisorConfig;
use crate::control::MotorParams;
use crate::frames::Dq;
use crate::{all_finite, sqrtf};

/// Copper's temperature coefficient of resistance [1/K] (at 20 deg C).
pub const COPPER_TEMPCO_PER_K: f32 = 0.003_93;
/// The temperature at which [`MotorParams::r_ohm`] is taken [deg C].
pub const R_REFERENCE_C: f32 = 20.0;
/// The winding estimate saturates here [deg C] (far beyond any insulation
/// class: the winding derating is at 0 long before).
pub const THERMAL_MAX_C: f32 = 400.0;
/// The winding estimate never goes below this [deg C].
pub const THERMAL_MIN_C: f32 = -60.0;

/// Limits of the power stage, the winding model and the brake chopper.
///
/// "Off" is `f32::INFINITY` for every limit and threshold (a current or
/// power limit of `+inf`, a derating or regen window ending at `+inf`, a
/// brake threshold of `+inf`). NaN never means "off": see
/// [`Self::sanitized`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PowerLimitsConfig {
    /// The motor model of the power balance and of the copper loss. Its
    /// `r_ohm` is the phase resistance at [`R_REFERENCE_C`] (20 deg C).
    /// Keep it equal to the current loop's motor (update both after an
    /// identification).
    pub motor: MotorParams,
    /// Bus voltage \[V\] above which regenerative current is reduced
    /// (linearly, to 0 at [`Self::regen_end_v`]).
    pub regen_start_v: f32,
    /// Bus voltage \[V\] at and above which no regenerative current is
    /// allowed; below the supervisor's `bus_over_voltage_v`. `+inf`: off.
    pub regen_end_v: f32,
    /// d-axis braking \[A\] (magnitude): while the drive brakes (the
    /// requested q-current opposes the speed) and the bus voltage is in the
    /// regen ramp, a negative d-current of `(1 - s(V_bus))` times this (at
    /// most the derated current limit) dissipates braking energy in the
    /// winding, so the motor keeps braking (up to zero net power into the
    /// bus) instead of coasting on a full bus, and the current vector turns
    /// towards the d axis instead of collapsing (its magnetic energy stays
    /// in the winding rather than charging the bus). Costs winding heat
    /// (counted by the winding model). `+inf`: up to the current limit; 0:
    /// off.
    pub regen_id_max_a: f32,
    /// Largest current drawn from the supply \[A\] (`P / V_bus`, averaged
    /// over a PWM period). Size: the supply's or battery's discharge limit
    /// (or its fuse). `+inf`: off.
    pub bus_current_motoring_max_a: f32,
    /// Largest current returned to the supply \[A\] (magnitude, `>= 0`).
    /// Size: what the supply can sink, a battery's (BMS) charge-current
    /// limit. A diode-fed bench supply sinks nothing, but the bus
    /// capacitor does: leave this off there and let the bus-voltage ramp
    /// ([`Self::regen_start_v`]) hold the bus; 0 forbids regenerative
    /// braking altogether (only copper-loss braking remains). `+inf`: off.
    pub bus_current_regen_max_a: f32,
    /// Largest power drawn from the supply \[W\]. `+inf`: off.
    pub power_motoring_max_w: f32,
    /// Largest power returned to the supply \[W\] (magnitude). `+inf`: off.
    pub power_regen_max_w: f32,
    /// Winding-to-ambient thermal resistance [K/W]: the steady temperature
    /// rise per watt of copper loss.
    pub thermal_resistance_k_per_w: f32,
    /// Winding thermal time constant \[s\] (63 % of a step's final rise).
    pub thermal_time_constant_s: f32,
    /// Ambient temperature of the winding model [deg C] (also its start).
    pub ambient_c: f32,
    /// Modelled winding temperature [deg C] where derating starts.
    pub winding_derate_start_c: f32,
    /// Modelled winding temperature [deg C] where the current limit reaches
    /// 0. `+inf`: winding derating off.
    pub winding_derate_end_c: f32,
    /// Measured power-stage temperature [deg C] where derating starts.
    pub stage_derate_start_c: f32,
    /// Measured power-stage temperature [deg C] where the current limit
    /// reaches 0 (below the supervisor's `max_temperature_c`). `+inf`:
    /// stage derating off (and no stage sensor needed).
    pub stage_derate_end_c: f32,
    /// Bus voltage \[V\] at which the brake chopper switches on. `+inf`: no
    /// brake resistor.
    pub brake_on_v: f32,
    /// Bus voltage \[V\] at which the brake chopper switches off again
    /// (`<= brake_on_v`: the hysteresis). Above the supply's highest
    /// voltage, or the supply feeds the resistor (see
    /// [`Self::brake_max_on_s`]).
    pub brake_off_v: f32,
    /// Longest the chopper may conduct while the motor does not
    /// regenerate \[s\] (a leaky count: it runs down at a tenth of the rate
    /// while the chopper is off or the motor regenerates): then it locks
    /// out until the bus falls below `brake_off_v`. What it catches: a
    /// supply that feeds the resistor (held above `brake_off_v`, or
    /// sagging and recovering under the resistor's load), a full battery
    /// above the thresholds. Braking a load that regenerates for a long
    /// time (lowering a weight) is not counted. `+inf`: no guard; values
    /// above about 500 s act as `+inf` (f32 resolution at 20 kHz).
    pub brake_max_on_s: f32,
}

/// `x` unless NaN or negative (then 0): a limit magnitude.
#[inline(always)]
fn limit_or_zero(x: f32) -> f32 {
    if x >= 0.0 {
        x
    } else {
        0.0
    }
}

/// A `(start, end)` window with `start <= end` (a start above the end is
/// lowered to it: derating starts earlier, never later); a NaN in either
/// makes both `-inf` (always past the end, even when the other said "off").
#[inline(always)]
fn ordered_window(start: f32, end: f32) -> (f32, f32) {
    if start.is_nan() || end.is_nan() {
        return (f32::NEG_INFINITY, f32::NEG_INFINITY);
    }
    (if start > end { end } else { start }, end)
}

impl PowerLimitsConfig {
    /// Defaults from the supervisor's thresholds and the motor:
    ///
    /// - regen window: `regen_end_v = 0.95 bus_over_voltage_v` (30 V ->
    ///   28.5 V, a margin for the bus rising within a speed-loop period and
    ///   the measurement's noise), `regen_start_v = regen_end_v - 0.10
    ///   bus_over_voltage_v` (25.5 V), not below `bus_under_voltage_v`.
    ///   Raise `regen_start_v` above a battery's full-charge voltage.
    /// - d-axis braking in the regen ramp: up to the current limit
    ///   (`regen_id_max_a = +inf`).
    /// - bus currents and powers: off (`+inf`): they depend on the supply,
    ///   which the board does not know (see each field for sizing).
    /// - winding model: `R_th = 2 K/W`, `tau = 60 s`, ambient 40 deg C,
    ///   derating 100 -> 120 deg C (class B insulation, 130 deg C, with a
    ///   margin for the model's error). The thermal figures are
    ///   placeholders for a small outrunner: measure yours (`R_th` = the
    ///   steady rise over the copper loss at a known current, `tau` = the
    ///   time to 63 % of it).
    /// - stage derating (with `stage_sensor`): from `max_temperature_c - 25`
    ///   to `max_temperature_c - 5` (65 -> 85 deg C at the default 90), so
    ///   the current is at 0 before the over-temperature fault; without a
    ///   sensor it is off.
    /// - brake chopper: off (see [`Self::with_brake_resistor`]); its guard
    ///   at 1 s on without a break.
    ///
    /// A non-finite over-voltage threshold gives no regen ramp (and no
    /// brake from [`Self::with_brake_resistor`]).
    pub fn for_board(
        supervisor: &SupervisorConfig,
        motor: MotorParams,
        stage_sensor: bool,
    ) -> Self {
        let ov = supervisor.bus_over_voltage_v;
        // No (finite) over-voltage threshold: no regen ramp either.
        let (regen_start_v, regen_end_v) = if ov.is_finite() && ov > 0.0 {
            let end = 0.95 * ov;
            let start = end - 0.10 * ov;
            if start < supervisor.bus_under_voltage_v {
                (supervisor.bus_under_voltage_v, end)
            } else {
                (start, end)
            }
        } else {
            (f32::INFINITY, f32::INFINITY)
        };
        let t_max = supervisor.max_temperature_c;
        let (stage_derate_start_c, stage_derate_end_c) = if stage_sensor {
            (t_max - 25.0, t_max - 5.0)
        } else {
            (f32::INFINITY, f32::INFINITY)
        };
        Self {
            motor,
            regen_start_v,
            regen_end_v,
            regen_id_max_a: f32::INFINITY,
            bus_current_motoring_max_a: f32::INFINITY,
            bus_current_regen_max_a: f32::INFINITY,
            power_motoring_max_w: f32::INFINITY,
            power_regen_max_w: f32::INFINITY,
            thermal_resistance_k_per_w: 2.0,
            thermal_time_constant_s: 60.0,
            ambient_c: 40.0,
            winding_derate_start_c: 100.0,
            winding_derate_end_c: 120.0,
            stage_derate_start_c,
            stage_derate_end_c,
            brake_on_v: f32::INFINITY,
            brake_off_v: f32::INFINITY,
            brake_max_on_s: 1.0,
        }
        .sanitized()
    }

    /// With a brake resistor: the chopper switches on at `regen_start_v`
    /// (before the regen limit cuts the braking torque) and off 3 % (at
    /// least 0.5 V) lower.
    pub fn with_brake_resistor(self) -> Self {
        let on = self.regen_start_v;
        // No finite, positive ramp start: no brake (never on blindly).
        if !(on.is_finite() && on > 0.0) {
            return self.sanitized();
        }
        let band = 0.03 * on;
        let band = if band > 0.5 { band } else { 0.5 };
        Self {
            brake_on_v: on,
            brake_off_v: on - band,
            ..self
        }
        .sanitized()
    }

    /// The safe reading of every field:
    ///
    /// - current and power limits: NaN or negative -> 0 (no current in that
    ///   direction); `+inf` stays (off). `regen_id_max_a` the same (0: no
    ///   d-axis braking).
    /// - regen and derating windows: a NaN start or end -> both `-inf` (the
    ///   window is always past its end: no regenerative current,
    ///   respectively no current at all, until the configuration is fixed,
    ///   even if the other threshold said "off"); a start above the end is
    ///   lowered to the end (a step at the end).
    /// - thermal model: a NaN, negative or zero `thermal_resistance_k_per_w`
    ///   and a NaN `ambient_c` -> the estimate is at [`THERMAL_MAX_C`]
    ///   from its next step on (derated to 0 when winding derating is on;
    ///   an `ambient_c` at or above it reads the same); a NaN
    ///   or negative time constant -> 0 (the estimate follows the loss at
    ///   once).
    /// - brake: a `brake_on_v` that is not finite and positive -> `+inf`
    ///   (never switches on: a resistor switched on blindly could burn);
    ///   `brake_off_v` NaN, not positive or above `brake_on_v` ->
    ///   `brake_on_v`; `brake_max_on_s` NaN or negative -> 0 (the chopper
    ///   locks out at once).
    ///
    /// The motor model is left as it is: [`iq_window`] answers
    /// [`ActiveLimit::InvalidModel`] (no current) while it is not finite or
    /// its resistance is negative.
    pub fn sanitized(self) -> Self {
        let (regen_start_v, regen_end_v) = ordered_window(self.regen_start_v, self.regen_end_v);
        let (winding_derate_start_c, winding_derate_end_c) =
            ordered_window(self.winding_derate_start_c, self.winding_derate_end_c);
        let (stage_derate_start_c, stage_derate_end_c) =
            ordered_window(self.stage_derate_start_c, self.stage_derate_end_c);
        let brake_on_v = if self.brake_on_v.is_finite() && self.brake_on_v > 0.0 {
            self.brake_on_v
        } else {
            f32::INFINITY
        };
        let brake_off_v = if self.brake_off_v > 0.0 && self.brake_off_v <= brake_on_v {
            self.brake_off_v
        } else {
            brake_on_v
        };
        let thermal_resistance_k_per_w = if self.thermal_resistance_k_per_w > 0.0 {
            self.thermal_resistance_k_per_w
        } else {
            f32::INFINITY
        };
        let ambient_c = if self.ambient_c.is_nan() {
            THERMAL_MAX_C
        } else {
            self.ambient_c
        };
        Self {
            motor: self.motor,
            regen_start_v,
            regen_end_v,
            regen_id_max_a: limit_or_zero(self.regen_id_max_a),
            bus_current_motoring_max_a: limit_or_zero(self.bus_current_motoring_max_a),
            bus_current_regen_max_a: limit_or_zero(self.bus_current_regen_max_a),
            power_motoring_max_w: limit_or_zero(self.power_motoring_max_w),
            power_regen_max_w: limit_or_zero(self.power_regen_max_w),
            thermal_resistance_k_per_w,
            thermal_time_constant_s: limit_or_zero(self.thermal_time_constant_s),
            ambient_c,
            winding_derate_start_c,
            winding_derate_end_c,
            stage_derate_start_c,
            stage_derate_end_c,
            brake_on_v,
            brake_off_v,
            brake_max_on_s: limit_or_zero(self.brake_max_on_s),
        }
    }

    /// Phase resistance at winding temperature `t_c` \[ohm\]:
    /// `R_20 (1 + 0.00393 (T - 20))`, never below 0; `t_c` is clamped to
    /// `[THERMAL_MIN_C, THERMAL_MAX_C]` (NaN reads as [`THERMAL_MAX_C`]).
    #[inline]
    pub fn r_at_ohm(&self, t_c: f32) -> f32 {
        let t = clamp_temperature(t_c);
        let r = self.motor.r_ohm * (1.0 + COPPER_TEMPCO_PER_K * (t - R_REFERENCE_C));
        if r > 0.0 {
            r
        } else {
            0.0
        }
    }

    /// The regen factor `s(V_bus)` in `[0, 1]`: 1 at or below
    /// `regen_start_v`, 0 at or above `regen_end_v`, linear between; 0 for
    /// a NaN voltage.
    #[inline]
    pub fn regen_factor(&self, v_bus_v: f32) -> f32 {
        ramp_down(v_bus_v, self.regen_start_v, self.regen_end_v)
    }

    /// The winding derating factor in `[0, 1]` at a winding temperature
    /// [deg C] (0 for NaN).
    #[inline]
    pub fn winding_factor(&self, t_c: f32) -> f32 {
        ramp_down(t_c, self.winding_derate_start_c, self.winding_derate_end_c)
    }

    /// The stage derating factor in `[0, 1]` at a stage temperature
    /// [deg C] (0 for NaN).
    #[inline]
    pub fn stage_factor(&self, t_c: f32) -> f32 {
        ramp_down(t_c, self.stage_derate_start_c, self.stage_derate_end_c)
    }

    /// Stage derating is configured (and so a stage sensor is needed).
    #[inline]
    pub fn stage_derating_on(&self) -> bool {
        self.stage_derate_end_c < f32::INFINITY
    }
}

/// 1 at or below `start`, 0 at or above `end`, linear between; 1
/// everywhere for `end = +inf` (off); 0 when `x`, `start` or `end` is NaN
/// (also unsanitized: NaN never switches a limit off). Expects
/// `start <= end` (sanitized); otherwise a step at `end`.
#[inline(always)]
pub fn ramp_down(x: f32, start: f32, end: f32) -> f32 {
    if x.is_nan() || start.is_nan() || end.is_nan() {
        return 0.0;
    }
    if end == f32::INFINITY {
        return 1.0;
    }
    if x >= end {
        return 0.0;
    }
    if x <= start {
        return 1.0;
    }
    // start < x < end < inf.
    let k = (end - x) / (end - start);
    if k >= 0.0 {
        if k <= 1.0 {
            k
        } else {
            1.0
        }
    } else {
        0.0
    }
}

#[inline(always)]
fn clamp_temperature(t_c: f32) -> f32 {
    if t_c < THERMAL_MIN_C {
        THERMAL_MIN_C
    } else if t_c <= THERMAL_MAX_C {
        t_c
    } else {
        THERMAL_MAX_C
    }
}
