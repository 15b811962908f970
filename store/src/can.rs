//! The CAN node settings ([`CanRecord`]): stored under their own key
//! ([`crate::store::CAN_RECORD_KEY`]), apart from the drive record, so
//! that either changes without touching the other's schema.
//!
//! # Envelope
//!
//! The same layout as the drive record's ([`crate::record`]), with its own
//! version counter ([`CAN_SCHEMA_VERSION`]):
//!
//! ```text
//! version:u16 LE | len:u16 LE | postcard(CanRecord) (len bytes) | crc32:u32 LE
//! ```
//!
//! CRC-32/ISO-HDLC over `version | len | payload`. [`CanRecord::decode`]
//! checks the length, the CRC, then the version, never panics and never
//! returns a partially decoded record.
//!
//! ```
//! use foc_store::can::{CanRecord, MAX_CAN_RECORD_BYTES};
//! let r = CanRecord { node_id: 5, bitrate_kbit: 500, ..CanRecord::DEFAULT };
//! assert_eq!(r.validate(), Ok(()));
//! let mut buf = [0u8; MAX_CAN_RECORD_BYTES];
//! let n = r.encode(&mut buf).unwrap();
//! assert_eq!(CanRecord::decode(&buf[..n]), Ok(r));
//! buf[5] ^= 1; // a flipped bit
//! assert!(CanRecord::decode(&buf[..n]).is_err());
//! ```

use serde::{Deserialize, Serialize};

use crate::record::{Invalid, RecordError};

/// Version of [`CanRecord`]'s layout written by this build (independent
/// of the drive record's `SCHEMA_VERSION`). Bump it on any layout change
/// and decode the old one in [`CanRecord::decode`].
pub const CAN_SCHEMA_VERSION: u16 = 1;

/// Largest envelope \[bytes\]: header 4, payload at most 11 (postcard
/// varints: `u8` 1, `u16` up to 3), CRC 4 = 19; the rest is room for a
/// later layout.
pub const MAX_CAN_RECORD_BYTES: usize = 32;

/// The bit rates a node may be set to [kbit/s].
pub const BITRATES_KBIT: [u16; 4] = [125, 250, 500, 1000];

/// The CANopen node settings kept across power-off (CiA 301: node-ID,
/// bit rate, producer heartbeat time `0x1017`, one consumer heartbeat
/// entry `0x1016:01`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[serde(deny_unknown_fields)]
pub struct CanRecord {
    /// Node-ID, `1..=127`.
    pub node_id: u8,
    /// Bit rate [kbit/s], one of [`BITRATES_KBIT`].
    pub bitrate_kbit: u16,
    /// Producer heartbeat period \[ms\] (`0x1017`; 0 = no heartbeat).
    pub heartbeat_ms: u16,
    /// Node whose heartbeat this node watches (`0x1016:01`), `1..=127`
    /// and not this node; 0 = none.
    pub consumer_node: u8,
    /// Longest wait for that heartbeat \[ms\] (`> 0` with a consumer node,
    /// 0 without: one way to say "none").
    pub consumer_ms: u16,
}

impl Default for CanRecord {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// `Ok` when `ok`, else the field.
fn check(ok: bool, field: &'static str) -> Result<(), Invalid> {
    if ok {
        Ok(())
    } else {
        Err(Invalid { field })
    }
}

impl CanRecord {
    /// The settings of a drive that never stored any: node 1, 1 Mbit/s,
    /// heartbeat every 100 ms, no consumer.
    pub const DEFAULT: CanRecord = CanRecord {
        node_id: 1,
        bitrate_kbit: 1000,
        heartbeat_ms: 100,
        consumer_node: 0,
        consumer_ms: 0,
    };

    /// Check every value; the error names the first bad field
    /// (`can.<field>`).
    pub fn validate(&self) -> Result<(), Invalid> {
        check((1..=127).contains(&self.node_id), "can.node_id")?;
        check(
            BITRATES_KBIT.contains(&self.bitrate_kbit),
            "can.bitrate_kbit",
        )?;
        check(
            self.consumer_node <= 127 && self.consumer_node != self.node_id,
            "can.consumer_node",
        )?;
        check(
            (self.consumer_node == 0) == (self.consumer_ms == 0),
            "can.consumer_ms",
        )?;
        Ok(())
    }

    /// Write the envelope into `out`; returns the number of bytes used.
    /// [`RecordError::TooLong`] when it does not fit in `out` or exceeds
    /// [`MAX_CAN_RECORD_BYTES`]. Does not validate (see [`Self::validate`]).
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, RecordError> {
        crate::envelope::seal(self, CAN_SCHEMA_VERSION, out, MAX_CAN_RECORD_BYTES)
    }

    /// Read an envelope: length, then CRC, then version (only
    /// [`CAN_SCHEMA_VERSION`] exists; any other is
    /// [`RecordError::UnsupportedVersion`]). `bytes` must be exactly one
    /// envelope. Does not validate.
    pub fn decode(bytes: &[u8]) -> Result<CanRecord, RecordError> {
        let (version, payload) = crate::envelope::open(bytes, MAX_CAN_RECORD_BYTES)?;
        if version != CAN_SCHEMA_VERSION {
            return Err(RecordError::UnsupportedVersion {
                found: version,
                supported: CAN_SCHEMA_VERSION,
            });
        }
        match postcard::take_from_bytes::<CanRecord>(payload) {
            Ok((r, [])) => Ok(r),
            _ => Err(RecordError::Malformed),
        }
    }
}
