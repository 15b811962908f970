//! The winding-temperature estimate: copper losses into a first-order
//! thermal model, the resistance following the temperature.

use super::*;

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
    pub(super) temperature_c: f32,
    pub(super) valid: bool,
    pub(super) invalid_steps: u32,
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

    /// Copper loss \[W\] at dq current `i_dq_a` and winding temperature
    /// `t_c`: `1.5 R(T) (i_d^2 + i_q^2)`.
    #[inline]
    pub fn copper_loss_w(cfg: &PowerLimitsConfig, i_dq_a: Dq, t_c: f32) -> f32 {
        1.5 * cfg.r_at_ohm(t_c) * (i_dq_a.d * i_dq_a.d + i_dq_a.q * i_dq_a.q)
    }

    /// Advance by `dt_s` \[s\] with the dq current `i_dq_a` \[A\] (measured);
    /// returns the new estimate [deg C].
    pub fn step(&mut self, cfg: &PowerLimitsConfig, i_dq_a: Dq, dt_s: f32) -> f32 {
        self.step_planned(cfg, &mut ThermalPlan::of(cfg), i_dq_a, dt_s)
    }

    /// [`Self::step`] with the configuration's plan (`plan` must be
    /// `ThermalPlan::of(cfg)`, possibly since used with other `dt_s`).
    #[inline(always)]
    pub(super) fn step_planned(
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

/// What [`ThermalEstimate::step`] decides from the configuration alone,
/// worked out once (design §20): whether the model is usable, and the
/// backward-Euler gain `h / (1 + h)`, `h = dt / tau`, for the last step
/// length (two divisions every period otherwise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct ThermalPlan {
    /// `R_th` finite and the ambient below [`THERMAL_MAX_C`] (sanitized:
    /// a NaN, zero or negative `R_th` is `+inf`, a NaN ambient the
    /// maximum).
    pub(super) model_ok: bool,
    /// The step length the gain is for \[s\] (NaN: none yet).
    pub(super) dt_s: f32,
    /// `h / (1 + h)` for `dt_s` (only used when `tau > 0`).
    pub(super) gain: f32,
}

impl ThermalPlan {
    pub(super) fn of(cfg: &PowerLimitsConfig) -> Self {
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
    pub(super) fn gain(&mut self, tau: f32, dt_s: f32) -> f32 {
        if dt_s != self.dt_s {
            let h = dt_s / tau;
            self.gain = h / (1.0 + h);
            self.dt_s = dt_s;
        }
        self.gain
    }
}
