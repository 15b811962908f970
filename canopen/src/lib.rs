//! CANopen for the FOC drive: a CiA 301 node with the CiA 402 drive
//! profile, on top of the drive's [`foc_protocol::device::DeviceContext`].
//!
//! no_std, no alloc, no unsafe, no panics. The node is sans-I/O: its owner
//! (the firmware's CAN task, the host test bus) hands it received frames and
//! the time, and sends the frames it produces.
//!
//! # Where to start reading
//!
//! [`node::Node`] (one CAN frame in, the answers out), then [`od`] (the
//! object dictionary), [`sdo`] and [`pdo`] (how objects travel), and
//! [`cia402`] (the drive profile's state machine on top of the drive).
#![no_std]
#![forbid(unsafe_code)]
// The no-panic lints and `missing_docs`: `[workspace.lints]` (Cargo.toml).

pub mod abort;
pub mod cia402;
pub mod frame;
pub mod slcan;

pub use abort::Abort;
pub use frame::CanFrame;
pub mod eds;
pub mod emcy;
pub mod nmt;
pub mod node;
pub mod od;
pub mod pdo;
pub mod profile;
pub mod sdo;
