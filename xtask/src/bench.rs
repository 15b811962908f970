//! `cargo xtask bench`: exact instruction counts on the Cortex-M4F.
//!
//! Runs the `bench` binary of the emulated board under QEMU with
//! `-icount shift=10,align=off`, where SysTick advances exactly 172.032
//! ticks per executed instruction (checked with a 100-nop self-check, see the README), and
//! prints a table of instructions per item with the loop rate each would
//! allow at 168 MHz if one instruction took one cycle (a lower bound on
//! time: loads, branches and FP divides take more). Figures are reported
//! against the goals, never enforced.

use std::time::Duration;

use crate::qemu;
use crate::util::{Error, Result};

/// Goals to report against: (item prefix, instructions).
const GOALS: [(&str, u32); 2] = [
    ("current-loop math step", 250),
    ("current-loop task body", 400),
];

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
}

/// Parse a `BENCH <name> <min> <max> <mean>` line.
pub fn parse_line(line: &str) -> Option<Row> {
    let rest = line.trim().strip_prefix("BENCH ")?;
    let mut parts = rest.rsplitn(4, ' ');
    let mean = parts.next()?.parse().ok()?;
    let max = parts.next()?.parse().ok()?;
    let min = parts.next()?.parse().ok()?;
    let name = parts.next()?.to_string();
    Some(Row {
        name,
        min,
        max,
        mean,
    })
}

/// `cargo xtask bench`.
pub fn run_cmd() -> Result {
    let (_, bench) = qemu::build_emulated()?;
    let r = qemu::run(
        &bench,
        &[],
        "shift=10,align=off",
        Duration::from_secs(120),
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
    let rows: Vec<Row> = r.lines.iter().filter_map(|l| parse_line(l)).collect();
    println!(
        "{:<72} {:>6} {:>6} {:>8} {:>12}",
        "item (exact instruction counts, Cortex-M4F under QEMU)",
        "min",
        "max",
        "mean",
        "rate@168MHz"
    );
    for row in &rows {
        let rate = if row.max > 0 {
            format!("{:.0} kHz", 168_000.0 / row.max as f64)
        } else {
            "-".into()
        };
        println!(
            "{:<72} {:>6} {:>6} {:>8.1} {:>12}",
            row.name, row.min, row.max, row.mean, rate
        );
    }
    println!(
        "(rate: 168 MHz / max instructions, i.e. one instruction per cycle; real cycles are more)"
    );
    for (prefix, goal) in GOALS {
        if let Some(row) = rows.iter().find(|r| r.name.starts_with(prefix)) {
            let verdict = if row.max <= goal { "met" } else { "NOT met" };
            println!(
                "goal: {prefix} <= {goal} instructions: {verdict} (max {})",
                row.max
            );
        }
    }
    for l in r.lines.iter().filter(|l| l.starts_with("INFO")) {
        println!("{l}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_bench_lines() {
        let r = parse_line("BENCH current-loop math step (Clarke..SVPWM) 588 611 593.98").unwrap();
        assert_eq!(r.name, "current-loop math step (Clarke..SVPWM)");
        assert_eq!((r.min, r.max), (588, 611));
        assert!((r.mean - 593.98).abs() < 1e-3);
        assert_eq!(parse_line("INFO something"), None);
        assert_eq!(parse_line("BENCH name x 2 3"), None);
    }
}
