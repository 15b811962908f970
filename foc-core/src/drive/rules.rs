//! The drive's rules for commands and configuration changes, each written
//! once: the [`Lifecycle`](super::Lifecycle) applies them when it takes a
//! command or a change at a period boundary, and the command protocol
//! applies the very same functions to its snapshot of the drive's
//! [`Status`] for an immediate Nack (so a refused request changes nothing).
//!
//! ```
//! use foc_core::drive::{Progress, Refusal, Status};
//! use foc_core::control::{Command, CommandError, Mode};
//! let running = Status { running: true, mode: Mode::Torque, faulted: false, calibrated: true, sensorless: false, injection: false, calibration: Progress::Idle };
//! assert_eq!(running.check_config(), Err(Refusal::NotDisabled));
//! let starting = Status { running: false, mode: Mode::Disabled, ..running };
//! assert_eq!(starting.check_config(), Err(Refusal::Busy));
//! let idle = Status { mode: Mode::Disabled, calibrated: false, ..running };
//! assert_eq!(idle.check_config(), Ok(()));
//! # let limits = foc_core::drive::cascade::CascadeConfig::for_motor(
//! #     foc_core::control::MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 1e-4, lq_h: 1e-4, flux_linkage_wb: 0.01 },
//! #     20_000.0, 5.0).current.limits;
//! assert_eq!(idle.check_command(&Command::Torque { iq_a: 1.0 }, &limits), Err(CommandError::NotCalibrated));
//! // Without the angle sensor: velocity only (and open loop).
//! let sensorless = Status { mode: Mode::Disabled, sensorless: true, ..running };
//! assert_eq!(sensorless.check_command(&Command::Torque { iq_a: 1.0 }, &limits), Err(CommandError::NeedsAngleSensor));
//! assert_eq!(sensorless.check_command(&Command::Velocity { rad_s: 10.0 }, &limits), Ok(()));
//! // With injection (a salient motor) it holds torque at standstill.
//! let injection = Status { injection: true, ..sensorless };
//! assert_eq!(injection.check_command(&Command::Torque { iq_a: 1.0 }, &limits), Ok(()));
//! ```

use crate::control::current::CurrentLoopConfig;
pub use crate::control::joint::JointChange;
use crate::control::permit::Calibrated;
use crate::control::power::PowerLimitsConfig;
use crate::control::sensorless::SensorlessConfig;
use crate::control::stage::BesideConfig;
pub use crate::control::Refusal;
use crate::control::{admit, Command, CommandError, Fault, Limits, Mechanics, Mode};

/// What the rules look at: the drive's state as its owner last published it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// Start-up finished and no calibration running (phase `Run`).
    pub running: bool,
    /// The active mode.
    pub mode: Mode,
    /// A fault is latched.
    pub faulted: bool,
    /// Offsets calibrated and a calibration permit installed.
    pub calibrated: bool,
    /// The drive runs without its angle sensor (design §27).
    pub sensorless: bool,
    /// ... and holds torque at standstill with high-frequency injection
    /// (design §28; a salient motor).
    pub injection: bool,
    /// The calibration running, or how the last one ended (for the host).
    pub calibration: crate::drive::Progress,
}

impl Status {
    /// Limits, gains, dividers and the offset calibration: only once
    /// started ([`Refusal::Busy`]) and while disabled
    /// ([`Refusal::NotDisabled`]).
    pub fn check_config(&self) -> Result<(), Refusal> {
        if !self.running {
            return Err(Refusal::Busy);
        }
        if self.mode != Mode::Disabled {
            return Err(Refusal::NotDisabled);
        }
        Ok(())
    }

    /// A calibration (offsets, identification): as [`Self::check_config`],
    /// and not while a fault is latched ([`Refusal::Faulted`]).
    pub fn check_calibration(&self) -> Result<(), Refusal> {
        self.check_config()?;
        if self.faulted {
            return Err(Refusal::Faulted);
        }
        Ok(())
    }

    /// True when the rotor's angle is known only once it turns
    /// (sensorless without injection): torque, position and impedance
    /// commands are refused.
    pub fn angle_only_in_motion(&self) -> bool {
        self.sensorless && !self.injection
    }

    /// A command: [`admit`] (values, latched fault, calibration), no
    /// torque, position or impedance command while the angle is known
    /// only in motion ([`Self::angle_only_in_motion`],
    /// [`CommandError::NeedsAngleSensor`]), and while start-up or an identification runs only `Disable`
    /// ([`CommandError::Busy`]: the drive would take it only later).
    pub fn check_command(&self, cmd: &Command, limits: &Limits) -> Result<(), CommandError> {
        admit(cmd, limits, self.faulted, self.calibrated)?;
        if self.angle_only_in_motion() && cmd.mode().needs_angle_sensor() {
            return Err(CommandError::NeedsAngleSensor);
        }
        if !self.running && *cmd != Command::Disable {
            return Err(CommandError::Busy);
        }
        Ok(())
    }
}

/// A configuration change for the drive, applied at the start of a period.
/// Its settings (limits, current loop, dividers) are applied all together
/// or, when [`Status::check_config`] or [`Limits::validate`] refuses, not
/// at all; a calibration request is judged on its own
/// ([`Status::check_calibration`]), so a refused calibration never drops
/// settings the host was told were taken. Changes merge: a newer value
/// replaces a pending one.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ConfigChange {
    /// New command limits (checked with [`Limits::validate`]).
    pub limits: Option<Limits>,
    /// New current-loop configuration: installed with a new calibration
    /// permit for the stage's angle calibration when the stage is
    /// calibrated and the values pass the permit's check; otherwise it
    /// revokes the calibration.
    pub current: Option<CurrentLoopConfig>,
    /// New speed / position dividers \[periods\] (0 is taken as 1).
    pub dividers: Option<(u16, u16)>,
    /// New power limits (design §18): `Some(Some(cfg))` installs them
    /// (sanitized; their motor model is the current loop's; the winding
    /// estimate carries on), `Some(None)` switches them off.
    pub power: Option<Option<PowerLimitsConfig>>,
    /// A calibration permit to install (e.g. one stored after an earlier
    /// identification and checked with `Calibrated::supplied`): unlocks the
    /// closed-loop modes once the offsets are calibrated.
    pub permit: Option<Calibrated>,
    /// Re-run the current-offset calibration, bridge off
    /// ([`Status::check_calibration`]).
    pub calibrate_offsets: bool,
    /// Run the motor identification ([`Status::check_calibration`]).
    pub identify: bool,
    /// Latch this fault (e.g. a link watchdog's `Disable` reaction); taken
    /// in any phase, never refused.
    pub fault: Option<Fault>,
    /// The rotor's mechanics for the speed observer's model (design §19),
    /// e.g. from a stored record; applied after `current` (its torque
    /// constant). Unusable values change nothing.
    pub mechanics: Option<Mechanics>,
    /// New travel range and joint settings (design §21): taken while
    /// running as well (homing moves the range), judged on its own.
    pub joint: Option<JointChange>,
    /// The angle source (design §27): `Some(Some(cfg))` runs without the
    /// angle sensor from the next enable, `Some(None)` on the sensor
    /// again. Applied after `current` (its motor is the current loop's).
    pub sensorless: Option<Option<SensorlessConfig>>,
    /// The flux observer beside the angle sensor (design §27: a check,
    /// limp-home, halls + sensorless): `Some(Some(cfg))` installs it (it
    /// runs while the drive is on its sensor), `Some(None)` removes it.
    /// Applied after `sensorless`.
    pub beside: Option<Option<BesideConfig>>,
}

impl ConfigChange {
    /// Merge a newer change into this one.
    pub fn merge(&mut self, newer: ConfigChange) {
        self.limits = newer.limits.or(self.limits);
        self.current = newer.current.or(self.current);
        self.dividers = newer.dividers.or(self.dividers);
        self.power = newer.power.or(self.power);
        self.permit = newer.permit.or(self.permit);
        self.calibrate_offsets |= newer.calibrate_offsets;
        self.identify |= newer.identify;
        self.fault = self.fault.or(newer.fault);
        self.mechanics = newer.mechanics.or(self.mechanics);
        self.joint = newer.joint.or(self.joint);
        self.sensorless = newer.sensorless.or(self.sensorless);
        self.beside = newer.beside.or(self.beside);
    }

    /// True when it carries settings (limits, current loop, dividers,
    /// power limits, a permit).
    pub fn has_settings(&self) -> bool {
        self.limits.is_some()
            || self.current.is_some()
            || self.dividers.is_some()
            || self.power.is_some()
            || self.permit.is_some()
            || self.mechanics.is_some()
            || self.sensorless.is_some()
            || self.beside.is_some()
    }
}
