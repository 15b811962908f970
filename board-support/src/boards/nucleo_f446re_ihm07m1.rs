//! NUCLEO-F446RE + X-NUCLEO-IHM07M1 (the default board).
//!
//! Clock: 8 MHz from the ST-LINK's MCO into OSC_IN (HSE bypass; ST UM1724,
//! "HSE clock (high-speed external clock)", MCO from ST-LINK is the default
//! configuration), PLL to 180 MHz (over-drive enabled by the HAL), APB2 =
//! 90 MHz so TIM1 runs at 180 MHz, APB1 = 45 MHz. Pin map and power stage:
//! see the shared X-NUCLEO-IHM07M1 module documentation (re-exported items
//! below), which also covers the power-stage NTC (read, on PC2) and the
//! brake (none: `Brake` is `NoBrake`).
//! Memory: `board-support/memory/nucleo-f446re-ihm07m1.x`.

pub use super::ihm07m1::{
    after_hardfault, after_panic, angle_kind, break_isr_ack, emergency_disable, gate_driver_fault,
    Angle, Board, Brake, Bus, Currents, Pwm, ANGLE_SOURCE, BRAKE_OUTPUT, BREAK_IRQ, BUS_SCALE,
    BUS_VOLTAGE_MAX_V, BUS_VOLTAGE_MIN_V, CURRENT_IRQ, CURRENT_SCALE, DEAD_TIME_NS, DIAG_PIN,
    ENABLE_PINS, HALL_PINS, HAS_BREAK_INPUT, HAS_CAN, LED_PIN, MAX_MEASURABLE_CURRENT_A,
    MAX_PHASE_CURRENT_A, PWM_FREQUENCY_15K_HZ, PWM_FREQUENCY_HZ, SERIAL_BAUD, SERIAL_IRQ,
    STAGE_TEMPERATURE_SENSOR, STORE_RANGE, THERMISTOR, THERMISTOR_CHANNEL,
};
pub use super::Led;
pub use crate::hw::angle::AngleSource;
pub use crate::hw::flash::StoreFlash;
pub use crate::hw::serial::CommandSerial;
use crate::pac;
use fugit::RateExtU32;
use stm32f4xx_hal::rcc::Config;

/// Board name.
pub const NAME: &str = "NUCLEO-F446RE + X-NUCLEO-IHM07M1";
/// Core clock [Hz].
pub const SYSCLK_HZ: u32 = 180_000_000;

/// Set up clocks, pins, TIM1, ADC1 and the angle input. Bridge disabled,
/// PWM counter running, NVIC untouched.
pub fn init(dp: pac::Peripherals) -> Board {
    super::ihm07m1::init(
        dp,
        super::ihm07m1::Params {
            rcc: Config::hse(8.MHz())
                .bypass_hse_oscillator()
                .sysclk(SYSCLK_HZ.Hz())
                .hclk(SYSCLK_HZ.Hz())
                .pclk1(45.MHz())
                .pclk2(90.MHz()),
            sysclk_hz: SYSCLK_HZ,
            pwm_hz: PWM_FREQUENCY_HZ,
            angle: ANGLE_SOURCE,
        },
    )
}
