//! The checked-in EDS (`docs/canopen/foc-drive.eds`) is what `write_eds`
//! writes from the object table.
// Test support outside `#[test]` functions: unwrapping and indexing a
// fixture is the test failing, which is what it should do.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_canopen::eds::{write_eds, EdsInfo};

#[test]
fn eds_matches_the_checked_in_file() {
    let mut s = String::new();
    write_eds(&mut s, &EdsInfo::FOC_DRIVE).expect("write");
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/canopen/foc-drive.eds");
    if std::env::var_os("UPDATE_EDS").is_some() {
        std::fs::write(path, &s).expect("write the EDS");
        return;
    }
    let on_disk = std::fs::read_to_string(path).unwrap_or_default();
    assert!(
        on_disk == s,
        "docs/canopen/foc-drive.eds is out of date: regenerate with: UPDATE_EDS=1 cargo test -p foc-canopen --test eds"
    );
}

#[test]
fn eds_is_deterministic_and_lists_every_object() {
    let mut a = String::new();
    let mut b = String::new();
    write_eds(&mut a, &EdsInfo::FOC_DRIVE).unwrap();
    write_eds(&mut b, &EdsInfo::FOC_DRIVE).unwrap();
    assert_eq!(a, b);
    for d in foc_canopen::od::OBJECTS {
        let section = match d.kind {
            foc_canopen::od::Kind::Var => format!("[{:04X}]\n", d.index),
            _ => format!("[{:04X}sub{:X}]\n", d.index, d.sub),
        };
        assert!(a.contains(&section), "{section}");
    }
    assert!(a.contains("NrOfRXPDO=4\nNrOfTXPDO=4\n"));
    assert!(a.contains("BaudRate_500=1\n"));
}
