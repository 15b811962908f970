//! Configuration records over the link ([`foc_protocol::config`]): read the
//! live or the stored record, write a record to the device's staging
//! buffer, run a store operation.
//!
//! The client moves bytes only; what they mean is `foc-store`'s business
//! (`DriveRecord::decode`, whose envelope CRC also tells whether the pieces
//! read belong together).
//!
//! Flash operations stall a real drive for seconds (a 128 KiB sector erase
//! takes 2-4 s at the HAL's x8 parallelism; an erase of the whole store two
//! of them), so `Store` requests and reads of the stored record (which
//! may repair the store, a write) wait [`Client::set_store_timeout`] per
//! attempt instead of the normal reply timeout. Retrying them is safe: a
//! retransmitted `Store` is answered from the device's reply cache, not run
//! twice.
//!
//! ```no_run
//! use foc_ctl::Client;
//! use foc_protocol::config::{ConfigSource, StoreOp};
//!
//! let mut c = Client::connect_tcp("127.0.0.1:4444")?;
//! let live = c.read_config(ConfigSource::Live)?;
//! c.write_config(&live)?;
//! c.store(StoreOp::ApplyAndSave)?;
//! # Ok::<(), foc_ctl::ClientError>(())
//! ```

use crate::{Client, ClientError};
use foc_protocol::config::{Chunk, ConfigSource, StoreOp, CHUNK_BYTES, MAX_RECORD};
use foc_protocol::message::{Request, Response};
use std::fmt;
use std::time::Duration;

/// Default reply timeout of flash operations (per attempt).
pub const DEFAULT_STORE_TIMEOUT: Duration = Duration::from_secs(10);

/// A configuration transfer that does not add up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransferError {
    /// The device announced a record longer than [`MAX_RECORD`] bytes.
    TooLong {
        /// Announced length \[bytes\].
        total: u16,
    },
    /// The device changed the record's length between two chunks.
    TotalChanged {
        /// Length announced by the first chunk \[bytes\].
        first: u16,
        /// Length announced now \[bytes\].
        now: u16,
    },
    /// The device answered with a chunk at another offset than asked.
    WrongOffset {
        /// Offset asked for.
        asked: u16,
        /// Offset answered.
        got: u16,
    },
    /// An empty chunk before the end of the record (the device would
    /// never finish), or a chunk running past the announced length.
    BadLength {
        /// Where the chunk starts.
        offset: u16,
        /// Bytes it carries.
        len: usize,
        /// The record's length.
        total: u16,
    },
    /// (Host side) the record to write is empty or longer than
    /// [`MAX_RECORD`] bytes.
    RecordSize {
        /// Its length \[bytes\].
        len: usize,
    },
}

impl fmt::Display for TransferError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            TransferError::TooLong { total } => write!(
                f,
                "the device announced a {total}-byte record (at most {MAX_RECORD})"
            ),
            TransferError::TotalChanged { first, now } => write!(
                f,
                "the record's length changed during the read ({first} then {now} bytes): read it again"
            ),
            TransferError::WrongOffset { asked, got } => {
                write!(f, "asked for the chunk at {asked}, the device sent {got}")
            }
            TransferError::BadLength { offset, len, total } => write!(
                f,
                "the device sent {len} byte(s) at offset {offset} of a {total}-byte record (the read would not finish)"
            ),
            TransferError::RecordSize { len } => write!(
                f,
                "a record of {len} bytes cannot be sent (1 to {MAX_RECORD} bytes)"
            ),
        }
    }
}

impl std::error::Error for TransferError {}

impl From<TransferError> for ClientError {
    fn from(e: TransferError) -> Self {
        ClientError::Transfer(e)
    }
}

/// Check one chunk of a read against what was asked and what came before;
/// returns the record's length.
fn check_chunk(c: &Chunk, asked: u16, total: Option<u16>) -> Result<u16, TransferError> {
    if usize::from(c.total) > MAX_RECORD {
        return Err(TransferError::TooLong { total: c.total });
    }
    if let Some(first) = total {
        if c.total != first {
            return Err(TransferError::TotalChanged {
                first,
                now: c.total,
            });
        }
    }
    if c.offset != asked {
        return Err(TransferError::WrongOffset {
            asked,
            got: c.offset,
        });
    }
    let len = c.data().len();
    let end = usize::from(c.offset).saturating_add(len);
    if (len == 0 && c.offset < c.total) || end > usize::from(c.total) {
        return Err(TransferError::BadLength {
            offset: c.offset,
            len,
            total: c.total,
        });
    }
    Ok(c.total)
}

impl Client {
    /// Reply timeout per attempt of flash operations (`Store`, reads of the
    /// stored record); default [`DEFAULT_STORE_TIMEOUT`]. The normal
    /// timeout is used when it is longer.
    pub fn set_store_timeout(&mut self, timeout: Duration) {
        self.store_timeout = timeout;
    }

    fn flash_timeout(&self) -> Duration {
        self.store_timeout.max(self.timeout)
    }

    /// The command limits in force (the live configuration record's, with
    /// the joint's impedance maxima where it has a joint).
    pub fn limits(&mut self) -> Result<foc_core::control::Limits, ClientError> {
        let bytes = self.read_config(ConfigSource::Live)?;
        let r = foc_store::DriveRecord::decode(&bytes).map_err(|e| {
            ClientError::Io(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("the drive's live record does not decode: {e:?}"),
            ))
        })?;
        Ok(match r.joint {
            Some(j) => j.limits(&r.limits),
            None => r.limits.to_limits(),
        })
    }

    /// The whole live or stored record (the foc-store envelope), read chunk
    /// by chunk. [`ClientError::Transfer`] when the device's chunks do not
    /// add up (the length changes midway, a chunk at the wrong offset, an
    /// empty chunk before the end): at most [`MAX_RECORD`] requests are
    /// sent.
    pub fn read_config(&mut self, source: ConfigSource) -> Result<Vec<u8>, ClientError> {
        let timeout = match source {
            ConfigSource::Live => self.timeout,
            ConfigSource::Stored => self.flash_timeout(),
        };
        let mut record = Vec::new();
        let mut total = None;
        loop {
            // Every chunk but the last carries at least one byte, so the
            // offset grows each time and stays <= MAX_RECORD: the loop ends.
            let offset = u16::try_from(record.len())
                .map_err(|_| TransferError::RecordSize { len: record.len() })?;
            let c = match self.request_timed(&Request::ReadConfig { source, offset }, timeout)? {
                Response::ConfigChunk(c) => c,
                r => return Err(ClientError::Unexpected(r)),
            };
            let t = check_chunk(&c, offset, total)?;
            total = Some(t);
            record.extend_from_slice(c.data());
            if record.len() >= usize::from(t) {
                return Ok(record);
            }
        }
    }

    /// Write `record` (1 to [`MAX_RECORD`] bytes) to the device's staging
    /// buffer in chunks of [`CHUNK_BYTES`], offset 0 first (which restarts
    /// the staging). Nothing is applied until [`Self::store`] with
    /// [`StoreOp::Apply`] or [`StoreOp::ApplyAndSave`].
    pub fn write_config(&mut self, record: &[u8]) -> Result<(), ClientError> {
        if record.is_empty() || record.len() > MAX_RECORD {
            return Err(TransferError::RecordSize { len: record.len() }.into());
        }
        for start in (0..record.len()).step_by(CHUNK_BYTES) {
            let offset = u16::try_from(start)
                .map_err(|_| TransferError::RecordSize { len: record.len() })?;
            let chunk =
                Chunk::of(record, offset).ok_or(TransferError::RecordSize { len: record.len() })?;
            self.expect_ack(&Request::WriteConfig(chunk))?;
        }
        Ok(())
    }

    /// Run a store operation (the drive must be disabled), waiting up to
    /// the store timeout per attempt.
    pub fn store(&mut self, op: StoreOp) -> Result<(), ClientError> {
        match self.request_timed(&Request::Store(op), self.flash_timeout())? {
            Response::Ack => Ok(()),
            r => Err(ClientError::Unexpected(r)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_are_checked_against_the_request_and_the_first_total() {
        let r = [7u8; 100];
        let c0 = Chunk::of(&r, 0).unwrap();
        assert_eq!(check_chunk(&c0, 0, None), Ok(100));
        let c1 = Chunk::of(&r, 48).unwrap();
        assert_eq!(check_chunk(&c1, 48, Some(100)), Ok(100));
        assert_eq!(
            check_chunk(&c1, 48, Some(90)),
            Err(TransferError::TotalChanged {
                first: 90,
                now: 100
            })
        );
        assert_eq!(
            check_chunk(&c1, 0, Some(100)),
            Err(TransferError::WrongOffset { asked: 0, got: 48 })
        );
        let empty = Chunk::new(48, 100, &[]).unwrap();
        assert!(matches!(
            check_chunk(&empty, 48, Some(100)),
            Err(TransferError::BadLength { .. })
        ));
        let past = Chunk::new(96, 100, &[0; 8]).unwrap();
        assert!(matches!(
            check_chunk(&past, 96, Some(100)),
            Err(TransferError::BadLength { .. })
        ));
        let too_long = MAX_RECORD as u16 + 1;
        let huge = Chunk::new(0, too_long, &[0; 8]).unwrap();
        assert_eq!(
            check_chunk(&huge, 0, None),
            Err(TransferError::TooLong { total: too_long })
        );
        // An empty record is a complete (empty) read.
        let none = Chunk::new(0, 0, &[]).unwrap();
        assert_eq!(check_chunk(&none, 0, None), Ok(0));
    }
}
