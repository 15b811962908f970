//! # foc-plant: the simulated motor, inverter and DC link
//!
//! A PMSM + three-phase inverter + DC source + sensor plant that the
//! controller of `foc-core` can be run against, one PWM period at a time.
//! It is `no_std` (core + `libm`, no alloc, no unsafe), so the same plant
//! serves the host test bench (`foc-bench`) and the emulated board of
//! `board-support` (feature `qemu`), where it runs on the emulated
//! Cortex-M4F itself. `foc-core` never depends on it.
//!
//! - [`plant`]: motor, inverter (averaged or carrier-compared PWM, dead time,
//!   computation delay, disabled bridge), DC source, sensors, fault injection.
//! - [`power`]: optional power-stage models: DC link (capacitor, limited,
//!   sinking or non-sinking source), brake chopper, winding and power-stage
//!   temperatures (all off by default).
//! - [`adapters`]: `foc-core` hardware traits on a shared plant.
//! - [`rng`]: deterministic noise for the sensors.
//! - [`real`]: the plant's scalar, [`real::Real`]: `f64` by default, `f32`
//!   with the `plant-f32` feature (faster on the Cortex-M4F, less accurate).
//!
//! A simulation runner closes the loop like this:
//!
//! ```
//! use foc_plant::plant::{BenchConfig, MotorParams, Plant};
//! let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
//! let mut duties = [0.5f32; 3];
//! for _ in 0..100 {
//!     let m = plant.step_period(duties, true, 0.0);
//!     // duties = controller.step(m);
//!     let _ = m;
//!     duties = [0.52, 0.49, 0.49];
//! }
//! assert!(plant.iq_a().is_finite());
//! ```
//!
//! # Where to start reading
//!
//! [`plant::Plant`] (one PWM period of the motor, inverter and supply),
//! then its configuration and fault injection in [`plant`]'s submodules,
//! and [`emulated`] (the plant behind the emulated board).
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
// `Real` is f64 or f32 by feature: a cast to or from it is a no-op in one of the two.
#![allow(clippy::unnecessary_cast)]

pub mod adapters;
pub mod emulated;
pub mod plant;
pub mod power;
pub mod real;
pub mod rng;
