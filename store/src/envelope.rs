//! The envelope around a stored record (shared by [`crate::DriveRecord`]
//! and [`crate::CanRecord`], each with its own version counter):
//!
//! ```text
//! version:u16 LE | len:u16 LE | postcard(record) (len bytes) | crc32:u32 LE
//! ```
//!
//! CRC-32/ISO-HDLC over `version | len | payload`. Neither function
//! panics; [`open`] checks the length, then the CRC, and leaves the
//! version to the record type.

use serde::Serialize;

use crate::record::RecordError;

/// Bytes of the envelope before the payload: version, length.
const HEADER_BYTES: usize = 4;
/// Bytes of the CRC after the payload.
const CRC_BYTES: usize = 4;

const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

fn le_u16(bytes: &[u8], at: usize) -> Option<u16> {
    let b = bytes.get(at..at.checked_add(2)?)?;
    Some(u16::from_le_bytes([*b.first()?, *b.get(1)?]))
}

/// `value` in an envelope of `version`, written into `out`; the number of
/// bytes used. [`RecordError::TooLong`] when it does not fit in `out` or
/// in `max` bytes.
pub(crate) fn seal<T: Serialize>(
    value: &T,
    version: u16,
    out: &mut [u8],
    max: usize,
) -> Result<usize, RecordError> {
    let limit = out.len().min(max);
    let out = out.get_mut(..limit).ok_or(RecordError::TooLong)?;
    let payload_room = limit
        .checked_sub(HEADER_BYTES + CRC_BYTES)
        .ok_or(RecordError::TooLong)?;
    let payload_len = {
        let room = out
            .get_mut(HEADER_BYTES..HEADER_BYTES + payload_room)
            .ok_or(RecordError::TooLong)?;
        postcard::to_slice(value, room)
            .map_err(|_| RecordError::TooLong)?
            .len()
    };
    let len = u16::try_from(payload_len).map_err(|_| RecordError::TooLong)?;
    let [v0, v1] = version.to_le_bytes();
    let [l0, l1] = len.to_le_bytes();
    out.get_mut(..HEADER_BYTES)
        .ok_or(RecordError::TooLong)?
        .copy_from_slice(&[v0, v1, l0, l1]);
    let body_end = HEADER_BYTES + payload_len;
    let crc = CRC32.checksum(out.get(..body_end).ok_or(RecordError::TooLong)?);
    out.get_mut(body_end..body_end + CRC_BYTES)
        .ok_or(RecordError::TooLong)?
        .copy_from_slice(&crc.to_le_bytes());
    Ok(body_end + CRC_BYTES)
}

/// The version and the payload of the envelope `bytes` (exactly one, at
/// most `max` bytes), once its length and CRC check out.
pub(crate) fn open(bytes: &[u8], max: usize) -> Result<(u16, &[u8]), RecordError> {
    if bytes.len() > max {
        return Err(RecordError::TooLong);
    }
    let version = le_u16(bytes, 0).ok_or(RecordError::TooShort)?;
    let len = usize::from(le_u16(bytes, 2).ok_or(RecordError::TooShort)?);
    let body_end = HEADER_BYTES + len;
    let total = body_end + CRC_BYTES;
    if bytes.len() < total {
        return Err(RecordError::TooShort);
    }
    if bytes.len() > total {
        return Err(RecordError::TooLong);
    }
    let body = bytes.get(..body_end).ok_or(RecordError::TooShort)?;
    let crc_bytes = bytes.get(body_end..total).ok_or(RecordError::TooShort)?;
    let stored = u32::from_le_bytes(crc_bytes.try_into().map_err(|_| RecordError::TooShort)?);
    if CRC32.checksum(body) != stored {
        return Err(RecordError::BadChecksum);
    }
    let payload = body.get(HEADER_BYTES..).ok_or(RecordError::TooShort)?;
    Ok((version, payload))
}
