//! STM32F4 drivers for the `foc_core::hal` traits (feature `_hal`).
//!
//! Register-level code is confined to these modules; each `unsafe` names
//! the reference-manual section it follows: RM0090 (F405), RM0390 (F446),
//! RM0368 (F401). The register layouts used here are identical on the three
//! chips (TIM1, ADC1, GPIO, general-purpose timers).

pub mod adc;
pub mod angle;
pub mod as5047p;
#[cfg(feature = "odrive-v3")]
pub mod brake;
#[cfg(feature = "odrive-v3")]
pub mod can;
pub mod drv8301;
#[cfg(not(feature = "qemu"))]
pub mod flash;
pub mod pwm;
pub mod serial;
#[cfg(feature = "qemu")]
pub mod slcan;

use crate::pac;

/// A GPIO port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Port {
    /// GPIOA.
    A,
    /// GPIOB.
    B,
    /// GPIOC.
    C,
    /// GPIOD.
    D,
}

/// One GPIO pin, addressed by port and number, for code that must work
/// from any context (safe state, fault pins).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PinId {
    /// Port.
    pub port: Port,
    /// Pin number 0..=15.
    pub pin: u8,
}

impl PinId {
    /// Pin `pin` of `port`.
    pub const fn new(port: Port, pin: u8) -> Self {
        Self { port, pin }
    }

    /// Drive the pin high (`high = true`) or low through `BSRR`.
    ///
    /// A single atomic store: safe from any context and racing with nothing
    /// (RM0090 8.4.7 / RM0390 7.4.7 / RM0368 8.4.7, GPIOx_BSRR).
    #[inline]
    pub fn set(self, high: bool) {
        let n = (self.pin & 15) as u32;
        let bits = if high { 1 << n } else { 1 << (16 + n) };
        // SAFETY: BSRR is write-only and set/reset per bit; writing it never
        // disturbs other pins or a concurrent read-modify-write of ODR.
        unsafe {
            match self.port {
                Port::A => (*pac::GPIOA::ptr()).bsrr().write(|w| w.bits(bits)),
                Port::B => (*pac::GPIOB::ptr()).bsrr().write(|w| w.bits(bits)),
                Port::C => (*pac::GPIOC::ptr()).bsrr().write(|w| w.bits(bits)),
                Port::D => (*pac::GPIOD::ptr()).bsrr().write(|w| w.bits(bits)),
            };
        }
    }

    /// Input level of the pin (`IDR`, RM0090 8.4.5).
    #[inline]
    pub fn is_high(self) -> bool {
        let n = (self.pin & 15) as u32;
        // SAFETY: read-only access to the input data register.
        let idr = unsafe {
            match self.port {
                Port::A => (*pac::GPIOA::ptr()).idr().read().bits(),
                Port::B => (*pac::GPIOB::ptr()).idr().read().bits(),
                Port::C => (*pac::GPIOC::ptr()).idr().read().bits(),
                Port::D => (*pac::GPIOD::ptr()).idr().read().bits(),
            }
        };
        idr & (1 << n) != 0
    }

    /// Output latch of the pin (`ODR`): what the pin is being driven to.
    #[inline]
    pub fn is_set_high(self) -> bool {
        let n = (self.pin & 15) as u32;
        // SAFETY: read-only access to the output data register.
        let odr = unsafe {
            match self.port {
                Port::A => (*pac::GPIOA::ptr()).odr().read().bits(),
                Port::B => (*pac::GPIOB::ptr()).odr().read().bits(),
                Port::C => (*pac::GPIOC::ptr()).odr().read().bits(),
                Port::D => (*pac::GPIOD::ptr()).odr().read().bits(),
            }
        };
        odr & (1 << n) != 0
    }
}

/// Free-running time stamp: the DWT cycle counter (core clock ticks).
///
/// Enabled by the board's `init` (ARMv7-M ARM C1.8, DWT_CTRL.CYCCNTENA).
#[inline]
pub fn cycle_count() -> u32 {
    cortex_m::peripheral::DWT::cycle_count()
}

/// Enable the DWT cycle counter (trace enable in DEMCR, then CYCCNTENA).
#[cfg_attr(feature = "qemu", allow(dead_code))]
pub(crate) fn enable_cycle_counter() {
    // SAFETY: only sets enable bits in DEMCR / DWT_CTRL (ARMv7-M ARM C1.6.5,
    // C1.8.7); harmless for any other user of the DWT (e.g. profiling).
    unsafe {
        let mut cp = cortex_m::Peripherals::steal();
        cp.DCB.enable_trace();
        cp.DWT.enable_cycle_counter();
    }
}

/// Busy-wait for `us` microseconds at `sysclk_hz` (initialisation only).
pub fn delay_us(sysclk_hz: u32, us: u32) {
    cortex_m::asm::delay((sysclk_hz / 1_000_000).saturating_mul(us));
}
