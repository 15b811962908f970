//! Mode of operation -> drive command: the profile's demand generator
//! (pp trapezoid, pv / tq ramps, quick-stop ramp, cyclic targets) and the
//! [`Follower`] that turns a position demand into a drive command.
//!
//! The demand lives here, in SI and the rotor frame; the profile converts
//! targets and parameters on the way in and the demand on the way out.
//!
//! ```
//! use foc_canopen::cia402::modes::ramp;
//! // 10 rad/s^2 for 0.1 s: 1 rad/s closer to the target.
//! assert_eq!(ramp(0.0, 5.0, 10.0, 20.0, 0.1), 1.0);
//! assert_eq!(ramp(4.5, 5.0, 10.0, 20.0, 0.1), 5.0);
//! ```

use foc_core::control::joint::Impedance;
use foc_core::control::trajectory::Trapezoid;
use foc_core::control::{Command, Feedback, Limits};
use foc_protocol::device::DeviceContext;
use foc_protocol::message::ParamId;

use super::units::{
    clamp_abs, clamp_range, finite_or_zero, inc_to_rad, permille_to_amps, rated_current_a,
    uinc_to_rad, RAD_PER_INC,
};
use super::{OpMode, Params, Targets};

/// How a position demand (pp's profile, csp's targets) goes to the drive.
///
/// Measured on the bench plant (emulated board's motor, updates every
/// 1 ms, `tests/cia402_plant.rs`): csp along a 1 rev (peak to peak)
/// sinusoid over 1 s, max |0x60F4|: `Impedance` 255 inc (0.024 rad),
/// `Velocity` 469 inc, `Position` 65 536 inc (does not follow, see
/// there); all three settle to 0 inc after a pp move. Hence the default,
/// [`Follower::Impedance`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Follower {
    /// `Command::Position` at the demand: the drive's own trapezoid planner
    /// re-plans to every new demand. It does not follow a demand that
    /// changes at every position-loop step: each re-plan restarts the
    /// trajectory at its first sample, so the drive's reference stands
    /// still until the demand stops changing (foc-core's
    /// `PositionStage::retarget`). Kept for comparison.
    Position,
    /// `Command::Velocity = v_demand + kp (p_demand - p_actual)`: the
    /// profile closes the position loop at its update rate with the drive's
    /// position gain; the drive's speed PI removes the static error.
    Velocity,
    /// `Command::Impedance { p_demand, v_demand, kp, kd, T_ff }`: the
    /// drive's own P-PI position / speed cascade written as an impedance
    /// (`kd = kt kv`, `kp = kt (kv kp_pos + ki)`, and the speed integral's
    /// `kt ki kp_pos` integral of the position error as `T_ff`), closed by
    /// the drive every PWM period, its position reference advancing with
    /// the velocity between updates (no 1 ms staircase). A zero stiffness
    /// limit falls back to [`Follower::Velocity`].
    Impedance,
}

/// The gains a [`Follower`] uses (read from the drive when operation is
/// enabled).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FollowerGains {
    /// Position gain [(rad/s)/rad].
    pub kp_per_s: f32,
    /// Impedance stiffness [N m/rad].
    pub kp_nm_per_rad: f32,
    /// Impedance damping [N m s/rad].
    pub kd_nm_s_per_rad: f32,
    /// Integral gain on the position error [N m/(rad s)].
    pub ki_nm_per_rad_s: f32,
    /// Bound of the integral's torque [N m].
    pub torque_max_nm: f32,
}

/// What one update works with.
#[derive(Clone, Copy, Debug)]
pub struct Inputs<'a> {
    /// Targets.
    pub targets: &'a Targets,
    /// Parameters.
    pub params: &'a Params,
    /// Limits in force (rotor frame).
    pub limits: &'a Limits,
    /// Rated current \[A\].
    pub rated_a: f32,
    /// The drive's feedback.
    pub fb: &'a Feedback,
    /// Time since the last update \[s\].
    pub dt_s: f32,
    /// Now \[us\].
    pub now_us: u64,
    /// Controlword bit 8.
    pub halt: bool,
}

/// The demand: what the profile asks of the drive, SI, rotor frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Demand {
    /// Position \[rad\].
    pub pos_rad: f32,
    /// Velocity [rad/s].
    pub vel_rad_s: f32,
    /// q current \[A\].
    pub iq_a: f32,
    /// Feed-forward torque of the impedance follower [N m]: the integral
    /// of the position error (the drive's speed-loop integral, moved here).
    pub torque_ff_nm: f32,
}

/// Move `x` towards `target` by at most `accel dt` when speeding up (away
/// from 0) and `decel dt` when slowing down. NaN-safe (gives `target` or
/// holds `x` when finite).
pub fn ramp(x: f32, target: f32, accel: f32, decel: f32, dt_s: f32) -> f32 {
    let x = finite_or_zero(x);
    let target = finite_or_zero(target);
    let away = target.abs() > x.abs() && x * target >= 0.0;
    let step = finite_or_zero(if away { accel } else { decel } * dt_s);
    let d = target - x;
    if d.abs() <= step {
        target
    } else if d > 0.0 {
        x + step
    } else {
        x - step
    }
}

/// The demand generator's state.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Generator {
    /// The demand.
    pub demand: Demand,
    traj: Trapezoid,
    t_s: f32,
    /// pp: the target in force \[rad\] (the last set-point taken).
    pub target_rad: f32,
    /// pp: the target in force \[inc\] (base of relative set-points).
    pub target_inc: i32,
    pending: Option<i32>,
    halted: bool,
    /// A target or demand was clamped to the limits (statusword bit 11).
    pub limited: bool,
    /// pv / tq: the (clamped) target the ramp runs to [rad/s] / \[A\].
    pub ramp_target: f32,
    last_target_inc: i32,
    /// csp: a target written after the start is followed (bit 12).
    pub following: bool,
    last_change_us: u64,
    interval_us: u64,
    v_back_rad_s: f32,
    v_est_rad_s: f32,
}

impl Generator {
    /// Start a mode from the actual values (bumpless).
    pub fn start(&mut self, fb: &Feedback, targets: &Targets, now_us: u64) {
        let p = finite_or_zero(fb.position_rad);
        *self = Self {
            demand: Demand {
                pos_rad: p,
                vel_rad_s: finite_or_zero(fb.velocity_rad_s),
                iq_a: finite_or_zero(fb.i_dq_ref_a.q),
                torque_ff_nm: 0.0,
            },
            traj: Trapezoid::plan(p, 0.0, p, 1.0, 1.0),
            target_rad: p,
            target_inc: super::units::rad_to_inc(p),
            last_target_inc: targets.position_inc,
            last_change_us: now_us,
            ..Self::default()
        };
    }

    /// True while a pp move (or its buffered successor) is under way.
    pub fn moving(&self) -> bool {
        self.t_s < self.traj.duration_s() || self.pending.is_some()
    }

    /// pp: a new set-point (controlword bit 4 rising). Absolute, or relative
    /// to the target in force (bit 6); taken now when `immediately` (bit 5)
    /// or when no move runs, else buffered (one deep, a newer replaces it).
    pub fn set_point(&mut self, target_inc: i32, relative: bool, immediately: bool, p: &Params) {
        let base = if relative { self.target_inc } else { 0 };
        let t = base.saturating_add(target_inc);
        if immediately || !self.moving() {
            self.plan(t, p);
        } else {
            self.pending = Some(t);
        }
    }

    fn plan(&mut self, target_inc: i32, p: &Params) {
        self.pending = None;
        self.target_inc = target_inc;
        self.target_rad = inc_to_rad(target_inc);
        let v = uinc_to_rad(p.profile_velocity_inc_s.min(p.max_profile_velocity_inc_s));
        let a = uinc_to_rad(
            p.profile_acceleration_inc_s2
                .min(p.profile_deceleration_inc_s2),
        );
        let d = self.demand;
        self.traj = Trapezoid::plan(d.pos_rad, d.vel_rad_s, self.target_rad, v, a);
        self.t_s = 0.0;
    }

    /// Integrate the demand position over `dt` at the demand velocity.
    fn integrate(&mut self, dt_s: f32) {
        self.demand.pos_rad = finite_or_zero(self.demand.pos_rad + self.demand.vel_rad_s * dt_s);
    }

    /// pp: advance the trapezoid (or the halt ramp).
    pub fn step_pp(&mut self, i: &Inputs) {
        let decel = uinc_to_rad(i.params.profile_deceleration_inc_s2);
        if i.halt {
            self.halted = true;
            self.demand.vel_rad_s = ramp(self.demand.vel_rad_s, 0.0, decel, decel, i.dt_s);
            self.integrate(i.dt_s);
            return;
        }
        if self.halted {
            self.halted = false;
            self.plan(self.target_inc, i.params);
        }
        self.t_s += i.dt_s;
        if self.t_s >= self.traj.duration_s() {
            if let Some(t) = self.pending {
                self.plan(t, i.params);
            }
        }
        let s = self.traj.sample(self.t_s);
        self.demand.pos_rad = s.position;
        self.demand.vel_rad_s = s.velocity;
    }

    /// pv: ramp the velocity to the target (or to 0 on halt).
    pub fn step_pv(&mut self, i: &Inputs) {
        let p = i.params;
        let vmax = uinc_to_rad(p.max_profile_velocity_inc_s).min(i.limits.max_velocity_rad_s);
        let raw = inc_to_rad(i.targets.velocity_inc_s);
        let target = if i.halt { 0.0 } else { clamp_abs(raw, vmax) };
        self.limited = !i.halt && target != raw;
        self.ramp_target = target;
        let (acc, dec) = (
            uinc_to_rad(p.profile_acceleration_inc_s2),
            uinc_to_rad(p.profile_deceleration_inc_s2),
        );
        self.demand.vel_rad_s = ramp(self.demand.vel_rad_s, target, acc, dec, i.dt_s);
        self.integrate(i.dt_s);
    }

    /// The largest q current \[A\]: 0x6072 of the rated current, within the
    /// current limit.
    fn iq_max(i: &Inputs) -> f32 {
        let a = permille_to_amps(f32::from(i.params.max_torque_permille), i.rated_a);
        a.min(i.limits.max_current_a)
    }

    /// tq: ramp the q current to the target torque with 0x6087.
    pub fn step_tq(&mut self, i: &Inputs) {
        let raw = permille_to_amps(f32::from(i.targets.torque_permille), i.rated_a);
        let target = if i.halt {
            0.0
        } else {
            clamp_abs(raw, Self::iq_max(i))
        };
        self.limited = !i.halt && target != raw;
        self.ramp_target = target;
        let slope = permille_to_amps(i.params.torque_slope_permille_s as f32, i.rated_a);
        self.demand.iq_a = ramp(self.demand.iq_a, target, slope, slope, i.dt_s);
    }

    /// csp: the target position (clamped to the range) and a velocity
    /// feed-forward: 0x60B1 when non-zero, else estimated from the last
    /// two different targets over the time between them (extrapolated by
    /// half an interval). The target present when the mode started is
    /// ignored (the actual position is held, statusword bit 12 = 0) until
    /// the master writes a different one: a stale 0x607A does not make the
    /// axis jump at enable.
    pub fn step_csp(&mut self, i: &Inputs) {
        if !self.following && i.targets.position_inc == self.last_target_inc {
            self.demand.vel_rad_s = 0.0;
            return;
        }
        self.following = true;
        let raw = inc_to_rad(i.targets.position_inc);
        let p = clamp_range(raw, i.limits.min_position_rad, i.limits.max_position_rad);
        self.limited = p != raw;
        self.estimate_velocity(i.targets.position_inc, i.now_us);
        let offset = inc_to_rad(i.targets.velocity_offset_inc_s);
        let v = if offset != 0.0 {
            offset
        } else {
            self.v_est_rad_s
        };
        self.demand.pos_rad = finite_or_zero(p);
        self.demand.vel_rad_s = clamp_abs(v, i.limits.max_velocity_rad_s);
    }

    fn estimate_velocity(&mut self, target_inc: i32, now_us: u64) {
        let since = now_us.saturating_sub(self.last_change_us);
        if target_inc != self.last_target_inc {
            let d = target_inc.wrapping_sub(self.last_target_inc) as f32 * RAD_PER_INC;
            let v_back = if (1..=100_000).contains(&since) {
                d / (since as f32 * 1e-6)
            } else {
                0.0
            };
            // The backward difference is the velocity half an interval
            // ago; the command holds for the next interval: extrapolate to
            // its middle (one interval ahead).
            self.v_est_rad_s = finite_or_zero(2.0 * v_back - self.v_back_rad_s);
            self.v_back_rad_s = v_back;
            self.interval_us = since;
            self.last_target_inc = target_inc;
            self.last_change_us = now_us;
        } else if since > self.interval_us.saturating_mul(2) {
            // The targets stopped moving.
            self.v_est_rad_s = 0.0;
            self.v_back_rad_s = 0.0;
        }
    }

    /// csv: target velocity plus 0x60B1, clamped.
    pub fn step_csv(&mut self, i: &Inputs) {
        let t = i.targets;
        let raw = inc_to_rad(t.velocity_inc_s.saturating_add(t.velocity_offset_inc_s));
        self.demand.vel_rad_s = clamp_abs(raw, i.limits.max_velocity_rad_s);
        self.limited = self.demand.vel_rad_s != raw;
        self.integrate(i.dt_s);
    }

    /// cst: target torque plus 0x60B2, limited by 0x6072.
    pub fn step_cst(&mut self, i: &Inputs) {
        let t = i.targets;
        let sum = i32::from(t.torque_permille) + i32::from(t.torque_offset_permille);
        let raw = permille_to_amps(sum as f32, i.rated_a);
        self.demand.iq_a = clamp_abs(raw, Self::iq_max(i));
        self.limited = self.demand.iq_a != raw;
    }

    /// Quick stop: ramp the velocity to 0 with `decel` [rad/s^2]; true once
    /// at 0.
    pub fn step_stop(&mut self, decel: f32, dt_s: f32) -> bool {
        self.demand.vel_rad_s = ramp(self.demand.vel_rad_s, 0.0, decel, decel, dt_s);
        self.integrate(dt_s);
        self.demand.vel_rad_s == 0.0
    }

    /// Run the mode's generator for one update.
    pub fn step(&mut self, mode: OpMode, i: &Inputs) {
        match mode {
            OpMode::ProfilePosition => self.step_pp(i),
            OpMode::ProfileVelocity => self.step_pv(i),
            OpMode::ProfileTorque => self.step_tq(i),
            OpMode::CyclicPosition => self.step_csp(i),
            OpMode::CyclicVelocity => self.step_csv(i),
            OpMode::CyclicTorque => self.step_cst(i),
            OpMode::NoMode => {}
        }
    }

    /// Position modes with the impedance follower: integrate the position
    /// error into the feed-forward torque (bounded by the rated torque).
    pub fn integrate_error(&mut self, mode: OpMode, f: Follower, g: &FollowerGains, i: &Inputs) {
        let position = matches!(mode, OpMode::ProfilePosition | OpMode::CyclicPosition);
        if !(position && f == Follower::Impedance) {
            self.demand.torque_ff_nm = 0.0;
            return;
        }
        let e = finite_or_zero(self.demand.pos_rad - i.fb.position_rad);
        let t = self.demand.torque_ff_nm + g.ki_nm_per_rad_s * e * i.dt_s;
        self.demand.torque_ff_nm = clamp_abs(t, g.torque_max_nm);
    }

    /// The drive command of the demand in `mode`.
    pub fn command(&self, mode: OpMode, f: Follower, g: &FollowerGains, i: &Inputs) -> Command {
        let d = self.demand;
        match mode {
            OpMode::ProfilePosition | OpMode::CyclicPosition => follow(&d, f, g, i),
            OpMode::ProfileVelocity | OpMode::CyclicVelocity => {
                Command::Velocity { rad_s: d.vel_rad_s }
            }
            OpMode::ProfileTorque | OpMode::CyclicTorque => Command::Torque { iq_a: d.iq_a },
            OpMode::NoMode => Command::Disable,
        }
    }
}

/// The position gain used when the drive reports none [(rad/s)/rad].
pub const DEFAULT_KP_PER_S: f32 = 30.0;

/// The follower's gains from the drive: its position gain, and the
/// impedance of its position / speed cascade (`kd = kt kv`, `kp = kd
/// kp_pos`) within the limits' impedance maxima.
pub fn follower_gains<C: DeviceContext>(ctx: &C) -> FollowerGains {
    let positive = |x: Option<f32>| x.filter(|v| v.is_finite() && *v > 0.0);
    let kp = positive(ctx.param(ParamId::PositionKp)).unwrap_or(DEFAULT_KP_PER_S);
    let kv = positive(ctx.param(ParamId::SpeedKp)).unwrap_or(0.0);
    let ki = positive(ctx.param(ParamId::SpeedKi)).unwrap_or(0.0);
    let kt = positive(Some(ctx.torque_constant_nm_per_a())).unwrap_or(0.0);
    let l = ctx.limits();
    let kd = clamp_range(kt * kv, 0.0, l.max_kd_nm_s_per_rad);
    FollowerGains {
        kp_per_s: kp,
        kp_nm_per_rad: clamp_range(kt * (kv * kp + ki), 0.0, l.max_kp_nm_per_rad),
        kd_nm_s_per_rad: kd,
        ki_nm_per_rad_s: finite_or_zero(kt * ki * kp),
        torque_max_nm: finite_or_zero(kt * rated_current_a(&l)),
    }
}

/// A position demand as a drive command (see [`Follower`]).
pub fn follow(d: &Demand, f: Follower, g: &FollowerGains, i: &Inputs) -> Command {
    let vmax = i.limits.max_velocity_rad_s;
    match f {
        Follower::Position => Command::Position { rad: d.pos_rad },
        Follower::Impedance if g.kp_nm_per_rad > 0.0 => Command::Impedance(Impedance {
            position_rad: d.pos_rad,
            velocity_rad_s: clamp_abs(d.vel_rad_s, vmax),
            kp_nm_per_rad: g.kp_nm_per_rad,
            kd_nm_s_per_rad: g.kd_nm_s_per_rad,
            torque_ff_nm: d.torque_ff_nm,
            torque_limit_nm: f32::INFINITY,
        }),
        // Impedance without stiffness allowed (limit 0): velocity.
        Follower::Velocity | Follower::Impedance => {
            let e = finite_or_zero(d.pos_rad - i.fb.position_rad);
            Command::Velocity {
                rad_s: clamp_abs(d.vel_rad_s + g.kp_per_s * e, vmax),
            }
        }
    }
}
