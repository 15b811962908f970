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
//! Units (the factors, documented in the README and the EDS):
//! - position: increments, [`INC_PER_REV`] per motor (rotor) mechanical
//!   revolution (0x608F); velocity: increments/s; acceleration:
//!   increments/s^2;
//! - torque: per mille of the rated torque (0x6076, mN m); current: per
//!   mille of the rated current (0x6075, mA);
//! - DC-link voltage: mV (0x6079).

use foc_protocol::device::DeviceContext;

use crate::Abort;

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
    /// 0x607A target position [inc].
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
    /// 0x6065 following error window [inc] (0xFFFFFFFF: off).
    pub following_error_window_inc: u32,
    /// 0x6066 following error time out [ms].
    pub following_error_timeout_ms: u16,
    /// 0x6067 position window [inc] (target reached, pp).
    pub position_window_inc: u32,
    /// 0x6068 position window time [ms].
    pub position_window_time_ms: u16,
    /// 0x606D velocity window [inc/s] (target reached, pv).
    pub velocity_window_inc_s: u16,
    /// 0x606E velocity window time [ms].
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
    /// 0x6064 position actual value [inc].
    pub position_inc: i32,
    /// 0x6062 position demand value [inc].
    pub position_demand_inc: i32,
    /// 0x606C velocity actual value [inc/s].
    pub velocity_inc_s: i32,
    /// 0x606B velocity demand value [inc/s].
    pub velocity_demand_inc_s: i32,
    /// 0x6077 torque actual value [per mille].
    pub torque_permille: i16,
    /// 0x6078 current actual value [per mille of rated current].
    pub current_permille: i16,
    /// 0x60F4 following error actual value [inc].
    pub following_error_inc: i32,
    /// 0x603F error code (the last fault's EMCY code, 0 when none).
    pub error_code: u16,
    /// 0x6079 DC link circuit voltage [mV].
    pub dc_link_mv: u32,
}

/// The profile: state machine, mode and values of one axis.
#[derive(Clone, Debug)]
pub struct Cia402 {
    /// Targets (written by SDO / RPDO).
    pub targets: Targets,
    /// Parameters (written by SDO).
    pub params: Params,
    /// Actual values (read by SDO / TPDO).
    pub actuals: Actuals,
}

impl Cia402 {
    /// At boot: not ready to switch on, no mode, parameters at their
    /// defaults.
    pub fn new() -> Self {
        todo!("issue 22: cia402 helper")
    }

    /// The power state.
    pub fn state(&self) -> State {
        todo!()
    }

    /// The mode in force (0x6061).
    pub fn mode(&self) -> OpMode {
        todo!()
    }

    /// The last controlword written.
    pub fn controlword(&self) -> u16 {
        todo!()
    }

    /// The mode requested (0x6060).
    pub fn requested_mode(&self) -> i8 {
        todo!()
    }

    /// Write 0x6040 (SDO or RPDO): run the state machine's transition now
    /// (shutdown, switch on, enable operation, disable voltage, quick stop,
    /// disable operation, fault reset on the rising edge of bit 7; new
    /// set-point on the rising edge of bit 4 in pp; halt bit 8). Refused
    /// transitions leave the state unchanged (not an abort: CiA 402).
    pub fn write_controlword<C: DeviceContext>(&mut self, cw: u16, now_us: u64, ctx: &mut C) {
        let _ = (cw, now_us, ctx);
        todo!()
    }

    /// Write 0x6060: an unsupported value is [`Abort::InvalidValue`] and
    /// changes nothing; a supported one takes effect now (in operation
    /// enabled: the new mode starts from the actual values, bumplessly).
    pub fn write_mode<C: DeviceContext>(
        &mut self,
        mode: i8,
        now_us: u64,
        ctx: &mut C,
    ) -> Result<(), Abort> {
        let _ = (mode, now_us, ctx);
        todo!()
    }

    /// Check a whole parameter set before it replaces [`Self::params`]
    /// (cross-field rules, e.g. profile velocity <= max profile velocity).
    pub fn check_params(&self, p: &Params) -> Result<(), Abort> {
        let _ = p;
        todo!()
    }

    /// At every SYNC (after the synchronous RPDOs were applied) and at every
    /// tick of the node (at least 1 kHz): follow the drive's faults and
    /// start-up (fault reaction -> fault; not ready -> switch on disabled),
    /// post the command of the mode in force from the targets (validated
    /// against the limits in force before posting; keep-alive otherwise),
    /// work out following error / target reached / quick stop, refresh
    /// [`Self::actuals`].
    pub fn update<C: DeviceContext>(&mut self, now_us: u64, ctx: &mut C) {
        let _ = (now_us, ctx);
        todo!()
    }

    /// The connection to the master was lost (heartbeat consumer timeout,
    /// bus-off): react per 0x6007 (0 none, 1 fault, 2 disable voltage,
    /// 3 quick stop).
    pub fn connection_lost<C: DeviceContext>(&mut self, now_us: u64, ctx: &mut C) {
        let _ = (now_us, ctx);
        todo!()
    }

    /// The profile's own fault (following error) latched in this node, if
    /// any, as its EMCY code (0x8611): the node sends the EMCY and the
    /// drive is disabled; cleared by fault reset.
    pub fn profile_fault(&self) -> Option<u16> {
        todo!()
    }
}

impl Default for Cia402 {
    fn default() -> Self {
        Self::new()
    }
}
