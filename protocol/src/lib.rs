//! The drive's command and telemetry protocol.
//!
//! A small binary protocol for a byte stream (UART, USB CDC, a TCP socket to
//! QEMU's emulated USART), in three layers:
//!
//! 1. **Framing** ([`frame`]): every frame is `COBS(payload) 0x00`, so 0x00
//!    only ever appears as the delimiter and a receiver resynchronises at the
//!    next 0x00 after any garbage. The payload is
//!    `tag:u8 | seq:u16 | body | crc32:u32`, all little-endian, the CRC
//!    (CRC-32/ISO-HDLC, the Ethernet/zlib CRC) over `tag | seq | body`.
//!    [`frame::FrameDecoder`] is fed byte by byte from a fixed buffer and never
//!    panics; [`frame::encode`] writes into a caller's `&mut [u8]`.
//! 2. **Messages** ([`message`]): [`message::Request`] (host to device) and
//!    [`message::Response`] (device to host), each with a fixed
//!    little-endian layout per tag (see the tables there). Every reply echoes
//!    the request's sequence number.
//!    Positions, velocities, torques and stiffnesses of commands and
//!    telemetry are in the joint's **output frame**, the motor's limits in
//!    the **rotor frame** (the rule and every field's frame: [`joint`],
//!    the message tables).
//! 3. **Device side** ([`device`]): [`device::DeviceState`] turns a decoded
//!    request into a reply through a [`device::DeviceContext`] the firmware
//!    implements; it validates everything before touching the context, owns
//!    the [`device::CommandWatchdog`] and schedules telemetry. It is plain
//!    code, tested on the host.
//!
//! ```
//! use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
//! use foc_protocol::message::Request;
//! use foc_core::control::Command;
//!
//! let mut wire = [0u8; MAX_FRAME];
//! let n = encode(7, &Request::SetCommand(Command::Velocity { rad_s: 10.0 }), &mut wire).unwrap();
//! assert_eq!(wire[n - 1], 0x00); // the delimiter ends the frame
//!
//! let mut dec = FrameDecoder::new();
//! let mut got = None;
//! for &b in &wire[..n] {
//!     if let Some(r) = dec.feed::<Request>(b) {
//!         got = Some(r.unwrap());
//!     }
//! }
//! let packet = got.unwrap();
//! assert_eq!(packet.seq, 7);
//! assert_eq!(packet.msg, Request::SetCommand(Command::Velocity { rad_s: 10.0 }));
//! ```
//!
//! # Where to start reading
//!
//! [`frame`] (COBS frames and their checksum), then [`message`] (every
//! request and response and its layout), then [`DeviceContext`] and
//! [`device`] (what a drive must implement to answer them). The book's
//! reference chapter on the command channel lists the messages.
#![no_std]
#![forbid(unsafe_code)]
// The no-panic lints and `missing_docs`: `[workspace.lints]` (Cargo.toml);
// this crate parses untrusted bytes and adds no unchecked arithmetic.
#![cfg_attr(not(test), deny(clippy::arithmetic_side_effects))]

pub mod config;
pub mod device;
pub mod frame;
pub mod joint;
pub mod message;
pub mod scope;
mod wire;

pub use device::{CommandWatchdog, DeviceContext, DeviceState, Refusal, WatchdogConfig};
pub use frame::{encode, FrameDecoder, FrameError, Packet, MAX_FRAME, MAX_PAYLOAD};
pub use message::{ErrorCode, Message, Request, Response};

/// Version of this protocol, reported in [`message::Hello`]. Bumped on any
/// incompatible change of the frame or of a message layout (5: the
/// telemetry's flags byte carries the angle in use in bits 2 and 3, which
/// a version-4 host refuses).
pub const PROTOCOL_VERSION: u8 = 5;
