//! Toolchain set-up: the thumb target and the rustup components xtask needs.
//!
//! `RUSTUP_AUTO_INSTALL=0` may be set, and rustup never installs the targets
//! and components listed in rust-toolchain.toml by itself for an installed
//! toolchain, so xtask checks `rustup target list --installed` and
//! `rustup component list --installed` and adds what is missing.

use std::path::PathBuf;

use crate::util::{self, command, output, run, Result, THUMB_TARGET};

/// The rustup components a full `cargo xtask test` needs.
pub const ALL_COMPONENTS: &[&str] = &["llvm-tools", "rustfmt", "clippy"];

/// Makes sure the active toolchain has `thumbv7em-none-eabihf` (if `thumb`)
/// and the given components, installing what is missing with rustup.
///
/// Without rustup (a distribution's toolchain) it only warns: cargo will
/// report whatever is really missing.
pub fn ensure(thumb: bool, components: &[&str]) -> Result {
    if output(command("rustup", ["--version"])).is_err() {
        println!(
            "warning: rustup not found; assuming the toolchain already has \
             {THUMB_TARGET} and {}",
            components.join(", ")
        );
        return Ok(());
    }
    if thumb {
        let installed = output(command("rustup", ["target", "list", "--installed"]))?;
        if installed.lines().any(|l| l.trim() == THUMB_TARGET) {
            println!("toolchain: target {THUMB_TARGET} installed");
        } else {
            println!("toolchain: target {THUMB_TARGET} missing, installing it");
            run(command("rustup", ["target", "add", THUMB_TARGET]))?;
        }
    }
    if !components.is_empty() {
        let installed = output(command("rustup", ["component", "list", "--installed"]))?;
        for &component in components {
            if has_component(&installed, component) {
                println!("toolchain: component {component} installed");
            } else {
                println!("toolchain: component {component} missing, installing it");
                run(command("rustup", ["component", "add", component]))?;
            }
        }
    }
    Ok(())
}

/// Whether `rustup component list --installed` output lists `component`
/// (lines look like `clippy-x86_64-unknown-linux-gnu`).
fn has_component(installed: &str, component: &str) -> bool {
    let prefix = format!("{component}-");
    installed
        .lines()
        .map(str::trim)
        .any(|l| l == component || l.starts_with(&prefix))
}

/// The host triple, from `rustc -vV`.
pub fn host() -> Result<String> {
    let vv = output(command("rustc", ["-vV"]))?;
    vv.lines()
        .find_map(|l| l.strip_prefix("host: "))
        .map(|h| h.trim().to_string())
        .ok_or_else(|| util::Error("`rustc -vV` printed no host triple".into()))
}

/// The path of an llvm-tools binary (e.g. `llvm-size`) of the active toolchain:
/// `$(rustc --print sysroot)/lib/rustlib/<host>/bin/<tool>`.
pub fn llvm_tool(tool: &str) -> Result<PathBuf> {
    let sysroot = output(command("rustc", ["--print", "sysroot"]))?;
    let path = PathBuf::from(sysroot.trim())
        .join("lib/rustlib")
        .join(host()?)
        .join("bin")
        .join(tool);
    if path.is_file() {
        Ok(path)
    } else {
        Err(util::Error(format!(
            "{} not found (is the llvm-tools component installed? \
             `rustup component add llvm-tools`)",
            path.display()
        )))
    }
}

/// Prints the versions of the tools in use.
pub fn print_versions() -> Result {
    for (program, args) in [
        ("rustup", &["--version"][..]),
        ("rustc", &["-V"][..]),
        ("cargo", &["-V"][..]),
    ] {
        match output(command(program, args)) {
            Ok(v) => println!("{}", v.lines().next().unwrap_or("").trim()),
            Err(e) => println!("{program}: {e}"),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn component_lines() {
        let list = "cargo-x86_64-unknown-linux-gnu\nclippy-x86_64-unknown-linux-gnu\n\
                    llvm-tools-x86_64-unknown-linux-gnu\nrust-std-thumbv7em-none-eabihf\n";
        assert!(has_component(list, "clippy"));
        assert!(has_component(list, "llvm-tools"));
        assert!(!has_component(list, "rustfmt"));
        assert!(!has_component(list, "miri"));
    }
}
