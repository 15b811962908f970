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
//! | 0x18 | `SetParam` | `id:u8` (a writable [`ParamId`]: [`ParamId::is_writable`]) `value:f32` (its unit; an on/off parameter 0 or 1; checked with [`ParamId::accepts`]) | `Ack` (only while disabled) |
//! | 0x20 | `RunCalibration` | `routine:u8` (0 offsets, 1 identification, 2 alignment, 3 anticogging, 4 encoder linearisation) | `Ack` (started) |
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
//!
//! Files: this one the message types; `telemetry` the telemetry sample and
//! its wire codes; `codec` the encoding of requests and replies.

mod codec;
mod progress;
mod telemetry;

pub use progress::*;
pub use telemetry::*;

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
    /// The anticogging map (design §32): a slow sweep both ways on the
    /// closed loop; the map is installed (switched on) and kept with the
    /// configuration by the next save. Needs a calibrated drive and the
    /// angle at low speed (`foc_core::drive::Status::check_sweep`).
    Anticogging = 3,
    /// The angle sensor's correction (design §33: encoder linearisation):
    /// turns at a constant speed both ways; installed (switched on) and
    /// kept by the next save. Needs a calibrated drive on a fine angle
    /// sensor (not halls, not sensorless).
    EncoderLinearisation = 4,
}

impl Calibration {
    /// From its wire code.
    pub const fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Self::Offsets),
            1 => Some(Self::Identification),
            2 => Some(Self::Alignment),
            3 => Some(Self::Anticogging),
            4 => Some(Self::EncoderLinearisation),
            _ => None,
        }
    }

    /// The sweep calibration this routine is (`None`: not a sweep).
    pub const fn sweep(self) -> Option<foc_core::drive::Sweep> {
        match self {
            Self::Anticogging => Some(foc_core::drive::Sweep::Cogging),
            Self::EncoderLinearisation => Some(foc_core::drive::Sweep::Encoder),
            Self::Offsets | Self::Identification | Self::Alignment => None,
        }
    }
}

/// How often to stream telemetry.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TelemetryRate {
    /// One sample every K current-loop periods (K >= 1).
    EveryPeriods(u32),
    /// A rate \[Hz\] (converted with the PWM frequency; at most that).
    Hz(f32),
}

macro_rules! param_ids {
    ($( $(#[$doc:meta])* $name:ident = $code:expr, $text:expr, $unit:expr; )*) => {
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
            /// Its unit, for people (`""` for a count or a code).
            pub const fn unit(self) -> &'static str {
                match self { $( ParamId::$name => $unit, )* }
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
    PolePairs = 0, "pole-pairs", "";
    /// Phase resistance \[ohm\].
    ResistanceOhm = 1, "r", "ohm";
    /// d-axis inductance \[H\].
    LdH = 2, "ld", "H";
    /// q-axis inductance \[H\].
    LqH = 3, "lq", "H";
    /// Flux linkage \[Wb\].
    FluxLinkageWb = 4, "psi", "Wb";
    /// PWM = current-loop frequency \[Hz\].
    PwmFrequencyHz = 5, "pwm-frequency", "Hz";
    /// Speed loop every N periods.
    SpeedDivider = 6, "speed-divider", "periods";
    /// Position loop every M periods.
    PositionDivider = 7, "position-divider", "periods";
    /// Firmware version as `major * 10000 + minor * 100 + patch`.
    FirmwareVersion = 8, "firmware-version", "";
    /// Protocol version ([`crate::PROTOCOL_VERSION`]; answered by the protocol layer).
    ProtocolVersion = 9, "protocol-version", "";
    /// Bus voltage \[V\].
    BusVoltageV = 10, "bus-voltage", "V";
    /// 1 when calibrated, else 0.
    Calibrated = 11, "calibrated", "";
    /// Longest current-loop run so far [CPU cycles].
    MaxLoopCycles = 12, "max-loop-cycles", "CPU cycles";
    /// Telemetry divider in force (periods; 0 = streaming off; answered by the protocol layer).
    TelemetryDivider = 13, "telemetry-divider", "periods";
    /// Watchdog timeout \[periods\] (0 = off; answered by the protocol layer).
    WatchdogTimeout = 14, "watchdog-timeout", "periods";
    /// Current-loop proportional gain, q axis [V/A].
    CurrentKp = 15, "current-kp", "V/A";
    /// Current-loop integral gain, q axis [V/(A s)].
    CurrentKi = 16, "current-ki", "V/(A s)";
    /// Speed-loop proportional gain [A/(rad/s)] (rotor).
    SpeedKp = 17, "speed-kp", "A/(rad/s)";
    /// Speed-loop integral gain [A/rad] (rotor).
    SpeedKi = 18, "speed-ki", "A/rad";
    /// Position-loop gain [(rad/s)/rad].
    PositionKp = 19, "position-kp", "1/s";
    /// Values the scope buffer holds (0: no scope).
    ScopeCapacity = 20, "scope-capacity", "values";
    /// The angle in use (design §27; the telemetry's `angle_in_use`): 0
    /// the angle sensor, 1 sensorless (the flux observer), 2 the observer
    /// beside the sensor above its speed (halls + sensorless), 3
    /// limp-home (the observer, the sensor having failed). At 1 and 3
    /// torque, position and impedance commands are refused.
    AngleSource = 21, "angle-source", "";
    /// The calibration running or last run: its step
    /// ([`progress_codes`]): 0 none, 1 current offsets, 2 resistance, 3
    /// inductance, 4 current-loop gains, 5 sensor alignment, 6 flux
    /// linkage, 7 mechanics, 8 finished, 9 the angle sensor's check, 10
    /// anticogging, 11 encoder linearisation.
    CalibrationStep = 22, "calibration-step", "";
    /// How it stands ([`progress_codes`]): 0 none since reset, 1 running,
    /// 2 done, 3 aborted (by a fault or a `Disable`), 4 offsets rejected, 5
    /// the angle sensor's check failed, 32 + n failed for reason n
    /// ([`FAILURE_REASONS`]).
    CalibrationResult = 23, "calibration-result", "";
    /// The board's hardware current limit \[A\]: no limit or record goes
    /// above it (a request that does is refused `Unsupported`).
    BoardMaxCurrentA = 24, "board-max-current", "A";
    /// The current limit in force \[A\] (commands are checked against the
    /// limits in force: the motor's, rotor frame, with the joint's travel
    /// range as the position range where it has one).
    MaxCurrentA = 25, "max-current", "A";
    /// The velocity limit in force [rad/s, rotor].
    MaxVelocityRadS = 26, "max-velocity", "rad/s";
    /// The lowest position in force \[rad, rotor\].
    MinPositionRad = 27, "min-position", "rad";
    /// The highest position in force \[rad, rotor\].
    MaxPositionRad = 28, "max-position", "rad";
    /// The open-loop voltage limit in force \[V\].
    MaxOpenLoopVoltageV = 29, "max-open-loop-voltage", "V";
    /// The open-loop speed limit in force [rad/s, electrical].
    MaxOpenLoopOmegaERadS = 30, "max-open-loop-omega-e", "rad/s";
    /// The largest impedance stiffness in force [N m/rad, rotor].
    MaxImpedanceKp = 31, "max-impedance-kp", "N m/rad";
    /// The largest impedance damping in force [N m s/rad, rotor].
    MaxImpedanceKd = 32, "max-impedance-kd", "N m s/rad";
    /// Field weakening above base speed (design §30): 1 on, 0 off.
    /// Writable ([`Request::SetParam`]); refused (`Unsupported`) on a
    /// coarse angle sensor (halls), or with `max-id` 0.
    FieldWeakening = 33, "field-weakening", "";
    /// Maximum torque per ampere (design §30; acts on a salient rotor):
    /// 1 on, 0 off. Writable.
    Mtpa = 34, "mtpa", "";
    /// The largest `|id|` field weakening may use \[A\] (the magnets'
    /// demagnetisation limit; at most the current limit is used): finite,
    /// `>= 0`, below 10^6. Writable.
    MaxIdA = 35, "max-id", "A";
    /// The active short circuit as the safe state above the speed where
    /// the back-EMF's peak exceeds the bus (design §30): 1 on, 0 off
    /// (freewheeling). Writable.
    ShortCircuit = 36, "short-circuit", "";
    /// The anticogging feed-forward (design §32): 1 on, 0 off. Writable;
    /// switching it on without a map (never measured, nor loaded with the
    /// configuration) is refused `NotCalibrated`.
    Anticogging = 37, "anticogging", "";
    /// The angle sensor's correction (design §33, encoder
    /// linearisation): 1 on, 0 off. Writable; on without a correction is
    /// refused `NotCalibrated`.
    EncoderLinearisation = 38, "encoder-linearisation", "";
    /// The anticogging map's largest feed-forward \[A\] (0: no map).
    AnticoggingPeakA = 39, "anticogging-peak", "A";
    /// The angle correction's largest correction [rad, mechanical] (0:
    /// none).
    EncoderCorrectionPeakRad = 40, "encoder-correction-peak", "rad";
}

impl ParamId {
    /// True for the parameters [`Request::SetParam`] writes: the
    /// d-current reference's (design §30), whole in the drive's
    /// `FieldConfig`, and the switches of the tables kept with the
    /// configuration (design §32, §33).
    pub const fn is_writable(self) -> bool {
        matches!(
            self,
            ParamId::FieldWeakening
                | ParamId::Mtpa
                | ParamId::MaxIdA
                | ParamId::ShortCircuit
                | ParamId::Anticogging
                | ParamId::EncoderLinearisation
        )
    }

    /// True for an on/off setting (1 on, 0 off).
    pub const fn is_switch(self) -> bool {
        matches!(
            self,
            ParamId::FieldWeakening
                | ParamId::Mtpa
                | ParamId::ShortCircuit
                | ParamId::Anticogging
                | ParamId::EncoderLinearisation
        )
    }

    /// True when `value` may be written to this parameter: a writable one
    /// ([`Self::is_writable`]), 0 or 1 for a switch, and for `max-id` a
    /// current foc-core's own rule takes (`FieldConfig::check`: finite,
    /// `>= 0`, below 10^6). The rest of the rule (field weakening needs a
    /// fine angle sensor and `max-id` above 0) is the drive's: see
    /// `foc_core::drive::check_field`.
    pub fn accepts(self, value: f32) -> bool {
        use foc_core::control::field::FieldConfig;
        match self {
            ParamId::FieldWeakening
            | ParamId::Mtpa
            | ParamId::ShortCircuit
            | ParamId::Anticogging
            | ParamId::EncoderLinearisation => value == 0.0 || value == 1.0,
            ParamId::MaxIdA => FieldConfig {
                max_id_a: value,
                ..FieldConfig::OFF
            }
            .check()
            .is_ok(),
            _ => false,
        }
    }
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
    /// The drive runs without its angle sensor: torque, position and
    /// impedance commands need it (velocity and open loop are taken).
    NeedsAngleSensor,
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
            Self::NeedsAngleSensor => (14, 0),
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
            14 => Self::NeedsAngleSensor,
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
    /// Largest payload the device accepts \[bytes\].
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
    /// Write a parameter ([`ParamId::is_writable`]: the d-current
    /// reference's, the tables' switches; only while disabled).
    SetParam {
        /// Which parameter.
        id: ParamId,
        /// Its value, in its unit (a switch: 0 or 1).
        value: f32,
    },
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
            Request::SetParam { .. } => &["id", "value"],
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
