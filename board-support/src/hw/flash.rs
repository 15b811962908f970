//! The configuration store's flash region on the real boards:
//! `embedded_storage::nor_flash::{ReadNorFlash, NorFlash, MultiwriteNorFlash}`
//! over the last two 128 KiB sectors of the on-chip flash, delegating to
//! stm32f4xx-hal's `LockedFlash` / `UnlockedFlash`.
//!
//! # Region
//!
//! Offsets are relative to the flash base `0x0800_0000`, as the HAL's
//! `NorFlash` expects; each board exports its region as `STORE_RANGE`
//! (e.g. `0x4_0000..0x8_0000` = sectors 6-7 on the 512 KiB F446RE/F401RE,
//! RM0390 §3.3 table 4, RM0368 §3.3 table 5; `0xC_0000..0x10_0000` =
//! sectors 10-11 on the 1 MiB F405RG, RM0090 §3.3 table 5). The linker
//! script of each board (`board-support/memory/<board>.x`) keeps the
//! program out of it. Any access outside the region is refused with
//! `NorFlashErrorKind::OutOfBounds`, an erase not on 128 KiB boundaries
//! with `NotAligned` (rules in [`crate::logic::nor_region`]).
//!
//! # Timing: an erase stalls the whole CPU
//!
//! The CPU executes from this same (single) flash bank. While an erase or a
//! program operation is under way (`FLASH_SR.BSY`), a read of the flash
//! (instruction fetch, literal pool, constant) stalls the bus until it
//! completes (RM0090 §3.5 / RM0390 §3.5 and §3.6, "Erase and program
//! operations"). A 128 KiB sector erase takes seconds (datasheet table
//! "Flash memory programming", parameter `t_ERASE128KB`, STM32F405xx
//! DS8626 / STM32F446xx DS10693: about 1 s typical at x32 parallelism,
//! about 2 s typical and 4 s maximum at x8, which the HAL uses; figures
//! from memory of the datasheets, not checked here): no code in flash runs
//! meanwhile, interrupt handlers included, so the control loop stops.
//! Callers must have the bridge **disabled** and the independent watchdog
//! stretched before erasing (the firmware does that). Byte programs are
//! short (microseconds each, same table).
//!
//! The HAL programs with `PSIZE = x8`, valid over the whole supply range
//! (RM0390 §3.6.2 table 8), so `WRITE_SIZE = 1`. The HAL's unlock
//! asserts that `FLASH_CR.LOCK` cleared; it only stays set after a wrong
//! key sequence, which never happens here (RM0390 §3.7.1).
//!
//! # Example
//!
//! ```ignore
//! use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
//! let mut store = board.store; // from board::init
//! store.erase(board::STORE_RANGE.start, board::STORE_RANGE.start + 128 * 1024)?;
//! store.write(board::STORE_RANGE.start, &[1, 2, 3, 4])?;
//! let mut buf = [0u8; 4];
//! store.read(board::STORE_RANGE.start, &mut buf)?;
//! ```

use crate::logic::nor_region::{check_access, check_erase};
use crate::pac;
use core::ops::Range;
use embedded_storage::nor_flash::{
    ErrorType, MultiwriteNorFlash, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use stm32f4xx_hal::flash::{Error as HalFlashError, FlashExt, LockedFlash};

/// Erase unit of the store's sectors [bytes] (128 KiB sectors).
pub const SECTOR_SIZE: u32 = 128 * 1024;

/// True when `region` is made of whole 128 KiB sectors of a flash of
/// `flash_bytes` (the boards check their `STORE_RANGE` with it at compile
/// time).
pub const fn is_store_region(region: &Range<u32>, flash_bytes: u32) -> bool {
    region.start < region.end
        && region.start.is_multiple_of(SECTOR_SIZE)
        && region.end.is_multiple_of(SECTOR_SIZE)
        && region.end <= flash_bytes
}

/// Error of [`StoreFlash`].
#[derive(Clone, Copy, Debug)]
pub enum StoreFlashError {
    /// Outside the store region.
    OutOfBounds,
    /// Erase not on sector boundaries.
    NotAligned,
    /// The flash interface reported an error (`FLASH_SR`, RM0390 §3.8.4).
    Hal(HalFlashError),
}

impl NorFlashError for StoreFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            StoreFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            StoreFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            StoreFlashError::Hal(e) => e.kind(),
        }
    }
}

impl From<NorFlashErrorKind> for StoreFlashError {
    fn from(kind: NorFlashErrorKind) -> Self {
        match kind {
            NorFlashErrorKind::NotAligned => StoreFlashError::NotAligned,
            _ => StoreFlashError::OutOfBounds,
        }
    }
}

/// The store region of the on-chip flash (owns the FLASH peripheral).
pub struct StoreFlash {
    flash: LockedFlash,
    region: Range<u32>,
}

impl StoreFlash {
    /// Take the flash peripheral; only `region` (offsets from the flash
    /// base, whole 128 KiB sectors) is readable and writable through it.
    ///
    /// The clock set-up (`rcc.freeze`) sets the wait states through its own
    /// pointer to `FLASH_ACR` and does not need the peripheral, so this can
    /// be created at any time.
    pub fn new(flash: pac::FLASH, region: Range<u32>) -> Self {
        Self {
            flash: LockedFlash::new(flash),
            region,
        }
    }

    /// The region (offsets from the flash base).
    pub fn region(&self) -> Range<u32> {
        self.region.clone()
    }
}

impl ErrorType for StoreFlash {
    type Error = StoreFlashError;
}

impl ReadNorFlash for StoreFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        check_access(&self.region, offset, bytes.len())?;
        ReadNorFlash::read(&mut self.flash, offset, bytes).map_err(StoreFlashError::Hal)
    }

    /// The end of the region: offsets are absolute, so the addressable
    /// extent reaches `region.end` (offsets below `region.start` exist but
    /// are refused).
    fn capacity(&self) -> usize {
        self.region.end as usize
    }
}

impl NorFlash for StoreFlash {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = SECTOR_SIZE as usize;

    /// Erase the sectors `from..to`: stalls the CPU for seconds per
    /// sector (module docs).
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        check_erase(&self.region, from, to, SECTOR_SIZE)?;
        if from == to {
            // The HAL would erase the sector at `from` before comparing.
            return Ok(());
        }
        clear_error_flags();
        let mut unlocked = self.flash.unlocked();
        NorFlash::erase(&mut unlocked, from, to).map_err(StoreFlashError::Hal)
        // `unlocked` drops here: FLASH_CR.LOCK set again (RM0390 §3.7.1).
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        check_access(&self.region, offset, bytes.len())?;
        clear_error_flags();
        let mut unlocked = self.flash.unlocked();
        NorFlash::write(&mut unlocked, offset, bytes).map_err(StoreFlashError::Hal)
    }
}

/// Clear the sticky error flags of `FLASH_SR` (OPERR, WRPERR, PGAERR,
/// PGPERR, PGSERR: `rc_w1`, RM0090 §3.9.5, RM0390 §3.8.4, RM0368 §3.8.4).
/// The HAL reports them after an operation but leaves them set, so one
/// failed operation would fail every later one (a stale PGSERR even blocks
/// the next program, RM0390 §3.6.4): clear them before each operation.
fn clear_error_flags() {
    // SAFETY: writing 1 to an `rc_w1` error bit clears it and writing 0
    // changes nothing (EOP and BSY untouched); this driver is the only
    // user of the flash interface after the clock set-up.
    let flash = unsafe { &*pac::FLASH::ptr() };
    flash.sr().write(|w| {
        w.operr()
            .clear()
            .wrperr()
            .clear()
            .pgaerr()
            .clear()
            .pgperr()
            .clear()
            .pgserr()
            .clear()
    });
}

/// A byte can be programmed again (only clearing bits), as the HAL says for
/// its own `UnlockedFlash` (RM0390 §3.6.4 allows programming a 0 over a
/// programmed byte).
impl MultiwriteNorFlash for StoreFlash {}
