//! [`FakeFlash`]: a NOR flash in RAM with power-cut injection, for tests.
//!
//! NOR semantics: erase sets a page to 0xFF, a write can only clear bits
//! (the stored byte becomes `old & new`). Writes must be word-aligned and
//! whole words; reads are byte-granular. It counts word writes and page
//! erases, and counts as *rewrites* the word writes that hit a word that was
//! not erased (legal on a [`MultiwriteNorFlash`], but worth knowing).
//!
//! [`FakeFlash::cut_power_after_words`] simulates a power cut: after `n`
//! more word writes the next word is left partly programmed (the upper four
//! bits of its first byte only) and every write and erase fails until [`FakeFlash::restore_power`].
//! An erase hit by the cut leaves its first page half erased.
//!
//! ```
//! use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};
//! use foc_store::fake::FakeFlash;
//! let mut f = FakeFlash::<2, 256, 4>::new();
//! f.write(0, &[0x0F, 0xF0, 0x00, 0xFF]).unwrap();
//! f.write(0, &[0xFF, 0x0F, 0xFF, 0x00]).unwrap(); // AND
//! let mut b = [0u8; 4];
//! f.read(0, &mut b).unwrap();
//! assert_eq!(b, [0x0F, 0x00, 0x00, 0x00]);
//! f.cut_power_after_words(0);
//! assert!(f.write(4, &[0; 4]).is_err());
//! ```

use embedded_storage::nor_flash::{
    ErrorType, MultiwriteNorFlash, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// Why a fake flash operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FakeError {
    /// Offset or length not aligned to the word (or the page for erase).
    NotAligned,
    /// Outside the flash.
    OutOfBounds,
    /// The power is off.
    PowerCut,
}

impl NorFlashError for FakeError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::NotAligned => NorFlashErrorKind::NotAligned,
            Self::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            Self::PowerCut => NorFlashErrorKind::Other,
        }
    }
}

/// A RAM NOR flash of `PAGES` erase pages of `PAGE_BYTES`, written in words
/// of `WORD` bytes.
#[derive(Clone, Debug)]
pub struct FakeFlash<const PAGES: usize, const PAGE_BYTES: usize, const WORD: usize> {
    pages: [[u8; PAGE_BYTES]; PAGES],
    page_erases: [u64; PAGES],
    writes: u64,
    rewrites: u64,
    /// Word writes left before the power cut (`None`: no cut armed).
    budget: Option<u64>,
    powered: bool,
}

impl<const PAGES: usize, const PAGE_BYTES: usize, const WORD: usize> Default
    for FakeFlash<PAGES, PAGE_BYTES, WORD>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const PAGES: usize, const PAGE_BYTES: usize, const WORD: usize>
    FakeFlash<PAGES, PAGE_BYTES, WORD>
{
    /// Fully erased flash, counters at zero, power on.
    pub const fn new() -> Self {
        Self {
            pages: [[0xFF; PAGE_BYTES]; PAGES],
            page_erases: [0; PAGES],
            writes: 0,
            rewrites: 0,
            budget: None,
            powered: true,
        }
    }

    /// Flash filled with `byte` everywhere (garbage tests).
    pub const fn filled(byte: u8) -> Self {
        let mut f = Self::new();
        f.pages = [[byte; PAGE_BYTES]; PAGES];
        f
    }

    /// Size \[bytes\].
    pub const fn size() -> usize {
        PAGES * PAGE_BYTES
    }

    /// Word writes so far.
    pub fn writes(&self) -> u64 {
        self.writes
    }

    /// Page erases so far.
    pub fn erases(&self) -> u64 {
        self.page_erases.iter().sum()
    }

    /// Page erases so far, per page.
    pub fn erases_per_page(&self) -> [u64; PAGES] {
        self.page_erases
    }

    /// Word writes that hit a word not fully erased.
    pub fn rewrites(&self) -> u64 {
        self.rewrites
    }

    /// Set the counters to zero.
    pub fn reset_counters(&mut self) {
        self.page_erases = [0; PAGES];
        self.writes = 0;
        self.rewrites = 0;
    }

    /// After `n` more word writes, cut the power (see the module docs).
    pub fn cut_power_after_words(&mut self, n: u64) {
        self.budget = Some(n);
    }

    /// Power back on; no cut armed.
    pub fn restore_power(&mut self) {
        self.budget = None;
        self.powered = true;
    }

    /// True while the power is off.
    pub fn power_cut(&self) -> bool {
        !self.powered
    }

    /// Every byte of the flash, page after page (to plant garbage).
    pub fn bytes_mut(&mut self) -> impl Iterator<Item = &mut u8> {
        self.pages.iter_mut().flatten()
    }

    fn byte_mut(&mut self, addr: usize) -> Option<&mut u8> {
        self.pages
            .get_mut(addr / PAGE_BYTES)?
            .get_mut(addr % PAGE_BYTES)
    }

    fn byte(&self, addr: usize) -> Option<u8> {
        self.pages
            .get(addr / PAGE_BYTES)?
            .get(addr % PAGE_BYTES)
            .copied()
    }

    /// Take one word of budget: false when the cut hits now.
    fn spend(&mut self) -> bool {
        match self.budget {
            None => true,
            Some(0) => {
                self.powered = false;
                false
            }
            Some(n) => {
                self.budget = Some(n - 1);
                true
            }
        }
    }
}

impl<const PAGES: usize, const PAGE_BYTES: usize, const WORD: usize> ErrorType
    for FakeFlash<PAGES, PAGE_BYTES, WORD>
{
    type Error = FakeError;
}

impl<const PAGES: usize, const PAGE_BYTES: usize, const WORD: usize> ReadNorFlash
    for FakeFlash<PAGES, PAGE_BYTES, WORD>
{
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let start = offset as usize;
        if start
            .checked_add(bytes.len())
            .is_none_or(|end| end > Self::size())
        {
            return Err(FakeError::OutOfBounds);
        }
        for (i, b) in bytes.iter_mut().enumerate() {
            *b = self.byte(start + i).ok_or(FakeError::OutOfBounds)?;
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        Self::size()
    }
}

impl<const PAGES: usize, const PAGE_BYTES: usize, const WORD: usize> NorFlash
    for FakeFlash<PAGES, PAGE_BYTES, WORD>
{
    const WRITE_SIZE: usize = WORD;
    const ERASE_SIZE: usize = PAGE_BYTES;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let (from, to) = (from as usize, to as usize);
        if !from.is_multiple_of(PAGE_BYTES) || !to.is_multiple_of(PAGE_BYTES) || from > to {
            return Err(FakeError::NotAligned);
        }
        if to > Self::size() {
            return Err(FakeError::OutOfBounds);
        }
        if !self.powered {
            return Err(FakeError::PowerCut);
        }
        for page in from / PAGE_BYTES..to / PAGE_BYTES {
            let cut = !self.spend();
            let Some(p) = self.pages.get_mut(page) else {
                return Err(FakeError::OutOfBounds);
            };
            if cut {
                // Interrupted erase: the first half of the page is erased.
                for b in p.iter_mut().take(PAGE_BYTES / 2) {
                    *b = 0xFF;
                }
                return Err(FakeError::PowerCut);
            }
            *p = [0xFF; PAGE_BYTES];
            if let Some(n) = self.page_erases.get_mut(page) {
                *n += 1;
            }
            // An erase costs no word of budget: undo the one `spend` took.
            if let Some(b) = self.budget.as_mut() {
                *b += 1;
            }
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let start = offset as usize;
        if !start.is_multiple_of(WORD) || !bytes.len().is_multiple_of(WORD) {
            return Err(FakeError::NotAligned);
        }
        if start
            .checked_add(bytes.len())
            .is_none_or(|end| end > Self::size())
        {
            return Err(FakeError::OutOfBounds);
        }
        if !self.powered {
            return Err(FakeError::PowerCut);
        }
        for (w, word) in bytes.chunks(WORD).enumerate() {
            let at = start + w * WORD;
            let cut = !self.spend();
            let erased = (0..WORD).all(|i| self.byte(at + i) == Some(0xFF));
            for (i, &b) in word.iter().enumerate() {
                // Cut: only the upper four bits of the word's first byte
                // get programmed.
                let b = match (cut, i) {
                    (false, _) => b,
                    (true, 0) => b | 0x0F,
                    (true, _) => break,
                };
                if let Some(cell) = self.byte_mut(at + i) {
                    *cell &= b;
                }
            }
            if cut {
                return Err(FakeError::PowerCut);
            }
            self.writes += 1;
            if !erased {
                self.rewrites += 1;
            }
        }
        Ok(())
    }
}

impl<const PAGES: usize, const PAGE_BYTES: usize, const WORD: usize> MultiwriteNorFlash
    for FakeFlash<PAGES, PAGE_BYTES, WORD>
{
}
