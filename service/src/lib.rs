//! The drive's device service: the rules of the command link, in one
//! place, for every front end that drives a motor.
//!
//! The protocol ([`foc_protocol::DeviceState`]) and the CANopen node
//! validate what a host sends and call a [`DeviceContext`]; this crate is
//! that context, and the same code runs in the firmware, on the CAN host
//! bus's simulated drives and behind `foc-ctl simulate`. What differs
//! between them is passed in:
//!
//! - the board's facts ([`Board`]): PWM rate, hardware current limit,
//!   whether the sensor's zero survives a reset, whether it identifies on
//!   command, version, scope size, the build-time configuration;
//! - a [`Snapshot`] of the drive when the frame arrived (feedback,
//!   status, the last identification, what is pending in its mailboxes);
//! - the configuration store ([`RecordStore`]) and the scope.
//!
//! What a frame asks for comes back in an [`Outbox`] (a command, a fault
//! clear, configuration changes per loop), which the owner commits: the
//! firmware into the loops' mailboxes, a simulation into its drive.
//!
//! The rules ([`link`]'s table): limits against the hardware, gains a
//! permit can vouch for, store operations only while quiet (the bridge off
//! and staying off, no calibration pending, the brake off), records
//! checked whole against the board before anything is written or applied
//! ([`records::admit`]), a stored calibration kept only where the sensor's
//! zero survives a reset, an identification folded into the configuration
//! ([`Service::fold_identification`]).
//!
//! Three rules the front ends used to disagree on, decided here once:
//! - a store operation while a calibration is requested and not yet
//!   taken is `Busy` (a flash stall must not cut a calibration short);
//! - a stored calibration applies only where the sensor's zero survives a
//!   reset ([`Board::zero_survives_reset`]); elsewhere its motor model and
//!   gains apply and the drive stays uncalibrated until an
//!   identification;
//! - limits above the board's hardware current limit are refused
//!   (`Unsupported`), in a simulation as on a board.
//!
//! `no_std`, no alloc, no unsafe, no panics.
//!
//! # Where to start reading
//!
//! [`Service`] (the settings in force and boot from the store), then
//! [`Link`] (what a frame may change, and when) and [`ConfigMailbox`] (how
//! a change reaches the loop that owns it). The rules are tested once for
//! every user in `service/tests/rules.rs`.

#![no_std]
#![forbid(unsafe_code)]

/// Log a warning (with the `defmt` feature; nothing otherwise).
macro_rules! log_warn {
    ($fmt:literal $(, $arg:expr)*) => {{
        #[cfg(feature = "defmt")]
        defmt::warn!($fmt $(, $arg)*);
        #[cfg(not(feature = "defmt"))]
        {
            $(let _ = &$arg;)*
        }
    }};
}
/// Log a note (with the `defmt` feature; nothing otherwise).
macro_rules! log_info {
    ($fmt:literal $(, $arg:expr)*) => {{
        #[cfg(feature = "defmt")]
        defmt::info!($fmt $(, $arg)*);
        #[cfg(not(feature = "defmt"))]
        {
            $(let _ = &$arg;)*
        }
    }};
}
pub(crate) use {log_info, log_warn};

pub mod board;
#[cfg(feature = "canopen")]
pub mod can;
pub mod forward;
pub mod link;
pub mod mailbox;
pub mod records;
pub mod service;
pub mod snapshot;
pub mod view;

pub use board::Board;
pub use link::Link;
pub use mailbox::{ConfigMailbox, Outbox};
pub use records::{NoStore, RecordStore};
pub use service::{BootOutcome, Service};
pub use snapshot::{Identified, Pending, Snapshot};
pub use view::View;

#[doc(no_inline)]
pub use foc_protocol::DeviceContext;

/// The crates [`forward_device_context!`] names (not an API).
#[doc(hidden)]
pub mod __deps {
    pub use foc_core;
    pub use foc_protocol;
}
