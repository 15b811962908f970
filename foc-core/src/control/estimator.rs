//! Speed and position estimate from the angle sensor: a phase-locked loop.
//!
//! Differentiating a quantised angle gives a speed that is mostly noise (one
//! encoder count per period at 20 kHz is 0.3 rad/s of jitter for 4096 counts/rev
//! ... and far worse for hall sensors). The tracking observer below follows
//! the angle with a second-order loop instead:
//!
//! ```text
//! e       = wrap(theta_meas - theta_est)            [rad, mechanical]
//! w_est  += ki * Ts * e
//! theta_est += (w_est + kp * e) * Ts
//! kp = 2 zeta wn,  ki = wn^2   (zeta = 1: critically damped)
//! ```
//!
//! Its innovation `e` (before the update) is also the supervisor's
//! plausibility check: a sensor that jumps, or sticks while the rotor turns,
//! makes `|e|` grow beyond anything the rotor's inertia allows.
//!
//! This loop lags a constant acceleration `a` by `2 a / wn` in speed
//! (11.7 rad/s at 2976 rad/s^2 with `wn` = 80 Hz). The speed the speed loop
//! uses comes from [`SpeedObserver`] instead (design §19): the same
//! measured angle plus the acceleration the motor's torque produces,
//! `kt iq / J`, and a third integrator `d` that learns what that model does
//! not know (load torque, friction, an inertia error) as an acceleration:
//!
//! ```text
//! e          = wrap(theta_meas - theta_obs)
//! d         += k3 * Ts * e                                 [rad/s^2]
//! w_obs     += (k2 * e + kt/J * iq + d) * Ts               [rad/s]
//! theta_obs += (w_obs + k1 * e) * Ts
//! (s + pd)(s + p)^2: k1 = 2p + pd, k2 = p^2 + 2 p pd, k3 = p^2 pd
//! ```
//!
//! It follows acceleration with no steady lag (type 3) and a torque step
//! at once, without a wider bandwidth. The tracker above stays what the
//! current stage uses for the angle interpolation, the decoupling and the
//! plausibility checks: it sees only the sensor, so a model that is wrong
//! for a moment (a rotor held against a stop) never moves the angle or
//! trips a check.
//!
//! ```
//! use foc_core::control::estimator::{AngleTracker, AngleTrackerConfig};
//! use foc_core::angle::MechanicalAngle;
//! let mut t = AngleTracker::new(AngleTrackerConfig::with_bandwidth(200.0, 1.0 / 20e3));
//! let mut theta = MechanicalAngle::ZERO;
//! for _ in 0..20_000 {               // 1 s at 20 kHz, 10 rad/s
//!     theta = theta.add_radians(10.0 / 20e3);
//!     t.update(theta);
//! }
//! assert!((t.velocity_rad_s() - 10.0).abs() < 0.01);
//! ```

use crate::angle::{MechanicalAngle, MultiTurn};

/// The speed observer's angle and speed poles [rad/s] (design §19).
pub const OBSERVER_POLE_RAD_S: f32 = 2.0 * core::f32::consts::PI * 50.0;
/// The speed observer's disturbance pole [rad/s] (design §19). With the
/// other two the speed gain `p^2 + 2 p pd` (50^2 + 2 50 25 = 5000 Hz^2) stays
/// below the 80 Hz tracker's `wn^2` (6400 Hz^2), so at standstill the
/// speed is no noisier than the tracker's, while the disturbance (a load)
/// is learnt within a few milliseconds.
pub const OBSERVER_DISTURBANCE_POLE_RAD_S: f32 = 2.0 * core::f32::consts::PI * 25.0;

/// PLL gains.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AngleTrackerConfig {
    /// Update period \[s\].
    pub ts_s: f32,
    /// Proportional gain [1/s].
    pub kp_per_s: f32,
    /// Integral gain [1/s^2].
    pub ki_per_s2: f32,
}

impl AngleTrackerConfig {
    /// Critically damped tracker with natural frequency `bandwidth_rad_s`.
    pub const fn with_bandwidth(bandwidth_rad_s: f32, ts_s: f32) -> Self {
        Self {
            ts_s,
            kp_per_s: 2.0 * bandwidth_rad_s,
            ki_per_s2: bandwidth_rad_s * bandwidth_rad_s,
        }
    }
}

/// Tracks the mechanical angle: filtered speed, predicted angle, and the
/// multi-turn position of the (measured) readings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AngleTracker {
    config: AngleTrackerConfig,
    theta_est: MechanicalAngle,
    omega_rad_s: f32,
    position: MultiTurn,
    innovation_rad: f32,
    primed: bool,
}

/// `rad` (|rad| < pi) as a wrapping angle increment, without `floorf`.
#[inline]
fn small_increment(rad: f32) -> MechanicalAngle {
    // 2^31 / pi counts per radian; the cast saturates for |rad| >= pi.
    MechanicalAngle::from_bits(((rad * 683_565_275.6) as i32) as u32)
}

impl AngleTracker {
    /// New tracker; the first reading initialises it.
    pub const fn new(config: AngleTrackerConfig) -> Self {
        Self {
            config,
            theta_est: MechanicalAngle::ZERO,
            omega_rad_s: 0.0,
            position: MultiTurn::ZERO,
            innovation_rad: 0.0,
            primed: false,
        }
    }

    /// Forget everything; the next reading initialises the tracker.
    pub fn reset(&mut self) {
        *self = Self::new(self.config);
    }

    /// Change the gains, keeping the state.
    pub fn set_config(&mut self, config: AngleTrackerConfig) {
        self.config = config;
    }

    /// Feed one reading. Returns the signed innovation
    /// `theta_meas - theta_pred` \[rad\] (0 for the first reading).
    pub fn update(&mut self, theta_meas: MechanicalAngle) -> f32 {
        if !self.primed {
            self.theta_est = theta_meas;
            self.position = MultiTurn::new(theta_meas);
            self.primed = true;
            self.innovation_rad = 0.0;
            return 0.0;
        }
        let c = &self.config;
        let e = theta_meas.diff_radians(self.theta_est);
        self.innovation_rad = e.abs();
        self.omega_rad_s += c.ki_per_s2 * c.ts_s * e;
        if !self.omega_rad_s.is_finite() {
            self.omega_rad_s = 0.0;
        }
        let step = (self.omega_rad_s + c.kp_per_s * e) * c.ts_s;
        self.theta_est = self.theta_est.wrapping_add(small_increment(step));
        self.position.update(theta_meas);
        e
    }

    /// Estimated mechanical velocity [rad/s].
    pub fn velocity_rad_s(&self) -> f32 {
        self.omega_rad_s
    }

    /// Estimated (filtered) mechanical angle: the prediction for the next
    /// reading.
    pub fn angle(&self) -> MechanicalAngle {
        self.theta_est
    }

    /// Estimated mechanical angle at the instant of the last reading: the
    /// prediction for it corrected by this reading (`theta_pred + kp e Ts`),
    /// i.e. [`Self::angle`] moved back by one period at the tracked speed.
    /// Between the edges of a coarse sensor this advances with the tracked
    /// speed (see `AngleCalibration::interpolation_half_count`).
    #[inline]
    pub fn angle_at_reading(&self) -> MechanicalAngle {
        self.theta_est
            .wrapping_sub(small_increment(self.omega_rad_s * self.config.ts_s))
    }

    /// Multi-turn position of the readings.
    pub fn position(&self) -> MultiTurn {
        self.position
    }

    /// Last innovation magnitude \[rad\].
    pub fn innovation_rad(&self) -> f32 {
        self.innovation_rad
    }
}

/// Gains of the [`SpeedObserver`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SpeedObserverConfig {
    /// Update period \[s\].
    pub ts_s: f32,
    /// Angle gain [1/s].
    pub k1_per_s: f32,
    /// Speed gain [1/s^2].
    pub k2_per_s2: f32,
    /// Acceleration-disturbance gain [1/s^3].
    pub k3_per_s3: f32,
    /// Acceleration per ampere of q current, `kt / J` [rad/s^2 / A,
    /// mechanical] (0: no torque input, a plain type-3 tracking loop).
    pub accel_per_a_rad_s2: f32,
    /// Coulomb friction as a deceleration, `Fc / J` [rad/s^2] (0: none).
    pub coulomb_rad_s2: f32,
    /// Viscous friction as a rate, `B / J` [1/s] (0: none).
    pub viscous_per_s: f32,
}

impl SpeedObserverConfig {
    /// Poles at `-pole_rad_s` (two: angle and speed, critically damped)
    /// and at `-disturbance_pole_rad_s` (the disturbance integrator), fed
    /// with `accel_per_a_rad_s2` [rad/s^2 per A] times the q current
    /// (non-finite or negative: 0). The error polynomial is
    /// `(s + pd)(s + p)^2`: `k1 = 2p + pd`, `k2 = p^2 + 2 p pd`,
    /// `k3 = p^2 pd`.
    pub fn new(
        pole_rad_s: f32,
        disturbance_pole_rad_s: f32,
        ts_s: f32,
        accel_per_a_rad_s2: f32,
    ) -> Self {
        let (p, pd) = (pole_rad_s, disturbance_pole_rad_s);
        Self {
            ts_s,
            k1_per_s: 2.0 * p + pd,
            k2_per_s2: p * p + 2.0 * p * pd,
            k3_per_s3: p * p * pd,
            accel_per_a_rad_s2: if accel_per_a_rad_s2.is_finite() && accel_per_a_rad_s2 > 0.0 {
                accel_per_a_rad_s2
            } else {
                0.0
            },
            coulomb_rad_s2: 0.0,
            viscous_per_s: 0.0,
        }
    }

    /// This configuration with the rotor's friction in the model: Coulomb
    /// `Fc` [N m] and viscous `B` [N m s/rad] on the inertia `J` [kg m^2]
    /// (a value that is not finite and non-negative, or a `J` that is not
    /// positive: that term off).
    pub fn with_friction(
        mut self,
        coulomb_nm: f32,
        viscous_nm_s_per_rad: f32,
        inertia_kg_m2: f32,
    ) -> Self {
        let per_j = |x: f32| {
            let v = x / inertia_kg_m2;
            if x >= 0.0 && v.is_finite() && inertia_kg_m2 > 0.0 {
                v
            } else {
                0.0
            }
        };
        self.coulomb_rad_s2 = per_j(coulomb_nm);
        // The viscous term is integrated explicitly: a rate beyond a tenth
        // of the update rate (a friction no rotor has) is left out rather
        // than made unstable.
        let v = per_j(viscous_nm_s_per_rad);
        self.viscous_per_s = if v * self.ts_s <= 0.1 { v } else { 0.0 };
        self
    }

    /// The observer of the cascade's poles
    /// ([`OBSERVER_POLE_RAD_S`] and
    /// `OBSERVER_DISTURBANCE_POLE_RAD_S`) with the model of `m` for the
    /// torque constant `kt` [N m / A]: `kt / J` and the friction.
    pub fn for_mechanics(m: &crate::control::Mechanics, kt: f32, ts_s: f32) -> Self {
        Self::new(
            OBSERVER_POLE_RAD_S,
            OBSERVER_DISTURBANCE_POLE_RAD_S,
            ts_s,
            Self::accel_per_amp(kt, m.inertia_kg_m2),
        )
        .with_friction(
            m.coulomb_friction_nm,
            m.viscous_friction_nm_s_per_rad,
            m.inertia_kg_m2,
        )
    }

    /// The observer without a model: exactly the angle tracker's
    /// critically damped loop at `bandwidth_rad_s` (`k1 = 2 wn`,
    /// `k2 = wn^2`, no disturbance integrator, no torque input), for a
    /// rotor whose inertia is not known.
    pub fn tracker_like(bandwidth_rad_s: f32, ts_s: f32) -> Self {
        Self {
            ts_s,
            k1_per_s: 2.0 * bandwidth_rad_s,
            k2_per_s2: bandwidth_rad_s * bandwidth_rad_s,
            k3_per_s3: 0.0,
            accel_per_a_rad_s2: 0.0,
            coulomb_rad_s2: 0.0,
            viscous_per_s: 0.0,
        }
    }

    /// `kt / J` [rad/s^2 per A] for a torque constant [N m / A] and an
    /// inertia [kg m^2]; 0 when either is not a positive finite value.
    pub fn accel_per_amp(torque_constant_nm_per_a: f32, inertia_kg_m2: f32) -> f32 {
        let k = torque_constant_nm_per_a / inertia_kg_m2;
        if k.is_finite() && k > 0.0 && inertia_kg_m2 > 0.0 {
            k
        } else {
            0.0
        }
    }
}

/// The torque-fed speed observer (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeedObserver {
    config: SpeedObserverConfig,
    theta: MechanicalAngle,
    omega_rad_s: f32,
    accel_rad_s2: f32,
    primed: bool,
}

impl SpeedObserver {
    /// New observer; the first reading initialises it.
    pub const fn new(config: SpeedObserverConfig) -> Self {
        Self {
            config,
            theta: MechanicalAngle::ZERO,
            omega_rad_s: 0.0,
            accel_rad_s2: 0.0,
            primed: false,
        }
    }

    /// Forget everything; the next reading initialises the observer.
    pub fn reset(&mut self) {
        *self = Self::new(self.config);
    }

    /// The configuration.
    pub fn config(&self) -> &SpeedObserverConfig {
        &self.config
    }

    /// Change the gains, keeping the state.
    pub fn set_config(&mut self, config: SpeedObserverConfig) {
        self.config = config;
    }

    /// Feed one reading [rad, mechanical] and the q current \[A\] that drove
    /// the rotor over the last period (a non-finite value counts as 0).
    #[inline]
    pub fn update(&mut self, theta_meas: MechanicalAngle, iq_a: f32) {
        if !self.primed {
            self.theta = theta_meas;
            self.primed = true;
            return;
        }
        let c = &self.config;
        let e = theta_meas.diff_radians(self.theta);
        self.accel_rad_s2 += c.k3_per_s3 * c.ts_s * e;
        let a = self.accel_rad_s2 + self.model_accel(iq_a);
        self.omega_rad_s += (c.k2_per_s2 * e + a) * c.ts_s;
        if !(self.omega_rad_s.is_finite() && self.accel_rad_s2.is_finite()) {
            self.omega_rad_s = 0.0;
            self.accel_rad_s2 = 0.0;
        }
        let step = (self.omega_rad_s + c.k1_per_s * e) * c.ts_s;
        self.theta = self.theta.wrapping_add(small_increment(step));
    }

    /// The model's acceleration [rad/s^2] for the q current `iq_a` at the
    /// estimated speed: `kt/J iq` less the friction. Within the speed
    /// two periods of Coulomb friction change (a rotor at rest), the
    /// friction holds the rotor as stiction does, up to `Fc / J`.
    #[inline(always)]
    fn model_accel(&self, iq_a: f32) -> f32 {
        let c = &self.config;
        let drive = c.accel_per_a_rad_s2 * iq_a;
        let drive = if drive.is_finite() { drive } else { 0.0 };
        if c.coulomb_rad_s2 == 0.0 && c.viscous_per_s == 0.0 {
            return drive;
        }
        let w = self.omega_rad_s;
        let fc = c.coulomb_rad_s2;
        let still = 2.0 * fc * c.ts_s;
        let coulomb = if w > still {
            -fc
        } else if w < -still {
            fc
        } else {
            -crate::clamp(drive, -fc, fc)
        };
        drive + coulomb - c.viscous_per_s * w
    }

    /// Estimated mechanical velocity [rad/s].
    pub fn velocity_rad_s(&self) -> f32 {
        self.omega_rad_s
    }

    /// The acceleration learnt beyond the torque model (load torque,
    /// friction, model error) [rad/s^2].
    pub fn disturbance_rad_s2(&self) -> f32 {
        self.accel_rad_s2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tracks_a_ramp_through_many_turns() {
        let ts = 1.0 / 20e3;
        let mut t = AngleTracker::new(AngleTrackerConfig::with_bandwidth(300.0, ts));
        let mut th = MechanicalAngle::ZERO;
        let w = -150.0; // rad/s, backwards
                        // The first reading sets the position (its angle within the turn);
                        // after that the position follows every reading across turns.
        t.update(th);
        let mut travelled = 0.0f64;
        for _ in 0..40_000 {
            let next = th.add_radians(w * ts);
            travelled += next.diff_radians(th) as f64;
            th = next;
            t.update(th);
        }
        assert!((t.velocity_rad_s() - w).abs() < 0.05);
        // About 2 s at -150 rad/s = -300 rad, counted across 47 turns.
        assert!((travelled + 300.0).abs() < 0.1, "{travelled}");
        assert!((t.position().to_radians() as f64 - travelled).abs() < 1e-3);
        assert!(t.innovation_rad() < 1e-3);
    }

    #[test]
    fn quantised_encoder_gives_smooth_speed() {
        // 2048-count encoder at 3 rad/s: fewer than one count per period.
        let ts = 1.0 / 20e3;
        let mut t = AngleTracker::new(AngleTrackerConfig::with_bandwidth(100.0, ts));
        let counts = 2048.0;
        let mut max_err: f32 = 0.0;
        for k in 0..60_000u32 {
            let true_turns = 3.0 * (k as f32 * ts) / core::f32::consts::TAU;
            let q = libm::floorf(true_turns * counts) / counts;
            t.update(MechanicalAngle::from_turns(q));
            if k > 20_000 {
                max_err = max_err.max((t.velocity_rad_s() - 3.0).abs());
            }
        }
        // Raw differencing would jump between 0 and 61 rad/s.
        assert!(max_err < 0.6, "speed ripple {max_err}");
    }

    #[test]
    fn jump_shows_as_innovation() {
        let ts = 1.0 / 20e3;
        let mut t = AngleTracker::new(AngleTrackerConfig::with_bandwidth(300.0, ts));
        t.update(MechanicalAngle::ZERO);
        t.update(MechanicalAngle::ZERO);
        let e = t.update(MechanicalAngle::from_degrees(90.0));
        assert!((e - core::f32::consts::FRAC_PI_2).abs() < 1e-3);
    }

    /// A rigid rotor under a q-current profile, read by a 4096-count
    /// encoder: (observer's, tracker's) largest speed error [rad/s] while
    /// it accelerates, after `settle` periods.
    fn accelerate(obs: SpeedObserverConfig, load_rad_s2: f32) -> (f32, f32) {
        let ts = 1.0 / 20e3;
        let k = obs.accel_per_a_rad_s2;
        let mut o = SpeedObserver::new(obs);
        let mut t = AngleTracker::new(AngleTrackerConfig::with_bandwidth(
            2.0 * core::f32::consts::PI * 80.0,
            ts,
        ));
        let (mut w, mut th) = (0.0f64, 0.0f64);
        let (mut eo, mut et) = (0.0f32, 0.0f32);
        for n in 0..8000u32 {
            // 0.1 s at rest, 0.2 s at 4 A, then 0 A.
            let iq = if (2000..6000).contains(&n) { 4.0 } else { 0.0 };
            let reading = MechanicalAngle::from_turns(
                (libm::floor(th / core::f64::consts::TAU * 4096.0) / 4096.0) as f32,
            );
            o.update(reading, iq);
            t.update(reading);
            if n > 2000 {
                eo = eo.max((o.velocity_rad_s() - w as f32).abs());
                et = et.max((t.velocity_rad_s() - w as f32).abs());
            }
            let a = if w > 0.0 || iq > 0.0 {
                (k * iq - load_rad_s2) as f64
            } else {
                0.0
            };
            th += w * ts as f64 + 0.5 * a * (ts * ts) as f64;
            w += a * ts as f64;
        }
        (eo, et)
    }

    #[test]
    fn observer_follows_a_torque_step_without_the_trackers_lag() {
        let ts = 1.0 / 20e3;
        // 2000 rad/s^2 per ampere: 8000 rad/s^2 at 4 A.
        let cfg = SpeedObserverConfig::new(
            2.0 * core::f32::consts::PI * 80.0,
            2.0 * core::f32::consts::PI * 80.0,
            ts,
            2000.0,
        );
        let (eo, et) = accelerate(cfg, 0.0);
        // The tracker lags 2a/wn = 31.8 rad/s; the observer a few counts'
        // worth of a speed quantum.
        assert!(et > 25.0, "tracker {et}");
        assert!(eo < 0.05 * et && eo < 1.0, "observer {eo} vs tracker {et}");
    }

    #[test]
    fn observer_learns_an_unknown_load() {
        let ts = 1.0 / 20e3;
        // The load (500 rad/s^2) is not in the model: the disturbance
        // integrator learns it; the error stays a fraction of the lag.
        let cfg = SpeedObserverConfig::new(
            2.0 * core::f32::consts::PI * 80.0,
            2.0 * core::f32::consts::PI * 80.0,
            ts,
            2000.0,
        );
        let (eo, et) = accelerate(cfg, 500.0);
        assert!(eo < 0.1 * et, "observer {eo} vs tracker {et}");
    }

    #[test]
    fn observer_at_standstill_is_no_noisier_than_the_tracker() {
        // A reading dithering between two counts and a noisy current (at
        // rest: the q current only carries noise), 1 s at 20 kHz.
        let ts = 1.0 / 20e3;
        // The observer as the cascade configures it, the tracker at its 80 Hz.
        let cfg = SpeedObserverConfig::new(
            OBSERVER_POLE_RAD_S,
            OBSERVER_DISTURBANCE_POLE_RAD_S,
            ts,
            2000.0,
        );
        let mut o = SpeedObserver::new(cfg);
        let mut t = AngleTracker::new(AngleTrackerConfig::with_bandwidth(
            2.0 * core::f32::consts::PI * 80.0,
            ts,
        ));
        let mut seed = 12345u32;
        let (mut so, mut st) = (0.0f64, 0.0f64);
        for n in 0..20_000u32 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let count = (seed >> 31) as f32;
            // +-10 mA of current-sense noise (20 rad/s^2 here).
            let iq = ((seed >> 8) & 0xffff) as f32 / 65536.0 * 0.02 - 0.01;
            let reading = MechanicalAngle::from_turns(count / 4096.0);
            o.update(reading, iq);
            t.update(reading);
            if n > 2000 {
                so += (o.velocity_rad_s() as f64).powi(2);
                st += (t.velocity_rad_s() as f64).powi(2);
            }
        }
        assert!(so <= st, "observer rms^2 sum {so} > tracker {st}");
    }

    #[test]
    fn observer_with_friction_holds_a_rotor_below_breakaway() {
        // 0.5 A on a rotor whose Coulomb friction needs 1 A to break away:
        // the rotor stays still, and so does the estimate.
        let ts = 1.0 / 20e3;
        // kt/J = 2000 rad/s^2 per A; Fc/J = 0.2 N m / 1e-4 kg m^2 = 2000
        // rad/s^2: breakaway at 1 A.
        let cfg = SpeedObserverConfig::new(500.0, 50.0, ts, 2000.0).with_friction(0.2, 0.0, 1e-4);
        assert!((cfg.coulomb_rad_s2 - 2000.0).abs() < 0.01);
        let mut o = SpeedObserver::new(cfg);
        for _ in 0..4000 {
            o.update(MechanicalAngle::ZERO, 0.5);
        }
        assert!(o.velocity_rad_s().abs() < 1e-3, "{}", o.velocity_rad_s());
        assert!(
            o.disturbance_rad_s2().abs() < 1.0,
            "{}",
            o.disturbance_rad_s2()
        );
    }

    #[test]
    fn observer_ignores_non_finite_current_and_bad_gains() {
        let mut o = SpeedObserver::new(SpeedObserverConfig::new(1e4, 1e4, 1e-2, f32::NAN));
        assert_eq!(o.config().accel_per_a_rad_s2, 0.0);
        let mut a = MechanicalAngle::ZERO;
        for k in 0..500u32 {
            a = a.wrapping_add(MechanicalAngle::from_bits(k.wrapping_mul(0x1234_5678)));
            o.update(a, if k % 3 == 0 { f32::NAN } else { f32::INFINITY });
            assert!(o.velocity_rad_s().is_finite() && o.disturbance_rad_s2().is_finite());
        }
    }
}
