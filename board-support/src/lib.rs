//! STM32F4 board support for foc-core (PLACEHOLDER, filled by the board work).
#![no_std]
#![warn(missing_docs)]
