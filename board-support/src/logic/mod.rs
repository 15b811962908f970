//! Pure logic, no hardware: always compiled, tested on the host.
//!
//! Every register encoding and unit conversion the drivers in `crate::hw`
//! use lives here, where `cargo test -p board-support` can check it.

pub mod as5047p;
pub mod can;
pub mod dead_time;
pub mod drv8301;
pub mod emu_args;
pub mod encoder;
pub mod hall;
pub mod instrument;
pub mod nor_region;
pub mod pwm_timing;
pub mod scaling;
pub mod serial;
pub mod spi_clock;
pub mod thermistor;
