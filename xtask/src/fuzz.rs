//! `cargo xtask fuzz`: the cargo-fuzz targets of `foc-protocol` (`fuzz/`).
//!
//! `fuzz/` is a standalone crate (its own `[workspace]`, not a member of
//! the root workspace), so plain `cargo build` / `cargo test` / `cargo
//! clippy` at the root never build it, and this task is not part of
//! `cargo xtask test`. Its checks are plain functions in `fuzz/src/lib.rs`;
//! the targets in `fuzz/fuzz_targets/` only hand libFuzzer's input to them.
//!
//! - `cargo xtask fuzz [--seconds N] [--target NAME]`: each target (or the
//!   one named) under libFuzzer for N seconds (default 30), i.e.
//!   `cargo +nightly fuzz run <target> <corpus> <seeds> -- -max_total_time=N`
//!   (run as `rustup run nightly cargo fuzz ...`). libFuzzer needs a nightly
//!   toolchain and cargo-fuzz; when either is missing this says what and how
//!   to install it and fails. It never installs anything itself.
//!   New corpus entries go to `fuzz/corpus/<target>/` and crash inputs to
//!   `fuzz/artifacts/<target>/` (neither committed); the committed seed
//!   corpus is `fuzz/seeds/<target>/`.
//! - `cargo xtask fuzz --replay`: the stable smoke mode, no libFuzzer:
//!   `cargo test --no-default-features` in `fuzz/`, whose tests run every
//!   file of `fuzz/seeds/<target>/` and `fuzz/corpus/<target>/` through the
//!   same check functions (and check that the seed files match their
//!   generator, `fuzz/src/seeds.rs`).
//!
//! Builds go to `<target dir>/fuzz` (`CARGO_TARGET_DIR` respected).

use std::fs;
use std::path::PathBuf;

use clap::builder::PossibleValuesParser;
use clap::Args;

use crate::util::{self, banner, command, output, run, Error, Result};

/// The fuzz targets (`fuzz/fuzz_targets/<name>.rs`).
pub const TARGETS: [&str; 3] = ["frame_decoder", "message_decode", "device_commands"];

/// libFuzzer time per target by default [s].
pub const DEFAULT_SECONDS: u64 = 30;

/// The toolchain libFuzzer runs with by default.
pub const DEFAULT_TOOLCHAIN: &str = "nightly";

/// `cargo xtask fuzz` options.
#[derive(Debug, Args, Clone)]
pub struct FuzzArgs {
    /// libFuzzer run time per target [s] (`-max_total_time`).
    #[arg(long, default_value_t = DEFAULT_SECONDS,
          value_parser = clap::value_parser!(u64).range(1..))]
    pub seconds: u64,
    /// Only this target (default: every target, one after the other).
    #[arg(long, value_parser = PossibleValuesParser::new(TARGETS))]
    pub target: Option<String>,
    /// The nightly toolchain to fuzz with (a rustup toolchain name).
    #[arg(long, default_value = DEFAULT_TOOLCHAIN)]
    pub toolchain: String,
    /// Stable smoke mode, no libFuzzer: run the seed corpus and the local
    /// corpus through the same checks (`cargo test` in fuzz/).
    #[arg(long, conflicts_with_all = ["seconds", "toolchain"])]
    pub replay: bool,
}

/// `cargo xtask fuzz`.
pub fn run_cmd(args: &FuzzArgs) -> Result {
    let targets: Vec<&str> = match &args.target {
        Some(t) => vec![t.as_str()],
        None => TARGETS.to_vec(),
    };
    if args.replay {
        return replay(args.target.as_deref());
    }
    let missing = missing_tools(&args.toolchain);
    if !missing.is_empty() {
        eprintln!("{}", missing_message(&args.toolchain, &missing));
        return Err(Error(
            "cargo xtask fuzz: nightly toolchain or cargo-fuzz missing (nothing installed)".into(),
        ));
    }
    for target in targets {
        banner(&format!("fuzz {target} ({} s)", args.seconds));
        fs::create_dir_all(corpus_dir(target))?;
        run(fuzz_run_command(&args.toolchain, target, args.seconds))
            .map_err(|e| Error(format!("{e}; crash inputs in fuzz/artifacts/{target}/")))?;
    }
    Ok(())
}

/// What `cargo xtask fuzz` lacks on this machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Missing {
    /// No rustup (libFuzzer's toolchain is picked through rustup).
    Rustup,
    /// The nightly toolchain is not installed.
    Toolchain,
    /// `cargo fuzz` is not installed.
    CargoFuzz,
}

/// Checks, without installing anything: rustup, the toolchain, cargo-fuzz.
fn missing_tools(toolchain: &str) -> Vec<Missing> {
    let mut missing = Vec::new();
    match output(command("rustup", ["toolchain", "list"])) {
        Ok(list) if has_toolchain(&list, toolchain) => {}
        Ok(_) => missing.push(Missing::Toolchain),
        Err(_) => missing.extend([Missing::Rustup, Missing::Toolchain]),
    }
    // cargo-fuzz is a cargo subcommand on the PATH (or in $CARGO_HOME/bin),
    // whatever the toolchain: ask the cargo that runs xtask.
    if output(util::cargo(["fuzz", "--version"])).is_err() {
        missing.push(Missing::CargoFuzz);
    }
    missing
}

/// Whether `rustup toolchain list` output has `name` (lines look like
/// `nightly-x86_64-unknown-linux-gnu` or `stable-... (active, default)`;
/// `nightly` is not a dated `nightly-2026-01-01-...`).
fn has_toolchain(list: &str, name: &str) -> bool {
    let prefix = format!("{name}-");
    list.lines()
        .filter_map(|l| l.split_whitespace().next())
        .any(|t| {
            t == name
                || t.strip_prefix(&prefix)
                    .is_some_and(|host| !host.starts_with(|c: char| c.is_ascii_digit()))
        })
}

/// What is missing and how to install it.
fn missing_message(toolchain: &str, missing: &[Missing]) -> String {
    let mut m = String::from(
        "cargo xtask fuzz runs the fuzz targets under libFuzzer, which needs a nightly \
         toolchain and cargo-fuzz. Missing here:\n",
    );
    for item in missing {
        let line = match item {
            Missing::Rustup => {
                "rustup (https://rustup.rs), which provides the toolchains".to_string()
            }
            Missing::Toolchain => format!(
                "the `{toolchain}` toolchain: install it with \
                 `rustup toolchain install {toolchain}`"
            ),
            Missing::CargoFuzz => "cargo-fuzz: install it with `cargo install cargo-fuzz` \
                                   (`--locked` for its tested dependency versions)"
                .to_string(),
        };
        m.push_str(&format!("  - {line}\n"));
    }
    m.push_str(
        "Nothing was installed. Meanwhile `cargo xtask fuzz --replay` runs the seed \
         corpus through the same checks on stable, without libFuzzer.",
    );
    m
}

fn fuzz_dir() -> PathBuf {
    util::root().join("fuzz")
}

/// libFuzzer's working corpus of `target` (written to, not committed).
fn corpus_dir(target: &str) -> PathBuf {
    fuzz_dir().join("corpus").join(target)
}

/// The committed seed corpus of `target`.
fn seeds_dir(target: &str) -> PathBuf {
    fuzz_dir().join("seeds").join(target)
}

/// `rustup run <toolchain> cargo fuzz run <target> <corpus> <seeds> --
/// -max_total_time=N` (= `cargo +<toolchain> fuzz run ...`). New inputs go
/// to the first corpus directory; the seeds are only read.
fn fuzz_run_command(toolchain: &str, target: &str, seconds: u64) -> std::process::Command {
    let mut cmd = command("rustup", ["run", toolchain, "cargo", "fuzz", "run", target]);
    cmd.arg("--fuzz-dir")
        .arg(fuzz_dir())
        .arg("--target-dir")
        .arg(util::target_dir().join("fuzz"))
        .arg(corpus_dir(target))
        .arg(seeds_dir(target))
        .arg("--")
        .arg(format!("-max_total_time={seconds}"));
    // The stable toolchain's variables, set by `cargo xtask`'s rustup proxy,
    // must not leak into the nightly build.
    for var in ["RUSTUP_TOOLCHAIN", "RUSTC", "RUSTDOC", "CARGO_TARGET_DIR"] {
        cmd.env_remove(var);
    }
    cmd
}

/// `cargo xtask fuzz --replay`: the corpus through the checks, on stable.
fn replay(target: Option<&str>) -> Result {
    banner("fuzz corpus replay (stable, no libFuzzer)");
    let manifest = fuzz_dir().join("Cargo.toml");
    let mut cmd = util::cargo(["test", "--no-default-features", "--lib", "--manifest-path"]);
    cmd.arg(manifest)
        .arg("--target-dir")
        .arg(util::target_dir().join("fuzz"))
        .arg("--")
        .arg("--show-output");
    if let Some(t) = target {
        cmd.arg(format!("replay::{t}"));
    }
    run(cmd)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        args: FuzzArgs,
    }

    fn parse(args: &[&str]) -> std::result::Result<FuzzArgs, clap::Error> {
        Cli::try_parse_from(std::iter::once("fuzz").chain(args.iter().copied())).map(|c| c.args)
    }

    #[test]
    fn defaults_and_options() {
        let a = parse(&[]).unwrap();
        assert_eq!(
            (a.seconds, a.target, a.toolchain.as_str(), a.replay),
            (30, None, "nightly", false)
        );
        let a = parse(&["--seconds", "5", "--target", "message_decode"]).unwrap();
        assert_eq!(
            (a.seconds, a.target.as_deref()),
            (5, Some("message_decode"))
        );
        assert!(
            parse(&["--replay", "--target", "frame_decoder"])
                .unwrap()
                .replay
        );
        assert!(parse(&["--target", "nope"]).is_err());
        assert!(parse(&["--seconds", "0"]).is_err());
        assert!(parse(&["--replay", "--seconds", "5"]).is_err());
    }

    #[test]
    fn every_target_has_a_source_and_seeds() {
        for t in TARGETS {
            assert!(fuzz_dir()
                .join("fuzz_targets")
                .join(format!("{t}.rs"))
                .is_file());
            assert!(fs::read_dir(seeds_dir(t)).unwrap().next().is_some(), "{t}");
        }
        let manifest = fs::read_to_string(fuzz_dir().join("Cargo.toml")).unwrap();
        assert!(
            manifest.contains("\n[workspace]"),
            "fuzz/ must stay standalone"
        );
    }

    #[test]
    fn toolchain_list_parsing() {
        let list = "stable-x86_64-unknown-linux-gnu (active, default)\n\
                    nightly-x86_64-unknown-linux-gnu\n\
                    1.95.0-x86_64-unknown-linux-gnu\n";
        assert!(has_toolchain(list, "nightly"));
        assert!(has_toolchain(list, "stable"));
        assert!(!has_toolchain(list, "nightly-2026-01-01"));
        assert!(!has_toolchain(
            "stable-x86_64-unknown-linux-gnu\n",
            "nightly"
        ));
        let dated = "nightly-2026-01-01-x86_64-unknown-linux-gnu\n";
        assert!(has_toolchain(dated, "nightly-2026-01-01"));
        assert!(!has_toolchain(dated, "nightly"));
    }

    #[test]
    fn run_command_line() {
        let line = util::display(&fuzz_run_command("nightly", "frame_decoder", 30));
        assert!(
            line.starts_with("rustup run nightly cargo fuzz run frame_decoder --fuzz-dir "),
            "{line}"
        );
        assert!(line.contains("corpus/frame_decoder"), "{line}");
        assert!(line.contains("seeds/frame_decoder"), "{line}");
        assert!(line.ends_with(" -- -max_total_time=30"), "{line}");
    }

    #[test]
    fn message_says_how_to_install() {
        let m = missing_message("nightly", &[Missing::Toolchain, Missing::CargoFuzz]);
        assert!(m.contains("rustup toolchain install nightly"), "{m}");
        assert!(m.contains("cargo install cargo-fuzz"), "{m}");
        assert!(m.contains("--replay"), "{m}");
        let m = missing_message("nightly", &[Missing::CargoFuzz]);
        assert!(!m.contains("rustup toolchain install"), "{m}");
    }
}
