//! The command UART: a small non-blocking, interrupt-driven USART driver.
//!
//! Register level (PAC), because QEMU's netduinoplus2 needs it (no RCC
//! model, no HAL clock set-up) and because the driver is tiny. The USART
//! register layout used here (SR, DR, BRR, CR1, CR2, CR3) is identical on
//! the STM32F405/F446/F401: RM0090 section 30.6, RM0390 section 25.6,
//! RM0368 section 19.6.
//!
//! - Receive: the RXNE interrupt moves each byte into a small RX ring;
//!   [`CommandSerial::read_byte`] takes them out.
//! - Transmit: [`CommandSerial::write`] queues bytes into a TX ring and
//!   enables the TXE interrupt, which drains the ring one byte per
//!   interrupt and disables itself when the ring is empty.
//! - Errors: overrun, framing, noise and parity flags are cleared by the
//!   SR-then-DR read sequence and counted ([`SerialErrors`]); a byte with a
//!   framing or parity error is dropped. Nothing here panics or blocks.
//!
//! Call [`CommandSerial::on_interrupt`] from the task bound to the
//! board's `SERIAL_IRQ`. Every method takes `&mut self`: keep the driver in
//! one place (the RTIC app shares it between tasks of the same priority).
//!
//! ```ignore
//! // In the SERIAL_IRQ task:
//! serial.on_interrupt();
//! while let Some(b) = serial.read_byte() {
//!     // feed the protocol decoder
//! }
//! let sent = serial.write(b"reply");
//! ```

pub use crate::logic::serial::brr_value;
use crate::logic::serial::Ring;
use crate::pac;

/// Size of the receive ring [bytes] (the task empties it at every interrupt).
pub const RX_CAPACITY: usize = 64;
/// Size of the transmit ring [bytes] (several telemetry frames).
pub const TX_CAPACITY: usize = 512;

/// USART status register bits (RM0090 30.6.1, USART_SR).
mod sr {
    pub const PE: u16 = 1 << 0;
    pub const FE: u16 = 1 << 1;
    pub const NF: u16 = 1 << 2;
    pub const ORE: u16 = 1 << 3;
    pub const RXNE: u16 = 1 << 5;
    pub const TXE: u16 = 1 << 7;
}

/// USART control register 1 bits (RM0090 30.6.4, USART_CR1).
mod cr1 {
    pub const RE: u16 = 1 << 2;
    pub const TE: u16 = 1 << 3;
    pub const RXNEIE: u16 = 1 << 5;
    pub const TXEIE: u16 = 1 << 7;
    pub const UE: u16 = 1 << 13;
}

/// Error and drop counters (wrapping).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SerialErrors {
    /// Receiver overruns (a byte arrived before the previous was read).
    pub overrun: u32,
    /// Framing errors (byte dropped).
    pub framing: u32,
    /// Noise detected (byte kept).
    pub noise: u32,
    /// Parity errors (byte dropped; parity is off, so only on line garbage).
    pub parity: u32,
    /// Received bytes dropped because the RX ring was full.
    pub rx_dropped: u32,
    /// Bytes refused by [`CommandSerial::write`] because the TX ring was full.
    pub tx_dropped: u32,
}

/// Line settings: 8 data bits, no parity, 1 stop bit at this baud rate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SerialConfig {
    /// Baud rate [bit/s].
    pub baud: u32,
    /// Clock of the USART's APB bus [Hz] (PCLK1 for USART2).
    pub pclk_hz: u32,
}

/// The command UART (one USART, 8N1, interrupt driven).
pub struct CommandSerial {
    /// Base address of the USART's register block.
    base: usize,
    rx: Ring<RX_CAPACITY>,
    tx: Ring<TX_CAPACITY>,
    errors: SerialErrors,
}

impl CommandSerial {
    /// USART2 on PA2 (TX) / PA3 (RX), AF7, the same on every board here:
    /// pins, clock enable and reset through the HAL (RCC_APB1ENR.USART2EN,
    /// RM0090 7.3.13 / RM0390 6.3.13 / RM0368 6.3.11), then [`Self::usart2`].
    pub fn usart2_on_pa2_pa3(
        usart: pac::USART2,
        pa2: stm32f4xx_hal::gpio::PA2,
        pa3: stm32f4xx_hal::gpio::PA3,
        rcc: &mut stm32f4xx_hal::rcc::Rcc,
        baud: u32,
    ) -> Self {
        use stm32f4xx_hal::rcc::{Enable, Reset};
        let _tx = pa2.into_alternate::<7>();
        let _rx = pa3.into_alternate::<7>().internal_pull_up(true);
        pac::USART2::enable(rcc);
        pac::USART2::reset(rcc);
        Self::usart2(
            usart,
            SerialConfig {
                baud,
                pclk_hz: rcc.clocks.pclk1().raw(),
            },
        )
    }

    /// Set up USART2 (clock already enabled and pins already in their
    /// alternate function by the board): 8N1 at `cfg.baud`, receiver and
    /// transmitter on, RXNE interrupt enabled. The NVIC line is left to
    /// the RTIC app.
    pub fn usart2(_usart: pac::USART2, cfg: SerialConfig) -> Self {
        Self::at(pac::USART2::ptr() as usize, cfg)
    }

    /// Set up USART1 (RM0090 §2.3 memory map: 0x4001_1000, on APB2; the
    /// same register block, RM0090 §30.6), clock already enabled
    /// (`RCC_APB2ENR.USART1EN`, RM0090 §7.3.14): 8N1 at `cfg.baud`,
    /// receiver and transmitter on. The emulated board polls it as its
    /// instrument port (QEMU's first `-serial` device); its NVIC line stays
    /// masked.
    #[cfg(feature = "qemu")]
    pub fn usart1(_usart: pac::USART1, cfg: SerialConfig) -> Self {
        Self::at(pac::USART1::ptr() as usize, cfg)
    }

    /// Set up USART3 (RM0090 §2.3 memory map: 0x4000_4800, on APB1; the
    /// same register block as USART2, RM0090 §30.6), clock already enabled
    /// (`RCC_APB1ENR.USART3EN`, RM0090 §7.3.13) and pins already in their
    /// alternate function by the board: 8N1 at `cfg.baud` (`pclk_hz` is
    /// PCLK1), receiver and transmitter on, RXNE interrupt enabled (the
    /// `USART3` NVIC line is left to the RTIC app). The emulated board
    /// carries its CAN frames on it (QEMU's third `-serial` device). Not
    /// on the STM32F401, which has no USART3 (RM0368 §19: USART1, 2, 6).
    #[cfg(not(feature = "nucleo-f401re-ihm07m1"))]
    pub fn usart3(_usart: pac::USART3, cfg: SerialConfig) -> Self {
        Self::at(pac::USART3::ptr() as usize, cfg)
    }

    /// The driver of the USART register block at `base` (a constructor
    /// took ownership of that peripheral), configured.
    fn at(base: usize, cfg: SerialConfig) -> Self {
        let mut s = Self {
            base,
            rx: Ring::new(),
            tx: Ring::new(),
            errors: SerialErrors::default(),
        };
        s.configure(cfg);
        s
    }

    fn regs(&self) -> &pac::usart1::RegisterBlock {
        // SAFETY: `base` is the address of a USART register block (set from
        // the PAC's pointer in the constructor, which took ownership of the
        // peripheral), valid for the whole program.
        unsafe { &*(self.base as *const pac::usart1::RegisterBlock) }
    }

    fn configure(&mut self, cfg: SerialConfig) {
        let r = self.regs();
        // CR1 = 0: USART off while it is configured (RM0090 30.6.4).
        r.cr1().write(|w| unsafe { w.bits(0) });
        // CR2: STOP = 00, one stop bit; no clock output (RM0090 30.6.5).
        r.cr2().write(|w| unsafe { w.bits(0) });
        // CR3: no flow control, no DMA, no error interrupt (RM0090 30.6.6).
        r.cr3().write(|w| unsafe { w.bits(0) });
        // BRR: baud rate, oversampling by 16 (RM0090 30.6.3, 30.3.4).
        r.brr()
            .write(|w| unsafe { w.bits(brr_value(cfg.pclk_hz, cfg.baud)) });
        // CR1: M = 0 (8 bits), PCE = 0 (no parity), TE, RE, RXNEIE, then
        // UE last (RM0090 30.6.4; 30.3.2 and 30.3.3 enabling sequences).
        let on = cr1::TE | cr1::RE | cr1::RXNEIE;
        r.cr1().write(|w| unsafe { w.bits(on) });
        r.cr1().write(|w| unsafe { w.bits(on | cr1::UE) });
        // Clear anything latched before UE (SR read then DR read,
        // RM0090 30.6.1).
        let _ = r.sr().read().bits();
        let _ = r.dr().read().bits();
    }

    /// Service the USART: take a received byte (counting and clearing
    /// errors), and move one queued byte to the transmitter if it is
    /// empty. Call from the `SERIAL_IRQ` task.
    pub fn on_interrupt(&mut self) {
        // Bounded: at most a few bytes can be pending at once.
        for _ in 0..4 {
            let r = self.regs();
            // SR read first: the SR-then-DR sequence clears ORE, NF, FE, PE
            // and RXNE (RM0090 30.6.1).
            let status = r.sr().read().bits();
            let errs = status & (sr::ORE | sr::FE | sr::NF | sr::PE);
            if status & sr::RXNE == 0 && errs == 0 {
                break;
            }
            // DR read (RM0090 30.6.2): the received byte.
            let byte = (r.dr().read().bits() & 0xFF) as u8;
            let e = &mut self.errors;
            if errs & sr::ORE != 0 {
                e.overrun = e.overrun.wrapping_add(1);
            }
            if errs & sr::NF != 0 {
                e.noise = e.noise.wrapping_add(1);
            }
            if errs & sr::FE != 0 {
                e.framing = e.framing.wrapping_add(1);
            }
            if errs & sr::PE != 0 {
                e.parity = e.parity.wrapping_add(1);
            }
            let keep = status & sr::RXNE != 0 && errs & (sr::FE | sr::PE) == 0;
            if keep && !self.rx.push(byte) {
                self.errors.rx_dropped = self.errors.rx_dropped.wrapping_add(1);
            }
        }
        self.pump_tx();
    }

    /// Move queued bytes to the transmitter while it is empty; TXE
    /// interrupt on while bytes remain, off when the ring is empty.
    fn pump_tx(&mut self) {
        // Bounded: one byte per empty-transmitter (QEMU's transmitter is
        // always empty, a real one takes one byte per interrupt).
        for _ in 0..TX_CAPACITY {
            // SR.TXE (RM0090 30.6.1): the data register can take a byte.
            if self.regs().sr().read().bits() & sr::TXE == 0 {
                break;
            }
            match self.tx.pop() {
                // DR write (RM0090 30.6.2) starts the transmission.
                Some(b) => {
                    self.regs().dr().write(|w| unsafe { w.bits(u16::from(b)) });
                }
                None => break,
            }
        }
        let want = !self.tx.is_empty();
        let r = self.regs();
        // CR1.TXEIE (RM0090 30.6.4): read-modify-write, only ever from
        // the one priority that owns this driver.
        let c = r.cr1().read().bits();
        let new = if want {
            c | cr1::TXEIE
        } else {
            c & !cr1::TXEIE
        };
        if new != c {
            r.cr1().write(|w| unsafe { w.bits(new) });
        }
    }

    /// The next received byte, if any.
    pub fn read_byte(&mut self) -> Option<u8> {
        self.rx.pop()
    }

    /// Queue `bytes` for transmission; returns how many were queued (the
    /// rest did not fit and is counted in [`SerialErrors::tx_dropped`]).
    pub fn write(&mut self, bytes: &[u8]) -> usize {
        let mut n = 0;
        for &b in bytes {
            if !self.tx.push(b) {
                break;
            }
            n += 1;
        }
        let dropped = (bytes.len() - n) as u32;
        self.errors.tx_dropped = self.errors.tx_dropped.wrapping_add(dropped);
        if n > 0 {
            self.pump_tx();
        }
        n
    }

    /// Free space in the transmit ring [bytes]: a whole frame that fits
    /// can be queued without being cut.
    pub fn tx_free(&self) -> usize {
        self.tx.free()
    }

    /// Error and drop counters.
    pub fn errors(&self) -> SerialErrors {
        self.errors
    }
}
