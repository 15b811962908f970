//! NUCLEO-F446RE + X-NUCLEO-IHM07M1 (the default board).
//!
//! Clock: 8 MHz from the ST-LINK's MCO into OSC_IN (HSE bypass; ST UM1724,
//! "HSE clock (high-speed external clock)", MCO from ST-LINK is the default
//! configuration), PLL to 180 MHz (over-drive enabled by the HAL), APB2 =
//! 90 MHz so TIM1 runs at 180 MHz, APB1 = 45 MHz. Pin map and power stage:
//! see the shared X-NUCLEO-IHM07M1 module documentation (re-exported items
//! below). Memory: `board-support/memory/nucleo-f446re-ihm07m1.x`.

pub use super::ihm07m1::{
    break_isr_ack, emergency_disable, gate_driver_fault, Angle, Board, Bus, Currents, Pwm,
    BUS_SCALE, CURRENT_SCALE, DIAG_PIN, ENABLE_PINS, HALL_PINS, LED_PIN, SERIAL_BAUD,
};
pub use super::Led;
pub use crate::hw::angle::AngleSource;
pub use crate::hw::serial::CommandSerial;
use crate::logic::hall::HallConfig;
use crate::pac;
use fugit::RateExtU32;
use stm32f4xx_hal::rcc::Config;

/// Board name.
pub const NAME: &str = "NUCLEO-F446RE + X-NUCLEO-IHM07M1";
/// Core clock [Hz].
pub const SYSCLK_HZ: u32 = 180_000_000;
/// The source's alternative PWM frequency [Hz].
pub const PWM_FREQUENCY_15K_HZ: u32 = 15_000;
/// PWM frequency [Hz] (set to [`PWM_FREQUENCY_15K_HZ`] for 15 kHz).
pub const PWM_FREQUENCY_HZ: u32 = 20_000;
/// Dead time [ns]: inserted by the L6230 itself (3-PWM), none by TIM1.
/// Typical value from the L6230 datasheet, to be confirmed there.
pub const DEAD_TIME_NS: u32 = 1_000;
/// ADC interrupt (injected end of conversion of the phase currents).
pub const CURRENT_IRQ: pac::Interrupt = pac::Interrupt::ADC;
/// TIM1 break interrupt (never fires here: no BKIN on this board).
pub const BREAK_IRQ: pac::Interrupt = pac::Interrupt::TIM1_BRK_TIM9;
/// Command UART interrupt (USART2: PA2 TX / PA3 RX, the ST-LINK virtual
/// COM port).
pub const SERIAL_IRQ: pac::Interrupt = pac::Interrupt::USART2;
/// TIM1 BKIN wired to a hardware fault signal.
pub const HAS_BREAK_INPUT: bool = false;
/// Largest phase current of the power stage [A] (L6230: 2.8 A peak, 1.4 A rms).
pub const MAX_PHASE_CURRENT_A: f32 = 2.8;
/// Largest current the sensing can measure [A] (1.65 V / (1.53 * 0.33 ohm)).
pub const MAX_MEASURABLE_CURRENT_A: f32 = 3.2;
/// Lowest bus voltage of the power stage [V].
pub const BUS_VOLTAGE_MIN_V: f32 = 8.0;
/// Highest bus voltage of the power stage [V].
pub const BUS_VOLTAGE_MAX_V: f32 = 48.0;
/// Rotor angle input chosen at `init` (the shield's connector carries either
/// halls or an encoder on the same pins). Halls: the P-NUCLEO-IHM001 kit
/// motor has them; set the pole pairs and offset here or at run time.
pub const ANGLE_SOURCE: AngleSource = AngleSource::Hall(HallConfig {
    // The motor this board is paired with in the firmware's config
    // (GM4108H-class gimbal motor, 11 pole pairs); the firmware checks at
    // compile time that the two agree.
    pole_pairs: 11,
    ..HallConfig::DEFAULT
});

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
