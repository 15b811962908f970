//! Messages and their wire layout.
//!
//! Every body is a fixed sequence of little-endian fields (`f32` as IEEE 754
//! bits). Field numbers (0-based, in body order) are what a
//! [`ErrorCode::OutOfRange`] Nack points at.
//!
//! Host to device ([`Request`]); every one is answered with the same `seq`.
//! Frames (see [`crate::joint`]): **out** = output frame (after the
//! gearbox, converted by the device with the joint's frame), **rot** =
//! rotor frame (the motor shaft), no mark = no frame (currents, voltages,
//! electrical quantities, times, counts).
//!
//! | tag | request | body | reply |
//! |---|---|---|---|
//! | 0x01 | `Ping` | - | `Hello` |
//! | 0x02 | `KeepAlive` | - | `Ack` (feeds the watchdog, refreshes the command) |
//! | 0x10 | `SetCommand` | `mode:u8`, then per mode: disable -; torque `iq_a:f32`; velocity `rad_s:f32` (out); position `rad:f32` (out); open loop `v_d_v:f32 v_q_v:f32 theta_e:u32 (turn/2^32) omega_e_rad_s:f32`; impedance `position_rad velocity_rad_s kp_nm_per_rad kd_nm_s_per_rad torque_ff_nm torque_limit_nm` (6 x f32, out; `torque_limit_nm` >= 0, `inf` for the current limit's) | `Ack` |
//! | 0x11 | `SetLimits` | `max_current_a max_velocity_rad_s min_position_rad max_position_rad max_open_loop_voltage_v max_open_loop_omega_e_rad_s max_kp_nm_per_rad max_kd_nm_s_per_rad` (8 x f32; rot) | `Ack` |
//! | 0x12 | `SetCurrentGains` | `kp_d ki_d kp_q ki_q` (f32, V/A and V/(A s)) | `Ack` |
//! | 0x13 | `SetSpeedGains` | `kp_a_per_rad_s ki_a_per_rad` (f32, rot) | `Ack` |
//! | 0x14 | `SetPositionGains` | `kp_per_s max_velocity_rad_s max_acceleration_rad_s2` (f32, rot) | `Ack` |
//! | 0x15 | `SetDividers` | `speed:u16 position:u16` (current-loop periods per run) | `Ack` |
//! | 0x16 | `SetWatchdog` | `timeout_periods:u32` (0 = off), `reaction:u8` (0 disable, 1 stop, 2 hold; in impedance mode always damping, then disable) | `Ack` |
//! | 0x17 | `SetJoint` | `gear_ratio:f32` (rotor turns per output turn, signed) `rotor_at_zero_rad:f32` (rot) `travel:u8` (0 none, 1 the range below) `travel_min_rad travel_max_rad` (f32, out; both +0.0 without travel) `fault_margin_rad` (rot) `brake_accel_rad_s2` (rot) `kv_a_per_rad_s` (A/(rad/s), rot) (f32) `entry_blend_periods:u32` `timeout_kd_nm_s_per_rad:f32` (rot) | `Ack` |
//! | 0x20 | `RunCalibration` | `routine:u8` (0 offsets, 1 identification, 2 alignment) | `Ack` (started) |
//! | 0x21 | `ReadFaults` | - | `Faults` |
//! | 0x22 | `ClearFaults` | - | `Ack` |
//! | 0x23 | `ReadParam` | `id:u8` ([`ParamId`]) | `Param` |
//! | 0x24 | `ReadTelemetry` | - | `Telemetry` (one sample, `seq` echoed) |
//! | 0x25 | `ReadJoint` | - | `Joint` |
//! | 0x26 | `StartHoming` | `method:u8` (0 present position, 1 end stop) `home_output_rad:f32` (out), then for an end stop `velocity_rad_s` (out, its sign the direction) `current_a` `detect_fraction` `confirm_s` `backoff_rad` (out) `max_travel_rad` (out) (f32) | `Ack` (started; present position: done) |
//! | 0x27 | `ReadHoming` | - | `Homing` |
//! | 0x30 | `StartTelemetry` | `kind:u8` (0 every K periods, 1 rate in Hz), `value:u32 K` or `f32 Hz` | `Ack` |
//! | 0x31 | `StopTelemetry` | - | `Ack` |
//! | 0x40 | `ReadConfig` | `source:u8` (0 live, 1 stored) `offset:u16` | `ConfigChunk` |
//! | 0x41 | `WriteConfig` | a chunk: `offset:u16 total:u16 len:u8` then `len` (<= 48) record bytes | `Ack` (staged) |
//! | 0x42 | `Store` | `op:u8` (0 save, 1 load, 2 erase, 3 apply staged, 4 apply staged and save) | `Ack` (done) |
//! | 0x50..0x54 | `SetScope`, `ArmScope`, `TriggerScope`, `ReadScope`, `ReadScopeData` | see [`crate::scope`] | `Ack`, `Scope`, `ScopeData` |
//!
//! Device to host ([`Response`]):
//!
//! | tag | response | body |
//! |---|---|---|
//! | 0x80 | `Ack` | - |
//! | 0x81 | `Nack` | `code:u8 field:u8` ([`ErrorCode`]; `field` only for out-of-range, else 0) |
//! | 0x82 | `Hello` | `protocol_version:u8 fw_major:u8 fw_minor:u8 fw_patch:u8 max_payload:u8` |
//! | 0x83 | `Faults` | `bits:u32` ([`FaultSet`], bit n = fault code n), `first:u8` (first fault code, 0 none) |
//! | 0x84 | `Param` | `id:u8 value:f32` |
//! | 0x85 | `Telemetry` | `period:u32 i_d_a i_q_a v_d_v v_q_v velocity_rad_s position_rad (f32; velocity and position out) mode:u8 fault:u8 max_loop_cycles:u32 v_bus_v:f32 power_limit:u8 limit_left_pct:u8 flags:u8 winding_dC:i16 stage_dC:i16` (reply to `ReadTelemetry`; `power_limit` an [`ActiveLimit`] code, `flags` bit 0 brake on, bit 1 brake locked out by its guard, temperatures in 0.1 deg C with -32768 for none) |
//! | 0x86 | `Stream` | as `Telemetry`; unsolicited, after `StartTelemetry`, `seq` = wrapping stream counter |
//! | 0x87 | `ConfigChunk` | a chunk, as in `WriteConfig` (see [`crate::config`]) |
//! | 0x88 | `Joint` | as `SetJoint` (the joint in force) |
//! | 0x89 | `Homing` | `state:u8` (0 idle, 1 running, 2 done, 3 failed) `reason:u8` (failed: [`HomingFailure`] code, else 0) |
//! | 0x8A / 0x8B | `Scope` / `ScopeData` | see [`crate::scope`] |
//!
//! A frame-level error (bad CRC, bad COBS, too long, too short) cannot be
//! trusted to carry a sequence number: its Nack goes out with `seq = 0`, and
//! hosts never use 0 for a request. Streamed telemetry has its own tag (so
//! it is never taken for a reply) and a wrapping stream counter in `seq` (so
//! the host can count lost frames).

pub use crate::config::{Chunk, ConfigSource, StoreOp};
pub use crate::wire::DecodeError;
use crate::wire::{Reader, Writer};
use foc_core::angle::ElectricalAngle;
use foc_core::control::homing::{EndStop, HomingMethod};
use foc_core::control::joint::Impedance;
use foc_core::control::power::ActiveLimit;
use foc_core::control::stage::TimeoutReaction;
use foc_core::control::{Command, Fault, FaultSet, Feedback, Limits, Mode};

pub use crate::joint::{HomingFailure, HomingStart, HomingState, JointSettings};
pub use crate::scope::{ScopeData, ScopeReport};
use foc_core::scope::ScopeConfig;

/// A message type of one direction.
pub trait Message: Sized {
    /// The tag byte.
    fn tag(&self) -> u8;
    /// Write the body (after tag and seq).
    fn encode_body(&self, w: &mut Writer<'_>);
    /// Read the body of a message with `tag`.
    fn decode_body(tag: u8, r: &mut Reader<'_>) -> Result<Self, DecodeError>;
}

/// Current-loop PI gains of both axes.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CurrentGains {
    /// d-axis proportional gain [V/A].
    pub kp_d: f32,
    /// d-axis integral gain [V/(A s)].
    pub ki_d: f32,
    /// q-axis proportional gain [V/A].
    pub kp_q: f32,
    /// q-axis integral gain [V/(A s)].
    pub ki_q: f32,
}

impl CurrentGains {
    /// The gains of a current-loop configuration.
    pub fn from_config(c: &foc_core::control::current::CurrentLoopConfig) -> Self {
        Self {
            kp_d: c.d_gains.kp_v_per_a,
            ki_d: c.d_gains.ki_v_per_a_s,
            kp_q: c.q_gains.kp_v_per_a,
            ki_q: c.q_gains.ki_v_per_a_s,
        }
    }
    /// Write these gains into a current-loop configuration.
    pub fn apply(&self, c: &mut foc_core::control::current::CurrentLoopConfig) {
        c.d_gains.kp_v_per_a = self.kp_d;
        c.d_gains.ki_v_per_a_s = self.ki_d;
        c.q_gains.kp_v_per_a = self.kp_q;
        c.q_gains.ki_v_per_a_s = self.ki_q;
    }
}

/// Speed-loop PI gains.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SpeedGains {
    /// Proportional gain [A / (rad/s)].
    pub kp_a_per_rad_s: f32,
    /// Integral gain [A / rad].
    pub ki_a_per_rad: f32,
}

impl SpeedGains {
    /// Write these gains into a speed-loop configuration.
    pub fn apply(&self, c: &mut foc_core::control::speed::SpeedLoopConfig) {
        c.kp_a_per_rad_s = self.kp_a_per_rad_s;
        c.ki_a_per_rad = self.ki_a_per_rad;
    }
}

/// Position-loop gain and trajectory limits.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PositionGains {
    /// Proportional gain [(rad/s) / rad].
    pub kp_per_s: f32,
    /// Trajectory velocity limit [rad/s].
    pub max_velocity_rad_s: f32,
    /// Trajectory acceleration limit [rad/s^2].
    pub max_acceleration_rad_s2: f32,
}

impl PositionGains {
    /// Write these into a position-loop configuration.
    pub fn apply(&self, c: &mut foc_core::control::position::PositionLoopConfig) {
        c.kp_per_s = self.kp_per_s;
        c.max_velocity_rad_s = self.max_velocity_rad_s;
        c.max_acceleration_rad_s2 = self.max_acceleration_rad_s2;
    }
}

/// Configuration of the link watchdog (see [`crate::device::CommandWatchdog`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WatchdogConfig {
    /// Current-loop periods without a command or keep-alive before the
    /// reaction (0: off).
    pub timeout_periods: u32,
    /// What to do then.
    pub reaction: TimeoutReaction,
}

impl WatchdogConfig {
    /// Watchdog off.
    pub const OFF: Self = Self {
        timeout_periods: 0,
        reaction: TimeoutReaction::Disable,
    };
}

/// A calibration routine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Calibration {
    /// Current-sensor offsets (bridge off).
    Offsets = 0,
    /// Resistance and inductance identification.
    Identification = 1,
    /// Angle-sensor direction, pole pairs and electrical zero.
    Alignment = 2,
}

impl Calibration {
    /// From its wire code.
    pub const fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Self::Offsets),
            1 => Some(Self::Identification),
            2 => Some(Self::Alignment),
            _ => None,
        }
    }
}

/// How often to stream telemetry.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TelemetryRate {
    /// One sample every K current-loop periods (K >= 1).
    EveryPeriods(u32),
    /// A rate [Hz] (converted with the PWM frequency; at most that).
    Hz(f32),
}

macro_rules! param_ids {
    ($( $(#[$doc:meta])* $name:ident = $code:expr, $text:expr; )*) => {
        /// A readable parameter.
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[repr(u8)]
        pub enum ParamId { $( $(#[$doc])* $name = $code, )* }
        impl ParamId {
            /// Every parameter.
            pub const ALL: &'static [ParamId] = &[$(ParamId::$name),*];
            /// From its wire code.
            pub const fn from_code(c: u8) -> Option<Self> {
                match c { $( $code => Some(ParamId::$name), )* _ => None }
            }
            /// Its name on the command line (`foc-ctl param NAME`).
            pub const fn name(self) -> &'static str {
                match self { $( ParamId::$name => $text, )* }
            }
            /// The parameter with this command-line name.
            pub fn from_name(s: &str) -> Option<Self> {
                Self::ALL.iter().copied().find(|p| p.name() == s)
            }
        }
    };
}

param_ids! {
    /// Pole pairs.
    PolePairs = 0, "pole-pairs";
    /// Phase resistance [ohm].
    ResistanceOhm = 1, "r";
    /// d-axis inductance [H].
    LdH = 2, "ld";
    /// q-axis inductance [H].
    LqH = 3, "lq";
    /// Flux linkage [Wb].
    FluxLinkageWb = 4, "psi";
    /// PWM = current-loop frequency [Hz].
    PwmFrequencyHz = 5, "pwm-frequency";
    /// Speed loop every N periods.
    SpeedDivider = 6, "speed-divider";
    /// Position loop every M periods.
    PositionDivider = 7, "position-divider";
    /// Firmware version as `major * 10000 + minor * 100 + patch`.
    FirmwareVersion = 8, "firmware-version";
    /// Protocol version ([`crate::PROTOCOL_VERSION`]; answered by the protocol layer).
    ProtocolVersion = 9, "protocol-version";
    /// Bus voltage [V].
    BusVoltageV = 10, "bus-voltage";
    /// 1 when calibrated, else 0.
    Calibrated = 11, "calibrated";
    /// Longest current-loop run so far [CPU cycles].
    MaxLoopCycles = 12, "max-loop-cycles";
    /// Telemetry divider in force (periods; 0 = streaming off; answered by the protocol layer).
    TelemetryDivider = 13, "telemetry-divider";
    /// Watchdog timeout [periods] (0 = off; answered by the protocol layer).
    WatchdogTimeout = 14, "watchdog-timeout";
    /// Current-loop proportional gain, q axis [V/A].
    CurrentKp = 15, "current-kp";
    /// Current-loop integral gain, q axis [V/(A s)].
    CurrentKi = 16, "current-ki";
    /// Speed-loop proportional gain [A/(rad/s)] (rotor).
    SpeedKp = 17, "speed-kp";
    /// Speed-loop integral gain [A/rad] (rotor).
    SpeedKi = 18, "speed-ki";
    /// Position-loop gain [(rad/s)/rad].
    PositionKp = 19, "position-kp";
    /// Values the scope buffer holds (0: no scope).
    ScopeCapacity = 20, "scope-capacity";
}

/// A Nack's reason.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorCode {
    /// Frame could not be decoded (COBS, length, too long, body size).
    Malformed,
    /// CRC mismatch.
    BadCrc,
    /// Unknown tag.
    UnknownMessage,
    /// Field `field` (0-based, in body order) invalid or out of range.
    OutOfRange {
        /// The offending field.
        field: u8,
    },
    /// A fault is latched: clear it first.
    Faulted,
    /// The device is busy (e.g. a calibration is running).
    Busy,
    /// Closed-loop modes need calibration first.
    NotCalibrated,
    /// Only allowed while disabled.
    NotDisabled,
    /// Not supported by this device.
    Unsupported,
    /// The flash store failed (flash error, corrupt, full).
    StoreFailed,
    /// A configuration record was refused: incomplete, bad checksum,
    /// unknown version, or a value out of range (nothing applied).
    BadRecord,
    /// Nothing is stored.
    NothingStored,
    /// The scope is not in the state the request needs (trigger: armed;
    /// data: done).
    ScopeState,
    /// A code this version does not know (decoding only).
    Other(u8),
}

impl ErrorCode {
    /// Wire code and field.
    pub const fn to_wire(self) -> (u8, u8) {
        match self {
            Self::Malformed => (1, 0),
            Self::BadCrc => (2, 0),
            Self::UnknownMessage => (3, 0),
            Self::OutOfRange { field } => (4, field),
            Self::Faulted => (5, 0),
            Self::Busy => (6, 0),
            Self::NotCalibrated => (7, 0),
            Self::NotDisabled => (8, 0),
            Self::Unsupported => (9, 0),
            Self::StoreFailed => (10, 0),
            Self::BadRecord => (11, 0),
            Self::NothingStored => (12, 0),
            Self::ScopeState => (13, 0),
            Self::Other(c) => (c, 0),
        }
    }
    /// From wire code and field.
    pub const fn from_wire(code: u8, field: u8) -> Self {
        match code {
            1 => Self::Malformed,
            2 => Self::BadCrc,
            3 => Self::UnknownMessage,
            4 => Self::OutOfRange { field },
            5 => Self::Faulted,
            6 => Self::Busy,
            7 => Self::NotCalibrated,
            8 => Self::NotDisabled,
            9 => Self::Unsupported,
            10 => Self::StoreFailed,
            11 => Self::BadRecord,
            12 => Self::NothingStored,
            13 => Self::ScopeState,
            c => Self::Other(c),
        }
    }
}

/// Reply to `Ping`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Hello {
    /// [`crate::PROTOCOL_VERSION`] of the device.
    pub protocol_version: u8,
    /// Firmware version `[major, minor, patch]`.
    pub firmware_version: [u8; 3],
    /// Largest payload the device accepts [bytes].
    pub max_payload: u8,
}

/// Latched faults.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FaultReport {
    /// All latched faults.
    pub set: FaultSet,
    /// Code of the first fault (0: none).
    pub first_code: u8,
}

impl FaultReport {
    /// From the supervisor's view.
    pub fn new(set: FaultSet, first: Option<Fault>) -> Self {
        Self {
            set,
            first_code: first.map_or(0, Fault::code),
        }
    }
    /// The first fault, if its code is known.
    pub fn first(&self) -> Option<Fault> {
        Fault::from_code(self.first_code)
    }
}

/// One telemetry sample. Equality compares the temperatures as they
/// travel (0.1 deg C, "none" equal to "none"), every other field exactly.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Telemetry {
    /// Current-loop period counter (wraps).
    pub period: u32,
    /// Measured d current [A].
    pub i_d_a: f32,
    /// Measured q current [A].
    pub i_q_a: f32,
    /// Commanded d voltage [V].
    pub v_d_v: f32,
    /// Commanded q voltage [V].
    pub v_q_v: f32,
    /// Mechanical velocity [rad/s]: the drive's (rotor frame) from
    /// [`Self::from_feedback`]; on the wire the output frame's (the
    /// device converts, see [`crate::joint`]).
    pub velocity_rad_s: f32,
    /// Multi-turn mechanical position [rad]: rotor frame from
    /// [`Self::from_feedback`], output frame on the wire.
    pub position_rad: f32,
    /// Active mode.
    pub mode: Mode,
    /// First latched fault code (0: none).
    pub fault_code: u8,
    /// Longest current-loop run [CPU cycles].
    pub max_loop_cycles: u32,
    /// Bus voltage [V].
    pub v_bus_v: f32,
    /// The power limit that cut the q-current window the most (design
    /// §18; `None` while nothing is cut).
    pub power_limit: ActiveLimit,
    /// Share of the current limit left at that end [%] (100: nothing
    /// cut; rounded down, so 99 means a cut of at most 1 %).
    pub limit_left_pct: u8,
    /// The brake chopper conducts.
    pub brake_on: bool,
    /// The brake chopper's guard has locked it out.
    pub brake_locked: bool,
    /// Estimated winding temperature [deg C] (NaN: no power limits; 0.1
    /// deg C on the wire).
    pub winding_c: f32,
    /// Measured power-stage temperature [deg C] (NaN: no sensor or no
    /// reading; 0.1 deg C on the wire).
    pub stage_c: f32,
}

impl PartialEq for Telemetry {
    fn eq(&self, o: &Self) -> bool {
        self.period == o.period
            && self.i_d_a == o.i_d_a
            && self.i_q_a == o.i_q_a
            && self.v_d_v == o.v_d_v
            && self.v_q_v == o.v_q_v
            && self.velocity_rad_s == o.velocity_rad_s
            && self.position_rad == o.position_rad
            && self.mode == o.mode
            && self.fault_code == o.fault_code
            && self.max_loop_cycles == o.max_loop_cycles
            && self.v_bus_v == o.v_bus_v
            && self.power_limit == o.power_limit
            && self.limit_left_pct == o.limit_left_pct
            && self.brake_on == o.brake_on
            && self.brake_locked == o.brake_locked
            && temperature_to_wire(self.winding_c) == temperature_to_wire(o.winding_c)
            && temperature_to_wire(self.stage_c) == temperature_to_wire(o.stage_c)
    }
}

impl Telemetry {
    /// A zero sample (disabled).
    pub const ZERO: Self = Self {
        period: 0,
        i_d_a: 0.0,
        i_q_a: 0.0,
        v_d_v: 0.0,
        v_q_v: 0.0,
        velocity_rad_s: 0.0,
        position_rad: 0.0,
        mode: Mode::Disabled,
        fault_code: 0,
        max_loop_cycles: 0,
        v_bus_v: 0.0,
        power_limit: ActiveLimit::None,
        limit_left_pct: 100,
        brake_on: false,
        brake_locked: false,
        winding_c: f32::NAN,
        stage_c: f32::NAN,
    };

    /// The sample of a current-stage [`Feedback`].
    pub fn from_feedback(fb: &Feedback, max_loop_cycles: u32) -> Self {
        Self {
            period: fb.period,
            i_d_a: fb.i_dq_a.d,
            i_q_a: fb.i_dq_a.q,
            v_d_v: fb.v_dq_v.d,
            v_q_v: fb.v_dq_v.q,
            velocity_rad_s: fb.velocity_rad_s,
            position_rad: fb.position_rad,
            mode: fb.mode,
            fault_code: fb.first_fault.map_or(0, Fault::code),
            max_loop_cycles,
            v_bus_v: fb.v_bus_v,
            power_limit: fb.power.active,
            limit_left_pct: percent(fb.power.factor),
            brake_on: fb.power.brake_on,
            brake_locked: fb.power.brake_locked,
            winding_c: fb.power.winding_c,
            stage_c: fb.power.stage_c,
        }
    }
}

/// `f` in `[0, 1]` as a whole percentage, rounded down (NaN: 0).
fn percent(f: f32) -> u8 {
    let p = f * 100.0;
    if p >= 100.0 {
        100
    } else if p >= 0.0 {
        p as u8
    } else {
        0
    }
}

/// Wire code of "no temperature" ([`Telemetry::winding_c`], `stage_c`).
pub const NO_TEMPERATURE: i16 = i16::MIN;

/// A temperature [deg C] in 0.1 deg C (saturated; NaN: [`NO_TEMPERATURE`]).
pub fn temperature_to_wire(t_c: f32) -> i16 {
    let d = t_c * 10.0;
    if d.is_nan() {
        NO_TEMPERATURE
    } else if d >= 32767.0 {
        i16::MAX
    } else if d <= -32767.0 {
        -i16::MAX
    } else {
        // Round half away from zero without `round` (no_std).
        (if d >= 0.0 { d + 0.5 } else { d - 0.5 }) as i16
    }
}

/// A wire temperature back in deg C ([`NO_TEMPERATURE`]: NaN).
pub fn temperature_from_wire(w: i16) -> f32 {
    if w == NO_TEMPERATURE {
        f32::NAN
    } else {
        f32::from(w) / 10.0
    }
}

/// [`ActiveLimit`] from its wire code (its `u8` value).
pub const fn active_limit_from_code(c: u8) -> Option<ActiveLimit> {
    Some(match c {
        0 => ActiveLimit::None,
        1 => ActiveLimit::Regen,
        2 => ActiveLimit::BusCurrentMotoring,
        3 => ActiveLimit::BusCurrentRegen,
        4 => ActiveLimit::PowerMotoring,
        5 => ActiveLimit::PowerRegen,
        6 => ActiveLimit::WindingTemperature,
        7 => ActiveLimit::StageTemperature,
        8 => ActiveLimit::MissingSensor,
        9 => ActiveLimit::InvalidModel,
        _ => return None,
    })
}

/// Mode from its wire code ([`Mode`] as `u8`).
pub const fn mode_from_code(c: u8) -> Option<Mode> {
    match c {
        0 => Some(Mode::Disabled),
        1 => Some(Mode::Torque),
        2 => Some(Mode::Velocity),
        3 => Some(Mode::Position),
        4 => Some(Mode::OpenLoop),
        5 => Some(Mode::Impedance),
        _ => None,
    }
}

/// Timeout reaction wire code.
pub const fn reaction_code(r: TimeoutReaction) -> u8 {
    match r {
        TimeoutReaction::Disable => 0,
        TimeoutReaction::Stop => 1,
        TimeoutReaction::Hold => 2,
    }
}

/// Timeout reaction from its wire code.
pub const fn reaction_from_code(c: u8) -> Option<TimeoutReaction> {
    match c {
        0 => Some(TimeoutReaction::Disable),
        1 => Some(TimeoutReaction::Stop),
        2 => Some(TimeoutReaction::Hold),
        _ => None,
    }
}

/// Host-to-device messages.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Request {
    /// Who are you? (no side effects; does not feed the watchdog).
    Ping,
    /// Keep the active command alive (feeds the watchdog).
    KeepAlive,
    /// Set mode and target.
    SetCommand(Command),
    /// Replace the command limits.
    SetLimits(Limits),
    /// Current-loop gains.
    SetCurrentGains(CurrentGains),
    /// Speed-loop gains.
    SetSpeedGains(SpeedGains),
    /// Position-loop gain and trajectory limits.
    SetPositionGains(PositionGains),
    /// Loop dividers (only while disabled).
    SetDividers {
        /// Speed loop every N periods (>= 1).
        speed: u16,
        /// Position loop every M periods (>= 1).
        position: u16,
    },
    /// Link watchdog.
    SetWatchdog(WatchdogConfig),
    /// Set the joint up: output frame, travel range, soft stop, impedance
    /// entry and timeout (see [`crate::joint`] for the frames).
    SetJoint(JointSettings),
    /// The joint in force (`Joint`).
    ReadJoint,
    /// Start homing (the output frame's zero): a command from the host
    /// aborts it.
    StartHoming(HomingStart),
    /// Where homing stands (`Homing`).
    ReadHoming,
    /// Start a calibration routine (only while disabled and not faulted).
    RunCalibration(Calibration),
    /// Read the latched faults.
    ReadFaults,
    /// Clear the latched faults.
    ClearFaults,
    /// Read a parameter.
    ReadParam(ParamId),
    /// One telemetry sample now.
    ReadTelemetry,
    /// Stream telemetry.
    StartTelemetry(TelemetryRate),
    /// Stop streaming.
    StopTelemetry,
    /// A chunk of the live or the stored configuration record.
    ReadConfig {
        /// Which record.
        source: ConfigSource,
        /// From this byte on.
        offset: u16,
    },
    /// Stage a chunk of a configuration record (applied by `Store`).
    WriteConfig(Chunk),
    /// A store operation (only while started and disabled).
    Store(StoreOp),
    /// Configure the scope (it goes idle, a capture is dropped).
    SetScope(ScopeConfig),
    /// Start recording, waiting for the trigger.
    ArmScope,
    /// Trigger the armed scope now.
    TriggerScope,
    /// The scope's state (`Scope`).
    ReadScope,
    /// Values of a finished capture from `offset` on (`ScopeData`).
    ReadScopeData {
        /// Value index.
        offset: u16,
    },
}

impl Request {
    /// True for requests that only read (never deduplicated, never change
    /// the device).
    pub const fn is_query(&self) -> bool {
        matches!(
            self,
            Request::Ping
                | Request::ReadFaults
                | Request::ReadParam(_)
                | Request::ReadTelemetry
                | Request::ReadConfig { .. }
                | Request::ReadJoint
                | Request::ReadHoming
                | Request::ReadScope
                | Request::ReadScopeData { .. }
        )
    }

    /// The name of field `field` (0-based, body order: what an
    /// [`ErrorCode::OutOfRange`] Nack of this request points at), for
    /// people; `None` past the body.
    pub fn field_name(&self, field: u8) -> Option<&'static str> {
        let names: &[&str] = match self {
            Request::SetCommand(c) => command_fields(c),
            Request::SetLimits(_) => &[
                "max_current_a",
                "max_velocity_rad_s",
                "min_position_rad",
                "max_position_rad",
                "max_open_loop_voltage_v",
                "max_open_loop_omega_e_rad_s",
                "max_kp_nm_per_rad",
                "max_kd_nm_s_per_rad",
            ],
            Request::SetCurrentGains(_) => &["kp_d", "ki_d", "kp_q", "ki_q"],
            Request::SetSpeedGains(_) => &["kp_a_per_rad_s", "ki_a_per_rad"],
            Request::SetPositionGains(_) => {
                &["kp_per_s", "max_velocity_rad_s", "max_acceleration_rad_s2"]
            }
            Request::SetDividers { .. } => &["speed", "position"],
            Request::SetWatchdog(_) => &["timeout_periods", "reaction"],
            Request::SetJoint(_) => &[
                "gear_ratio",
                "rotor_at_zero_rad",
                "travel",
                "travel_min_rad",
                "travel_max_rad",
                "fault_margin_rad",
                "brake_accel_rad_s2",
                "kv_a_per_rad_s",
                "entry_blend_periods",
                "timeout_kd_nm_s_per_rad",
            ],
            Request::StartHoming(_) => &[
                "method",
                "home_output_rad",
                "velocity_rad_s",
                "current_a",
                "detect_fraction",
                "confirm_s",
                "backoff_rad",
                "max_travel_rad",
            ],
            Request::RunCalibration(_) => &["routine"],
            Request::ReadParam(_) => &["id"],
            Request::StartTelemetry(_) => &["kind", "value"],
            Request::ReadConfig { .. } => &["source", "offset"],
            Request::WriteConfig(_) => &["offset", "total", "len"],
            Request::Store(_) => &["op"],
            Request::SetScope(_) => &[
                "signal0",
                "signal1",
                "signal2",
                "signal3",
                "signal4",
                "signal5",
                "signal6",
                "signal7",
                "divider",
                "samples",
                "pre_trigger",
                "trigger",
                "trigger_signal",
                "level",
            ],
            Request::ReadScopeData { .. } => &["offset"],
            Request::Ping
            | Request::KeepAlive
            | Request::ReadFaults
            | Request::ClearFaults
            | Request::ReadTelemetry
            | Request::StopTelemetry
            | Request::ReadJoint
            | Request::ReadHoming
            | Request::ArmScope
            | Request::TriggerScope
            | Request::ReadScope => &[],
        };
        names.get(usize::from(field)).copied()
    }
}

/// Field names of a `SetCommand` body.
fn command_fields(c: &Command) -> &'static [&'static str] {
    match c {
        Command::Disable => &["mode"],
        Command::Torque { .. } => &["mode", "iq_a"],
        Command::Velocity { .. } => &["mode", "rad_s"],
        Command::Position { .. } => &["mode", "rad"],
        Command::OpenLoop { .. } => &["mode", "v_d_v", "v_q_v", "theta_e", "omega_e_rad_s"],
        Command::Impedance(_) => &[
            "mode",
            "position_rad",
            "velocity_rad_s",
            "kp_nm_per_rad",
            "kd_nm_s_per_rad",
            "torque_ff_nm",
            "torque_limit_nm",
        ],
    }
}

fn get_telemetry(r: &mut Reader<'_>) -> Result<Telemetry, DecodeError> {
    // Fields in wire order (struct literals evaluate in source order, but
    // the flags byte feeds two fields).
    let period = r.u32()?;
    let i_d_a = r.f32()?;
    let i_q_a = r.f32()?;
    let v_d_v = r.f32()?;
    let v_q_v = r.f32()?;
    let velocity_rad_s = r.f32()?;
    let position_rad = r.f32()?;
    let mode = mode_from_code(r.u8()?).ok_or(DecodeError::BadField(7))?;
    let fault_code = r.u8()?;
    let max_loop_cycles = r.u32()?;
    let v_bus_v = r.f32()?;
    let power_limit = active_limit_from_code(r.u8()?).ok_or(DecodeError::BadField(11))?;
    let limit_left_pct = match r.u8()? {
        p @ 0..=100 => p,
        _ => return Err(DecodeError::BadField(12)),
    };
    let flags = match r.u8()? {
        f @ 0..=3 => f,
        _ => return Err(DecodeError::BadField(13)),
    };
    let winding_c = temperature_from_wire(r.u16()? as i16);
    let stage_c = temperature_from_wire(r.u16()? as i16);
    Ok(Telemetry {
        period,
        i_d_a,
        i_q_a,
        v_d_v,
        v_q_v,
        velocity_rad_s,
        position_rad,
        mode,
        fault_code,
        max_loop_cycles,
        v_bus_v,
        power_limit,
        limit_left_pct,
        brake_on: flags & 1 != 0,
        brake_locked: flags & 2 != 0,
        winding_c,
        stage_c,
    })
}

fn put_command(w: &mut Writer<'_>, c: &Command) {
    w.u8(c.mode() as u8);
    match *c {
        Command::Disable => {}
        Command::Torque { iq_a } => w.f32(iq_a),
        Command::Velocity { rad_s } => w.f32(rad_s),
        Command::Position { rad } => w.f32(rad),
        Command::OpenLoop {
            v_d_v,
            v_q_v,
            theta_e,
            omega_e_rad_s,
        } => {
            w.f32(v_d_v);
            w.f32(v_q_v);
            w.u32(theta_e.to_bits());
            w.f32(omega_e_rad_s);
        }
        Command::Impedance(i) => {
            w.f32(i.position_rad);
            w.f32(i.velocity_rad_s);
            w.f32(i.kp_nm_per_rad);
            w.f32(i.kd_nm_s_per_rad);
            w.f32(i.torque_ff_nm);
            w.f32(i.torque_limit_nm);
        }
    }
}

fn get_command(r: &mut Reader<'_>) -> Result<Command, DecodeError> {
    let mode = mode_from_code(r.u8()?).ok_or(DecodeError::BadField(0))?;
    Ok(match mode {
        Mode::Disabled => Command::Disable,
        Mode::Torque => Command::Torque { iq_a: r.f32()? },
        Mode::Velocity => Command::Velocity { rad_s: r.f32()? },
        Mode::Position => Command::Position { rad: r.f32()? },
        Mode::OpenLoop => Command::OpenLoop {
            v_d_v: r.f32()?,
            v_q_v: r.f32()?,
            theta_e: ElectricalAngle::from_bits(r.u32()?),
            omega_e_rad_s: r.f32()?,
        },
        Mode::Impedance => Command::Impedance(Impedance {
            position_rad: r.f32()?,
            velocity_rad_s: r.f32()?,
            kp_nm_per_rad: r.f32()?,
            kd_nm_s_per_rad: r.f32()?,
            torque_ff_nm: r.f32()?,
            torque_limit_nm: r.f32()?,
        }),
    })
}

fn put_joint(w: &mut Writer<'_>, j: &JointSettings) {
    w.f32(j.gear_ratio);
    w.f32(j.rotor_at_zero_rad);
    let (flag, (lo, hi)) = match j.travel_out_rad {
        Some(range) => (1, range),
        None => (0, (0.0, 0.0)),
    };
    w.u8(flag);
    w.f32(lo);
    w.f32(hi);
    w.f32(j.fault_margin_rad);
    w.f32(j.brake_accel_rad_s2);
    w.f32(j.kv_a_per_rad_s);
    w.u32(j.entry_blend_periods);
    w.f32(j.timeout_kd_nm_s_per_rad);
}

fn get_joint(r: &mut Reader<'_>) -> Result<JointSettings, DecodeError> {
    let gear_ratio = r.f32()?;
    let rotor_at_zero_rad = r.f32()?;
    let flag = r.u8()?;
    let range = (r.f32()?, r.f32()?);
    // Without a travel range its two fields are 0 (one layout per value).
    let travel_out_rad = match flag {
        0 if range.0.to_bits() == 0 && range.1.to_bits() == 0 => None,
        0 => return Err(DecodeError::BadField(3)),
        1 => Some(range),
        _ => return Err(DecodeError::BadField(2)),
    };
    Ok(JointSettings {
        gear_ratio,
        rotor_at_zero_rad,
        travel_out_rad,
        fault_margin_rad: r.f32()?,
        brake_accel_rad_s2: r.f32()?,
        kv_a_per_rad_s: r.f32()?,
        entry_blend_periods: r.u32()?,
        timeout_kd_nm_s_per_rad: r.f32()?,
    })
}

fn put_homing(w: &mut Writer<'_>, h: &HomingStart) {
    match h.method {
        HomingMethod::Present => {
            w.u8(0);
            w.f32(h.home_output_rad);
        }
        HomingMethod::EndStop(e) => {
            w.u8(1);
            w.f32(h.home_output_rad);
            w.f32(e.velocity_rad_s);
            w.f32(e.current_a);
            w.f32(e.detect_fraction);
            w.f32(e.confirm_s);
            w.f32(e.backoff_rad);
            w.f32(e.max_travel_rad);
        }
    }
}

fn get_homing(r: &mut Reader<'_>) -> Result<HomingStart, DecodeError> {
    let method = r.u8()?;
    let home_output_rad = r.f32()?;
    let method = match method {
        0 => HomingMethod::Present,
        1 => HomingMethod::EndStop(EndStop {
            velocity_rad_s: r.f32()?,
            current_a: r.f32()?,
            detect_fraction: r.f32()?,
            confirm_s: r.f32()?,
            backoff_rad: r.f32()?,
            max_travel_rad: r.f32()?,
        }),
        _ => return Err(DecodeError::BadField(0)),
    };
    Ok(HomingStart {
        method,
        home_output_rad,
    })
}

fn put_chunk(w: &mut Writer<'_>, c: &Chunk) {
    w.u16(c.offset);
    w.u16(c.total);
    w.u8(c.data().len() as u8);
    w.bytes(c.data());
}

fn get_chunk(r: &mut Reader<'_>) -> Result<Chunk, DecodeError> {
    let offset = r.u16()?;
    let total = r.u16()?;
    let len = r.u8()?;
    Chunk::new(offset, total, r.slice(usize::from(len))?).ok_or(DecodeError::BadField(2))
}

mod tags {
    pub const PING: u8 = 0x01;
    pub const KEEP_ALIVE: u8 = 0x02;
    pub const SET_COMMAND: u8 = 0x10;
    pub const SET_LIMITS: u8 = 0x11;
    pub const SET_CURRENT_GAINS: u8 = 0x12;
    pub const SET_SPEED_GAINS: u8 = 0x13;
    pub const SET_POSITION_GAINS: u8 = 0x14;
    pub const SET_DIVIDERS: u8 = 0x15;
    pub const SET_WATCHDOG: u8 = 0x16;
    pub const SET_JOINT: u8 = 0x17;
    pub const RUN_CALIBRATION: u8 = 0x20;
    pub const READ_FAULTS: u8 = 0x21;
    pub const CLEAR_FAULTS: u8 = 0x22;
    pub const READ_PARAM: u8 = 0x23;
    pub const READ_TELEMETRY: u8 = 0x24;
    pub const READ_JOINT: u8 = 0x25;
    pub const START_HOMING: u8 = 0x26;
    pub const READ_HOMING: u8 = 0x27;
    pub const START_TELEMETRY: u8 = 0x30;
    pub const STOP_TELEMETRY: u8 = 0x31;
    pub const READ_CONFIG: u8 = 0x40;
    pub const WRITE_CONFIG: u8 = 0x41;
    pub const STORE: u8 = 0x42;
    pub const SET_SCOPE: u8 = 0x50;
    pub const ARM_SCOPE: u8 = 0x51;
    pub const TRIGGER_SCOPE: u8 = 0x52;
    pub const READ_SCOPE: u8 = 0x53;
    pub const READ_SCOPE_DATA: u8 = 0x54;

    pub const ACK: u8 = 0x80;
    pub const NACK: u8 = 0x81;
    pub const HELLO: u8 = 0x82;
    pub const FAULTS: u8 = 0x83;
    pub const PARAM: u8 = 0x84;
    pub const TELEMETRY: u8 = 0x85;
    pub const STREAM: u8 = 0x86;
    pub const CONFIG_CHUNK: u8 = 0x87;
    pub const JOINT: u8 = 0x88;
    pub const HOMING: u8 = 0x89;
    pub const SCOPE: u8 = 0x8A;
    pub const SCOPE_DATA: u8 = 0x8B;
}

impl Message for Request {
    fn tag(&self) -> u8 {
        use tags::*;
        match self {
            Request::Ping => PING,
            Request::KeepAlive => KEEP_ALIVE,
            Request::SetCommand(_) => SET_COMMAND,
            Request::SetLimits(_) => SET_LIMITS,
            Request::SetCurrentGains(_) => SET_CURRENT_GAINS,
            Request::SetSpeedGains(_) => SET_SPEED_GAINS,
            Request::SetPositionGains(_) => SET_POSITION_GAINS,
            Request::SetDividers { .. } => SET_DIVIDERS,
            Request::SetWatchdog(_) => SET_WATCHDOG,
            Request::SetJoint(_) => SET_JOINT,
            Request::ReadJoint => READ_JOINT,
            Request::StartHoming(_) => START_HOMING,
            Request::ReadHoming => READ_HOMING,
            Request::RunCalibration(_) => RUN_CALIBRATION,
            Request::ReadFaults => READ_FAULTS,
            Request::ClearFaults => CLEAR_FAULTS,
            Request::ReadParam(_) => READ_PARAM,
            Request::ReadTelemetry => READ_TELEMETRY,
            Request::StartTelemetry(_) => START_TELEMETRY,
            Request::StopTelemetry => STOP_TELEMETRY,
            Request::ReadConfig { .. } => READ_CONFIG,
            Request::WriteConfig(_) => WRITE_CONFIG,
            Request::Store(_) => STORE,
            Request::SetScope(_) => SET_SCOPE,
            Request::ArmScope => ARM_SCOPE,
            Request::TriggerScope => TRIGGER_SCOPE,
            Request::ReadScope => READ_SCOPE,
            Request::ReadScopeData { .. } => READ_SCOPE_DATA,
        }
    }

    fn encode_body(&self, w: &mut Writer<'_>) {
        match self {
            Request::Ping
            | Request::KeepAlive
            | Request::ReadFaults
            | Request::ClearFaults
            | Request::ReadTelemetry
            | Request::StopTelemetry
            | Request::ReadJoint
            | Request::ReadHoming
            | Request::ArmScope
            | Request::TriggerScope
            | Request::ReadScope => {}
            Request::SetScope(c) => crate::scope::put_config(w, c),
            Request::ReadScopeData { offset } => w.u16(*offset),
            Request::SetCommand(c) => put_command(w, c),
            Request::SetLimits(l) => {
                w.f32(l.max_current_a);
                w.f32(l.max_velocity_rad_s);
                w.f32(l.min_position_rad);
                w.f32(l.max_position_rad);
                w.f32(l.max_open_loop_voltage_v);
                w.f32(l.max_open_loop_omega_e_rad_s);
                w.f32(l.max_kp_nm_per_rad);
                w.f32(l.max_kd_nm_s_per_rad);
            }
            Request::SetCurrentGains(g) => {
                w.f32(g.kp_d);
                w.f32(g.ki_d);
                w.f32(g.kp_q);
                w.f32(g.ki_q);
            }
            Request::SetSpeedGains(g) => {
                w.f32(g.kp_a_per_rad_s);
                w.f32(g.ki_a_per_rad);
            }
            Request::SetPositionGains(g) => {
                w.f32(g.kp_per_s);
                w.f32(g.max_velocity_rad_s);
                w.f32(g.max_acceleration_rad_s2);
            }
            Request::SetDividers { speed, position } => {
                w.u16(*speed);
                w.u16(*position);
            }
            Request::SetWatchdog(c) => {
                w.u32(c.timeout_periods);
                w.u8(reaction_code(c.reaction));
            }
            Request::SetJoint(j) => put_joint(w, j),
            Request::StartHoming(h) => put_homing(w, h),
            Request::RunCalibration(c) => w.u8(*c as u8),
            Request::ReadParam(p) => w.u8(*p as u8),
            Request::StartTelemetry(rate) => match *rate {
                TelemetryRate::EveryPeriods(k) => {
                    w.u8(0);
                    w.u32(k);
                }
                TelemetryRate::Hz(hz) => {
                    w.u8(1);
                    w.f32(hz);
                }
            },
            Request::ReadConfig { source, offset } => {
                w.u8(*source as u8);
                w.u16(*offset);
            }
            Request::WriteConfig(c) => put_chunk(w, c),
            Request::Store(op) => w.u8(*op as u8),
        }
    }

    fn decode_body(tag: u8, r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        use tags::*;
        Ok(match tag {
            PING => Request::Ping,
            KEEP_ALIVE => Request::KeepAlive,
            SET_COMMAND => Request::SetCommand(get_command(r)?),
            SET_LIMITS => Request::SetLimits(Limits {
                max_current_a: r.f32()?,
                max_velocity_rad_s: r.f32()?,
                min_position_rad: r.f32()?,
                max_position_rad: r.f32()?,
                max_open_loop_voltage_v: r.f32()?,
                max_open_loop_omega_e_rad_s: r.f32()?,
                max_kp_nm_per_rad: r.f32()?,
                max_kd_nm_s_per_rad: r.f32()?,
            }),
            SET_CURRENT_GAINS => Request::SetCurrentGains(CurrentGains {
                kp_d: r.f32()?,
                ki_d: r.f32()?,
                kp_q: r.f32()?,
                ki_q: r.f32()?,
            }),
            SET_SPEED_GAINS => Request::SetSpeedGains(SpeedGains {
                kp_a_per_rad_s: r.f32()?,
                ki_a_per_rad: r.f32()?,
            }),
            SET_POSITION_GAINS => Request::SetPositionGains(PositionGains {
                kp_per_s: r.f32()?,
                max_velocity_rad_s: r.f32()?,
                max_acceleration_rad_s2: r.f32()?,
            }),
            SET_DIVIDERS => Request::SetDividers {
                speed: r.u16()?,
                position: r.u16()?,
            },
            SET_WATCHDOG => {
                let timeout_periods = r.u32()?;
                let reaction = reaction_from_code(r.u8()?).ok_or(DecodeError::BadField(1))?;
                Request::SetWatchdog(WatchdogConfig {
                    timeout_periods,
                    reaction,
                })
            }
            SET_JOINT => Request::SetJoint(get_joint(r)?),
            READ_JOINT => Request::ReadJoint,
            START_HOMING => Request::StartHoming(get_homing(r)?),
            READ_HOMING => Request::ReadHoming,
            SET_SCOPE => Request::SetScope(crate::scope::get_config(r)?),
            ARM_SCOPE => Request::ArmScope,
            TRIGGER_SCOPE => Request::TriggerScope,
            READ_SCOPE => Request::ReadScope,
            READ_SCOPE_DATA => Request::ReadScopeData { offset: r.u16()? },
            RUN_CALIBRATION => Request::RunCalibration(
                Calibration::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?,
            ),
            READ_FAULTS => Request::ReadFaults,
            CLEAR_FAULTS => Request::ClearFaults,
            READ_PARAM => {
                Request::ReadParam(ParamId::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?)
            }
            READ_TELEMETRY => Request::ReadTelemetry,
            START_TELEMETRY => Request::StartTelemetry(match r.u8()? {
                0 => TelemetryRate::EveryPeriods(r.u32()?),
                1 => TelemetryRate::Hz(r.f32()?),
                _ => return Err(DecodeError::BadField(0)),
            }),
            STOP_TELEMETRY => Request::StopTelemetry,
            READ_CONFIG => Request::ReadConfig {
                source: ConfigSource::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?,
                offset: r.u16()?,
            },
            WRITE_CONFIG => Request::WriteConfig(get_chunk(r)?),
            STORE => Request::Store(StoreOp::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?),
            _ => return Err(DecodeError::UnknownTag),
        })
    }
}

/// Device-to-host messages.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Response {
    /// Done / accepted.
    Ack,
    /// Refused; nothing changed.
    Nack(ErrorCode),
    /// Reply to `Ping`.
    Hello(Hello),
    /// Latched faults.
    Faults(FaultReport),
    /// A parameter value.
    Param {
        /// Which parameter.
        id: ParamId,
        /// Its value (in the unit of [`ParamId`]).
        value: f32,
    },
    /// A telemetry sample (reply to `ReadTelemetry`).
    Telemetry(Telemetry),
    /// A streamed telemetry sample (unsolicited; `seq` is a stream counter).
    Stream(Telemetry),
    /// A chunk of a configuration record (reply to `ReadConfig`).
    ConfigChunk(Chunk),
    /// The joint in force (reply to `ReadJoint`).
    Joint(JointSettings),
    /// Where homing stands (reply to `ReadHoming`).
    Homing(HomingState),
    /// The scope's state (reply to `ReadScope`).
    Scope(ScopeReport),
    /// Captured values (reply to `ReadScopeData`).
    ScopeData(ScopeData),
}

impl Message for Response {
    fn tag(&self) -> u8 {
        use tags::*;
        match self {
            Response::Ack => ACK,
            Response::Nack(_) => NACK,
            Response::Hello(_) => HELLO,
            Response::Faults(_) => FAULTS,
            Response::Param { .. } => PARAM,
            Response::Telemetry(_) => TELEMETRY,
            Response::Stream(_) => STREAM,
            Response::ConfigChunk(_) => CONFIG_CHUNK,
            Response::Joint(_) => JOINT,
            Response::Homing(_) => HOMING,
            Response::Scope(_) => SCOPE,
            Response::ScopeData(_) => SCOPE_DATA,
        }
    }

    fn encode_body(&self, w: &mut Writer<'_>) {
        match self {
            Response::Ack => {}
            Response::Nack(e) => {
                let (c, f) = e.to_wire();
                w.u8(c);
                w.u8(f);
            }
            Response::Hello(h) => {
                w.u8(h.protocol_version);
                w.bytes(&h.firmware_version);
                w.u8(h.max_payload);
            }
            Response::Faults(f) => {
                w.u32(f.set.0);
                w.u8(f.first_code);
            }
            Response::Param { id, value } => {
                w.u8(*id as u8);
                w.f32(*value);
            }
            Response::Telemetry(t) | Response::Stream(t) => {
                w.u32(t.period);
                w.f32(t.i_d_a);
                w.f32(t.i_q_a);
                w.f32(t.v_d_v);
                w.f32(t.v_q_v);
                w.f32(t.velocity_rad_s);
                w.f32(t.position_rad);
                w.u8(t.mode as u8);
                w.u8(t.fault_code);
                w.u32(t.max_loop_cycles);
                w.f32(t.v_bus_v);
                w.u8(t.power_limit as u8);
                w.u8(t.limit_left_pct.min(100));
                w.u8(u8::from(t.brake_on) | (u8::from(t.brake_locked) << 1));
                w.u16(temperature_to_wire(t.winding_c) as u16);
                w.u16(temperature_to_wire(t.stage_c) as u16);
            }
            Response::ConfigChunk(c) => put_chunk(w, c),
            Response::Joint(j) => put_joint(w, j),
            Response::Homing(h) => {
                let (state, reason) = h.to_wire();
                w.u8(state);
                w.u8(reason);
            }
            Response::Scope(r) => crate::scope::put_report(w, r),
            Response::ScopeData(d) => crate::scope::put_data(w, d),
        }
    }

    fn decode_body(tag: u8, r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        use tags::*;
        Ok(match tag {
            ACK => Response::Ack,
            NACK => {
                let code = r.u8()?;
                let field = r.u8()?;
                Response::Nack(ErrorCode::from_wire(code, field))
            }
            HELLO => Response::Hello(Hello {
                protocol_version: r.u8()?,
                firmware_version: [r.u8()?, r.u8()?, r.u8()?],
                max_payload: r.u8()?,
            }),
            FAULTS => Response::Faults(FaultReport {
                set: FaultSet(r.u32()?),
                first_code: r.u8()?,
            }),
            PARAM => Response::Param {
                id: ParamId::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?,
                value: r.f32()?,
            },
            TELEMETRY => Response::Telemetry(get_telemetry(r)?),
            STREAM => Response::Stream(get_telemetry(r)?),
            CONFIG_CHUNK => Response::ConfigChunk(get_chunk(r)?),
            JOINT => Response::Joint(get_joint(r)?),
            HOMING => {
                let state = r.u8()?;
                let reason = r.u8()?;
                Response::Homing(
                    HomingState::from_wire(state, reason).ok_or(DecodeError::BadField(0))?,
                )
            }
            SCOPE => Response::Scope(crate::scope::get_report(r)?),
            SCOPE_DATA => Response::ScopeData(crate::scope::get_data(r)?),
            _ => return Err(DecodeError::UnknownTag),
        })
    }
}
