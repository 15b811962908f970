//! `cargo xtask test` and `cargo xtask ci`: the full check, as a list of steps.
//!
//! Each [`Step`] is a name and an action. [`steps`] builds the list; to add a
//! check (QEMU emulation, a simulation smoke run, ...) push another `Step`
//! there. The runner prints a banner and the time of each step, stops at the
//! first failure and ends with a summary line.

use std::time::Instant;

use crate::boards::BOARDS;
use crate::build::{self, Profile};
use crate::sim;
use crate::toolchain;
use crate::util::{banner, cargo, fmt_duration, run, Error, Result, THUMB_TARGET};
use crate::{bench, e2e, qemu};

// The host crates are the workspace's `default-members` (root Cargo.toml):
// cargo run at the root with no `-p` selects exactly them, so the list is
// kept in one place and a new host crate is checked without touching xtask.
// (`--workspace` would pull in the thumb-only firmware.)

/// One step of the check.
pub struct Step {
    /// Shown in the banner and the summary.
    pub name: String,
    action: Box<dyn Fn() -> Result>,
}

impl Step {
    /// A step that runs a function.
    pub fn new(name: impl Into<String>, action: impl Fn() -> Result + 'static) -> Self {
        Step {
            name: name.into(),
            action: Box::new(action),
        }
    }

    /// A step that runs `cargo <args>` at the workspace root.
    pub fn cargo(name: impl Into<String>, args: Vec<String>) -> Self {
        Step::new(name, move || run(cargo(&args)))
    }
}

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|s| (*s).to_string()).collect()
}

/// The steps of `cargo xtask test`, in order.
pub fn steps() -> Vec<Step> {
    let mut steps = lint_steps();
    steps.extend(host_steps());
    steps.extend(build_steps());
    steps.extend(emulation_steps());
    steps
}

/// Formatting, then clippy on the host crates and the firmware per board.
fn lint_steps() -> Vec<Step> {
    let mut steps = vec![
        Step::cargo(
            "rustfmt (cargo fmt --all --check)",
            strings(&["fmt", "--all", "--check"]),
        ),
        Step::cargo(
            "clippy, host crates (the workspace's default members)",
            strings(&["clippy", "--all-targets", "--", "-D", "warnings"]),
        ),
    ];
    for board in &BOARDS {
        steps.push(Step::cargo(
            format!("clippy, firmware for {}", board.name),
            strings(&[
                "clippy",
                "-p",
                "firmware",
                "--target",
                THUMB_TARGET,
                "--features",
                board.feature,
                "--",
                "-D",
                "warnings",
            ]),
        ));
    }
    steps
}

/// What runs on the host: the crates' tests, the docs, the Python package,
/// the CANopen master on the host bus, the simulation.
fn host_steps() -> Vec<Step> {
    vec![
        Step::cargo(
            "tests, host crates (the workspace's default members)",
            strings(&["test"]),
        ),
        Step::new(
            "API docs of the library crates, rustdoc warnings denied (cargo xtask doc)",
            crate::book::api_docs,
        ),
        Step::new(
            "the book: its tables against the code, mdBook build, every internal link (cargo xtask book)",
            || crate::book::run_cmd(&crate::book::BookArgs::default()),
        ),
        // The Python package (python/): installed into a virtual
        // environment, its tests against `foc-ctl simulate`.
        Step::new(
            "Python package foc-drive: install, tests against foc-ctl simulate",
            crate::python::run_tests,
        ),
        Step::new(
            "the dashboard in headless Chromium: live plot, console, refusal, setup wizard (cargo xtask dashboard)",
            crate::dashboard::run_tests,
        ),
        // CANopen (issue 22): the Python canopen master against three drives
        // on the host test bus, then the emulated firmware on the bus.
        Step::new(
            "CANopen: python-canopen master, three drives on the host test bus, then the emulated firmware joined to it",
            crate::canopen::run_tests,
        ),
        Step::new("simulation smoke run (cargo xtask sim)", sim_smoke),
        Step::new(
            "sensorless mission (cargo xtask sim --sensorless): the default motor and the 2.2 kW interior-PM file",
            sim_sensorless,
        ),
    ]
}

/// The sensorless mission (design §27) on the default motor and on the
/// interior-PM file: each segment reached without a fault.
fn sim_sensorless() -> Result {
    for motor in [None, Some("tests/motors/ipm-2k2-540v.toml")] {
        sim::run_cmd(&sim::SimArgs {
            motor: motor.map(std::path::PathBuf::from),
            all: false,
            out: Some(crate::util::root().join("out/sim-sensorless")),
            bench: false,
            config: None,
            save_config: None,
            sensorless: true,
        })?;
    }
    Ok(())
}

/// Smoke run of the closed-loop simulation (the default motor's mission, a
/// few seconds): it must pass its criteria and write its reports. Then the
/// same mission started from the configuration the first one saved (its
/// calibration restored at start-up, no identification).
fn sim_smoke() -> Result {
    let saved = crate::util::root().join("out/sim/drive.toml");
    sim::run_cmd(&sim::SimArgs {
        motor: None,
        all: false,
        out: None,
        bench: false,
        config: None,
        save_config: Some(saved.clone()),
        sensorless: false,
    })?;
    sim::run_cmd(&sim::SimArgs {
        motor: None,
        all: false,
        out: Some(crate::util::root().join("out/sim-restored")),
        bench: false,
        config: Some(saved),
        save_config: None,
        sensorless: false,
    })
}

/// The bare-metal build of foc-core and a release build of every board.
fn build_steps() -> Vec<Step> {
    let mut steps = vec![Step::cargo(
        format!("foc-core bare-metal build ({THUMB_TARGET}, no default features)"),
        strings(&[
            "build",
            "-p",
            "foc-core",
            "--no-default-features",
            "--target",
            THUMB_TARGET,
        ]),
    )];
    for board in &BOARDS {
        steps.push(Step::new(
            format!("firmware build for {} (release)", board.name),
            move || build::build_board(board, Profile::Release).map(|_| ()),
        ));
    }
    steps
}

/// The firmware under QEMU.
fn emulation_steps() -> Vec<Step> {
    vec![
        // The real firmware binary on an emulated Cortex-M4F against the
        // plant, driven from the host: scenario, forced panic (the bridge
        // must be left safe), braking and store runs.
        Step::new("firmware in the loop under QEMU (cargo xtask qemu)", || {
            qemu::run_cmd(&qemu::QemuArgs::default())
        }),
        // The command channel end to end: QEMU's USART2 on a loopback
        // socket, driven by foc-ctl's client (ping, velocity, position, bad
        // frames, refused commands, faults).
        Step::new(
            "command channel end to end under QEMU (cargo xtask e2e)",
            || e2e::run_cmd(&e2e::E2eArgs::default()),
        ),
        // Exact instruction counts, each item's worst case checked against
        // the committed budget (xtask/bench-budget.txt).
        Step::new(
            "instruction counts under QEMU, against the budget (cargo xtask bench)",
            || bench::run_cmd(&bench::BenchArgs::default()),
        ),
        // The simulation and the bench above rewrote the book's figures:
        // they must be the committed ones.
        Step::new(
            "the book's figures are this run's (git status docs/src/figures)",
            crate::figures::check_committed,
        ),
    ]
}

/// Runs the steps in order, stopping at the first failure.
pub fn run_steps(title: &str, steps: &[Step]) -> Result {
    let total = steps.len();
    let start = Instant::now();
    let mut done: Vec<(&str, String)> = Vec::new();
    for (i, step) in steps.iter().enumerate() {
        banner(&format!("[{}/{total}] {}", i + 1, step.name));
        let t = Instant::now();
        let result = (step.action)();
        let took = fmt_duration(t.elapsed());
        match result {
            Ok(()) => {
                println!("---- ok: {} ({took})", step.name);
                done.push((&step.name, took));
            }
            Err(e) => {
                println!("---- FAILED: {} ({took})", step.name);
                print_times(&done);
                println!(
                    "{title}: FAILED at step {}/{total} ({}) after {}",
                    i + 1,
                    step.name,
                    fmt_duration(start.elapsed())
                );
                return Err(Error(format!("step `{}` failed: {e}", step.name)));
            }
        }
    }
    print_times(&done);
    println!(
        "{title}: all {total} steps passed in {}",
        fmt_duration(start.elapsed())
    );
    Ok(())
}

fn print_times(done: &[(&str, String)]) {
    if done.is_empty() {
        return;
    }
    println!();
    println!("steps passed:");
    for (name, took) in done {
        println!("  {took:>12}  {name}");
    }
}

/// `cargo xtask test`: toolchain check, then every step.
pub fn test() -> Result {
    banner("toolchain");
    toolchain::ensure(true, &["rustfmt", "clippy"])?;
    run_steps("cargo xtask test", &steps())
}

/// `cargo xtask ci`: the full toolchain set-up and versions, then exactly
/// `cargo xtask test`.
pub fn ci() -> Result {
    banner("toolchain set-up");
    toolchain::ensure(true, toolchain::ALL_COMPONENTS)?;
    toolchain::print_versions()?;
    test()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_board_is_linted_and_built_once() {
        let steps = steps();
        for board in &BOARDS {
            // Whole words: `odrive-v3` must not count `odrive-v3-as5047p`.
            let n = steps
                .iter()
                .filter(|s| {
                    let words: Vec<&str> = s.name.split_whitespace().collect();
                    words.windows(2).any(|w| w == ["for", board.name])
                })
                .count();
            assert_eq!(n, 2, "{}", board.name);
        }
        assert!(steps[0].name.starts_with("rustfmt"));
    }

    #[test]
    fn runner_stops_at_first_failure() {
        use std::cell::Cell;
        use std::rc::Rc;
        let ran = Rc::new(Cell::new(0));
        let (a, b) = (ran.clone(), ran.clone());
        let steps = [
            Step::new("ok", move || {
                a.set(a.get() + 1);
                Ok(())
            }),
            Step::new("fails", || Err(Error("boom".into()))),
            Step::new("never", move || {
                b.set(b.get() + 100);
                Ok(())
            }),
        ];
        let err = run_steps("t", &steps).unwrap_err();
        assert!(err.0.contains("fails"));
        assert_eq!(ran.get(), 1);
    }
}
