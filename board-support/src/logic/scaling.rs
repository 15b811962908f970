//! Raw ADC counts to physical units: phase current and divided voltages.
//!
//! Current through a shunt measured by an amplifier with a bias:
//!
//! `i [A] = sign * (counts - offset_counts) * (vref / 2^bits) / (gain * shunt_ohm)`
//!
//! `sign` is -1 for inverting amplifiers (the X-NUCLEO-IHM07M1's, gain
//! -1.53) and +1 for the DRV8301's (whose output is `Vref/2 - G * (SN - SP)`,
//! with SN/SP wired so that the firmware convention comes out positive).
//!
//! Voltage through a divider `r_top` over `r_bottom`:
//!
//! `v [V] = counts * (vref / 2^bits) * (r_top + r_bottom) / r_bottom`
//!
//! ```
//! use board_support::logic::scaling::{CurrentScale, VoltageScale};
//! let cs = CurrentScale::new(0.33, 1.53, 3.3, 12, 2048.0, -1.0);
//! assert!((cs.amps(2048) - 0.0).abs() < 1e-6);
//! assert!(cs.amps(2148) < 0.0); // inverting amplifier
//! let vs = VoltageScale::divider(169_000.0, 9_310.0, 3.3, 12);
//! assert!((vs.volts(4096) - 3.3 * 19.152).abs() < 0.01);
//! ```

/// Conversion from ADC counts to phase current [A].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentScale {
    /// Amperes per ADC count, sign included.
    pub amps_per_count: f32,
    /// ADC reading at zero current (nominally mid-scale).
    pub offset_counts: f32,
}

impl CurrentScale {
    /// From the hardware values: shunt [ohm], amplifier gain magnitude [V/V],
    /// ADC reference [V], ADC resolution [bits], zero-current reading
    /// [counts], and sign (+1 or -1; anything `< 0` is taken as -1).
    pub const fn new(
        shunt_ohm: f32,
        gain: f32,
        vref_v: f32,
        adc_bits: u8,
        offset_counts: f32,
        sign: f32,
    ) -> Self {
        let full_scale = (1u32 << adc_bits) as f32;
        let s = if sign < 0.0 { -1.0 } else { 1.0 };
        Self {
            amps_per_count: s * vref_v / full_scale / (gain * shunt_ohm),
            offset_counts,
        }
    }

    /// Current [A] for a raw reading.
    #[inline]
    pub fn amps(&self, counts: u16) -> f32 {
        (counts as f32 - self.offset_counts) * self.amps_per_count
    }

    /// Largest current magnitude [A] measurable on the smaller side of the
    /// offset, for an ADC of `adc_bits`.
    pub fn range_a(&self, adc_bits: u8) -> f32 {
        let top = ((1u32 << adc_bits) - 1) as f32 - self.offset_counts;
        let bottom = self.offset_counts;
        let m = if top < bottom { top } else { bottom };
        m * abs(self.amps_per_count)
    }
}

/// Conversion from ADC counts to a voltage behind a resistor divider.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VoltageScale {
    /// Volts (at the divider input) per ADC count.
    pub volts_per_count: f32,
}

impl VoltageScale {
    /// From the divider resistors [ohm], ADC reference [V] and resolution.
    pub const fn divider(r_top_ohm: f32, r_bottom_ohm: f32, vref_v: f32, adc_bits: u8) -> Self {
        Self::ratio((r_top_ohm + r_bottom_ohm) / r_bottom_ohm, vref_v, adc_bits)
    }

    /// From the division ratio `v_in / v_adc` (e.g. 19.0).
    pub const fn ratio(ratio: f32, vref_v: f32, adc_bits: u8) -> Self {
        Self {
            volts_per_count: vref_v / (1u32 << adc_bits) as f32 * ratio,
        }
    }

    /// Voltage [V] for a raw reading.
    #[inline]
    pub fn volts(&self, counts: u16) -> f32 {
        counts as f32 * self.volts_per_count
    }
}

#[inline]
fn abs(x: f32) -> f32 {
    if x < 0.0 {
        -x
    } else {
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn ihm07m1_current() {
        let cs = CurrentScale::new(0.33, 1.53, 3.3, 12, 2048.0, -1.0);
        // 1 A through 0.33 ohm, gain 1.53 -> 0.5049 V below the bias.
        let counts: f32 = 2048.0 - 0.5049 / 3.3 * 4096.0;
        assert!((cs.amps(counts.round() as u16) - 1.0).abs() < 0.01);
        assert!((cs.range_a(12) - 3.27).abs() < 0.01);
    }

    #[test]
    fn odrive_current() {
        // DRV8301 gain 40, 0.5 mOhm, +1 sign: 1 count = 3.3/4096/0.02 A.
        let cs = CurrentScale::new(0.0005, 40.0, 3.3, 12, 2048.0, 1.0);
        assert!((cs.amps(2049) - 0.040_283).abs() < 1e-5);
        assert!((cs.amps(2048 + 1000) - 40.283).abs() < 1e-2);
    }

    #[test]
    fn bus_voltage() {
        let vs = VoltageScale::ratio(19.0, 3.3, 12);
        assert!((vs.volts(2048) - 31.35).abs() < 1e-3);
        assert_eq!(vs.volts(0), 0.0);
    }

    proptest! {
        #[test]
        fn current_is_linear_and_odd(c in 0u16..4096, sign in prop::bool::ANY) {
            let s = if sign { 1.0 } else { -1.0 };
            let cs = CurrentScale::new(0.33, 1.53, 3.3, 12, 2048.0, s);
            let i = cs.amps(c);
            let mirrored = cs.amps((4096 - c as u32).min(4095) as u16);
            prop_assert!(i.is_finite());
            if c > 0 {
                prop_assert!((i + mirrored).abs() < 1e-4);
            }
            if c != 2048 {
                prop_assert_eq!(i > 0.0, (c > 2048) == sign);
            }
        }
    }
}
