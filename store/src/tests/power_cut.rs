//! A power cut after every flash word of a save: the store holds the old
//! record or the new one, never a mix, never neither. The new one is the
//! largest kind (record B with both tables, 1.8 KB: many words).

use super::{record_a, record_t as record_b};
use crate::fake::FakeFlash;
use crate::record::DriveRecord;
use crate::store::Store;

/// Flash holding A as the newest record. With `compaction`, the region is
/// filled first so that the next save of B must close a page, move the
/// live item and erase a page.
fn flash_with_a<const P: usize, const PB: usize, const W: usize>(
    compaction: bool,
) -> FakeFlash<P, PB, W> {
    let range = 0..(P * PB) as u32;
    let mut f = FakeFlash::<P, PB, W>::new();
    let a = record_a();
    let b = record_b();
    // Some history first, so moved items have company.
    {
        let mut s = Store::new(&mut f, range.clone()).unwrap();
        s.save(&b).unwrap();
        s.save(&a).unwrap();
    }
    if !compaction {
        return f;
    }
    for i in 0..10_000 {
        let mut trial = f.clone();
        trial.reset_counters();
        Store::new(&mut trial, range.clone())
            .unwrap()
            .save(&b)
            .unwrap();
        if trial.erases() > 0 {
            return f;
        }
        // Zero, one or two saves of B before the one of A, in turn: where
        // a page ends then varies, whatever the two records' sizes (with
        // A's alone, or one B every other round, it can end where B
        // always fits).
        let mut s = Store::new(&mut f, range.clone()).unwrap();
        for _ in 0..i % 3 {
            s.save(&b).unwrap();
        }
        s.save(&a).unwrap();
    }
    panic!("no save ever erased a page");
}

/// Returns the words one save of B writes.
fn sweep<const P: usize, const PB: usize, const W: usize>(compaction: bool) -> u64 {
    let range = 0..(P * PB) as u32;
    let (a, b) = (record_a(), record_b());
    let start = flash_with_a::<P, PB, W>(compaction);

    // Measure one uninterrupted save.
    let mut full = start.clone();
    full.reset_counters();
    Store::new(&mut full, range.clone())
        .unwrap()
        .save(&b)
        .unwrap();
    let words = full.writes();
    let erases = full.erases();
    assert_eq!(compaction, erases > 0);
    std::eprintln!(
        "WORD={W}, {P} pages of {PB} B, compaction={compaction}: one save of B = {words} word writes, {erases} page erases"
    );

    let mut seen_b = None;
    let mut repairs = 0;
    for n in 0..=words + 1 {
        let mut f = start.clone();
        f.cut_power_after_words(n);
        let saved = Store::new(&mut f, range.clone()).unwrap().save(&b);
        if n >= words {
            assert_eq!(saved, Ok(()), "n = {n}");
        } else {
            assert!(saved.is_err(), "n = {n}: save succeeded with the power cut");
        }
        f.restore_power();
        f.reset_counters();
        let loaded = Store::new(&mut f, range.clone()).unwrap().load();
        if f.writes() + f.erases() > 0 {
            repairs += 1;
        }
        let got: DriveRecord = match loaded {
            Ok(Some(r)) => r,
            other => panic!("n = {n}: load after the cut gave {other:?}"),
        };
        if got == b {
            seen_b.get_or_insert(n);
        } else {
            assert_eq!(got, a, "n = {n}: neither A nor B");
            assert!(seen_b.is_none(), "n = {n}: A again after B at {seen_b:?}");
        }
        // And the store keeps working: a reload is stable, a save lands.
        let mut s = Store::new(&mut f, range.clone()).unwrap();
        assert_eq!(s.load(), Ok(Some(got)), "n = {n}: second load differs");
        s.save(&a)
            .unwrap_or_else(|e| panic!("n = {n}: save after recovery: {e}"));
        assert_eq!(s.load(), Ok(Some(a.clone())), "n = {n}");
    }
    let first_b = seen_b.expect("B never loaded");
    assert!(first_b <= words, "B only after the save completed");
    std::eprintln!(
        "  B loads from n = {first_b}; {repairs} of {} loads wrote to flash (repair)",
        words + 2
    );
    words
}

#[test]
fn power_cut_word1_append() {
    sweep::<4, 4096, 1>(false);
}

#[test]
fn power_cut_word1_compaction() {
    sweep::<4, 4096, 1>(true);
}

#[test]
fn power_cut_word4_append() {
    sweep::<4, 4096, 4>(false);
}

#[test]
fn power_cut_word4_compaction() {
    sweep::<4, 4096, 4>(true);
}

#[test]
fn power_cut_word4_compaction_two_pages() {
    sweep::<2, 4096, 4>(true);
}

#[test]
fn power_cut_word1_compaction_two_pages() {
    sweep::<2, 4096, 1>(true);
}
