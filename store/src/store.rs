//! [`Store`]: the drive record in a region of NOR flash.
//!
//! # Design
//!
//! The store is a [`sequential_storage::map::MapStorage`] with two keys:
//! [`RECORD_KEY`], whose value is the drive record's envelope
//! ([`DriveRecord::encode`]), and [`CAN_RECORD_KEY`], the CAN node
//! settings' ([`CanRecord::encode`], saved and loaded apart:
//! [`Store::save_can`], [`Store::load_can`]; a region never given one
//! yields [`CanRecord::DEFAULT`] through [`Store::load_can_or_default`]). sequential-storage is a tested,
//! power-fail-safe log over NOR flash: every save appends a new item to the
//! open page and the newest valid item wins, so the previous record stays
//! readable until the new one is completely written. We do not hand-write a
//! log.
//!
//! sequential-storage is async over `embedded_storage_async`; the store wraps
//! the blocking [`NorFlash`] in a private adapter and drives the futures with
//! [`embassy_futures::block_on`] (the flash never returns `Pending`, so this
//! is just a call).
//!
//! # Two checksums
//!
//! - sequential-storage's item CRC (a CRC-32C variant over the item data,
//!   plus a CRC-16 of the length) says whether an *item* was completely
//!   written: a torn or half-programmed item fails it and is skipped, so the
//!   previous item is returned.
//! - Our envelope CRC (CRC-32/ISO-HDLC over version, length and payload)
//!   says the *record* is the one some firmware encoded: it covers the
//!   envelope end to end, independent of the storage layer, and is what the
//!   TOML export and any other transport can check too.
//!
//! # Power cuts
//!
//! A power cut during [`Store::save`] leaves either the old record or the new
//! one (never a mix, never neither), as the power-cut tests show for a cut
//! after every written word, including saves that move items and erase a
//! page. A cut during [`Store::erase`] can leave a partly erased region that
//! loads as an error or as empty: erase again.
//!
//! After an interrupted operation, the next [`Store::load`] (or save) may
//! **repair** the region: sequential-storage then erases and rewrites pages
//! (finishing an interrupted page migration) before it answers. `load` can
//! therefore write to flash; on the real board call it where a flash stall
//! is acceptable (at start-up, bridge off).
//!
//! # Wear
//!
//! Items are appended page after page round the region; a page is erased
//! only when the log wraps round to it (its live item is first copied
//! forward). Every page is thus erased about equally often: one erase per
//! `items per page` saves. With 128 KiB sectors and a record of about 270
//! bytes (no tables) that is one erase per ~450 saves; with both tables
//! (schema 9: the anticogging map and the angle correction, 1.8 KB an
//! item) one per ~70 saves, so the STM32F4's 10 000 erase cycles per
//! sector last for about 1.4 million saves over the two sectors.
//!
//! A page must hold the largest record ([`Store::new`] checks it): 2 KiB
//! since schema 9, so the store needs pages of at least about 2.1 KiB
//! (the boards' 16 KiB emulated pages and 128 KiB sectors are far above).
//!
//! ```
//! use foc_store::{fake::FakeFlash, Store};
//! # let record = foc_store::record::example();
//! let mut store = Store::new(FakeFlash::<2, 4096, 4>::new(), 0..8192).unwrap();
//! assert_eq!(store.load(), Ok(None));
//! store.save(&record).unwrap();
//! assert_eq!(store.load(), Ok(Some(record)));
//! ```

use core::fmt;
use core::ops::Range;

use embedded_storage::nor_flash::{
    ErrorType, MultiwriteNorFlash, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage};

use crate::can::{CanRecord, MAX_CAN_RECORD_BYTES};
use crate::record::{DriveRecord, Invalid, RecordError, MAX_RECORD_BYTES};

/// The map key of the drive record.
pub const RECORD_KEY: u8 = 1;

/// The map key of the CAN node settings ([`CanRecord`]).
pub const CAN_RECORD_KEY: u8 = 2;

/// Largest flash word sequential-storage supports \[bytes\].
const MAX_WORD_BYTES: usize = 32;

// The CAN envelope fits where the drive record's does.
const _: () = assert!(MAX_CAN_RECORD_BYTES <= MAX_RECORD_BYTES);

/// Work buffer: key, envelope, and rounding up to the flash word.
const BUFFER_BYTES: usize = 1 + MAX_RECORD_BYTES + MAX_WORD_BYTES;

/// Item header of sequential-storage \[bytes\] (before rounding to words).
const ITEM_HEADER_BYTES: usize = 8;

/// Why a store operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreError {
    /// The region is not page-aligned, has fewer than two pages, lies
    /// outside the flash, or a page cannot hold a record.
    Layout,
    /// The flash driver failed.
    Flash(NorFlashErrorKind),
    /// The region holds no consistent log (garbage, or an interrupted erase):
    /// erase it.
    Corrupt,
    /// No room left for the record even after compaction.
    Full,
    /// The region has been written but holds no valid record: the record
    /// was damaged, or the first save was cut short.
    NoValidRecord,
    /// The stored bytes are not a record this firmware reads.
    Record(RecordError),
    /// The record has an out-of-range value (refused by save, or found by load).
    Invalid(Invalid),
}

impl fmt::Display for StoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Layout => f.write_str(
                "the configuration flash region is not page-aligned, too small, or outside the flash",
            ),
            Self::Flash(kind) => write!(f, "the flash driver failed: {kind:?}"),
            Self::Corrupt => {
                f.write_str("the configuration flash region is corrupted; erase it and save again")
            }
            Self::Full => f.write_str("the configuration flash region is full"),
            Self::NoValidRecord => f.write_str(
                "the configuration flash region holds no valid record (damaged, or the first save was cut short)",
            ),
            Self::Record(e) => write!(f, "{e}"),
            Self::Invalid(e) => write!(f, "{e}"),
        }
    }
}

impl From<RecordError> for StoreError {
    fn from(e: RecordError) -> Self {
        Self::Record(e)
    }
}

impl From<Invalid> for StoreError {
    fn from(e: Invalid) -> Self {
        Self::Invalid(e)
    }
}

fn map_error<E: NorFlashError>(e: sequential_storage::Error<E>) -> StoreError {
    match e {
        sequential_storage::Error::Storage { value, .. } => StoreError::Flash(value.kind()),
        sequential_storage::Error::FullStorage => StoreError::Full,
        sequential_storage::Error::ItemTooBig => StoreError::Layout,
        // Corrupted, a logic bug of the layer, an item longer than our buffer
        // (only garbage can claim that): the region is not ours to trust.
        _ => StoreError::Corrupt,
    }
}

/// The blocking flash seen through the async traits sequential-storage uses.
struct Blocking<F>(F);

impl<F: ErrorType> embedded_storage_async::nor_flash::ErrorType for Blocking<F> {
    type Error = F::Error;
}

impl<F: ReadNorFlash> embedded_storage_async::nor_flash::ReadNorFlash for Blocking<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl<F: NorFlash> embedded_storage_async::nor_flash::NorFlash for Blocking<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.0.erase(from, to)
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.write(offset, bytes)
    }
}

impl<F: MultiwriteNorFlash> embedded_storage_async::nor_flash::MultiwriteNorFlash for Blocking<F> {}

type Map<F> = MapStorage<u8, Blocking<F>, Cache<Uncached, Uncached, Uncached, u8>>;

/// The drive record and the CAN node settings in a region of NOR flash
/// (see the module docs).
pub struct Store<F: NorFlash> {
    map: Map<F>,
    buffer: [u8; BUFFER_BYTES],
}

impl<F: NorFlash> Store<F> {
    /// A store over `range` of `flash` ([`StoreError::Layout`] unless the
    /// range is page-aligned, at least two pages, inside the flash, and a
    /// page can hold the largest record). Reads nothing yet.
    pub fn new(flash: F, range: Range<u32>) -> Result<Self, StoreError> {
        let end = usize::try_from(range.end).map_err(|_| StoreError::Layout)?;
        if range.start >= range.end || end > flash.capacity() {
            return Err(StoreError::Layout);
        }
        let word = F::WRITE_SIZE.max(F::READ_SIZE);
        let round = |n: usize| n.div_ceil(word).saturating_mul(word);
        // Page markers (one word each end), item header, key and envelope.
        let needed = 2 * word + round(ITEM_HEADER_BYTES) + round(1 + MAX_RECORD_BYTES);
        if F::ERASE_SIZE < needed {
            return Err(StoreError::Layout);
        }
        let config = MapConfig::<Blocking<F>>::try_new(range).map_err(|_| StoreError::Layout)?;
        Ok(Self {
            map: MapStorage::new(Blocking(flash), config, Cache::new_uncached()),
            buffer: [0; BUFFER_BYTES],
        })
    }

    /// The stored record: `Ok(None)` when the store holds none (the region
    /// is blank: never written, or erased; or it holds only other keys'
    /// items, e.g. the CAN settings); a region that was written but yields
    /// no item at all is [`StoreError::NoValidRecord`]; a stored record
    /// is decoded and validated ([`StoreError::Record`],
    /// [`StoreError::Invalid`]). May repair (write) the region after an
    /// interrupted operation (see the module docs).
    ///
    /// With the CAN settings stored, a first drive-record save cut short
    /// loads as `Ok(None)` (the region holds a valid item), not as
    /// `NoValidRecord`.
    pub fn load(&mut self) -> Result<Option<DriveRecord>, StoreError> {
        let mut envelope = [0u8; MAX_RECORD_BYTES];
        let Some(n) = self.fetch(RECORD_KEY, &mut envelope)? else {
            return Ok(None);
        };
        let record = DriveRecord::decode(envelope.get(..n).ok_or(StoreError::NoValidRecord)?)?;
        record.validate()?;
        Ok(Some(record))
    }

    /// The stored CAN node settings: `Ok(None)` when none were saved (the
    /// region is blank or holds only other keys' items); otherwise as
    /// [`Self::load`] (a written region without any item is
    /// [`StoreError::NoValidRecord`]; a stored record is decoded and
    /// validated). May repair the region like [`Self::load`].
    pub fn load_can(&mut self) -> Result<Option<CanRecord>, StoreError> {
        let mut envelope = [0u8; MAX_CAN_RECORD_BYTES];
        let Some(n) = self.fetch(CAN_RECORD_KEY, &mut envelope)? else {
            return Ok(None);
        };
        let record = CanRecord::decode(envelope.get(..n).ok_or(StoreError::NoValidRecord)?)?;
        record.validate()?;
        Ok(Some(record))
    }

    /// [`Self::load_can`], with [`CanRecord::DEFAULT`] when none was
    /// saved. Errors stay errors (the caller decides whether to fall back
    /// to the defaults).
    pub fn load_can_or_default(&mut self) -> Result<CanRecord, StoreError> {
        Ok(self.load_can()?.unwrap_or_default())
    }

    /// Store `r` as the CAN node settings. Validates first: nothing is
    /// written for invalid settings ([`StoreError::Invalid`]). The drive
    /// record is not touched. On any error the previous settings are
    /// still the ones [`Self::load_can`] returns, unless the new ones were
    /// completely written.
    pub fn save_can(&mut self, r: &CanRecord) -> Result<(), StoreError> {
        r.validate()?;
        let mut envelope = [0u8; MAX_CAN_RECORD_BYTES];
        let n = r.encode(&mut envelope)?;
        self.store(
            CAN_RECORD_KEY,
            envelope
                .get(..n)
                .ok_or(StoreError::Record(RecordError::TooLong))?,
        )
    }

    /// The newest value of `key`, copied into `out`; its length, or `None`
    /// when the key has no item and the region is blank or holds other
    /// items ([`StoreError::NoValidRecord`] when it was written but holds
    /// no item at all). A value longer than `out` is
    /// [`RecordError::TooLong`].
    fn fetch(&mut self, key: u8, out: &mut [u8]) -> Result<Option<usize>, StoreError> {
        let found = embassy_futures::block_on(self.map.fetch_item::<&[u8]>(&mut self.buffer, &key))
            .map_err(map_error)?;
        if let Some(bytes) = found {
            let dst = out
                .get_mut(..bytes.len())
                .ok_or(StoreError::Record(RecordError::TooLong))?;
            dst.copy_from_slice(bytes);
            return Ok(Some(bytes.len()));
        }
        if self.is_blank()? || self.holds_any_item()? {
            Ok(None)
        } else {
            Err(StoreError::NoValidRecord)
        }
    }

    /// True when the log holds at least one complete item (of any key).
    fn holds_any_item(&mut self) -> Result<bool, StoreError> {
        let mut items = embassy_futures::block_on(self.map.fetch_all_items(&mut self.buffer))
            .map_err(map_error)?;
        let first =
            embassy_futures::block_on(items.next::<&[u8]>(&mut self.buffer)).map_err(map_error)?;
        Ok(first.is_some())
    }

    /// Store `r` as the new record. Validates first: nothing is written for
    /// an invalid record ([`StoreError::Invalid`]). On any error the previous
    /// record is still the one [`Self::load`] returns, unless the new one was
    /// completely written.
    pub fn save(&mut self, r: &DriveRecord) -> Result<(), StoreError> {
        r.validate()?;
        let mut envelope = [0u8; MAX_RECORD_BYTES];
        let n = r.encode(&mut envelope)?;
        self.save_envelope(
            envelope
                .get(..n)
                .ok_or(StoreError::Record(RecordError::TooLong))?,
        )
    }

    /// Append raw envelope bytes of the drive record (no validation).
    fn save_envelope(&mut self, bytes: &[u8]) -> Result<(), StoreError> {
        self.store(RECORD_KEY, bytes)
    }

    /// Append `bytes` as the newest value of `key`.
    fn store(&mut self, key: u8, bytes: &[u8]) -> Result<(), StoreError> {
        embassy_futures::block_on(self.map.store_item(&mut self.buffer, &key, &bytes))
            .map_err(map_error)
    }

    /// Store raw envelope bytes, bypassing validation (tests of what load does
    /// with foreign or corrupt records).
    #[cfg(test)]
    pub(crate) fn save_raw(&mut self, bytes: &[u8]) -> Result<(), StoreError> {
        self.save_envelope(bytes)
    }

    /// Store raw bytes under the CAN key, bypassing validation (tests).
    #[cfg(test)]
    pub(crate) fn save_can_raw(&mut self, bytes: &[u8]) -> Result<(), StoreError> {
        self.store(CAN_RECORD_KEY, bytes)
    }

    /// Erase the whole region (the store is then empty: the drive record
    /// and the CAN settings both go).
    pub fn erase(&mut self) -> Result<(), StoreError> {
        embassy_futures::block_on(self.map.erase_all()).map_err(map_error)
    }

    /// True when every byte of the region reads erased (0xFF).
    fn is_blank(&mut self) -> Result<bool, StoreError> {
        let range = self.map.flash_range();
        let flash = &mut self.map.flash().0;
        let mut chunk = [0u8; 64];
        let mut at = range.start;
        while at < range.end {
            let n = (range.end - at).min(chunk.len() as u32);
            let part = chunk.get_mut(..n as usize).ok_or(StoreError::Layout)?;
            flash
                .read(at, part)
                .map_err(|e| StoreError::Flash(e.kind()))?;
            if part.iter().any(|&b| b != 0xFF) {
                return Ok(false);
            }
            at += n;
        }
        Ok(true)
    }

    /// The flash back.
    pub fn into_flash(self) -> F {
        self.map.destroy().0 .0
    }
}
