//! Link set-up: the selected board's memory.x on the linker search path,
//! and the cortex-m-rt / defmt linker scripts for the binary.
// Build script (host code): unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]
use std::{env, fs, path::PathBuf};

/// (cargo feature, memory file in board-support/memory/).
const BOARDS: &[(&str, &str)] = &[
    ("nucleo-f446re-ihm07m1", "nucleo-f446re-ihm07m1.x"),
    ("nucleo-f401re-ihm07m1", "nucleo-f401re-ihm07m1.x"),
    ("odrive-v3", "odrive-v3.x"),
    ("qemu", "qemu.x"),
];

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let root = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("manifest dir"));
    let selected: Vec<_> = BOARDS
        .iter()
        .filter(|(f, _)| {
            let var = format!("CARGO_FEATURE_{}", f.to_uppercase().replace('-', "_"));
            env::var_os(var).is_some()
        })
        .collect();
    match selected.as_slice() {
        [(_, file)] => {
            let src = root.join("../board-support/memory").join(file);
            println!("cargo:rerun-if-changed={}", src.display());
            let text = fs::read(&src).unwrap_or_else(|e| panic!("{}: {e}", src.display()));
            // The root memory.x includes board-memory.x (see its comment).
            fs::write(out.join("board-memory.x"), &text).expect("write board-memory.x");
            fs::write(out.join("memory.x"), text).expect("write memory.x");
            println!("cargo:rustc-link-search={}", out.display());
            println!("cargo:rustc-link-arg-bins=-Tlink.x");
            println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
        }
        [] => println!(
            "cargo:warning=no board feature selected: build with `cargo xtask build --board <name>`"
        ),
        _ => panic!("select exactly one board feature"),
    }
    println!("cargo:rerun-if-changed=build.rs");
}
