//! The speed loop (design §10 and §19, middle loop): PI on the mechanical
//! speed estimate, producing the q-current reference within a current limit.
//!
//! Two degrees of freedom (design §19). A step of the reference does not
//! reach the PI: a reference model, first order at the loop's bandwidth
//! ([`REFERENCE_BANDWIDTH_RATIO`]) and no faster than the current
//! limit `I` can accelerate, turns it into a speed `w_m` and an
//! acceleration `a_m`, and the current that acceleration needs is fed
//! forward. So is the current that cancels the speed observer's
//! disturbance `d` (a load torque, friction: design §19's disturbance
//! feed-forward). The PI only corrects what both do not know:
//!
//! ```text
//! a_m    = clamp(wm (w_ref - w_m), -I / K, I / K)       K = J / kt [A / (rad/s^2)]
//! iq_ref = clamp(PI(w_m - w_est) + K a_m - K d, lo, hi)   [A]
//! w_m   += a_m Ts       (w_m = w_est while the output is on the limit a_m pushes into)
//! ```
//!
//! A one-degree-of-freedom PI overshoots a step by design (its zero); this
//! one follows the model, which does not. The window `[lo, hi]` may be
//! narrower than `+-I` (the power limits of design §18): the model asks
//! for what the current limit allows, so the power stage sees the whole
//! request (e.g. to brake through the d axis). While the output is on the
//! limit the acceleration pushes into, the model restarts from the rotor
//! instead of running ahead, and the PI integrates conditionally
//! ([`AntiWindup::Clamp`]): nothing winds up that would overshoot
//! afterwards. Without a model (`reference_bandwidth_rad_s = 0`, or
//! [`SpeedLoop::step_in`] as the position stage uses it with its own
//! smooth reference and acceleration feed-forward) the reference goes to
//! the PI as given.
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

/// The reference model's bandwidth over the feedback's (design §19): the
/// model is outside the loop, so it can be faster than the loop; the
/// feed-forward makes the rotor follow it and the PI corrects the rest.
pub const REFERENCE_BANDWIDTH_RATIO: f32 = 1.0;

/// Speed-loop configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SpeedLoopConfig {
    /// Loop period \[s\] (PWM period times the speed divider).
    pub ts_s: f32,
    /// Proportional gain [A / (rad/s)].
    pub kp_a_per_rad_s: f32,
    /// Integral gain [A / rad].
    pub ki_a_per_rad: f32,
    /// q-current limit \[A\] (symmetric).
    pub current_limit_a: f32,
    /// Anti-windup strategy.
    pub anti_windup: AntiWindup,
    /// Acceleration feed-forward `J / kt` [A / (rad/s^2)] of the reference
    /// model (0: none).
    pub accel_ff_a_per_rad_s2: f32,
    /// Bandwidth of the reference model [rad/s] (0: no model, the
    /// reference goes to the PI as given).
    pub reference_bandwidth_rad_s: f32,
}

impl SpeedLoopConfig {
    /// PI gains for a speed bandwidth `wc` on a rigid inertia `J` with
    /// torque constant `kt = 1.5 p psi` [N m / A]: `Kp = J wc / kt`,
    /// `Ki = Kp wc / 8` (the PI's zero an eighth of the bandwidth: the
    /// disturbance feed-forward already cancels a load at the observer's
    /// rate, so the integrator only trims, and a larger one overshoots a
    /// step on friction); the reference model at `wc` with the
    /// feed-forward `J / kt`; conditional integration.
    pub fn from_bandwidth(
        inertia_kg_m2: f32,
        torque_constant_nm_per_a: f32,
        bandwidth_rad_s: f32,
        ts_s: f32,
        current_limit_a: f32,
    ) -> Self {
        let k = inertia_kg_m2 / torque_constant_nm_per_a;
        let kp = k * bandwidth_rad_s;
        Self {
            ts_s,
            kp_a_per_rad_s: kp,
            ki_a_per_rad: kp * bandwidth_rad_s * 0.125,
            current_limit_a,
            anti_windup: AntiWindup::Clamp,
            accel_ff_a_per_rad_s2: if k.is_finite() && k > 0.0 { k } else { 0.0 },
            reference_bandwidth_rad_s: if bandwidth_rad_s.is_finite() && bandwidth_rad_s > 0.0 {
                REFERENCE_BANDWIDTH_RATIO * bandwidth_rad_s
            } else {
                0.0
            },
        }
    }
}

/// The speed loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeedLoop {
    config: SpeedLoopConfig,
    pi: Pi,
    /// The reference model's speed [rad/s].
    w_model_rad_s: f32,
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
            w_model_rad_s: 0.0,
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

    /// Zero the integrator and the reference model.
    pub fn reset(&mut self) {
        self.pi.reset();
        self.w_model_rad_s = 0.0;
    }

    /// Bumpless entry: the next step with zero error outputs `iq_a`.
    pub fn preload(&mut self, iq_a: f32) {
        self.pi.preload(iq_a);
    }

    /// Start the reference model at the speed `w_rad_s` (e.g. the estimate
    /// on entering velocity mode; a non-finite value: 0).
    pub fn start_model(&mut self, w_rad_s: f32) {
        self.w_model_rad_s = if w_rad_s.is_finite() { w_rad_s } else { 0.0 };
    }

    /// The reference model's speed [rad/s].
    pub fn model_speed_rad_s(&self) -> f32 {
        self.w_model_rad_s
    }

    /// One step with the reference model (module docs): the reference
    /// `w_ref_rad_s` and the estimate [rad/s, mechanical], the model's
    /// acceleration within what `limit_a` \[A\] gives (and the configured
    /// limit), the output held within `[min_a, max_a]` as in
    /// [`Self::step_in`]. Without a model configured it is
    /// [`Self::step_in`] with no feed-forward. A non-finite reference
    /// holds the model.
    pub fn step_model(
        &mut self,
        w_ref_rad_s: f32,
        w_est_rad_s: f32,
        disturbance_rad_s2: f32,
        limit_a: f32,
        min_a: f32,
        max_a: f32,
    ) -> f32 {
        let c = &self.config;
        let bw = c.reference_bandwidth_rad_s;
        if bw.is_nan() || bw <= 0.0 {
            return self.step_in(w_ref_rad_s, w_est_rad_s, 0.0, min_a, max_a);
        }
        let (lo, hi) = self.window(min_a, max_a);
        let (_, lim) = self.window(-limit_a, limit_a);
        let k = c.accel_ff_a_per_rad_s2;
        let wm = self.w_model_rad_s;
        let mut a = bw * (w_ref_rad_s - wm);
        // Never further than the reference in one step (a fast model on a
        // slow loop), and no faster than the current limit can accelerate.
        let gap = (w_ref_rad_s - wm) / c.ts_s;
        a = if gap >= 0.0 { a.min(gap) } else { a.max(gap) };
        if k > 0.0 {
            a = clamp(a, -lim / k, lim / k);
        }
        if !a.is_finite() {
            a = 0.0;
        }
        // Within the window, so that the PI's own window `[lo - ff, hi - ff]`
        // always holds 0 (its integrator is never pushed off 0 by a
        // feed-forward the window cuts).
        let ff_raw = k * a + self.disturbance_ff_a(disturbance_rad_s2);
        let ff = clamp(ff_raw, lo, hi);
        // The feed-forward alone meets the limit the acceleration pushes
        // into: the output is that limit, and the PI starts again from 0
        // (its integrator could only hold the output off the limit; the
        // disturbance feed-forward carries the load).
        let cut = (a > 0.0 && ff_raw >= hi) || (a < 0.0 && ff_raw <= lo);
        let out = if cut {
            self.pi.preload(0.0);
            ff
        } else {
            self.pi.step_error(wm - w_est_rad_s, lo - ff, hi - ff) + ff
        };
        // On the limit the acceleration pushes into, the model restarts
        // from the rotor (it never runs ahead of what the current can
        // do, so nothing is left to catch up afterwards); otherwise it
        // advances.
        let pushing = cut || (a > 0.0 && out >= hi) || (a < 0.0 && out <= lo);
        let next = if pushing {
            w_est_rad_s
        } else {
            wm + a * c.ts_s
        };
        if next.is_finite() {
            self.w_model_rad_s = next;
        }
        out
    }

    /// The current that cancels the observer's disturbance \[A\]: `-J/kt d`
    /// (a load torque `T_L` shows as `d = -T_L / J`: `T_L / kt`); 0 when
    /// not finite or without a feed-forward gain.
    #[inline]
    pub fn disturbance_ff_a(&self, disturbance_rad_s2: f32) -> f32 {
        let f = -self.config.accel_ff_a_per_rad_s2 * disturbance_rad_s2;
        if f.is_finite() {
            f
        } else {
            0.0
        }
    }

    /// The output window `[lo, hi]` from `[min_a, max_a]` and the
    /// configured limit (see [`Self::step_in`]).
    #[inline]
    fn window(&self, min_a: f32, max_a: f32) -> (f32, f32) {
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
        (lo, hi)
    }

    /// One step: speed reference and estimate [rad/s, mechanical], torque
    /// feed-forward as a q current \[A\]. Returns the q-current reference \[A\]
    /// within the current limit; non-finite inputs give the last integrator
    /// value (state unchanged).
    pub fn step(&mut self, w_ref_rad_s: f32, w_est_rad_s: f32, iq_ff_a: f32) -> f32 {
        self.step_within(w_ref_rad_s, w_est_rad_s, iq_ff_a, f32::INFINITY)
    }

    /// As [`Self::step`] with the output held within `limit_a` \[A\] as well
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

    /// As [`Self::step`] with the output held within `[min_a, max_a]` \[A\]
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
        let (lo, hi) = self.window(min_a, max_a);
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

    /// A rigid rotor with Coulomb friction behind a current loop of a few
    /// periods' lag, the speed measured exactly: (largest speed [rad/s],
    /// largest output \[A\]).
    fn step_response(limit_a: f32, w_ref: f32) -> (f32, f32) {
        let (j, kt, ts) = (2e-5f32, 0.05f32, 1e-3f32);
        let mut s = SpeedLoop::new(SpeedLoopConfig::from_bandwidth(j, kt, 150.0, ts, limit_a));
        s.start_model(0.0);
        let (mut w, mut iq, mut w_max, mut out_max) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
        for _ in 0..3000 {
            let out = s.step_model(w_ref, w, 0.0, limit_a, -limit_a, limit_a);
            assert!(out.abs() <= limit_a + 1e-5);
            out_max = out_max.max(out.abs());
            // Ten substeps per loop period; the current follows with a
            // 0.3 ms time constant.
            for _ in 0..10 {
                iq += (out - iq) * (0.1 * ts / 3e-4);
                let friction = if w > 0.0 { 0.002 } else { 0.0 };
                w += (kt * iq - friction).max(if w > 0.0 { f32::MIN } else { 0.0 }) / j * 0.1 * ts;
            }
            w_max = w_max.max(w);
        }
        (w_max, out_max)
    }

    #[test]
    fn two_degrees_of_freedom_step_does_not_overshoot() {
        // Within the current limit (the model's feed-forward needs
        // J wm w_ref / kt = 2.4 A at the start, wm = 300 rad/s).
        let (w_max, out_max) = step_response(10.0, 20.0);
        assert!(out_max < 10.0, "{out_max}");
        assert!(w_max < 20.0 * 1.02, "overshoot: {w_max}");
    }

    #[test]
    fn current_limited_step_does_not_overshoot() {
        // A step the current limit cuts to a thirtieth of what the model
        // asks (18 A).
        let (w_max, out_max) = step_response(0.6, 150.0);
        assert!((out_max - 0.6).abs() < 1e-5, "{out_max}");
        assert!(w_max < 150.0 * 1.02, "overshoot: {w_max}");
    }

    #[test]
    fn one_degree_of_freedom_overshoots_the_same_step() {
        // The same loop with the reference straight into the PI: the
        // overshoot the model removes.
        let (j, kt, ts) = (2e-5f32, 0.05f32, 1e-3f32);
        let mut s = SpeedLoop::new(SpeedLoopConfig::from_bandwidth(j, kt, 150.0, ts, 10.0));
        let (mut w, mut iq, mut w_max) = (0.0f32, 0.0f32, 0.0f32);
        for _ in 0..3000 {
            let out = s.step_in(20.0, w, 0.0, -10.0, 10.0);
            for _ in 0..10 {
                iq += (out - iq) * (0.1 * ts / 3e-4);
                w += kt * iq / j * 0.1 * ts;
            }
            w_max = w_max.max(w);
        }
        assert!(w_max > 20.0 * 1.05, "{w_max}");
    }

    #[test]
    fn disturbance_feed_forward_cancels_a_known_load() {
        // d = -T_L / J: the feed-forward is T_L / kt.
        let s = SpeedLoop::new(SpeedLoopConfig::from_bandwidth(
            2e-5, 0.05, 150.0, 1e-3, 10.0,
        ));
        let d = -0.01 / 2e-5;
        assert!((s.disturbance_ff_a(d) - 0.2).abs() < 1e-5);
        assert_eq!(s.disturbance_ff_a(f32::NAN), 0.0);
    }
}
