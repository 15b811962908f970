//! Moving a configuration record over the link (design §17).
//!
//! A record (the drive's `foc-store` envelope: version, length, postcard
//! body, CRC-32) is up to [`MAX_RECORD`] bytes, more than one frame
//! carries, so it travels in [`Chunk`]s of at most [`CHUNK_BYTES`]:
//!
//! - **read**: `ReadConfig { source, offset }` is answered with the chunk
//!   at `offset` of the live or the stored record (`total` says how long
//!   it is); the host asks again at `offset + len` until `total`. The
//!   record's own CRC tells the host the pieces belong together.
//! - **write**: `WriteConfig(chunk)` appends to the device's staging
//!   buffer (offset 0 restarts it; any other offset must continue where the
//!   last chunk ended); nothing is applied until `Store(Apply)` or
//!   `Store(ApplyAndSave)`, which hands the whole staged record to the
//!   device, which decodes and validates *all* of it before changing
//!   anything.
//!
//! The protocol never looks inside a record: it moves bytes, the device's
//! store decides what they mean.

use crate::message::ErrorCode;

/// Record bytes per chunk (a chunk's body is `offset:u16 total:u16 len:u8`
/// and the bytes: 53 of the 57 a frame carries after tag, seq and CRC).
pub const CHUNK_BYTES: usize = 48;

/// Largest record the link moves \[bytes\] (`foc_store::MAX_RECORD_BYTES`,
/// which the firmware checks at build time): 2048 since the record keeps
/// the anticogging map and the angle sensor's correction (store schema 9,
/// up to 1861 bytes: 39 chunks), 320 before.
pub const MAX_RECORD: usize = 2048;

/// A piece of a configuration record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Chunk {
    /// Where these bytes start in the record.
    pub offset: u16,
    /// The whole record's length.
    pub total: u16,
    len: u8,
    bytes: [u8; CHUNK_BYTES],
}

impl Chunk {
    /// The chunk of `record` starting at `offset` (empty past the end; at
    /// most [`CHUNK_BYTES`]); `None` when the record is longer than
    /// [`MAX_RECORD`].
    pub fn of(record: &[u8], offset: u16) -> Option<Self> {
        if record.len() > MAX_RECORD {
            return None;
        }
        let rest = record.get(usize::from(offset)..).unwrap_or(&[]);
        let n = rest.len().min(CHUNK_BYTES);
        let mut bytes = [0u8; CHUNK_BYTES];
        bytes.get_mut(..n)?.copy_from_slice(rest.get(..n)?);
        Some(Self {
            offset,
            total: record.len() as u16,
            len: n as u8,
            bytes,
        })
    }

    /// From its wire fields; `None` when `data` is longer than
    /// [`CHUNK_BYTES`].
    pub fn new(offset: u16, total: u16, data: &[u8]) -> Option<Self> {
        let mut bytes = [0u8; CHUNK_BYTES];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Self {
            offset,
            total,
            len: data.len() as u8,
            bytes,
        })
    }

    /// The record bytes carried.
    pub fn data(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

/// Which record `ReadConfig` reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum ConfigSource {
    /// The configuration in force now.
    Live = 0,
    /// The record in the drive's flash store.
    Stored = 1,
}

impl ConfigSource {
    /// From its wire code.
    pub const fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Self::Live),
            1 => Some(Self::Stored),
            _ => None,
        }
    }
}

/// What `Store` does (only while started and disabled: an erase or a write
/// of the internal flash stalls the processor).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum StoreOp {
    /// Write the configuration in force to the store.
    Save = 0,
    /// Apply the stored record (validated whole first).
    Load = 1,
    /// Erase the store: the next boot starts from the build-time defaults,
    /// uncalibrated. The configuration in force is kept.
    Erase = 2,
    /// Apply the staged record (validated whole first).
    Apply = 3,
    /// Apply the staged record, then save it.
    ApplyAndSave = 4,
}

impl StoreOp {
    /// From its wire code.
    pub const fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Self::Save),
            1 => Some(Self::Load),
            2 => Some(Self::Erase),
            3 => Some(Self::Apply),
            4 => Some(Self::ApplyAndSave),
            _ => None,
        }
    }

    /// True for the operations that take the staged record.
    pub const fn uses_staged(self) -> bool {
        matches!(self, Self::Apply | Self::ApplyAndSave)
    }
}

/// The device's staging buffer for `WriteConfig`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Staging {
    buf: [u8; MAX_RECORD],
    len: u16,
    total: u16,
}

impl Default for Staging {
    fn default() -> Self {
        Self::new()
    }
}

impl Staging {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_RECORD],
            len: 0,
            total: 0,
        }
    }

    /// Append `c` (offset 0 restarts). Refused, with the staged bytes
    /// dropped, when the chunk does not continue the record or would run
    /// past its announced length or [`MAX_RECORD`]; the error names the
    /// wire field at fault (0 offset, 1 total, 2 length).
    pub fn write(&mut self, c: &Chunk) -> Result<(), ErrorCode> {
        if c.offset == 0 {
            *self = Self::new();
            self.total = c.total;
        }
        let field = if c.offset != self.len {
            Some(0)
        } else if c.total != self.total || usize::from(c.total) > MAX_RECORD {
            Some(1)
        } else if usize::from(c.offset).saturating_add(c.data().len()) > usize::from(c.total) {
            Some(2)
        } else {
            None
        };
        if let Some(field) = field {
            *self = Self::new();
            return Err(ErrorCode::OutOfRange { field });
        }
        let start = usize::from(self.len);
        let end = start.saturating_add(c.data().len());
        let Some(dst) = self.buf.get_mut(start..end) else {
            *self = Self::new();
            return Err(ErrorCode::OutOfRange { field: 2 });
        };
        dst.copy_from_slice(c.data());
        self.len = end as u16;
        Ok(())
    }

    /// The whole staged record, once every byte of it has arrived.
    pub fn complete(&self) -> Option<&[u8]> {
        (self.total > 0 && self.len == self.total)
            .then(|| self.buf.get(..usize::from(self.len)))
            .flatten()
    }

    /// Drop what is staged.
    pub fn clear(&mut self) {
        *self = Self::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(n: usize) -> [u8; MAX_RECORD] {
        let mut r = [0u8; MAX_RECORD];
        for (i, b) in r.iter_mut().enumerate().take(n) {
            *b = (i * 7 + 3) as u8;
        }
        r
    }

    #[test]
    fn chunks_reassemble_the_record() {
        for n in [1, 47, 48, 49, 130, MAX_RECORD] {
            let r = record(n);
            let mut st = Staging::new();
            let mut off = 0u16;
            while usize::from(off) < n {
                let c = Chunk::of(&r[..n], off).unwrap();
                assert_eq!(c.total as usize, n);
                st.write(&c).unwrap();
                off += c.data().len() as u16;
            }
            assert_eq!(st.complete(), Some(&r[..n]), "n = {n}");
        }
    }

    #[test]
    fn out_of_order_or_overlong_chunks_are_refused_and_drop_the_staging() {
        let r = record(100);
        let mut st = Staging::new();
        st.write(&Chunk::of(&r[..100], 0).unwrap()).unwrap();
        // A gap.
        let c = Chunk::new(60, 100, &r[60..70]).unwrap();
        assert_eq!(st.write(&c), Err(ErrorCode::OutOfRange { field: 0 }));
        assert_eq!(st.complete(), None);
        // Past the announced total.
        st.write(&Chunk::new(0, 10, &r[..8]).unwrap()).unwrap();
        let c = Chunk::new(8, 10, &r[8..12]).unwrap();
        assert_eq!(st.write(&c), Err(ErrorCode::OutOfRange { field: 2 }));
        // A total that changes midway, or beyond MAX_RECORD.
        st.write(&Chunk::new(0, 20, &r[..8]).unwrap()).unwrap();
        let c = Chunk::new(8, 30, &r[8..12]).unwrap();
        assert_eq!(st.write(&c), Err(ErrorCode::OutOfRange { field: 1 }));
        let c = Chunk::new(0, MAX_RECORD as u16 + 1, &r[..8]).unwrap();
        assert_eq!(st.write(&c), Err(ErrorCode::OutOfRange { field: 1 }));
        assert_eq!(st.complete(), None);
        // An incomplete record is not complete.
        st.write(&Chunk::new(0, 20, &r[..8]).unwrap()).unwrap();
        assert_eq!(st.complete(), None);
        assert!(Chunk::new(0, 60, &[0u8; 49]).is_none());
        assert!(Chunk::of(&[0u8; MAX_RECORD + 1], 0).is_none());
    }
}
