//! The emulated board's CAN port: CAN frames as SLCAN (Lawicel) lines on
//! a UART ([`SlcanPort`], feature `qemu` only).
//!
//! QEMU's netduinoplus2 models no bxCAN. The emulated board carries the
//! same frames a CAN controller would, in the SLCAN framing of
//! [`foc_canopen::slcan`] (host-tested there), on USART3, QEMU's third
//! `-serial` device; the host test bus (`foc-canbus --relay
//! tcp:HOST:PORT`) connects to it and makes it a participant of its
//! virtual bus. [`SlcanPort`] implements [`foc_core::hal::CanPort`] like
//! the ODrive's bxCAN port, with [`foc_canopen::CanFrame`] (an
//! [`embedded_can::Frame`]) as its frame type.
//!
//! - Receive: [`SlcanPort::on_interrupt`] (the task bound to
//!   `board::CAN_RX_IRQ`, `USART3`) moves the received bytes into the
//!   UART's ring; `receive` decodes them and returns the next 11-bit
//!   frame, `WouldBlock` once the ring is empty. A malformed line is
//!   counted and dropped (the decoder resynchronises at the next `\r`),
//!   a 29-bit frame ignored. A command line (`O`, `S8`, `V`, ...) gets an
//!   adapter's answer ([`slcan::encode_reply`]: `\r`, or the version line)
//!   so a tool can talk to the port directly; a malformed line gets none
//!   (a BEL would prefix the peer's next line).
//! - Transmit: a frame's whole line is queued, or nothing
//!   (`WouldBlock`) when the UART's transmit ring cannot take it or the
//!   port is not started; never blocks, never replaces a queued frame.
//! - Bus state: always [`BusState::ErrorActive`] (a UART has no fault
//!   confinement).
//!
//! ```ignore
//! let mut port = SlcanPort::new(CommandSerial::usart3(dp.USART3, cfg));
//! port.start(Bitrate::DEFAULT)?; // the rate is recorded only
//! // In the USART3 task:
//! port.on_interrupt();
//! while let Ok(frame) = port.receive() { /* node.on_frame(&frame, ..) */ }
//! ```

use crate::hw::serial::CommandSerial;
use crate::logic::can::Bitrate;
use foc_canopen::slcan::{self, Decoder, Event};
use foc_canopen::CanFrame;
use foc_core::hal::{BusState, CanPort};

/// Version answered to `V` / `v` (hardware 1, software 0).
const VERSION: (u8, u8) = (1, 0);
/// Serial number answered to `N`.
const SERIAL: &[u8; 4] = b"FOCQ";

/// Why the port failed (it never does: the type `embedded-can` asks for).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum SlcanError {}

impl embedded_can::Error for SlcanError {
    fn kind(&self) -> embedded_can::ErrorKind {
        match *self {}
    }
}

/// Counters of the port (wrapping).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
pub struct SlcanCounters {
    /// Frames received.
    pub rx_frames: u32,
    /// Malformed lines dropped.
    pub malformed: u32,
    /// 29-bit frames ignored.
    pub extended: u32,
    /// Command lines answered.
    pub commands: u32,
    /// Frames sent.
    pub tx_frames: u32,
}

/// CAN frames as SLCAN lines over a UART (module docs).
pub struct SlcanPort {
    serial: CommandSerial,
    decoder: Decoder,
    bitrate: Bitrate,
    started: bool,
    counters: SlcanCounters,
}

impl SlcanPort {
    /// The port over `serial` (set up, 8N1), not started: frames are
    /// received but not sent until [`Self::start`].
    pub fn new(serial: CommandSerial) -> Self {
        Self {
            serial,
            decoder: Decoder::new(),
            bitrate: Bitrate::DEFAULT,
            started: false,
            counters: SlcanCounters::default(),
        }
    }

    /// Join the bus: transmission allowed from now on. `bitrate` is only
    /// recorded (a UART line has no CAN bit timing); the same call as the
    /// bxCAN port's, which never fails here.
    pub fn start(&mut self, bitrate: Bitrate) -> Result<(), SlcanError> {
        self.bitrate = bitrate;
        self.started = true;
        Ok(())
    }

    /// The bit rate of the last [`Self::start`] (or the default).
    pub fn bitrate(&self) -> Bitrate {
        self.bitrate
    }

    /// Service the UART (received bytes into its ring, queued bytes out):
    /// call from the task bound to `board::CAN_RX_IRQ`, then `receive`
    /// until `WouldBlock`.
    pub fn on_interrupt(&mut self) {
        self.serial.on_interrupt();
    }

    /// The port's counters.
    pub fn counters(&self) -> SlcanCounters {
        self.counters
    }

    /// The UART's error and drop counters.
    pub fn serial_errors(&self) -> crate::hw::serial::SerialErrors {
        self.serial.errors()
    }

    /// Answer a command line as an adapter does (whole, or not at all).
    fn answer(&mut self, cmd: slcan::Cmd) {
        let mut line = [0u8; 8];
        let n = slcan::encode_reply(cmd, VERSION, SERIAL, 0, &mut line);
        let line = line.get(..n).unwrap_or(&[]);
        if self.serial.tx_free() >= line.len() {
            self.serial.write(line);
        }
    }
}

impl embedded_can::nb::Can for SlcanPort {
    type Frame = CanFrame;
    type Error = SlcanError;

    fn transmit(&mut self, frame: &CanFrame) -> nb::Result<Option<CanFrame>, SlcanError> {
        if !self.started {
            return Err(nb::Error::WouldBlock);
        }
        let mut line = [0u8; 27];
        let n = slcan::encode(frame, &mut line);
        let line = line.get(..n).unwrap_or(&[]);
        if self.serial.tx_free() < line.len() {
            return Err(nb::Error::WouldBlock);
        }
        self.serial.write(line);
        self.counters.tx_frames = self.counters.tx_frames.wrapping_add(1);
        Ok(None)
    }

    fn receive(&mut self) -> nb::Result<CanFrame, SlcanError> {
        // Bounded by the ring: every pass takes one byte out.
        while let Some(b) = self.serial.read_byte() {
            let c = &mut self.counters;
            match self.decoder.push(b) {
                None => {}
                Some(Event::Frame(f)) => {
                    c.rx_frames = c.rx_frames.wrapping_add(1);
                    return Ok(f);
                }
                Some(Event::Extended) => c.extended = c.extended.wrapping_add(1),
                Some(Event::Error) => c.malformed = c.malformed.wrapping_add(1),
                Some(Event::Command(cmd)) => {
                    c.commands = c.commands.wrapping_add(1);
                    self.answer(cmd);
                }
            }
        }
        Err(nb::Error::WouldBlock)
    }
}

impl CanPort for SlcanPort {
    /// Always error active: a UART has no fault confinement.
    fn bus_state(&self) -> BusState {
        BusState::ErrorActive
    }
}
