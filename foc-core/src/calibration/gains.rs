//! Current-loop gains from measured motor values, with the source's tuning
//! (technical optimum, design §11):
//! `Kp_d = Ld / (3 Ts)`, `Kp_q = Lq / (3 Ts)`, `Ki_d = Ki_q = R / (3 Ts)`,
//! through [`crate::tuning::technical_optimum`] for each axis.
//!
//! ```
//! use foc_core::calibration::gains::current_loop_config;
//! use foc_core::control::MotorParams;
//! let m = MotorParams { pole_pairs: 7, r_ohm: 0.2, ld_h: 60e-6, lq_h: 90e-6, flux_linkage_wb: 0.0 };
//! let c = current_loop_config(m, 1.0 / 20_000.0).unwrap();
//! assert!((c.q_gains.kp_v_per_a - 90e-6 * 20_000.0 / 3.0).abs() < 1e-5);
//! assert!(current_loop_config(MotorParams { r_ohm: f32::NAN, ..m }, 5e-5).is_err());
//! ```

use super::common::CalError;
use crate::control::current::{
    CurrentLoopConfig, DEFAULT_ANTI_WINDUP, DEFAULT_DELAY_COMPENSATION_PERIODS,
};
use crate::control::MotorParams;
use crate::tuning;

/// A [`CurrentLoopConfig`] for `motor` at loop period `ts_s` \[s\]: technical
/// optimum on both axes, decoupling on, 95 % of the linear range, matched
/// back-calculation anti-windup (the same choices as
/// [`CurrentLoopConfig::technical_optimum`]).
///
/// [`CalError::ImplausibleResult`] unless R, Ld, Lq and `ts_s` are finite
/// and positive, the flux linkage finite and not negative, and the pole
/// pairs at least 1.
pub fn current_loop_config(motor: MotorParams, ts_s: f32) -> Result<CurrentLoopConfig, CalError> {
    let pos = |x: f32| x.is_finite() && x > 0.0;
    if !(pos(motor.r_ohm)
        && pos(motor.ld_h)
        && pos(motor.lq_h)
        && pos(ts_s)
        && motor.flux_linkage_wb.is_finite()
        && motor.flux_linkage_wb >= 0.0
        && motor.pole_pairs > 0)
    {
        return Err(CalError::ImplausibleResult);
    }
    let d = tuning::technical_optimum(motor.ld_h, motor.r_ohm, ts_s);
    let q = tuning::technical_optimum(motor.lq_h, motor.r_ohm, ts_s);
    if !(pos(d.kp_v_per_a) && pos(d.ki_v_per_a_s) && pos(q.kp_v_per_a) && pos(q.ki_v_per_a_s)) {
        return Err(CalError::ImplausibleResult);
    }
    Ok(CurrentLoopConfig {
        ts_s,
        d_gains: d,
        q_gains: q,
        motor,
        decoupling: true,
        max_modulation: 0.95,
        anti_windup: DEFAULT_ANTI_WINDUP,
        delay_compensation_periods: DEFAULT_DELAY_COMPENSATION_PERIODS,
        dead_time: crate::control::dead_time::DeadTimeCompensation::OFF,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_as_technical_optimum_constructor() {
        let m = MotorParams {
            pole_pairs: 21,
            r_ohm: 1.13,
            ld_h: 0.57e-3,
            lq_h: 0.82e-3,
            flux_linkage_wb: 0.0088,
        };
        let a = current_loop_config(m, 1.0 / 20_000.0).unwrap();
        let b = CurrentLoopConfig::technical_optimum(m, 20_000.0);
        assert!((a.d_gains.kp_v_per_a - b.d_gains.kp_v_per_a).abs() < 1e-6);
        assert!((a.q_gains.ki_v_per_a_s - b.q_gains.ki_v_per_a_s).abs() < 1e-2);
        assert!(a.q_gains.kp_v_per_a > a.d_gains.kp_v_per_a);
        for bad in [
            MotorParams { ld_h: 0.0, ..m },
            MotorParams { r_ohm: -1.0, ..m },
            MotorParams {
                flux_linkage_wb: f32::INFINITY,
                ..m
            },
            MotorParams { pole_pairs: 0, ..m },
        ] {
            assert_eq!(
                current_loop_config(bad, 5e-5),
                Err(CalError::ImplausibleResult)
            );
        }
    }
}
