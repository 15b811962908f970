//! ODrive v3.x (STM32F405RG, two DRV8301), axis M0 only.
//!
//! Pin map. Sources: ODrive firmware `Board/v3/Inc/main.h` (CubeMX pin
//! defines for v3.5/v3.6) and `board_config.h`, cross-checked with the
//! Apache NuttX ODrive V3.6 board documentation:
//!
//! | signal               | pin              | function here                  |
//! |----------------------|------------------|--------------------------------|
//! | M0 AH / BH / CH      | PA8 / PA9 / PA10 | TIM1_CH1..3 (AF1)              |
//! | M0 AL / BL / CL      | PB13 / PB14 / PB15 | TIM1_CH1N..3N (AF1)          |
//! | EN_GATE (both DRVs)  | PB12             | GPIO out                       |
//! | nFAULT (both DRVs)   | PD2              | GPIO in, pull-up, low = fault  |
//! | SPI3 SCK/MISO/MOSI   | PC10 / PC11 / PC12 | AF6, DRV8301 configuration   |
//! | M0 nCS / M1 nCS      | PC13 / PC14      | GPIO out, idle high            |
//! | M0 SO1 (phase B)     | PC0              | ADC1_IN10                      |
//! | M0 SO2 (phase C)     | PC1              | ADC1_IN11                      |
//! | VBUS_S               | PA6              | ADC1_IN6                       |
//! | M0_TEMP (FET NTC)    | PC5              | ADC1_IN15, regular, alternating with VBUS |
//! | AUX_L (low side)     | PB10             | GPIO out, held low (never on)  |
//! | AUX_H (high side)    | PB11             | TIM2_CH4 (AF1): brake chopper  |
//! | M0 ENC A / B         | PB4 / PB5        | TIM3_CH1 / CH2 (AF2)           |
//! | M0 ENC Z             | PC9              | TIM3_CH4 (AF2, index capture)  |
//! | M1 AH/BH/CH, AL/BL/CL| PC6-8, PA7/PB0/PB1 | GPIO out low (M1 unused)     |
//! | GPIO3 / GPIO4        | PA2 / PA3        | USART2 TX / RX (AF7), command UART, 115200 8N1 |
//! | GPIO1 (feature `as5047p`) | PA0         | GPIO out, idle high: AS5047P CSn |
//! | CAN_R / CAN_D (J2)   | PB8 / PB9        | CAN1_RX / CAN1_TX (AF9), on-board transceiver |
//!
//! Command UART: USART2 on the J3 header pins GPIO3 (PA2, TX) and GPIO4
//! (PA3, RX). The ODrive firmware calls this port UART_B; its default
//! UART_A is UART4 on GPIO1/GPIO2 = PA0/PA1 (ODrive firmware
//! `Board/v3/Inc/main.h`: `GPIO_1` = PA0 ... `GPIO_4` = PA3, and
//! `board.h`: GPIO1/2 `GPIO_AF8_UART4`, GPIO3/4 `GPIO_AF7_USART2`; ODrive
//! docs `uart.md`, "How to use UART on GPIO3/4"). USART2 is used so that
//! every board has the same `SERIAL_IRQ` vector (`USART2`), which the RTIC
//! app binds by name.
//!
//! CAN ([`Can`], [`HAS_CAN`] = true): CAN1 on PB8 (RX) / PB9 (TX), AF9,
//! to the board's CAN transceiver (J2 CANH / CANL; the termination
//! resistor is a DIP switch on the board). Source: ODrive firmware
//! `Firmware/Board/v3/Src/can.c` (`HAL_CAN_MspInit`: "PB8 ------>
//! CAN1_RX, PB9 ------> CAN1_TX", `GPIO_AF9_CAN1`, `AutoBusOff = ENABLE`),
//! cross-checked with stm32f4xx-hal 0.23's alternate-function table for
//! the F405 (`gpio/alt/f4.rs`: CAN1 RX PB8<9>, TX PB9<9>). `init` leaves
//! the controller asleep (off the bus): start it with the stored node
//! settings' rate, `board.can.start(bitrate)`; then frames through
//! [`foc_core::hal::CanPort`], received in the task bound to
//! [`CAN_RX_IRQ`] (`CAN1_RX0`). Bit timing from APB1 = 42 MHz: 14 tq
//! (1 + 11 + 2, SJW 1, sample point 85.7 %), prescaler 3 / 6 / 12 / 24
//! for 1000 / 500 / 250 / 125 kbit/s, `CAN_BTR` `0x001A_0002` at
//! 1 Mbit/s (`logic::can`; RM0090 §32.7.7). Automatic bus-off recovery
//! (ABOM). Details: [`crate::hw::can`]. **Unverified on hardware.**
//!
//! Power stage: shunts 0.5 mOhm (v3.4 and later; 0.675 mOhm on v3.1-3.3),
//! DRV8301 amplifier gain 10/20/40/80 (40 used: +-82 A range), VBUS divider
//! ratio 19 (v3.5+ 56 V variant; 11 on older boards), 8 MHz HSE crystal,
//! 168 MHz. NuttX lists 40 A output without MOSFET cooling.
//!
//! No TIM1 break input is wired (PB12, the F405's TIM1_BKIN pin, is
//! EN_GATE). The DRV8301 latches its own over-current shut-down (OCP
//! latch mode, V_DS threshold 0.730 V as the ODrive firmware sets) and
//! reports on nFAULT: [`gate_driver_fault`].
//!
//! Brake resistor ([`BRAKE_OUTPUT`] = true): on the AUX half-bridge, the
//! resistor from the AUX switch node to ground, switched by the high-side
//! FET (AUX_H, PB11, active high) as TIM2_CH4 PWM at 10 kHz / 95 % while on
//! (the high-side gate supply is a bootstrap that must recharge every
//! period); the low side (AUX_L, PB10) is held off for good, so the two
//! never conduct together. Off at `init` and in [`emergency_disable`].
//! Sources and register details: [`crate::hw::brake`]. **Unverified on
//! hardware.**
//!
//! Power-stage temperature ([`STAGE_TEMPERATURE_SENSOR`] = true): the M0
//! FET thermistor on PC5 = ADC12_IN15 (ODrive firmware `Board/v3/board.cpp`,
//! `fet_thermistors[0]`: ADC channel 15 on every v3.x; `main.h`:
//! `M0_TEMP_Pin` = PC5), converted with the ODrive firmware's cubic fit
//! ([`crate::logic::thermistor::ODRIVE_V3_FET`]; open or shorted NTC is an
//! error, not a temperature). ADC1's regular group converts it and VBUS in
//! turn (`hw::adc`, [`RegularBus::with_thermistor`]): each is refreshed
//! every other read, i.e. every other PWM period. M1's thermistor (ADC
//! channel 4, PA4) and the AUX thermistor (PA5) are not read. Unverified on
//! hardware.
//!
//! `Pwm::disable` clears MOE only (all gate inputs low = every FET off) and
//! keeps EN_GATE high, because EN_GATE low resets the DRV8301's SPI
//! configuration; [`emergency_disable`] also pulls EN_GATE low (gate
//! drivers shut down), after which `Pwm::enable` refuses until `init` runs
//! again.
//!
//! # Option `as5047p`: an AS5047P on SPI3
//!
//! With the board-support feature `as5047p` (firmware feature
//! `odrive-v3-as5047p`) the rotor angle comes from an AS5047P magnetic
//! sensor (14 bits, absolute: [`ANGLE_SOURCE`] is
//! `AngleSource::Absolute { counts_per_rev: 16384 }`, so a stored
//! calibration applies at boot) instead of the M0 encoder input, which is
//! left unconfigured. Wiring: sensor CLK, MISO (its `MISO`/`DO`) and MOSI
//! (`MOSI`/`DI`) to the ODrive's SPI3 SCK / MISO / MOSI (PC10 / PC11 /
//! PC12, shared with both DRV8301s), CSn to J3 GPIO1 (PA0), 3.3 V and GND.
//!
//! Chip select on GPIO1 (PA0): the ODrive firmware's own default SPI
//! encoder chip select (`abs_spi_cs_gpio_pin = 1` in
//! `MotorControl/encoder.hpp`; GPIO1 = PA0 on v3.3-v3.6 in
//! `Board/v3/board.cpp`). Its docs (`encoders.md`, "Using SPI") let the
//! user pick any GPIO, show GPIO4 as the example and warn that GPIO1/2
//! usually carry UART_A: here GPIO4 (PA3) is the command UART's RX, while
//! GPIO1/2 are free because the command UART is on GPIO3/4.
//!
//! MOSI: the ODrive docs (`encoders.md`, "Using SPI") tie the sensor's
//! MOSI to 3.3 V: the ODrive firmware only ever sends `READ ANGLECOM`
//! (0xFFFF). This driver also reads `ERRFL` after an error flag (to clear
//! it), which needs MOSI wired; with MOSI tied high that read is an angle
//! read the driver discards (`As5047pError::NotAnAngle`), one sample per
//! error.
//!
//! Bus hand-over: `init` configures the DRV8301 over SPI3 exactly as the
//! encoder build does (mode 1, 1 MHz requested), then takes the bus back
//! (`Drv8301::release`, `Spi::release`) and sets SPI3 up again for the
//! sensor (mode 1, `AS5047P_SPI_HZ` = APB1 42 MHz / 8 = 5.25 MHz, the
//! fastest divider within the AS5047P's 10 MHz: /4 would be 10.5 MHz;
//! `SPI_CR1.BR`, RM0090 28.5.1). From then on the bus belongs to the
//! sensor (an `embedded-hal-bus` `ExclusiveDevice` with CSn on PA0 and the
//! HAL's DWT delay for the sensor's CSn-to-clock time; SCK and MOSI at
//! medium output speed for the faster clock); the DRV8301 chip
//! selects (PC13, PC14) are held high in `Board::gate_driver_ncs`, so
//! the DRV8301 status registers are not read after `init` (nFAULT still
//! is: [`gate_driver_fault`]). The DRV8301 keeps its configuration while
//! EN_GATE stays high.
//!
//! Timing: one 16-bit frame per PWM period, read in the current-loop
//! interrupt: 16 clocks at 5.25 MHz = 3.05 us plus the 0.4 us CSn set-up,
//! about 3.5 us of the 50 us period at 20 kHz (at the DRV8301's 1 MHz
//! request, which the HAL rounds to 42 MHz / 32 = 1.3125 MHz, the frame
//! would take 12.2 us, and two frames for an angle of the same period
//! 24.4 us; at 5.25 MHz two frames would take about 7 us). The angle is
//! one frame (one period) old (see `hw::as5047p`); `init` sends the first
//! frame so the first read in the current loop already returns an angle.

pub use super::Led;
use crate::hw::adc::{
    set_regular_sample_time, setup_adc1, InjectedCurrents, RegularBus, SampleTime, Shunts,
    Thermistor,
};
pub use crate::hw::angle::AngleSource;
#[cfg(not(feature = "as5047p"))]
use crate::hw::angle::{AngleInput, HallSensor, QuadEncoder};
use crate::hw::brake::{aux_off_hard, AuxBrake};
pub use crate::hw::can::{CanBus, CanError};
use crate::hw::drv8301::{Drv8301, Drv8301Error};
pub use crate::hw::flash::StoreFlash;
use crate::hw::pwm::{PwmConfig, Tim1Pwm, Topology};
pub use crate::hw::serial::CommandSerial;
use crate::hw::{delay_us, enable_cycle_counter, PinId, Port};
use crate::logic::can::BitTiming;
pub use crate::logic::can::Bitrate;
use crate::logic::drv8301::{Control1, Control2, Gain, GateCurrent, OcpMode, OctwMode, PwmMode};
use crate::logic::scaling::{CurrentScale, VoltageScale};
use crate::pac;
use fugit::RateExtU32;
use stm32f4xx_hal::gpio::{self, GpioExt, Output, PinState, PC13};
#[cfg(not(feature = "as5047p"))]
use stm32f4xx_hal::qei::Qei;
use stm32f4xx_hal::rcc::{Config, Enable, Rcc, RccExt, Reset};
use stm32f4xx_hal::spi::{Spi, SpiExt};
#[cfg(feature = "as5047p")]
use {
    crate::hw::as5047p::As5047p,
    embedded_hal_bus::spi::ExclusiveDevice,
    foc_core::hal::AngleSensor,
    stm32f4xx_hal::dwt::{self, DwtExt},
    stm32f4xx_hal::gpio::{PinSpeed, Speed, PA0, PC14},
};

/// Board name.
#[cfg(not(feature = "as5047p"))]
pub const NAME: &str = "ODrive v3.x (M0)";
/// Board name.
#[cfg(feature = "as5047p")]
pub const NAME: &str = "ODrive v3.x (M0) + AS5047P";
/// Core clock [Hz].
pub const SYSCLK_HZ: u32 = 168_000_000;
/// APB1 clock [Hz] (SPI3, USART2).
pub const PCLK1_HZ: u32 = 42_000_000;
/// The source's alternative PWM frequency [Hz].
pub const PWM_FREQUENCY_15K_HZ: u32 = 15_000;
/// PWM frequency [Hz] (set to [`PWM_FREQUENCY_15K_HZ`] for 15 kHz).
pub const PWM_FREQUENCY_HZ: u32 = 20_000;
/// TIM1 dead time [ns] (ODrive: 20 clocks at 168 MHz = 119 ns; rounded up
/// by the DTG encoding to 21 clocks = 125 ns).
pub const DEAD_TIME_NS: u32 = 120;
/// ADC interrupt (injected end of conversion of the phase currents).
pub const CURRENT_IRQ: pac::Interrupt = pac::Interrupt::ADC;
/// TIM1 break interrupt (never fires here: no BKIN on this board).
pub const BREAK_IRQ: pac::Interrupt = pac::Interrupt::TIM1_BRK_TIM9;
/// Command UART interrupt (USART2: GPIO3 = PA2 TX, GPIO4 = PA3 RX).
pub const SERIAL_IRQ: pac::Interrupt = pac::Interrupt::USART2;
/// Baud rate of the command UART [bit/s] (8N1).
pub const SERIAL_BAUD: u32 = 115_200;
/// The board has a CAN port ([`Can`]: CAN1 on PB8 / PB9 and the on-board
/// transceiver).
pub const HAS_CAN: bool = true;
/// CAN receive interrupt: FIFO 0 holds a frame (`CAN1_RX0`; every
/// accepted frame goes to FIFO 0).
pub const CAN_RX_IRQ: pac::Interrupt = pac::Interrupt::CAN1_RX0;
// Every CAN bit rate is exact from this APB1 clock (`logic::can`).
// (Evaluated at compile time: an index out of range fails the build.)
#[allow(clippy::indexing_slicing)]
const _: () = {
    let mut i = 0;
    while i < Bitrate::ALL.len() {
        assert!(BitTiming::for_bitrate(PCLK1_HZ, Bitrate::ALL[i]).is_some());
        i += 1;
    }
};
/// TIM1 BKIN wired to a hardware fault signal.
pub const HAS_BREAK_INPUT: bool = false;
/// Largest phase current of the power stage [A] (without MOSFET cooling).
pub const MAX_PHASE_CURRENT_A: f32 = 40.0;
/// Largest current the sensing can measure [A] (1.65 V / (40 * 0.5 mOhm)).
pub const MAX_MEASURABLE_CURRENT_A: f32 = 82.0;
/// Lowest bus voltage [V].
pub const BUS_VOLTAGE_MIN_V: f32 = 12.0;
/// Highest bus voltage [V] (56 V variant; 24 V on the 24 V variant).
pub const BUS_VOLTAGE_MAX_V: f32 = 56.0;
/// The board switches a brake resistor: the AUX output ([`Brake`], module
/// docs). Connect the resistor to the AUX terminals before enabling it.
pub const BRAKE_OUTPUT: bool = true;
/// The board measures its power-stage temperature: the M0 FET thermistor
/// ([`Bus`]'s `read_temperature_c`, module docs).
pub const STAGE_TEMPERATURE_SENSOR: bool = true;
/// Rotor angle input chosen at `init`: the M0 encoder (CUI AMT102 at 2048
/// lines = 8192 counts, the usual ODrive encoder; change to suit).
#[cfg(not(feature = "as5047p"))]
pub const ANGLE_SOURCE: AngleSource = AngleSource::Encoder { cpr: 8192 };
/// Rotor angle input: the AS5047P on SPI3, 14 bits, absolute.
#[cfg(feature = "as5047p")]
pub const ANGLE_SOURCE: AngleSource = AngleSource::Absolute {
    counts_per_rev: crate::logic::as5047p::COUNTS_PER_TURN,
};

/// AS5047P chip select: J3 GPIO1 (see the module docs).
#[cfg(feature = "as5047p")]
pub const AS5047P_NCS_PIN: PinId = PinId::new(Port::A, 0);
/// SPI3 clock for the AS5047P [Hz]: the fastest APB1 divider within the
/// sensor's limit (42 MHz / 8 = 5.25 MHz).
#[cfg(feature = "as5047p")]
pub const AS5047P_SPI_HZ: u32 = match crate::logic::spi_clock::fastest_spi_clock_hz(
    PCLK1_HZ,
    crate::logic::as5047p::MAX_SPI_HZ,
) {
    Some(hz) => hz,
    None => panic!("no SPI3 divider within the AS5047P's clock limit"),
};

/// The configuration store: flash sectors 10-11 (0x080C_0000..0x0810_0000)
/// of the 1 MiB STM32F405RG, as offsets from the flash base (RM0090 §3.3
/// table 5). The linker script keeps the program out of it (`STORE` region
/// of `memory/odrive-v3.x`).
pub const STORE_RANGE: core::ops::Range<u32> = 0xC_0000..0x10_0000;
const _: () = assert!(crate::hw::flash::is_store_region(&STORE_RANGE, 1024 * 1024));

/// What the angle input tells at reset (from [`ANGLE_SOURCE`]).
pub const fn angle_kind() -> foc_core::drive::AngleKind {
    ANGLE_SOURCE.kind()
}

/// Shunt resistance [ohm] (v3.4+).
pub const SHUNT_OHM: f32 = 0.0005;
/// DRV8301 amplifier gain.
pub const CURRENT_GAIN: Gain = Gain::G40;
/// VBUS divider ratio (v3.5+).
pub const BUS_DIVIDER_RATIO: f32 = 19.0;
/// Current conversion (DRV8301 output `Vref/2 - G (SN - SP)`, ODrive's
/// sign convention: positive).
pub const CURRENT_SCALE: CurrentScale =
    CurrentScale::new(SHUNT_OHM, CURRENT_GAIN.value(), 3.3, 12, 2048.0, 1.0);
/// Bus-voltage conversion.
pub const BUS_SCALE: VoltageScale = VoltageScale::ratio(BUS_DIVIDER_RATIO, 3.3, 12);

/// DRV8301 control register 1 as the ODrive firmware sets it.
pub const DRV_CONTROL1: Control1 = Control1 {
    gate_current: GateCurrent::A1_7,
    gate_reset: false,
    pwm_mode: PwmMode::SixInputs,
    ocp_mode: OcpMode::LatchShutdown,
    oc_adj_set: 21, // 0.730 V
};
/// DRV8301 control register 2.
pub const DRV_CONTROL2: Control2 = Control2 {
    octw_mode: OctwMode::OtAndOc,
    gain: CURRENT_GAIN,
    dc_cal_ch1: false,
    dc_cal_ch2: false,
    oc_toff: false,
};

/// EN_GATE (both DRV8301).
pub const EN_GATE: PinId = PinId::new(Port::B, 12);
/// nFAULT (both DRV8301, open drain).
pub const NFAULT_PIN: PinId = PinId::new(Port::D, 2);
/// Hall inputs when `ANGLE_SOURCE` is halls (encoder A, B, Z pins).
pub const HALL_PINS: [PinId; 3] = [
    PinId::new(Port::B, 4),
    PinId::new(Port::B, 5),
    PinId::new(Port::C, 9),
];
const ENABLE_PINS: [PinId; 1] = [EN_GATE];
/// ADC channels of the shunts (phase B, phase C).
pub const CURRENT_CHANNELS: [u8; 2] = [10, 11];
/// ADC channel of VBUS.
pub const BUS_CHANNEL: u8 = 6;
/// ADC channel of the M0 FET thermistor (PC5).
pub const THERMISTOR_CHANNEL: u8 = 15;
/// The M0 FET thermistor as the bus reader converts it.
pub const THERMISTOR: Thermistor = Thermistor {
    channel: THERMISTOR_CHANNEL,
    divider: crate::logic::thermistor::ODRIVE_V3_FET,
};

/// The PWM stage.
pub type Pwm = Tim1Pwm;
/// Phase currents (shunts on B and C, A derived).
pub type Currents = InjectedCurrents;
/// Rotor angle: encoder on TIM3 or halls.
#[cfg(not(feature = "as5047p"))]
pub type Angle = AngleInput<pac::TIM3>;
/// Rotor angle: the AS5047P on SPI3, CSn on PA0.
#[cfg(feature = "as5047p")]
pub type Angle = As5047p<ExclusiveDevice<Spi<pac::SPI3>, PA0<Output>, dwt::Delay>>;
/// Bus voltage and the M0 FET temperature.
pub type Bus = RegularBus;
/// The brake chopper on the AUX output (TIM2_CH4 on AUX_H).
pub type Brake = AuxBrake;
/// The CAN port: CAN1 (bxCAN) on PB8 / PB9.
pub type Can = CanBus;
/// The M0 DRV8301 on SPI3.
pub type GateDriver = Drv8301<Spi<pac::SPI3>, PC13<Output>>;

/// Everything `init` sets up.
pub struct Board {
    /// TIM1 6-PWM with dead time, disabled.
    pub pwm: Pwm,
    /// Phase currents (ADC1 injected, TIM1-triggered).
    pub currents: Currents,
    /// Rotor angle.
    pub angle: Angle,
    /// Bus voltage and M0 FET temperature (ADC1 regular, alternating).
    pub bus: Bus,
    /// Brake chopper on the AUX output, off.
    pub brake: Brake,
    /// No user LED on the ODrive: a no-op.
    pub led: Led,
    /// The M0 gate driver (status reads).
    #[cfg(not(feature = "as5047p"))]
    pub gate_driver: GateDriver,
    /// The chip selects of both DRV8301 (M0 PC13, M1 PC14), held high:
    /// after `init` SPI3 belongs to the angle sensor.
    #[cfg(feature = "as5047p")]
    pub gate_driver_ncs: (PC13<Output>, PC14<Output>),
    /// Result of the DRV8301 configuration at init. On error EN_GATE is
    /// left low and `pwm.enable()` fails.
    pub gate_driver_config: Result<(), Drv8301Error>,
    /// Command UART: USART2 on GPIO3 (PA2, TX) / GPIO4 (PA3, RX).
    pub serial: CommandSerial,
    /// The configuration store's flash region ([`STORE_RANGE`]). Erasing a
    /// sector stalls the CPU for 1-2 s: bridge off first (`hw::flash`).
    pub store: StoreFlash,
    /// CAN1 on PB8 / PB9, asleep (off the bus) until `can.start(..)`.
    pub can: Can,
}

/// Set up clocks, pins, TIM1, ADC1, the DRV8301 and the angle input.
/// Bridge disabled (MOE = 0; EN_GATE high if the DRV8301 was configured),
/// PWM counter running, NVIC untouched.
pub fn init(dp: pac::Peripherals) -> Board {
    let mut rcc = freeze_clocks(dp.RCC);
    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);
    let gpioc = dp.GPIOC.split(&mut rcc);
    let gpiod = dp.GPIOD.split(&mut rcc);
    let (aux_h, m0_ncs, _m1_ncs) = outputs_safe(
        (gpiob.pb10, gpiob.pb11),
        gpiob.pb12,
        (gpioc.pc6, gpioc.pc7, gpioc.pc8),
        (gpioa.pa7, gpiob.pb0, gpiob.pb1),
        gpiod.pd2,
        (gpioc.pc13, gpioc.pc14),
    );
    enable_cycle_counter();

    let pwm = tim1_six_pwm(
        dp.TIM1,
        (gpioa.pa8, gpioa.pa9, gpioa.pa10),
        (gpiob.pb13, gpiob.pb14, gpiob.pb15),
        &mut rcc,
    );
    let (gate_driver, gate_driver_config) = drv8301_on_spi3(
        dp.SPI3,
        (gpioc.pc10, gpioc.pc11, gpioc.pc12),
        m0_ncs,
        &mut rcc,
    );
    let (currents, bus) = adc1_sensing(
        &dp.ADC1,
        &dp.ADC_COMMON,
        (gpioc.pc0, gpioc.pc1),
        gpioa.pa6,
        gpioc.pc5,
        &mut rcc,
    );
    let brake = aux_brake(dp.TIM2, aux_h, &mut rcc);

    #[cfg(not(feature = "as5047p"))]
    let angle = encoder_or_halls(dp.TIM3, (gpiob.pb4, gpiob.pb5), gpioc.pc9, &mut rcc);
    #[cfg(feature = "as5047p")]
    let (angle, gate_driver_ncs) = spi3_to_as5047p(gate_driver, gpioa.pa0, _m1_ncs, &mut rcc);

    // Command UART: USART2 on PA2/PA3 (AF7). Clock enable and reset
    // through the HAL (RCC_APB1ENR.USART2EN, RM0090 7.3.13).
    let serial =
        CommandSerial::usart2_on_pa2_pa3(dp.USART2, gpioa.pa2, gpioa.pa3, &mut rcc, SERIAL_BAUD);

    // CAN1 on PB8/PB9 (AF9), asleep until started with the stored rate.
    let can = CanBus::can1_on_pb8_pb9(dp.CAN1, gpiob.pb8, gpiob.pb9, &mut rcc);

    Board {
        pwm,
        currents,
        angle,
        bus,
        brake,
        led: Led::new(None),
        #[cfg(not(feature = "as5047p"))]
        gate_driver,
        #[cfg(feature = "as5047p")]
        gate_driver_ncs,
        gate_driver_config,
        serial,
        // After `rcc.freeze`, which sets the wait states through its own
        // FLASH_ACR pointer and does not need the peripheral.
        store: StoreFlash::new(dp.FLASH, STORE_RANGE),
        can,
    }
}

/// Clocks: 8 MHz HSE to [`SYSCLK_HZ`] (HCLK the same), APB1 at
/// [`PCLK1_HZ`], APB2 at 84 MHz.
fn freeze_clocks(rcc: pac::RCC) -> Rcc {
    rcc.freeze(
        Config::hse(8.MHz())
            .sysclk(SYSCLK_HZ.Hz())
            .hclk(SYSCLK_HZ.Hz())
            .pclk1(PCLK1_HZ.Hz())
            .pclk2(84.MHz()),
    )
}

/// Every output that can turn a FET on, driven off before anything else:
/// the AUX half-bridge (AUX_L PB10, AUX_H PB11), EN_GATE (PB12) and the
/// unused M1 gate inputs (PC6-8, PA7/PB0/PB1) low; then nFAULT (PD2) as
/// an input with pull-up and both DRV8301 chip selects (PC13, PC14) idle
/// high. Returns AUX_H (it goes to TIM2_CH4 later) and the chip selects
/// (M0, M1).
fn outputs_safe(
    aux: (gpio::PB10, gpio::PB11),
    en_gate: gpio::PB12,
    m1_high: (gpio::PC6, gpio::PC7, gpio::PC8),
    m1_low: (gpio::PA7, gpio::PB0, gpio::PB1),
    nfault: gpio::PD2,
    ncs: (gpio::PC13, gpio::PC14),
) -> (gpio::PB11<Output>, PC13<Output>, gpio::PC14<Output>) {
    // AUX half-bridge off first: both gate inputs low (AUX_H goes to
    // TIM2_CH4 once the timer holds it off, below).
    let _aux_l = aux.0.into_push_pull_output_in_state(PinState::Low);
    let aux_h = aux.1.into_push_pull_output_in_state(PinState::Low);
    // Gate drivers off, M1 inputs low.
    let _en_gate = en_gate.into_push_pull_output_in_state(PinState::Low);
    let _m1 = (
        m1_high.0.into_push_pull_output_in_state(PinState::Low),
        m1_high.1.into_push_pull_output_in_state(PinState::Low),
        m1_high.2.into_push_pull_output_in_state(PinState::Low),
        m1_low.0.into_push_pull_output_in_state(PinState::Low),
        m1_low.1.into_push_pull_output_in_state(PinState::Low),
        m1_low.2.into_push_pull_output_in_state(PinState::Low),
    );
    let _nfault = nfault.into_pull_up_input();
    let m0_ncs = ncs.0.into_push_pull_output_in_state(PinState::High);
    let m1_ncs = ncs.1.into_push_pull_output_in_state(PinState::High);
    (aux_h, m0_ncs, m1_ncs)
}

/// TIM1 6-PWM: the high sides (PA8-10) and low sides (PB13-15) to their
/// TIM1 channels (AF1), TIM1's clock enabled and the timer reset, then
/// [`Tim1Pwm`] at [`PWM_FREQUENCY_HZ`] with [`DEAD_TIME_NS`].
fn tim1_six_pwm(
    tim1: pac::TIM1,
    high: (gpio::PA8, gpio::PA9, gpio::PA10),
    low: (gpio::PB13, gpio::PB14, gpio::PB15),
    rcc: &mut Rcc,
) -> Pwm {
    // TIM1 6-PWM.
    let _h = (
        high.0.into_alternate::<1>(),
        high.1.into_alternate::<1>(),
        high.2.into_alternate::<1>(),
    );
    let _l = (
        low.0.into_alternate::<1>(),
        low.1.into_alternate::<1>(),
        low.2.into_alternate::<1>(),
    );
    pac::TIM1::enable(rcc);
    pac::TIM1::reset(rcc);
    let tim_clk = rcc.clocks.timclk2().raw();
    match Tim1Pwm::new(
        tim1,
        tim_clk,
        PwmConfig {
            frequency_hz: PWM_FREQUENCY_HZ,
            topology: Topology::SixPwm {
                dead_time_ns: DEAD_TIME_NS,
            },
            break_input: None,
            enable_pins: &ENABLE_PINS,
            enable_pins_in_disable: false,
        },
    ) {
        Ok(pwm) => pwm,
        // Only a PWM_FREQUENCY_HZ const out of range gets here.
        // A board constant out of range, found at init before the bridge
        // was ever enabled (the timer never starts): halting is the safe
        // state there.
        #[allow(clippy::panic)]
        Err(e) => panic!("PWM timing: {:?}", e),
    }
}

/// The M0 DRV8301 on SPI3 (SCK/MISO/MOSI = PC10/PC11/PC12, AF6; CS
/// `m0_ncs`), and the result of its configuration. EN_GATE is left low
/// when the configuration failed.
fn drv8301_on_spi3(
    spi3: pac::SPI3,
    pins: (gpio::PC10, gpio::PC11, gpio::PC12),
    m0_ncs: PC13<Output>,
    rcc: &mut Rcc,
) -> (GateDriver, Result<(), Drv8301Error>) {
    // DRV8301: EN_GATE high (MOE = 0 keeps every gate input low), let it
    // start, configure over SPI3 (mode 1, 1 MHz) and read back.
    let spi = spi3.spi(
        (
            Some(pins.0.into_alternate::<6>()),
            Some(pins.1.into_alternate::<6>()),
            Some(pins.2.into_alternate::<6>()),
        ),
        embedded_hal::spi::MODE_1,
        1.MHz(),
        rcc,
    );
    EN_GATE.set(true);
    delay_us(SYSCLK_HZ, 20_000);
    let mut gate_driver = Drv8301::new(spi, m0_ncs, SYSCLK_HZ / 1_000_000);
    let gate_driver_config = gate_driver.configure(DRV_CONTROL1, DRV_CONTROL2);
    if gate_driver_config.is_err() {
        EN_GATE.set(false);
    }
    (gate_driver, gate_driver_config)
}

/// ADC1: the B and C shunts (PC0, PC1) in the injected group, VBUS (PA6)
/// and the M0 FET thermistor (PC5) alternating in the regular group.
fn adc1_sensing(
    adc1: &pac::ADC1,
    adc_common: &pac::ADC_COMMON,
    shunts: (gpio::PC0, gpio::PC1),
    vbus: gpio::PA6,
    m0_temp: gpio::PC5,
    rcc: &mut Rcc,
) -> (Currents, Bus) {
    // ADC1: B and C shunts, VBUS, M0 FET thermistor.
    let _ib = shunts.0.into_analog();
    let _ic = shunts.1.into_analog();
    let _vbus = vbus.into_analog();
    let _m0_temp = m0_temp.into_analog();
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
    let currents = InjectedCurrents::new(Shunts::BC(CURRENT_CHANNELS), CURRENT_SCALE);
    set_regular_sample_time(adc1, THERMISTOR_CHANNEL, SampleTime::Cycles144);
    let bus = RegularBus::new(BUS_SCALE, BUS_CHANNEL).with_thermistor(THERMISTOR);
    (currents, bus)
}

/// The brake chopper on TIM2_CH4, off, with AUX_H (held low until now)
/// handed to the timer.
fn aux_brake(tim2: pac::TIM2, aux_h: gpio::PB11<Output>, rcc: &mut Rcc) -> Brake {
    // Brake chopper: TIM2 (clock and reset through the HAL: RCC_APB1ENR /
    // RCC_APB1RSTR, RM0090 7.3.13 / 7.3.8) with CCR4 = 0, then AUX_H to
    // TIM2_CH4 (AF1): the pin goes from driven low to the timer's low.
    pac::TIM2::enable(rcc);
    pac::TIM2::reset(rcc);
    let brake = AuxBrake::new(tim2, rcc.clocks.timclk1().raw());
    let _aux_h = aux_h.into_alternate::<1>();
    brake
}

/// The M0 encoder input (A/B = PB4/PB5 on TIM3, Z = PC9) or halls on the
/// same pins, as [`ANGLE_SOURCE`] says.
#[cfg(not(feature = "as5047p"))]
fn encoder_or_halls(
    tim3: pac::TIM3,
    ab: (gpio::PB4<gpio::Debugger>, gpio::PB5),
    z: gpio::PC9,
    rcc: &mut Rcc,
) -> Angle {
    match ANGLE_SOURCE {
        AngleSource::Encoder { cpr } => {
            let qei = Qei::new(
                tim3,
                (ab.0.into_alternate::<2>(), ab.1.into_alternate::<2>()),
                rcc,
            );
            let _z = z.into_alternate::<2>();
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
            AngleInput::Hall(HallSensor::new(HALL_PINS, cfg.at_tick_rate(SYSCLK_HZ)))
        }
    }
}

/// SPI3 handed from the DRV8301 (`gate_driver`) to the AS5047P, CSn on
/// `pa0` (idle high); returns the sensor and both DRV8301 chip selects
/// (M0, `m1_ncs`), which stay high.
#[cfg(feature = "as5047p")]
fn spi3_to_as5047p(
    gate_driver: GateDriver,
    pa0: gpio::PA0,
    m1_ncs: PC14<Output>,
    rcc: &mut Rcc,
) -> (Angle, (PC13<Output>, PC14<Output>)) {
    // SPI3 from the DRV8301 to the AS5047P (module docs, "Bus hand-over").
    let (spi, m0_ncs) = gate_driver.release();
    let ncs = pa0.into_push_pull_output_in_state(PinState::High);
    (as5047p_on_spi3(spi, ncs, rcc), (m0_ncs, m1_ncs))
}

/// SPI3 set up again for the AS5047P (mode 1, [`AS5047P_SPI_HZ`]; the
/// HAL enables and resets SPI3 through RCC_APB1ENR / RCC_APB1RSTR,
/// RM0090 7.3.13 / 7.3.8) as an `ExclusiveDevice` with CSn `ncs` (high),
/// and the sensor's first frame sent (its answer comes with the next).
#[cfg(feature = "as5047p")]
fn as5047p_on_spi3(spi: Spi<pac::SPI3>, ncs: PA0<Output>, rcc: &mut Rcc) -> Angle {
    let (spi3, (mut sck, miso, mut mosi)) = spi.release();
    // The outputs at medium speed (GPIOx_OSPEEDR = 01, RM0090 8.4.3): the
    // reset value (low) is meant for a few MHz, the clock here is 5.25 MHz.
    if let Some(p) = sck.as_mut() {
        p.set_speed(Speed::Medium);
    }
    if let Some(p) = mosi.as_mut() {
        p.set_speed(Speed::Medium);
    }
    let spi = spi3.spi(
        (sck, miso, mosi),
        embedded_hal::spi::MODE_1,
        AS5047P_SPI_HZ.Hz(),
        rcc,
    );
    // The HAL's DWT delay reads the cycle counter `init` enabled; DWT and
    // DCB are taken only to build it (`enable_cycle_counter` steals them
    // the same way, the RTIC app enables the same bits again).
    // SAFETY: only DCB_DEMCR.TRCENA and DWT_CTRL.CYCCNTENA are set
    // (ARMv7-M ARM C1.6.5, C1.8.7), idempotently; nothing else is touched.
    let cp = unsafe { cortex_m::Peripherals::steal() };
    let delay = cp.DWT.constrain(cp.DCB, &rcc.clocks).delay();
    let device = match ExclusiveDevice::new(spi, ncs, delay) {
        Ok(d) => d,
        Err(never) => match never {},
    };
    let mut sensor = As5047p::new(device);
    // Nothing to answer yet: the first frame only primes the pipeline.
    let _ = sensor.read_angle();
    sensor
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

/// Safe state from any context: `MOE = 0` and EN_GATE low (both DRV8301
/// shut down; `init` must run again before the bridge can be enabled), and
/// the brake chopper off (AUX_H low, taken from the timer; it stays off
/// until `init`): a brake left on by dead software would hold a resistor
/// sized for braking pulses across the full bus until it burns.
pub fn emergency_disable() {
    crate::hw::pwm::safe_state_hard(&ENABLE_PINS);
    aux_off_hard();
}

/// Clear the TIM1 break flag; the outputs stay off.
pub fn break_isr_ack() {
    crate::hw::pwm::break_flag_clear();
}

/// True while a DRV8301 pulls nFAULT low.
pub fn gate_driver_fault() -> bool {
    !NFAULT_PIN.is_high()
}
