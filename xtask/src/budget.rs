//! The instruction budget: the committed worst case of each item `cargo
//! xtask bench` measures (`xtask/bench-budget.txt`), checked on every run.
//!
//! The counts are exact and repeatable (QEMU `-icount`, see `bench`), so
//! the check is a comparison, not a timing: an item fails when its worst
//! case exceeds its budget by more than [`TOLERANCE`] (and by more than
//! [`SLACK_INSTRUCTIONS`], the self-check's resolution, for the small
//! items). An item measured without a budget line, or a budget line no
//! longer measured, fails too: the file always lists what is measured.
//! Raising a budget is a reviewed change of the file; `cargo xtask bench
//! --write-budget` rewrites it from a run.

use std::fmt::Write as _;
use std::path::PathBuf;

use crate::bench::Row;
use crate::util::{root, Error, Result};

/// Over-budget tolerance: a fraction of the budget.
pub const TOLERANCE: f64 = 0.02;

/// ... and at least this many instructions.
pub const SLACK_INSTRUCTIONS: u32 = 2;

/// The budget file's path.
pub fn path() -> PathBuf {
    root().join("xtask/bench-budget.txt")
}

/// One budget line: the worst case allowed for an item.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Budget {
    /// The item's name, as the bench prints it.
    pub name: String,
    /// Its worst case [instructions].
    pub max: u32,
}

/// Parses the budget file: `<max> <item name>` per line; `#` comments and
/// blank lines ignored.
pub fn parse(text: &str) -> Result<Vec<Budget>> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let bad = || Error(format!("bench budget line {}: `{line}`", n + 1));
        let (max, name) = line.split_once(char::is_whitespace).ok_or_else(bad)?;
        let max = max.parse().map_err(|_| bad())?;
        out.push(Budget {
            name: name.trim().to_string(),
            max,
        });
    }
    Ok(out)
}

/// The worst case allowed before an item fails.
pub fn allowed(budget: u32) -> u32 {
    let frac = (f64::from(budget) * TOLERANCE).floor() as u32;
    budget + frac.max(SLACK_INSTRUCTIONS)
}

/// Compares a run with the budget; returns the report lines and whether
/// every item is within its budget.
pub fn check(rows: &[Row], budget: &[Budget]) -> (Vec<String>, bool) {
    let mut lines = Vec::new();
    let mut ok = true;
    for row in rows.iter().filter(|r| budgeted(&r.name)) {
        match budget.iter().find(|b| b.name == row.name) {
            None => {
                ok = false;
                lines.push(format!("NO BUDGET  {} (max {})", row.name, row.max));
            }
            Some(b) if row.max > allowed(b.max) => {
                ok = false;
                lines.push(format!(
                    "OVER       {}: max {} > budget {} (+{:.1} %)",
                    row.name,
                    row.max,
                    b.max,
                    percent(row.max, b.max)
                ));
            }
            Some(b) => lines.push(format!(
                "ok         {}: max {} / budget {} ({:+.1} %)",
                row.name,
                row.max,
                b.max,
                percent(row.max, b.max)
            )),
        }
    }
    for b in budget {
        if !rows.iter().any(|r| r.name == b.name) {
            ok = false;
            lines.push(format!("NOT MEASURED  {} (budget {})", b.name, b.max));
        }
    }
    (lines, ok)
}

fn percent(max: u32, budget: u32) -> f64 {
    100.0 * (f64::from(max) - f64::from(budget)) / f64::from(budget.max(1))
}

/// Items with a budget: everything but the self-check's raw calls.
fn budgeted(name: &str) -> bool {
    !name.starts_with("self-check raw")
}

/// The budget file's text for a run (every budgeted item at its max).
pub fn render(rows: &[Row]) -> String {
    let mut s = String::from(
        "# Instruction budget: the worst case of each item `cargo xtask bench`\n\
         # measures (exact QEMU counts, Cortex-M4F). `cargo xtask test` fails\n\
         # when an item exceeds its line by more than 2 % (and 2 instructions).\n\
         # Raising a line is a reviewed change; `cargo xtask bench\n\
         # --write-budget` rewrites the file from a run.\n\
         # <max instructions> <item>\n",
    );
    for r in rows.iter().filter(|r| budgeted(&r.name)) {
        let _ = writeln!(s, "{} {}", r.max, r.name);
    }
    s
}

/// Reads the committed budget.
pub fn load() -> Result<Vec<Budget>> {
    let p = path();
    let text = std::fs::read_to_string(&p)
        .map_err(|e| Error(format!("cannot read {}: {e}", p.display())))?;
    parse(&text)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(name: &str, max: u32) -> Row {
        Row {
            name: name.into(),
            min: max,
            max,
            mean: max as f32,
            median: max,
        }
    }

    #[test]
    fn parses_and_renders_the_same_items() {
        let rows = [row("sin_cos", 47), row("drive period: torque 1 A", 1538)];
        let b = parse(&render(&rows)).unwrap();
        assert_eq!(b.len(), 2);
        assert_eq!(b[1].name, "drive period: torque 1 A");
        assert_eq!(b[1].max, 1538);
        assert!(parse("12x name").is_err());
        assert!(parse("nonumber").is_err());
    }

    #[test]
    fn tolerance_is_two_percent_or_two_instructions() {
        assert_eq!(allowed(1000), 1020);
        assert_eq!(allowed(47), 49);
        let b = parse("1000 big\n47 small\n").unwrap();
        assert!(check(&[row("big", 1020), row("small", 49)], &b).1);
        assert!(!check(&[row("big", 1021), row("small", 49)], &b).1);
        assert!(!check(&[row("big", 1000), row("small", 50)], &b).1);
    }

    #[test]
    fn missing_and_unbudgeted_items_fail_self_check_raw_is_ignored() {
        let b = parse("100 a\n100 b\n").unwrap();
        let (lines, ok) = check(&[row("a", 90), row("self-check raw: x", 5)], &b);
        assert!(!ok);
        assert!(lines
            .iter()
            .any(|l| l.starts_with("NOT MEASURED") && l.contains(" b ")));
        let (lines, ok) = check(&[row("a", 90), row("b", 90), row("c", 1)], &b);
        assert!(!ok);
        assert!(lines
            .iter()
            .any(|l| l.starts_with("NO BUDGET") && l.contains(" c ")));
        assert!(check(&[row("a", 90), row("b", 90)], &b).1);
    }
}
