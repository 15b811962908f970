//! The drive's persistent configuration and calibration.
//!
//! - [`record`]: the on-flash schema [`DriveRecord`], its versioned,
//!   checksummed envelope and its validation.
//! - [`settings`]: the live [`Settings`] and their conversion to and from a
//!   record.
//! - [`can`]: the CAN node settings [`CanRecord`], their own envelope and
//!   validation (stored apart from the drive record).
//! - [`store`]: [`Store`], the records in a power-fail-safe log over NOR
//!   flash (sequential-storage's map, one key per record).
//! - `fake` (tests, feature `fake`): a RAM NOR flash with power-cut
//!   injection.
//! - `text` (feature `std`): TOML export and import.
//!
//! `no_std`, no alloc, no unsafe, no panics.
//!
//! ```
//! use foc_store::{fake::FakeFlash, DriveRecord, Store, MAX_RECORD_BYTES};
//! # let record = foc_store::record::example();
//! let mut store = Store::new(FakeFlash::<4, 4096, 1>::new(), 0..16384).unwrap();
//! store.save(&record).unwrap();
//! let loaded: Option<DriveRecord> = store.load().unwrap();
//! assert_eq!(loaded, Some(record));
//! ```
//!
//! # Where to start reading
//!
//! [`DriveRecord`] (what is stored), [`record`] (its versions and
//! validation), then [`Store`] (how a record reaches flash, all or nothing).
#![no_std]
#![forbid(unsafe_code)]
// The no-panic lints and `missing_docs`: `[workspace.lints]` (Cargo.toml).

#[cfg(any(test, feature = "std"))]
extern crate std;

pub mod can;
mod envelope;
#[cfg(any(test, feature = "fake"))]
pub mod fake;
pub mod record;
pub mod settings;
pub mod store;
#[cfg(feature = "std")]
pub mod text;

#[cfg(test)]
mod tests;

pub use can::CanRecord;
pub use record::{DriveRecord, Invalid, Label, RecordError, MAX_RECORD_BYTES, SCHEMA_VERSION};
pub use settings::Settings;
pub use store::{Store, StoreError};
