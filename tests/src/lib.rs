//! # foc-bench: the test bench of the FOC drive
//!
//! Runs the controller of `foc-core` against the PMSM + inverter + sensor
//! plant of the `foc-plant` crate, one PWM period at a time, with (default
//! `std` feature) motor parameter files, step-response metrics, missions and
//! report writers.
//!
//! Re-exported from `foc-plant` (`no_std`; the same code runs on the emulated
//! board), so `foc_bench::plant::...` and `foc_plant::plant::...` name the
//! same items. The `plant-f32` feature forwards to `foc-plant/plant-f32`.
//!
//! - [`plant`]: motor, inverter (averaged or carrier-compared PWM, dead time,
//!   computation delay, disabled bridge), DC source, sensors, fault injection.
//! - [`adapters`]: `foc-core` hardware traits on a shared plant.
//! - [`rng`], [`real`]: deterministic noise and the plant's scalar.
//!
//! The bench's own modules (`std`):
//!
//! - [`motor_file`]: TOML motor files in `tests/motors/`.
//! - [`identify`]: current offsets and the motor identification of
//!   `foc-core` driven through a simulated cascade.
//! - [`metrics`]: overshoot, settling, rise time, errors.
//! - [`report`]: CSV traces, SVG plots, dynamometer reports.
//! - [`mission`]: the real `foc-core` cascade against the plant
//!   through a scripted mission (identify, current step, speed, load, position).
//! - [`dyno`]: simulated dynamometer sweeps (Performance Curve Report).
//! - [`sil`]: the software-in-the-loop protocol of the `foc-sil` binary.
//!
//! A simulation runner closes the loop like this:
//!
//! ```
//! use foc_bench::plant::{BenchConfig, MotorParams, Plant};
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
//! [`mission::run_mission`] (what `cargo xtask sim` runs) and its
//! [`mission::MissionResult`], then [`motor_file`] (the motor files in
//! `tests/motors/`) and [`sil`] (the controller driven by an outside plant).
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
// `Real` is f64 or f32 by feature: a cast to or from it is a no-op in one of the two.
#![allow(clippy::unnecessary_cast)]

pub use foc_plant::{adapters, plant, power, real, rng};

#[cfg(feature = "std")]
pub mod dyno;
#[cfg(feature = "std")]
pub mod identify;
#[cfg(feature = "std")]
pub mod metrics;
#[cfg(feature = "std")]
pub mod mission;
#[cfg(feature = "std")]
pub mod motor_file;
#[cfg(feature = "std")]
pub mod report;
/// The bench's side of the scope's current step (design §22).
#[cfg(feature = "std")]
pub mod scope_step;
#[cfg(feature = "std")]
pub mod sil;
