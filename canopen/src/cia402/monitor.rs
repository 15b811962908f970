//! Windows with a time: target reached (0x6067/0x6068, 0x606D/0x606E) and
//! following error (0x6065/0x6066), and the 0x603F error code of a drive
//! fault.
//!
//! ```
//! use foc_canopen::cia402::monitor::WindowTimer;
//! let mut w = WindowTimer::new();
//! assert!(!w.held(true, 0, 10));        // inside since 0 us
//! assert!(w.held(true, 10_000, 10));    // for 10 ms
//! assert!(!w.held(false, 11_000, 10));  // left: restarts
//! ```

use foc_core::control::Feedback;
use foc_protocol::device::DeviceContext;

use super::state::state_bits;
use super::units::{amps_to_permille, rad_to_inc, rated_current_a, volts_to_mv};
use super::{OpMode, State};

/// How long a condition has held without a break.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WindowTimer {
    since_us: Option<u64>,
}

impl WindowTimer {
    /// Not holding.
    pub const fn new() -> Self {
        Self { since_us: None }
    }

    /// Forget (the condition starts again).
    pub fn reset(&mut self) {
        self.since_us = None;
    }

    /// `cond` now: true once it has held for at least `time_ms`.
    pub fn held(&mut self, cond: bool, now_us: u64, time_ms: u16) -> bool {
        cond && self.elapsed_us(cond, now_us) >= u64::from(time_ms) * 1000
    }

    /// `cond` now: true once it has held for longer than `time_ms`
    /// (a time-out: 0 ms trips at the first sample outside).
    pub fn exceeded(&mut self, cond: bool, now_us: u64, time_ms: u16) -> bool {
        cond && self.elapsed_us(cond, now_us) >= u64::from(time_ms) * 1000
    }

    fn elapsed_us(&mut self, cond: bool, now_us: u64) -> u64 {
        if !cond {
            self.since_us = None;
            return 0;
        }
        let since = *self.since_us.get_or_insert(now_us);
        now_us.saturating_sub(since)
    }
}

/// The following error window check: `|error| > window`, with 0xFFFFFFFF
/// switching the check off.
pub fn outside_following_window(error_inc: i32, window_inc: u32) -> bool {
    window_inc != u32::MAX && error_inc.unsigned_abs() > window_inc
}

impl super::Cia402 {
    /// Following error (pp, csp) and target reached, after the demand of
    /// this update.
    pub(super) fn monitor(&mut self, now_us: u64, fb: &Feedback) {
        let actual = rad_to_inc(fb.position_rad);
        let demand = rad_to_inc(self.gen.demand.pos_rad);
        let p = self.params;
        if matches!(self.mode, OpMode::ProfilePosition | OpMode::CyclicPosition) {
            let err = demand.saturating_sub(actual);
            let out = outside_following_window(err, p.following_error_window_inc);
            if self
                .ferr_timer
                .exceeded(out, now_us, p.following_error_timeout_ms)
            {
                self.following_error = true;
                self.profile_fault = Some(super::FOLLOWING_ERROR_CODE);
            }
        }
        let halt = self.cw & super::state::CW_HALT != 0;
        let g = &self.gen;
        let (inside, time_ms) = match self.mode {
            OpMode::ProfilePosition if halt => (g.demand.vel_rad_s == 0.0, 0),
            OpMode::ProfilePosition => {
                let e = g.target_inc.saturating_sub(actual).unsigned_abs();
                (
                    !g.moving() && e <= p.position_window_inc,
                    p.position_window_time_ms,
                )
            }
            OpMode::ProfileVelocity => {
                let e = rad_to_inc(fb.velocity_rad_s - g.ramp_target).unsigned_abs();
                let at = g.demand.vel_rad_s == g.ramp_target;
                (
                    at && e <= u32::from(p.velocity_window_inc_s),
                    p.velocity_window_time_ms,
                )
            }
            OpMode::ProfileTorque => (g.demand.iq_a == g.ramp_target, 0),
            _ => (false, 0),
        };
        self.target_reached = self.reached.held(inside, now_us, time_ms);
    }

    /// Refresh the actual values and the statusword.
    pub(super) fn refresh<C: DeviceContext>(&mut self, ctx: &C) {
        let fb = ctx.feedback();
        let rated = rated_current_a(&ctx.limits());
        let enabled = self.bridge_asked();
        let a = &mut self.actuals;
        a.position_inc = rad_to_inc(fb.position_rad);
        a.velocity_inc_s = rad_to_inc(fb.velocity_rad_s);
        a.torque_permille = amps_to_permille(fb.i_dq_a.q, rated);
        a.current_permille = a.torque_permille;
        a.dc_link_mv = volts_to_mv(fb.v_bus_v);
        a.mode_display = self.mode as i8;
        let d = self.gen.demand;
        (a.position_demand_inc, a.velocity_demand_inc_s) = if enabled {
            (rad_to_inc(d.pos_rad), rad_to_inc(d.vel_rad_s))
        } else {
            (a.position_inc, 0)
        };
        a.following_error_inc = a.position_demand_inc.saturating_sub(a.position_inc);
        let drive = ctx.faults().1.map(crate::emcy::fault_code);
        a.error_code = self.profile_fault.or(drive).unwrap_or(0);
        self.actuals.statusword = self.statusword(&fb);
    }

    /// Operation enabled or quick stop active: the profile drives the
    /// bridge.
    fn bridge_asked(&self) -> bool {
        matches!(self.state, State::OperationEnabled | State::QuickStopActive)
    }

    /// The statusword of the state, the mode and the monitors.
    fn statusword(&self, fb: &Feedback) -> u16 {
        let enabled = self.bridge_asked();
        let op = self.state == State::OperationEnabled;
        let iq_sat = fb.current_limit_a > 0.0 && fb.i_dq_ref_a.q.abs() >= fb.current_limit_a;
        let limited = self.gen.limited || fb.voltage_limited || iq_sat;
        let bits = [
            (fb.v_bus_v > 0.0, super::STATUS_VOLTAGE_ENABLED),
            (self.warning, super::STATUS_WARNING),
            (enabled && self.target_reached, super::STATUS_TARGET_REACHED),
            (enabled && limited, super::STATUS_INTERNAL_LIMIT),
            (op && self.bit12(fb), super::STATUS_MODE_12),
            (self.following_error, super::STATUS_MODE_13),
        ];
        let qs = self.cw & 0x04 != 0;
        bits.iter().filter(|(on, _)| *on).fold(
            state_bits(self.state, qs) | super::STATUS_REMOTE,
            |sw, (_, b)| sw | b,
        )
    }

    /// Bit 12: pp set-point acknowledge, pv speed 0 (|v| within 0x606D),
    /// csp / csv / cst target followed (csp: once a new target came).
    fn bit12(&self, fb: &Feedback) -> bool {
        match self.mode {
            OpMode::ProfilePosition => self.ack,
            OpMode::ProfileVelocity => {
                rad_to_inc(fb.velocity_rad_s).unsigned_abs()
                    <= u32::from(self.params.velocity_window_inc_s)
            }
            OpMode::CyclicPosition => self.gen.following,
            OpMode::CyclicVelocity | OpMode::CyclicTorque => true,
            OpMode::ProfileTorque | OpMode::NoMode => false,
        }
    }
}
