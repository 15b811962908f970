//! The store: versions, checksums, garbage, invalid records, wear.

use super::record_tests::envelope;
use super::{record_a, record_b};
use crate::fake::FakeFlash;
use crate::record::{DriveRecord, Invalid, RecordError, MAX_RECORD_BYTES, SCHEMA_VERSION};
use crate::store::{Store, StoreError};
use embedded_storage::nor_flash::NorFlash;

/// Four pages of 4 KiB: a page must hold the largest record (2 KiB).
type Flash4 = FakeFlash<4, 4096, 4>;

fn new_store(f: &mut Flash4) -> Store<&mut Flash4> {
    Store::new(f, 0..16384).unwrap()
}

fn payload_of(r: &DriveRecord) -> std::vec::Vec<u8> {
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let n = r.encode(&mut buf).unwrap();
    buf[4..n - 4].to_vec()
}

#[test]
fn layout_is_checked() {
    let mut f = Flash4::new();
    assert!(matches!(
        Store::new(&mut f, 0..4096),
        Err(StoreError::Layout)
    ));
    assert!(matches!(
        Store::new(&mut f, 1..8193),
        Err(StoreError::Layout)
    ));
    assert!(matches!(
        Store::new(&mut f, 0..8000),
        Err(StoreError::Layout)
    ));
    assert!(matches!(
        Store::new(&mut f, 8192..24576),
        Err(StoreError::Layout)
    ));
    assert!(matches!(
        Store::new(
            &mut f,
            core::ops::Range {
                start: 8192,
                end: 4096
            }
        ),
        Err(StoreError::Layout)
    ));
    // Pages too small for the largest record: 128 B, and 2 KiB since
    // schema 9 (a record with both tables takes up to 1861 bytes, the
    // envelope's bound 2048).
    let mut tiny = FakeFlash::<4, 128, 4>::new();
    assert!(matches!(
        Store::new(&mut tiny, 0..512),
        Err(StoreError::Layout)
    ));
    let mut small = FakeFlash::<4, 2048, 4>::new();
    assert!(matches!(
        Store::new(&mut small, 0..8192),
        Err(StoreError::Layout)
    ));
    assert!(Store::new(&mut f, 4096..12288).is_ok());
    assert!(Store::new(&mut f, 0..16384).is_ok());
}

#[test]
fn empty_then_saved_then_erased() {
    let mut f = Flash4::new();
    let mut s = new_store(&mut f);
    assert_eq!(s.load(), Ok(None));
    s.save(&record_a()).unwrap();
    assert_eq!(s.load(), Ok(Some(record_a())));
    s.save(&record_b()).unwrap();
    assert_eq!(s.load(), Ok(Some(record_b())));
    s.erase().unwrap();
    assert_eq!(s.load(), Ok(None));
    // A new store on the same flash sees what the old one wrote.
    s.save(&record_a()).unwrap();
    let _ = s.into_flash();
    assert_eq!(new_store(&mut f).load(), Ok(Some(record_a())));
}

#[test]
fn newer_and_older_versions_are_refused() {
    for version in [0, SCHEMA_VERSION + 1, 0x7FFF] {
        let mut f = Flash4::new();
        let mut s = new_store(&mut f);
        s.save(&record_a()).unwrap();
        s.save_raw(&envelope(version, &payload_of(&record_b())))
            .unwrap();
        assert_eq!(
            s.load(),
            Err(StoreError::Record(RecordError::UnsupportedVersion {
                found: version,
                supported: SCHEMA_VERSION
            })),
            "version {version}"
        );
    }
}

#[test]
fn bad_envelope_checksum_is_reported() {
    let mut f = Flash4::new();
    let mut s = new_store(&mut f);
    s.save(&record_a()).unwrap();
    let mut bytes = envelope(SCHEMA_VERSION, &payload_of(&record_b()));
    let last = bytes.len() - 1;
    bytes[last] ^= 0x01;
    // Stored through the map: sequential-storage's own CRC is right.
    s.save_raw(&bytes).unwrap();
    assert_eq!(s.load(), Err(StoreError::Record(RecordError::BadChecksum)));
    // Saving a good record again recovers.
    s.save(&record_b()).unwrap();
    assert_eq!(s.load(), Ok(Some(record_b())));
}

#[test]
fn invalid_records_are_refused_by_save_and_load() {
    let mut f = Flash4::new();
    let mut s = new_store(&mut f);
    s.save(&record_a()).unwrap();
    let _ = s.into_flash();
    let before = f.clone();
    let mut bad = record_b();
    bad.motor.r_ohm = f32::NAN;
    let mut s = new_store(&mut f);
    assert_eq!(
        s.save(&bad),
        Err(StoreError::Invalid(Invalid {
            field: "motor.r_ohm"
        }))
    );
    let _ = s.into_flash();
    assert_eq!(f.writes(), before.writes(), "nothing written on refusal");
    let mut s = new_store(&mut f);
    assert_eq!(s.load(), Ok(Some(record_a())));
    // Written raw, load refuses it.
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let n = bad.encode(&mut buf).unwrap();
    s.save_raw(&buf[..n]).unwrap();
    assert_eq!(
        s.load(),
        Err(StoreError::Invalid(Invalid {
            field: "motor.r_ohm"
        }))
    );
}

fn garbage_then_recover(mut f: Flash4, what: &str) {
    let got = new_store(&mut f).load();
    std::eprintln!("load of {what}: {got:?}");
    match got {
        Ok(None) | Err(_) => {}
        Ok(Some(r)) => panic!("garbage ({what}) loaded as a record: {r:?}"),
    }
    let mut s = new_store(&mut f);
    s.erase().unwrap();
    assert_eq!(s.load(), Ok(None));
    s.save(&record_a()).unwrap();
    assert_eq!(s.load(), Ok(Some(record_a())));
}

#[test]
fn garbage_region_is_never_a_record() {
    for byte in [0x5A, 0x00, 0xA5, 0x0F, 0xFE] {
        garbage_then_recover(
            Flash4::filled(byte),
            &std::format!("0x{byte:02X} everywhere"),
        );
    }
    // Random bytes (a fixed xorshift so failures reproduce).
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    for seed in 0..200 {
        let mut f = Flash4::new();
        for b in f.bytes_mut() {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *b = x as u8;
        }
        let got = new_store(&mut f).load();
        // Never a record, and never taken for an empty store either.
        assert!(got.is_err(), "seed {seed}: {got:?}");
        if seed < 3 {
            garbage_then_recover(f, &std::format!("random bytes #{seed}"));
        }
    }
}

#[test]
fn a_valid_log_behind_garbage_items_still_loads() {
    // A record, then garbage written raw into the free space of the open
    // page (a half-written foreign item): the record stays readable.
    let mut f = Flash4::new();
    new_store(&mut f).save(&record_a()).unwrap();
    let mut junk = [0u8; 64];
    for (i, b) in junk.iter_mut().enumerate() {
        *b = (i as u8).wrapping_mul(37) | 1;
    }
    f.write(512, &junk).unwrap();
    let mut s = new_store(&mut f);
    assert_eq!(s.load(), Ok(Some(record_a())));
    s.save(&record_b()).unwrap();
    assert_eq!(s.load(), Ok(Some(record_b())));
}

fn wear<const PAGES: usize>(saves: usize) {
    let mut f = FakeFlash::<PAGES, 4096, 4>::new();
    let mut s = Store::new(&mut f, 0..(PAGES as u32 * 4096)).unwrap();
    // A small record and one with both tables, in turn.
    let (a, b) = (record_a(), super::record_t());
    for i in 0..saves {
        let r = if i % 2 == 0 { &a } else { &b };
        s.save(r).unwrap_or_else(|e| panic!("save {i}: {e}"));
        if i % 97 == 0 {
            assert_eq!(s.load().as_ref(), Ok(&Some(r.clone())), "save {i}");
        }
    }
    let last = if (saves - 1).is_multiple_of(2) {
        &a
    } else {
        &b
    };
    assert_eq!(s.load().as_ref(), Ok(&Some(last.clone())));
    let _ = s.into_flash();
    let per_page = f.erases_per_page();
    let (min, max) = (
        *per_page.iter().min().unwrap(),
        *per_page.iter().max().unwrap(),
    );
    std::eprintln!(
        "{saves} saves on {PAGES} pages of 4 KiB: erases per page {per_page:?}, {} word writes",
        f.writes()
    );
    assert!(min > 0, "every page takes its share: {per_page:?}");
    assert!(max * 10 <= min * 11 + 10, "wear spread: {per_page:?}");
    assert_eq!(f.rewrites(), 0, "no word is programmed twice");
}

#[test]
fn many_saves_rotate_pages_evenly_2_pages() {
    wear::<2>(4000);
}

#[test]
fn many_saves_rotate_pages_evenly_4_pages() {
    wear::<4>(6000);
}

#[test]
fn store_error_messages() {
    assert_eq!(
        std::format!(
            "{}",
            StoreError::Invalid(Invalid {
                field: "limits.max_current_a"
            })
        ),
        "record value `limits.max_current_a` is out of range"
    );
    assert!(std::format!("{}", StoreError::Corrupt).contains("erase"));
    let mut f = Flash4::new();
    let s = new_store(&mut f);
    let _: &mut Flash4 = s.into_flash();
}

#[test]
fn a_damaged_record_is_reported_not_taken_for_an_empty_store() {
    let mut f = Flash4::new();
    assert_eq!(new_store(&mut f).load(), Ok(None), "blank: empty");
    new_store(&mut f).save(&record_a()).unwrap();
    // Flip bits in the stored envelope (its payload, past the item header):
    // the item fails sequential-storage's CRC and is skipped.
    let mut hit = 0;
    for (i, b) in f.bytes_mut().enumerate() {
        if (40..48).contains(&i) && *b != 0xFF {
            *b ^= 0x10;
            hit += 1;
        }
    }
    assert!(hit > 0);
    assert_eq!(new_store(&mut f).load(), Err(StoreError::NoValidRecord));
    // Erased: empty again, and usable.
    let mut s = new_store(&mut f);
    s.erase().unwrap();
    assert_eq!(s.load(), Ok(None));
    s.save(&record_b()).unwrap();
    assert_eq!(s.load(), Ok(Some(record_b())));
}

#[test]
fn a_first_save_cut_short_is_never_a_record_nor_empty() {
    let mut probe = Flash4::new();
    new_store(&mut probe).save(&record_a()).unwrap();
    let words = probe.writes();
    for n in 0..words {
        let mut f = Flash4::new();
        f.cut_power_after_words(n);
        assert!(new_store(&mut f).save(&record_a()).is_err());
        f.restore_power();
        let got = new_store(&mut f).load();
        match got {
            Ok(Some(r)) => assert_eq!(r, record_a(), "cut after {n} words"),
            Ok(None) => assert_eq!(n, 0, "cut after {n} words: something was written"),
            Err(StoreError::NoValidRecord) => {}
            other => panic!("cut after {n} words: {other:?}"),
        }
    }
}

/// A stored record whose table foc-core's check refuses (written raw, as
/// another firmware might have): the load names it, nothing is taken;
/// a save of it is refused before anything is written.
#[test]
fn a_stored_record_with_an_implausible_table_is_refused_by_name() {
    let mut f = Flash4::new();
    let mut s = new_store(&mut f);
    let mut bad = super::record_t();
    bad.cogging.as_mut().unwrap().scale_a = f32::NAN;
    assert_eq!(
        s.save(&bad),
        Err(StoreError::Invalid(Invalid {
            field: "cogging.scale_a"
        }))
    );
    assert_eq!(s.load(), Ok(None), "nothing written");
    s.save_raw(&envelope(SCHEMA_VERSION, &payload_of(&bad)))
        .unwrap();
    assert_eq!(
        s.load(),
        Err(StoreError::Invalid(Invalid {
            field: "cogging.scale_a"
        }))
    );
    // The good one, saved after, loads whole with its tables.
    s.save(&super::record_t()).unwrap();
    assert_eq!(s.load(), Ok(Some(super::record_t())));
}
