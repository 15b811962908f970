//! [`Calibrated`]: the permit that unlocks the closed-loop modes (see
//! `calibration::permit` for how one is obtained and enforced).
//!
//! The type lives with the control code it unlocks, so `control` never
//! imports `calibration`: the calibration routines produce permits, the
//! stages consume them (dependency direction calibration -> control).
//!
//! ```
//! use foc_core::control::permit::{Calibrated, PermitError};
//! use foc_core::control::{current::CurrentLoopConfig, stage::AngleCalibration, MotorParams};
//! use foc_core::angle::ElectricalAngle;
//! let motor = MotorParams { pole_pairs: 7, r_ohm: 0.2, ld_h: 60e-6, lq_h: 60e-6, flux_linkage_wb: 0.004 };
//! let angle = AngleCalibration { pole_pairs: 7, zero_offset: ElectricalAngle::ZERO, reversed: false, sensor_counts_per_rev: 0, sensorless_only: false };
//! let gains = CurrentLoopConfig::technical_optimum(motor, 20_000.0);
//! assert!(Calibrated::supplied(angle, gains).is_ok());
//! let bad = AngleCalibration { pole_pairs: 0, ..angle };
//! assert_eq!(Calibrated::supplied(bad, gains), Err(PermitError));
//! ```

use super::current::CurrentLoopConfig;
use super::stage::{AngleCalibration, CurrentStage};

/// Supplied calibration values that fail the plausibility check of
/// [`Calibrated::supplied`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PermitError;

/// Proof that the angle calibration and the current-loop configuration are
/// known (measured or explicitly supplied and checked).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Calibrated {
    angle: AngleCalibration,
    current: CurrentLoopConfig,
}

impl Calibrated {
    /// From explicitly supplied values. [`PermitError`] unless
    /// the pole pairs are at least 1, the period, gains and motor values are
    /// finite and positive (flux linkage may be zero), the pole pairs of the
    /// angle and of the motor agree, `max_modulation` is in `(0, 1]` and
    /// `delay_compensation_periods` in `[0, 4]`.
    pub fn supplied(
        angle: AngleCalibration,
        current: CurrentLoopConfig,
    ) -> Result<Self, PermitError> {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let m = &current.motor;
        let ok = angle.pole_pairs > 0
            && m.pole_pairs == angle.pole_pairs
            && pos(current.ts_s)
            && pos(current.d_gains.kp_v_per_a)
            && pos(current.d_gains.ki_v_per_a_s)
            && pos(current.q_gains.kp_v_per_a)
            && pos(current.q_gains.ki_v_per_a_s)
            && pos(m.r_ohm)
            && pos(m.ld_h)
            && pos(m.lq_h)
            && m.flux_linkage_wb.is_finite()
            && m.flux_linkage_wb >= 0.0
            && pos(current.max_modulation)
            && current.max_modulation <= 1.0
            && (0.0..=4.0).contains(&current.delay_compensation_periods);
        if ok {
            Ok(Self { angle, current })
        } else {
            Err(PermitError)
        }
    }

    /// The angle calibration.
    pub fn angle(&self) -> AngleCalibration {
        self.angle
    }

    /// The current-loop configuration (gains and motor parameters).
    pub fn current_config(&self) -> CurrentLoopConfig {
        self.current
    }

    /// Install the angle calibration and the current-loop configuration in
    /// a current stage and unlock its closed-loop modes (the same as
    /// [`CurrentStage::set_calibration`]). Call before the first
    /// closed-loop command; it resets the stage's angle tracker.
    pub fn apply_to(&self, stage: &mut CurrentStage) {
        stage.set_calibration(self);
    }
}
