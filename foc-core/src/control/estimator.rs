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

/// PLL gains.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AngleTrackerConfig {
    /// Update period [s].
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
    /// `theta_meas - theta_pred` [rad] (0 for the first reading).
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

    /// Last innovation magnitude [rad].
    pub fn innovation_rad(&self) -> f32 {
        self.innovation_rad
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
}
