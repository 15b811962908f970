//! The power window: the power and regen limits' q-current window, the
//! brake chopper, and the window the stage publishes.

use super::*;

impl CurrentStage {
    /// Configure (or switch off, `None`) the power limits (design §18).
    /// Their motor model is the current loop's (`cfg.motor` is replaced).
    /// A stage that already had power limits keeps its winding estimate
    /// (reconfiguring does not cool the winding); the first configuration
    /// starts it at the ambient temperature.
    pub fn set_power_limits(&mut self, cfg: Option<PowerLimitsConfig>) {
        let motor = self.config.current.motor;
        let cfg = cfg.map(|c| PowerLimitsConfig { motor, ..c });
        self.config.power = cfg;
        self.power = match (cfg, self.power.as_ref()) {
            (Some(c), Some(old)) => Some(old.reconfigured(c)),
            (Some(c), None) => Some(PowerLimiter::new(c)),
            (None, _) => None,
        };
    }

    /// Step the brake chopper alone, for a period in which [`Self::step`]
    /// does not run (the drive's start-up calibrations, bridge off);
    /// nothing without power limits.
    pub fn step_brake(&mut self, v_bus_v: Option<f32>) {
        if let Some(p) = self.power.as_mut() {
            self.power_report.brake_on = p.step_chopper(v_bus_v, self.config.current.ts_s);
            self.power_report.brake_locked = p.brake_locked_out();
        }
    }

    /// The power limits' brake chopper conducts (false without power
    /// limits).
    #[inline]
    pub fn brake_on(&self) -> bool {
        self.power.is_some() && self.power_report.brake_on
    }

    /// The power limits' report of the last period (the current limit's
    /// window without power limits).
    pub fn power_report(&self) -> PowerReport {
        if self.power.is_some() {
            self.power_report
        } else {
            PowerReport::unlimited(self.config.limits.max_current_a)
        }
    }

    /// The power limits' q-current window of this period, when they are
    /// configured (true): steps the winding estimate (from the last
    /// measured currents) and the brake chopper, the report written into
    /// `power_report`. Without them nothing is computed (false; the
    /// published report is the current limit's window).
    #[inline(always)]
    pub(super) fn power_window(&mut self, sensed: &Sensed, w_e: f32, i_request_a: Dq) -> bool {
        let Some(p) = self.power.as_mut() else {
            return false;
        };
        p.step_into(
            self.state.last_i_dq,
            self.state.last_out_v_dq,
            self.config.current.ts_s,
            PowerInputs {
                v_bus_v: sensed.v_bus_read_v,
                omega_e_rad_s: w_e,
                i_d_a: i_request_a.d,
                iq_request_a: i_request_a.q,
                current_limit_a: self.config.limits.max_current_a,
                winding_temperature_c: None,
                stage_temperature_c: sensed.temperature_c,
            },
            &mut self.power_report,
        );
        true
    }
}

impl CurrentStage {
    /// The power report published: the power limits' (or the current
    /// limit's) window, narrowed by the travel limits' soft stop.
    #[inline(always)]
    pub(super) fn published_window(&self) -> PowerReport {
        let mut r = if self.power.is_some() {
            self.power_report
        } else {
            PowerReport::unlimited(self.config.limits.max_current_a)
        };
        if let Some((lo, hi)) = self.state.travel_window_a {
            if lo > r.iq_min_a {
                r.iq_min_a = lo;
            }
            if hi < r.iq_max_a {
                r.iq_max_a = hi;
            }
        }
        r
    }
}
