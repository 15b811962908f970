//! `cargo xtask`: the project's tasks (build, size, test, ci, ...).
//!
//! One module per subcommand; this file only parses the command line and
//! dispatches. To add a subcommand: a module with its `Args` and a `run_cmd`,
//! a variant in [`Command`], and its arm in [`main`].

mod bench;
mod boards;
mod book;
mod budget;
mod build;
mod canopen;
mod check;
mod dashboard;
mod doctables;
mod dyno;
mod e2e;
mod e2e_scope;
mod figures;
mod fil;
mod fuzz;
mod python;
mod qemu;
mod sim;
mod size;
mod toolchain;
mod util;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Tasks of the Rust FOC project: build, size, test, ci.
#[derive(Debug, Parser)]
#[command(name = "cargo xtask", bin_name = "cargo xtask")]
pub(crate) struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Build the firmware (release) for a board or all boards, one cargo
    /// invocation per board, and print its flash and RAM use.
    Build(build::BuildArgs),
    /// Print flash (text+data) and static RAM (data+bss) of the firmware per
    /// board, against the default board's goals (building it if needed).
    Size(size::SizeArgs),
    /// The full check, in order: rustfmt; clippy (host crates and every
    /// board); the host crates' tests; the API docs and the book (tables
    /// checked against the code, links); the Python package against `foc-ctl
    /// simulate`; the dashboard in headless Chromium; CANopen (python-canopen on the host test bus, then the
    /// emulated firmware); the simulation (`sim`) and the sensorless mission;
    /// foc-core's bare-metal build; a release build of every board; QEMU
    /// firmware-in-the-loop (`qemu`) and the command channel end to end
    /// (`e2e`); instruction counts against the budget (`bench`); the book's
    /// figures are this run's. Stops at the first failure.
    Test,
    /// What CI runs: toolchain set-up and versions, then exactly `test`.
    Ci,
    /// Install the thumb target and the llvm-tools, rustfmt and clippy
    /// components if they are missing, and print the versions.
    Toolchain,
    /// List the boards: name (= cargo feature), probe-rs chip, QEMU support.
    Boards,
    /// Closed-loop simulation: the foc-core cascade against the bench plant
    /// through a mission (identification, current step, speed, load step,
    /// position);
    /// CSV, SVG and summary.md in out/sim.
    Sim(sim::SimArgs),
    /// Simulated dynamometer sweep: Performance Curve Report (CSV, Markdown,
    /// SVG) in out/dyno.
    Dyno(dyno::DynoArgs),
    /// Firmware in the loop under QEMU: the product's firmware with the
    /// emulated board, driven from the host (scenario, panic, braking and
    /// store runs).
    Qemu(qemu::QemuArgs),
    /// Exact instruction counts of the control code under QEMU, checked
    /// against the committed budget (xtask/bench-budget.txt).
    Bench(bench::BenchArgs),
    /// The command channel end to end: the emulated board driven through
    /// foc-ctl's client over QEMU's USART2 (loopback TCP).
    E2e(e2e::E2eArgs),
    /// The Python package (python/, foc-drive): install it into a virtual
    /// environment under the target directory and run its tests against
    /// `foc-ctl simulate`.
    Python,
    /// foc-ctl's dashboard in a real headless browser (Debian's Chromium
    /// over WebDriver): the page, a live plot, the console, a refusal, the
    /// setup wizard; screenshots in out/dashboard.
    Dashboard,
    /// CANopen (CiA 301 / CiA 402): a Python `canopen` master against
    /// several drives on the host test bus (foc-canbus), then against the
    /// emulated firmware (QEMU, CAN as SLCAN on USART3) joined to the bus.
    Canopen,
    /// The book (mdBook, docs/) into target/book, every internal link and
    /// anchor checked; mdBook is installed into target/tools when missing.
    Book(book::BookArgs),
    /// The library crates' API docs (`cargo doc --no-deps`), rustdoc
    /// warnings denied.
    Doc,
    /// Fuzz foc-protocol (cargo-fuzz targets in fuzz/; nightly + cargo-fuzz),
    /// or `--replay` the corpus through the same checks on stable.
    Fuzz(fuzz::FuzzArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Build(args) => build::run_cmd(args),
        Command::Size(args) => size::run_cmd(args),
        Command::Test => check::test(),
        Command::Ci => check::ci(),
        Command::Toolchain => toolchain::ensure(true, toolchain::ALL_COMPONENTS)
            .and_then(|()| toolchain::print_versions()),
        Command::Sim(args) => sim::run_cmd(args),
        Command::Dyno(args) => dyno::run_cmd(args),
        Command::Qemu(args) => qemu::run_cmd(args),
        Command::Bench(args) => bench::run_cmd(args),
        Command::E2e(args) => e2e::run_cmd(args),
        Command::Fuzz(args) => fuzz::run_cmd(args),
        Command::Python => python::run_tests(),
        Command::Dashboard => dashboard::run_tests(),
        Command::Canopen => canopen::run_tests(),
        Command::Book(args) => book::run_cmd(args),
        Command::Doc => book::api_docs(),
        Command::Boards => {
            list_boards();
            Ok(())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn list_boards() {
    println!(
        "{:<24} {:<15} {:<5} description",
        "board (feature)", "probe-rs chip", "qemu"
    );
    for b in &boards::BOARDS {
        println!(
            "{:<24} {:<15} {:<5} {}",
            b.name,
            b.chip,
            if b.qemu { "yes" } else { "no" },
            b.description
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn cli_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn parses_board_all() {
        let cli = Cli::try_parse_from(["xtask", "build", "--board", "all", "--debug"]).unwrap();
        match cli.command {
            Command::Build(args) => {
                assert_eq!(args.board, boards::Selection::All);
                assert!(args.debug);
            }
            other => panic!("parsed as {other:?}"),
        }
        assert!(Cli::try_parse_from(["xtask", "build", "--board", "nope"]).is_err());
    }
}
