//! bxCAN register encodings: bit timing (`CAN_BTR`), received mailboxes
//! (`CAN_RIxR` / `CAN_RDTxR` / `CAN_RDLxR` / `CAN_RDHxR`) and the error
//! status (`CAN_ESR`). Pure, host-tested; the driver is `hw::can`.
//!
//! # Bit timing (RM0090 §32.7.7, figure 346; `CAN_BTR` §32.9.2)
//!
//! ```text
//! tq       = (BRP + 1) / f_PCLK1
//! bit time = tq * (1 + (TS1 + 1) + (TS2 + 1))    [SYNC_SEG + BS1 + BS2]
//! sample point after SYNC_SEG + BS1
//! CAN_BTR  = SJW[25:24] | TS2[22:20] | TS1[19:16] | BRP[9:0]   (each "value - 1")
//! ```
//!
//! Every rate here uses the same 14-quantum bit: 1 + 11 + 2 tq, SJW 1 tq,
//! sample point 12/14 = 85.7 % (CiA DS 102 recommends 87.5 %, and
//! 75-90 % is the range usually allowed; 87.5 % exactly needs a multiple
//! of 8 tq per bit, and 42 MHz / 1 Mbit/s = 42 clocks per bit has none
//! within the bxCAN's 8-25 tq). From the ODrive's
//! APB1 = 42 MHz only the prescaler changes:
//!
//! | rate        | prescaler | tq       | `CAN_BTR`     |
//! |-------------|-----------|----------|---------------|
//! | 1 Mbit/s    | 3         | 71.4 ns  | `0x001A_0002` |
//! | 500 kbit/s  | 6         | 142.9 ns | `0x001A_0005` |
//! | 250 kbit/s  | 12        | 285.7 ns | `0x001A_000B` |
//! | 125 kbit/s  | 24        | 571.4 ns | `0x001A_0017` |
//!
//! (The ODrive firmware itself uses prescaler 8, BS1 16, BS2 4, SJW 4 =
//! 250 kbit/s at 81 %: `Firmware/Board/v3/Src/can.c`.)
//!
//! ```
//! use board_support::logic::can::{BitTiming, Bitrate};
//! let t = BitTiming::for_bitrate(42_000_000, Bitrate::M1).unwrap();
//! assert_eq!((t.prescaler, t.bs1_tq, t.bs2_tq, t.sjw_tq), (3, 11, 2, 1));
//! assert_eq!(t.btr(), Some(0x001A_0002));
//! assert_eq!(t.bitrate_hz(42_000_000), 1_000_000);
//! assert_eq!(t.sample_point_permille(), 857);
//! ```

use embedded_can::{ExtendedId, Id, StandardId};
use foc_core::hal::BusState;

/// The bit rates a node may be set to (the CANopen ones this drive
/// offers; CiA 301 lists 10 kbit/s to 1 Mbit/s).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Bitrate {
    /// 125 kbit/s.
    K125,
    /// 250 kbit/s.
    K250,
    /// 500 kbit/s.
    K500,
    /// 1 Mbit/s (the default).
    M1,
}

impl Bitrate {
    /// Every rate, slowest first.
    pub const ALL: [Bitrate; 4] = [Bitrate::K125, Bitrate::K250, Bitrate::K500, Bitrate::M1];
    /// The default rate: 1 Mbit/s.
    pub const DEFAULT: Bitrate = Bitrate::M1;

    /// The rate of `kbit` kbit/s (125, 250, 500 or 1000), else `None`.
    pub const fn from_kbit(kbit: u16) -> Option<Self> {
        match kbit {
            125 => Some(Bitrate::K125),
            250 => Some(Bitrate::K250),
            500 => Some(Bitrate::K500),
            1000 => Some(Bitrate::M1),
            _ => None,
        }
    }

    /// The rate [kbit/s].
    pub const fn kbit(self) -> u16 {
        match self {
            Bitrate::K125 => 125,
            Bitrate::K250 => 250,
            Bitrate::K500 => 500,
            Bitrate::M1 => 1000,
        }
    }

    /// The rate [bit/s].
    pub const fn bit_per_s(self) -> u32 {
        self.kbit() as u32 * 1000
    }
}

/// One bit's timing in time quanta, and the prescaler that makes a
/// quantum from the APB clock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BitTiming {
    /// APB clock cycles per time quantum, `1..=1024` (`BRP + 1`).
    pub prescaler: u16,
    /// Bit segment 1 [tq], `1..=16` (`TS1 + 1`; propagation and phase
    /// segment 1).
    pub bs1_tq: u8,
    /// Bit segment 2 [tq], `1..=8` (`TS2 + 1`).
    pub bs2_tq: u8,
    /// Resynchronisation jump width [tq], `1..=4` (`SJW + 1`), at most
    /// `bs2_tq`.
    pub sjw_tq: u8,
}

impl BitTiming {
    /// Quanta per bit of [`Self::for_bitrate`] (1 + 11 + 2).
    pub const TQ_PER_BIT: u32 = 14;

    /// The 14-quantum timing (1 + 11 + 2 tq, SJW 1) for `bitrate` from
    /// an APB clock of `pclk_hz`; `None` unless the clock divides exactly
    /// into `bitrate * 14` with a prescaler of at most 1024 (an inexact
    /// rate is refused, not rounded).
    pub const fn for_bitrate(pclk_hz: u32, bitrate: Bitrate) -> Option<Self> {
        let per_bit = bitrate.bit_per_s() as u64 * Self::TQ_PER_BIT as u64;
        let pclk = pclk_hz as u64;
        if !pclk.is_multiple_of(per_bit) {
            return None;
        }
        let prescaler = pclk / per_bit;
        if prescaler < 1 || prescaler > 1024 {
            return None;
        }
        Some(Self {
            prescaler: prescaler as u16,
            bs1_tq: 11,
            bs2_tq: 2,
            sjw_tq: 1,
        })
    }

    /// True when every field is within its register field and SJW <= BS2
    /// (the resynchronisation may not shorten BS2 below zero).
    pub const fn is_valid(&self) -> bool {
        self.prescaler >= 1
            && self.prescaler <= 1024
            && self.bs1_tq >= 1
            && self.bs1_tq <= 16
            && self.bs2_tq >= 1
            && self.bs2_tq <= 8
            && self.sjw_tq >= 1
            && self.sjw_tq <= 4
            && self.sjw_tq <= self.bs2_tq
    }

    /// The `CAN_BTR` value (mode bits LBKM / SILM clear: normal mode), or
    /// `None` for an invalid timing.
    pub const fn btr(&self) -> Option<u32> {
        if !self.is_valid() {
            return None;
        }
        Some(
            ((self.sjw_tq as u32 - 1) << 24)
                | ((self.bs2_tq as u32 - 1) << 20)
                | ((self.bs1_tq as u32 - 1) << 16)
                | (self.prescaler as u32 - 1),
        )
    }

    /// Quanta per bit: SYNC_SEG + BS1 + BS2.
    pub const fn tq_per_bit(&self) -> u32 {
        1 + self.bs1_tq as u32 + self.bs2_tq as u32
    }

    /// The bit rate [bit/s] from an APB clock of `pclk_hz` (rounded down;
    /// 0 for a zero prescaler).
    pub const fn bitrate_hz(&self, pclk_hz: u32) -> u32 {
        match pclk_hz.checked_div(self.prescaler as u32 * self.tq_per_bit()) {
            Some(hz) => hz,
            None => 0,
        }
    }

    /// Sample point [per mille of the bit] (rounded to nearest).
    pub const fn sample_point_permille(&self) -> u16 {
        let n = self.tq_per_bit();
        ((1 + self.bs1_tq as u32) * 1000 + n / 2).saturating_div(n) as u16
    }
}

/// `CAN_ESR` bits (RM0090 §32.9.2): bus-off and error-passive flags.
pub mod esr {
    /// BOFF: bus-off (TEC above 255).
    pub const BOFF: u32 = 1 << 2;
    /// EPVF: error passive (TEC or REC above 127).
    pub const EPVF: u32 = 1 << 1;
    /// EWGF: error warning (TEC or REC at least 96).
    pub const EWGF: u32 = 1 << 0;
    /// Transmit error counter, bits 23:16 (its low 8 bits).
    pub const fn tec(esr: u32) -> u8 {
        (esr >> 16) as u8
    }
    /// Receive error counter, bits 31:24.
    pub const fn rec(esr: u32) -> u8 {
        (esr >> 24) as u8
    }
}

/// The fault-confinement state a `CAN_ESR` value reports: BOFF first,
/// then EPVF.
pub const fn bus_state(esr: u32) -> BusState {
    if esr & esr::BOFF != 0 {
        BusState::BusOff
    } else if esr & esr::EPVF != 0 {
        BusState::ErrorPassive
    } else {
        BusState::ErrorActive
    }
}

/// `CAN_RIxR` bits (RM0090 §32.9.3).
mod rir {
    /// IDE: extended identifier.
    pub const IDE: u32 = 1 << 2;
    /// RTR: remote frame.
    pub const RTR: u32 = 1 << 1;
}

/// `CAN_TIxR.TXRQ`: transmit request (RM0090 §32.9.3).
pub const TXRQ: u32 = 1;

/// A frame as a transmit mailbox's four registers take it (`CAN_TIxR`
/// without `TXRQ`, `CAN_TDTxR`, `CAN_TDLxR`, `CAN_TDHxR`; RM0090
/// §32.9.3): the identifier field has the layout of the receive
/// mailbox's `CAN_RIxR` ([`RxFrame::from_registers`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TxWords {
    /// `CAN_TIxR` (STID/EXID, IDE, RTR; `TXRQ` clear).
    pub tir: u32,
    /// `CAN_TDTxR` (DLC).
    pub tdtr: u32,
    /// `CAN_TDLxR`: data bytes 0-3.
    pub tdlr: u32,
    /// `CAN_TDHxR`: data bytes 4-7.
    pub tdhr: u32,
}

impl TxWords {
    /// The registers for `id`, a remote frame of `dlc` bytes or a data
    /// frame of `data` (at most 8 bytes taken, the DLC clamped to 8).
    pub fn new(id: Id, remote: bool, dlc: usize, data: &[u8]) -> Self {
        let mut tir = match id {
            Id::Standard(s) => u32::from(s.as_raw()) << 21,
            Id::Extended(e) => (e.as_raw() << 3) | rir::IDE,
        };
        let mut bytes = [0u8; 8];
        let len = if remote {
            tir |= rir::RTR;
            dlc.min(8)
        } else {
            let n = data.len().min(8);
            if let (Some(dst), Some(src)) = (bytes.get_mut(..n), data.get(..n)) {
                dst.copy_from_slice(src);
            }
            n
        };
        Self {
            tir,
            tdtr: len as u32,
            tdlr: u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]),
            tdhr: u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]),
        }
    }
}

/// Frames waiting for a free transmit mailbox, oldest first.
pub type TxQueue = heapless::Deque<TxWords, TX_QUEUE>;

/// Frames the transmit queue holds (a node's burst: four TPDOs, EMCYs,
/// an SDO reply and a heartbeat in one millisecond, with room).
pub const TX_QUEUE: usize = 32;

/// `CAN_TSR.TME0..2`: the free transmit mailboxes (RM0090 §32.9.2), as
/// indices `0..3`.
pub fn free_mailboxes(tsr: u32) -> impl Iterator<Item = usize> {
    (0..3).filter(move |i| tsr & (1 << (26 + i)) != 0)
}

/// A received frame as the mailbox registers hold it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RxFrame {
    /// Identifier (standard: `STID[31:21]`, extended: `EXID[31:3]`).
    pub id: Id,
    /// Remote transmission request.
    pub remote: bool,
    /// Data length, `0..=8`: a DLC of 9 to 15, legal on the wire, means 8
    /// bytes (ISO 11898-1) and is clamped here.
    pub len: u8,
    /// Data bytes (`RDLR` bytes 0-3, `RDHR` bytes 4-7, little-endian);
    /// those beyond `len` as the registers held them.
    pub data: [u8; 8],
}

impl RxFrame {
    /// Decode the four mailbox registers of a receive FIFO (`CAN_RIxR`,
    /// `CAN_RDTxR`, `CAN_RDLxR`, `CAN_RDHxR`, RM0090 §32.9.3).
    pub const fn from_registers(rir: u32, rdtr: u32, rdlr: u32, rdhr: u32) -> Self {
        let id = if rir & rir::IDE != 0 {
            match ExtendedId::new(rir >> 3) {
                Some(e) => Id::Extended(e),
                None => Id::Extended(ExtendedId::MAX),
            }
        } else {
            match StandardId::new((rir >> 21) as u16) {
                Some(s) => Id::Standard(s),
                None => Id::Standard(StandardId::MAX),
            }
        };
        let dlc = (rdtr & 0xF) as u8;
        let lo = rdlr.to_le_bytes();
        let hi = rdhr.to_le_bytes();
        Self {
            id,
            remote: rir & rir::RTR != 0,
            len: if dlc > 8 { 8 } else { dlc },
            data: [lo[0], lo[1], lo[2], lo[3], hi[0], hi[1], hi[2], hi[3]],
        }
    }

    /// The data bytes (empty for a remote frame).
    pub fn payload(&self) -> &[u8] {
        if self.remote {
            &[]
        } else {
            self.data.get(..usize::from(self.len)).unwrap_or(&self.data)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn btr_values_at_42_mhz() {
        let expected = [
            (Bitrate::M1, 3, 0x001A_0002),
            (Bitrate::K500, 6, 0x001A_0005),
            (Bitrate::K250, 12, 0x001A_000B),
            (Bitrate::K125, 24, 0x001A_0017),
        ];
        for (rate, prescaler, btr) in expected {
            let t = BitTiming::for_bitrate(42_000_000, rate).unwrap();
            assert_eq!(t.prescaler, prescaler, "{rate:?}");
            assert_eq!(t.btr(), Some(btr), "{rate:?}");
            // Exact rate, back from the register fields as RM0090 §32.7.7
            // computes it: f = PCLK / ((BRP + 1) * (1 + TS1 + 1 + TS2 + 1)).
            let brp = btr & 0x3FF;
            let ts1 = (btr >> 16) & 0xF;
            let ts2 = (btr >> 20) & 0x7;
            let sjw = (btr >> 24) & 0x3;
            assert_eq!((ts1, ts2, sjw), (10, 1, 0));
            let per_bit = (brp + 1) * (1 + (ts1 + 1) + (ts2 + 1));
            assert_eq!(42_000_000 % per_bit, 0);
            assert_eq!(42_000_000 / per_bit, rate.bit_per_s());
            assert_eq!(t.bitrate_hz(42_000_000), rate.bit_per_s());
            assert_eq!(t.sample_point_permille(), 857);
        }
    }

    #[test]
    fn inexact_or_out_of_range_clocks_are_refused() {
        // 45 MHz (F446 at 180 MHz): 45e6 / 14e6 is not an integer.
        assert_eq!(BitTiming::for_bitrate(45_000_000, Bitrate::M1), None);
        // Prescaler above 1024.
        assert_eq!(BitTiming::for_bitrate(1_837_500_000, Bitrate::K125), None);
        assert!(BitTiming::for_bitrate(1_792_000_000, Bitrate::K125).is_some());
        assert_eq!(BitTiming::for_bitrate(0, Bitrate::K125), None);
        // 16 MHz HSI: 16e6 / 14e6 not an integer either.
        assert_eq!(BitTiming::for_bitrate(16_000_000, Bitrate::K500), None);
    }

    #[test]
    fn invalid_fields_give_no_btr() {
        let ok = BitTiming {
            prescaler: 1,
            bs1_tq: 16,
            bs2_tq: 8,
            sjw_tq: 4,
        };
        assert_eq!(ok.btr(), Some(0x037F_0000));
        for bad in [
            BitTiming { prescaler: 0, ..ok },
            BitTiming {
                prescaler: 1025,
                ..ok
            },
            BitTiming { bs1_tq: 0, ..ok },
            BitTiming { bs1_tq: 17, ..ok },
            BitTiming { bs2_tq: 9, ..ok },
            BitTiming { sjw_tq: 5, ..ok },
            BitTiming {
                bs2_tq: 2,
                sjw_tq: 3,
                ..ok
            },
        ] {
            assert_eq!(bad.btr(), None, "{bad:?}");
        }
        assert_eq!(BitTiming { prescaler: 0, ..ok }.bitrate_hz(42_000_000), 0);
    }

    #[test]
    fn kbit_round_trip() {
        for r in Bitrate::ALL {
            assert_eq!(Bitrate::from_kbit(r.kbit()), Some(r));
        }
        for k in [0, 10, 20, 50, 100, 800, 1001, u16::MAX] {
            assert_eq!(Bitrate::from_kbit(k), None);
        }
        assert_eq!(Bitrate::DEFAULT.bit_per_s(), 1_000_000);
    }

    #[test]
    fn esr_decoding() {
        assert_eq!(bus_state(0), BusState::ErrorActive);
        assert_eq!(bus_state(esr::EWGF), BusState::ErrorActive);
        assert_eq!(bus_state(esr::EWGF | esr::EPVF), BusState::ErrorPassive);
        assert_eq!(
            bus_state(esr::EWGF | esr::EPVF | esr::BOFF | 0xFF_0000),
            BusState::BusOff
        );
        assert_eq!(esr::tec(0x85FF_0000), 0xFF);
        assert_eq!(esr::rec(0x85FF_0000), 0x85);
    }

    #[test]
    fn mailbox_decoding() {
        // Standard 0x605, data, DLC 8.
        let f = RxFrame::from_registers(0x605 << 21, 8, 0x0010_0040, 0x0403_0201);
        assert_eq!(f.id, Id::Standard(StandardId::new(0x605).unwrap()));
        assert!(!f.remote);
        assert_eq!(f.payload(), &[0x40, 0x00, 0x10, 0x00, 1, 2, 3, 4]);
        // Standard remote frame, DLC 1 (e.g. a node-guarding request).
        let r = RxFrame::from_registers((0x705 << 21) | 0b10, 1, 0xAA, 0);
        assert!(r.remote);
        assert_eq!(r.len, 1);
        assert_eq!(r.payload(), &[] as &[u8]);
        // Extended id.
        let e = RxFrame::from_registers((0x1234_5678 << 3) | 0b100, 2, 0xBBAA, 0);
        assert_eq!(e.id, Id::Extended(ExtendedId::new(0x1234_5678).unwrap()));
        assert_eq!(e.payload(), &[0xAA, 0xBB]);
    }

    #[test]
    fn dlc_above_8_is_8_bytes() {
        for dlc in 9..=15 {
            let f = RxFrame::from_registers(0x181 << 21, dlc, u32::MAX, u32::MAX);
            assert_eq!(f.len, 8);
            assert_eq!(f.payload().len(), 8);
        }
        // Reserved bits above DLC ignored (RDTxR also holds FMI and TIME).
        let f = RxFrame::from_registers(0x181 << 21, 0xFFFF_FF03, 0, 0);
        assert_eq!(f.len, 3);
    }
}

#[cfg(test)]
mod tx_tests {
    use super::*;

    #[test]
    fn transmit_words_read_back_as_the_receive_mailbox_would() {
        let id = Id::Standard(StandardId::new(0x185).unwrap());
        let w = TxWords::new(id, false, 3, &[1, 2, 3]);
        assert_eq!(w.tir & TXRQ, 0);
        let rx = RxFrame::from_registers(w.tir, w.tdtr, w.tdlr, w.tdhr);
        assert_eq!(
            (rx.id, rx.remote, rx.payload()),
            (id, false, &[1u8, 2, 3][..])
        );
        let r = TxWords::new(id, true, 12, &[]);
        let rx = RxFrame::from_registers(r.tir, r.tdtr, r.tdlr, r.tdhr);
        assert_eq!((rx.remote, rx.len), (true, 8));
        let long = TxWords::new(id, false, 0, &[9; 12]);
        assert_eq!(long.tdtr, 8);
        let ext = Id::Extended(ExtendedId::new(0x1234_5678).unwrap());
        let e = TxWords::new(ext, false, 0, &[]);
        assert_eq!(RxFrame::from_registers(e.tir, e.tdtr, 0, 0).id, ext);
    }

    #[test]
    fn free_mailboxes_from_tsr() {
        assert_eq!(free_mailboxes(0).count(), 0);
        let all: heapless::Vec<usize, 3> = free_mailboxes(0x1C00_0000).collect();
        assert_eq!(&all[..], &[0, 1, 2]);
        let one: heapless::Vec<usize, 3> = free_mailboxes(1 << 27).collect();
        assert_eq!(&one[..], &[1]);
    }

    #[test]
    fn the_queue_keeps_order_and_refuses_when_full() {
        let mut q = TxQueue::new();
        let id = Id::Standard(StandardId::new(0x701).unwrap());
        for k in 0..TX_QUEUE {
            assert!(q.push_back(TxWords::new(id, false, 0, &[k as u8])).is_ok());
        }
        assert!(q.push_back(TxWords::new(id, false, 0, &[0xFF])).is_err());
        assert_eq!(q.pop_front().map(|w| w.tdlr & 0xFF), Some(0));
    }
}
