//! # foc-simdrive: the real drive on the host
//!
//! [`HostDrive`] is foc-core's drive (the cascade and its lifecycle:
//! offsets, sensor check, identification, the loops, the supervisor) on
//! the bench plant ([`foc_bench`]), behind the device service's rules
//! ([`foc_service`]) with a configuration store on a RAM flash and the
//! firmware's scope. It is the drive `foc-ctl simulate` serves and the
//! drives of the host CAN test bus (`foc-canbus`), so the host's
//! simulations and the firmware share one set of rules and one control
//! code.
//!
//! - [`drive`]: the drive, stepped period by period on command.
//! - [`board`]: what the simulated board is ([`Options`], [`Start`]) and
//!   the facts the service checks against.
//! - [`inject`]: faults in the plant or its sensors.
//! - `can` (feature `canopen`): the CANopen node's device.
#![forbid(unsafe_code)]

pub mod board;
#[cfg(feature = "canopen")]
pub mod can;
pub mod drive;
pub mod inject;

pub use board::{Options, Start};
pub use drive::{DriveFlash, HostDrive};
pub use inject::FaultKind;
