//! X-NUCLEO-IHM07M1 (L6230 three-phase driver) on a NUCLEO-64 board: the
//! part shared by the F446RE and F401RE boards.
//!
//! Pin map. Sources: ST UM1943 (X-NUCLEO-IHM07M1 user manual) via the
//! Apache NuttX board documentation of this shield on NUCLEO-64 boards
//! (`Documentation/platforms/arm/stm32f3/boards/nucleo-f302r8/index.rst`,
//! `boards/arm/stm32/nucleo-f103rb/README.txt`; the NUCLEO-64 morpho
//! connectors route the same pins on every LQFP64 part, ST UM1724), and the
//! STM32F401/F446 datasheets' alternate-function tables:
//!
//! | signal                 | pin   | function here                 |
//! |------------------------|-------|-------------------------------|
//! | IN1 / IN2 / IN3        | PA8 / PA9 / PA10 | TIM1_CH1..3 (AF1) |
//! | EN1 / EN2 / EN3        | PC10 / PC11 / PC12 | GPIO out, high = phase on |
//! | DIAG/EN (L6230 fault)  | PA11  | GPIO in, low = fault          |
//! | current U / V / W      | PA0 / PC1 / PC0 | ADC1_IN0 / IN11 / IN10 |
//! | VBUS                   | PA1   | ADC1_IN1                      |
//! | temperature (NTC)      | PC2   | ADC1_IN12, regular, alternating with VBUS |
//! | ENC A / H1             | PA15  | TIM2_CH1 (AF1) or GPIO        |
//! | ENC B / H2             | PB3   | TIM2_CH2 (AF1) or GPIO        |
//! | ENC Z / H3             | PB10  | TIM2_CH3 (AF1, index capture) or GPIO |
//! | user LED LD2 (NUCLEO)  | PA5   | GPIO out (ST UM1724)          |
//! | command UART TX / RX   | PA2 / PA3 | USART2 (AF7), 115200 8N1: the ST-LINK virtual COM port (ST UM1724, solder bridges SB13/SB14 closed by default) |
//!
//! Power stage (same sources): shunts 0.33 ohm, current amplifier gain
//! -1.53 (inverting, biased), bus divider 169k / 9.31k (ratio 19.152),
//! bus 8..48 V, L6230 output 1.4 A rms (2.8 A peak).
//!
//! Power-stage temperature ([`STAGE_TEMPERATURE_SENSOR`] = true): the
//! shield's NTC network on PC2 (the NuttX pin table above: "Temperature",
//! PC2; ADC1_IN12 on the F401/F446, datasheets' pin tables), converted with
//! ST's Motor Control SDK law for this power stage, 1.055 V at 25 deg C and
//! 23 mV/K (a `power_stage_parameters.h` of the MC SDK for the stage with
//! 0.33 Ohm shunts, gain 1.53 and bus divider 0.0522; its `T_MAX`, the
//! sensor temperature at the stage's limit, is 110 deg C): see
//! [`crate::logic::thermistor::IHM07M1`]. It sits near the L6230 on the
//! board, so it lags the die; the L6230's own thermal shutdown (which pulls
//! DIAG/EN low, [`gate_driver_fault`]) stays the last line. ADC1's regular
//! group converts it and VBUS in turn (`hw::adc`): each is refreshed every
//! other PWM period. UM1943 itself was not available to check the part;
//! unverified on hardware.
//!
//! Brake resistor ([`BRAKE_OUTPUT`] = false): the shield has none and no
//! switch for one ([`Brake`] is `foc_core::hal::NoBrake`); regenerated
//! energy can only be limited (design §18) or absorbed by the supply.
//!
//! No TIM1 break input: the shield's BKIN1 signal lands on PB14, which is
//! TIM1_CH2N on the F4, not BKIN. The L6230's own over-current/thermal
//! protection pulls DIAG/EN low and disables the bridge by itself; that pin
//! is what [`gate_driver_fault`] reports.

use super::Led;
use crate::hw::adc::{
    set_regular_sample_time, setup_adc1, InjectedCurrents, RegularBus, SampleTime, Shunts,
};
use crate::hw::angle::{AngleInput, AngleSource, HallSensor, QuadEncoder};
use crate::hw::flash::StoreFlash;
use crate::hw::pwm::{PwmConfig, Tim1Pwm, Topology};
use crate::hw::serial::CommandSerial;
use crate::hw::{enable_cycle_counter, PinId, Port};
use crate::logic::hall::HallConfig;
use crate::pac;
use foc_core::hal::NoBrake;
use stm32f4xx_hal::gpio::{self, GpioExt, PinState};
use stm32f4xx_hal::qei::Qei;
use stm32f4xx_hal::rcc::{Config, Enable, Rcc, RccExt, Reset};

// Constants of the shield, the same on every NUCLEO-64 board it sits on
// (re-exported by the board modules).

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
/// No CAN port: the X-NUCLEO-IHM07M1 has no CAN transceiver (and the
/// F401 no CAN controller); see the crate docs, "CAN".
pub const HAS_CAN: bool = false;
/// Largest phase current of the power stage [A] (L6230: 2.8 A peak, 1.4 A rms).
pub const MAX_PHASE_CURRENT_A: f32 = 2.8;
/// Largest current the sensing can measure [A] (1.65 V / (1.53 * 0.33 ohm)).
pub const MAX_MEASURABLE_CURRENT_A: f32 = 3.2;
/// Lowest bus voltage of the power stage [V].
pub const BUS_VOLTAGE_MIN_V: f32 = 8.0;
/// Highest bus voltage of the power stage [V].
pub const BUS_VOLTAGE_MAX_V: f32 = 48.0;
/// No brake resistor and no switch for one on the shield ([`Brake`] is
/// `NoBrake`).
pub const BRAKE_OUTPUT: bool = false;
/// The shield's NTC near the L6230 is read ([`Bus`]'s `read_temperature_c`,
/// module docs).
pub const STAGE_TEMPERATURE_SENSOR: bool = true;
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

/// The configuration store: flash sectors 6-7 (0x0804_0000..0x0808_0000) of
/// the 512 KiB STM32F446RE / F401RE, as offsets from the flash base
/// (RM0390 §3.3 table 4, RM0368 §3.3 table 5). The linker scripts keep the
/// program out of it (`STORE` region of `memory/<board>.x`).
pub const STORE_RANGE: core::ops::Range<u32> = 0x4_0000..0x8_0000;
const _: () = assert!(crate::hw::flash::is_store_region(&STORE_RANGE, 512 * 1024));

/// What the angle input tells at reset (from [`ANGLE_SOURCE`]).
pub const fn angle_kind() -> foc_core::drive::AngleKind {
    ANGLE_SOURCE.kind()
}

/// The L6230 enable pins EN1..3 (PC10, PC11, PC12).
pub const ENABLE_PINS: [PinId; 3] = [
    PinId::new(Port::C, 10),
    PinId::new(Port::C, 11),
    PinId::new(Port::C, 12),
];
/// L6230 DIAG/EN (open drain, low = over-current or over-temperature).
pub const DIAG_PIN: PinId = PinId::new(Port::A, 11);
/// NUCLEO user LED LD2.
pub const LED_PIN: PinId = PinId::new(Port::A, 5);
/// Hall inputs H1, H2, H3 (phase A, B, C sensors).
pub const HALL_PINS: [PinId; 3] = [
    PinId::new(Port::A, 15),
    PinId::new(Port::B, 3),
    PinId::new(Port::B, 10),
];

pub use super::ihm07m1_analog::*;

/// The PWM stage.
pub type Pwm = Tim1Pwm;
/// Phase-current sensing (three shunts).
pub type Currents = InjectedCurrents;
/// Rotor angle: encoder on TIM2 or halls (see `ANGLE_SOURCE`).
pub type Angle = AngleInput<pac::TIM2>;
/// Bus voltage and the power-stage NTC.
pub type Bus = RegularBus;
/// No brake output on this shield.
pub type Brake = NoBrake;

/// Everything `init` sets up.
pub struct Board {
    /// TIM1 PWM (3-PWM + EN pins), disabled.
    pub pwm: Pwm,
    /// Phase currents (ADC1 injected, TIM1-triggered).
    pub currents: Currents,
    /// Rotor angle.
    pub angle: Angle,
    /// Bus voltage and power-stage temperature (ADC1 regular, alternating).
    pub bus: Bus,
    /// No brake output: `NoBrake` (does nothing, never on).
    pub brake: Brake,
    /// NUCLEO LED LD2.
    pub led: Led,
    /// Command UART: USART2 on PA2/PA3, the ST-LINK virtual COM port.
    pub serial: CommandSerial,
    /// The configuration store's flash region ([`STORE_RANGE`]). Erasing a
    /// sector stalls the CPU for seconds: bridge off first (`hw::flash`).
    pub store: StoreFlash,
}

/// Baud rate of the command UART [bit/s] (8N1).
pub const SERIAL_BAUD: u32 = 115_200;

/// Parameters that differ between the NUCLEO boards.
pub(crate) struct Params {
    pub rcc: Config,
    pub sysclk_hz: u32,
    pub pwm_hz: u32,
    pub angle: AngleSource,
}

/// Set up clocks, pins, TIM1, ADC1, the angle input and the command UART.
/// Bridge disabled (MOE = 0, EN1..3 low), PWM counter running, NVIC
/// untouched.
pub(crate) fn init(dp: pac::Peripherals, p: Params) -> Board {
    // Safe state first: EN pins low before anything else.
    let mut rcc = dp.RCC.freeze(p.rcc);
    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);
    let gpioc = dp.GPIOC.split(&mut rcc);
    outputs_safe((gpioc.pc10, gpioc.pc11, gpioc.pc12), gpioa.pa11, gpioa.pa5);
    enable_cycle_counter();

    let pwm = tim1_three_pwm(
        dp.TIM1,
        (gpioa.pa8, gpioa.pa9, gpioa.pa10),
        p.pwm_hz,
        &mut rcc,
    );
    let (currents, bus) = adc1_sensing(
        &dp.ADC1,
        &dp.ADC_COMMON,
        (gpioa.pa0, gpioc.pc1, gpioc.pc0),
        gpioa.pa1,
        gpioc.pc2,
        &mut rcc,
    );
    let angle = encoder_or_halls(
        dp.TIM2,
        p.angle,
        p.sysclk_hz,
        (gpioa.pa15, gpiob.pb3),
        gpiob.pb10,
        &mut rcc,
    );

    // Command UART: USART2 TX/RX on PA2/PA3 (AF7), wired to the ST-LINK
    // virtual COM port (UM1724). Clock enable and reset through the HAL
    // (RCC_APB1ENR.USART2EN, RM0390 6.3.13 / RM0368 6.3.11).
    let serial =
        CommandSerial::usart2_on_pa2_pa3(dp.USART2, gpioa.pa2, gpioa.pa3, &mut rcc, SERIAL_BAUD);

    Board {
        pwm,
        currents,
        angle,
        bus,
        brake: NoBrake,
        led: Led::new(Some(LED_PIN)),
        serial,
        // After `rcc.freeze`, which sets the wait states through its own
        // FLASH_ACR pointer and does not need the peripheral.
        store: StoreFlash::new(dp.FLASH, STORE_RANGE),
    }
}

/// The safe state of the pins: the L6230 enables EN1..3 (PC10-12) low,
/// DIAG/EN (PA11) an input with pull-up, the LED (PA5) off.
fn outputs_safe(en: (gpio::PC10, gpio::PC11, gpio::PC12), diag: gpio::PA11, led: gpio::PA5) {
    let _en1 = en.0.into_push_pull_output_in_state(PinState::Low);
    let _en2 = en.1.into_push_pull_output_in_state(PinState::Low);
    let _en3 = en.2.into_push_pull_output_in_state(PinState::Low);
    let _diag = diag.into_pull_up_input();
    let _led = led.into_push_pull_output_in_state(PinState::Low);
}

/// TIM1 3-PWM (the L6230 inserts the dead time): CH1..3 to PA8-10, TIM1's
/// clock enabled and the timer reset, then [`Tim1Pwm`] at `pwm_hz` with
/// the EN pins.
fn tim1_three_pwm(
    tim1: pac::TIM1,
    pins: (gpio::PA8, gpio::PA9, gpio::PA10),
    pwm_hz: u32,
    rcc: &mut Rcc,
) -> Pwm {
    // TIM1: CH1..3 on PA8..10 (AF1).
    let _ch1 = pins.0.into_alternate::<1>();
    let _ch2 = pins.1.into_alternate::<1>();
    let _ch3 = pins.2.into_alternate::<1>();
    pac::TIM1::enable(rcc);
    pac::TIM1::reset(rcc);
    let tim_clk = rcc.clocks.timclk2().raw();
    match Tim1Pwm::new(
        tim1,
        tim_clk,
        PwmConfig {
            frequency_hz: pwm_hz,
            topology: Topology::ThreePwm,
            break_input: None,
            enable_pins: &ENABLE_PINS,
            enable_pins_in_disable: true,
        },
    ) {
        Ok(pwm) => pwm,
        // Only a PWM_FREQUENCY_HZ const out of range gets here: a build-time
        // configuration error, before the bridge was ever enabled.
        // A board constant out of range, found at init before the bridge
        // was ever enabled (the timer never starts): halting is the safe
        // state there.
        #[allow(clippy::panic)]
        Err(e) => panic!("PWM timing: {:?}", e),
    }
}

/// ADC1: the three shunts (U, V, W = PA0, PC1, PC0) in the injected
/// group, VBUS (PA1) and the NTC (PC2) alternating in the regular group.
fn adc1_sensing(
    adc1: &pac::ADC1,
    adc_common: &pac::ADC_COMMON,
    shunts: (gpio::PA0, gpio::PC1, gpio::PC0),
    vbus: gpio::PA1,
    ntc: gpio::PC2,
    rcc: &mut Rcc,
) -> (Currents, Bus) {
    // ADC1.
    let _ia = shunts.0.into_analog();
    let _ib = shunts.1.into_analog();
    let _ic = shunts.2.into_analog();
    let _vbus = vbus.into_analog();
    let _ntc = ntc.into_analog();
    pac::ADC1::enable(rcc);
    pac::ADC1::reset(rcc);
    setup_adc1(
        adc1,
        adc_common,
        &CURRENT_CHANNELS,
        SampleTime::Cycles15,
        BUS_CHANNEL,
        SampleTime::Cycles144,
    );
    let currents = InjectedCurrents::new(Shunts::Three(CURRENT_CHANNELS), CURRENT_SCALE);
    set_regular_sample_time(adc1, THERMISTOR_CHANNEL, SampleTime::Cycles144);
    let bus = RegularBus::new(BUS_SCALE, BUS_CHANNEL).with_thermistor(THERMISTOR);
    (currents, bus)
}

/// The angle input on PA15 / PB3 / PB10: the encoder on TIM2 (A, B;
/// Z = index) or halls H1..3, as `source` says; `sysclk_hz`, the core
/// clock, is the hall timing's tick rate.
fn encoder_or_halls(
    tim2: pac::TIM2,
    source: AngleSource,
    sysclk_hz: u32,
    ab: (gpio::PA15<gpio::Debugger>, gpio::PB3<gpio::Debugger>),
    z: gpio::PB10,
    rcc: &mut Rcc,
) -> Angle {
    // Angle input on PA15 / PB3 / PB10.
    match source {
        AngleSource::Encoder { cpr } => {
            let qei = Qei::new(
                tim2,
                (ab.0.into_alternate::<1>(), ab.1.into_alternate::<1>()),
                rcc,
            );
            let _z = z.into_alternate::<1>();
            let _ = qei.release();
            // The index is not used to re-zero the count: the electrical
            // zero is identified against the power-on count, and a later
            // index pulse would move the angle by up to half a turn.
            AngleInput::Encoder(QuadEncoder::new(cpr, false))
        }
        AngleSource::Hall(cfg) => {
            let _h1 = ab.0.into_pull_up_input();
            let _h2 = ab.1.into_pull_up_input();
            let _h3 = z.into_pull_up_input();
            AngleInput::Hall(HallSensor::new(HALL_PINS, cfg.at_tick_rate(sysclk_hz)))
        }
    }
}

/// After a panic (the firmware's handler has turned the bridge off and
/// logged): stop here with an undefined instruction (a debugger halts;
/// otherwise the HardFault handler and then the independent watchdog reset
/// the board, which boots with the bridge off).
pub fn after_panic() -> ! {
    cortex_m::asm::udf()
}

/// After a HardFault (bridge off, logged): wait for the independent
/// watchdog's reset.
pub fn after_hardfault() -> ! {
    loop {
        cortex_m::asm::nop();
    }
}

/// Safe state from any context: `MOE = 0` and EN1..3 low. (No brake
/// output to switch off on this shield.)
pub fn emergency_disable() {
    crate::hw::pwm::safe_state_hard(&ENABLE_PINS);
}

/// Clear the TIM1 break flag; the outputs stay off.
pub fn break_isr_ack() {
    crate::hw::pwm::break_flag_clear();
}

/// True while the L6230 pulls DIAG/EN low (over-current / over-temperature).
pub fn gate_driver_fault() -> bool {
    !DIAG_PIN.is_high()
}
