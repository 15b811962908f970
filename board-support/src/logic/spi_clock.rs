//! SPI master clock: the fastest rate the STM32F4 SPI can make from its
//! bus clock without exceeding a device's limit.
//!
//! The SPI divides its APB clock by a power of two, 2 to 256
//! (`SPI_CR1.BR[2:0]`, RM0090 28.5.1; SPI2/SPI3 run from APB1, SPI1 from
//! APB2). Requesting exactly the returned rate from the HAL makes the
//! clock-to-rate ratio that power of two, so the HAL picks that divider.
//!
//! ```
//! use board_support::logic::spi_clock::fastest_spi_clock_hz;
//! // ODrive v3: APB1 at 42 MHz, AS5047P at most 10 MHz: /8 = 5.25 MHz
//! // (/4 = 10.5 MHz would be too fast).
//! assert_eq!(fastest_spi_clock_hz(42_000_000, 10_000_000), Some(5_250_000));
//! ```

/// The SPI's clock dividers, fastest first (`BR` = 0b000 ..= 0b111).
pub const DIVIDERS: [u32; 8] = [2, 4, 8, 16, 32, 64, 128, 256];

/// The smallest divider of [`DIVIDERS`] for which `pclk_hz / divider` is
/// at most `max_hz` (compared without rounding: `pclk_hz <= max_hz *
/// divider`), or `None` when even `/256` is too fast or the result would
/// be below 1 Hz.
pub const fn fastest_divider(pclk_hz: u32, max_hz: u32) -> Option<u32> {
    let mut rest: &[u32] = &DIVIDERS;
    while let [div, tail @ ..] = rest {
        let div = *div;
        if pclk_hz as u64 <= max_hz as u64 * div as u64 {
            return if pclk_hz / div > 0 { Some(div) } else { None };
        }
        rest = tail;
    }
    None
}

/// The fastest SPI clock [Hz] at most `max_hz`: `pclk_hz /`
/// [`fastest_divider`].
pub const fn fastest_spi_clock_hz(pclk_hz: u32, max_hz: u32) -> Option<u32> {
    match fastest_divider(pclk_hz, max_hz) {
        Some(div) => Some(pclk_hz / div),
        None => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn known_clocks() {
        // ODrive v3 SPI3 (APB1 42 MHz): AS5047P (10 MHz) and DRV8301 (10 MHz).
        assert_eq!(
            fastest_spi_clock_hz(42_000_000, 10_000_000),
            Some(5_250_000)
        );
        // Exactly at the limit is allowed.
        assert_eq!(
            fastest_spi_clock_hz(42_000_000, 10_500_000),
            Some(10_500_000)
        );
        assert_eq!(
            fastest_spi_clock_hz(42_000_000, 21_000_000),
            Some(21_000_000)
        );
        assert_eq!(
            fastest_spi_clock_hz(42_000_000, 100_000_000),
            Some(21_000_000)
        );
        // 1 MHz: /64 = 656.25 kHz (/32 = 1.3125 MHz is too fast).
        assert_eq!(fastest_spi_clock_hz(42_000_000, 1_000_000), Some(656_250));
        // SPI1 on APB2 at 84 MHz.
        assert_eq!(
            fastest_spi_clock_hz(84_000_000, 10_000_000),
            Some(5_250_000)
        );
        // Nothing slow enough, or no clock.
        assert_eq!(fastest_spi_clock_hz(42_000_000, 100_000), None);
        assert_eq!(fastest_spi_clock_hz(42_000_000, 0), None);
        assert_eq!(fastest_spi_clock_hz(0, 10_000_000), None);
        assert_eq!(fastest_divider(42_000_000, 10_000_000), Some(8));
        assert_eq!(fastest_divider(42_000_000, 1_000_000), Some(64));
    }

    proptest! {
        #[test]
        fn never_too_fast_and_never_needlessly_slow(
            pclk in 1u32..=200_000_000,
            max in 1u32..=100_000_000,
        ) {
            match fastest_divider(pclk, max) {
                Some(div) => {
                    let i = DIVIDERS.iter().position(|&d| d == div);
                    prop_assert!(i.is_some());
                    let hz = fastest_spi_clock_hz(pclk, max);
                    prop_assert_eq!(hz, Some(pclk / div));
                    prop_assert!(pclk / div <= max && pclk / div > 0);
                    // The next faster divider would exceed the limit.
                    if let Some(i) = i.filter(|&i| i > 0) {
                        prop_assert!(pclk as u64 > max as u64 * DIVIDERS[i - 1] as u64);
                    }
                }
                None => prop_assert!(
                    pclk as u64 > max as u64 * 256
                        || DIVIDERS.iter().any(|&d| pclk as u64 <= max as u64 * d as u64 && pclk / d == 0)
                ),
            }
        }
    }
}
