//! STM32F4 board support for `foc-core`: one module per board, selected by
//! cargo feature, all with the same API.
//!
//! # Layout
//!
//! - [`logic`]: pure logic (register encodings, unit conversions, sensor
//!   decoding). Always compiled, tested on the host with
//!   `cargo test -p board-support` (no feature).
//! - `hw` (feature `_hal`, set by every board feature): drivers implementing
//!   `foc_core::hal::{PwmDriver, CurrentSense, AngleSensor, BusVoltage}` on
//!   the STM32F4 (stm32f4xx-hal 0.23 where it has the API, PAC for the rest;
//!   every `unsafe` names its reference-manual section).
//! - `boards::*`: one module per board; the selected one is re-exported as
//!   `board`.
//!
//! # Boards (exactly one feature per build)
//!
//! | feature                  | board                                      |
//! |--------------------------|--------------------------------------------|
//! | `nucleo-f446re-ihm07m1`  | NUCLEO-F446RE + X-NUCLEO-IHM07M1 (default) |
//! | `nucleo-f401re-ihm07m1`  | NUCLEO-F401RE + X-NUCLEO-IHM07M1           |
//! | `odrive-v3`              | ODrive v3.x (STM32F405RG), axis M0         |
//!
//! Option: `as5047p` (with `odrive-v3` only) reads the rotor angle from an
//! AS5047P on the ODrive's SPI3 bus instead of the M0 encoder input
//! (firmware feature `odrive-v3-as5047p`; see `boards::odrive_v3`).
//!
//! Never build two boards in one cargo invocation: the HAL chip features
//! clash. The linker memory layout of each board is in
//! `board-support/memory/<feature>.x`.
//!
//! # The uniform API (identical names on every board)
//!
//! `board_support::pac` is `stm32f4xx_hal::pac`. `board_support::board` is
//! the selected board module and provides:
//!
//! - constants: `NAME: &str`, `SYSCLK_HZ: u32`, `PWM_FREQUENCY_HZ: u32`
//!   (20 kHz; `PWM_FREQUENCY_15K_HZ` is the source's 15 kHz alternative,
//!   swap it in the board module to use it), `DEAD_TIME_NS: u32`,
//!   `CURRENT_IRQ: pac::Interrupt` (ADC: end of the injected conversion of
//!   the phase currents, once per PWM period), `BREAK_IRQ: pac::Interrupt`
//!   (`TIM1_BRK_TIM9`), `MAX_PHASE_CURRENT_A: f32` (power stage, peak),
//!   `MAX_MEASURABLE_CURRENT_A: f32` (current-sense range),
//!   `BUS_VOLTAGE_MIN_V: f32`, `BUS_VOLTAGE_MAX_V: f32`, `HAS_BREAK_INPUT: bool`,
//!   `SERIAL_IRQ: pac::Interrupt` (the command UART's interrupt, `USART2`
//!   on every board), `SERIAL_BAUD: u32` (115200, 8N1),
//!   `BRAKE_OUTPUT: bool` (the board switches a brake resistor),
//!   `STAGE_TEMPERATURE_SENSOR: bool` (the board measures its power-stage
//!   temperature), `HAS_CAN: bool` (the board has a CAN port, see "CAN"
//!   below);
//! - type aliases `Pwm`, `Currents`, `Angle`, `Bus`, `Brake` implementing
//!   [`foc_core::hal::PwmDriver`], [`foc_core::hal::CurrentSense`],
//!   [`foc_core::hal::AngleSensor`], [`foc_core::hal::BusVoltage`] (with
//!   `read_temperature_c` where the board has a sensor),
//!   [`foc_core::hal::BrakeOutput`] ([`foc_core::hal::NoBrake`] where the
//!   board has no brake output);
//! - `pub struct Board { pub pwm: Pwm, pub currents: Currents, pub angle: Angle,
//!   pub bus: Bus, pub brake: Brake, pub led: Led, pub serial: CommandSerial }` and
//!   `pub fn init(dp: pac::Peripherals) -> Board`: clocks, pins, timers, ADC,
//!   the command UART (and the DRV8301 over SPI on the ODrive). On
//!   return the bridge is **disabled** (safe state), the brake output off,
//!   the PWM counter runs
//!   (so the ADC is triggered every period and `CURRENT_IRQ` becomes pending
//!   once the NVIC line is unmasked, which is left to the RTIC app);
//! - `pub fn emergency_disable()`: safe state from any context (steals the
//!   peripherals; for panic / HardFault handlers), brake output included;
//! - `pub fn after_panic() -> !` and `pub fn after_hardfault() -> !`: what
//!   the board does once the handler has made the bridge safe and logged
//!   (a real board stops for the debugger or the watchdog's reset; the
//!   emulated board ends the emulation with the verdict as exit status);
//! - `pub fn break_isr_ack()`: clears the TIM1 break flag, outputs stay off;
//! - `pub fn gate_driver_fault() -> bool`: the power stage's fault pin is
//!   asserted (DRV8301 nFAULT on the ODrive, L6230 DIAG/EN on the IHM07M1).
//!
//! The command UART ([`hw::serial::CommandSerial`], re-exported by every
//! board as `CommandSerial`) is USART2 everywhere: PA2 (TX) / PA3 (RX),
//! AF7, 115200 8N1. On the NUCLEO boards that is the ST-LINK virtual COM
//! port (ST UM1724); on the ODrive v3 the J3 pins GPIO3 / GPIO4 (the ODrive
//! firmware's UART_B; its default UART_A is UART4 on GPIO1/2); under QEMU
//! the second `-serial` device. Receive on RXNE, transmit from a ring
//! drained by TXE; `read_byte`, `write`, `on_interrupt` (call it from the
//! task bound to `SERIAL_IRQ`), errors counted, never a panic.
//!
//! # CAN
//!
//! | board                      | CAN port                                        |
//! |----------------------------|-------------------------------------------------|
//! | ODrive v3.x                | CAN1 on PB8 (RX) / PB9 (TX), on-board transceiver: `Board::can` |
//! | NUCLEO-F446RE + IHM07M1    | none: the F446 has bxCAN (CAN1 RX/TX on PA11/PA12 or PB8/PB9, AF9), but neither the NUCLEO nor the X-NUCLEO-IHM07M1 shield has a CAN transceiver; an external transceiver board would be needed |
//! | NUCLEO-F401RE + IHM07M1    | none: the STM32F401 has no CAN controller        |
//! | QEMU                       | no bxCAN model: the same frames as SLCAN lines on USART3 (QEMU's third `-serial`), [`hw::slcan::SlcanPort`]: `Board::can` |
//!
//! On the ODrive, `board::HAS_CAN` is true and the board module adds:
//! `Can` ([`hw::can::CanBus`], implementing [`foc_core::hal::CanPort`]),
//! `Bitrate` ([`logic::can::Bitrate`]: 125 / 250 / 500 / 1000 kbit/s),
//! `CAN_RX_IRQ: pac::Interrupt` (`CAN1_RX0`) and the `Board::can` field.
//! `init` leaves the controller asleep, off the bus; `can.start(bitrate)`
//! joins it (bit timing, automatic bus-off recovery). The emulated board
//! has the same names (`Can` = [`hw::slcan::SlcanPort`], `CAN_RX_IRQ` =
//! `USART3`, `Bitrate` recorded only). Elsewhere `HAS_CAN` is false and
//! there is no port.
//!
//! Safe state = TIM1 `BDTR.MOE = 0` (outputs forced to their idle level,
//! low: every switch off) **and** the power stage's enable pins low (and,
//! in `emergency_disable`, the brake switch off).
//!
//! # Power-stage temperature and brake, per board
//!
//! | board            | temperature (`Bus::read_temperature_c`)          | brake (`Brake`)                      |
//! |------------------|--------------------------------------------------|--------------------------------------|
//! | ODrive v3.x      | M0 FET NTC, PC5 = ADC12_IN15, ODrive's cubic fit  | AUX high side, PB11 TIM2_CH4 (10 kHz, 95 %) |
//! | NUCLEO + IHM07M1 | shield NTC, PC2 = ADC1_IN12, ST MC SDK linear law | none (`NoBrake`)                     |
//! | QEMU             | the plant's stage thermal model                  | `SimBrake` (the plant has no resistor by default) |
//!
//! Counts to deg C with open / short detection: [`logic::thermistor`]. The
//! thermistor and VBUS share ADC1's regular group, alternating (`hw::adc`).
//!
//! Phase currents are sampled by ADC1 injected conversions triggered by
//! TIM1 (`TRGO = OC4REF`, channel 4 compare just before the counter peak,
//! where all low-side switches conduct). `Currents::read_currents` reads
//! the `JDRx` registers, converts to amperes and clears `JEOC`: call it from
//! the `CURRENT_IRQ` handler.
#![no_std]
// The no-panic lints and `missing_docs`: `[workspace.lints]` (Cargo.toml).

pub mod logic;

#[cfg(feature = "_hal")]
pub mod hw;

#[cfg(feature = "_hal")]
pub mod boards;

/// The peripheral access crate of the selected chip.
#[cfg(feature = "_hal")]
pub use stm32f4xx_hal::pac;

#[cfg(all(feature = "_hal", feature = "nucleo-f446re-ihm07m1"))]
pub use boards::nucleo_f446re_ihm07m1 as board;

#[cfg(all(feature = "_hal", feature = "nucleo-f401re-ihm07m1"))]
pub use boards::nucleo_f401re_ihm07m1 as board;

#[cfg(all(feature = "_hal", feature = "odrive-v3"))]
pub use boards::odrive_v3 as board;
#[cfg(all(feature = "_hal", feature = "qemu"))]
pub use boards::qemu as board;

#[cfg(any(
    all(feature = "nucleo-f446re-ihm07m1", feature = "nucleo-f401re-ihm07m1"),
    all(feature = "nucleo-f446re-ihm07m1", feature = "odrive-v3"),
    all(feature = "nucleo-f401re-ihm07m1", feature = "odrive-v3"),
))]
compile_error!("board-support: select exactly one board feature per build");

#[cfg(all(feature = "as5047p", not(feature = "odrive-v3")))]
compile_error!("board-support: feature `as5047p` is an option of `odrive-v3` only");
