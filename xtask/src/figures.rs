//! The book's figures (`docs/src/figures/`), written by the runs that
//! measure them: `cargo xtask sim` (each motor file's mission summary),
//! `cargo xtask bench` (instruction counts), `cargo xtask size` (flash and
//! RAM). `cargo xtask test` ends by checking that the committed figures
//! are what its own runs wrote.

use std::fs;
use std::path::PathBuf;

use crate::util::{output, root, Error, Result};

/// Where the figures live.
pub fn dir() -> PathBuf {
    root().join("docs/src/figures")
}

/// Writes `docs/src/figures/<name>` with a header naming what wrote it.
pub fn write(name: &str, written_by: &str, body: &str) -> Result {
    let path = dir().join(name);
    let text = format!("<!-- written by {written_by}; do not edit -->\n{body}");
    fs::write(&path, text).map_err(|e| Error(format!("{}: {e}", path.display())))?;
    println!("  wrote {}", path.display());
    Ok(())
}

/// A mission summary without what depends on the machine (wall times) and
/// without its title (the book's chapter has one).
pub fn without_wall_time(summary: &str) -> String {
    let mut out = String::new();
    for line in summary.lines().filter(|l| !l.starts_with("# ")) {
        let mut l = line.to_string();
        // "... in 17.88 s wall time." and "(13.67 s wall)".
        if let Some(i) = l.rfind(" in ").filter(|_| l.ends_with(" s wall time.")) {
            l.truncate(i);
            l.push('.');
        }
        if let Some(b) = l.find(" s wall)") {
            if let Some(a) = l[..b].rfind(" (") {
                l.replace_range(a..b + " s wall)".len(), "");
            }
        }
        out.push_str(&l);
        out.push('\n');
    }
    out.trim_start_matches('\n').to_string()
}

/// The rows of the motors' mission summaries compared side by side.
const COMPARED: [&str; 15] = [
    "identified R / error",
    "identified Ld / error",
    "identified Lq / error",
    "identified flux linkage / error",
    "identified inertia / error",
    "identified electrical zero / error",
    "q-current overshoot",
    "q-current 2 % settling",
    "speed overshoot",
    "current-limited step overshoot",
    "position 2 % settling",
    "model check: largest healthy residual / bound, disturbance / envelope",
    "low-speed smoothness: zero-torque shaft-torque ripple p-p, before -> after",
    "low-speed smoothness: angle error p-p of the sensor's reading, before -> after",
    "faults",
];

/// One table of the main figures of several missions, a column per motor:
/// `(motor, summary markdown)`.
pub fn side_by_side(runs: &[(String, String)]) -> String {
    let mut s = String::from("| figure |");
    for (motor, _) in runs {
        s += &format!(" {motor} |");
    }
    s += "\n|---|";
    s += &"---:|".repeat(runs.len());
    s += "\n";
    for row in COMPARED {
        s += &format!("| {row} |");
        for (_, summary) in runs {
            let value = summary
                .lines()
                .find_map(|l| l.strip_prefix(&format!("| {row} | ")))
                .map_or("-", |v| v.trim_end_matches(" |"));
            s += &format!(" {value} |");
        }
        s += "\n";
    }
    s
}

/// Fails when the committed figures differ from what this checkout's runs
/// wrote (`git status` on `docs/src/figures`); skipped outside a git
/// checkout. A figure whose header names another compiler than the
/// committed one's (the instruction counts, written with the rustc
/// version) is reported, not failed: a new stable release may change the
/// code it generates, and the budget (`xtask/bench-budget.txt`, 2 %
/// tolerance) is the gate for that.
pub fn check_committed() -> Result {
    if !root().join(".git").exists() {
        println!("not a git checkout: the figures are not compared");
        return Ok(());
    }
    let git = |args: &[&str]| output(crate::util::command("git", args));
    let changed = git(&["status", "--porcelain", "--", "docs/src/figures"])?;
    let mut differ = Vec::new();
    for line in changed.lines() {
        let path = line.get(3..).unwrap_or("").trim();
        let header = |text: &str| text.lines().next().unwrap_or("").to_string();
        let committed = git(&["show", &format!("HEAD:{path}")]).unwrap_or_default();
        let now = fs::read_to_string(root().join(path)).unwrap_or_default();
        if !committed.is_empty() && header(&committed) != header(&now) {
            println!(
                "{path}: written by another toolchain than the committed one ({}), not compared",
                header(&now)
            );
        } else {
            differ.push(path.to_string());
        }
    }
    if differ.is_empty() {
        println!("the book's figures are what this run measured");
        Ok(())
    } else {
        let mut args = vec!["diff", "--"];
        args.extend(differ.iter().map(String::as_str));
        eprintln!("{}", git(&args)?);
        Err(Error(format!(
            "the book's figures differ from this run's (commit them if the change is meant): {}",
            differ.join(", ")
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wall_times_go() {
        let s = "# Simulation: M\n\nPWM 15000 Hz; 607045 periods (40.470 s simulated) in 17.88 s wall time.\n\n| identification time (offsets + identification) | 0.067 s + 31.02 s simulated (13.67 s wall) |\n";
        let t = without_wall_time(s);
        assert_eq!(
            t,
            "PWM 15000 Hz; 607045 periods (40.470 s simulated).\n\n| identification time (offsets + identification) | 0.067 s + 31.02 s simulated |\n"
        );
    }
}
