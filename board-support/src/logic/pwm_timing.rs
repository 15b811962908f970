//! PWM period (ARR) and prescaler (PSC) for centre-aligned counting.
//!
//! In centre-aligned mode the counter runs `0 -> ARR -> 0`, so one PWM
//! period is `2 * ARR` counts of the prescaled clock:
//!
//! `f_pwm = f_tim / (2 * (PSC + 1) * ARR)`
//!
//! [`centre_aligned`] picks the smallest prescaler (best resolution) that
//! fits ARR in 16 bits and rounds ARR to the nearest count.
//!
//! ```
//! use board_support::logic::pwm_timing::centre_aligned;
//! let t = centre_aligned(180_000_000, 20_000).unwrap();
//! assert_eq!((t.psc, t.arr), (0, 4500));
//! assert_eq!(t.actual_hz(180_000_000), 20_000.0);
//! ```

/// Smallest accepted ARR: below this the duty resolution is meaningless.
pub const MIN_ARR: u32 = 16;

/// Prescaler and auto-reload for a centre-aligned timer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PwmTiming {
    /// Value for `TIMx_PSC` (the clock is divided by `psc + 1`).
    pub psc: u16,
    /// Value for `TIMx_ARR` (the PWM period is `2 * arr` prescaled counts).
    pub arr: u16,
}

/// Why a PWM frequency cannot be produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PwmTimingError {
    /// Frequency or timer clock is zero.
    Zero,
    /// The frequency is so high that ARR would be below [`MIN_ARR`].
    TooFast,
    /// The frequency is so low that even PSC = 65535 does not fit ARR.
    TooSlow,
}

impl PwmTiming {
    /// The PWM frequency these values produce with timer clock `tim_clk_hz`.
    pub fn actual_hz(&self, tim_clk_hz: u32) -> f32 {
        tim_clk_hz as f32 / (2.0 * (self.psc as f32 + 1.0) * self.arr as f32)
    }
}

/// PSC and ARR for a centre-aligned PWM of `pwm_hz` from a timer clock of
/// `tim_clk_hz`.
pub const fn centre_aligned(tim_clk_hz: u32, pwm_hz: u32) -> Result<PwmTiming, PwmTimingError> {
    if tim_clk_hz == 0 || pwm_hz == 0 {
        return Err(PwmTimingError::Zero);
    }
    let denom = 2 * pwm_hz as u64;
    // total = (PSC + 1) * ARR, rounded.
    let total = (tim_clk_hz as u64 + denom / 2) / denom;
    let div = total.div_ceil(u16::MAX as u64);
    let div = if div == 0 { 1 } else { div };
    if div > 65_536 {
        return Err(PwmTimingError::TooSlow);
    }
    let arr = (tim_clk_hz as u64 + denom * div / 2) / (denom * div);
    if arr < MIN_ARR as u64 {
        return Err(PwmTimingError::TooFast);
    }
    if arr > u16::MAX as u64 {
        return Err(PwmTimingError::TooSlow);
    }
    Ok(PwmTiming {
        psc: (div - 1) as u16,
        arr: arr as u16,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn boards() {
        assert_eq!(
            centre_aligned(180_000_000, 20_000),
            Ok(PwmTiming { psc: 0, arr: 4500 })
        );
        assert_eq!(
            centre_aligned(180_000_000, 15_000),
            Ok(PwmTiming { psc: 0, arr: 6000 })
        );
        assert_eq!(
            centre_aligned(84_000_000, 20_000),
            Ok(PwmTiming { psc: 0, arr: 2100 })
        );
        assert_eq!(
            centre_aligned(84_000_000, 15_000),
            Ok(PwmTiming { psc: 0, arr: 2800 })
        );
        assert_eq!(
            centre_aligned(168_000_000, 20_000),
            Ok(PwmTiming { psc: 0, arr: 4200 })
        );
        assert_eq!(
            centre_aligned(168_000_000, 15_000),
            Ok(PwmTiming { psc: 0, arr: 5600 })
        );
        // ODrive's own setting: 3500 counts at 168 MHz = 24 kHz.
        assert_eq!(
            centre_aligned(168_000_000, 24_000),
            Ok(PwmTiming { psc: 0, arr: 3500 })
        );
    }

    #[test]
    fn errors() {
        assert_eq!(centre_aligned(0, 1), Err(PwmTimingError::Zero));
        assert_eq!(centre_aligned(1, 0), Err(PwmTimingError::Zero));
        assert_eq!(
            centre_aligned(168_000_000, 10_000_000),
            Err(PwmTimingError::TooFast)
        );
        // Even 1 Hz fits with a prescaler (TooSlow needs a clock above u32).
        assert!(centre_aligned(168_000_000, 1).is_ok());
        // Low but feasible: needs a prescaler.
        let t = centre_aligned(168_000_000, 100).unwrap();
        assert!(t.psc > 0);
    }

    proptest! {
        #[test]
        fn frequency_close(clk in 8_000_000u32..=200_000_000, f in 2_000u32..=100_000) {
            if let Ok(t) = centre_aligned(clk, f) {
                let got = t.actual_hz(clk);
                // ARR is rounded to the nearest count: relative error <= 1/(2*ARR).
                let rel = ((got - f as f32) / f as f32).abs();
                prop_assert!(rel <= 0.5 / t.arr as f32 + 1e-5, "rel {} arr {}", rel, t.arr);
                prop_assert!(t.arr as u32 >= MIN_ARR);
            } else {
                prop_assert!(clk / (2 * f) < MIN_ARR);
            }
        }
    }
}
