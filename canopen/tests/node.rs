//! CiA 301 services of the node against a fake profile and device.
// Test support outside `#[test]` functions: unwrapping and indexing a
// fixture is the test failing, which is what it should do.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

mod common;

use common::*;
use foc_canopen::emcy::{self, fault_code};
use foc_canopen::nmt::NmtState;
use foc_canopen::node::{BusState, CommSettings, LOAD, SAVE};
use foc_canopen::od::{self, Access, Default as Dflt, Kind, OBJECTS};
use foc_canopen::CanFrame;
use foc_core::control::{Fault, Mode};
use foc_protocol::config::StoreOp;

const SDO_RX: u16 = 0x600 + ID as u16;

// ---------------------------------------------------------------- table

#[test]
fn table_is_sorted_unique_and_consistent() {
    for w in OBJECTS.windows(2) {
        assert!(
            (w[0].index, w[0].sub) < (w[1].index, w[1].sub),
            "{:#x}",
            w[1].index
        );
    }
    for d in OBJECTS {
        match d.kind {
            Kind::Var => assert_eq!(d.sub, 0, "{:#x}", d.index),
            Kind::Array(n) | Kind::Record(n) => {
                let highest = OBJECTS
                    .iter()
                    .filter(|e| e.index == d.index)
                    .map(|e| e.sub)
                    .max();
                assert_eq!(highest, Some(n), "{:#x}", d.index);
                assert!(od::find(d.index, 0).is_some());
            }
        }
        if d.pdo_mappable {
            assert_ne!(d.data_type.size(), 0);
        }
        if let (Some((lo, hi)), Dflt::Int(v)) = (d.limits, d.default) {
            assert!(lo <= v && v <= hi, "{:#x}", d.index);
        }
    }
}

#[test]
fn fresh_node_holds_the_table_defaults() {
    let mut b = Bench::with(CommSettings::new(ID, 1000, 100, None).unwrap());
    for d in OBJECTS {
        // Actual values (ro, 0x6xxx) follow the drive; 0x2100 is the next boot's.
        if !d.access.readable()
            || d.index == 0x2100
            || (d.index >= 0x6000 && d.access == Access::Ro)
        {
            continue;
        }
        let want = match d.default {
            Dflt::Int(v) => v as u32,
            Dflt::NodeId(base) => base + u32::from(ID),
            _ => continue,
        };
        let got = b.read_u32(d.index, d.sub);
        let mask = if d.data_type.size() == 4 {
            u32::MAX
        } else {
            (1u32 << (8 * d.data_type.size())) - 1
        };
        assert_eq!(got, want & mask, "{:#06x} sub {}", d.index, d.sub);
    }
}

// ---------------------------------------------------------------- SDO

#[test]
fn expedited_upload_of_device_type() {
    let mut b = Bench::new();
    assert_eq!(
        b.sdo([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]),
        [0x43, 0x00, 0x10, 0, 0x92, 0x01, 0x02, 0x00]
    );
    assert_eq!(b.read(0x1001, 0), Ok(vec![0]));
    assert_eq!(b.read_u32(0x1018, 4), 77);
    assert_eq!(b.read(0x100A, 0), Ok(b"1.2.3".to_vec()));
}

#[test]
fn segmented_upload_of_device_name_and_wrong_toggle() {
    let mut b = Bench::new();
    assert_eq!(b.read(0x1008, 0), Ok(b"FOC drive test bench".to_vec()));
    let r = b.sdo([0x40, 0x08, 0x10, 0, 0, 0, 0, 0]);
    assert_eq!(r, [0x41, 0x08, 0x10, 0, 20, 0, 0, 0]);
    // First segment with toggle 1: abort 0x05030000.
    let r = b.sdo([0x70, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(r, [0x80, 0x08, 0x10, 0, 0x00, 0x00, 0x03, 0x05]);
    // The transfer is over: a segment now is an unknown command.
    let r = b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(u32::from_le_bytes([r[4], r[5], r[6], r[7]]), 0x0504_0001);
}

#[test]
fn expedited_and_segmented_download() {
    let mut b = Bench::new();
    b.write(0x1017, 0, &250u16.to_le_bytes()).unwrap();
    assert_eq!(b.read_u32(0x1017, 0), 250);
    // Expedited without size: the object's own size.
    assert_eq!(
        b.sdo([0x22, 0x17, 0x10, 0, 0x2C, 0x01, 0, 0]),
        [0x60, 0x17, 0x10, 0, 0, 0, 0, 0]
    );
    assert_eq!(b.read_u32(0x1017, 0), 300);
    // Segmented, size 4, into 0x6081.
    assert_eq!(
        b.sdo([0x21, 0x81, 0x60, 0, 4, 0, 0, 0]),
        [0x60, 0x81, 0x60, 0, 0, 0, 0, 0]
    );
    // 4 bytes, 3 unused, last.
    assert_eq!(b.sdo([(3 << 1) | 1, 0x10, 0x27, 0, 0, 0, 0, 0])[0], 0x20);
    assert_eq!(b.read_u32(0x6081, 0), 10_000);
    // Segmented in two segments with toggles, size 2 into 0x1017.
    assert_eq!(b.sdo([0x21, 0x17, 0x10, 0, 2, 0, 0, 0])[0], 0x60);
    assert_eq!(b.sdo([6 << 1, 0x90, 0, 0, 0, 0, 0, 0])[0], 0x20);
    assert_eq!(
        b.sdo([0x10 | (6 << 1) | 1, 0x01, 0, 0, 0, 0, 0, 0])[0],
        0x30
    );
    assert_eq!(b.read_u32(0x1017, 0), 0x190);
}

fn abort_code(r: [u8; 8]) -> u32 {
    assert_eq!(r[0], 0x80, "{r:x?}");
    u32::from_le_bytes([r[4], r[5], r[6], r[7]])
}

/// Every abort, each leaving the dictionary, the profile and the device
/// as they were.
#[test]
fn every_abort_changes_nothing() {
    let mut b = Bench::new();
    b.dev.ctx.mode = Mode::Torque; // enabled: store refused
    let cases: Vec<([u8; 8], u32)> = vec![
        ([0xE0, 0, 0x10, 0, 0, 0, 0, 0], 0x0504_0001), // unknown ccs
        ([0xC0, 0x00, 0x10, 0, 0, 0, 0, 0], 0x0504_0001), // block upload
        ([0x40, 0x00, 0x30, 0, 0, 0, 0, 0], 0x0602_0000), // no object
        ([0x40, 0x18, 0x10, 9, 0, 0, 0, 0], 0x0609_0011), // no sub
        ([0x2F, 0x00, 0x10, 0, 1, 0, 0, 0], 0x0601_0002), // const
        ([0x2B, 0x41, 0x60, 0, 1, 0, 0, 0], 0x0601_0002), // ro statusword
        ([0x23, 0x17, 0x10, 0, 1, 0, 0, 0], 0x0607_0012), // 4 bytes into U16
        ([0x2F, 0x17, 0x10, 0, 1, 0, 0, 0], 0x0607_0013), // 1 byte into U16
        ([0x2F, 0x00, 0x21, 0, 0, 0, 0, 0], 0x0609_0032), // node id 0
        ([0x2F, 0x00, 0x21, 0, 128, 0, 0, 0], 0x0609_0031), // node id 128
        ([0x2B, 0x01, 0x21, 0, 0x2C, 0x01, 0, 0], 0x0609_0030), // 300 kbit/s
        ([0x2F, 0x60, 0x60, 0, 2, 0, 0, 0], 0x0609_0030), // mode 2
        ([0x2B, 0x5A, 0x60, 0, 9, 0, 0, 0], 0x0609_0031), // quick stop option 9
        ([0x23, 0x10, 0x10, 1, 0x73, 0x61, 0x76, 0x65], 0x0800_0022), // save while enabled
        ([0x23, 0x10, 0x10, 1, 1, 2, 3, 4], 0x0800_0020), // wrong signature
        ([0x23, 0x00, 0x16, 1, 0x10, 0, 0x40, 0x60], 0x0800_0022), // mapping of a valid PDO
        ([0x2F, 0x03, 0x10, 0, 1, 0, 0, 0], 0x0609_0030), // 0x1003 sub0 != 0
        ([0x23, 0x12, 0x20, 0, 0, 0, 0x80, 0xBF], 0x0609_0032), // negative gain
        ([0x23, 0x12, 0x20, 0, 0, 0, 0xC0, 0x7F], 0x0609_0030), // NaN gain
        ([0x23, 0x81, 0x60, 0, 0xFF, 0xFF, 0xFF, 0x7F], 0x0604_0043), // profile check
        ([0x21, 0x17, 0x10, 0, 4, 0, 0, 0], 0x0607_0012), // segmented size 4 into U16
        ([0x21, 0x17, 0x10, 0, 1, 0, 0, 0], 0x0607_0013), // segmented size 1 into U16
        ([0x23, 0x16, 0x10, 1, 0x2C, 0x01, 0x05, 0x00], 0x0609_0030), // consumer = own id
        ([0x23, 0x00, 0x18, 1, 0x81, 0x01, 0, 0], 0x0609_0030), // valid TPDO to another id
        ([0x2F, 0x00, 0x18, 2, 250, 0, 0, 0], 0x0609_0030), // reserved transmission type
        ([0x00, 0, 0, 0, 0, 0, 0, 0], 0x0504_0001),    // segment without transfer
    ];
    for (req, code) in cases {
        let before = b.state();
        assert_eq!(abort_code(b.sdo(req)), code, "{req:x?}");
        assert_eq!(b.state(), before, "{req:x?} changed something");
    }
    // Segmented download with a wrong toggle, then with a wrong total length.
    let before = b.state();
    assert_eq!(b.sdo([0x21, 0x81, 0x60, 0, 4, 0, 0, 0])[0], 0x60);
    assert_eq!(
        abort_code(b.sdo([0x10 | (3 << 1) | 1, 1, 2, 3, 4, 0, 0, 0])),
        0x0503_0000
    );
    assert_eq!(b.sdo([0x21, 0x81, 0x60, 0, 4, 0, 0, 0])[0], 0x60);
    assert_eq!(
        abort_code(b.sdo([(5 << 1) | 1, 1, 2, 0, 0, 0, 0, 0])),
        0x0607_0010
    );
    assert_eq!(b.state(), before);
    // DLC != 8: an abort, nothing else.
    b.sent.clear();
    b.frame(SDO_RX, &[0x40, 0x00, 0x10]);
    let r = b.take();
    assert_eq!(r.len(), 1);
    assert_eq!(
        u32::from_le_bytes([r[0].data[4], r[0].data[5], r[0].data[6], r[0].data[7]]),
        0x0504_0001
    );
    assert_eq!(b.state(), before);
}

#[test]
fn write_only_is_refused_on_read() {
    // No wo object in this dictionary: the access rule itself.
    assert!(!Access::Wo.readable());
    assert!(Access::Wo.writable());
    assert!(!Access::Const.writable());
}

#[test]
fn segmented_transfer_times_out_after_one_second() {
    let mut b = Bench::new();
    assert_eq!(b.sdo([0x21, 0x81, 0x60, 0, 4, 0, 0, 0])[0], 0x60);
    b.sent.clear();
    b.run_to(999_000, 1000);
    assert!(b.take().iter().all(|f| f.id != 0x585));
    b.run_to(1_001_000, 1000);
    let r: Vec<_> = b.take().into_iter().filter(|f| f.id == 0x585).collect();
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].data, [0x80, 0x81, 0x60, 0, 0, 0, 0x04, 0x05]);
}

// ---------------------------------------------------------------- NMT

#[test]
fn boot_up_and_nmt_transitions() {
    let mut b = Bench::new();
    assert_eq!(b.take(), vec![CanFrame::new(0x705, &[0]).unwrap()]);
    assert_eq!(b.node.nmt_state(), NmtState::PreOperational);
    b.nmt(0x01, 6); // another node
    assert_eq!(b.node.nmt_state(), NmtState::PreOperational);
    b.nmt(0x01, 0); // broadcast
    assert_eq!(b.node.nmt_state(), NmtState::Operational);
    b.nmt(0x80, ID);
    assert_eq!(b.node.nmt_state(), NmtState::PreOperational);
    b.nmt(0x02, ID);
    assert_eq!(b.node.nmt_state(), NmtState::Stopped);
    // No SDO while stopped.
    b.sent.clear();
    b.frame(SDO_RX, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]);
    assert!(b.take().is_empty());
    b.nmt(0x01, ID);
    assert_eq!(b.node.nmt_state(), NmtState::Operational);
    // Reset communication: defaults back, boot-up, pre-operational.
    b.write(0x1017, 0, &500u16.to_le_bytes()).unwrap();
    b.sent.clear();
    b.nmt(0x82, ID);
    assert_eq!(b.take(), vec![CanFrame::new(0x705, &[0]).unwrap()]);
    assert_eq!(b.node.nmt_state(), NmtState::PreOperational);
    assert_eq!(b.read_u32(0x1017, 0), 100);
    assert!(!b.node.take_reset_request());
    b.nmt(0x81, 0);
    assert!(b.node.take_reset_request());
    assert_eq!(b.node.nmt_state(), NmtState::PreOperational);
    // Malformed NMT frames are ignored.
    b.frame(0, &[0x01]);
    b.frame(0, &[0x01, ID, 0]);
    b.frame(0, &[0x77, ID]);
    assert_eq!(b.node.nmt_state(), NmtState::PreOperational);
}

#[test]
fn heartbeat_producer_timing() {
    let mut b = Bench::new();
    b.take();
    let mut beats = Vec::new();
    for t in (0..=1_000_000u64).step_by(1000) {
        b.tick_to(t);
        for f in b.take() {
            if f.id == 0x705 {
                beats.push((t, f.data[0]));
            }
        }
        if t == 450_000 {
            b.start();
        }
    }
    let times: Vec<u64> = beats.iter().map(|x| x.0).collect();
    assert_eq!(times, (1..=10).map(|k| k * 100_000).collect::<Vec<_>>());
    assert_eq!(beats[3].1, 0x7F);
    assert_eq!(beats[4].1, 0x05);
    // 0 switches it off.
    b.write(0x1017, 0, &[0, 0]).unwrap();
    b.run_to(2_000_000, 1000);
    assert!(b.take().iter().all(|f| f.id != 0x705));
}

#[test]
fn heartbeat_consumer_starts_at_the_first_heartbeat_and_times_out_once() {
    let mut b = Bench::new(); // master 1, 300 ms
    b.run_to(2_000_000, 1000);
    assert_eq!(b.node.cia402().lost, 0, "not before the first heartbeat");
    b.frame(0x701, &[0x05]);
    b.take();
    b.run_to(2_300_000, 1000);
    assert_eq!(b.node.cia402().lost, 0);
    b.run_to(2_302_000, 1000);
    assert_eq!(b.node.cia402().lost, 1);
    let e = emcys(&b.take());
    assert_eq!(e, vec![(emcy::HEARTBEAT, 0x11, 0)]);
    b.run_to(4_000_000, 1000);
    assert_eq!(b.node.cia402().lost, 1, "once");
    assert_eq!(b.node.error_register(), 0x11);
    // The master is back: the error resets.
    b.frame(0x701, &[0x05]);
    b.tick_to(4_001_000);
    assert_eq!(emcys(&b.take()), vec![(0, 0, 0)]);
    assert_eq!(b.node.error_register(), 0);
}

// ---------------------------------------------------------------- PDO

#[test]
fn default_pdo_mappings_and_cob_ids() {
    let mut b = Bench::new();
    let rx = [
        &[0x6040_0010u32][..],
        &[0x6040_0010, 0x6060_0008],
        &[0x6040_0010, 0x607A_0020],
        &[0x6040_0010, 0x60FF_0020],
    ];
    let tx = [
        &[0x6041_0010u32][..],
        &[0x6041_0010, 0x6061_0008],
        &[0x6041_0010, 0x6064_0020],
        &[0x6041_0010, 0x606C_0020],
    ];
    for n in 0..4u16 {
        assert_eq!(b.read_u32(0x1400 + n, 1), 0x205 + 0x100 * u32::from(n));
        assert_eq!(
            b.read_u32(0x1800 + n, 1),
            0x4000_0185 + 0x100 * u32::from(n),
            "bit 30: no RTR"
        );
        assert_eq!(b.read_u32(0x1400 + n, 2), 255);
        assert_eq!(b.read_u32(0x1800 + n, 2), 255);
        let (r, t) = (rx[n as usize], tx[n as usize]);
        assert_eq!(b.read_u32(0x1600 + n, 0), r.len() as u32);
        assert_eq!(b.read_u32(0x1A00 + n, 0), t.len() as u32);
        for (k, e) in r.iter().enumerate() {
            assert_eq!(b.read_u32(0x1600 + n, k as u8 + 1), *e);
        }
        for (k, e) in t.iter().enumerate() {
            assert_eq!(b.read_u32(0x1A00 + n, k as u8 + 1), *e);
        }
    }
}

#[test]
fn no_pdo_before_operational() {
    let mut b = Bench::new();
    b.frame(0x205, &[0x0F, 0]);
    b.run_to(10_000, 1000);
    assert_eq!(b.node.cia402().cw_writes, 0);
    assert!(b.take().iter().all(|f| f.id != 0x185));
    b.start();
    b.frame(0x205, &[0x0F, 0]);
    assert_eq!(b.node.cia402().cw, 0x0F);
    b.tick_to(11_000);
    assert!(b
        .take()
        .iter()
        .any(|f| f.id == 0x185 && f.data() == [0x50, 0x02]));
}

#[test]
fn remapping_procedure_over_sdo() {
    let mut b = Bench::new();
    // TPDO2: 0x6041 + 0x6061 -> 0x6064 + 0x6079.
    assert_eq!(
        b.write_u32(0x1A01, 1, 0x6064_0020),
        Err(0x0800_0022),
        "valid PDO"
    );
    b.write_u32(0x1801, 1, 0xC000_0285).unwrap();
    assert_eq!(
        b.write_u32(0x1A01, 1, 0x6064_0020),
        Err(0x0601_0000),
        "sub0 != 0"
    );
    b.write(0x1A01, 0, &[0]).unwrap();
    assert_eq!(
        b.write_u32(0x1A01, 1, 0x1000_0020),
        Err(0x0604_0041),
        "not mappable"
    );
    assert_eq!(
        b.write_u32(0x1A01, 1, 0x6064_0010),
        Err(0x0604_0041),
        "wrong length"
    );
    assert_eq!(
        b.write_u32(0x1A01, 1, 0x7000_0020),
        Err(0x0602_0000),
        "no object"
    );
    b.write_u32(0x1A01, 1, 0x6064_0020).unwrap();
    b.write_u32(0x1A01, 2, 0x6079_0020).unwrap();
    b.write_u32(0x1A01, 3, 0x6064_0020).unwrap();
    assert_eq!(b.write(0x1A01, 0, &[3]), Err(0x0604_0042), "96 bits");
    assert_eq!(b.write(0x1A01, 0, &[9]), Err(0x0609_0031));
    b.write(0x1A01, 0, &[2]).unwrap();
    b.write_u32(0x1801, 1, 0x4000_0285).unwrap();
    // An RPDO cannot map a read-only object.
    b.write_u32(0x1400, 1, 0x8000_0205).unwrap();
    b.write(0x1600, 0, &[0]).unwrap();
    assert_eq!(b.write_u32(0x1600, 1, 0x6041_0010), Err(0x0604_0041));
    b.start();
    b.tick_to(1000);
    let f: Vec<_> = b.take().into_iter().filter(|f| f.id == 0x285).collect();
    assert_eq!(f.len(), 1);
    let mut want = 0i32.to_le_bytes().to_vec();
    want.extend_from_slice(&24_000u32.to_le_bytes());
    assert_eq!(f[0].data(), &want[..]);
    // RPDO1 is invalid: its frames are ignored.
    b.frame(0x205, &[0x0F, 0]);
    assert_eq!(b.node.cia402().cw_writes, 0);
}

#[test]
fn synchronous_cyclic_tpdo_every_nth_sync_and_acyclic_on_change() {
    let mut b = Bench::new();
    b.write(0x1800, 2, &[3]).unwrap(); // TPDO1 every 3rd SYNC
    b.write(0x1801, 2, &[0]).unwrap(); // TPDO2 acyclic synchronous
    b.start();
    b.take();
    let mut t1 = Vec::new();
    let mut t2 = Vec::new();
    for k in 1..=9 {
        b.frame(0x080, &[]);
        for f in b.take() {
            if f.id == 0x185 {
                t1.push(k);
            }
            if f.id == 0x285 {
                t2.push(k);
            }
        }
    }
    assert_eq!(t1, vec![3, 6, 9]);
    assert_eq!(t2, vec![1], "acyclic: only when the data changed");
    assert_eq!(b.node.cia402().updates, 9, "profile updated at each SYNC");
    // A SYNC with a counter byte is a SYNC too.
    b.frame(0x080, &[7]);
    assert_eq!(b.node.cia402().updates, 10);
}

#[test]
fn event_tpdo_respects_inhibit_time_and_event_timer() {
    let mut b = Bench::with(CommSettings::new(ID, 1000, 0, None).unwrap());
    b.write_u32(0x1800, 1, 0xC000_0185).unwrap();
    b.write(0x1800, 3, &50u16.to_le_bytes()).unwrap(); // 5 ms
    b.write(0x1800, 5, &20u16.to_le_bytes()).unwrap(); // 20 ms
    b.write_u32(0x1800, 1, 0x4000_0185).unwrap();
    assert_eq!(
        b.write(0x1800, 3, &[0, 0]),
        Err(0x0609_0030),
        "inhibit while valid"
    );
    b.start();
    b.take();
    let mut sent = Vec::new();
    for t in (1000..=60_000u64).step_by(1000) {
        // The statusword changes every ms until 10 ms.
        if t <= 10_000 {
            b.node_profile_mut(|p| p.actuals.statusword = t as u16);
        }
        b.tick_to(t);
        for f in b.take() {
            if f.id == 0x185 {
                sent.push(t);
            }
        }
    }
    // Sent at 0 by the NMT start (taken above); changes every ms held
    // back by the 5 ms inhibit: 5, 10; then the event timer every 20 ms.
    assert_eq!(sent, vec![5000, 10_000, 30_000, 50_000]);
}

trait ProfileMut {
    fn node_profile_mut(&mut self, f: impl FnOnce(&mut FakeProfile));
}

impl ProfileMut for Bench {
    fn node_profile_mut(&mut self, f: impl FnOnce(&mut FakeProfile)) {
        // The fake profile's actual values are set through an RPDO-less
        // path: rebuild the node around an edited profile clone.
        let mut p = self.node.cia402().clone();
        f(&mut p);
        self.node.replace_profile_for_test(p);
    }
}

#[test]
fn rpdo_wrong_length_sends_emcy_and_applies_nothing() {
    let mut b = Bench::new();
    b.start();
    b.tick_to(1000);
    b.take();
    let before = b.state();
    b.frame(0x305, &[0x0F, 0x00]); // RPDO2 wants 3 bytes
    assert_eq!(emcys(&b.take()), vec![(emcy::PDO_LENGTH, 0x11, 0)]);
    b.frame(0x305, &[0x0F, 0x00, 0x08, 0x00]);
    assert_eq!(emcys(&b.take()), vec![(emcy::PDO_LENGTH_EXCEEDED, 0x11, 0)]);
    assert_eq!(b.state().1, before.1);
    assert_eq!(
        b.node.error_register(),
        0,
        "PDO length errors are not latched"
    );
    // An unsupported mode in the PDO: nothing applied, not even the controlword.
    b.frame(0x305, &[0x0F, 0x00, 0x02]);
    assert_eq!(b.node.cia402().cw_writes, 0);
    b.frame(0x305, &[0x0F, 0x00, 0x08]);
    assert_eq!(b.node.cia402().cw, 0x0F);
    assert_eq!(b.node.cia402().mode, 8);
    b.frame(0x405, &[0x1F, 0x00, 0x10, 0x27, 0, 0]);
    assert_eq!(b.node.cia402().targets.position_inc, 10_000);
}

#[test]
fn synchronous_rpdo_is_applied_at_the_next_sync() {
    let mut b = Bench::new();
    b.write(0x1402, 2, &[1]).unwrap();
    b.start();
    b.frame(0x405, &[0x0F, 0x00, 0x40, 0x9C, 0, 0]);
    assert_eq!(b.node.cia402().targets.position_inc, 0);
    assert_eq!(b.node.cia402().cw_writes, 0);
    b.frame(0x080, &[]);
    assert_eq!(b.node.cia402().targets.position_inc, 40_000);
    assert_eq!(b.node.cia402().cw, 0x0F);
}

// ---------------------------------------------------------------- EMCY

#[test]
fn every_fault_sends_its_emcy_once_then_error_reset() {
    for f in Fault::ALL {
        let mut b = Bench::new();
        b.tick_to(1000);
        b.take();
        b.dev.set_faults(&[f]);
        b.tick_to(2000);
        b.tick_to(3000);
        let e = emcys(&b.take());
        let reg = emcy::register_bits(fault_code(f));
        assert_eq!(e, vec![(fault_code(f), reg, f.code())], "{f:?}");
        assert_eq!(b.read_u32(0x1001, 0), u32::from(reg));
        assert_eq!(b.read_u32(0x1003, 0), 1);
        assert_eq!(
            b.read_u32(0x1003, 1),
            (u32::from(f.code()) << 16) | u32::from(fault_code(f))
        );
        b.dev.set_faults(&[]);
        b.tick_to(4000);
        assert_eq!(emcys(&b.take()), vec![(0, 0, 0)], "{f:?}");
    }
}

#[test]
fn fault_codes_are_cia_codes_and_shared_only_with_reason() {
    let shared: &[(Fault, Fault)] = &[
        (Fault::CurrentSenseError, Fault::BusSenseError),
        (Fault::Watchdog, Fault::LoopOverrun),
        (Fault::AngleSensorError, Fault::AngleSensorImplausible),
        (Fault::OverSpeed, Fault::SpeedRunaway),
    ];
    for a in Fault::ALL {
        let c = fault_code(a);
        assert!((0x2000..0x9000).contains(&c), "{a:?}");
        assert_ne!(emcy::register_bits(c), 0);
        for b in Fault::ALL {
            if a != b && fault_code(b) == c {
                assert!(
                    shared.contains(&(a, b)) || shared.contains(&(b, a)),
                    "{a:?} and {b:?} share {c:#x}"
                );
            }
        }
    }
}

#[test]
fn history_is_newest_first_capped_at_8_and_cleared_by_writing_0() {
    let mut b = Bench::new();
    for (k, f) in Fault::ALL.iter().take(10).enumerate() {
        b.dev.set_faults(&[*f]);
        b.tick_to(1000 * (2 * k as u64 + 1));
        b.dev.set_faults(&[]);
        b.tick_to(1000 * (2 * k as u64 + 2));
    }
    assert_eq!(b.read_u32(0x1003, 0), 8);
    assert_eq!(
        b.read_u32(0x1003, 1) & 0xFFFF,
        u32::from(fault_code(Fault::ALL[9]))
    );
    assert_eq!(
        b.read_u32(0x1003, 8) & 0xFFFF,
        u32::from(fault_code(Fault::ALL[2]))
    );
    b.write(0x1003, 0, &[0]).unwrap();
    assert_eq!(b.read_u32(0x1003, 0), 0);
}

#[test]
fn profile_fault_and_bus_off() {
    let mut b = Bench::new();
    b.tick_to(1000);
    b.take();
    b.node_profile_mut(|p| p.fault = Some(emcy::FOLLOWING_ERROR));
    b.tick_to(2000);
    b.tick_to(3000);
    assert_eq!(emcys(&b.take()), vec![(0x8611, 0x21, 0)]);
    b.node_profile_mut(|p| p.fault = None);
    b.tick_to(4000);
    assert_eq!(emcys(&b.take()), vec![(0, 0, 0)]);
    let sent = &mut b.sent;
    b.node
        .on_bus_state(BusState::BusOff, 5000, &mut b.dev, &mut |f| sent.push(f));
    b.node
        .on_bus_state(BusState::BusOff, 5100, &mut b.dev, &mut |f| sent.push(f));
    assert_eq!(b.node.cia402().lost, 1);
    b.node
        .on_bus_state(BusState::ErrorActive, 6000, &mut b.dev, &mut |f| {
            sent.push(f)
        });
    assert_eq!(emcys(&b.take()), vec![(0x8140, 0x11, 0)]);
}

// ---------------------------------------------------------------- store

#[test]
fn save_path_stores_the_drive_and_the_comm_settings() {
    let mut b = Bench::new();
    // Not saved: a reset keeps the node id.
    b.write(0x2100, 0, &[8]).unwrap();
    b.nmt(0x81, ID);
    assert_eq!(b.node.node_id(), ID);
    b.write(0x2100, 0, &[9]).unwrap();
    b.write(0x2101, 0, &1000u16.to_le_bytes()).unwrap();
    assert_eq!(
        b.node.settings().node_id(),
        ID,
        "takes effect after save + reset"
    );
    b.write_u32(0x1010, 1, SAVE).unwrap();
    assert_eq!(b.dev.stores, vec![StoreOp::Save]);
    assert_eq!(
        b.dev.saved,
        Some(CommSettings::new(9, 1000, 100, Some((1, 300))).unwrap())
    );
    // Failures: 0x06060000.
    b.dev.save_comm_fails = true;
    assert_eq!(b.write_u32(0x1010, 1, SAVE), Err(0x0606_0000));
    b.dev.store_fails = true;
    assert_eq!(b.write_u32(0x1010, 1, SAVE), Err(0x0606_0000));
    b.dev.store_fails = false;
    assert_eq!(b.read_u32(0x1010, 1), 1);
    // Reset node takes the saved node id.
    b.sent.clear();
    b.nmt(0x81, ID);
    assert_eq!(b.node.node_id(), 9);
    assert!(b.take().contains(&CanFrame::new(0x709, &[0]).unwrap()));
}

/// 0x1010 writes two records (the CAN settings, then the drive's): when
/// either write fails the SDO aborts with 0x06060000 and nothing stored
/// has changed (the CAN record is written back when the drive's fails).
#[test]
fn an_aborted_save_changes_nothing_stored() {
    let mut b = Bench::new();
    b.write(0x2100, 0, &[9]).unwrap();
    b.write_u32(0x1010, 1, SAVE).unwrap();
    let before = (b.dev.stores.clone(), b.dev.saved);
    b.write(0x2100, 0, &[10]).unwrap();
    // The CAN record cannot be written: the drive's is not touched.
    b.dev.save_comm_fails = true;
    assert_eq!(b.write_u32(0x1010, 1, SAVE), Err(0x0606_0000));
    assert_eq!((b.dev.stores.clone(), b.dev.saved), before);
    b.dev.save_comm_fails = false;
    // The drive's record cannot be written: the CAN record goes back.
    b.dev.store_fails = true;
    assert_eq!(b.write_u32(0x1010, 1, SAVE), Err(0x0606_0000));
    assert_eq!((b.dev.stores.clone(), b.dev.saved), before);
    b.dev.store_fails = false;
    // A reset node takes the last saved node id, not the aborted one.
    b.nmt(0x81, ID);
    assert_eq!(b.node.node_id(), 9);
    // Never saved in this run: the rollback writes what the node started
    // with (the store's record, or the defaults where it had none).
    let mut b = Bench::new();
    let boot = *b.node.settings();
    b.write(0x2100, 0, &[11]).unwrap();
    b.dev.store_fails = true;
    assert_eq!(b.write_u32(0x1010, 1, SAVE), Err(0x0606_0000));
    assert_eq!(b.dev.saved, Some(boot));
    assert!(b.dev.stores.is_empty());
}

#[test]
fn restore_forgets_the_saved_settings() {
    let mut b = Bench::new();
    b.write(0x2100, 0, &[9]).unwrap();
    b.write_u32(0x1010, 1, SAVE).unwrap();
    // Restore erases the store: a reset then keeps the settings in force
    // (the defaults come at the next power-on), not the erased ones.
    b.write_u32(0x1011, 1, LOAD).unwrap();
    assert_eq!(b.dev.stores.last(), Some(&StoreOp::Erase));
    assert_eq!(b.write_u32(0x1011, 1, SAVE), Err(0x0800_0020));
    b.nmt(0x81, ID);
    assert_eq!(b.node.node_id(), ID);
}

#[test]
fn manufacturer_objects_read_the_drive_and_write_gains_through_it() {
    let mut b = Bench::new();
    assert_eq!(b.read_u32(0x2100, 0), 5);
    assert_eq!(b.read_u32(0x2000, 0), 7);
    assert_eq!(f32::from_bits(b.read_u32(0x2001, 0)), 0.12);
    assert_eq!(b.read(0x2002, 0), Err(0x0800_0024), "the device has no Ld");
    assert_eq!(b.read_u32(0x2006, 0), 10_203);
    assert_eq!(b.read_u32(0x2007, 0), 0, "on the angle sensor");
    b.dev.sensorless = true;
    assert_eq!(b.read_u32(0x2007, 0), 1, "sensorless");
    b.dev.sensorless = false;
    assert_eq!(b.read_u32(0x6075, 0), 10_000);
    assert_eq!(b.read_u32(0x6076, 0), 1000);
    b.write_u32(0x2012, 0, 1.5f32.to_bits()).unwrap();
    let g = b.dev.ctx.speed_gains.unwrap();
    assert_eq!((g.kp_a_per_rad_s, g.ki_a_per_rad), (1.5, 2.0));
    b.dev.ctx.mode = Mode::Velocity;
    assert_eq!(b.write_u32(0x2013, 0, 1.0f32.to_bits()), Err(0x0800_0022));
    assert_eq!(b.read_u32(0x60C2, 1), 1);
    assert_eq!(b.read(0x60C2, 2), Ok(vec![0xFD]));
    b.write_u32(0x1006, 0, 250).unwrap();
    assert_eq!(b.read_u32(0x60C2, 1), 25); // 25e-5 s
    assert_eq!(b.read(0x60C2, 2), Ok(vec![0xFB]));
    b.write_u32(0x1006, 0, 0).unwrap();
    assert_eq!(b.read_u32(0x60C2, 1), 0);
}

/// 0x2008, the d-current reference (design §30): each sub-index reads and
/// writes one setting through the drive; a value the parameter does not
/// take, a write while running and the drive's refusal (field weakening
/// on halls) abort and change nothing.
#[test]
fn the_d_current_reference_is_written_one_setting_at_a_time() {
    let mut b = Bench::new();
    assert_eq!(b.read_u32(0x2008, 0), 4);
    assert_eq!(b.read(0x2008, 1), Ok(vec![0]), "field weakening off");
    assert_eq!(f32::from_bits(b.read_u32(0x2008, 3)), 10.0);
    b.write(0x2008, 1, &[1]).unwrap();
    b.write(0x2008, 2, &[1]).unwrap();
    b.write_u32(0x2008, 3, 4.5f32.to_bits()).unwrap();
    b.write(0x2008, 4, &[1]).unwrap();
    assert_eq!(b.read(0x2008, 1), Ok(vec![1]));
    assert_eq!(b.read(0x2008, 2), Ok(vec![1]));
    assert_eq!(f32::from_bits(b.read_u32(0x2008, 3)), 4.5);
    assert_eq!(b.read(0x2008, 4), Ok(vec![1]));
    assert!(b.dev.field.field_weakening && b.dev.field.mtpa && b.dev.field.short_circuit);
    let before = b.snapshot();
    let calls = b.dev.ctx.calls;
    // Values the parameter does not take, and the drive's rule (max-id 0
    // while field weakening is on).
    for (sub, data, abort) in [
        (1u8, vec![2u8], 0x0609_0031u32),
        (3, f32::NAN.to_le_bytes().to_vec(), 0x0609_0030),
        (3, (-1.0f32).to_le_bytes().to_vec(), 0x0609_0032),
        (3, 1.0e7f32.to_le_bytes().to_vec(), 0x0609_0031),
        (3, 0.0f32.to_le_bytes().to_vec(), 0x0609_0030),
        (5, vec![1], 0x0609_0011),
    ] {
        assert_eq!(
            b.write(0x2008, sub, &data),
            Err(abort),
            "sub {sub} {data:?}"
        );
    }
    // Not while running.
    b.dev.ctx.mode = Mode::Velocity;
    assert_eq!(b.write(0x2008, 2, &[0]), Err(0x0800_0022));
    b.dev.ctx.mode = Mode::Disabled;
    assert_eq!(b.snapshot(), before);
    assert_eq!(b.dev.ctx.calls, calls);
    // Halls: field weakening refused by the drive, MTPA taken.
    let mut b = Bench::new();
    b.dev.angle.sensor_counts_per_rev = 48;
    assert_eq!(b.write(0x2008, 1, &[1]), Err(0x0609_0030));
    assert_eq!(b.read(0x2008, 1), Ok(vec![0]));
    b.write(0x2008, 2, &[1]).unwrap();
    assert!(b.dev.field.mtpa && !b.dev.field.field_weakening);
}

#[test]
fn comm_settings_and_the_stored_record_agree() {
    assert_eq!(
        CommSettings::DEFAULT.to_record(),
        foc_store::CanRecord::DEFAULT
    );
    assert_eq!(
        CommSettings::from_record(&foc_store::CanRecord::DEFAULT),
        Ok(CommSettings::DEFAULT)
    );
    let s = CommSettings::new(9, 250, 50, Some((127, 300))).unwrap();
    assert_eq!(CommSettings::from_record(&s.to_record()), Ok(s));
    assert!(s.to_record().validate().is_ok());
    // What one refuses the other refuses.
    for (id, kbit, consumer) in [
        (0u8, 1000u16, 0u8),
        (128, 1000, 0),
        (5, 800, 0),
        (5, 1000, 5),
    ] {
        let r = foc_store::CanRecord {
            node_id: id,
            bitrate_kbit: kbit,
            heartbeat_ms: 100,
            consumer_node: consumer,
            consumer_ms: if consumer == 0 { 0 } else { 100 },
        };
        assert!(r.validate().is_err());
        assert!(CommSettings::from_record(&r).is_err());
    }
}

/// 0x2009 and 0x200A, the tables kept with the configuration (design §32,
/// §33): sub 1 the switch, sub 2 the calibration (write 1 to start it;
/// reads 1 while it runs), sub 3 the table's peak. A switch without its
/// table, a calibration on an uncalibrated drive, on halls or while
/// running abort with the drive's reason and change nothing.
#[test]
fn the_tables_are_switched_and_calibrated_through_their_objects() {
    use foc_core::calibration::identification::Step;
    use foc_core::drive::Progress;
    use foc_protocol::message::Calibration;
    let mut b = Bench::new();
    for index in [0x2009u16, 0x200A] {
        assert_eq!(b.read_u32(index, 0), 3);
        assert_eq!(b.read(index, 1), Ok(vec![0]), "{index:#x} off");
        assert_eq!(b.read(index, 2), Ok(vec![0]), "{index:#x} not running");
        assert_eq!(f32::from_bits(b.read_u32(index, 3)), 0.0);
        // On without a table: the drive's refusal (its state).
        assert_eq!(b.write(index, 1, &[1]), Err(0x0800_0022));
        // Only 1 starts the calibration.
        for v in [0u8, 2] {
            assert_eq!(b.write(index, 2, &[v]), Err(0x0609_0030));
        }
        // The peak is read-only.
        assert_eq!(b.write_u32(index, 3, 0), Err(0x0601_0002));
        assert_eq!(b.read(index, 4), Err(0x0609_0011));
    }
    assert_eq!(b.dev.ctx.calibration, None);
    let before = b.snapshot();
    // Not while running, nor on an uncalibrated drive, nor on halls.
    b.dev.ctx.mode = Mode::Velocity;
    assert_eq!(b.write(0x2009, 2, &[1]), Err(0x0800_0022));
    b.dev.ctx.mode = Mode::Disabled;
    b.dev.ctx.calibrated = false;
    assert_eq!(b.write(0x200A, 2, &[1]), Err(0x0800_0022));
    b.dev.ctx.calibrated = true;
    b.dev.angle.sensor_counts_per_rev = 48;
    assert_eq!(b.write(0x2009, 2, &[1]), Err(0x0609_0030));
    assert_eq!(b.write(0x200A, 2, &[1]), Err(0x0609_0030));
    b.dev.angle.sensor_counts_per_rev = 4096;
    assert_eq!(b.dev.ctx.calibration, None);
    assert_eq!(b.snapshot(), before);
    // Started; the running calibration reads 1 on its own object only.
    b.write(0x2009, 2, &[1]).unwrap();
    assert_eq!(b.dev.ctx.calibration, Some(Calibration::Anticogging));
    b.dev.progress = Progress::Running(Step::Cogging);
    assert_eq!(b.read(0x2009, 2), Ok(vec![1]));
    assert_eq!(b.read(0x200A, 2), Ok(vec![0]));
    b.dev.progress = Progress::Done;
    assert_eq!(b.read(0x2009, 2), Ok(vec![0]));
    b.write(0x200A, 2, &[1]).unwrap();
    assert_eq!(
        b.dev.ctx.calibration,
        Some(Calibration::EncoderLinearisation)
    );
    // Measured: on, with their peaks; switched by sub 1.
    assert_eq!(b.read(0x2009, 1), Ok(vec![1]));
    assert_eq!(f32::from_bits(b.read_u32(0x2009, 3)), 0.25);
    assert_eq!(f32::from_bits(b.read_u32(0x200A, 3)), 0.004);
    b.write(0x2009, 1, &[0]).unwrap();
    assert_eq!(b.read(0x2009, 1), Ok(vec![0]));
    assert_eq!(b.dev.cogging, Some(false));
    b.write(0x2009, 1, &[1]).unwrap();
    assert_eq!(b.dev.cogging, Some(true));
    // Not while running.
    b.dev.ctx.mode = Mode::Velocity;
    assert_eq!(b.write(0x200A, 1, &[0]), Err(0x0800_0022));
    assert_eq!(b.dev.correction, Some(true));
}
