//! The speed loop (design §10, middle loop): PI on the mechanical
//! speed estimate, producing the q-current reference within a current limit.
//!
//! ```text
//! e = w_ref - w_est                       [rad/s, mechanical]
//! iq_ref = clamp(PI(e) + iq_ff, -I_max, I_max)   anti-windup: PI limits
//! ```
//!
//! Gains can be derived from the motor's torque constant and inertia with
//! [`SpeedLoopConfig::from_bandwidth`].
//!
//! ```
//! use foc_core::control::speed::{SpeedLoop, SpeedLoopConfig};
//! let mut s = SpeedLoop::new(SpeedLoopConfig::from_bandwidth(1e-5, 0.05, 100.0, 1e-3, 5.0));
//! let iq = s.step(10.0, 0.0, 0.0); // below the target: positive torque
//! assert!(iq > 0.0 && iq <= 5.0);
//! ```

use crate::clamp;
use crate::pi::{AntiWindup, Pi, PiConfig};

/// Speed-loop configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SpeedLoopConfig {
    /// Loop period [s] (PWM period times the speed divider).
    pub ts_s: f32,
    /// Proportional gain [A / (rad/s)].
    pub kp_a_per_rad_s: f32,
    /// Integral gain [A / rad].
    pub ki_a_per_rad: f32,
    /// q-current limit [A] (symmetric).
    pub current_limit_a: f32,
    /// Anti-windup strategy.
    pub anti_windup: AntiWindup,
}

impl SpeedLoopConfig {
    /// PI gains for a speed bandwidth `wc` on a rigid inertia `J` with
    /// torque constant `kt = 1.5 p psi` [N m / A]: `Kp = J wc / kt`,
    /// `Ki = Kp wc / 4` (PI zero a quarter of the bandwidth, about 60 deg
    /// phase margin ignoring the current loop).
    pub fn from_bandwidth(
        inertia_kg_m2: f32,
        torque_constant_nm_per_a: f32,
        bandwidth_rad_s: f32,
        ts_s: f32,
        current_limit_a: f32,
    ) -> Self {
        let kp = inertia_kg_m2 * bandwidth_rad_s / torque_constant_nm_per_a;
        Self {
            ts_s,
            kp_a_per_rad_s: kp,
            ki_a_per_rad: kp * bandwidth_rad_s * 0.25,
            current_limit_a,
            anti_windup: AntiWindup::BackCalculation {
                kb_per_s: bandwidth_rad_s * 0.25,
            },
        }
    }
}

/// The speed loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeedLoop {
    config: SpeedLoopConfig,
    pi: Pi,
}

impl SpeedLoop {
    fn pi_config(c: &SpeedLoopConfig) -> PiConfig {
        let lim = if c.current_limit_a.is_finite() {
            c.current_limit_a.abs()
        } else {
            0.0
        };
        PiConfig {
            kp: c.kp_a_per_rad_s,
            ki_per_s: c.ki_a_per_rad,
            ts_s: c.ts_s,
            out_min: -lim,
            out_max: lim,
            anti_windup: c.anti_windup,
        }
    }

    /// New loop with zero state.
    pub fn new(config: SpeedLoopConfig) -> Self {
        Self {
            pi: Pi::new(Self::pi_config(&config)),
            config,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &SpeedLoopConfig {
        &self.config
    }

    /// Replace the configuration, keeping the integrator.
    pub fn set_config(&mut self, config: SpeedLoopConfig) {
        self.pi.config = Self::pi_config(&config);
        self.config = config;
    }

    /// Zero the integrator.
    pub fn reset(&mut self) {
        self.pi.reset();
    }

    /// Bumpless entry: the next step with zero error outputs `iq_a`.
    pub fn preload(&mut self, iq_a: f32) {
        self.pi.preload(iq_a);
    }

    /// One step: speed reference and estimate [rad/s, mechanical], torque
    /// feed-forward as a q current [A]. Returns the q-current reference [A]
    /// within the current limit; non-finite inputs give the last integrator
    /// value (state unchanged).
    pub fn step(&mut self, w_ref_rad_s: f32, w_est_rad_s: f32, iq_ff_a: f32) -> f32 {
        self.step_within(w_ref_rad_s, w_est_rad_s, iq_ff_a, f32::INFINITY)
    }

    /// As [`Self::step`] with the output held within `limit_a` [A] as well
    /// as the configured limit (the smaller wins; the integrator's
    /// anti-windup works against it). A NaN `limit_a` is ignored.
    pub fn step_within(
        &mut self,
        w_ref_rad_s: f32,
        w_est_rad_s: f32,
        iq_ff_a: f32,
        limit_a: f32,
    ) -> f32 {
        self.step_in(w_ref_rad_s, w_est_rad_s, iq_ff_a, -limit_a, limit_a)
    }

    /// As [`Self::step`] with the output held within `[min_a, max_a]` [A]
    /// (an asymmetric window: the power limits of design §18 may cut
    /// regeneration and not motoring) as well as the configured limit;
    /// the integrator's anti-windup works against it. `min_a` above 0,
    /// `max_a` below 0 or NaN are ignored (the configured limit applies).
    pub fn step_in(
        &mut self,
        w_ref_rad_s: f32,
        w_est_rad_s: f32,
        iq_ff_a: f32,
        min_a: f32,
        max_a: f32,
    ) -> f32 {
        let cfg = self.pi.config.out_max;
        let hi = if max_a >= 0.0 && max_a < cfg {
            max_a
        } else {
            cfg
        };
        let lo = if min_a <= 0.0 && min_a > -cfg {
            min_a
        } else {
            -cfg
        };
        let ff = if iq_ff_a.is_finite() {
            clamp(iq_ff_a, lo, hi)
        } else {
            0.0
        };
        // Feed-forward shifts the PI's limits so the total stays within the window.
        self.pi
            .step_error(w_ref_rad_s - w_est_rad_s, lo - ff, hi - ff)
            + ff
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rigid-body plant: the loop settles on the reference with no steady
    /// error against a constant load, and never exceeds its current limit.
    #[test]
    fn rejects_constant_load_and_respects_limit() {
        let (j, kt, ts) = (2e-5, 0.05, 1e-3);
        let mut s = SpeedLoop::new(SpeedLoopConfig::from_bandwidth(j, kt, 150.0, ts, 4.0));
        let mut w = 0.0f32;
        let load = 0.05; // N m = 1 A worth
        for k in 0..3000 {
            let iq = s.step(100.0, w, 0.0);
            assert!(iq.abs() <= 4.0 + 1e-6);
            let torque = kt * iq - if k > 1500 { load } else { 0.0 };
            w += torque / j * ts;
        }
        assert!((w - 100.0).abs() < 0.5, "w = {w}");
    }

    #[test]
    fn bumpless_preload() {
        let mut s = SpeedLoop::new(SpeedLoopConfig::from_bandwidth(
            1e-5, 0.05, 100.0, 1e-3, 5.0,
        ));
        s.preload(2.5);
        assert!((s.step(7.0, 7.0, 0.0) - 2.5).abs() < 1e-6);
    }

    #[test]
    fn nan_keeps_state() {
        let mut s = SpeedLoop::new(SpeedLoopConfig::from_bandwidth(
            1e-5, 0.05, 100.0, 1e-3, 5.0,
        ));
        s.preload(1.0);
        let out = s.step(f32::NAN, 0.0, 0.0);
        assert_eq!(out, 1.0);
        assert!((s.step(0.0, 0.0, 0.0) - 1.0).abs() < 1e-6);
    }
}
