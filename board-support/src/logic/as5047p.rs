//! AS5047P magnetic angle sensor: SPI frames (ams AS5047P datasheet, SPI
//! interface section).
//!
//! 16-bit frames, MSB first, SPI mode 1 (CPOL = 0, CPHA = 1).
//!
//! Command frame: bit 15 `PARC` (even parity over bits 14..0), bit 14
//! `R/W` (1 = read), bits 13..0 address.
//!
//! Read data frame: bit 15 `PARD` (even parity over bits 14..0), bit 14
//! `EF` (error flag: the *previous* command failed or the chip reports an
//! error, see `ERRFL`), bits 13..0 data.
//!
//! The answer to a read command arrives during the *next* frame. A frame
//! with bad parity or the error flag set is an error, never an angle.
//!
//! ```
//! use board_support::logic::as5047p::{read_command, decode_response, ANGLECOM, Response};
//! assert_eq!(read_command(ANGLECOM), 0xFFFF);
//! assert_eq!(decode_response(0x2000 | 0x8000), Ok(Response::Data(0x2000))); // half a turn
//! ```

/// Address of `NOP` (reading it returns 0).
pub const NOP: u16 = 0x0000;
/// Address of `ERRFL` (error register; reading it clears it).
pub const ERRFL: u16 = 0x0001;
/// Address of `DIAAGC` (diagnostics and AGC).
pub const DIAAGC: u16 = 0x3FFC;
/// Address of `ANGLEUNC` (angle without dynamic angle error compensation).
pub const ANGLEUNC: u16 = 0x3FFE;
/// Address of `ANGLECOM` (angle with dynamic angle error compensation).
pub const ANGLECOM: u16 = 0x3FFF;

/// Counts per turn of the 14-bit angle.
pub const COUNTS_PER_TURN: u32 = 1 << 14;

/// Highest SPI clock [Hz] (datasheet: SPI timing, `1/tclk`).
pub const MAX_SPI_HZ: u32 = 10_000_000;
/// Shortest time from CSn falling to the first CLK rising edge [ns]
/// (datasheet: SPI timing, `tL`).
pub const T_L_NS: u32 = 350;
/// Shortest CSn high time between two frames [ns] (datasheet: SPI
/// timing, `tCSn`).
pub const T_CSN_NS: u32 = 350;
/// The wait after CSn falls, before the frame's clock starts [ns]: `tL`
/// with margin for a delay that rounds its cycle count down.
pub const CSN_SETUP_NS: u32 = T_L_NS + 50;

/// A decoded read data frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Response {
    /// The 14 data bits.
    Data(u16),
}

/// Why a frame is not usable.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum FrameError {
    /// Even parity over the 16 bits does not hold.
    Parity,
    /// Error flag (bit 14) set: read `ERRFL` to find out and clear it.
    ErrorFlag,
}

/// True when `x` has an even number of ones.
#[inline]
pub const fn even_parity_ok(x: u16) -> bool {
    x.count_ones().is_multiple_of(2)
}

/// Command frame reading register `addr` (14 bits), with parity.
pub const fn read_command(addr: u16) -> u16 {
    let f = 0x4000 | (addr & 0x3FFF);
    if f.count_ones() % 2 == 1 {
        f | 0x8000
    } else {
        f
    }
}

/// Command frame writing register `addr` (the data follows in the next frame).
pub const fn write_command(addr: u16) -> u16 {
    let f = addr & 0x3FFF;
    if f.count_ones() % 2 == 1 {
        f | 0x8000
    } else {
        f
    }
}

/// Decode a read data frame: parity first, then the error flag.
pub const fn decode_response(frame: u16) -> Result<Response, FrameError> {
    if !even_parity_ok(frame) {
        return Err(FrameError::Parity);
    }
    if frame & 0x4000 != 0 {
        return Err(FrameError::ErrorFlag);
    }
    Ok(Response::Data(frame & 0x3FFF))
}

/// The 14-bit angle as a fraction of a turn in the 32-bit angle format of
/// `foc_core::angle` (`2^32` = one turn).
#[inline]
pub const fn angle_bits(counts14: u16) -> u32 {
    ((counts14 & 0x3FFF) as u32) << 18
}

/// Bits of `ERRFL`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Errfl {
    /// Framing error.
    pub frerr: bool,
    /// Invalid command.
    pub invcomm: bool,
    /// Parity error (of a command the chip received).
    pub parerr: bool,
}

impl Errfl {
    /// Decode the 14 data bits of an `ERRFL` read.
    pub const fn from_data(d: u16) -> Self {
        Self {
            frerr: d & 1 != 0,
            invcomm: d & 2 != 0,
            parerr: d & 4 != 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn commands() {
        assert_eq!(read_command(ANGLECOM), 0xFFFF);
        assert_eq!(read_command(NOP), 0xC000);
        assert_eq!(read_command(ERRFL), 0x4001);
        assert_eq!(read_command(DIAAGC), 0xFFFC);
        assert_eq!(read_command(ANGLEUNC), 0x7FFE);
        for a in [NOP, ERRFL, DIAAGC, ANGLEUNC, ANGLECOM] {
            assert!(even_parity_ok(read_command(a)));
            assert!(even_parity_ok(write_command(a)));
        }
    }

    #[test]
    fn responses() {
        assert_eq!(decode_response(0x0000), Ok(Response::Data(0)));
        assert_eq!(decode_response(0x0001), Err(FrameError::Parity));
        // EF set, parity right.
        assert_eq!(decode_response(0xC000), Err(FrameError::ErrorFlag));
        // EF set, parity wrong: parity wins.
        assert_eq!(decode_response(0x4000), Err(FrameError::Parity));
        assert_eq!(angle_bits(0x2000), 0x8000_0000);
        assert_eq!(angle_bits(0x3FFF), 0xFFFC_0000);
        assert_eq!(
            Errfl::from_data(5),
            Errfl {
                frerr: true,
                invcomm: false,
                parerr: true
            }
        );
    }

    proptest! {
        #[test]
        fn any_single_bit_flip_is_caught(data in 0u16..0x4000, bit in 0u32..16) {
            let mut good = data;
            if !even_parity_ok(good) { good |= 0x8000; }
            prop_assert_eq!(decode_response(good), Ok(Response::Data(data)));
            let bad = good ^ (1 << bit);
            prop_assert!(decode_response(bad).is_err());
        }

        #[test]
        fn command_roundtrip(addr in 0u16..0x4000) {
            let c = read_command(addr);
            prop_assert!(even_parity_ok(c));
            prop_assert_eq!(c & 0x3FFF, addr);
            prop_assert!(c & 0x4000 != 0);
        }
    }
}
