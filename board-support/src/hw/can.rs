//! bxCAN (CAN1) as a [`foc_core::hal::CanPort`]: the ODrive v3's CAN
//! port (feature `odrive-v3` only; the other boards have none, see the
//! crate docs).
//!
//! Built on stm32f4xx-hal 0.23's `can` module (clock enable and reset,
//! pins) and the `bxcan` 0.8 crate it implements (`bxcan::Instance` for
//! `stm32f4xx_hal::can::Can<CAN1>`): configuration, filters and the
//! transmit mailboxes are bxcan's. bxcan 0.8 implements `embedded-can`
//! 0.4 (`embedded_can::nb::Can` for `bxcan::Can`, `embedded_can::Frame`
//! for `bxcan::Frame`, `embedded_can::Error` for its `OverrunError`), the
//! version foc-core's trait is written against.
//!
//! Two things are register-level here (PAC, RM0090 §32.9):
//!
//! - **Receive** (FIFO 0): bxcan 0.8's `receive` copies the mailbox's
//!   4-bit DLC (`CAN_RDTxR.DLC`) into the frame's length unchecked, and
//!   its `Data` then slices up to 15 bytes out of 8 (`Frame::dlc` and
//!   `Frame::data` would panic). A DLC of 9 to 15 is legal on the wire
//!   (it means 8 bytes, ISO 11898-1); whether the bxCAN stores it
//!   unclamped is not checked here (RM0090 §32.9.3 documents 0 to 8), so
//!   this port's `receive` (`embedded_can::nb::Can`) reads the FIFO 0
//!   mailbox itself and clamps the DLC to 8
//!   ([`crate::logic::can::RxFrame`], host-tested): no frame from the bus
//!   can panic the drive.
//! - **Bus state**: `CAN_ESR` (BOFF, EPVF), which bxcan does not expose.
//!
//! # Behaviour
//!
//! - Built asleep ([`CanBus::can1_on_pb8_pb9`]): pins, clock, filters
//!   and the FIFO 0 interrupt set up, but the controller stays off the
//!   bus until [`CanBus::start`] with the bit rate (the stored node
//!   settings' rate is known only after the store is read; a node at the
//!   wrong rate would disturb the bus with error frames).
//! - Bit timing from `crate::logic::can` (14 tq, 85.7 %; 1 Mbit/s =
//!   `CAN_BTR` `0x001A_0002` at APB1 = 42 MHz).
//! - Automatic bus-off management on: bxcan's `enable_non_blocking` sets
//!   `CAN_MCR.ABOM` (RM0090 §32.9.2) each time the controller is started,
//!   so after bus-off the controller rejoins by itself once it has seen
//!   128 occurrences of 11 recessive bits (RM0090 §32.7.6). Automatic
//!   retransmission on (`NART` = 0).
//! - Filter bank 0, 32-bit mask mode, accepts every standard identifier
//!   (data and remote frames; extended identifiers are rejected: CANopen's
//!   pre-defined connection set uses 11-bit identifiers) into FIFO 0
//!   (RM0090 §32.7.4).
//! - `CAN_IER.FMPIE0` set: the `CAN1_RX0` interrupt is pending while
//!   FIFO 0 holds a frame; the task bound to it must call `receive` until
//!   `WouldBlock`. The NVIC line is left to the RTIC app.
//! - **Transmit** (register level too): a queue of
//!   [`crate::logic::can::TX_QUEUE`] frames, moved into the three
//!   mailboxes as they free up (at every `transmit` and `poll`, oldest
//!   first, `CAN_MCR.TXFP` = 1 so the bus sees them in that order).
//!   bxcan 0.8's `transmit` is not used: it refuses a frame whose
//!   identifier is not more urgent than every pending one even with a
//!   free mailbox, which drops most of a node's burst (four TPDOs after a
//!   statusword change). `WouldBlock` while the queue is full, stopped or
//!   bus-off; at bus-off `poll` drops the queue and aborts the mailboxes,
//!   so no stale frame goes out after the recovery.
//!
//! ```ignore
//! // After the store was read:
//! board.can.start(Bitrate::from_kbit(rec.bitrate_kbit).unwrap_or(Bitrate::DEFAULT))?;
//! // In the task bound to board::CAN_RX_IRQ:
//! loop {
//!     match can.receive() {
//!         Ok(frame) => node.on_frame(&frame),
//!         Err(nb::Error::Other(CanError::Overrun)) => node.on_overrun(),
//!         Err(_) => break,
//!     }
//! }
//! ```

use crate::logic::can::{
    bus_state, esr, free_mailboxes, BitTiming, Bitrate, RxFrame, TxQueue, TxWords, TXRQ,
};
use crate::pac;
use bxcan::filter::Mask32;
use bxcan::{Fifo, Interrupt, StandardId};
use foc_core::hal::{BusState, CanPort};
use stm32f4xx_hal::gpio::{Speed, PB8, PB9};

/// The frame type of the port (`bxcan::Frame`, an `embedded_can::Frame`).
pub type Frame = bxcan::Frame;

type Inner = bxcan::Can<stm32f4xx_hal::can::Can<pac::CAN1>>;

/// Why the port failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum CanError {
    /// A received frame was lost: FIFO 0 was full (`CAN_RF0R.FOVR0`).
    /// The frames still in the FIFO are received next.
    Overrun,
    /// The APB1 clock does not divide exactly into the bit rate
    /// ([`BitTiming::for_bitrate`]): the controller was not (re)started.
    BitTiming,
    /// A mailbox held an identifier `embedded-can` refuses (cannot happen
    /// with the register layout; the frame was dropped).
    Malformed,
}

impl embedded_can::Error for CanError {
    fn kind(&self) -> embedded_can::ErrorKind {
        match self {
            CanError::Overrun => embedded_can::ErrorKind::Overrun,
            CanError::BitTiming | CanError::Malformed => embedded_can::ErrorKind::Other,
        }
    }
}

/// CAN1 as a [`CanPort`] (module docs).
pub struct CanBus {
    can: Inner,
    pclk1_hz: u32,
    bitrate: Bitrate,
    started: bool,
    /// Frames waiting for a free mailbox, oldest first.
    txq: TxQueue,
}

impl CanBus {
    /// CAN1 on PB8 (RX) / PB9 (TX), AF9 (the ODrive v3's transceiver):
    /// clock enable and reset through the HAL (`RCC_APB1ENR.CAN1EN`,
    /// RM0090 §7.3.13), pins at high speed (`GPIOx_OSPEEDR`, RM0090
    /// §8.4.3, as the ODrive firmware sets them), bit timing for
    /// [`Bitrate::DEFAULT`], filters, FIFO 0 interrupt; left asleep (off
    /// the bus) until [`Self::start`].
    pub fn can1_on_pb8_pb9(
        can1: pac::CAN1,
        pb8: PB8,
        pb9: PB9,
        rcc: &mut stm32f4xx_hal::rcc::Rcc,
    ) -> Self {
        let pclk1_hz = rcc.clocks.pclk1().raw();
        let mut rx = pb8.into_alternate::<9>();
        let mut tx = pb9.into_alternate::<9>();
        rx.set_speed(Speed::High);
        tx.set_speed(Speed::High);
        let hal_can = stm32f4xx_hal::can::Can::new(can1, (tx, rx), rcc);
        // An inexact default rate leaves the reset timing in place; `start`
        // refuses it the same way (the board checks its clock at compile
        // time).
        let btr = BitTiming::for_bitrate(pclk1_hz, Bitrate::DEFAULT).and_then(|t| t.btr());
        let mut builder = bxcan::Can::builder(hal_can).set_automatic_retransmit(true);
        if let Some(btr) = btr {
            builder = builder.set_bit_timing(btr);
        }
        let mut can = builder.leave_disabled();
        // Bank 0 of the 28 shared with CAN2 (CAN1 owns banks 0..14 after
        // reset, CAN_FMR.CAN2SB = 14, RM0090 §32.9.4).
        can.modify_filters().enable_bank(
            0,
            Fifo::Fifo0,
            Mask32::frames_with_std_id(StandardId::ZERO, StandardId::ZERO),
        );
        can.enable_interrupt(Interrupt::Fifo0MessagePending);
        Self {
            can,
            pclk1_hz,
            bitrate: Bitrate::DEFAULT,
            started: false,
            txq: TxQueue::new(),
        }
    }

    /// Join the bus at `bitrate`: bit timing set (in initialisation mode,
    /// RM0090 §32.4.1), then the controller leaves sleep mode with
    /// `ABOM` set and synchronises by itself once it sees 11 recessive
    /// bits (non-blocking: a silent or stuck bus never hangs the caller).
    /// Also re-times a running port (a frame in transfer completes
    /// first). [`CanError::BitTiming`] when the clock does not divide
    /// into the rate: the port is then stopped.
    pub fn start(&mut self, bitrate: Bitrate) -> Result<(), CanError> {
        let Some(btr) = BitTiming::for_bitrate(self.pclk1_hz, bitrate).and_then(|t| t.btr()) else {
            self.stop();
            return Err(CanError::BitTiming);
        };
        self.can
            .modify_config()
            .set_bit_timing(btr)
            .set_automatic_retransmit(true)
            .leave_disabled();
        // CAN_MCR.TXFP = 1: the mailboxes go out in the order they were
        // requested, not by identifier (RM0090 §32.9.2, §32.7.1), so the
        // queue's order is the bus's. Set while asleep, before joining.
        // SAFETY: a read-modify-write of CAN1_MCR's TXFP bit only; `self`
        // owns CAN1.
        unsafe {
            (*pac::CAN1::ptr())
                .mcr()
                .modify(|r, w| w.bits(r.bits() | MCR_TXFP));
        }
        // Sets CAN_MCR.ABOM and clears SLEEP (bxcan 0.8,
        // `Can::enable_non_blocking`); WouldBlock only means "joining".
        let _ = self.can.enable_non_blocking();
        self.bitrate = bitrate;
        self.started = true;
        Ok(())
    }

    /// Leave the bus (sleep mode, RM0090 §32.4.3): nothing is sent or
    /// acknowledged until [`Self::start`].
    pub fn stop(&mut self) {
        self.can.sleep();
        self.started = false;
    }

    /// True between [`Self::start`] and [`Self::stop`].
    pub fn is_started(&self) -> bool {
        self.started
    }

    /// The bit rate set by the last [`Self::start`] (or the default).
    pub fn bitrate(&self) -> Bitrate {
        self.bitrate
    }

    /// Transmit and receive error counters `(TEC, REC)` (`CAN_ESR`; TEC's
    /// low 8 bits).
    pub fn error_counters(&self) -> (u8, u8) {
        let e = read_esr();
        (esr::tec(e), esr::rec(e))
    }
}

/// `CAN_MCR.TXFP`: transmit FIFO priority (by request order).
const MCR_TXFP: u32 = 1 << 2;
/// `CAN_TSR.ABRQ0..2`: abort the request of mailbox 0, 1, 2.
const TSR_ABRQ: u32 = (1 << 7) | (1 << 15) | (1 << 23);

impl CanBus {
    /// Move queued frames into the free mailboxes, oldest first
    /// (register level: bxcan 0.8's `transmit` refuses a frame whose
    /// identifier is not more urgent than every pending one, even with a
    /// free mailbox, which would drop most of a CANopen node's burst).
    fn pump(&mut self) {
        // SAFETY: CAN1's transmit status and mailbox registers (RM0090
        // §32.9.2 CAN_TSR, §32.9.3 CAN_TIxR/TDTxR/TDLxR/TDHxR); `self`
        // owns CAN1 and bxcan's transmit is never called. A mailbox is
        // written only while TSR says it is empty, TIxR (with TXRQ) last.
        let can = unsafe { &*pac::CAN1::ptr() };
        let tsr = can.tsr().read().bits();
        for i in free_mailboxes(tsr) {
            let Some(w) = self.txq.pop_front() else {
                return;
            };
            let mb = can.tx(i);
            mb.tdtr().write(|x| unsafe { x.bits(w.tdtr) });
            mb.tdlr().write(|x| unsafe { x.bits(w.tdlr) });
            mb.tdhr().write(|x| unsafe { x.bits(w.tdhr) });
            mb.tir().write(|x| unsafe { x.bits(w.tir | TXRQ) });
        }
    }

    /// Bus-off: drop the queue and abort the mailboxes' requests, so no
    /// stale frame goes out after the recovery.
    fn flush(&mut self) {
        self.txq.clear();
        // SAFETY: CAN_TSR's ABRQx bits are rs (set to abort); the other
        // bits written 0 have no effect (rc_w1 / read-only), RM0090
        // §32.9.2. `self` owns CAN1.
        unsafe { (*pac::CAN1::ptr()).tsr().write(|w| w.bits(TSR_ABRQ)) };
    }
}

/// `CAN_ESR` of CAN1.
fn read_esr() -> u32 {
    // SAFETY: a read of CAN1_ESR (RM0090 §32.9.2), no side effect; the
    // only writable field (LEC) is never written here.
    unsafe { (*pac::CAN1::ptr()).esr().read().bits() }
}

impl embedded_can::nb::Can for CanBus {
    type Frame = Frame;
    type Error = CanError;

    /// Queue `frame` (in order; `WouldBlock` when the queue is full, the
    /// port stopped or bus-off) and fill the free mailboxes.
    fn transmit(&mut self, frame: &Frame) -> nb::Result<Option<Frame>, CanError> {
        use embedded_can::Frame as F;
        if !self.started || bus_state(read_esr()).is_bus_off() {
            return Err(nb::Error::WouldBlock);
        }
        let w = TxWords::new(
            F::id(frame),
            F::is_remote_frame(frame),
            F::dlc(frame),
            F::data(frame),
        );
        let queued = self.txq.push_back(w).is_ok();
        self.pump();
        if queued {
            Ok(None)
        } else {
            Err(nb::Error::WouldBlock)
        }
    }

    /// The oldest frame of FIFO 0 (register level, see the module docs).
    fn receive(&mut self) -> nb::Result<Frame, CanError> {
        // SAFETY: CAN1's receive FIFO 0 registers (RM0090 §32.9.2
        // CAN_RF0R, §32.9.3 CAN_RI0R/RDT0R/RDL0R/RDH0R). `self` owns CAN1
        // (through the bxcan and HAL wrappers) and bxcan's own receive is
        // never called, so nothing else reads or releases this FIFO. The
        // writes set only rc_w1 bits (FOVR0, RFOM0); zeros written to the
        // other bits have no effect.
        let can = unsafe { &*pac::CAN1::ptr() };
        let rf0r = can.rf0r().read();
        if rf0r.fmp().bits() == 0 {
            return Err(nb::Error::WouldBlock);
        }
        if rf0r.fovr().bit_is_set() {
            can.rf0r().write(|w| w.fovr().clear());
            return Err(nb::Error::Other(CanError::Overrun));
        }
        let mb = can.rx(0);
        let rx = RxFrame::from_registers(
            mb.rir().read().bits(),
            mb.rdtr().read().bits(),
            mb.rdlr().read().bits(),
            mb.rdhr().read().bits(),
        );
        // Release the output mailbox (RFOM0): the next frame moves up.
        can.rf0r().write(|w| w.rfom().release());
        let frame = if rx.remote {
            <Frame as embedded_can::Frame>::new_remote(rx.id, usize::from(rx.len))
        } else {
            <Frame as embedded_can::Frame>::new(rx.id, rx.payload())
        };
        frame.ok_or(nb::Error::Other(CanError::Malformed))
    }
}

impl CanPort for CanBus {
    /// From `CAN_ESR` (RM0090 §32.9.2): BOFF, then EPVF.
    fn bus_state(&self) -> BusState {
        bus_state(read_esr())
    }

    /// Fill the free mailboxes from the queue; bus-off: drop the queue and
    /// abort the pending requests.
    fn poll(&mut self) {
        if bus_state(read_esr()).is_bus_off() {
            self.flush();
        } else if self.started {
            self.pump();
        }
    }
}
