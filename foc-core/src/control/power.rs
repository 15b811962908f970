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
//! `P = 1.5 (v_d i_d + v_q i_q)` [W]. In steady state (no `L di/dt`)
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
    /// Bus voltage [V] above which regenerative current is reduced
    /// (linearly, to 0 at [`Self::regen_end_v`]).
    pub regen_start_v: f32,
    /// Bus voltage [V] at and above which no regenerative current is
    /// allowed; below the supervisor's `bus_over_voltage_v`. `+inf`: off.
    pub regen_end_v: f32,
    /// d-axis braking [A] (magnitude): while the drive brakes (the
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
    /// Largest current drawn from the supply [A] (`P / V_bus`, averaged
    /// over a PWM period). Size: the supply's or battery's discharge limit
    /// (or its fuse). `+inf`: off.
    pub bus_current_motoring_max_a: f32,
    /// Largest current returned to the supply [A] (magnitude, `>= 0`).
    /// Size: what the supply can sink, a battery's (BMS) charge-current
    /// limit. A diode-fed bench supply sinks nothing, but the bus
    /// capacitor does: leave this off there and let the bus-voltage ramp
    /// ([`Self::regen_start_v`]) hold the bus; 0 forbids regenerative
    /// braking altogether (only copper-loss braking remains). `+inf`: off.
    pub bus_current_regen_max_a: f32,
    /// Largest power drawn from the supply [W]. `+inf`: off.
    pub power_motoring_max_w: f32,
    /// Largest power returned to the supply [W] (magnitude). `+inf`: off.
    pub power_regen_max_w: f32,
    /// Winding-to-ambient thermal resistance [K/W]: the steady temperature
    /// rise per watt of copper loss.
    pub thermal_resistance_k_per_w: f32,
    /// Winding thermal time constant [s] (63 % of a step's final rise).
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
    /// Bus voltage [V] at which the brake chopper switches on. `+inf`: no
    /// brake resistor.
    pub brake_on_v: f32,
    /// Bus voltage [V] at which the brake chopper switches off again
    /// (`<= brake_on_v`: the hysteresis). Above the supply's highest
    /// voltage, or the supply feeds the resistor (see
    /// [`Self::brake_max_on_s`]).
    pub brake_off_v: f32,
    /// Longest the chopper may conduct while the motor does not
    /// regenerate [s] (a leaky count: it runs down at a tenth of the rate
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

    /// Phase resistance at winding temperature `t_c` [ohm]:
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

/// Which limit set a bound of the q-current window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum ActiveLimit {
    /// No limit below the current limit.
    None = 0,
    /// The bus-voltage regen ramp ([`PowerLimitsConfig::regen_start_v`]).
    Regen = 1,
    /// [`PowerLimitsConfig::bus_current_motoring_max_a`].
    BusCurrentMotoring = 2,
    /// [`PowerLimitsConfig::bus_current_regen_max_a`].
    BusCurrentRegen = 3,
    /// [`PowerLimitsConfig::power_motoring_max_w`].
    PowerMotoring = 4,
    /// [`PowerLimitsConfig::power_regen_max_w`].
    PowerRegen = 5,
    /// Winding-temperature derating (the modelled temperature).
    WindingTemperature = 6,
    /// Power-stage temperature derating (the measured temperature).
    StageTemperature = 7,
    /// A needed input missing or not finite (the bus voltage, the speed,
    /// `i_d`, the current limit, a temperature): window `[0, 0]`.
    MissingSensor = 8,
    /// The motor model is not finite or its resistance negative: window
    /// `[0, 0]`.
    InvalidModel = 9,
}

/// The q-current window for this period.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IqWindow {
    /// Lowest allowed q-current [A] (`<= 0`).
    pub min_a: f32,
    /// Highest allowed q-current [A] (`>= 0`).
    pub max_a: f32,
    /// The limit that set `min_a` ([`ActiveLimit::None`]: the current limit).
    pub min_by: ActiveLimit,
    /// The limit that set `max_a`.
    pub max_by: ActiveLimit,
    /// The limit that cut the window the most (of `min_by` / `max_by`, by
    /// [`Self::factor`]); [`ActiveLimit::None`] when nothing cut.
    pub active: ActiveLimit,
    /// How much of the current limit is left at the more restricted end,
    /// in `[0, 1]`: `min(max_a, -min_a) / current_limit_a` (1 with a zero
    /// current limit; 0 for the safe window).
    pub factor: f32,
    /// The d-current reference [A]: [`PowerInputs::i_d_a`] plus the d-axis
    /// braking current (`<= 0`, see [`PowerLimitsConfig::regen_id_max_a`]).
    pub id_a: f32,
}

impl IqWindow {
    /// No current: the answer to a missing or invalid input.
    pub const fn zero(why: ActiveLimit) -> Self {
        Self {
            min_a: 0.0,
            max_a: 0.0,
            min_by: why,
            max_by: why,
            active: why,
            factor: 0.0,
            id_a: 0.0,
        }
    }

    /// `iq_a` clamped into the window; NaN gives 0.
    #[inline]
    pub fn clamp(&self, iq_a: f32) -> f32 {
        if iq_a < self.min_a {
            self.min_a
        } else if iq_a > self.max_a {
            self.max_a
        } else if iq_a.is_nan() {
            0.0
        } else {
            iq_a
        }
    }

    /// True when `iq_a` lies in the window.
    #[inline]
    pub fn contains(&self, iq_a: f32) -> bool {
        self.min_a <= iq_a && iq_a <= self.max_a
    }
}

/// What [`iq_window`] needs each period.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PowerInputs {
    /// Measured bus voltage [V] (`None`: the read failed).
    pub v_bus_v: Option<f32>,
    /// Electrical angular velocity [rad/s] (the tracker's speed times the
    /// pole pairs).
    pub omega_e_rad_s: f32,
    /// d-axis current [A] (the reference, or the measurement), without the
    /// d-axis braking this module adds.
    pub i_d_a: f32,
    /// The q-current the controller asks for before the window [A]: only
    /// its direction against the speed matters (braking or not, for the
    /// d-axis braking).
    pub iq_request_a: f32,
    /// The q-current limit before this module [A] (`Limits::max_current_a`
    /// or the stage's limit in force), finite and `>= 0`.
    pub current_limit_a: f32,
    /// Winding temperature [deg C] ([`ThermalEstimate::checked_temperature_c`]):
    /// needed (the power model's `R(T)` and the winding derating).
    pub winding_temperature_c: Option<f32>,
    /// Measured power-stage temperature [deg C]; `None` where the board
    /// has no sensor, allowed only with stage derating off.
    pub stage_temperature_c: Option<f32>,
}

/// The steady-state bus power [W] at q-current `iq_a` (the model of this
/// module: `1.5 R(T) (i_d^2 + i_q^2) + 1.5 w_e (psi + (L_d - L_q) i_d) i_q`);
/// `None` for the inputs [`iq_window`] refuses.
pub fn bus_power_w(cfg: &PowerLimitsConfig, inputs: &PowerInputs, iq_a: f32) -> Option<f32> {
    let (a, b, c) = coefficients(cfg, inputs, inputs.i_d_a)?;
    let p = (a * iq_a + b) * iq_a + c;
    if p.is_finite() {
        Some(p)
    } else {
        None
    }
}

/// `(a, b, c)` of `P(i_q) = a i_q^2 + b i_q + c` [W], `None` when an
/// input or the model is not valid.
fn coefficients(cfg: &PowerLimitsConfig, inp: &PowerInputs, i_d_a: f32) -> Option<(f32, f32, f32)> {
    let t = inp.winding_temperature_c?;
    let m = &cfg.motor;
    if !(all_finite([
        m.r_ohm,
        m.ld_h,
        m.lq_h,
        m.flux_linkage_wb,
        inp.omega_e_rad_s,
        i_d_a,
        t,
    ]) && m.r_ohm >= 0.0)
    {
        return None;
    }
    let r = cfg.r_at_ohm(t);
    let psi_eff = m.flux_linkage_wb + (m.ld_h - m.lq_h) * i_d_a;
    let a = 1.5 * r;
    let b = 1.5 * inp.omega_e_rad_s * psi_eff;
    let c = a * i_d_a * i_d_a;
    if all_finite([a, b, c]) {
        Some((a, b, c))
    } else {
        None
    }
}

/// The interval around 0 where `a x^2 + b x + q <= 0`, for `q <= 0`,
/// `a >= 0` (the roots on each side of 0, in the forms without
/// cancellation).
#[inline(always)]
fn below_roots(a: f32, b: f32, q: f32) -> (f32, f32) {
    let s = sqrtf(b * b - 4.0 * a * q); // >= |b|
                                        // Both roots 0 (a > 0, q = 0, b = 0), or no bound (a = 0).
    let flat = if q < 0.0 || a == 0.0 {
        f32::INFINITY
    } else {
        0.0
    };
    let hi = if b >= 0.0 {
        let d = b + s;
        if d > 0.0 {
            -2.0 * q / d
        } else {
            flat
        }
    } else {
        (s - b) / (2.0 * a)
    };
    let lo = if b <= 0.0 {
        let d = s - b;
        if d > 0.0 {
            2.0 * q / d
        } else {
            -flat
        }
    } else {
        -(b + s) / (2.0 * a)
    };
    (lo, hi)
}

/// The interval around 0 where `a x^2 + b x + q >= 0`, for `q >= 0`,
/// `a >= 0`: unbounded except on the side of the roots (`-b`'s sign),
/// bounded there by the root nearer 0.
#[inline(always)]
fn above_roots(a: f32, b: f32, q: f32) -> (f32, f32) {
    let disc = b * b - 4.0 * a * q;
    if disc <= 0.0 {
        return (f32::NEG_INFINITY, f32::INFINITY);
    }
    if disc.is_nan() {
        return (0.0, 0.0); // NaN: the safe interval
    }
    let s = sqrtf(disc); // <= |b|
    if b > 0.0 {
        (-2.0 * q / (b + s), f32::INFINITY)
    } else {
        // b < 0 (b = 0 gives disc <= 0)
        (f32::NEG_INFINITY, 2.0 * q / (s - b))
    }
}

/// One end of the window being narrowed.
#[derive(Clone, Copy)]
struct End {
    mag: f32,
    by: ActiveLimit,
}

impl End {
    #[inline(always)]
    fn cut(&mut self, mag: f32, by: ActiveLimit) {
        // A NaN bound cuts to 0 (never widens).
        if mag.is_nan() || mag < self.mag {
            self.mag = if mag > 0.0 { mag } else { 0.0 };
            self.by = by;
        }
    }
}

/// The q-current window for this period: the current limit, derated by
/// temperature, cut by the power and bus-current limits (exact roots of the
/// steady-state power balance, see the module docs), its regenerating end
/// scaled by the bus-voltage regen factor.
///
/// Always contains 0 for valid inputs (a limit never forces torque);
/// `[0, 0]` with [`ActiveLimit::MissingSensor`] when the bus voltage is
/// missing, non-finite or `<= 0`, when the speed, `i_d`, the current limit
/// or a needed temperature is missing or not finite (or the current limit
/// negative), and with [`ActiveLimit::InvalidModel`] for an invalid motor
/// model. Expects a [`sanitized`](PowerLimitsConfig::sanitized) `cfg`; an
/// unsanitized NaN limit still gives no current in its direction.
pub fn iq_window(cfg: &PowerLimitsConfig, inp: &PowerInputs) -> IqWindow {
    iq_window_planned(cfg, &WindowPlan::of(cfg), inp)
}

/// What [`iq_window`] decides from the configuration alone, worked out
/// once per configuration instead of every period (design §20).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WindowPlan {
    /// The motor model is finite with `R >= 0`.
    model_ok: bool,
    /// No bus-current or power limit is configured (each is `+inf`).
    no_bus_or_power_limit: bool,
}

impl WindowPlan {
    /// The plan of `cfg`.
    pub fn of(cfg: &PowerLimitsConfig) -> Self {
        let m = &cfg.motor;
        Self {
            model_ok: all_finite([m.r_ohm, m.ld_h, m.lq_h, m.flux_linkage_wb]) && m.r_ohm >= 0.0,
            no_bus_or_power_limit: cfg.bus_current_motoring_max_a == f32::INFINITY
                && cfg.bus_current_regen_max_a == f32::INFINITY
                && cfg.power_motoring_max_w == f32::INFINITY
                && cfg.power_regen_max_w == f32::INFINITY,
        }
    }
}

/// [`iq_window`] with the configuration's plan (`plan` must be
/// `WindowPlan::of(cfg)`).
#[inline(always)]
fn iq_window_planned(cfg: &PowerLimitsConfig, plan: &WindowPlan, inp: &PowerInputs) -> IqWindow {
    if !plan.model_ok {
        return IqWindow::zero(ActiveLimit::InvalidModel);
    }
    let missing = IqWindow::zero(ActiveLimit::MissingSensor);
    let v = match inp.v_bus_v {
        Some(v) if v > 0.0 && v < f32::INFINITY => v,
        _ => return missing,
    };
    let i_lim = inp.current_limit_a;
    if !(0.0..f32::INFINITY).contains(&i_lim) {
        return missing;
    }
    let k_stage = match inp.stage_temperature_c {
        Some(t) if t.is_finite() => cfg.stage_factor(t),
        None if !cfg.stage_derating_on() => 1.0,
        _ => return missing,
    };
    let Some(t_winding) = inp.winding_temperature_c else {
        return missing;
    };
    let k_winding = cfg.winding_factor(t_winding);

    // 1. Thermal derating of the current limit (both ends).
    let (k, k_by) = if k_stage < k_winding {
        (k_stage, ActiveLimit::StageTemperature)
    } else {
        (k_winding, ActiveLimit::WindingTemperature)
    };
    let s = cfg.regen_factor(v);
    // The common case, cheaply: no derating, the bus below the regen ramp,
    // no d-current and no bus-current or power limit configured: the
    // window is the current limit (what the full computation gives then).
    if k >= 1.0
        && s >= 1.0
        && inp.i_d_a == 0.0
        && inp.omega_e_rad_s.is_finite()
        && t_winding.is_finite()
        && plan.no_bus_or_power_limit
    {
        return IqWindow {
            min_a: 0.0 - i_lim,
            max_a: i_lim,
            min_by: ActiveLimit::None,
            max_by: ActiveLimit::None,
            active: ActiveLimit::None,
            factor: 1.0,
            id_a: 0.0,
        };
    }
    // The d-axis braking current (bus in the regen ramp, braking asked).
    let id_brake = braking_id_a(cfg, s, inp, k * i_lim, cfg.r_at_ohm(t_winding));
    let i_d = inp.i_d_a + id_brake;
    let Some((a, b, c)) = coefficients(cfg, inp, i_d) else {
        return missing;
    };
    let mut lo = End {
        mag: i_lim,
        by: ActiveLimit::None,
    };
    let mut hi = lo;
    lo.cut(k * i_lim, k_by);
    hi.cut(k * i_lim, k_by);
    // The current vector within the (derated) limit: |i_q| <= sqrt(I^2 - i_d^2).
    if i_d != 0.0 {
        let kk = k * i_lim;
        let room = kk * kk - i_d * i_d;
        let q = if room > 0.0 { sqrtf(room) } else { 0.0 };
        let by = if id_brake != 0.0 {
            ActiveLimit::Regen
        } else {
            k_by
        };
        lo.cut(q, by);
        hi.cut(q, by);
    }

    // 2. Motoring: P(iq) <= P_mot (NaN limits read as 0).
    let p_bus_mot = v * cfg.bus_current_motoring_max_a;
    let p_cfg = limit_or_zero(cfg.power_motoring_max_w);
    let p_bus_mot = limit_or_zero(p_bus_mot);
    let (p_mot, mot_by) = if p_cfg <= p_bus_mot {
        (p_cfg, ActiveLimit::PowerMotoring)
    } else {
        (p_bus_mot, ActiveLimit::BusCurrentMotoring)
    };
    if p_mot < f32::INFINITY {
        // The loss of i_d alone is not this module's to limit: 0 stays in.
        let q = if c > p_mot { 0.0 } else { c - p_mot };
        let (x_lo, x_hi) = below_roots(a, b, q);
        lo.cut(-x_lo, mot_by);
        hi.cut(x_hi, mot_by);
    }

    // 3. Regeneration: P(iq) >= -P_regen.
    let p_bus_regen = v * cfg.bus_current_regen_max_a;
    let p_cfg = limit_or_zero(cfg.power_regen_max_w);
    let p_bus_regen = limit_or_zero(p_bus_regen);
    let (p_regen, regen_by) = if p_cfg <= p_bus_regen {
        (p_cfg, ActiveLimit::PowerRegen)
    } else {
        (p_bus_regen, ActiveLimit::BusCurrentRegen)
    };
    if p_regen < f32::INFINITY {
        let (x_lo, x_hi) = above_roots(a, b, c + p_regen);
        lo.cut(-x_lo, regen_by);
        hi.cut(x_hi, regen_by);
    }

    // 4. The bus-voltage regen ramp on the regenerating end (i_q b < 0),
    // never below the current of zero net power (the copper loss of the
    // d-current pays for that much braking).
    if s < 1.0 {
        let keep = zero_power_q_a(a, b, c);
        if b > 0.0 {
            let m = lo.mag;
            lo.cut(max_of(s * m, min_of(keep, m)), ActiveLimit::Regen);
        } else if b < 0.0 {
            let m = hi.mag;
            hi.cut(max_of(s * m, min_of(keep, m)), ActiveLimit::Regen);
        }
    }

    if !(lo.mag >= 0.0 && hi.mag >= 0.0) {
        return missing; // unreachable for finite inputs; NaN-safe anyway
    }
    let (factor, active) = if i_lim > 0.0 {
        let (tight, by) = if lo.mag < hi.mag {
            (lo.mag, lo.by)
        } else {
            (hi.mag, hi.by)
        };
        let f = tight / i_lim;
        if f >= 1.0 {
            (1.0, ActiveLimit::None)
        } else {
            (f, by)
        }
    } else {
        (1.0, ActiveLimit::None)
    };
    IqWindow {
        min_a: 0.0 - lo.mag, // +0.0, not -0.0, for an empty end
        max_a: hi.mag,
        min_by: lo.by,
        max_by: hi.by,
        active,
        factor,
        id_a: i_d,
    }
}

/// The d-axis braking current [A] (`<= 0`): `-(1 - s) min(regen_id_max_a,
/// limit)` while `s < 1` and the requested q-current regenerates (it
/// opposes the speed, and the back-EMF's power exceeds the copper loss of
/// the q-current the ramp admits, `|w_e psi| > R min(|i_q|, s I)`; below
/// that speed braking already draws from the bus), else 0 (also for any
/// non-finite input).
#[inline(always)]
fn braking_id_a(
    cfg: &PowerLimitsConfig,
    s: f32,
    inp: &PowerInputs,
    limit_a: f32,
    r_ohm: f32,
) -> f32 {
    let iq = inp.iq_request_a;
    let w = inp.omega_e_rad_s;
    let emf = w * cfg.motor.flux_linkage_wb;
    // Against the q-current the ramp admits (`s` of the limit), not the
    // request alone: near `s = 0` any braking request qualifies, so the
    // d-current does not switch on and off with the speed there.
    let iq_mag = if iq < 0.0 { -iq } else { iq };
    let admitted = min_of(iq_mag, s * limit_a);
    let braking = iq * w < 0.0 && emf * emf > (r_ohm * admitted) * (r_ohm * admitted);
    if !(s < 1.0 && braking && cfg.regen_id_max_a > 0.0) {
        return 0.0;
    }
    let cap = min_of(cfg.regen_id_max_a, limit_a);
    let id = -(1.0 - s) * cap;
    if id <= 0.0 && id > f32::NEG_INFINITY {
        id
    } else {
        0.0
    }
}

/// The regenerating q-current magnitude up to which `P >= 0` (the smaller
/// root of `a m^2 - |b| m + c = 0`, `m` along the regenerating direction):
/// 0 without a d-current (`c = 0`). When `P > 0` everywhere on that side
/// (`b^2 < 4 a c`) the vertex `|b| / (2 a)`, where that root ends up as
/// `b^2` falls to `4 a c`: continuous in the speed and the d-current (a
/// jump from the vertex to the whole range would make the window, and the
/// current reference, flip between the two).
#[inline(always)]
fn zero_power_q_a(a: f32, b: f32, c: f32) -> f32 {
    // `c` is `>= 0` (a square); 0 (or NaN): no d-current to pay for any.
    if c.is_nan() || c <= 0.0 {
        return 0.0;
    }
    let bb = if b < 0.0 { -b } else { b };
    let disc = bb * bb - 4.0 * a * c;
    if disc < 0.0 {
        // a > 0 here (a = 0 gives disc = b^2 >= 0).
        return bb / (2.0 * a);
    }
    let d = bb + sqrtf(disc);
    if d > 0.0 {
        2.0 * c / d
    } else {
        0.0
    }
}

#[inline(always)]
fn min_of(x: f32, y: f32) -> f32 {
    if x < y {
        x
    } else {
        y
    }
}

#[inline(always)]
fn max_of(x: f32, y: f32) -> f32 {
    if x > y {
        x
    } else {
        y
    }
}

/// The winding temperature model (state; the parameters are in
/// [`PowerLimitsConfig`]): `tau dT/dt = T_amb + R_th P_cu - T` with the
/// copper loss `P_cu = 1.5 R(T) (i_d^2 + i_q^2)`, a backward-Euler step in
/// the decay (stable for any `dt`, the loss taken at the old temperature),
/// saturated to `[THERMAL_MIN_C, THERMAL_MAX_C]`.
///
/// A non-finite current or `dt` (or a negative `dt`) keeps the old estimate
/// and marks it invalid for that step: [`Self::is_valid`] is false and
/// [`Self::checked_temperature_c`] is `None` (so [`iq_window`] gives no
/// current) until the next valid step; [`Self::invalid_steps`] counts them.
/// (A NaN current means the current read failed: the supervisor has the
/// bridge off then, so no heating is missed.)
///
/// ```
/// use foc_core::control::power::{PowerLimitsConfig, ThermalEstimate};
/// use foc_core::control::{supervisor::SupervisorConfig, MotorParams};
/// use foc_core::frames::Dq;
/// let motor = MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 40e-6, lq_h: 40e-6, flux_linkage_wb: 0.004 };
/// let cfg = PowerLimitsConfig::for_board(&SupervisorConfig::default(), motor, false);
/// let mut t = ThermalEstimate::at_ambient(&cfg);
/// for _ in 0..1000 {
///     t.step(&cfg, Dq::new(0.0, 10.0), 0.01);
/// }
/// assert!(t.temperature_c() > cfg.ambient_c);
/// t.step(&cfg, Dq::new(0.0, f32::NAN), 0.01);
/// assert_eq!(t.checked_temperature_c(), None);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ThermalEstimate {
    temperature_c: f32,
    valid: bool,
    invalid_steps: u32,
}

impl ThermalEstimate {
    /// Starting at `temperature_c` [deg C] (clamped; NaN starts hot, at
    /// [`THERMAL_MAX_C`]).
    pub const fn new(temperature_c: f32) -> Self {
        let t = if temperature_c.is_nan() || temperature_c > THERMAL_MAX_C {
            THERMAL_MAX_C
        } else if temperature_c < THERMAL_MIN_C {
            THERMAL_MIN_C
        } else {
            temperature_c
        };
        Self {
            temperature_c: t,
            valid: true,
            invalid_steps: 0,
        }
    }

    /// Starting at the configured ambient.
    pub const fn at_ambient(cfg: &PowerLimitsConfig) -> Self {
        Self::new(cfg.ambient_c)
    }

    /// Back to the ambient (e.g. after a long power-off), valid.
    pub fn reset(&mut self, cfg: &PowerLimitsConfig) {
        *self = Self::at_ambient(cfg);
    }

    /// Copper loss [W] at dq current `i_dq_a` and winding temperature
    /// `t_c`: `1.5 R(T) (i_d^2 + i_q^2)`.
    #[inline]
    pub fn copper_loss_w(cfg: &PowerLimitsConfig, i_dq_a: Dq, t_c: f32) -> f32 {
        1.5 * cfg.r_at_ohm(t_c) * (i_dq_a.d * i_dq_a.d + i_dq_a.q * i_dq_a.q)
    }

    /// Advance by `dt_s` [s] with the dq current `i_dq_a` [A] (measured);
    /// returns the new estimate [deg C].
    pub fn step(&mut self, cfg: &PowerLimitsConfig, i_dq_a: Dq, dt_s: f32) -> f32 {
        self.step_planned(cfg, &mut ThermalPlan::of(cfg), i_dq_a, dt_s)
    }

    /// [`Self::step`] with the configuration's plan (`plan` must be
    /// `ThermalPlan::of(cfg)`, possibly since used with other `dt_s`).
    #[inline(always)]
    fn step_planned(
        &mut self,
        cfg: &PowerLimitsConfig,
        plan: &mut ThermalPlan,
        i_dq_a: Dq,
        dt_s: f32,
    ) -> f32 {
        if !(all_finite([i_dq_a.d, i_dq_a.q, dt_s]) && dt_s >= 0.0) {
            self.valid = false;
            self.invalid_steps = self.invalid_steps.saturating_add(1);
            return self.temperature_c;
        }
        self.valid = true;
        // A model the configuration left invalid (sanitized: a NaN, zero
        // or negative `R_th` is +inf, a NaN ambient is THERMAL_MAX_C) reads
        // hot at once, not one time constant later: a drive reconfigured
        // with it keeps its estimate and would otherwise run at the full
        // current for seconds (tau ln(...) ~ 11 s at the default 60 s).
        if !plan.model_ok {
            self.temperature_c = THERMAL_MAX_C;
            return self.temperature_c;
        }
        let t = self.temperature_c;
        let loss = Self::copper_loss_w(cfg, i_dq_a, t);
        // NaN (inf * 0, a bad model) reads as the hot end.
        let target = clamp_temperature(cfg.ambient_c + cfg.thermal_resistance_k_per_w * loss);
        let tau = cfg.thermal_time_constant_s;
        let next = if tau > 0.0 {
            // Backward Euler, T + (target - T) h / (1 + h): exactly
            // still at the target.
            t + (target - t) * plan.gain(tau, dt_s)
        } else if tau.is_nan() || tau < 0.0 || dt_s > 0.0 {
            target
        } else {
            t
        };
        self.temperature_c = clamp_temperature(next);
        self.temperature_c
    }

    /// The estimate [deg C] (the last valid one).
    pub const fn temperature_c(&self) -> f32 {
        self.temperature_c
    }

    /// The estimate, `None` after a step with an invalid input.
    pub const fn checked_temperature_c(&self) -> Option<f32> {
        if self.valid {
            Some(self.temperature_c)
        } else {
            None
        }
    }

    /// False after a step with a non-finite input, until the next valid step.
    pub const fn is_valid(&self) -> bool {
        self.valid
    }

    /// Steps refused so far (saturating).
    pub const fn invalid_steps(&self) -> u32 {
        self.invalid_steps
    }
}

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
    on: bool,
    /// Leaky count of the time on while the motor did not regenerate [s].
    on_s: f32,
    /// Locked out by the guard until the bus falls below `brake_off_v`.
    locked: bool,
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

    /// One bus reading [V] after `dt_s`, and whether the motor
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

/// What the current stage publishes of its power limits each period
/// ([`crate::control::Feedback::power`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PowerReport {
    /// Lowest q-current allowed this period [A] (the current limit's
    /// `-max_current_a` when no power limits are configured).
    pub iq_min_a: f32,
    /// Highest q-current allowed this period [A].
    pub iq_max_a: f32,
    /// The d-current reference of this period [A] (`<= 0`: d-axis braking
    /// while the bus is in the regen ramp; 0 otherwise).
    pub id_ref_a: f32,
    /// The limit that cut the window the most.
    pub active: ActiveLimit,
    /// Fraction of the current limit left at the more restricted end (1:
    /// nothing cut).
    pub factor: f32,
    /// Estimated winding temperature [deg C] (NaN without power limits).
    pub winding_c: f32,
    /// Measured power-stage temperature [deg C] (NaN: the board has no
    /// sensor, the reading failed, or no power limits are configured).
    pub stage_c: f32,
    /// The brake chopper conducts (a board with a brake resistor switches
    /// it; the bench drives the plant's).
    pub brake_on: bool,
    /// The chopper's guard has locked it out
    /// ([`PowerLimitsConfig::brake_max_on_s`]).
    pub brake_locked: bool,
}

impl PowerReport {
    /// Before the first period.
    pub const INIT: Self = Self::unlimited(0.0);

    /// No power limits: the window of the current limit `limit_a`.
    pub const fn unlimited(limit_a: f32) -> Self {
        Self {
            iq_min_a: -limit_a,
            iq_max_a: limit_a,
            id_ref_a: 0.0,
            active: ActiveLimit::None,
            factor: 1.0,
            winding_c: f32::NAN,
            stage_c: f32::NAN,
            brake_on: false,
            brake_locked: false,
        }
    }

    /// `iq_a` within the window (NaN gives 0).
    pub fn clamp(&self, iq_a: f32) -> f32 {
        if iq_a < self.iq_min_a {
            self.iq_min_a
        } else if iq_a > self.iq_max_a {
            self.iq_max_a
        } else if iq_a.is_nan() {
            0.0
        } else {
            iq_a
        }
    }
}

/// What [`ThermalEstimate::step`] decides from the configuration alone,
/// worked out once (design §20): whether the model is usable, and the
/// backward-Euler gain `h / (1 + h)`, `h = dt / tau`, for the last step
/// length (two divisions every period otherwise).
#[derive(Clone, Copy, Debug, PartialEq)]
struct ThermalPlan {
    /// `R_th` finite and the ambient below [`THERMAL_MAX_C`] (sanitized:
    /// a NaN, zero or negative `R_th` is `+inf`, a NaN ambient the
    /// maximum).
    model_ok: bool,
    /// The step length the gain is for [s] (NaN: none yet).
    dt_s: f32,
    /// `h / (1 + h)` for `dt_s` (only used when `tau > 0`).
    gain: f32,
}

impl ThermalPlan {
    fn of(cfg: &PowerLimitsConfig) -> Self {
        Self {
            model_ok: cfg.thermal_resistance_k_per_w < f32::INFINITY
                && cfg.ambient_c < THERMAL_MAX_C,
            dt_s: f32::NAN,
            gain: f32::NAN,
        }
    }

    /// `h / (1 + h)` with `h = dt_s / tau` (`tau > 0`, the configuration's,
    /// which the plan is remade with), computed again only when `dt_s`
    /// changes: the same bits as computing it every step.
    #[inline(always)]
    fn gain(&mut self, tau: f32, dt_s: f32) -> f32 {
        if dt_s != self.dt_s {
            let h = dt_s / tau;
            self.gain = h / (1.0 + h);
            self.dt_s = dt_s;
        }
        self.gain
    }
}

/// The current stage's power limits: the configuration, the winding
/// temperature estimate and the brake chopper, stepped once per period.
#[derive(Clone, Copy, Debug)]
pub struct PowerStage {
    cfg: PowerLimitsConfig,
    thermal: ThermalEstimate,
    chopper: BrakeChopper,
    /// The bus voltage the regen ramp (and its d-axis braking) follows,
    /// filtered [V] (NaN: none yet).
    v_ramp_v: f32,
    /// `WindowPlan::of(&cfg)`, kept with `cfg`.
    plan: WindowPlan,
    /// `ThermalPlan::of(&cfg)`, kept with `cfg`.
    thermal_plan: ThermalPlan,
}

impl PowerStage {
    /// From `cfg` (sanitized here); the winding starts at the ambient
    /// temperature.
    pub fn new(cfg: PowerLimitsConfig) -> Self {
        let cfg = cfg.sanitized();
        Self {
            cfg,
            thermal: ThermalEstimate::new(cfg.ambient_c),
            chopper: BrakeChopper::new(),
            v_ramp_v: f32::NAN,
            plan: WindowPlan::of(&cfg),
            thermal_plan: ThermalPlan::of(&cfg),
        }
    }

    /// The configuration in force (sanitized).
    pub fn config(&self) -> &PowerLimitsConfig {
        &self.cfg
    }

    /// Follow a new motor model (after an identification or a gains
    /// change): the power model's resistance, inductances and flux linkage.
    pub fn set_motor(&mut self, motor: MotorParams) {
        self.cfg.motor = motor;
        self.plan = WindowPlan::of(&self.cfg);
    }

    /// A new configuration that keeps this stage's winding estimate (a
    /// reconfiguration must not cool the modelled winding down to the
    /// ambient temperature) and its chopper guard (count and lock-out);
    /// the chopper itself restarts off, with the new thresholds.
    pub fn reconfigured(&self, cfg: PowerLimitsConfig) -> Self {
        let mut chopper = self.chopper;
        chopper.on = false;
        let cfg = cfg.sanitized();
        Self {
            cfg,
            thermal: self.thermal,
            chopper,
            v_ramp_v: self.v_ramp_v,
            plan: WindowPlan::of(&cfg),
            thermal_plan: ThermalPlan::of(&cfg),
        }
    }

    /// The chopper alone (periods where the current stage does not run,
    /// e.g. the start-up calibrations, bridge off: nothing regenerates
    /// through the drive): returns whether it is on.
    pub fn step_chopper(&mut self, v_bus_v: Option<f32>, dt_s: f32) -> bool {
        self.chopper.step(&self.cfg, v_bus_v, dt_s, false)
    }

    /// The chopper's guard has locked it out.
    pub fn brake_locked_out(&self) -> bool {
        self.chopper.is_locked_out()
    }

    /// One period: the winding estimate from the measured currents over
    /// `dt_s`, the chopper from the bus voltage (and whether the motor
    /// regenerated: `1.5 (v_d i_d + v_q i_q) < 0` with the voltage applied
    /// with those currents, `v_dq_applied_v`), and the q-current window
    /// (with the d-axis braking current) for `inputs`, whose winding
    /// temperature is replaced by the estimate's.
    pub fn step(
        &mut self,
        i_dq_measured_a: Dq,
        v_dq_applied_v: Dq,
        dt_s: f32,
        inputs: PowerInputs,
    ) -> PowerReport {
        let mut report = PowerReport::unlimited(0.0);
        self.step_into(i_dq_measured_a, v_dq_applied_v, dt_s, inputs, &mut report);
        report
    }

    /// [`Self::step`] with the report written into `report` (the current
    /// stage's own copy, not returned by value: design §20).
    pub fn step_into(
        &mut self,
        i_dq_measured_a: Dq,
        v_dq_applied_v: Dq,
        dt_s: f32,
        inputs: PowerInputs,
        report: &mut PowerReport,
    ) {
        self.thermal
            .step_planned(&self.cfg, &mut self.thermal_plan, i_dq_measured_a, dt_s);
        let p = v_dq_applied_v.d * i_dq_measured_a.d + v_dq_applied_v.q * i_dq_measured_a.q;
        let brake_on = self.chopper.step(&self.cfg, inputs.v_bus_v, dt_s, p < 0.0);
        // The ramp follows a rising bus at once and a falling one through a
        // first-order filter of four periods (design §19): the d-axis
        // braking current the ramp sets moves the bus itself within a
        // period, and on the raw reading the two chattered from one period
        // to the next on a large inductance (M153: 6 <-> 44 A, the q
        // current lost, a current-sense fault). Held high, the ramp only
        // errs on the safe side. A missing or non-finite reading passes
        // through (the window is then [0, 0]).
        let v = match inputs.v_bus_v {
            Some(v) if v.is_finite() && self.v_ramp_v.is_finite() && v < self.v_ramp_v => {
                self.v_ramp_v + 0.25 * (v - self.v_ramp_v)
            }
            other => other.unwrap_or(f32::NAN),
        };
        self.v_ramp_v = v;
        let w = iq_window_planned(
            &self.cfg,
            &self.plan,
            &PowerInputs {
                v_bus_v: inputs.v_bus_v.map(|_| v),
                winding_temperature_c: self.thermal.checked_temperature_c(),
                ..inputs
            },
        );
        *report = PowerReport {
            iq_min_a: w.min_a,
            iq_max_a: w.max_a,
            id_ref_a: w.id_a,
            active: w.active,
            factor: w.factor,
            winding_c: self.thermal.temperature_c(),
            stage_c: inputs.stage_temperature_c.unwrap_or(f32::NAN),
            brake_on,
            brake_locked: self.chopper.is_locked_out(),
        };
    }
}
