//! Bounds, alignment and NOR-programming rules of a store region: the pure
//! part of the `NorFlash` implementations (`hw::flash` on the real boards,
//! the semihosting file on the emulated board).
//!
//! A region is a range of *offsets* (relative to the flash base, as the
//! `embedded_storage::nor_flash` traits and the stm32f4xx-hal expect).
//! Every access must lie entirely inside it; an erase must also start and
//! end on an erase-unit boundary of the region.
//!
//! ```
//! use board_support::logic::nor_region::{check_access, check_erase, nor_program};
//! use embedded_storage::nor_flash::NorFlashErrorKind;
//! let region = 0x4_0000..0x8_0000;
//! assert_eq!(check_access(&region, 0x4_0000, 16), Ok(()));
//! assert_eq!(check_access(&region, 0x3_FFFF, 1), Err(NorFlashErrorKind::OutOfBounds));
//! assert_eq!(check_erase(&region, 0x4_0000, 0x6_0000, 0x2_0000), Ok(()));
//! assert_eq!(check_erase(&region, 0x4_0001, 0x6_0000, 0x2_0000), Err(NorFlashErrorKind::NotAligned));
//! let mut cell = [0xF0u8, 0xFF];
//! nor_program(&mut cell, &[0x3C, 0x00]);
//! assert_eq!(cell, [0x30, 0x00]);
//! ```

use core::ops::Range;
use embedded_storage::nor_flash::NorFlashErrorKind;

/// `len` bytes from `offset` lie inside `region` (an empty access at the
/// region's end is inside too). No overflow for any input.
pub fn check_access(region: &Range<u32>, offset: u32, len: usize) -> Result<(), NorFlashErrorKind> {
    let len = u32::try_from(len).map_err(|_| NorFlashErrorKind::OutOfBounds)?;
    let end = offset
        .checked_add(len)
        .ok_or(NorFlashErrorKind::OutOfBounds)?;
    if offset >= region.start && end <= region.end {
        Ok(())
    } else {
        Err(NorFlashErrorKind::OutOfBounds)
    }
}

/// `from..to` is a valid erase of `region`: inside it, `from <= to`, and
/// both ends on an `erase_size_bytes` boundary counted from the region's
/// start (`NotAligned` otherwise; bounds are checked first).
pub fn check_erase(
    region: &Range<u32>,
    from: u32,
    to: u32,
    erase_size_bytes: u32,
) -> Result<(), NorFlashErrorKind> {
    if from > to || from < region.start || to > region.end {
        return Err(NorFlashErrorKind::OutOfBounds);
    }
    if erase_size_bytes == 0 {
        return Err(NorFlashErrorKind::NotAligned);
    }
    let aligned = |x: u32| (x - region.start).is_multiple_of(erase_size_bytes);
    if aligned(from) && aligned(to) {
        Ok(())
    } else {
        Err(NorFlashErrorKind::NotAligned)
    }
}

/// NOR programming: a write can only clear bits, so the cell becomes
/// `existing & new` (only the first `min(len)` bytes are touched).
pub fn nor_program(existing: &mut [u8], new: &[u8]) {
    for (e, n) in existing.iter_mut().zip(new) {
        *e &= *n;
    }
}

/// The erased value of a NOR cell.
pub const ERASED_BYTE: u8 = 0xFF;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const F446: Range<u32> = 0x4_0000..0x8_0000;
    const SECTOR: u32 = 128 * 1024;

    #[test]
    fn access_bounds() {
        assert_eq!(check_access(&F446, 0x4_0000, 0), Ok(()));
        assert_eq!(check_access(&F446, 0x7_FFFF, 1), Ok(()));
        assert_eq!(check_access(&F446, 0x8_0000, 0), Ok(()));
        assert_eq!(
            check_access(&F446, 0x7_FFFF, 2),
            Err(NorFlashErrorKind::OutOfBounds)
        );
        assert_eq!(
            check_access(&F446, 0x0, 4),
            Err(NorFlashErrorKind::OutOfBounds)
        );
        assert_eq!(
            check_access(&F446, u32::MAX, 2),
            Err(NorFlashErrorKind::OutOfBounds)
        );
    }

    #[test]
    fn erase_rules() {
        assert_eq!(check_erase(&F446, 0x4_0000, 0x8_0000, SECTOR), Ok(()));
        assert_eq!(check_erase(&F446, 0x6_0000, 0x6_0000, SECTOR), Ok(()));
        assert_eq!(
            check_erase(&F446, 0x2_0000, 0x4_0000, SECTOR),
            Err(NorFlashErrorKind::OutOfBounds)
        );
        assert_eq!(
            check_erase(&F446, 0x6_0000, 0x4_0000, SECTOR),
            Err(NorFlashErrorKind::OutOfBounds)
        );
        assert_eq!(
            check_erase(&F446, 0x4_0000, 0x5_0000, SECTOR),
            Err(NorFlashErrorKind::NotAligned)
        );
        assert_eq!(
            check_erase(&F446, 0x4_0000, 0x6_0000, 0),
            Err(NorFlashErrorKind::NotAligned)
        );
        // The emulated board's 16 KiB pages.
        assert_eq!(check_erase(&(0..0x1_0000), 0x4000, 0xC000, 0x4000), Ok(()));
    }

    #[test]
    fn program_ands() {
        let mut cell = [0xFFu8; 4];
        nor_program(&mut cell, &[0x12, 0x34, 0x56, 0x78]);
        assert_eq!(cell, [0x12, 0x34, 0x56, 0x78]);
        // Bits never come back without an erase.
        nor_program(&mut cell, &[0xFF, 0xFF, 0x0F, 0xF0]);
        assert_eq!(cell, [0x12, 0x34, 0x06, 0x70]);
    }

    proptest! {
        #[test]
        fn access_inside_iff_checked(offset in any::<u32>(), len in 0usize..0x10_0000) {
            let ok = check_access(&F446, offset, len).is_ok();
            let end = offset as u64 + len as u64;
            prop_assert_eq!(ok, offset >= F446.start && end <= F446.end as u64);
        }

        #[test]
        fn program_only_clears(a in any::<[u8; 8]>(), b in any::<[u8; 8]>()) {
            let mut c = a;
            nor_program(&mut c, &b);
            for k in 0..8 {
                prop_assert_eq!(c[k] & !a[k], 0);
                prop_assert_eq!(c[k], a[k] & b[k]);
            }
        }
    }
}
