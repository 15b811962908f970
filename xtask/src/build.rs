//! `cargo xtask build`: the firmware, one cargo invocation per board.

use std::fs;
use std::path::PathBuf;

use clap::Args;

use crate::boards::{self, Board, Selection};
use crate::size;
use crate::toolchain;
use crate::util::{cargo, run, target_dir, Error, Result, THUMB_TARGET};

/// Arguments of `cargo xtask build`.
#[derive(Debug, Args)]
pub struct BuildArgs {
    /// Board to build (its cargo feature), or `all`.
    #[arg(long, value_name = "BOARD|all", default_value = boards::DEFAULT_BOARD.name,
          value_parser = boards::parse_selection)]
    pub board: Selection,
    /// Build the dev profile instead of release.
    #[arg(long)]
    pub debug: bool,
}

/// Cargo profile of a firmware build.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Profile {
    /// `--release` (the default: what goes on a board).
    Release,
    /// The dev profile.
    Debug,
}

impl Profile {
    /// From a `--debug` flag.
    pub fn from_debug(debug: bool) -> Self {
        if debug {
            Profile::Debug
        } else {
            Profile::Release
        }
    }

    /// The profile's directory under `target/<triple>/`.
    pub fn dir(self) -> &'static str {
        match self {
            Profile::Release => "release",
            Profile::Debug => "debug",
        }
    }
}

/// The cargo arguments that build the firmware for one board:
/// `build -p firmware [--release] --target thumbv7em-none-eabihf --features <board>`.
pub fn firmware_args(board: &Board, profile: Profile) -> Vec<&'static str> {
    let mut args = vec!["build", "-p", "firmware"];
    if profile == Profile::Release {
        if board.small_flash {
            args.extend(["--profile", "release-small"]);
        } else {
            args.push("--release");
        }
    }
    args.extend(["--target", THUMB_TARGET, "--features", board.feature]);
    args
}

/// Where cargo puts the firmware ELF (overwritten by every board's build).
pub fn cargo_elf(profile: Profile) -> PathBuf {
    target_dir()
        .join(THUMB_TARGET)
        .join(profile.dir())
        .join("firmware")
}

/// The profile directory a board's build lands in: `release-small` for a
/// board with little flash ([`Board::small_flash`]).
pub fn profile_dir(board: &Board, profile: Profile) -> &'static str {
    match profile {
        Profile::Release if board.small_flash => "release-small",
        p => p.dir(),
    }
}

/// The per-board copy of the ELF that xtask keeps:
/// `target/thumbv7em-none-eabihf/<profile>/firmware-<board>.elf`.
pub fn board_elf(board: &Board, profile: Profile) -> PathBuf {
    target_dir()
        .join(THUMB_TARGET)
        .join(profile_dir(board, profile))
        .join(format!("firmware-{}.elf", board.name))
}

/// Builds the firmware for one board and copies the ELF to [`board_elf`].
/// Returns the path of that copy. The toolchain must already be set up.
pub fn build_board(board: &Board, profile: Profile) -> Result<PathBuf> {
    println!(
        "building firmware for {} ({})",
        board.name,
        profile_dir(board, profile)
    );
    run(cargo(firmware_args(board, profile))).map_err(|e| {
        Error(format!(
            "firmware build for board {} failed: {e}",
            board.name
        ))
    })?;
    let from = target_dir()
        .join(THUMB_TARGET)
        .join(profile_dir(board, profile))
        .join("firmware");
    let to = board_elf(board, profile);
    fs::copy(&from, &to).map_err(|e| {
        Error(format!(
            "could not copy {} to {}: {e}",
            from.display(),
            to.display()
        ))
    })?;
    println!("firmware for {}: {}", board.name, to.display());
    Ok(to)
}

/// `cargo xtask build`: builds the selected boards, then prints their sizes.
pub fn run_cmd(args: &BuildArgs) -> Result {
    toolchain::ensure(true, &["llvm-tools"])?;
    let profile = Profile::from_debug(args.debug);
    let mut built = Vec::new();
    for board in args.board.boards() {
        let elf = build_board(board, profile)?;
        built.push((board, elf));
    }
    // The size table is information: a missing llvm-size does not fail a build.
    match size::measure_all(&built) {
        Ok(rows) => size::print_table(&rows, profile),
        Err(e) => println!("warning: no size report: {e}"),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boards::BOARDS;

    #[test]
    fn release_args() {
        assert_eq!(
            firmware_args(&BOARDS[0], Profile::Release),
            [
                "build",
                "-p",
                "firmware",
                "--profile",
                "release-small",
                "--target",
                "thumbv7em-none-eabihf",
                "--features",
                "nucleo-f446re-ihm07m1"
            ]
        );
        assert!(firmware_args(&BOARDS[2], Profile::Release).contains(&"--release"));
        assert!(!firmware_args(&BOARDS[2], Profile::Debug).contains(&"--release"));
        assert_eq!(profile_dir(&BOARDS[0], Profile::Release), "release-small");
        assert_eq!(profile_dir(&BOARDS[2], Profile::Release), "release");
    }
}
