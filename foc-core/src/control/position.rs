//! The position loop (design §10, outer loop): P on the mechanical
//! position with velocity feed-forward from a trapezoidal trajectory.
//!
//! ```text
//! (p_ref, v_ff) = trajectory(t)
//! w_ref = clamp(v_ff + kp (p_ref - p_meas), -v_max, v_max)   [rad/s]
//! ```
//!
//! ```
//! use foc_core::control::position::{PositionLoop, PositionLoopConfig};
//! let mut p = PositionLoop::new(PositionLoopConfig { ts_s: 1e-3, kp_per_s: 20.0, max_velocity_rad_s: 50.0, max_acceleration_rad_s2: 500.0, accel_ff_a_per_rad_s2: 0.0 });
//! p.start_move(0.0, 0.0, 1.0);
//! let _at_start = p.step(0.0); // the reference starts at rest
//! let w = p.step(0.0);           // then accelerates towards the target
//! assert!(w > 0.0);
//! ```

use super::trajectory::{TrajectoryPoint, Trapezoid};
use crate::clamp;

/// Position-loop configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PositionLoopConfig {
    /// Loop period \[s\].
    pub ts_s: f32,
    /// Proportional gain [(rad/s) / rad].
    pub kp_per_s: f32,
    /// Trajectory and output velocity limit [rad/s].
    pub max_velocity_rad_s: f32,
    /// Trajectory acceleration limit [rad/s^2].
    pub max_acceleration_rad_s2: f32,
    /// Acceleration feed-forward gain `J / kt` [A / (rad/s^2)]: the q current
    /// the trajectory's acceleration needs (0 disables it).
    pub accel_ff_a_per_rad_s2: f32,
}

/// Position loop with its trajectory generator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionLoop {
    config: PositionLoopConfig,
    traj: Trapezoid,
    t_s: f32,
    last_ref: TrajectoryPoint,
}

impl PositionLoop {
    /// New loop holding position 0.
    pub fn new(config: PositionLoopConfig) -> Self {
        Self {
            config,
            traj: Trapezoid::plan(0.0, 0.0, 0.0, 1.0, 1.0),
            t_s: 0.0,
            last_ref: TrajectoryPoint::default(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &PositionLoopConfig {
        &self.config
    }

    /// Replace the configuration (applies to the next move).
    pub fn set_config(&mut self, config: PositionLoopConfig) {
        self.config = config;
    }

    /// Plan a move from `(p0, v0)` to `target` [rad, rad/s].
    pub fn start_move(&mut self, p0: f32, v0: f32, target: f32) {
        let c = &self.config;
        self.traj = Trapezoid::plan(
            p0,
            v0,
            target,
            c.max_velocity_rad_s,
            c.max_acceleration_rad_s2,
        );
        self.t_s = 0.0;
        self.last_ref = self.traj.sample(0.0);
    }

    /// Re-target mid-move, continuing from the current reference point.
    pub fn retarget(&mut self, target: f32) {
        let r = self.last_ref;
        self.start_move(r.position, r.velocity, target);
    }

    /// Current target \[rad\].
    pub fn target(&self) -> f32 {
        self.traj.target()
    }

    /// q-current feed-forward \[A\] for the last reference's acceleration.
    pub fn current_feed_forward_a(&self) -> f32 {
        let ff = self.config.accel_ff_a_per_rad_s2 * self.last_ref.acceleration;
        if ff.is_finite() {
            ff
        } else {
            0.0
        }
    }

    /// The reference point used by the last step.
    pub fn reference(&self) -> TrajectoryPoint {
        self.last_ref
    }

    /// True once the trajectory has reached its end.
    pub fn trajectory_done(&self) -> bool {
        self.t_s >= self.traj.duration_s()
    }

    /// One step: measured position \[rad\] in, velocity reference [rad/s] out.
    /// A non-finite measurement gives the feed-forward alone.
    pub fn step(&mut self, p_meas_rad: f32) -> f32 {
        let r = self.traj.sample(self.t_s);
        self.last_ref = r;
        if self.t_s < self.traj.duration_s() {
            self.t_s += self.config.ts_s;
        }
        let v_max = self.config.max_velocity_rad_s;
        let corr = if p_meas_rad.is_finite() {
            self.config.kp_per_s * (r.position - p_meas_rad)
        } else {
            0.0
        };
        let w = clamp(r.velocity + corr, -v_max, v_max);
        if w.is_finite() {
            w
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn follows_move_on_ideal_velocity_plant() {
        let c = PositionLoopConfig {
            ts_s: 1e-3,
            kp_per_s: 30.0,
            max_velocity_rad_s: 20.0,
            max_acceleration_rad_s2: 200.0,
            accel_ff_a_per_rad_s2: 0.0,
        };
        let mut pl = PositionLoop::new(c);
        let mut p = 0.0f32;
        pl.start_move(p, 0.0, 6.0);
        for _ in 0..1000 {
            let w = pl.step(p);
            assert!(w.abs() <= 20.0);
            p += w * c.ts_s;
        }
        assert!(pl.trajectory_done());
        assert!((p - 6.0).abs() < 1e-3, "p = {p}");
    }
}
