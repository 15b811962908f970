//! [`PowerLimiter`]: the power limits as the current stage runs them each
//! period (window, thermal estimate, chopper) and what it reports.

use super::*;

/// What the current stage publishes of its power limits each period
/// ([`crate::control::Feedback::power`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PowerReport {
    /// Lowest q-current allowed this period \[A\] (the current limit's
    /// `-max_current_a` when no power limits are configured).
    pub iq_min_a: f32,
    /// Highest q-current allowed this period \[A\].
    pub iq_max_a: f32,
    /// The d-current reference of this period \[A\] (`<= 0`: d-axis braking
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

/// The current stage's power limits: the configuration, the winding
/// temperature estimate and the brake chopper, stepped once per period.
#[derive(Clone, Copy, Debug)]
pub struct PowerLimiter {
    pub(super) cfg: PowerLimitsConfig,
    pub(super) thermal: ThermalEstimate,
    pub(super) chopper: BrakeChopper,
    /// The bus voltage the regen ramp (and its d-axis braking) follows,
    /// filtered \[V\] (NaN: none yet).
    pub(super) v_ramp_v: f32,
    /// `WindowPlan::of(&cfg)`, kept with `cfg`.
    pub(super) plan: WindowPlan,
    /// `ThermalPlan::of(&cfg)`, kept with `cfg`.
    pub(super) thermal_plan: ThermalPlan,
}

impl PowerLimiter {
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
