//! The CAN node settings: envelope, validation, the store's key for them
//! (apart from the drive record), defaults, corrupt bytes, power cuts.

use super::{record_a, record_b};
use crate::can::{CanRecord, CAN_SCHEMA_VERSION, MAX_CAN_RECORD_BYTES};
use crate::fake::FakeFlash;
use crate::record::{Invalid, RecordError};
use crate::store::{Store, StoreError};
use proptest::prelude::*;
use std::{vec, vec::Vec};

type Flash4 = FakeFlash<4, 4096, 4>;

fn new_store(f: &mut Flash4) -> Store<&mut Flash4> {
    Store::new(f, 0..16384).unwrap()
}

fn can_a() -> CanRecord {
    CanRecord {
        node_id: 5,
        bitrate_kbit: 500,
        heartbeat_ms: 100,
        consumer_node: 1,
        consumer_ms: 350,
    }
}

fn can_b() -> CanRecord {
    CanRecord {
        node_id: 127,
        bitrate_kbit: 125,
        heartbeat_ms: 0,
        consumer_node: 0,
        consumer_ms: 0,
    }
}

fn largest() -> CanRecord {
    CanRecord {
        node_id: 127,
        bitrate_kbit: u16::MAX,
        heartbeat_ms: u16::MAX,
        consumer_node: 126,
        consumer_ms: u16::MAX,
    }
}

fn envelope(r: &CanRecord) -> Vec<u8> {
    let mut buf = [0u8; MAX_CAN_RECORD_BYTES];
    let n = r.encode(&mut buf).unwrap();
    buf[..n].to_vec()
}

/// `payload` in an envelope of `version` with a correct CRC.
fn envelope_of(version: u16, payload: &[u8]) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend_from_slice(&version.to_le_bytes());
    v.extend_from_slice(&(payload.len() as u16).to_le_bytes());
    v.extend_from_slice(payload);
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&v);
    v.extend_from_slice(&crc.to_le_bytes());
    v
}

#[test]
fn round_trip_and_defaults() {
    for r in [CanRecord::DEFAULT, can_a(), can_b(), largest()] {
        assert_eq!(CanRecord::decode(&envelope(&r)), Ok(r));
    }
    assert_eq!(CanRecord::default(), CanRecord::DEFAULT);
    assert_eq!(CanRecord::DEFAULT.validate(), Ok(()));
    assert_eq!(can_a().validate(), Ok(()));
    assert_eq!(can_b().validate(), Ok(()));
    // The widest payload fits with room to spare.
    assert_eq!(envelope(&largest()).len(), 4 + 11 + 4);
}

#[test]
fn encode_refuses_a_short_buffer() {
    let need = envelope(&can_a()).len();
    for n in 0..need {
        let mut buf = vec![0u8; n];
        assert_eq!(can_a().encode(&mut buf), Err(RecordError::TooLong), "{n}");
    }
}

#[test]
fn validation_names_the_field() {
    let bad = |r: CanRecord| r.validate().map_err(|Invalid { field }| field);
    let ok = can_a();
    assert_eq!(bad(CanRecord { node_id: 0, ..ok }), Err("can.node_id"));
    assert_eq!(bad(CanRecord { node_id: 128, ..ok }), Err("can.node_id"));
    assert_eq!(bad(CanRecord { node_id: 255, ..ok }), Err("can.node_id"));
    for kbit in [0, 10, 20, 50, 100, 800, 1001, u16::MAX] {
        assert_eq!(
            bad(CanRecord {
                bitrate_kbit: kbit,
                ..ok
            }),
            Err("can.bitrate_kbit")
        );
    }
    for kbit in [125, 250, 500, 1000] {
        assert_eq!(
            bad(CanRecord {
                bitrate_kbit: kbit,
                ..ok
            }),
            Ok(())
        );
    }
    // Its own heartbeat, or no node.
    assert_eq!(
        bad(CanRecord {
            consumer_node: 5,
            ..ok
        }),
        Err("can.consumer_node")
    );
    assert_eq!(
        bad(CanRecord {
            consumer_node: 128,
            ..ok
        }),
        Err("can.consumer_node")
    );
    // A consumer needs a time; no consumer, no time.
    assert_eq!(
        bad(CanRecord {
            consumer_ms: 0,
            ..ok
        }),
        Err("can.consumer_ms")
    );
    assert_eq!(
        bad(CanRecord {
            consumer_node: 0,
            ..ok
        }),
        Err("can.consumer_ms")
    );
    // Any heartbeat period (0 = off).
    for ms in [0, 1, u16::MAX] {
        assert_eq!(
            bad(CanRecord {
                heartbeat_ms: ms,
                ..ok
            }),
            Ok(())
        );
    }
}

#[test]
fn corrupt_envelopes_are_errors() {
    let good = envelope(&can_a());
    // Every truncation.
    for n in 0..good.len() {
        assert!(CanRecord::decode(&good[..n]).is_err(), "truncated to {n}");
    }
    // A byte too many.
    let mut long = good.clone();
    long.push(0);
    assert_eq!(CanRecord::decode(&long), Err(RecordError::TooLong));
    // Every single-bit flip.
    for i in 0..good.len() * 8 {
        let mut b = good.clone();
        b[i / 8] ^= 1 << (i % 8);
        assert!(CanRecord::decode(&b).is_err(), "bit {i}");
    }
    // Longer than any envelope.
    assert_eq!(
        CanRecord::decode(&[0u8; MAX_CAN_RECORD_BYTES + 1]),
        Err(RecordError::TooLong)
    );
    // Erased flash.
    assert!(CanRecord::decode(&[0xFF; 19]).is_err());
}

#[test]
fn versions_and_payloads_are_checked_after_the_crc() {
    let mut payload = envelope(&can_a());
    payload.truncate(payload.len() - 4);
    let payload = payload.split_off(4);
    assert_eq!(
        CanRecord::decode(&envelope_of(CAN_SCHEMA_VERSION + 1, &payload)),
        Err(RecordError::UnsupportedVersion {
            found: CAN_SCHEMA_VERSION + 1,
            supported: CAN_SCHEMA_VERSION
        })
    );
    assert_eq!(
        CanRecord::decode(&envelope_of(0, &payload)),
        Err(RecordError::UnsupportedVersion {
            found: 0,
            supported: CAN_SCHEMA_VERSION
        })
    );
    // Trailing payload byte, missing byte: malformed.
    let mut longer = payload.clone();
    longer.push(0);
    assert_eq!(
        CanRecord::decode(&envelope_of(CAN_SCHEMA_VERSION, &longer)),
        Err(RecordError::Malformed)
    );
    assert_eq!(
        CanRecord::decode(&envelope_of(
            CAN_SCHEMA_VERSION,
            &payload[..payload.len() - 1]
        )),
        Err(RecordError::Malformed)
    );
    // A drive record is not a CAN record.
    let mut drive = [0u8; crate::MAX_RECORD_BYTES];
    let n = record_a().encode(&mut drive).unwrap();
    assert!(CanRecord::decode(&drive[..n]).is_err());
}

proptest! {
    #[test]
    fn decode_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..48)) {
        let _ = CanRecord::decode(&bytes);
    }

    #[test]
    fn decode_of_any_payload_in_a_valid_envelope_never_panics(
        payload in proptest::collection::vec(any::<u8>(), 0..24)
    ) {
        if let Ok(r) = CanRecord::decode(&envelope_of(CAN_SCHEMA_VERSION, &payload)) {
            // Whatever decodes re-encodes to the same record.
            prop_assert_eq!(CanRecord::decode(&envelope(&r)), Ok(r));
        }
    }

    #[test]
    fn every_record_round_trips(
        node_id in any::<u8>(), bitrate_kbit in any::<u16>(), heartbeat_ms in any::<u16>(),
        consumer_node in any::<u8>(), consumer_ms in any::<u16>()
    ) {
        let r = CanRecord { node_id, bitrate_kbit, heartbeat_ms, consumer_node, consumer_ms };
        prop_assert_eq!(CanRecord::decode(&envelope(&r)), Ok(r));
    }
}

#[test]
fn absent_gives_none_and_defaults() {
    let mut f = Flash4::new();
    let mut s = new_store(&mut f);
    assert_eq!(s.load_can(), Ok(None));
    assert_eq!(s.load_can_or_default(), Ok(CanRecord::DEFAULT));
    // A drive record alone: still no CAN settings.
    s.save(&record_a()).unwrap();
    assert_eq!(s.load_can(), Ok(None));
    assert_eq!(s.load_can_or_default(), Ok(CanRecord::DEFAULT));
    assert_eq!(s.load(), Ok(Some(record_a())));
}

#[test]
fn can_settings_alone_leave_the_drive_record_absent() {
    let mut f = Flash4::new();
    let mut s = new_store(&mut f);
    s.save_can(&can_a()).unwrap();
    assert_eq!(s.load_can(), Ok(Some(can_a())));
    // Not `NoValidRecord`: the region holds a valid item, just not this key.
    assert_eq!(s.load(), Ok(None));
}

#[test]
fn the_two_records_are_independent() {
    let mut f = Flash4::new();
    let mut s = new_store(&mut f);
    s.save(&record_a()).unwrap();
    s.save_can(&can_a()).unwrap();
    s.save(&record_b()).unwrap();
    assert_eq!(s.load_can(), Ok(Some(can_a())));
    s.save_can(&can_b()).unwrap();
    assert_eq!(s.load(), Ok(Some(record_b())));
    assert_eq!(s.load_can(), Ok(Some(can_b())));
    // Many saves of one, through page rotations: the other survives.
    for i in 0..200 {
        let r = if i % 2 == 0 { can_a() } else { can_b() };
        s.save_can(&r).unwrap();
        assert_eq!(s.load(), Ok(Some(record_b())), "save {i}");
    }
    assert_eq!(s.load_can(), Ok(Some(can_b())));
    // Erase takes both.
    s.erase().unwrap();
    assert_eq!(s.load(), Ok(None));
    assert_eq!(s.load_can(), Ok(None));
}

#[test]
fn invalid_settings_are_refused_by_save_and_load() {
    let mut f = Flash4::new();
    let mut s = new_store(&mut f);
    s.save_can(&can_a()).unwrap();
    let bad = CanRecord {
        node_id: 0,
        ..can_a()
    };
    assert_eq!(
        s.save_can(&bad),
        Err(StoreError::Invalid(Invalid {
            field: "can.node_id"
        }))
    );
    assert_eq!(s.load_can(), Ok(Some(can_a())), "nothing written");
    // Stored anyway (another firmware, a bug): load refuses it.
    s.save_can_raw(&envelope(&bad)).unwrap();
    assert_eq!(
        s.load_can(),
        Err(StoreError::Invalid(Invalid {
            field: "can.node_id"
        }))
    );
}

#[test]
fn corrupt_stored_bytes_are_an_error_not_the_defaults() {
    let mut f = Flash4::new();
    let mut s = new_store(&mut f);
    s.save(&record_a()).unwrap();
    let mut bytes = envelope(&can_a());
    bytes[6] ^= 0x40;
    s.save_can_raw(&bytes).unwrap();
    assert_eq!(
        s.load_can(),
        Err(StoreError::Record(RecordError::BadChecksum))
    );
    // Something longer than any envelope under the CAN key.
    s.save_can_raw(&[0u8; MAX_CAN_RECORD_BYTES + 1]).unwrap();
    assert_eq!(s.load_can(), Err(StoreError::Record(RecordError::TooLong)));
    // The drive record is unaffected; a good save repairs the CAN key.
    assert_eq!(s.load(), Ok(Some(record_a())));
    s.save_can(&can_b()).unwrap();
    assert_eq!(s.load_can(), Ok(Some(can_b())));
}

/// A power cut after every word of a CAN save, from many fill levels of
/// the log (so that some saves close a page, move the live items and
/// erase one): the CAN settings are the old or the new ones, never an
/// error or the defaults, and the drive record is untouched.
#[test]
fn power_cut_during_save_can_keeps_the_old_settings() {
    let range = 0..8192;
    let mut f = FakeFlash::<2, 4096, 4>::new();
    {
        let mut s = Store::new(&mut f, range.clone()).unwrap();
        s.save(&record_a()).unwrap();
        s.save_can(&can_a()).unwrap();
    }
    let (mut cuts, mut with_erase) = (0u64, 0u32);
    for level in 0..400 {
        // Measure one uninterrupted save of B from here.
        let mut full = f.clone();
        full.reset_counters();
        Store::new(&mut full, range.clone())
            .unwrap()
            .save_can(&can_b())
            .unwrap();
        let words = full.writes();
        if full.erases() > 0 {
            with_erase += 1;
        }
        for n in 0..words {
            let mut t = f.clone();
            t.cut_power_after_words(n);
            assert!(
                Store::new(&mut t, range.clone())
                    .unwrap()
                    .save_can(&can_b())
                    .is_err(),
                "level {level}, cut after {n} of {words} words"
            );
            t.restore_power();
            let mut s = Store::new(&mut t, range.clone()).unwrap();
            let got = s.load_can();
            assert!(
                got == Ok(Some(can_a())) || got == Ok(Some(can_b())),
                "level {level}, cut after {n} of {words} words: {got:?}"
            );
            assert_eq!(s.load(), Ok(Some(record_a())), "level {level}, cut {n}");
            // And the store still works.
            s.save_can(&can_b()).unwrap();
            assert_eq!(s.load_can(), Ok(Some(can_b())));
            cuts += 1;
        }
        // Next fill level: one more save of A.
        Store::new(&mut f, range.clone())
            .unwrap()
            .save_can(&can_a())
            .unwrap();
    }
    assert!(cuts > 1000, "{cuts} cuts");
    assert!(with_erase > 0, "no save erased a page");
}

/// The envelope of `can_a()` as this build (CAN schema version 1) writes
/// it, captured when the golden was added: a layout change must bump
/// `CAN_SCHEMA_VERSION` and keep this one decoding.
const CAN_V1_GOLDEN: [u8; 15] = [
    0x01, 0x00, 0x07, 0x00, 0x05, 0xf4, 0x03, 0x64, 0x01, 0xde, 0x02, 0x43, 0x8e, 0xc0, 0x11,
];

#[test]
fn the_can_record_writes_and_reads_its_golden_envelope() {
    assert_eq!(envelope(&can_a()), CAN_V1_GOLDEN);
    assert_eq!(CanRecord::decode(&CAN_V1_GOLDEN), Ok(can_a()));
    assert_eq!(
        crate::can::CAN_SCHEMA_VERSION,
        1,
        "a new version freezes CAN_V1_GOLDEN"
    );
}
