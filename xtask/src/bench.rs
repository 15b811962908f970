//! `cargo xtask bench`: exact instruction counts on the Cortex-M4F.
//!
//! Runs the `bench` binary of the emulated board under QEMU with
//! `-icount shift=10,align=off`, where SysTick advances exactly 172.032
//! ticks per executed instruction (checked with a 100-nop self-check, see the book's Instruction counts chapter), and
//! prints a table of instructions per item with the loop rate each would
//! allow at 168 MHz if one instruction took one cycle (a lower bound on
//! time: loads, branches and FP divides take more). The worst case of
//! every item is checked against the committed budget (`budget`); the
//! goals are reported.

use std::time::Duration;

use clap::Args;

use crate::util::{Error, Result};
use crate::{budget, qemu};

/// Goals to report against: (item prefix, statistic, instructions).
const GOALS: [(&str, Stat, u32); 2] = [
    ("current-loop math step", Stat::Median, 250),
    ("drive per-period call", Stat::Max, 450),
];

/// Which statistic a goal is on.
#[derive(Debug, Clone, Copy)]
enum Stat {
    Median,
    Max,
}

/// Arguments of `cargo xtask bench`.
#[derive(Debug, Args, Default)]
pub struct BenchArgs {
    /// Rewrite `xtask/bench-budget.txt` from this run (every item at its
    /// worst case) instead of checking it; review the diff before
    /// committing.
    #[arg(long)]
    pub write_budget: bool,
}

/// One measured item.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// What was measured.
    pub name: String,
    /// Fewest instructions over the inputs.
    pub min: u32,
    /// Most instructions.
    pub max: u32,
    /// Mean.
    pub mean: f32,
    /// Median.
    pub median: u32,
}

/// Parse a `BENCH <name> <min> <max> <mean> <median>` line.
pub fn parse_line(line: &str) -> Option<Row> {
    let rest = line.trim().strip_prefix("BENCH ")?;
    let mut parts = rest.rsplitn(5, ' ');
    let median = parts.next()?.parse().ok()?;
    let mean = parts.next()?.parse().ok()?;
    let max = parts.next()?.parse().ok()?;
    let min = parts.next()?.parse().ok()?;
    let name = parts.next()?.trim().to_string();
    Some(Row {
        name,
        min,
        max,
        mean,
        median,
    })
}

/// Runs the bench binary under QEMU; its rows and INFO lines.
fn run_bench() -> Result<(Vec<Row>, Vec<String>)> {
    let (_, bench) = qemu::build_emulated()?;
    let r = qemu::run(
        &bench,
        &[],
        "shift=10,align=off",
        Duration::from_secs(900),
        false,
    )?;
    if r.code != Some(0) || !r.lines.iter().any(|l| l.contains("BENCH-DONE")) {
        for l in &r.lines {
            eprintln!("  | {l}");
        }
        return Err(Error(format!(
            "bench run failed (exit status {:?})",
            r.code
        )));
    }
    let rows = r.lines.iter().filter_map(|l| parse_line(l)).collect();
    let info = r
        .lines
        .into_iter()
        .filter(|l| l.starts_with("INFO"))
        .collect();
    Ok((rows, info))
}

/// The measured rows as the book's table.
fn figures_table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| item (exact instruction counts, Cortex-M4F under QEMU) | min | max | mean | median |\n|---|---:|---:|---:|---:|\n",
    );
    for r in rows {
        s += &format!(
            "| {} | {} | {} | {:.1} | {} |\n",
            r.name, r.min, r.max, r.mean, r.median
        );
    }
    s
}

fn print_rows(rows: &[Row]) {
    println!(
        "{:<76} {:>6} {:>6} {:>8} {:>6} {:>10}",
        "item (exact instruction counts, Cortex-M4F under QEMU)",
        "min",
        "max",
        "mean",
        "median",
        "rate@168MHz"
    );
    for row in rows {
        let rate = if row.max > 0 {
            format!("{:.0} kHz", 168_000.0 / row.max as f64)
        } else {
            "-".into()
        };
        println!(
            "{:<76} {:>6} {:>6} {:>8.1} {:>6} {:>10}",
            row.name, row.min, row.max, row.mean, row.median, rate
        );
    }
    println!(
        "(rate: 168 MHz / max instructions, i.e. one instruction per cycle; real cycles are more)"
    );
}

fn print_goals(rows: &[Row]) {
    for (prefix, stat, goal) in GOALS {
        if let Some(row) = rows.iter().find(|r| r.name.starts_with(prefix)) {
            let (what, v) = match stat {
                Stat::Median => ("median", row.median),
                Stat::Max => ("worst case", row.max),
            };
            let verdict = if v <= goal { "met" } else { "NOT met" };
            println!("goal: {prefix}, {what} <= {goal} instructions: {verdict} ({v})");
        }
    }
}

/// The counting method's self-check: 100 `nop`s must read 100 (one
/// instruction either way for the pairing of two calls), else the counts
/// mean nothing (a wrong SysTick scale or icount shift).
fn check_self_check(rows: &[Row]) -> Result {
    let ok = |v: u32| (99..=101).contains(&v);
    match rows
        .iter()
        .find(|r| r.name.starts_with("self-check: 100 nops"))
    {
        Some(r) if ok(r.min) && ok(r.max) && ok(r.median) => Ok(()),
        Some(r) => {
            // The raw calls, for the diagnosis.
            for raw in rows.iter().filter(|r| r.name.starts_with("self-check raw")) {
                eprintln!(
                    "  {}: min {} max {} median {}",
                    raw.name, raw.min, raw.max, raw.median
                );
            }
            Err(Error(format!(
                "the bench's self-check read {}-{} instructions for 100 nops: the counts are not exact",
                r.min, r.max
            )))
        }
        None => Err(Error("the bench printed no self-check".into())),
    }
}

/// `cargo xtask bench`.
pub fn run_cmd(args: &BenchArgs) -> Result {
    let (rows, info) = run_bench()?;
    check_self_check(&rows)?;
    print_rows(&rows);
    print_goals(&rows);
    let rustc = crate::util::output(crate::util::command("rustc", ["--version"]))?;
    crate::figures::write(
        "bench.md",
        &format!("`cargo xtask bench`, {}", rustc.trim()),
        &figures_table(&rows),
    )?;
    for l in &info {
        println!("{l}");
    }
    if args.write_budget {
        let p = budget::path();
        std::fs::write(&p, budget::render(&rows))
            .map_err(|e| Error(format!("cannot write {}: {e}", p.display())))?;
        println!("wrote {} (review the diff before committing)", p.display());
        return Ok(());
    }
    let (lines, ok) = budget::check(&rows, &budget::load()?);
    println!("instruction budget ({}):", budget::path().display());
    for l in &lines {
        println!("  {l}");
    }
    if ok {
        Ok(())
    } else {
        Err(Error(
            "instruction budget exceeded or out of date (see above; a raise is a reviewed change of xtask/bench-budget.txt)".into(),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_bench_lines() {
        let r =
            parse_line("BENCH current-loop math step (Clarke..SVPWM) 588 611 593.98 590").unwrap();
        assert_eq!(r.name, "current-loop math step (Clarke..SVPWM)");
        assert_eq!((r.min, r.max, r.median), (588, 611, 590));
        assert!((r.mean - 593.98).abs() < 1e-3);
        assert_eq!(parse_line("INFO something"), None);
        assert_eq!(parse_line("BENCH name x 2 3 4"), None);
        assert_eq!(parse_line("BENCH name 1 2 3"), None);
    }

    #[test]
    fn self_check_must_read_one_hundred() {
        let row = |min, max| Row {
            name: "self-check: 100 nops (difference of two calls, expect 100)".into(),
            min,
            max,
            mean: 100.0,
            median: 100,
        };
        assert!(check_self_check(&[row(100, 99)]).is_ok());
        assert!(check_self_check(&[row(50, 50)]).is_err());
        assert!(check_self_check(&[row(100, 120)]).is_err());
        assert!(check_self_check(&[]).is_err());
    }
}
