//! The emulated board's configuration store and options, over semihosting.
//!
//! # Options: [`args`]
//!
//! Read once by `init` with `SYS_GET_CMDLINE` (parsed by
//! [`crate::logic::emu_args`], see there for the keys). QEMU joins the
//! `-semihosting-config ...,arg=A,arg=B` values with spaces, the first being
//! the program name; with no `arg=`, it hands back the kernel file name and
//! the `-append` string. A command line that does not fit the 512-byte
//! buffer (the host then answers -1) leaves every option at its default.
//!
//! # Store: [`StoreFlash`]
//!
//! A 64 KiB host file (`store=PATH`, relative to QEMU's working directory
//! with `target=native`) seen as NOR flash: four 16 KiB erase pages (as the
//! F405's 16 KiB sectors), offsets `0..0x1_0000` ([`STORE_RANGE`]). A write
//! ANDs into the bytes already there (read, AND, write back: bits only
//! clear), an erase writes 0xFF. The file is opened `"r+b"` (semihosting
//! mode 3) at `init`, created `"w+b"` (mode 7) when missing, and padded to
//! 64 KiB with 0xFF when short. Without `store=`, or if the host refuses
//! the file, every operation fails with `NorFlashErrorKind::Other` (the
//! firmware reports "no store"). Nothing is allocated: data moves through a
//! 64-byte stack buffer. Unlike the real flash, an erase does not stall
//! the emulated CPU for long (the host writes 16 KiB).
//!
//! ```ignore
//! let board = board::init(dp);
//! if board::args().store_path().is_none() { /* no store */ }
//! let mut store = board.store;
//! store.erase(0, 0x4000)?;
//! store.write(0, &[0x12, 0x34])?;
//! ```

use crate::logic::emu_args::EmuArgs;
use crate::logic::nor_region::{check_access, check_erase, nor_program, ERASED_BYTE};
use core::cell::Cell;
use core::ops::Range;
use cortex_m::interrupt::{free, Mutex};
use cortex_m_semihosting::{nr, syscall};
use embedded_storage::nor_flash::{
    ErrorType, MultiwriteNorFlash, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// Size of the store [bytes]: four 16 KiB pages.
pub const STORE_SIZE: u32 = 4 * PAGE_SIZE;
/// Erase unit [bytes] (the F405's small sectors).
pub const PAGE_SIZE: u32 = 16 * 1024;
/// The store's offsets.
pub const STORE_RANGE: Range<u32> = 0..STORE_SIZE;

/// Bytes moved per semihosting transfer (stack buffer).
const CHUNK: usize = 64;
/// Room for the semihosting command line [bytes].
const CMDLINE_CAPACITY: usize = 512;

// ---------------------------------------------------------------- options

/// The options, once `init` has read them.
static ARGS: Mutex<Cell<Option<&'static EmuArgs>>> = Mutex::new(Cell::new(None));
/// What [`args`] answers before `init` (or if the host has no command line).
static DEFAULT_ARGS: EmuArgs = EmuArgs::DEFAULT;

/// The emulated board's options from the semihosting command line (the
/// defaults before `init` has read them).
pub fn args() -> &'static EmuArgs {
    free(|cs| ARGS.borrow(cs).get()).unwrap_or(&DEFAULT_ARGS)
}

/// Read and keep the options (first call only; later calls return them).
pub(crate) fn init_args() -> &'static EmuArgs {
    if let Some(a) = free(|cs| ARGS.borrow(cs).get()) {
        return a;
    }
    let parsed = read_cmdline();
    match cortex_m::singleton!(: EmuArgs = parsed) {
        Some(stored) => {
            let stored: &'static EmuArgs = stored;
            free(|cs| ARGS.borrow(cs).set(Some(stored)));
            stored
        }
        None => args(),
    }
}

/// `SYS_GET_CMDLINE` into a stack buffer, parsed; defaults on any failure.
fn read_cmdline() -> EmuArgs {
    let mut buf = [0u8; CMDLINE_CAPACITY];
    // Parameter block: buffer address and size in, string length out.
    let mut block = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: semihosting call with a valid two-word block; the host writes
    // at most `buf.len()` bytes into `buf` and one word into `block[1]`,
    // both live, writable stack memory for the duration of the call.
    let status =
        unsafe { cortex_m_semihosting::syscall1(nr::GET_CMDLINE, block.as_mut_ptr() as usize) };
    if status != 0 {
        return EmuArgs::DEFAULT;
    }
    // The host wrote the length (without the NUL) into `block[1]`; the
    // call's `asm!` may write any memory whose address escaped, so this
    // plain read sees it.
    let len = block[1].min(buf.len());
    EmuArgs::parse(buf.get(..len).unwrap_or(&buf))
}

// ------------------------------------------------------------ semihosting

/// Result word of a semihosting call that failed (-1).
fn failed(r: usize) -> bool {
    (r as isize) < 0
}

/// `SYS_OPEN` of a NUL-terminated `path` in `mode`: the handle.
fn sys_open(path_with_nul: &[u8], mode: usize) -> Option<usize> {
    let len = path_with_nul.len().checked_sub(1)?;
    // SAFETY: three-word block; the host reads `len + 1` bytes of the path,
    // which lives for the call.
    let r = unsafe { syscall!(OPEN, path_with_nul.as_ptr(), mode, len) };
    if failed(r) {
        None
    } else {
        Some(r)
    }
}

/// `SYS_SEEK` to absolute `pos`.
fn sys_seek(handle: usize, pos: u32) -> Result<(), ()> {
    // SAFETY: two-word block, no memory handed over.
    let r = unsafe { syscall!(SEEK, handle, pos) };
    if r == 0 {
        Ok(())
    } else {
        Err(())
    }
}

/// `SYS_READ` of exactly `buf.len()` bytes.
fn sys_read(handle: usize, buf: &mut [u8]) -> Result<(), ()> {
    // SAFETY: the host writes at most `buf.len()` bytes into `buf`, which is
    // exclusively borrowed for the call. Returns the count NOT read.
    let r = unsafe { syscall!(READ, handle, buf.as_mut_ptr(), buf.len()) };
    if r == 0 {
        Ok(())
    } else {
        Err(())
    }
}

/// `SYS_WRITE` of all of `buf`.
fn sys_write(handle: usize, buf: &[u8]) -> Result<(), ()> {
    // SAFETY: the host reads `buf.len()` bytes of `buf`, live for the call.
    // Returns the count NOT written.
    let r = unsafe { syscall!(WRITE, handle, buf.as_ptr(), buf.len()) };
    if r == 0 {
        Ok(())
    } else {
        Err(())
    }
}

/// `SYS_FLEN`: file length [bytes].
fn sys_flen(handle: usize) -> Result<u32, ()> {
    // SAFETY: one-word block, no memory handed over.
    let r = unsafe { syscall!(FLEN, handle) };
    if failed(r) {
        Err(())
    } else {
        Ok(r as u32)
    }
}

/// Fill `from..to` of the file with 0xFF.
fn fill_erased(handle: usize, from: u32, to: u32) -> Result<(), ()> {
    let ones = [ERASED_BYTE; CHUNK];
    sys_seek(handle, from)?;
    let mut at = from;
    while at < to {
        let n = ((to - at) as usize).min(CHUNK);
        sys_write(handle, ones.get(..n).unwrap_or(&ones))?;
        at += n as u32;
    }
    Ok(())
}

// ------------------------------------------------------------------ store

/// Error of [`StoreFlash`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimStoreError {
    /// No `store=` argument, or the host could not open the file.
    NoStore,
    /// Outside [`STORE_RANGE`].
    OutOfBounds,
    /// Erase not on 16 KiB page boundaries.
    NotAligned,
    /// A semihosting seek, read or write failed.
    Host,
}

impl NorFlashError for SimStoreError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SimStoreError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            SimStoreError::NotAligned => NorFlashErrorKind::NotAligned,
            SimStoreError::NoStore | SimStoreError::Host => NorFlashErrorKind::Other,
        }
    }
}

impl From<NorFlashErrorKind> for SimStoreError {
    fn from(kind: NorFlashErrorKind) -> Self {
        match kind {
            NorFlashErrorKind::NotAligned => SimStoreError::NotAligned,
            _ => SimStoreError::OutOfBounds,
        }
    }
}

impl From<()> for SimStoreError {
    fn from((): ()) -> Self {
        SimStoreError::Host
    }
}

/// The emulated store: NOR flash semantics over a host file.
pub struct StoreFlash {
    /// Semihosting file handle; `None`: no store.
    handle: Option<usize>,
}

impl StoreFlash {
    /// Open (or create, padded with 0xFF to [`STORE_SIZE`]) the file named
    /// by `args`; a store that fails every operation without `store=` or
    /// when the host refuses.
    pub fn open(args: &EmuArgs) -> Self {
        let handle = args.store_path_with_nul().and_then(|path| {
            let h = sys_open(path, nr::open::RW_BINARY)
                .or_else(|| sys_open(path, nr::open::RW_TRUNC_BINARY))?;
            let len = sys_flen(h).ok()?;
            if len < STORE_SIZE {
                fill_erased(h, len, STORE_SIZE).ok()?;
            }
            Some(h)
        });
        Self { handle }
    }

    /// True when a host file backs the store.
    pub fn is_present(&self) -> bool {
        self.handle.is_some()
    }

    fn handle(&self) -> Result<usize, SimStoreError> {
        self.handle.ok_or(SimStoreError::NoStore)
    }
}

impl ErrorType for StoreFlash {
    type Error = SimStoreError;
}

impl ReadNorFlash for StoreFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let h = self.handle()?;
        check_access(&STORE_RANGE, offset, bytes.len())?;
        if bytes.is_empty() {
            return Ok(());
        }
        sys_seek(h, offset)?;
        sys_read(h, bytes)?;
        Ok(())
    }

    fn capacity(&self) -> usize {
        STORE_SIZE as usize
    }
}

impl NorFlash for StoreFlash {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = PAGE_SIZE as usize;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let h = self.handle()?;
        check_erase(&STORE_RANGE, from, to, PAGE_SIZE)?;
        fill_erased(h, from, to)?;
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let h = self.handle()?;
        check_access(&STORE_RANGE, offset, bytes.len())?;
        let mut at = offset;
        for part in bytes.chunks(CHUNK) {
            let mut cell = [0u8; CHUNK];
            // (`chunks(CHUNK)`: never longer than the cell.)
            let cell = cell
                .get_mut(..part.len())
                .ok_or(SimStoreError::OutOfBounds)?;
            sys_seek(h, at)?;
            sys_read(h, cell)?;
            nor_program(cell, part);
            sys_seek(h, at)?;
            sys_write(h, cell)?;
            at += part.len() as u32;
        }
        Ok(())
    }
}

/// Bits can be cleared again without an erase, as on the STM32F4 flash.
impl MultiwriteNorFlash for StoreFlash {}
