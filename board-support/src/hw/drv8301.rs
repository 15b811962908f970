//! DRV8301 configuration over SPI at init, status read-back.
//!
//! Uses an embedded-hal 1.0 `SpiBus` (mode 1, <= 10 MHz; 8-bit words, two
//! per 16-bit frame) and a chip-select `OutputPin` held low for each frame.
//! EN_GATE must be high (and the DRV8301 given time to start) before.

use crate::logic::drv8301::{
    decode_answer, read_frame, write_frame, Control1, Control2, Register, Status,
};
use embedded_hal::digital::OutputPin;
use embedded_hal::spi::SpiBus;

/// DRV8301 communication or configuration error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum Drv8301Error {
    /// SPI or chip-select error.
    Bus,
    /// The chip reported a frame fault.
    FrameFault,
    /// A control register read back differs from what was written
    /// (`(register, expected, read)`).
    Mismatch(u8, u16, u16),
}

/// DRV8301 on a bus with its own chip select.
pub struct Drv8301<SPI, CS> {
    spi: SPI,
    cs: CS,
    /// Core cycles to keep nSCS high between frames.
    gap_cycles: u32,
}

impl<SPI: SpiBus<u8>, CS: OutputPin> Drv8301<SPI, CS> {
    /// Driver on `spi` with chip select `cs` (set high here).
    pub fn new(spi: SPI, mut cs: CS, gap_cycles: u32) -> Self {
        let _ = cs.set_high();
        Self {
            spi,
            cs,
            gap_cycles,
        }
    }

    /// One 16-bit frame; returns the word clocked out by the DRV8301 (the
    /// answer to the *previous* frame).
    pub fn frame(&mut self, word: u16) -> Result<u16, Drv8301Error> {
        let tx = word.to_be_bytes();
        let mut rx = [0u8; 2];
        self.cs.set_low().map_err(|_| Drv8301Error::Bus)?;
        let r = self
            .spi
            .transfer(&mut rx, &tx)
            .and_then(|_| self.spi.flush());
        let c = self.cs.set_high();
        cortex_m::asm::delay(self.gap_cycles);
        r.map_err(|_| Drv8301Error::Bus)?;
        c.map_err(|_| Drv8301Error::Bus)?;
        Ok(u16::from_be_bytes(rx))
    }

    /// Read register `reg` (two frames).
    pub fn read(&mut self, reg: Register) -> Result<u16, Drv8301Error> {
        self.frame(read_frame(reg))?;
        let a = decode_answer(self.frame(read_frame(Register::Status1))?);
        if a.frame_fault {
            return Err(Drv8301Error::FrameFault);
        }
        Ok(a.data)
    }

    /// Write both control registers and verify them by reading back.
    pub fn configure(&mut self, c1: Control1, c2: Control2) -> Result<(), Drv8301Error> {
        // GATE_RESET is self-clearing: compare without it.
        let want1 = Control1 {
            gate_reset: false,
            ..c1
        }
        .bits();
        self.frame(write_frame(Register::Control1, c1.bits()))?;
        self.frame(write_frame(Register::Control2, c2.bits()))?;
        let got1 = self.read(Register::Control1)?;
        let got2 = self.read(Register::Control2)?;
        if got1 != want1 {
            return Err(Drv8301Error::Mismatch(2, want1, got1));
        }
        if got2 != c2.bits() {
            return Err(Drv8301Error::Mismatch(3, c2.bits(), got2));
        }
        Ok(())
    }

    /// Read and decode both status registers (reading status 1 also clears
    /// its latched fault bits once their cause is gone).
    pub fn status(&mut self) -> Result<Status, Drv8301Error> {
        let s1 = self.read(Register::Status1)?;
        let s2 = self.read(Register::Status2)?;
        Ok(Status::decode(s1, s2))
    }

    /// Release bus and chip select.
    pub fn release(self) -> (SPI, CS) {
        (self.spi, self.cs)
    }
}
