//! The robot joint on the wire (design §21): which frame a value travels
//! in, the joint settings, homing.
//!
//! # The frame rule
//!
//! The drive runs in the **rotor frame** (the motor shaft); a joint is used
//! in the **output frame** (the shaft after the gearbox, zero at the home
//! point): `p_out = (p_rotor - rotor_at_zero) / g`, `v_out = v_rotor / g`,
//! `T_out = T_rotor * g`, `k_out = k_rotor * g^2` (see
//! [`foc_core::control::joint::OutputFrame`]). On the link:
//!
//! - **Output frame**: every position, velocity, torque, stiffness and
//!   damping of a command (`SetCommand` position, velocity, impedance), of
//!   telemetry (`position_rad`, `velocity_rad_s`), of a homing request
//!   (search velocity, back-off, longest travel, home position) and the
//!   joint's travel range. The [`crate::device::DeviceState`] converts with
//!   the joint's frame ([`crate::device::DeviceContext::joint`]) on the way
//!   in and out; the context only ever sees the rotor frame.
//! - **Rotor frame**: the motor's own limits (`SetLimits`: velocity limit,
//!   position range, impedance stiffness and damping maxima) and the joint's
//!   rotor-side settings (home offset `rotor_at_zero_rad`, fault margin,
//!   braking deceleration, timeout damping).
//! - **No frame**: currents (torque mode's `iq_a`, the homing current,
//!   telemetry currents), voltages, electrical angles and speeds (open
//!   loop), the soft stop's gain in A/(rad/s) of the rotor.
//!
//! Without a joint set up the frame is the identity (gear 1, zero at the
//! rotor's zero): both frames are the same numbers.

use crate::message::Telemetry;
use foc_core::control::homing::{EndStop, HomingError, HomingMethod};
use foc_core::control::joint::{
    Impedance, JointConfig, JointError, JointSetup, OutputFrame, TravelConfig,
};
use foc_core::control::{Command, CommandError, Feedback, Limits, Mode};

/// A joint's settings as they travel (`SetJoint`, the `Joint` reply): the
/// fields of a [`JointSetup`], flat and unchecked (a decoded message may
/// hold anything; the device checks them with [`Self::to_setup`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JointSettings {
    /// Rotor turns per output turn, signed (negative: the output turns the
    /// other way); `|g|` in [`OutputFrame::MIN_RATIO`]..=[`OutputFrame::MAX_RATIO`].
    pub gear_ratio: f32,
    /// The rotor position where the output reads 0 [rad, rotor] (the home
    /// offset; set by homing).
    pub rotor_at_zero_rad: f32,
    /// Travel range `(min, max)` [rad, output], `min < max`; `None`: the
    /// motor's own position range (`SetLimits`), no soft stop.
    pub travel_out_rad: Option<(f32, f32)>,
    /// Beyond the travel range by more than this, the drive faults
    /// (`TravelLimit`) [rad, rotor] (>= 0; used with a travel range).
    pub fault_margin_rad: f32,
    /// Deceleration of the soft stop at the travel range's ends
    /// [rad/s^2, rotor] (> 0; used with a travel range).
    pub brake_accel_rad_s2: f32,
    /// The soft stop's velocity gain [A/(rad/s), rotor] (> 0; used with a
    /// travel range).
    pub kv_a_per_rad_s: f32,
    /// Current-loop periods over which impedance mode blends in from the
    /// current in force (bumpless entry).
    pub entry_blend_periods: u32,
    /// Least damping after an impedance command times out
    /// [N m s/rad, rotor] (>= 0).
    pub timeout_kd_nm_s_per_rad: f32,
}

/// Field numbers of `SetJoint` (body order), for Nacks.
mod field {
    pub const GEAR_RATIO: u8 = 0;
    pub const ROTOR_AT_ZERO: u8 = 1;
    pub const TRAVEL_MIN: u8 = 3;
    pub const TRAVEL_MAX: u8 = 4;
    pub const FAULT_MARGIN: u8 = 5;
    pub const BRAKE_ACCEL: u8 = 6;
    pub const KV: u8 = 7;
    pub const TIMEOUT_KD: u8 = 9;
}

impl JointSettings {
    /// The settings of a joint set up.
    pub fn from_setup(s: &JointSetup) -> Self {
        Self {
            gear_ratio: s.frame.gear_ratio(),
            rotor_at_zero_rad: s.frame.rotor_at_zero_rad(),
            travel_out_rad: s.travel_out_rad,
            fault_margin_rad: s.travel.fault_margin_rad,
            brake_accel_rad_s2: s.travel.brake_accel_rad_s2,
            kv_a_per_rad_s: s.travel.kv_a_per_rad_s,
            entry_blend_periods: s.joint.entry_blend_periods,
            timeout_kd_nm_s_per_rad: s.joint.timeout_kd_nm_s_per_rad,
        }
    }

    /// Check every value and make the joint: the number of the first
    /// field (body order) out of range on error. On top of
    /// [`JointSetup::validate`]: the travel range must stay finite and
    /// ordered in the rotor frame (the drive's position range).
    pub fn to_setup(&self) -> Result<JointSetup, u8> {
        let frame =
            OutputFrame::check(self.gear_ratio, self.rotor_at_zero_rad).map_err(|e| match e {
                JointError::GearRatio => field::GEAR_RATIO,
                JointError::Offset | JointError::Travel => field::ROTOR_AT_ZERO,
            })?;
        let travel = TravelConfig {
            fault_margin_rad: self.fault_margin_rad,
            brake_accel_rad_s2: self.brake_accel_rad_s2,
            kv_a_per_rad_s: self.kv_a_per_rad_s,
        };
        if let Some((lo, hi)) = self.travel_out_rad {
            check_travel(&frame, lo, hi, &travel)?;
        }
        if !non_negative(self.timeout_kd_nm_s_per_rad) {
            return Err(field::TIMEOUT_KD);
        }
        let setup = JointSetup {
            frame,
            travel_out_rad: self.travel_out_rad,
            travel,
            joint: JointConfig {
                travel: None,
                entry_blend_periods: self.entry_blend_periods,
                timeout_kd_nm_s_per_rad: self.timeout_kd_nm_s_per_rad,
            },
        };
        // The drive's own check (the field is a fallback: every case it
        // refuses was named above).
        setup.validate().map_err(|_| field::GEAR_RATIO)?;
        Ok(setup)
    }
}

/// The field of the first value that is not finite, `values` being the
/// fields from `first` on.
fn first_non_finite(values: &[f32], first: u8) -> Option<u8> {
    let n = values.iter().position(|x| !x.is_finite())?;
    Some(first.saturating_add(u8::try_from(n).unwrap_or(u8::MAX)))
}

fn non_negative(x: f32) -> bool {
    x.is_finite() && x >= 0.0
}

fn positive(x: f32) -> bool {
    x.is_finite() && x > 0.0
}

/// The travel range and its soft stop, field-exact.
fn check_travel(frame: &OutputFrame, lo: f32, hi: f32, t: &TravelConfig) -> Result<(), u8> {
    if !lo.is_finite() {
        return Err(field::TRAVEL_MIN);
    }
    if !(hi.is_finite() && lo < hi) {
        return Err(field::TRAVEL_MAX);
    }
    let (a, b) = frame.range_to_rotor(lo, hi);
    if !(a.is_finite() && b.is_finite() && a < b) {
        return Err(field::TRAVEL_MAX);
    }
    if !non_negative(t.fault_margin_rad) {
        return Err(field::FAULT_MARGIN);
    }
    if !positive(t.brake_accel_rad_s2) {
        return Err(field::BRAKE_ACCEL);
    }
    if !positive(t.kv_a_per_rad_s) {
        return Err(field::KV);
    }
    Ok(())
}

/// The joint of a device that has none: identity frame, no travel range,
/// no impedance entry blend, no timeout damping.
pub const NO_JOINT: JointSetup = JointSetup {
    frame: OutputFrame::IDENTITY,
    travel_out_rad: None,
    travel: TravelConfig {
        fault_margin_rad: 0.0,
        brake_accel_rad_s2: 1.0,
        kv_a_per_rad_s: 1.0,
    },
    joint: JointConfig {
        travel: None,
        entry_blend_periods: 0,
        timeout_kd_nm_s_per_rad: 0.0,
    },
};

/// The command limits in force [rotor frame]: the motor's `limits` with,
/// when the joint has a travel range, that range (in the rotor frame) as
/// the position range (what the drive's stage holds after a `SetJoint`).
pub fn limits_in_force(limits: &Limits, joint: &JointSetup) -> Limits {
    let c = joint.rotor_change((limits.min_position_rad, limits.max_position_rad));
    Limits {
        min_position_rad: c.min_position_rad,
        max_position_rad: c.max_position_rad,
        ..*limits
    }
}

/// A command as the host gives it (output frame) in the rotor frame.
/// Torque (a current) and open loop (electrical) have no frame.
pub fn command_to_rotor(c: &Command, f: &OutputFrame) -> Command {
    match *c {
        Command::Position { rad } => Command::Position {
            rad: f.position_to_rotor(rad),
        },
        Command::Velocity { rad_s } => Command::Velocity {
            rad_s: f.velocity_to_rotor(rad_s),
        },
        Command::Impedance(i) => Command::Impedance(f.impedance_to_rotor(&i)),
        other => other,
    }
}

/// A telemetry sample of the drive (rotor frame) as the host gets it:
/// position and velocity at the output; currents, voltages and the rest
/// unchanged.
pub fn telemetry_to_output(t: &Telemetry, f: &OutputFrame) -> Telemetry {
    Telemetry {
        position_rad: f.position_to_output(t.position_rad),
        velocity_rad_s: f.velocity_to_output(t.velocity_rad_s),
        ..*t
    }
}

/// The fields of an impedance command the conversion to the rotor frame
/// would hide (the torque limit's sign: the rotor-frame limit is its
/// magnitude): the field number (in the `SetCommand` body) of a
/// non-finite value or a negative torque limit.
pub fn impedance_precheck(i: &Impedance) -> Result<(), u8> {
    let values = [
        i.position_rad,
        i.velocity_rad_s,
        i.kp_nm_per_rad,
        i.kd_nm_s_per_rad,
        i.torque_ff_nm,
    ];
    if let Some(f) = first_non_finite(&values, 1) {
        return Err(f);
    }
    if i.torque_limit_nm.is_nan() || i.torque_limit_nm < 0.0 {
        return Err(6);
    }
    Ok(())
}

/// The field (in the `SetCommand` body) a rotor-frame impedance command's
/// refusal points at.
pub fn impedance_field(i: &Impedance, e: CommandError) -> u8 {
    match e {
        CommandError::NonFinite => impedance_precheck(i).err().unwrap_or(1),
        CommandError::PositionOutOfRange => 1,
        CommandError::VelocityOutOfRange => 2,
        CommandError::StiffnessOutOfRange => 3,
        CommandError::DampingOutOfRange => 4,
        // The torque limit's sign (the only current a command carries).
        _ => 6,
    }
}

/// A homing request (`StartHoming`), **output frame**: an end stop's
/// search velocity, back-off and longest travel are output-frame values
/// here (the device converts them); its current \[A\], detection fraction
/// and confirmation time have no frame.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HomingStart {
    /// How to home.
    pub method: HomingMethod,
    /// The output position the home point gets [rad, output]: the new
    /// frame reads this there.
    pub home_output_rad: f32,
}

/// Field numbers of `StartHoming` (body order).
mod homing_field {
    pub const HOME: u8 = 1;
    pub const VELOCITY: u8 = 2;
    pub const CURRENT: u8 = 3;
    pub const DETECT: u8 = 4;
    pub const CONFIRM: u8 = 5;
    pub const BACKOFF: u8 = 6;
    pub const MAX_TRAVEL: u8 = 7;
}

impl HomingStart {
    /// The method in the rotor frame of `f`.
    pub fn method_in_rotor(&self, f: &OutputFrame) -> HomingMethod {
        match self.method {
            HomingMethod::Present => HomingMethod::Present,
            HomingMethod::EndStop(e) => {
                let g = f.gear_ratio().abs();
                HomingMethod::EndStop(EndStop {
                    velocity_rad_s: f.velocity_to_rotor(e.velocity_rad_s),
                    backoff_rad: e.backoff_rad * g,
                    max_travel_rad: e.max_travel_rad * g,
                    ..e
                })
            }
        }
    }

    /// Values that are not finite: the first one's field.
    pub fn check_finite(&self) -> Result<(), u8> {
        if !self.home_output_rad.is_finite() {
            return Err(homing_field::HOME);
        }
        if let HomingMethod::EndStop(e) = self.method {
            if let Some(f) = first_non_finite(&end_stop_values(&e), homing_field::VELOCITY) {
                return Err(f);
            }
        }
        Ok(())
    }
}

/// An end stop's values in body order.
fn end_stop_values(e: &EndStop) -> [f32; 6] {
    [
        e.velocity_rad_s,
        e.current_a,
        e.detect_fraction,
        e.confirm_s,
        e.backoff_rad,
        e.max_travel_rad,
    ]
}

/// The field (in the `StartHoming` body) a refused end-stop search points
/// at: `e` as the host gave it. A search whose damping (`kt I / v`) is
/// above the limit points at the velocity (search faster or with less
/// current), a back-off spring (`kt I / backoff`) above the stiffness
/// limit at the back-off.
pub fn end_stop_field(e: &EndStop, err: CommandError) -> u8 {
    match err {
        CommandError::NonFinite => first_non_finite(&end_stop_values(e), homing_field::VELOCITY)
            .unwrap_or(homing_field::VELOCITY),
        CommandError::VelocityOutOfRange => homing_field::VELOCITY,
        CommandError::CurrentOutOfRange => homing_field::CURRENT,
        // The search's and back-off's spring is `kt I / backoff`, damped
        // with it over 50 ms: a longer back-off softens both.
        CommandError::StiffnessOutOfRange | CommandError::DampingOutOfRange => {
            homing_field::BACKOFF
        }
        _ if !(e.detect_fraction > 0.0 && e.detect_fraction < 1.0) => homing_field::DETECT,
        _ if e.confirm_s < 0.0 => homing_field::CONFIRM,
        _ if e.backoff_rad <= 0.0 => homing_field::BACKOFF,
        _ => homing_field::MAX_TRAVEL,
    }
}

/// Why a homing did not finish.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum HomingFailure {
    /// No end stop within the longest travel.
    NoStop = 1,
    /// The drive left impedance mode (a fault, the bridge off).
    Interrupted = 2,
    /// A command from the host took over.
    Aborted = 3,
    /// The drive refused a homing command or the new frame.
    Refused = 4,
}

impl HomingFailure {
    /// From its wire code.
    pub const fn from_code(c: u8) -> Option<Self> {
        match c {
            1 => Some(Self::NoStop),
            2 => Some(Self::Interrupted),
            3 => Some(Self::Aborted),
            4 => Some(Self::Refused),
            _ => None,
        }
    }

    /// What it means, for people.
    pub const fn text(self) -> &'static str {
        match self {
            Self::NoStop => "no end stop within the longest travel",
            Self::Interrupted => "interrupted (a fault, or the bridge went off)",
            Self::Aborted => "aborted by a command from the host",
            Self::Refused => "the drive refused a homing command or the new frame",
        }
    }
}

impl From<HomingError> for HomingFailure {
    fn from(e: HomingError) -> Self {
        match e {
            HomingError::NoStop => Self::NoStop,
            HomingError::Interrupted => Self::Interrupted,
            HomingError::Invalid(_) => Self::Refused,
        }
    }
}

/// Where homing stands (`ReadHoming`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingState {
    /// Never started since the device started.
    #[default]
    Idle,
    /// Searching or backing off.
    Running,
    /// Homed: the joint's frame was set (read it with `ReadJoint`).
    Done,
    /// Failed; the bridge was disabled (unless a host command took over).
    Failed(HomingFailure),
}

impl HomingState {
    /// Wire code and reason (`HomingFailure` code, 0 unless failed).
    pub const fn to_wire(self) -> (u8, u8) {
        match self {
            Self::Idle => (0, 0),
            Self::Running => (1, 0),
            Self::Done => (2, 0),
            Self::Failed(f) => (3, f as u8),
        }
    }

    /// From wire code and reason; `None` for an unknown one.
    pub const fn from_wire(code: u8, reason: u8) -> Option<Self> {
        match (code, reason) {
            (0, 0) => Some(Self::Idle),
            (1, 0) => Some(Self::Running),
            (2, 0) => Some(Self::Done),
            (3, r) => match HomingFailure::from_code(r) {
                Some(f) => Some(Self::Failed(f)),
                None => None,
            },
            _ => None,
        }
    }
}

/// A [`Feedback`] built from a telemetry sample (rotor frame): what a
/// context without the drive's own feedback gives the homing sequencer
/// (the measured q current stands for its reference).
pub fn feedback_of(t: &Telemetry) -> Feedback {
    let mut fb = Feedback::INIT;
    fb.period = t.period;
    fb.mode = t.mode;
    fb.position_rad = t.position_rad;
    fb.velocity_rad_s = t.velocity_rad_s;
    fb.i_dq_a.q = t.i_q_a;
    fb.i_dq_ref_a.q = t.i_q_a;
    fb.v_bus_v = t.v_bus_v;
    fb.first_fault = foc_core::control::Fault::from_code(t.fault_code);
    fb
}

/// The damping-only command of an impedance timeout (design §21): no
/// spring, no feed-forward, the active command's damping (at least
/// `min_kd`) and torque limit, at `position_rad` \[rotor\] (unused with
/// `kp = 0`, kept inside the range).
pub fn damping_only(active: Option<Impedance>, min_kd: f32, position_rad: f32) -> Command {
    let (kd, limit) = active.map_or((0.0, f32::INFINITY), |i| {
        (i.kd_nm_s_per_rad, i.torque_limit_nm)
    });
    Command::Impedance(Impedance {
        position_rad,
        velocity_rad_s: 0.0,
        kp_nm_per_rad: 0.0,
        kd_nm_s_per_rad: if kd > min_kd { kd } else { min_kd },
        torque_ff_nm: 0.0,
        torque_limit_nm: limit,
    })
}

/// True when the feedback shows a command of `mode` taken (or a fault).
pub(crate) fn taken(fb: &Feedback, mode: Mode) -> bool {
    fb.mode == mode || fb.first_fault.is_some()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> JointSettings {
        JointSettings {
            gear_ratio: -20.0,
            rotor_at_zero_rad: 3.0,
            travel_out_rad: Some((-1.0, 2.0)),
            fault_margin_rad: 0.5,
            brake_accel_rad_s2: 100.0,
            kv_a_per_rad_s: 0.1,
            entry_blend_periods: 200,
            timeout_kd_nm_s_per_rad: 0.01,
        }
    }

    #[test]
    fn settings_round_trip_through_a_setup() {
        let s = settings();
        let setup = s.to_setup().unwrap();
        assert_eq!(JointSettings::from_setup(&setup), s);
        assert_eq!(setup.rotor_change((-1e3, 1e3)).min_position_rad, 3.0 - 40.0);
    }

    #[test]
    fn bad_settings_name_their_field() {
        type Case = (fn(&mut JointSettings), u8);
        let cases: [Case; 9] = [
            (|s| s.gear_ratio = 0.0, 0),
            (|s| s.gear_ratio = f32::NAN, 0),
            (|s| s.rotor_at_zero_rad = f32::INFINITY, 1),
            (|s| s.travel_out_rad = Some((f32::NAN, 1.0)), 3),
            (|s| s.travel_out_rad = Some((1.0, 1.0)), 4),
            (|s| s.travel_out_rad = Some((2.0, -1.0)), 4),
            (|s| s.fault_margin_rad = -0.1, 5),
            (|s| s.kv_a_per_rad_s = 0.0, 7),
            (|s| s.timeout_kd_nm_s_per_rad = -1.0, 9),
        ];
        for (f, want) in cases {
            let mut s = settings();
            f(&mut s);
            assert_eq!(s.to_setup().err(), Some(want), "{s:?}");
        }
        // Without a travel range its soft stop is not looked at.
        let mut s = settings();
        s.travel_out_rad = None;
        s.kv_a_per_rad_s = 0.0;
        assert!(s.to_setup().is_ok());
    }

    #[test]
    fn homing_state_wire_codes_round_trip() {
        for s in [
            HomingState::Idle,
            HomingState::Running,
            HomingState::Done,
            HomingState::Failed(HomingFailure::NoStop),
            HomingState::Failed(HomingFailure::Refused),
        ] {
            let (c, r) = s.to_wire();
            assert_eq!(HomingState::from_wire(c, r), Some(s));
        }
        assert_eq!(HomingState::from_wire(3, 0), None);
        assert_eq!(HomingState::from_wire(0, 1), None);
        assert_eq!(HomingState::from_wire(4, 0), None);
    }
}
