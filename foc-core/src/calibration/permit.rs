//! [`Calibrated`]: the type-level proof that the angle calibration and the
//! current-loop gains are known, required to run closed-loop modes.
//!
//! A `Calibrated` has private fields. There are exactly two ways to get one:
//! - a successful [`super::identification::Identification`] (its `Done`
//!   value carries one; its [`permit`](super::identification::Identification::permit)
//!   method also gives a provisional one for the flux step), or
//! - [`Calibrated::supplied`], from values the integrator states explicitly
//!   (e.g. stored in flash after an earlier identification); they are
//!   checked for plausibility.
//!
//! **How it is enforced.** A `CurrentStage` (and so a `Cascade`) starts
//! uncalibrated: it refuses `Torque`, `Velocity` and `Position` commands
//! (`Cascade::command` returns `CommandError::NotCalibrated`, the stage
//! counts them as rejected) and allows only `Disable` and `OpenLoop`, which
//! the calibration itself needs. The only way to unlock the closed-loop
//! modes is to hand the stage a `Calibrated`:
//! [`CurrentStage::set_calibration`](crate::control::stage::CurrentStage::set_calibration), [`Cascade::set_calibration`](crate::drive::cascade::Cascade::set_calibration),
//! [`Calibrated::apply_to`] or [`CalibratedCascade::new`](crate::drive::cascade::CalibratedCascade::new). Overwriting the
//! angle calibration or the current-loop configuration by hand
//! (`set_angle_calibration`, `set_current_config`) locks them again.
//!
//! ```
//! use foc_core::calibration::{Calibrated, CalError};
//! use foc_core::drive::cascade::CalibratedCascade;
//! use foc_core::control::{current::CurrentLoopConfig, stage::AngleCalibration, Command, CommandError, MotorParams};
//! use foc_core::drive::cascade::{Cascade, CascadeConfig};
//! use foc_core::angle::ElectricalAngle;
//! let motor = MotorParams { pole_pairs: 7, r_ohm: 0.2, ld_h: 60e-6, lq_h: 60e-6, flux_linkage_wb: 0.004 };
//! let angle = AngleCalibration { pole_pairs: 7, zero_offset: ElectricalAngle::from_degrees(42.0), reversed: true, sensor_counts_per_rev: 0, sensorless_only: false };
//! let permit = Calibrated::supplied(angle, CurrentLoopConfig::technical_optimum(motor, 20_000.0)).unwrap();
//! let config = CascadeConfig::for_motor(motor, 20_000.0, 5.0);
//! // Without a permit the closed-loop modes are locked.
//! let mut plain = Cascade::new(config);
//! assert_eq!(plain.command(Command::Torque { iq_a: 1.0 }), Err(CommandError::NotCalibrated));
//! plain.set_calibration(&permit);
//! plain.command(Command::Torque { iq_a: 1.0 }).unwrap();
//! // The same through the wrapper.
//! let mut drive = CalibratedCascade::new(config, &permit);
//! drive.command(Command::Torque { iq_a: 1.0 }).unwrap();
//! assert_eq!(drive.cascade().current.config().angle, angle);
//! // Implausible supplied values are refused.
//! let bad = AngleCalibration { pole_pairs: 0, ..angle };
//! assert!(Calibrated::supplied(bad, CurrentLoopConfig::technical_optimum(motor, 20_000.0)).is_err());
//! ```

use super::common::CalError;
use crate::control::current::CurrentLoopConfig;
pub use crate::control::permit::{Calibrated, PermitError};
use crate::control::stage::AngleCalibration;

impl From<PermitError> for CalError {
    fn from(_: PermitError) -> Self {
        CalError::InvalidConfig
    }
}

/// A permit from an identification's measured values ([`Calibrated::supplied`]'s
/// checks; [`CalError::ImplausibleResult`] when they fail).
pub(crate) fn identified(
    angle: AngleCalibration,
    current: CurrentLoopConfig,
) -> Result<Calibrated, CalError> {
    Calibrated::supplied(angle, current).map_err(|_| CalError::ImplausibleResult)
}
