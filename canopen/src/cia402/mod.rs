//! The CiA 402 drive profile: the power state machine (controlword 0x6040,
//! statusword 0x6041), modes of operation (0x6060 / 0x6061) and the
//! profile's targets, actual values and parameters, mapped onto the
//! drive's [`DeviceContext`].
//!
//! This module is the contract between the CiA 301 node (object
//! dictionary, SDO, PDO: `crate::node`, `crate::od`) and the profile: the
//! node stores nothing of the profile; it reads and writes the plain fields
//! of [`Targets`], [`Params`] and [`Actuals`] (already range-checked against
//! the object dictionary's limits) and calls the `Cia402` methods below.
//!
//! Units (the factors, documented in the book's CANopen chapter and the EDS):
//! - position: increments, [`INC_PER_REV`] per motor (rotor) mechanical
//!   revolution (0x608F); velocity: increments/s; acceleration:
//!   increments/s^2;
//! - torque: per mille of the rated torque (0x6076, mN m); current: per
//!   mille of the rated current (0x6075, mA);
//! - DC-link voltage: mV (0x6079).

use foc_core::control::{admit, Command, Fault, Mode};
use foc_protocol::device::DeviceContext;
use foc_protocol::joint::limits_in_force;

use crate::Abort;

pub mod modes;
pub mod monitor;
pub mod state;
pub mod units;

#[cfg(test)]
mod tests;

use modes::{follower_gains, FollowerGains, Generator, Inputs, DEFAULT_KP_PER_S};
pub use modes::{Demand, Follower};
use monitor::WindowTimer;
use state::{
    CwCommand, CW_CHANGE_IMMEDIATELY, CW_FAULT_RESET, CW_HALT, CW_NEW_SETPOINT, CW_RELATIVE,
};
use units::{finite_or_zero, rated_current_a, uinc_to_rad};

/// Position increments per motor mechanical revolution (0x608F sub 1,
/// with sub 2 = 1 revolution).
pub const INC_PER_REV: i32 = 65_536;

/// The power state (CiA 402 §6.2, figure 7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum State {
    /// Start-up (the drive's offset calibration and sensor check).
    NotReadyToSwitchOn,
    /// Bridge off, switching on not allowed until "shutdown".
    SwitchOnDisabled,
    /// Bridge off, ready.
    ReadyToSwitchOn,
    /// Bridge off, switched on (high voltage present).
    SwitchedOn,
    /// Bridge on, the mode of operation runs.
    OperationEnabled,
    /// Quick stop: decelerating (or holding, per 0x605A).
    QuickStopActive,
    /// A fault was detected: the reaction runs (bridge off).
    FaultReactionActive,
    /// Fault: bridge off until fault reset.
    Fault,
}

/// Modes of operation (0x6060 / 0x6061).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(i8)]
pub enum OpMode {
    /// No mode selected (bridge cannot be enabled).
    NoMode = 0,
    /// Profile position (pp).
    ProfilePosition = 1,
    /// Profile velocity (pv).
    ProfileVelocity = 3,
    /// Profile torque (tq).
    ProfileTorque = 4,
    /// Cyclic synchronous position (csp).
    CyclicPosition = 8,
    /// Cyclic synchronous velocity (csv).
    CyclicVelocity = 9,
    /// Cyclic synchronous torque (cst).
    CyclicTorque = 10,
}

impl OpMode {
    /// True for the velocity modes (pv, csv): the only ones a drive
    /// running without its angle sensor takes (design §27).
    pub const fn is_velocity(self) -> bool {
        matches!(self, Self::ProfileVelocity | Self::CyclicVelocity)
    }

    /// From the 0x6060 value; `None` for an unsupported mode.
    pub const fn from_i8(v: i8) -> Option<Self> {
        match v {
            0 => Some(Self::NoMode),
            1 => Some(Self::ProfilePosition),
            3 => Some(Self::ProfileVelocity),
            4 => Some(Self::ProfileTorque),
            8 => Some(Self::CyclicPosition),
            9 => Some(Self::CyclicVelocity),
            10 => Some(Self::CyclicTorque),
            _ => None,
        }
    }

    /// 0x6502 "supported drive modes": bit `mode - 1` for each mode.
    pub const SUPPORTED_MASK: u32 = (1 << 0) | (1 << 2) | (1 << 3) | (1 << 7) | (1 << 8) | (1 << 9);
}

/// Values the master writes that take effect as commands (RPDO-mappable).
/// The controlword and the mode of operation are written through
/// [`Cia402::write_controlword`] / [`Cia402::write_mode`] (they act at once);
/// the targets here are plain fields, taken at the next [`Cia402::update`]
/// (synchronous RPDOs are applied at the SYNC, before the update).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Targets {
    /// 0x607A target position \[inc\].
    pub position_inc: i32,
    /// 0x60FF target velocity [inc/s].
    pub velocity_inc_s: i32,
    /// 0x6071 target torque [per mille of rated torque].
    pub torque_permille: i16,
    /// 0x60B1 velocity offset (csp / csv feed-forward) [inc/s].
    pub velocity_offset_inc_s: i32,
    /// 0x60B2 torque offset (feed-forward) [per mille].
    pub torque_offset_permille: i16,
}

/// Profile parameters (SDO-written; range-checked by the object
/// dictionary, then by [`Cia402::check_params`] as a whole).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Params {
    /// 0x6065 following error window \[inc\] (0xFFFFFFFF: off).
    pub following_error_window_inc: u32,
    /// 0x6066 following error time out \[ms\].
    pub following_error_timeout_ms: u16,
    /// 0x6067 position window \[inc\] (target reached, pp).
    pub position_window_inc: u32,
    /// 0x6068 position window time \[ms\].
    pub position_window_time_ms: u16,
    /// 0x606D velocity window [inc/s] (target reached, pv).
    pub velocity_window_inc_s: u16,
    /// 0x606E velocity window time \[ms\].
    pub velocity_window_time_ms: u16,
    /// 0x6072 max torque [per mille of rated torque].
    pub max_torque_permille: u16,
    /// 0x607F max profile velocity [inc/s].
    pub max_profile_velocity_inc_s: u32,
    /// 0x6081 profile velocity [inc/s] (pp).
    pub profile_velocity_inc_s: u32,
    /// 0x6083 profile acceleration [inc/s^2].
    pub profile_acceleration_inc_s2: u32,
    /// 0x6084 profile deceleration [inc/s^2].
    pub profile_deceleration_inc_s2: u32,
    /// 0x6085 quick stop deceleration [inc/s^2].
    pub quick_stop_deceleration_inc_s2: u32,
    /// 0x605A quick stop option code.
    pub quick_stop_option: i16,
    /// 0x6007 abort connection option code (heartbeat / bus-off loss).
    pub abort_connection_option: i16,
    /// 0x6087 torque slope [per mille/s] (tq).
    pub torque_slope_permille_s: u32,
}

/// Actual values the node reads (TPDO-mappable), refreshed by
/// [`Cia402::update`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Actuals {
    /// 0x6041 statusword.
    pub statusword: u16,
    /// 0x6061 modes of operation display.
    pub mode_display: i8,
    /// 0x6064 position actual value \[inc\].
    pub position_inc: i32,
    /// 0x6062 position demand value \[inc\].
    pub position_demand_inc: i32,
    /// 0x606C velocity actual value [inc/s].
    pub velocity_inc_s: i32,
    /// 0x606B velocity demand value [inc/s].
    pub velocity_demand_inc_s: i32,
    /// 0x6077 torque actual value [per mille].
    pub torque_permille: i16,
    /// 0x6078 current actual value [per mille of rated current].
    pub current_permille: i16,
    /// 0x60F4 following error actual value \[inc\].
    pub following_error_inc: i32,
    /// 0x603F error code (the last fault's EMCY code, 0 when none).
    pub error_code: u16,
    /// 0x6079 DC link circuit voltage \[mV\].
    pub dc_link_mv: u32,
}

impl Targets {
    /// All zero.
    pub const ZERO: Self = Self {
        position_inc: 0,
        velocity_inc_s: 0,
        torque_permille: 0,
        velocity_offset_inc_s: 0,
        torque_offset_permille: 0,
    };
}

impl Params {
    /// The defaults (also the EDS's default values).
    pub const DEFAULT: Self = Self {
        following_error_window_inc: INC_PER_REV as u32 / 4,
        following_error_timeout_ms: 10,
        position_window_inc: 100,
        position_window_time_ms: 10,
        velocity_window_inc_s: 1_000,
        velocity_window_time_ms: 10,
        max_torque_permille: 1_000,
        max_profile_velocity_inc_s: 50 * INC_PER_REV as u32,
        profile_velocity_inc_s: 10 * INC_PER_REV as u32,
        profile_acceleration_inc_s2: 100 * INC_PER_REV as u32,
        profile_deceleration_inc_s2: 100 * INC_PER_REV as u32,
        quick_stop_deceleration_inc_s2: 200 * INC_PER_REV as u32,
        quick_stop_option: 2,
        abort_connection_option: 1,
        torque_slope_permille_s: 10_000,
    };
}

impl Actuals {
    /// Before the first update: not ready to switch on, remote.
    pub const INIT: Self = Self {
        statusword: STATUS_REMOTE,
        mode_display: 0,
        position_inc: 0,
        position_demand_inc: 0,
        velocity_inc_s: 0,
        velocity_demand_inc_s: 0,
        torque_permille: 0,
        current_permille: 0,
        following_error_inc: 0,
        error_code: 0,
        dc_link_mv: 0,
    };
}

/// Statusword bit 4: voltage enabled.
pub const STATUS_VOLTAGE_ENABLED: u16 = 1 << 4;
/// Statusword bit 7: warning.
pub const STATUS_WARNING: u16 = 1 << 7;
/// Statusword bit 9: remote (always set: the controlword is obeyed).
pub const STATUS_REMOTE: u16 = 1 << 9;
/// Statusword bit 10: target reached.
pub const STATUS_TARGET_REACHED: u16 = 1 << 10;
/// Statusword bit 11: internal limit active.
pub const STATUS_INTERNAL_LIMIT: u16 = 1 << 11;
/// Statusword bit 12: mode specific (pp set-point acknowledge, pv speed 0,
/// csp / csv / cst target value followed).
pub const STATUS_MODE_12: u16 = 1 << 12;
/// Statusword bit 13: mode specific (pp / csp following error).
pub const STATUS_MODE_13: u16 = 1 << 13;
/// The profile's own fault: following error (EMCY / 0x603F code).
pub const FOLLOWING_ERROR_CODE: u16 = 0x8611;

/// A quick stop in progress (the option taken when it started).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Stop {
    option: i16,
    /// When the ramp reached 0 \[us\].
    ramp_done_us: Option<u64>,
}

/// Options 1 / 2: after the ramp, the longest wait for standstill
/// (|velocity| within 0x606D) before the bridge is switched off \[us\].
pub const STANDSTILL_TIMEOUT_US: u64 = 200_000;

/// The profile: state machine, mode and values of one axis.
///
/// Behaviour beyond the standard's text (see also the book's CANopen chapter):
/// - enabling operation (transition 4) while the drive is not calibrated,
///   faulted, starting, or with no mode selected is refused: the state stays
///   (or becomes, from ready to switch on with `0x000F`) switched on and the
///   warning bit 7 is set until the next accepted transition;
/// - a command the drive's rules refuse in operation enabled (e.g. the
///   calibration was withdrawn) disables the bridge: switched on, warning;
/// - targets beyond the limits in force are clamped to them (bit 11);
/// - a non-finite value from the drive reads as 0 (the drive latches its
///   own `NonFinite` fault, which the profile then follows to Fault);
/// - 0x6007 = 1 (fault) acts in ready to switch on, switched on, operation
///   enabled and quick stop active (not while switch on disabled);
/// - halt (bit 8) acts in pp (profile deceleration, then hold; the move
///   resumes on release), pv (ramp to 0) and tq (torque to 0 with the
///   slope); the cyclic modes ignore it (the master owns the trajectory);
/// - csp ignores the target present when the mode starts (holds the
///   actual position, bit 12 = 0) until a different one is written;
/// - quick stop with 0x605A = 1 / 2 switches the bridge off once the ramp
///   is done and the rotor is within the velocity window 0x606D, at most
///   [`STANDSTILL_TIMEOUT_US`] after the ramp;
/// - the rated current (0x6075) is the drive's current limit, the rated
///   torque (0x6076) `kt` times it: torque and current per mille are the
///   same number (the q current over the current limit);
/// - pp plans its own trapezoid (`foc_core`'s planner, in the profile):
///   the drive's trajectory limits can only be set while disabled
///   (`Status::check_config`, [`foc_protocol::device::Refusal::NotDisabled`]),
///   so 0x6081 / 0x6083 / 0x6084 could not change during a move; the
///   trapezoid is symmetric, with the smaller of 0x6083 and 0x6084.
#[derive(Clone, Debug)]
pub struct Cia402 {
    /// Targets (written by SDO / RPDO).
    pub targets: Targets,
    /// Parameters (written by SDO).
    pub params: Params,
    /// Actual values (read by SDO / TPDO).
    pub actuals: Actuals,
    state: State,
    mode: OpMode,
    requested: i8,
    cw: u16,
    profile_fault: Option<u16>,
    warning: bool,
    /// A fault reset waiting for the drive's clear: the drive period at
    /// the reset.
    reset_pending: Option<u32>,
    last_us: Option<u64>,
    gen: Generator,
    follower: Follower,
    gains: FollowerGains,
    reached: WindowTimer,
    ferr_timer: WindowTimer,
    following_error: bool,
    target_reached: bool,
    ack: bool,
    stop: Option<Stop>,
}

impl Cia402 {
    /// At boot: not ready to switch on, no mode, parameters at their
    /// defaults.
    pub fn new() -> Self {
        Self {
            targets: Targets::ZERO,
            params: Params::DEFAULT,
            actuals: Actuals::INIT,
            state: State::NotReadyToSwitchOn,
            mode: OpMode::NoMode,
            requested: 0,
            cw: 0,
            profile_fault: None,
            warning: false,
            reset_pending: None,
            last_us: None,
            gen: Generator::default(),
            follower: Follower::Impedance,
            gains: FollowerGains {
                kp_per_s: DEFAULT_KP_PER_S,
                kp_nm_per_rad: 0.0,
                kd_nm_s_per_rad: 0.0,
                ki_nm_per_rad_s: 0.0,
                torque_max_nm: 0.0,
            },
            reached: WindowTimer::new(),
            ferr_timer: WindowTimer::new(),
            following_error: false,
            target_reached: false,
            ack: false,
            stop: None,
        }
    }

    /// The power state.
    pub fn state(&self) -> State {
        self.state
    }

    /// The mode in force (0x6061).
    pub fn mode(&self) -> OpMode {
        self.mode
    }

    /// The last controlword written.
    pub fn controlword(&self) -> u16 {
        self.cw
    }

    /// The mode requested (0x6060).
    pub fn requested_mode(&self) -> i8 {
        self.requested
    }

    /// How position demands go to the drive (default
    /// [`Follower::Impedance`]).
    pub fn follower(&self) -> Follower {
        self.follower
    }

    /// Choose how position demands go to the drive (taken at the next
    /// update; a manufacturer-specific setting).
    pub fn set_follower(&mut self, f: Follower) {
        self.follower = f;
    }

    /// The profile's demand (SI, rotor frame).
    pub fn demand(&self) -> Demand {
        self.gen.demand
    }

    /// Write 0x6040 (SDO or RPDO): run the state machine's transition now
    /// (shutdown, switch on, enable operation, disable voltage, quick stop,
    /// disable operation, fault reset on the rising edge of bit 7; new
    /// set-point on the rising edge of bit 4 in pp; halt bit 8). Refused
    /// transitions leave the state unchanged (not an abort: CiA 402).
    /// [`Self::actuals`] (the statusword) follow at once.
    pub fn write_controlword<C: DeviceContext>(&mut self, cw: u16, now_us: u64, ctx: &mut C) {
        self.take_controlword(cw, now_us, ctx);
        self.refresh(ctx);
    }

    /// The controlword's transition and pp set-point.
    fn take_controlword<C: DeviceContext>(&mut self, cw: u16, now_us: u64, ctx: &mut C) {
        let rising = cw & !self.cw;
        self.cw = cw;
        if rising & CW_FAULT_RESET != 0 {
            self.fault_reset(ctx);
            return;
        }
        if let Some(c) = state::decode(cw) {
            self.command(c, now_us, ctx);
        }
        if cw & CW_NEW_SETPOINT == 0 {
            self.ack = false;
        }
        let pp = self.state == State::OperationEnabled && self.mode == OpMode::ProfilePosition;
        if pp && rising & CW_NEW_SETPOINT != 0 {
            let (rel, now) = (cw & CW_RELATIVE != 0, cw & CW_CHANGE_IMMEDIATELY != 0);
            self.gen
                .set_point(self.targets.position_inc, rel, now, &self.params);
            self.reached.reset();
            self.ack = true;
        }
    }

    /// A device control command: the table's transition, if any.
    fn command<C: DeviceContext>(&mut self, c: CwCommand, now_us: u64, ctx: &mut C) {
        let from = self.state;
        let Some(to) = state::next(from, c) else {
            return;
        };
        let stop_holds = matches!(self.stop, Some(Stop { option: 5 | 6, .. }));
        if from == State::QuickStopActive && to == State::OperationEnabled && !stop_holds {
            return;
        }
        if to == State::OperationEnabled && !self.may_enable(ctx) {
            self.warning = true;
            if from == State::ReadyToSwitchOn {
                self.state = State::SwitchedOn;
            }
            return;
        }
        self.warning = false;
        self.enter(to, now_us, ctx);
    }

    /// Operation may be enabled: a mode (a velocity mode when the drive
    /// runs without its angle sensor), the drive started, calibrated and
    /// not faulted.
    fn may_enable<C: DeviceContext>(&self, ctx: &C) -> bool {
        let st = ctx.status();
        self.mode != OpMode::NoMode
            && (self.mode.is_velocity() || !st.angle_only_in_motion())
            && st.running
            && ctx.is_calibrated()
            && ctx.faults().0.is_empty()
            && self.profile_fault.is_none()
    }

    /// Enter `to` with its entry action (start the mode, start the quick
    /// stop, or disable the bridge when leaving operation).
    fn enter<C: DeviceContext>(&mut self, to: State, now_us: u64, ctx: &mut C) {
        let from = self.state;
        self.state = to;
        match to {
            State::OperationEnabled => {
                self.stop = None;
                self.start_mode(now_us, ctx);
                self.update(now_us, ctx);
            }
            State::QuickStopActive => self.start_quick_stop(now_us, ctx),
            _ if matches!(from, State::OperationEnabled | State::QuickStopActive) => {
                self.stop = None;
                self.disable(ctx);
            }
            _ => {}
        }
    }

    /// Start the mode in force from the actual values (bumpless).
    fn start_mode<C: DeviceContext>(&mut self, now_us: u64, ctx: &C) {
        let fb = ctx.feedback();
        self.gen.start(&fb, &self.targets, now_us);
        self.gains = follower_gains(ctx);
        self.reached.reset();
        self.ferr_timer.reset();
        self.following_error = false;
        self.target_reached = false;
        self.ack = false;
    }

    /// Quick stop (0x605A): 0 disables at once; 1, 2, 5, 6 ramp to 0.
    fn start_quick_stop<C: DeviceContext>(&mut self, now_us: u64, ctx: &mut C) {
        let option = self.params.quick_stop_option;
        if option == 0 {
            self.state = State::SwitchOnDisabled;
            self.disable(ctx);
            return;
        }
        self.stop = Some(Stop {
            option,
            ramp_done_us: None,
        });
        self.gen.demand.vel_rad_s = finite_or_zero(ctx.feedback().velocity_rad_s);
        self.target_reached = false;
        self.update(now_us, ctx);
    }

    /// Post `Disable` (always admitted).
    fn disable<C: DeviceContext>(&mut self, ctx: &mut C) {
        let _ = ctx.post(Command::Disable);
    }

    /// Post `cmd` if the drive's rules admit it (a sensorless drive takes
    /// no torque or position command): false when refused.
    fn post<C: DeviceContext>(&mut self, cmd: Command, ctx: &mut C) -> bool {
        let limits = limits_in_force(&ctx.limits(), &ctx.joint());
        let st = ctx.status();
        admit(&cmd, &limits, st.faulted, st.calibrated).is_ok()
            && !(st.angle_only_in_motion() && cmd.mode().needs_angle_sensor())
            && ctx.post(cmd).is_ok()
    }

    /// Fault reset (rising edge of bit 7): only in Fault; switch on disabled
    /// once the drive's faults are clear.
    fn fault_reset<C: DeviceContext>(&mut self, ctx: &mut C) {
        self.warning = false;
        if self.state != State::Fault {
            return;
        }
        ctx.clear_faults();
        self.profile_fault = None;
        self.following_error = false;
        if ctx.faults().0.is_empty() {
            self.state = State::SwitchOnDisabled;
        } else {
            self.reset_pending = Some(ctx.feedback().period);
        }
    }

    /// Write 0x6060: an unsupported value is [`Abort::InvalidValue`] and
    /// changes nothing; a supported one takes effect now (in operation
    /// enabled: the new mode starts from the actual values, bumplessly;
    /// "no mode" disables operation: switched on).
    pub fn write_mode<C: DeviceContext>(
        &mut self,
        mode: i8,
        now_us: u64,
        ctx: &mut C,
    ) -> Result<(), Abort> {
        let m = OpMode::from_i8(mode).ok_or(Abort::InvalidValue)?;
        self.requested = mode;
        if m == self.mode {
            return Ok(());
        }
        self.mode = m;
        if self.state == State::OperationEnabled {
            if m == OpMode::NoMode || (!m.is_velocity() && ctx.status().angle_only_in_motion()) {
                // (Without the angle sensor: velocity modes only.)
                self.warning = m != OpMode::NoMode;
                self.enter(State::SwitchedOn, now_us, ctx);
            } else {
                self.start_mode(now_us, ctx);
            }
        }
        self.refresh(ctx);
        Ok(())
    }

    /// Check a whole parameter set before it replaces [`Self::params`]
    /// (cross-field rules): profile velocity <= max profile velocity
    /// ([`Abort::ValueTooHigh`]); accelerations, decelerations, the max
    /// profile velocity and the torque slope non-zero, 0x605A in
    /// {0, 1, 2, 5, 6}, 0x6007 in 0..=3 ([`Abort::InvalidValue`]).
    pub fn check_params(&self, p: &Params) -> Result<(), Abort> {
        if p.profile_velocity_inc_s > p.max_profile_velocity_inc_s {
            return Err(Abort::ValueTooHigh);
        }
        let rates = [
            p.max_profile_velocity_inc_s,
            p.profile_acceleration_inc_s2,
            p.profile_deceleration_inc_s2,
            p.quick_stop_deceleration_inc_s2,
            p.torque_slope_permille_s,
        ];
        if rates.contains(&0)
            || !matches!(p.quick_stop_option, 0 | 1 | 2 | 5 | 6)
            || !(0..=3).contains(&p.abort_connection_option)
        {
            return Err(Abort::InvalidValue);
        }
        Ok(())
    }

    /// At every SYNC (after the synchronous RPDOs were applied) and at every
    /// tick of the node (at least 1 kHz): follow the drive's faults and
    /// start-up (fault reaction -> fault; not ready -> switch on disabled),
    /// post the command of the mode in force from the targets (validated
    /// against the limits in force before posting; posted at every update
    /// in operation enabled and quick stop active, which also keeps the
    /// drive's command timeout from firing), work out following error /
    /// target reached / quick stop, refresh [`Self::actuals`].
    pub fn update<C: DeviceContext>(&mut self, now_us: u64, ctx: &mut C) {
        let dt_s = self.elapsed_s(now_us);
        self.supervise(ctx);
        match self.state {
            State::OperationEnabled => self.run(dt_s, now_us, ctx),
            State::QuickStopActive => self.run_stop(dt_s, now_us, ctx),
            _ => {}
        }
        self.refresh(ctx);
    }

    /// Seconds since the last update (0 the first time, at most 0.1 s).
    fn elapsed_s(&mut self, now_us: u64) -> f32 {
        let dt = self.last_us.map_or(0, |t| now_us.saturating_sub(t));
        self.last_us = Some(now_us);
        dt.min(100_000) as f32 * 1e-6
    }

    /// Start-up, faults, fault reaction and fault reset.
    fn supervise<C: DeviceContext>(&mut self, ctx: &mut C) {
        let st = ctx.status();
        let faulted = st.faulted || !ctx.faults().0.is_empty();
        match self.state {
            State::Fault if self.reset_pending.is_some() && !faulted => {
                self.reset_pending = None;
                self.state = State::SwitchOnDisabled;
            }
            // The drive clears in its next period: still faulted two
            // periods after the reset, the fault stayed (or came back), and
            // only a new fault-reset edge may leave Fault.
            State::Fault
                if self
                    .reset_pending
                    .is_some_and(|p0| ctx.feedback().period.wrapping_sub(p0) >= 2) =>
            {
                self.reset_pending = None;
            }
            State::Fault => {}
            State::FaultReactionActive => {
                self.disable(ctx);
                if ctx.mode() == Mode::Disabled {
                    self.state = State::Fault;
                }
            }
            _ if faulted || self.profile_fault.is_some() => self.fault_reaction(ctx),
            State::NotReadyToSwitchOn if st.running => self.state = State::SwitchOnDisabled,
            State::NotReadyToSwitchOn => {}
            _ if !st.running => {
                self.enter(State::NotReadyToSwitchOn, 0, ctx);
            }
            _ => {}
        }
    }

    /// A fault: bridge off (the drive did it already for its own faults).
    fn fault_reaction<C: DeviceContext>(&mut self, ctx: &mut C) {
        self.state = State::FaultReactionActive;
        self.stop = None;
        self.reset_pending = None;
        self.disable(ctx);
    }

    /// Operation enabled: the mode's demand, the monitors, the command.
    fn run<C: DeviceContext>(&mut self, dt_s: f32, now_us: u64, ctx: &mut C) {
        let limits = limits_in_force(&ctx.limits(), &ctx.joint());
        let fb = ctx.feedback();
        let i = Inputs {
            targets: &self.targets,
            params: &self.params,
            limits: &limits,
            rated_a: rated_current_a(&ctx.limits()),
            fb: &fb,
            dt_s,
            now_us,
            halt: self.cw & CW_HALT != 0,
        };
        self.gen.step(self.mode, &i);
        self.gen
            .integrate_error(self.mode, self.follower, &self.gains, &i);
        let cmd = self.gen.command(self.mode, self.follower, &self.gains, &i);
        self.monitor(now_us, &fb);
        if self.profile_fault.is_some() {
            self.fault_reaction(ctx);
        } else if !self.post(cmd, ctx) {
            self.warning = true;
            self.state = State::SwitchedOn;
            self.disable(ctx);
        }
    }

    /// Quick stop active: ramp to 0, then (0x605A 1, 2) disable at
    /// standstill, or (5, 6) hold velocity 0.
    fn run_stop<C: DeviceContext>(&mut self, dt_s: f32, now_us: u64, ctx: &mut C) {
        let Some(mut stop) = self.stop else {
            return;
        };
        let p = &self.params;
        let decel = match stop.option {
            1 | 5 => p.profile_deceleration_inc_s2,
            _ => p.quick_stop_deceleration_inc_s2,
        };
        let done = self.gen.step_stop(uinc_to_rad(decel), dt_s);
        self.target_reached = done;
        if done && stop.ramp_done_us.is_none() {
            stop.ramp_done_us = Some(now_us);
            self.stop = Some(stop);
        }
        if matches!(stop.option, 1 | 2) && self.standstill(stop, now_us, ctx) {
            self.enter(State::SwitchOnDisabled, now_us, ctx);
        } else if !self.post(
            Command::Velocity {
                rad_s: self.gen.demand.vel_rad_s,
            },
            ctx,
        ) {
            self.warning = true;
            self.enter(State::SwitchOnDisabled, now_us, ctx);
        }
    }

    /// The ramp is done and the rotor within the velocity window (or the
    /// wait for it timed out).
    fn standstill<C: DeviceContext>(&self, stop: Stop, now_us: u64, ctx: &C) -> bool {
        let Some(t) = stop.ramp_done_us else {
            return false;
        };
        let v = units::rad_to_inc(ctx.feedback().velocity_rad_s).unsigned_abs();
        v <= u32::from(self.params.velocity_window_inc_s)
            || now_us.saturating_sub(t) >= STANDSTILL_TIMEOUT_US
    }

    /// The connection to the master was lost (heartbeat consumer timeout,
    /// bus-off): react per 0x6007 (0 none, 1 fault, 2 disable voltage,
    /// 3 quick stop). The statusword follows at once. A fault reports [`Fault::CommandTimeout`] to the drive
    /// (bridge off at once) and goes to fault reaction active.
    pub fn connection_lost<C: DeviceContext>(&mut self, now_us: u64, ctx: &mut C) {
        let live = matches!(
            self.state,
            State::ReadyToSwitchOn
                | State::SwitchedOn
                | State::OperationEnabled
                | State::QuickStopActive
        );
        match self.params.abort_connection_option {
            1 if live => {
                ctx.report_fault(Fault::CommandTimeout);
                self.fault_reaction(ctx);
            }
            2 => self.command(CwCommand::DisableVoltage, now_us, ctx),
            3 => self.command(CwCommand::QuickStop, now_us, ctx),
            _ => {}
        }
        self.refresh(ctx);
    }

    /// The profile's own fault (following error) latched in this node, if
    /// any, as its EMCY code (0x8611): the node sends the EMCY and the
    /// drive is disabled; cleared by fault reset.
    pub fn profile_fault(&self) -> Option<u16> {
        self.profile_fault
    }
}

impl Default for Cia402 {
    fn default() -> Self {
        Self::new()
    }
}
