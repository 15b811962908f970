//! `cargo xtask size`: flash and static RAM of the firmware, per board.
//!
//! Read from the ELF with `llvm-size` (Berkeley format) of the toolchain's
//! llvm-tools component: flash = text + data (the initial values of `.data`
//! live in flash), static RAM = data + bss (stack and heap not included).
//!
//! After the table, `cargo xtask size` splits each board's flash into
//! feature groups (control, calibration, protocol, storage, HAL, ...) from
//! the ELF's symbols with `llvm-nm`: see [`groups`] for the rules and how
//! the bytes no symbol names are reported.

mod groups;

use std::path::{Path, PathBuf};

use clap::Args;

use crate::boards::{self, Board, Selection};
use crate::build::{self, Profile};
use crate::toolchain;
use crate::util::{command, kib, output, Error, Result};

/// Arguments of `cargo xtask size`.
#[derive(Debug, Args)]
pub struct SizeArgs {
    /// Board to measure (its cargo feature), or `all`.
    #[arg(long, value_name = "BOARD|all", default_value = boards::DEFAULT_BOARD.name,
          value_parser = boards::parse_selection)]
    pub board: Selection,
    /// Measure the dev profile instead of release.
    #[arg(long)]
    pub debug: bool,
}

/// Section sizes of one ELF, in bytes (llvm-size's Berkeley columns).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Size {
    /// Code and read-only data (incl. the vector table).
    pub text: u64,
    /// Initialised RAM data (its initial values are in flash too).
    pub data: u64,
    /// Zero-initialised and uninitialised RAM.
    pub bss: u64,
}

impl Size {
    /// Bytes of flash: text + data.
    pub fn flash(&self) -> u64 {
        self.text + self.data
    }

    /// Bytes of static RAM: data + bss.
    pub fn ram(&self) -> u64 {
        self.data + self.bss
    }
}

/// Parses `llvm-size` (Berkeley) output: a header line, then
/// `text data bss dec hex filename`.
fn parse_berkeley(out: &str) -> Option<Size> {
    let line = out.lines().nth(1)?;
    let mut fields = line.split_whitespace().map(str::parse::<u64>);
    Some(Size {
        text: fields.next()?.ok()?,
        data: fields.next()?.ok()?,
        bss: fields.next()?.ok()?,
    })
}

/// Measures one ELF.
pub fn measure(llvm_size: &Path, elf: &Path) -> Result<Size> {
    let mut cmd = command(&llvm_size.to_string_lossy(), [elf]);
    cmd.arg("--format=berkeley");
    let out = output(cmd)?;
    parse_berkeley(&out).ok_or_else(|| {
        Error(format!(
            "could not read llvm-size output for {}:\n{out}",
            elf.display()
        ))
    })
}

/// Measures each (board, ELF) pair.
pub fn measure_all(elfs: &[(&'static Board, PathBuf)]) -> Result<Vec<(&'static Board, Size)>> {
    let llvm_size = toolchain::llvm_tool("llvm-size")?;
    elfs.iter()
        .map(|(board, elf)| Ok((*board, measure(&llvm_size, elf)?)))
        .collect()
}

/// Prints one line per board and its goals, if it has any. Reports only.
pub fn print_table(rows: &[(&Board, Size)], profile: Profile) {
    println!();
    println!("firmware size ({}):", profile.dir());
    println!(
        "  {:<24} {:>22} {:>22}  goal (flash / RAM)",
        "board", "flash (text+data)", "static RAM (data+bss)"
    );
    for (board, size) in rows {
        let goal = match board.goals() {
            Some((flash, ram)) => {
                let verdict = match (size.flash() <= flash, size.ram() <= ram) {
                    (true, true) => "met",
                    (false, true) => "NOT MET: flash over",
                    (true, false) => "NOT MET: RAM over",
                    (false, false) => "NOT MET: flash and RAM over",
                };
                format!("{} / {}: {verdict}", kib(flash), kib(ram))
            }
            None => "-".to_string(),
        };
        println!(
            "  {:<24} {:>22} {:>22}  {goal}",
            board.name,
            format!("{} ({} B)", kib(size.flash()), size.flash()),
            format!("{} ({} B)", kib(size.ram()), size.ram()),
        );
    }
}

/// `cargo xtask size`: builds the selected boards (a no-op when up to date)
/// and prints their sizes against the goals.
pub fn run_cmd(args: &SizeArgs) -> Result {
    toolchain::ensure(true, &["llvm-tools"])?;
    let profile = Profile::from_debug(args.debug);
    let mut built = Vec::new();
    for board in args.board.boards() {
        built.push((board, build::build_board(board, profile)?));
    }
    let rows = measure_all(&built)?;
    print_table(&rows, profile);
    if profile == Profile::Release && rows.len() == crate::boards::BOARDS.len() {
        crate::figures::write(
            "sizes.md",
            "`cargo xtask size --board all`",
            &figures_table(&rows),
        )?;
    }
    print_all_groups(&built, &rows)
}

/// Every board's release sizes as the book's table.
fn figures_table(rows: &[(&Board, Size)]) -> String {
    let mut s = String::from("| board (release build) | flash | static RAM |\n|---|---:|---:|\n");
    for (board, size) in rows {
        s += &format!(
            "| `{}` | {:.1} KiB | {:.1} KiB |\n",
            board.name,
            size.flash() as f64 / 1024.0,
            size.ram() as f64 / 1024.0
        );
    }
    s
}

/// Prints the flash per feature group of each measured board.
fn print_all_groups(built: &[(&Board, PathBuf)], rows: &[(&Board, Size)]) -> Result {
    let llvm_nm = toolchain::llvm_tool("llvm-nm")?;
    for ((board, elf), (_, size)) in built.iter().zip(rows) {
        let symbols = groups::read_symbols(&llvm_nm, elf)?;
        groups::print_groups(board.name, &symbols, size.flash());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_llvm_size() {
        let out = "   text\t   data\t    bss\t    dec\t    hex\tfilename\n\
                   \t  12000\t     56\t   2000\t  14056\t   36e8\tfirmware\n";
        let size = parse_berkeley(out).unwrap();
        assert_eq!(
            size,
            Size {
                text: 12000,
                data: 56,
                bss: 2000
            }
        );
        assert_eq!(size.flash(), 12056);
        assert_eq!(size.ram(), 2056);
        assert_eq!(parse_berkeley("garbage"), None);
    }

    #[test]
    fn table_prints_goals_for_default_board_only() {
        use crate::boards::BOARDS;
        let small = Size {
            text: 20_000,
            data: 100,
            bss: 3_000,
        };
        let big = Size {
            text: 60_000,
            data: 100,
            bss: 9_000,
        };
        print_table(
            &[(&BOARDS[0], small), (&BOARDS[0], big), (&BOARDS[2], big)],
            Profile::Release,
        );
        assert!(BOARDS[0].goals().is_some() && BOARDS[2].goals().is_none());
    }
}
