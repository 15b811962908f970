//! The on-flash schema ([`DriveRecord`]), its envelope and its validation.
//!
//! These are plain structs, deliberately separate from foc-core's types: a
//! change to foc-core never silently changes what is stored. Nothing that
//! makes the bridge start by itself is stored (no command, no mode).
//!
//! # Envelope
//!
//! The bytes stored as the map value:
//!
//! ```text
//! version:u16 LE | len:u16 LE | postcard(DriveRecord) (len bytes) | crc32:u32 LE
//! ```
//!
//! The CRC is CRC-32/ISO-HDLC (the Ethernet/zlib CRC) over
//! `version | len | payload`. [`DriveRecord::decode`] checks the length, the
//! CRC, then the version, and never returns a partially decoded record.
//!
//! ```
//! use foc_store::record::{DriveRecord, MAX_RECORD_BYTES};
//! # let r = foc_store::record::example();
//! let mut buf = [0u8; MAX_RECORD_BYTES];
//! let n = r.encode(&mut buf).unwrap();
//! assert_eq!(DriveRecord::decode(&buf[..n]), Ok(r));
//! assert!(DriveRecord::decode(&buf[..n - 1]).is_err());
//! ```
//!
//! Files: this one the schema (the record and its sub-records, encoding);
//! `fields` the sub-records' checks and conversions; `tables` the
//! anticogging map and the angle sensor's correction (schema 9); `migrate`
//! the frozen older versions and their migration.

mod fields;
mod migrate;
mod tables;

pub use fields::*;
use migrate::migrate;
pub use migrate::{v1, v2, v3, v4, v5, v6, v7, v8, AngleRecordV6};
pub use tables::*;

use core::f32::consts::TAU;
use core::fmt;

use foc_core::angle::ElectricalAngle;
use foc_core::control::current::CurrentLoopConfig;
use foc_core::control::field::FieldConfig;
use foc_core::control::joint::{JointConfig, JointError, JointSetup, OutputFrame, TravelConfig};
use foc_core::control::permit::Calibrated;
use foc_core::control::power::PowerLimitsConfig;
use foc_core::control::stage::AngleCalibration;
use foc_core::control::{Limits, LimitsError, Mechanics, MotorParams};
use foc_core::tuning::CurrentPiGains;
use serde::{Deserialize, Serialize};

/// Version of the schema written by this build ([`DriveRecord`]'s postcard
/// layout). Bump it on any change of the layout and add a migration step in
/// `migrate` for the old version.
pub const SCHEMA_VERSION: u16 = 9;

/// Largest envelope (header, payload and CRC) in bytes. The largest record
/// of schema 9 (32-character label, every option `Some`, every varint at
/// its widest) takes 1861: 309 of schema 8's, the anticogging map 1032
/// and the angle correction 520 (see [`CoggingRecord`]); the rest is room
/// for a later schema. The link must move records this long
/// (`foc_protocol::config::MAX_RECORD`), and a flash page hold one
/// (`Store::new` checks it).
pub const MAX_RECORD_BYTES: usize = 2048;

/// A user label: printable ASCII, at most 32 bytes.
pub type Label = heapless::String<32>;

/// Motor parameters (as identified or supplied).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotorRecord {
    /// Pole pairs (>= 1).
    pub pole_pairs: u8,
    /// Phase resistance \[ohm\] (> 0).
    pub r_ohm: f32,
    /// d-axis inductance \[H\] (> 0).
    pub ld_h: f32,
    /// q-axis inductance \[H\] (> 0).
    pub lq_h: f32,
    /// Permanent-magnet flux linkage \[Wb\] (>= 0).
    pub flux_linkage_wb: f32,
}

/// Current-loop PI gains of both axes (all > 0).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CurrentGainsRecord {
    /// d-axis proportional gain [V/A].
    pub kp_d_v_per_a: f32,
    /// d-axis integral gain [V/(A s)].
    pub ki_d_v_per_a_s: f32,
    /// q-axis proportional gain [V/A].
    pub kp_q_v_per_a: f32,
    /// q-axis integral gain [V/(A s)].
    pub ki_q_v_per_a_s: f32,
}

/// The identified angle calibration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AngleRecord {
    /// Electrical angle the sensor reads when the rotor d axis is on phase A
    /// [rad, electrical], in `[0, 2 pi)`.
    pub zero_offset_e_rad: f32,
    /// True when the sensor counts backwards relative to A -> B -> C.
    pub reversed: bool,
    /// Pole pairs (must equal the motor's).
    pub pole_pairs: u8,
    /// Counts per mechanical turn of a counting sensor, 0 if unknown.
    pub sensor_counts_per_rev: u32,
    /// Made without an angle sensor (design §29): it unlocks the closed
    /// loop only while the drive runs sensorless. Absent in a text file:
    /// false (schema 7; older records had none).
    #[serde(default)]
    pub sensorless_only: bool,
}

/// Command limits (checked by foc-core's `Limits::validate`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitsRecord {
    /// Largest q-current reference \[A\].
    pub max_current_a: f32,
    /// Largest velocity [rad/s, mechanical].
    pub max_velocity_rad_s: f32,
    /// Lower end of the position range [rad, mechanical].
    pub min_position_rad: f32,
    /// Upper end of the position range [rad, mechanical].
    pub max_position_rad: f32,
    /// Largest open-loop voltage magnitude \[V\].
    pub max_open_loop_voltage_v: f32,
    /// Largest open-loop electrical speed [rad/s].
    pub max_open_loop_omega_e_rad_s: f32,
}

/// Speed-loop PI gains (>= 0).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpeedRecord {
    /// Proportional gain [A / (rad/s)].
    pub kp_a_per_rad_s: f32,
    /// Integral gain [A / rad].
    pub ki_a_per_rad: f32,
}

/// Position loop and trajectory.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionRecord {
    /// Proportional gain [(rad/s) / rad] (> 0).
    pub kp_per_s: f32,
    /// Trajectory velocity limit [rad/s] (> 0, at most the limits' one).
    pub max_velocity_rad_s: f32,
    /// Trajectory acceleration limit [rad/s^2] (> 0).
    pub max_acceleration_rad_s2: f32,
}

/// Loop rate dividers [current-loop periods per run] (>= 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DividersRecord {
    /// The speed loop runs every `speed` current-loop periods.
    pub speed: u16,
    /// The position loop runs every `position` current-loop periods.
    pub position: u16,
}

/// What the command watchdog does when it expires.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WatchdogReaction {
    /// Latch a fault (bridge off).
    Disable,
    /// Switch to velocity 0.
    Stop,
    /// Hold the current position.
    Hold,
}

/// The command watchdog.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[serde(deny_unknown_fields)]
pub struct WatchdogRecord {
    /// Current-loop periods without a command before the reaction (0 = off).
    pub timeout_periods: u32,
    /// The reaction.
    pub reaction: WatchdogReaction,
}

/// Power limits (design §18; foc-core's `PowerLimitsConfig` without the
/// motor model, which is the record's [`MotorRecord`]). `inf` switches a
/// limit or threshold off; NaN is refused.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PowerRecord {
    /// Bus voltage where regenerative current starts to be reduced \[V\].
    pub regen_start_v: f32,
    /// Bus voltage with no regenerative current left \[V\] (>= start).
    pub regen_end_v: f32,
    /// Largest d-axis braking current in the regen ramp \[A\] (>= 0, `inf`:
    /// up to the current limit, 0: off).
    pub regen_id_max_a: f32,
    /// Largest current drawn from the supply \[A\] (>= 0).
    pub bus_current_motoring_max_a: f32,
    /// Largest current returned to the supply \[A\] (>= 0).
    pub bus_current_regen_max_a: f32,
    /// Largest power drawn from the supply \[W\] (>= 0).
    pub power_motoring_max_w: f32,
    /// Largest power returned to the supply \[W\] (>= 0).
    pub power_regen_max_w: f32,
    /// Winding-to-ambient thermal resistance [K/W] (> 0, finite).
    pub thermal_resistance_k_per_w: f32,
    /// Winding thermal time constant \[s\] (>= 0, finite).
    pub thermal_time_constant_s: f32,
    /// Ambient temperature of the winding model [deg C] (finite).
    pub ambient_c: f32,
    /// Modelled winding temperature where derating starts [deg C].
    pub winding_derate_start_c: f32,
    /// Modelled winding temperature with no current left [deg C].
    pub winding_derate_end_c: f32,
    /// Measured stage temperature where derating starts [deg C].
    pub stage_derate_start_c: f32,
    /// Measured stage temperature with no current left [deg C].
    pub stage_derate_end_c: f32,
    /// Bus voltage where the brake chopper switches on \[V\].
    pub brake_on_v: f32,
    /// Bus voltage where it switches off again \[V\] (<= on).
    pub brake_off_v: f32,
    /// Longest the chopper stays on without a break \[s\] (>= 0, `inf`: no
    /// guard).
    pub brake_max_on_s: f32,
}

/// The rotor's identified mechanics (design §19; foc-core's `Mechanics`),
/// rotor frame, mechanical.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MechanicsRecord {
    /// Inertia of the rotor and its load [kg m^2] (finite, in
    /// [`Self::INERTIA_RANGE_KG_M2`]).
    pub inertia_kg_m2: f32,
    /// Viscous friction [N m s/rad] (finite, `>= 0`, at most
    /// [`Self::MAX_VISCOUS_FRICTION_NM_S_PER_RAD`]).
    pub viscous_friction_nm_s_per_rad: f32,
    /// Coulomb friction [N m] (finite, `>= 0`, at most
    /// [`Self::MAX_COULOMB_FRICTION_NM`]).
    pub coulomb_friction_nm: f32,
}

/// Running without the angle sensor (design §27): the start's current and
/// the bus it runs on; the rest (the flux observer's gains, the alignment,
/// the field, the hand-over speed) is derived from the motor, the rotor's
/// mechanics, the PWM rate and the board's dead time, so a record with
/// it needs mechanics (its own or the build's).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorlessRecord {
    /// Current of the start's alignment and field \[A\] (finite, `> 0`,
    /// at most `limits.max_current_a`): the torque the start has against a
    /// load.
    pub start_current_a: f32,
    /// Nominal bus voltage \[V\] (finite, in
    /// [`Self::BUS_RANGE_V`]): the hand-over speed's back-EMF is kept well
    /// above the voltage error the dead time makes on this bus.
    pub bus_voltage_v: f32,
    /// `None` (absent): the drive runs without its angle sensor. Else the
    /// observer runs beside the sensor in this role (schema 6).
    pub beside_sensor: Option<BesideRole>,
    /// With [`BesideRole::HallSensorless`]: the rotor speed above which the
    /// current loop runs on the observer's angle [rad/s, mechanical]
    /// (finite, `> 0`; absent: twice the observer's hand-over speed).
    pub observer_above_rad_s: Option<f32>,
}

/// The flux observer's role beside the angle sensor (design §27).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BesideRole {
    /// A plausibility check: a lasting disagreement with the sensor above
    /// the observer's hand-over speed latches `AngleSensorImplausible`.
    #[serde(rename = "check")]
    Check,
    /// The check, and under a velocity command the observer takes over
    /// when the sensor fails above that speed (limp-home).
    #[serde(rename = "limp-home")]
    LimpHome,
    /// Limp-home, and above `observer_above_rad_s` the current loop runs
    /// on the observer's angle (halls at low speed, the observer above).
    #[serde(rename = "hall+sensorless")]
    HallSensorless,
}

/// The d-current reference and the safe state by speed (design §30;
/// foc-core's `FieldConfig`, every value of it). Checked with foc-core's
/// own rule (`FieldConfig::check`) value by value; field weakening on a
/// coarse angle sensor (halls) is refused where the record is applied
/// ([`DriveRecord::apply`]: the board's sensor decides).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FieldRecord {
    /// Maximum torque per ampere (acts on a salient rotor: `Lq` more
    /// than 5 % above `Ld`).
    pub mtpa: bool,
    /// Field weakening above base speed (needs `max_id_a > 0`,
    /// `bandwidth_rad_s > 0`, `voltage_margin` >= 0.02 and a fine angle
    /// sensor).
    pub field_weakening: bool,
    /// Largest `|id|` field weakening may use \[A\] (finite, `>= 0`; the
    /// magnets' demagnetisation limit; at most the current limit is used).
    pub max_id_a: f32,
    /// Share of the voltage circle field weakening keeps free (0 to 0.5;
    /// at least 0.02 with field weakening: it also sets its slew).
    pub voltage_margin: f32,
    /// Field-weakening loop bandwidth \[rad/s\] (finite, `>= 0`).
    pub bandwidth_rad_s: f32,
    /// The active short circuit as the safe state above the speed where
    /// the back-EMF's peak exceeds the bus (else the bridge freewheels).
    pub short_circuit: bool,
}

/// The robot joint (design §21; foc-core's `JointSetup`) and the impedance
/// maxima of the command limits.
///
/// Two frames: the **output frame** (the shaft after the gearbox, zero at
/// the home position) and the **rotor frame** (the motor shaft, mechanical
/// radians, N m at the motor shaft), related by
/// `p_rotor = rotor_at_zero_rad + gear_ratio * p_output`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointRecord {
    /// Rotor turns per output turn, signed (negative: the output turns the
    /// other way); magnitude in [`OutputFrame::MIN_RATIO`]..=
    /// [`OutputFrame::MAX_RATIO`], 1 without a gearbox.
    pub gear_ratio: f32,
    /// The home offset: the rotor position where the output reads 0
    /// [rad, rotor, mechanical] (finite; set by homing).
    pub rotor_at_zero_rad: f32,
    /// Travel range `(min, max)` [rad, output] (finite, `min < max`, and
    /// finite in the rotor frame too); `None`: no travel limits, the
    /// record's `limits` position range (rotor frame) only checks commands.
    pub travel_out_rad: Option<(f32, f32)>,
    /// With a travel range: beyond it by more than this the drive faults
    /// (`Fault::TravelLimit`) [rad, rotor] (finite, `>= 0`).
    pub fault_margin_rad: f32,
    /// With a travel range: the deceleration its soft stop brakes with
    /// [rad/s^2, rotor] (finite, `> 0`).
    pub brake_accel_rad_s2: f32,
    /// With a travel range: the soft stop's velocity gain [A/(rad/s),
    /// rotor] (finite, `> 0`).
    pub kv_a_per_rad_s: f32,
    /// Current-loop periods over which the current moves to the impedance
    /// law's when impedance mode is entered (bumpless entry).
    pub entry_blend_periods: u32,
    /// Damping after a command timeout in impedance mode, when the
    /// command's own is smaller [N m s/rad, rotor] (finite, `>= 0`).
    pub timeout_kd_nm_s_per_rad: f32,
    /// Largest impedance stiffness a command may ask [N m/rad, rotor]
    /// (finite, `>= 0`; at the output: `* gear_ratio^2`).
    pub max_kp_nm_per_rad: f32,
    /// Largest impedance damping a command may ask [N m s/rad, rotor]
    /// (finite, `>= 0`; at the output: `* gear_ratio^2`).
    pub max_kd_nm_s_per_rad: f32,
}

/// Everything the drive keeps across power-off: configuration and the
/// identified calibration (the on-flash schema, version [`SCHEMA_VERSION`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveRecord {
    /// User label, printable ASCII.
    pub label: Label,
    /// The PWM rate the gains and watchdog periods were made for \[Hz\].
    pub pwm_frequency_hz: u32,
    /// Motor parameters.
    pub motor: MotorRecord,
    /// Current-loop gains.
    pub current_gains: CurrentGainsRecord,
    /// Angle calibration; `None`: never identified.
    pub calibration: Option<AngleRecord>,
    /// Command limits.
    pub limits: LimitsRecord,
    /// Speed loop.
    pub speed: SpeedRecord,
    /// Position loop.
    pub position: PositionRecord,
    /// Loop rate dividers.
    pub dividers: DividersRecord,
    /// Command watchdog.
    pub watchdog: WatchdogRecord,
    /// Power limits; `None`: the build's defaults for the board (what a
    /// version-1 record, from before the power limits, becomes).
    pub power: Option<PowerRecord>,
    /// The rotor's mechanics; `None`: not identified, the build's (what a
    /// version-1 or -2 record, from before they were stored, becomes).
    pub mechanics: Option<MechanicsRecord>,
    /// The joint (output frame, home offset, travel limits, impedance
    /// settings and maxima); `None`: the build's (what a version-1, -2 or
    /// -3 record, from before it was stored, becomes).
    pub joint: Option<JointRecord>,
    /// Run without the angle sensor (design §27); `None`: on the angle
    /// sensor (what a record from before schema 5 becomes).
    pub sensorless: Option<SensorlessRecord>,
    /// The d-current reference and the safe state by speed (design §30);
    /// `None`: the motor's defaults (foc-core's `FieldConfig::for_motor`
    /// with the record's motor, current limit and PWM rate: MTPA as
    /// foc-core decides for the motor, no field weakening, the short
    /// circuit where its current is within the limit), what a record from
    /// before schema 8 becomes.
    pub field: Option<FieldRecord>,
    /// The anticogging map (design §32), with its switch; `None`: none
    /// measured (what a record from before schema 9 becomes). Checked
    /// against `limits.max_current_a` (foc-core's `CoggingMap::check`).
    pub cogging: Option<CoggingRecord>,
    /// The angle sensor's correction (design §33: encoder linearisation),
    /// with its switch; `None`: none learnt (what a record from before
    /// schema 9 becomes). Referred to the sensor's reading, so applied
    /// only where the reading's zero survives a reset (the device
    /// service's rule).
    pub angle_correction: Option<CorrectionRecord>,
}

/// Why bytes are not a record (see [`DriveRecord::decode`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecordError {
    /// Fewer bytes than the envelope's header and CRC, or than its length
    /// field announces.
    TooShort,
    /// More bytes than the length field announces, more than
    /// [`MAX_RECORD_BYTES`], or (encoding) an output buffer too small.
    TooLong,
    /// The envelope's CRC does not match its contents.
    BadChecksum,
    /// A schema version this build cannot read.
    UnsupportedVersion {
        /// Version in the envelope.
        found: u16,
        /// [`SCHEMA_VERSION`] of this build.
        supported: u16,
    },
    /// The payload is not a record (postcard failed or left trailing bytes).
    Malformed,
}

impl fmt::Display for RecordError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::TooShort => f.write_str("the record is truncated"),
            Self::TooLong => {
                f.write_str("the record is longer than its envelope or the buffer allows")
            }
            Self::BadChecksum => f.write_str("the record's checksum does not match (corrupted)"),
            Self::UnsupportedVersion { found, supported } => write!(
                f,
                "the record has schema version {found}, this firmware reads version {supported}"
            ),
            Self::Malformed => f.write_str("the record's contents cannot be decoded"),
        }
    }
}

/// A record value out of range: `field` is its TOML path (e.g. `"motor.r_ohm"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Invalid {
    /// The offending field, as its TOML path.
    pub field: &'static str,
}

impl fmt::Display for Invalid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.field {
            // Not a range: the rule that combines it with others.
            "field.field_weakening" => write!(
                f,
                "record value `field.field_weakening` is refused: field weakening needs \
                 `max_id_a` > 0, `bandwidth_rad_s` > 0, `voltage_margin` >= {} and a fine \
                 angle sensor (not halls)",
                foc_core::control::field::MIN_VOLTAGE_MARGIN
            ),
            "cogging.table" => f.write_str(
                "record value `cogging.table` is refused: the anticogging map's peak is above \
                 the current limit `limits.max_current_a` (a measurement gone wrong, not \
                 cogging); measure it again",
            ),
            "angle_correction.table" => write!(
                f,
                "record value `angle_correction.table` is refused: the angle correction's \
                 peak is above {} rad (a sensor that far off is loose or broken); learn it \
                 again",
                foc_core::control::angle_correction::MAX_CORRECTION_RAD
            ),
            field => write!(f, "record value `{field}` is out of range"),
        }
    }
}

impl DriveRecord {
    /// Write the envelope into `out`; returns the number of bytes used.
    /// [`RecordError::TooLong`] when it does not fit in `out` or exceeds
    /// [`MAX_RECORD_BYTES`]. Does not validate (see [`Self::validate`]).
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, RecordError> {
        crate::envelope::seal(self, SCHEMA_VERSION, out, MAX_RECORD_BYTES)
    }

    /// Read an envelope: length, then CRC, then version ([`SCHEMA_VERSION`]
    /// decodes; a newer one is [`RecordError::UnsupportedVersion`]; an older
    /// one goes through the migration steps: version 1 to 8 records
    /// decode with `power`, `mechanics`, `joint`, `sensorless`, `field`,
    /// `cogging` and `angle_correction` at `None` where they had none).
    /// `bytes` must be exactly one envelope. Does not validate.
    pub fn decode(bytes: &[u8]) -> Result<DriveRecord, RecordError> {
        let (version, payload) = crate::envelope::open(bytes, MAX_RECORD_BYTES)?;
        match version.cmp(&SCHEMA_VERSION) {
            core::cmp::Ordering::Greater => Err(RecordError::UnsupportedVersion {
                found: version,
                supported: SCHEMA_VERSION,
            }),
            core::cmp::Ordering::Less => migrate(version, payload),
            core::cmp::Ordering::Equal => match postcard::take_from_bytes::<DriveRecord>(payload) {
                Ok((r, [])) => Ok(r),
                _ => Err(RecordError::Malformed),
            },
        }
    }

    /// Check every value (see the module docs of [`crate::record`] and the
    /// field docs); the error names the first bad field by its TOML path.
    pub fn validate(&self) -> Result<(), Invalid> {
        self.validate_motor_and_gains()?;
        self.validate_limits()?;
        self.validate_outer_loops()?;
        self.validate_options()?;
        self.validate_calibration()
    }

    /// The label, the PWM frequency, the motor and the current gains.
    fn validate_motor_and_gains(&self) -> Result<(), Invalid> {
        check(
            self.label.bytes().all(|b| (0x20..=0x7e).contains(&b)),
            "label",
        )?;
        check(self.pwm_frequency_hz > 0, "pwm_frequency_hz")?;

        let m = &self.motor;
        check(m.pole_pairs >= 1, "motor.pole_pairs")?;
        check(positive(m.r_ohm), "motor.r_ohm")?;
        check(positive(m.ld_h), "motor.ld_h")?;
        check(positive(m.lq_h), "motor.lq_h")?;
        check(non_negative(m.flux_linkage_wb), "motor.flux_linkage_wb")?;

        let g = &self.current_gains;
        check(positive(g.kp_d_v_per_a), "current_gains.kp_d_v_per_a")?;
        check(positive(g.ki_d_v_per_a_s), "current_gains.ki_d_v_per_a_s")?;
        check(positive(g.kp_q_v_per_a), "current_gains.kp_q_v_per_a")?;
        check(positive(g.ki_q_v_per_a_s), "current_gains.ki_q_v_per_a_s")
    }

    /// The limits, as foc-core checks them, each error by its TOML path.
    fn validate_limits(&self) -> Result<(), Invalid> {
        self.limits.to_limits().validate().map_err(|e| {
            invalid(match e {
                LimitsError::MaxCurrent => "limits.max_current_a",
                LimitsError::MaxVelocity => "limits.max_velocity_rad_s",
                LimitsError::MinPosition => "limits.min_position_rad",
                LimitsError::MaxPosition => "limits.max_position_rad",
                LimitsError::OpenLoopVoltage => "limits.max_open_loop_voltage_v",
                LimitsError::OpenLoopOmega => "limits.max_open_loop_omega_e_rad_s",
                // Not in this part: `to_limits` fills them valid (the
                // joint's are checked with it, below).
                LimitsError::MaxStiffness | LimitsError::MaxDamping => "limits",
            })
        })
    }

    /// The speed and position loops and their dividers.
    fn validate_outer_loops(&self) -> Result<(), Invalid> {
        check(
            non_negative(self.speed.kp_a_per_rad_s),
            "speed.kp_a_per_rad_s",
        )?;
        check(non_negative(self.speed.ki_a_per_rad), "speed.ki_a_per_rad")?;

        let p = &self.position;
        check(positive(p.kp_per_s), "position.kp_per_s")?;
        check(
            positive(p.max_velocity_rad_s)
                && p.max_velocity_rad_s <= self.limits.max_velocity_rad_s,
            "position.max_velocity_rad_s",
        )?;
        check(
            positive(p.max_acceleration_rad_s2),
            "position.max_acceleration_rad_s2",
        )?;

        check(self.dividers.speed >= 1, "dividers.speed")?;
        check(self.dividers.position >= 1, "dividers.position")
    }

    /// The optional parts: power limits, mechanics, joint, sensorless,
    /// the d-current reference, the tables.
    fn validate_options(&self) -> Result<(), Invalid> {
        if let Some(p) = &self.power {
            p.validate()?;
        }
        if let Some(mech) = &self.mechanics {
            mech.validate()?;
            // What foc-core's `CascadeConfig::set_mechanics` needs to derive
            // the loops from them: a torque constant.
            let kt = self.motor.to_params().torque_constant_nm_per_a();
            check(kt.is_finite() && kt > 0.0, "mechanics")?;
        }
        if let Some(j) = &self.joint {
            j.validate(&self.limits)?;
        }
        if let Some(sl) = &self.sensorless {
            sl.validate(&self.limits)?;
            // The observer follows the magnet's back-EMF; without the
            // sensor the position has no fixed zero, so no travel range.
            check(self.motor.flux_linkage_wb > 0.0, "sensorless")?;
            check(
                !sl.replaces_sensor() || self.joint.is_none_or(|j| j.travel_out_rad.is_none()),
                "sensorless",
            )?;
        }
        if let Some(f) = &self.field {
            f.validate()?;
        }
        if let Some(c) = &self.cogging {
            c.validate(self.limits.max_current_a)?;
        }
        if let Some(c) = &self.angle_correction {
            c.validate()?;
        }
        Ok(())
    }

    /// The calibration, if any: for this motor, and plausible with this
    /// record's current loop.
    fn validate_calibration(&self) -> Result<(), Invalid> {
        let m = &self.motor;
        if let Some(c) = &self.calibration {
            check(c.pole_pairs == m.pole_pairs, "calibration.pole_pairs")?;
            check(
                c.zero_offset_e_rad.is_finite() && (0.0..TAU).contains(&c.zero_offset_e_rad),
                "calibration.zero_offset_e_rad",
            )?;
            // The same plausibility check the firmware applies before it
            // unlocks the closed-loop modes with this calibration.
            let current = CurrentLoopConfig {
                ts_s: 1.0 / self.pwm_frequency_hz as f32,
                d_gains: self.current_gains.d(),
                q_gains: self.current_gains.q(),
                motor: m.to_params(),
                decoupling: true,
                max_modulation: 0.95,
                anti_windup: foc_core::control::current::DEFAULT_ANTI_WINDUP,
                delay_compensation_periods: 1.5,
                dead_time: foc_core::control::dead_time::DeadTimeCompensation::OFF,
            };
            Calibrated::supplied(c.to_calibration(), current)
                .map_err(|_| invalid("calibration"))?;
        }
        Ok(())
    }
}

/// A plausible record (for examples and tests).
#[doc(hidden)]
pub fn example() -> DriveRecord {
    DriveRecord {
        label: Label::try_from("bench motor").unwrap_or_default(),
        pwm_frequency_hz: 20_000,
        motor: MotorRecord {
            pole_pairs: 7,
            r_ohm: 0.2,
            ld_h: 60e-6,
            lq_h: 70e-6,
            flux_linkage_wb: 0.004,
        },
        current_gains: CurrentGainsRecord {
            kp_d_v_per_a: 0.3,
            ki_d_v_per_a_s: 1000.0,
            kp_q_v_per_a: 0.35,
            ki_q_v_per_a_s: 1000.0,
        },
        calibration: Some(AngleRecord {
            zero_offset_e_rad: 1.25,
            reversed: true,
            pole_pairs: 7,
            sensor_counts_per_rev: 4096,
            sensorless_only: false,
        }),
        limits: LimitsRecord {
            max_current_a: 5.0,
            max_velocity_rad_s: 300.0,
            min_position_rad: -100.0,
            max_position_rad: 100.0,
            max_open_loop_voltage_v: 3.0,
            max_open_loop_omega_e_rad_s: 500.0,
        },
        speed: SpeedRecord {
            kp_a_per_rad_s: 0.05,
            ki_a_per_rad: 1.5,
        },
        position: PositionRecord {
            kp_per_s: 30.0,
            max_velocity_rad_s: 100.0,
            max_acceleration_rad_s2: 1000.0,
        },
        dividers: DividersRecord {
            speed: 10,
            position: 20,
        },
        watchdog: WatchdogRecord {
            timeout_periods: 2000,
            reaction: WatchdogReaction::Stop,
        },
        power: Some(PowerRecord {
            regen_start_v: 25.5,
            regen_end_v: 28.5,
            regen_id_max_a: f32::INFINITY,
            bus_current_motoring_max_a: 10.0,
            bus_current_regen_max_a: 2.0,
            power_motoring_max_w: f32::INFINITY,
            power_regen_max_w: f32::INFINITY,
            thermal_resistance_k_per_w: 2.0,
            thermal_time_constant_s: 60.0,
            ambient_c: 40.0,
            winding_derate_start_c: 100.0,
            winding_derate_end_c: 120.0,
            stage_derate_start_c: 65.0,
            stage_derate_end_c: 85.0,
            brake_on_v: f32::INFINITY,
            brake_off_v: f32::INFINITY,
            brake_max_on_s: 1.0,
        }),
        mechanics: Some(MechanicsRecord {
            inertia_kg_m2: 2.5e-5,
            viscous_friction_nm_s_per_rad: 1.0e-5,
            coulomb_friction_nm: 0.002,
        }),
        joint: Some(JointRecord {
            gear_ratio: -9.0,
            rotor_at_zero_rad: 1.5,
            travel_out_rad: Some((-1.5, 2.0)),
            fault_margin_rad: 0.25,
            brake_accel_rad_s2: 2000.0,
            kv_a_per_rad_s: 0.05,
            entry_blend_periods: 200,
            timeout_kd_nm_s_per_rad: 0.001,
            max_kp_nm_per_rad: 20.0,
            max_kd_nm_s_per_rad: 0.5,
        }),
        sensorless: None,
        field: Some(FieldRecord {
            mtpa: false,
            field_weakening: true,
            max_id_a: 4.0,
            voltage_margin: 0.05,
            bandwidth_rad_s: 2000.0,
            short_circuit: false,
        }),
        cogging: Some(CoggingRecord {
            enabled: true,
            scale_a: 1e-5,
            // A saw of 42 points a cycle, peak 0.21 A.
            table: Counts(core::array::from_fn(|k| ((k % 42) as i16 - 21) * 1000)),
        }),
        angle_correction: Some(CorrectionRecord {
            enabled: false,
            scale_rad: 1e-6,
            // A ramp over the turn, peak 12.8 mrad.
            table: Counts(core::array::from_fn(|k| (k as i16 - 128) * 100)),
        }),
    }
}
