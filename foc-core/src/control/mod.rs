//! The control cascade (design §10): current loop (inner, every PWM
//! period) <- speed loop (every N periods) <- position loop (every M periods).
//!
//! Each loop is a plain struct with a `Config`, a state, `reset()` and a
//! `step`; none knows who calls it. Three *stages* add the mode logic:
//!
//! | stage | runs | owns | reads | writes |
//! |---|---|---|---|---|
//! | [`stage::CurrentStage`] | every PWM period (highest priority) | current loop, angle tracker, fault supervisor | [`CommandSlot`], `iq_ref` from the speed stage, [`stage::Sample`] | [`BridgeCommand`], [`Feedback`] |
//! | [`stage::SpeedStage`] | every N periods | speed loop | [`Feedback`], `w_ref` from the position stage | `iq_ref` |
//! | [`stage::PositionStage`] | every M periods | position loop + trajectory | [`Feedback`] | `w_ref` |
//!
//! Everything that crosses between stages is a small `Copy` value, so the
//! firmware can run the stages as separate prioritised tasks sharing those
//! values, and the simulator can step them deterministically ([`Cascade`](crate::drive::cascade::Cascade)
//! does exactly what the firmware does, in the same order: current stage,
//! then the speed stage, then the position stage).
//!
//! Closed-loop modes (torque, velocity, position) are locked until the
//! current stage is given a [`Calibrated`](permit::Calibrated)
//! permit (`CurrentStage::set_calibration`, `Cascade::set_calibration`):
//! such commands are refused with [`CommandError::NotCalibrated`] before.
//! `Disable` and `OpenLoop` are always allowed (calibration needs them).
//!
//! The current stage is the single decider: it accepts or rejects commands,
//! applies the command timeout, latches faults and publishes the *active*
//! command and mode in [`Feedback`]; the slower stages follow it and make
//! every mode change bumpless (their integrators are preloaded from what the
//! faster loop is doing).
//!
//! # Wiring a board
//!
//! ```
//! use foc_core::control::{io, Command, CommandError, MotorParams};
//! use foc_core::drive::cascade::{Cascade, CascadeConfig};
//! use foc_core::calibration::Calibrated;
//! # use foc_core::{hal::*, angle::MechanicalAngle, frames::Abc};
//! # struct Pwm(bool); struct Cs; struct Enc; struct Bus;
//! # impl PwmDriver for Pwm { type Error = (); fn period_counts(&self) -> u16 { 4200 }
//! #   fn set_compare(&mut self, _: [u16; 3]) -> Result<(), ()> { Ok(()) }
//! #   fn enable(&mut self) -> Result<(), ()> { self.0 = true; Ok(()) } fn disable(&mut self) { self.0 = false }
//! #   fn is_enabled(&self) -> bool { self.0 } }
//! # impl CurrentSense for Cs { type Error = (); fn read_currents(&mut self) -> Result<PhaseCurrents, ()> { Ok(PhaseCurrents::TwoPhase { a_a: 0.0, b_a: 0.0 }) }
//! #   fn offsets_a(&self) -> Abc { Abc::default() } fn set_offsets_a(&mut self, _: Abc) {} }
//! # impl AngleSensor for Enc { type Error = (); fn read_angle(&mut self) -> Result<MechanicalAngle, ()> { Ok(MechanicalAngle::ZERO) } }
//! # impl BusVoltage for Bus { type Error = (); fn read_bus_voltage_v(&mut self) -> Result<f32, ()> { Ok(24.0) } }
//! let (mut pwm, mut cs, mut enc, mut bus) = (Pwm(false), Cs, Enc, Bus);
//! let motor = MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 40e-6, lq_h: 40e-6, flux_linkage_wb: 0.004 };
//! let config = CascadeConfig::for_motor(motor, 20_000.0, 10.0);
//! let mut drive_ctl = Cascade::new(config);
//! // Closed-loop modes need a calibration permit: from an identification,
//! // or supplied (e.g. stored in flash) and checked for plausibility.
//! assert_eq!(drive_ctl.command(Command::Torque { iq_a: 1.0 }), Err(CommandError::NotCalibrated));
//! let permit = Calibrated::supplied(config.current.angle, config.current.current).unwrap();
//! drive_ctl.set_calibration(&permit);
//! drive_ctl.command(Command::Torque { iq_a: 1.0 }).unwrap();
//! // In the PWM-synchronous interrupt (ADC end of conversion):
//! let sample = io::read_sample(&mut cs, &mut enc, &mut bus);
//! let bridge = drive_ctl.step(&sample);
//! io::apply(&mut pwm, bridge).unwrap();
//! assert!(pwm.is_enabled());
//! ```

pub mod angle_correction;
pub mod cogging;
pub mod current;
pub mod dead_time;
pub mod estimator;
pub mod field;
pub mod flux_observer;
pub mod frozen;
pub mod hfi;
pub mod homing;
pub mod io;
pub mod joint;
pub mod model;
pub mod permit;
pub mod position;
pub mod power;
pub mod sensorless;
pub mod speed;
pub mod stage;
pub mod supervisor;
pub mod trajectory;
pub mod unbalance;

use crate::angle::ElectricalAngle;
use crate::frames::Dq;
pub use supervisor::{Fault, FaultSet};

/// Mechanical parameters of the rotor and what it drives (rotor frame,
/// mechanical): measured by the identification (design §19) or given.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Mechanics {
    /// Inertia [kg m^2].
    pub inertia_kg_m2: f32,
    /// Viscous friction [N m s/rad].
    pub viscous_friction_nm_s_per_rad: f32,
    /// Coulomb friction [N m].
    pub coulomb_friction_nm: f32,
}

impl Mechanics {
    /// An inertia alone (no friction known).
    pub const fn inertia(inertia_kg_m2: f32) -> Self {
        Self {
            inertia_kg_m2,
            viscous_friction_nm_s_per_rad: 0.0,
            coulomb_friction_nm: 0.0,
        }
    }

    /// True when the inertia is a positive finite value and the frictions
    /// finite and non-negative.
    pub fn is_usable(&self) -> bool {
        let j = self.inertia_kg_m2;
        let ok = |x: f32| x.is_finite() && x >= 0.0;
        j.is_finite()
            && j > 0.0
            && ok(self.viscous_friction_nm_s_per_rad)
            && ok(self.coulomb_friction_nm)
    }
}

/// Why a configuration change or a calibration request was refused
/// (nothing changed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// Start-up or a calibration is still running: try again later.
    Busy,
    /// Closed-loop mode requested before a calibration permit exists.
    NotCalibrated,
    /// Only allowed while the drive is disabled.
    NotDisabled,
    /// A fault is latched: clear it first.
    Faulted,
    /// Not available on this drive, or values it cannot vouch for.
    Unsupported,
}

/// Electrical parameters of a PMSM.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotorParams {
    /// Pole pairs `p` (`theta_e = p theta_m`).
    pub pole_pairs: u8,
    /// Phase resistance \[ohm\].
    pub r_ohm: f32,
    /// d-axis inductance \[H\].
    pub ld_h: f32,
    /// q-axis inductance \[H\].
    pub lq_h: f32,
    /// Permanent-magnet flux linkage `psi` \[Wb\] (peak, per phase).
    pub flux_linkage_wb: f32,
}

impl MotorParams {
    /// Torque constant `kt = 1.5 p psi` [N m / A] (with `id = 0`).
    pub fn torque_constant_nm_per_a(&self) -> f32 {
        1.5 * self.pole_pairs as f32 * self.flux_linkage_wb
    }
}

/// Loop rates: the current loop runs every PWM period, the speed loop every
/// `speed_divider` periods, the position loop every `position_divider`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Rates {
    /// PWM (= current-loop) frequency \[Hz\].
    pub pwm_frequency_hz: f32,
    /// Speed loop every N current-loop periods (>= 1).
    pub speed_divider: u16,
    /// Position loop every M current-loop periods (>= 1).
    pub position_divider: u16,
}

impl Rates {
    /// Defaults for a PWM frequency: speed loop near 2 kHz, position near 1 kHz.
    pub fn for_pwm(pwm_frequency_hz: f32) -> Self {
        let div = |target: f32| -> u16 {
            let n = pwm_frequency_hz / target + 0.5;
            if (1.0..65_535.0).contains(&n) {
                n as u16
            } else {
                1
            }
        };
        Self {
            pwm_frequency_hz,
            speed_divider: div(2_000.0),
            position_divider: div(1_000.0),
        }
    }
    /// Current-loop period \[s\].
    pub fn current_ts_s(&self) -> f32 {
        1.0 / self.pwm_frequency_hz
    }
    /// Speed-loop period \[s\].
    pub fn speed_ts_s(&self) -> f32 {
        self.speed_divider.max(1) as f32 / self.pwm_frequency_hz
    }
    /// Position-loop period \[s\].
    pub fn position_ts_s(&self) -> f32 {
        self.position_divider.max(1) as f32 / self.pwm_frequency_hz
    }
}

/// Control mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Mode {
    /// Bridge off (safe state).
    Disabled = 0,
    /// Current (torque) control.
    Torque = 1,
    /// Velocity control.
    Velocity = 2,
    /// Position control with a trapezoidal trajectory.
    Position = 3,
    /// Open-loop voltage at a given (optionally rotating) electrical angle.
    OpenLoop = 4,
    /// Impedance (spring-damper with a feed-forward torque), design §21.
    Impedance = 5,
}

/// What the drive is asked to do. Speeds and positions are mechanical.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// Bridge off.
    Disable,
    /// q-current reference \[A\] with `id = 0` (design §6).
    Torque {
        /// q-axis current \[A\].
        iq_a: f32,
    },
    /// Velocity reference [rad/s].
    Velocity {
        /// Mechanical velocity [rad/s].
        rad_s: f32,
    },
    /// Move to an absolute mechanical position \[rad\] along a trapezoid.
    Position {
        /// Target position \[rad\].
        rad: f32,
    },
    /// Open-loop dq voltage at `theta_e`, rotating at `omega_e_rad_s`.
    OpenLoop {
        /// d-axis voltage \[V\].
        v_d_v: f32,
        /// q-axis voltage \[V\].
        v_q_v: f32,
        /// Starting electrical angle.
        theta_e: ElectricalAngle,
        /// Electrical angular velocity [rad/s] (0 holds the angle).
        omega_e_rad_s: f32,
    },
    /// Impedance control (design §21), rotor frame:
    /// `T = kp (p_ref - p) + kd (v_ref - v) + T_ff`, worked out every
    /// current-loop period and given to the current loop as
    /// `iq = T / kt`, clamped to the current limit (and the travel and
    /// power limits' window).
    Impedance(joint::Impedance),
}

impl Mode {
    /// True for the modes that close a loop on the angle sensor (torque,
    /// velocity, position): they need a calibrated current stage.
    pub const fn is_closed_loop(self) -> bool {
        matches!(
            self,
            Mode::Torque | Mode::Velocity | Mode::Position | Mode::Impedance
        )
    }

    /// True for the modes that need the angle sensor: a drive running
    /// sensorless (design §27) takes only `Disabled`, `OpenLoop` and
    /// `Velocity` (its start turns a field at a rate of its own, and the
    /// observer's angle is only known once the rotor turns, so torque,
    /// position and impedance commands are refused with
    /// [`CommandError::NeedsAngleSensor`]).
    pub const fn needs_angle_sensor(self) -> bool {
        matches!(self, Mode::Torque | Mode::Position | Mode::Impedance)
    }
}

impl Command {
    /// The mode this command selects.
    pub const fn mode(&self) -> Mode {
        match self {
            Command::Disable => Mode::Disabled,
            Command::Torque { .. } => Mode::Torque,
            Command::Velocity { .. } => Mode::Velocity,
            Command::Position { .. } => Mode::Position,
            Command::OpenLoop { .. } => Mode::OpenLoop,
            Command::Impedance(_) => Mode::Impedance,
        }
    }

    /// Check a command against the limits.
    pub fn validate(&self, l: &Limits) -> Result<(), CommandError> {
        let fin = |x: f32| {
            if x.is_finite() {
                Ok(())
            } else {
                Err(CommandError::NonFinite)
            }
        };
        match *self {
            Command::Disable => Ok(()),
            Command::Torque { iq_a } => {
                fin(iq_a)?;
                if !within(iq_a.abs(), l.max_current_a) {
                    return Err(CommandError::CurrentOutOfRange);
                }
                Ok(())
            }
            Command::Velocity { rad_s } => {
                fin(rad_s)?;
                if !within(rad_s.abs(), l.max_velocity_rad_s) {
                    return Err(CommandError::VelocityOutOfRange);
                }
                Ok(())
            }
            Command::Position { rad } => {
                fin(rad)?;
                if !(within(l.min_position_rad, rad) && within(rad, l.max_position_rad)) {
                    return Err(CommandError::PositionOutOfRange);
                }
                Ok(())
            }
            Command::OpenLoop {
                v_d_v,
                v_q_v,
                omega_e_rad_s,
                ..
            } => {
                fin(v_d_v)?;
                fin(v_q_v)?;
                fin(omega_e_rad_s)?;
                if !within(Dq::new(v_d_v, v_q_v).magnitude(), l.max_open_loop_voltage_v) {
                    return Err(CommandError::VoltageOutOfRange);
                }
                if !within(omega_e_rad_s.abs(), l.max_open_loop_omega_e_rad_s) {
                    return Err(CommandError::VelocityOutOfRange);
                }
                Ok(())
            }
            Command::Impedance(i) => i.validate(l),
        }
    }
}

/// `x <= limit`, false when either is NaN: a NaN limit refuses.
#[inline(always)]
fn within(x: f32, limit: f32) -> bool {
    x <= limit
}

/// Whether the current stage takes `cmd` now: the one rule every command
/// path applies (the stage itself, [`Cascade::command`](crate::drive::cascade::Cascade::command) and the
/// command protocol, through `drive::Status::check_command`).
///
/// In order: the values against `limits` ([`Command::validate`]); while a
/// fault is latched only `Disable` ([`CommandError::Faulted`]); a
/// closed-loop mode only with a calibration permit
/// ([`CommandError::NotCalibrated`]).
pub fn admit(
    cmd: &Command,
    limits: &Limits,
    faulted: bool,
    calibrated: bool,
) -> Result<(), CommandError> {
    cmd.validate(limits)?;
    if faulted && *cmd != Command::Disable {
        return Err(CommandError::Faulted);
    }
    if cmd.mode().is_closed_loop() && !calibrated {
        return Err(CommandError::NotCalibrated);
    }
    Ok(())
}

/// Why a command was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommandError {
    /// A value was NaN or infinite.
    NonFinite,
    /// Current reference beyond the current limit.
    CurrentOutOfRange,
    /// Velocity beyond the velocity limit.
    VelocityOutOfRange,
    /// Position outside the allowed range.
    PositionOutOfRange,
    /// Open-loop voltage beyond its limit.
    VoltageOutOfRange,
    /// A fault is latched: clear it first.
    Faulted,
    /// Start-up or an identification is running: only `Disable` is taken.
    Busy,
    /// A closed-loop command (`Torque`, `Velocity`, `Position`) before the
    /// current stage holds a calibration: install a
    /// [`Calibrated`](permit::Calibrated) permit first
    /// (`set_calibration`). `Disable` and `OpenLoop` need none.
    NotCalibrated,
    /// Impedance stiffness negative or above `Limits::max_kp_nm_per_rad`.
    StiffnessOutOfRange,
    /// Impedance damping negative or above `Limits::max_kd_nm_s_per_rad`.
    DampingOutOfRange,
    /// A torque, position or impedance command while the drive runs
    /// without its angle sensor ([`Mode::needs_angle_sensor`]).
    NeedsAngleSensor,
}

/// Limits that commands are checked against.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Limits {
    /// Largest q-current reference \[A\] (also the speed loop's output limit).
    pub max_current_a: f32,
    /// Largest velocity [rad/s, mechanical].
    pub max_velocity_rad_s: f32,
    /// Position range [rad, mechanical].
    pub min_position_rad: f32,
    /// Position range [rad, mechanical].
    pub max_position_rad: f32,
    /// Largest open-loop voltage magnitude \[V\].
    pub max_open_loop_voltage_v: f32,
    /// Largest open-loop electrical speed [rad/s].
    pub max_open_loop_omega_e_rad_s: f32,
    /// Largest impedance stiffness [N m/rad, rotor frame].
    pub max_kp_nm_per_rad: f32,
    /// Largest impedance damping [N m s/rad, rotor frame].
    pub max_kd_nm_s_per_rad: f32,
}

/// Which field of a [`Limits`] is invalid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LimitsError {
    /// `max_current_a` not finite and positive.
    MaxCurrent,
    /// `max_velocity_rad_s` not finite and positive.
    MaxVelocity,
    /// `min_position_rad` not finite.
    MinPosition,
    /// `max_position_rad` not finite, or not above `min_position_rad`.
    MaxPosition,
    /// `max_open_loop_voltage_v` not finite and non-negative.
    OpenLoopVoltage,
    /// `max_open_loop_omega_e_rad_s` not finite and non-negative.
    OpenLoopOmega,
    /// `max_kp_nm_per_rad` not finite and non-negative.
    MaxStiffness,
    /// `max_kd_nm_s_per_rad` not finite and non-negative.
    MaxDamping,
}

impl Limits {
    /// Check every field (the one check of a limits change, used by the
    /// drive when it applies one and by the protocol for its Nack).
    pub fn validate(&self) -> Result<(), LimitsError> {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let non_neg = |x: f32| x.is_finite() && x >= 0.0;
        if !pos(self.max_current_a) {
            return Err(LimitsError::MaxCurrent);
        }
        if !pos(self.max_velocity_rad_s) {
            return Err(LimitsError::MaxVelocity);
        }
        if !self.min_position_rad.is_finite() {
            return Err(LimitsError::MinPosition);
        }
        if !self.max_position_rad.is_finite() || self.min_position_rad >= self.max_position_rad {
            return Err(LimitsError::MaxPosition);
        }
        if !non_neg(self.max_open_loop_voltage_v) {
            return Err(LimitsError::OpenLoopVoltage);
        }
        if !non_neg(self.max_open_loop_omega_e_rad_s) {
            return Err(LimitsError::OpenLoopOmega);
        }
        if !non_neg(self.max_kp_nm_per_rad) {
            return Err(LimitsError::MaxStiffness);
        }
        if !non_neg(self.max_kd_nm_s_per_rad) {
            return Err(LimitsError::MaxDamping);
        }
        Ok(())
    }
}

/// What the current stage tells the bridge to do this period.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BridgeCommand {
    /// All switches off (high impedance).
    SafeState,
    /// The three low-side switches on, the high sides off (active short
    /// circuit, design §30): the safe state above the speed where the
    /// back-EMF would rectify into the bus through the freewheel diodes.
    ShortCircuit,
    /// Apply these duties (phases A, B, C, each in `[0, 1]`) and enable.
    Duties([f32; 3]),
}

/// The shared command mailbox written by the command handler and read by
/// the current stage. Bump `seq` for a new command, `clear_seq` to clear
/// latched faults.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommandSlot {
    /// The latest command.
    pub command: Command,
    /// Incremented for every new command (also a keep-alive).
    pub seq: u32,
    /// Incremented to request a fault clear.
    pub clear_seq: u32,
}

impl CommandSlot {
    /// Empty mailbox (disabled).
    pub const INIT: Self = Self {
        command: Command::Disable,
        seq: 0,
        clear_seq: 0,
    };
    /// Post a new command.
    pub fn post(&mut self, command: Command) {
        self.command = command;
        self.seq = self.seq.wrapping_add(1);
    }
    /// Request a fault clear.
    pub fn request_clear(&mut self) {
        self.clear_seq = self.clear_seq.wrapping_add(1);
    }
}

/// Everything the current stage publishes each period (plain `Copy` data).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Feedback {
    /// Active mode.
    pub mode: Mode,
    /// Active command (after validation, timeout reaction and faults).
    pub active: Command,
    /// Multi-turn mechanical position \[rad\].
    pub position_rad: f32,
    /// Estimated mechanical velocity [rad/s] (the speed observer's, design
    /// §19).
    pub velocity_rad_s: f32,
    /// The speed observer's disturbance: the acceleration its torque model
    /// does not explain (a load torque `T_L` shows as `-T_L / J`)
    /// [rad/s^2].
    pub disturbance_rad_s2: f32,
    /// Electrical angle used this period.
    pub theta_e: ElectricalAngle,
    /// Measured dq currents \[A\].
    pub i_dq_a: Dq,
    /// dq current reference \[A\].
    pub i_dq_ref_a: Dq,
    /// Commanded dq voltage \[V\].
    pub v_dq_v: Dq,
    /// Bus voltage \[V\].
    pub v_bus_v: f32,
    /// Duties applied (centred when in the safe state).
    pub duties: [f32; 3],
    /// Latched faults.
    pub faults: FaultSet,
    /// First latched fault.
    pub first_fault: Option<Fault>,
    /// Voltage limit active.
    pub voltage_limited: bool,
    /// The current stage's q-current limit in force \[A\] (the command
    /// limit; lower during an identification): the speed stage keeps its
    /// output, and so its anti-windup, within it.
    pub current_limit_a: f32,
    /// The power limits this period (q-current window, active limit,
    /// winding temperature, brake chopper; design §18): the speed stage
    /// keeps its output within the window as well.
    pub power: power::PowerReport,
    /// Periods since start (wraps).
    pub period: u32,
    /// Where the angle the current loop used came from (design §27).
    pub angle_in_use: AngleInUse,
}

/// Where the current loop's angle comes from (design §27).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum AngleInUse {
    /// The angle sensor.
    #[default]
    Sensor = 0,
    /// The flux observer (or the start's field): configured sensorless.
    Sensorless = 1,
    /// Halls + sensorless: the observer beside the sensor, above its
    /// speed (the observer's share of the angle is one half or more).
    Observer = 2,
    /// Limp-home: the observer, because the angle sensor failed.
    LimpHome = 3,
}

impl AngleInUse {
    /// The wire code (the discriminant).
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The value of a wire code (`None` above 3).
    pub const fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Self::Sensor),
            1 => Some(Self::Sensorless),
            2 => Some(Self::Observer),
            3 => Some(Self::LimpHome),
            _ => None,
        }
    }
}

impl Feedback {
    /// Feedback before the first period.
    pub const INIT: Self = Self {
        mode: Mode::Disabled,
        active: Command::Disable,
        position_rad: 0.0,
        velocity_rad_s: 0.0,
        disturbance_rad_s2: 0.0,
        theta_e: ElectricalAngle::ZERO,
        i_dq_a: Dq::ZERO,
        i_dq_ref_a: Dq::ZERO,
        v_dq_v: Dq::ZERO,
        v_bus_v: 0.0,
        duties: [0.5; 3],
        faults: FaultSet::EMPTY,
        first_fault: None,
        voltage_limited: false,
        current_limit_a: 0.0,
        power: power::PowerReport::INIT,
        period: 0,
        angle_in_use: AngleInUse::Sensor,
    };
}
