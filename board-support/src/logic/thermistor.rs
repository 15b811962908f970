//! Power-stage thermistors: ADC counts to degrees Celsius, with open- and
//! short-circuit detection.
//!
//! Both supported boards that measure their power stage do it the same way:
//! an NTC thermistor from the 3.3 V analog supply to the ADC input and a
//! fixed resistor from the input to ground, so the input voltage *rises*
//! with temperature. The reading is taken as the ratio
//! `x = counts / 2^bits` (the divider and the ADC share the 3.3 V
//! reference, so `x` does not depend on its exact value) and converted by
//! the board's [`Curve`]:
//!
//! - ODrive v3.x FET thermistors ([`ODRIVE_V3_FET`]): the cubic the ODrive
//!   firmware fits to its NTC network, `T = c0 x^3 + c1 x^2 + c2 x + c3`
//!   (`Firmware/Board/v3/board.cpp`, `fet_thermistor_poly_coeffs`,
//!   evaluated in `MotorControl/thermistor.cpp` on `V / 3.3 V` by
//!   `horner_fma`, coefficient 0 the highest order as `numpy.polyfit`
//!   gives them, `MotorControl/utils.hpp`). The part is not named there;
//!   the cubic matches a 10 kOhm (25 deg C) NTC with B = 3380..3435 K over
//!   3.3 kOhm to ground within 2 K from 0 to 120 deg C (checked here, see
//!   the tests: an inference, not a documented value).
//! - X-NUCLEO-IHM07M1 ([`IHM07M1`]): the linear law of ST's Motor Control
//!   SDK for this power stage, `V = V0 + dV/dT (T - T0)` with
//!   `V0 = 1.055 V`, `T0 = 25 deg C`, `dV/dT = 23 mV/K`, `T_MAX = 110 deg C`
//!   (an MC SDK `power_stage_parameters.h` for the stage with 0.33 Ohm
//!   shunts, gain 1.53 and bus divider 0.0522; the same law the SDK uses
//!   for a 10 kOhm NTC over 4.7 kOhm, which gives 1.055 V at 25 deg C).
//!   A linearisation: good near 25..90 deg C, a few kelvin off outside.
//!
//! Open and short circuit: with the NTC open the input is pulled to 0 V,
//! with it shorted it sits at the supply. Readings below
//! [`NtcDivider::open_below`] or above [`NtcDivider::short_above`] (as
//! ratios of full scale) are errors, never temperatures: 2 % and 98 % of
//! full scale here, which a 10 kOhm NTC over 3.3 or 4.7 kOhm reaches only
//! below about -35 deg C or above about 200 deg C. A floating input (sensor
//! not fitted) is not detected: it reads whatever the pin drifts to.
//!
//! ```
//! use board_support::logic::thermistor::{ThermistorError, ODRIVE_V3_FET};
//! let t = ODRIVE_V3_FET.temperature_c(1016, 12).unwrap(); // x = 0.248
//! assert!((t - 25.0).abs() < 1.5);
//! assert_eq!(ODRIVE_V3_FET.temperature_c(0, 12), Err(ThermistorError::Open));
//! assert_eq!(ODRIVE_V3_FET.temperature_c(4095, 12), Err(ThermistorError::Short));
//! ```

/// Why a thermistor reading is not a temperature.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum ThermistorError {
    /// The input is near 0 V: NTC open (or its supply missing).
    Open,
    /// The input is near full scale: NTC shorted (or the input tied high).
    Short,
}

/// Temperature as a function of the ratio `x = V / V_ref` of the input.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Curve {
    /// `T = c[0] x^3 + c[1] x^2 + c[2] x + c[3]` [deg C].
    Cubic([f32; 4]),
    /// `V = v0_v + dv_dt_v_per_k (T - t0_c)` with `V = x vref_v`.
    Linear {
        /// Reference of the ADC [V].
        vref_v: f32,
        /// Voltage at `t0_c` [V].
        v0_v: f32,
        /// Temperature at `v0_v` [deg C].
        t0_c: f32,
        /// Slope [V/K] (positive: the voltage rises with temperature).
        dv_dt_v_per_k: f32,
    },
}

impl Curve {
    /// Temperature [deg C] at ratio `x`.
    #[inline]
    pub fn temperature_c(&self, x: f32) -> f32 {
        match *self {
            Curve::Cubic(c) => ((c[0] * x + c[1]) * x + c[2]) * x + c[3],
            Curve::Linear {
                vref_v,
                v0_v,
                t0_c,
                dv_dt_v_per_k,
            } => t0_c + (x * vref_v - v0_v) / dv_dt_v_per_k,
        }
    }
}

/// An NTC divider read by the ADC: its curve and the limits of a sane
/// reading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NtcDivider {
    /// Counts-ratio to temperature.
    pub curve: Curve,
    /// Ratios below this are [`ThermistorError::Open`].
    pub open_below: f32,
    /// Ratios above this are [`ThermistorError::Short`].
    pub short_above: f32,
}

impl NtcDivider {
    /// Temperature [deg C] of a raw reading `counts` of an ADC of
    /// `adc_bits` bits, or why it is not one. Never NaN: `counts` is an
    /// integer and both curves are finite for every ratio in range.
    pub fn temperature_c(&self, counts: u16, adc_bits: u8) -> Result<f32, ThermistorError> {
        let full_scale = (1u32 << adc_bits.min(16)) as f32;
        let x = counts as f32 / full_scale;
        if x < self.open_below {
            Err(ThermistorError::Open)
        } else if x > self.short_above {
            Err(ThermistorError::Short)
        } else {
            Ok(self.curve.temperature_c(x))
        }
    }
}

/// Ratio of full scale below which a reading is an open NTC.
pub const OPEN_BELOW: f32 = 0.02;
/// Ratio of full scale above which a reading is a shorted NTC.
pub const SHORT_ABOVE: f32 = 0.98;

/// ODrive v3.x FET thermistor (M0: PC5 = ADC12_IN15; M1: ADC channel 4 on
/// v3.3+): the ODrive firmware's cubic (module docs).
pub const ODRIVE_V3_FET: NtcDivider = NtcDivider {
    curve: Curve::Cubic([363.939_1, -462.153_7, 307.551_3, -27.725_695]),
    open_below: OPEN_BELOW,
    short_above: SHORT_ABOVE,
};

/// X-NUCLEO-IHM07M1 power-stage NTC (PC2 = ADC1_IN12 on the NUCLEO-64
/// F4 boards): ST's linear law (module docs).
pub const IHM07M1: NtcDivider = NtcDivider {
    curve: Curve::Linear {
        vref_v: 3.3,
        v0_v: 1.055,
        t0_c: 25.0,
        dv_dt_v_per_k: 0.023,
    },
    open_below: OPEN_BELOW,
    short_above: SHORT_ABOVE,
};

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use proptest::prelude::*;

    /// Ratio of a `r25` NTC with constant `b` over `r_low` to ground at `t_c`.
    fn ratio(t_c: f64, r25: f64, b: f64, r_low: f64) -> f64 {
        let r = r25 * (b * (1.0 / (t_c + 273.15) - 1.0 / 298.15)).exp();
        r_low / (r_low + r)
    }

    fn counts(x: f64) -> u16 {
        (x * 4096.0).round() as u16
    }

    #[test]
    fn odrive_cubic_matches_a_10k_ntc_over_3k3() {
        for t in (0..=120).step_by(10) {
            let x = ratio(t as f64, 10e3, 3435.0, 3.3e3);
            let got = ODRIVE_V3_FET.temperature_c(counts(x), 12).unwrap();
            assert!((got - t as f32).abs() < 2.5, "{t} deg C read as {got}");
        }
    }

    #[test]
    fn ihm07m1_linear_law_points() {
        // V0 = 1.055 V at 25 deg C; 23 mV/K.
        let c = |v: f32| counts(f64::from(v / 3.3));
        let t25 = IHM07M1.temperature_c(c(1.055), 12).unwrap();
        assert!((t25 - 25.0).abs() < 0.1, "{t25}");
        let t110 = IHM07M1.temperature_c(c(1.055 + 0.023 * 85.0), 12).unwrap();
        assert!((t110 - 110.0).abs() < 0.1, "{t110}");
        // And the law is close to a 10k NTC over 4.7k where it matters.
        for t in [25.0, 50.0, 80.0] {
            let x = ratio(t, 10e3, 3435.0, 4.7e3);
            let got = IHM07M1.temperature_c(counts(x), 12).unwrap();
            assert!((got - t as f32).abs() < 6.0, "{t} deg C read as {got}");
        }
    }

    #[test]
    fn open_and_short_are_errors_not_temperatures() {
        for s in [ODRIVE_V3_FET, IHM07M1] {
            assert_eq!(s.temperature_c(0, 12), Err(ThermistorError::Open));
            assert_eq!(s.temperature_c(50, 12), Err(ThermistorError::Open));
            assert_eq!(s.temperature_c(4095, 12), Err(ThermistorError::Short));
            assert_eq!(s.temperature_c(4050, 12), Err(ThermistorError::Short));
            // Out of range for the resolution (a wrong `adc_bits`): short.
            assert_eq!(s.temperature_c(u16::MAX, 12), Err(ThermistorError::Short));
            // Just inside the limits: temperatures.
            assert!(s.temperature_c(100, 12).is_ok());
            assert!(s.temperature_c(4000, 12).is_ok());
        }
    }

    proptest! {
        #[test]
        fn finite_and_rising_inside_the_limits(a in 0u16..4096, b in 0u16..4096) {
            for s in [ODRIVE_V3_FET, IHM07M1] {
                let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
                match (s.temperature_c(lo, 12), s.temperature_c(hi, 12)) {
                    (Ok(tl), Ok(th)) => {
                        prop_assert!(tl.is_finite() && th.is_finite());
                        prop_assert!(tl <= th);
                    }
                    (rl, rh) => {
                        // Only the ends of the range are errors.
                        for (c, r) in [(lo, rl), (hi, rh)] {
                            if let Err(e) = r {
                                let x = c as f32 / 4096.0;
                                prop_assert!(
                                    (e == ThermistorError::Open && x < OPEN_BELOW)
                                        || (e == ThermistorError::Short && x > SHORT_ABOVE)
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}
