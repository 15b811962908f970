//! Trapezoidal velocity profile for position moves.
//!
//! A move from the current position and velocity to a target at rest, with a
//! velocity limit `v_max` and an acceleration limit `a_max`: accelerate (or
//! decelerate) to the peak velocity, cruise, decelerate to zero at the
//! target. Short moves become triangles. When the initial velocity points
//! away from the target or is too fast to stop in time, the profile first
//! brakes to a stop and then plans a fresh move from there (so a re-target
//! in the middle of a move is smooth).
//!
//! ```
//! use foc_core::control::trajectory::Trapezoid;
//! let t = Trapezoid::plan(0.0, 0.0, 10.0, 5.0, 10.0);
//! assert!((t.duration_s() - 2.5).abs() < 1e-5); // 0.5 s up, 1.5 s cruise, 0.5 s down
//! let s = t.sample(t.duration_s());
//! assert!((s.position - 10.0).abs() < 1e-5 && s.velocity == 0.0);
//! ```

use crate::{clamp, sqrtf};

/// A point of the profile.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrajectoryPoint {
    /// Position \[rad\].
    pub position: f32,
    /// Velocity [rad/s].
    pub velocity: f32,
    /// Acceleration [rad/s^2].
    pub acceleration: f32,
}

/// One constant-acceleration segment.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Segment {
    t0: f32,
    p0: f32,
    v0: f32,
    a: f32,
}

/// A planned trapezoidal (or braking + trapezoidal) move.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Trapezoid {
    /// Up to four segments: brake, accelerate, cruise, decelerate.
    seg: [Segment; 4],
    n: usize,
    t_end: f32,
    target: f32,
}

impl Trapezoid {
    /// Plan from position `p0` and velocity `v0` to `target` at rest.
    /// Non-finite or non-positive limits give a profile that holds `p0`.
    pub fn plan(p0: f32, v0: f32, target: f32, v_max: f32, a_max: f32) -> Self {
        let mut t = Self {
            seg: [Segment::default(); 4],
            n: 0,
            t_end: 0.0,
            target: p0,
        };
        let ok = [p0, v0, target, v_max, a_max].iter().all(|x| x.is_finite())
            && v_max > 0.0
            && a_max > 0.0;
        if !ok {
            t.push(0.0, p0, 0.0, 0.0);
            return t;
        }
        t.target = target;
        let v0 = clamp(v0, -v_max, v_max);
        let d = target - p0;
        let stop_dist = v0 * v0 / (2.0 * a_max);
        let towards = v0 * d >= 0.0;
        let (mut time, mut p, mut v) = (0.0f32, p0, v0);
        if v0 != 0.0 && (!towards || stop_dist > d.abs()) {
            // Brake to rest first.
            let a = -v0.signum() * a_max;
            let tb = v0.abs() / a_max;
            t.push(0.0, p, v, a);
            p += v0 * tb * 0.5;
            v = 0.0;
            time = tb;
        }
        let d = target - p;
        let s = if d >= 0.0 { 1.0 } else { -1.0 };
        let dist = d.abs();
        let u0 = v * s; // >= 0 here
        let vp = {
            let tri = sqrtf(a_max * dist + 0.5 * u0 * u0);
            if tri < v_max {
                tri
            } else {
                v_max
            }
        };
        let t1 = (vp - u0).abs() / a_max;
        let a1 = if vp >= u0 { a_max } else { -a_max };
        let d1 = 0.5 * (u0 + vp) * t1;
        let t3 = vp / a_max;
        let d3 = 0.5 * vp * t3;
        let d2 = dist - d1 - d3;
        let t2 = if vp > 0.0 && d2 > 0.0 { d2 / vp } else { 0.0 };
        t.push(time, p, s * u0, s * a1);
        time += t1;
        p += s * d1;
        t.push(time, p, s * vp, 0.0);
        time += t2;
        p += s * vp * t2;
        t.push(time, p, s * vp, -s * a_max);
        time += t3;
        t.t_end = time;
        t
    }

    fn push(&mut self, t0: f32, p0: f32, v0: f32, a: f32) {
        if let Some(slot) = self.seg.get_mut(self.n) {
            *slot = Segment { t0, p0, v0, a };
            self.n += 1;
        }
    }

    /// Total duration \[s\].
    pub fn duration_s(&self) -> f32 {
        self.t_end
    }

    /// Target position \[rad\].
    pub fn target(&self) -> f32 {
        self.target
    }

    /// Position, velocity and acceleration at time `t_s` after the start.
    /// Before 0 it is the start; after the end, the target at rest.
    pub fn sample(&self, t_s: f32) -> TrajectoryPoint {
        if t_s >= self.t_end || t_s.is_nan() {
            return TrajectoryPoint {
                position: self.target,
                velocity: 0.0,
                acceleration: 0.0,
            };
        }
        let t_s = if t_s > 0.0 { t_s } else { 0.0 };
        let mut cur = self.seg.first().copied().unwrap_or_default();
        for s in self.seg.iter().take(self.n) {
            if s.t0 <= t_s {
                cur = *s;
            }
        }
        let dt = t_s - cur.t0;
        TrajectoryPoint {
            position: cur.p0 + cur.v0 * dt + 0.5 * cur.a * dt * dt,
            velocity: cur.v0 + cur.a * dt,
            acceleration: cur.a,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check_limits_and_continuity(t: &Trapezoid, v_max: f32, a_max: f32) {
        let n = 2000;
        let mut prev = t.sample(0.0);
        for k in 1..=n {
            let s = t.sample(t.duration_s() * k as f32 / n as f32);
            assert!(s.velocity.abs() <= v_max * 1.001 + 1e-4, "{s:?}");
            assert!(s.acceleration.abs() <= a_max * 1.001);
            let dt = t.duration_s() / n as f32;
            assert!((s.position - prev.position).abs() <= v_max * dt * 1.01 + 1e-4);
            assert!((s.velocity - prev.velocity).abs() <= a_max * dt * 1.01 + 1e-4);
            prev = s;
        }
        assert!((prev.position - t.target()).abs() < 1e-3);
        assert!(prev.velocity.abs() < 1e-3);
    }

    #[test]
    fn trapezoid_and_triangle() {
        let t = Trapezoid::plan(1.0, 0.0, -9.0, 5.0, 10.0);
        check_limits_and_continuity(&t, 5.0, 10.0);
        let tri = Trapezoid::plan(0.0, 0.0, 0.4, 5.0, 10.0);
        // Triangle: peak sqrt(a d) = 2 rad/s, duration 2 sqrt(d/a) = 0.4 s.
        assert!((tri.duration_s() - 0.4).abs() < 1e-5);
        check_limits_and_continuity(&tri, 5.0, 10.0);
    }

    #[test]
    fn retarget_while_moving_away_brakes_first() {
        let t = Trapezoid::plan(0.0, 4.0, -2.0, 5.0, 10.0);
        check_limits_and_continuity(&t, 5.0, 10.0);
        assert!(t.sample(0.0).acceleration < 0.0);
        // Overshoot case: too fast to stop before the target.
        let t2 = Trapezoid::plan(0.0, 5.0, 0.5, 5.0, 10.0);
        check_limits_and_continuity(&t2, 5.0, 10.0);
    }

    #[test]
    fn bad_limits_hold_position() {
        let t = Trapezoid::plan(3.0, 1.0, 7.0, f32::NAN, 1.0);
        let s = t.sample(0.5);
        assert_eq!((s.position, s.velocity), (3.0, 0.0));
    }
}
