//! `cargo xtask dyno`: the simulated dynamometer of `foc_bench::dyno`.
//!
//! Load-torque steps at a fixed speed command (`--sweep load`, default),
//! supply-voltage steps with a proportional speed command (`--sweep
//! voltage`) or overhauling-load steps at a fixed speed command, the drive
//! braking and returning energy to the supply (`--sweep regen`), each
//! operating point measured on the plant in steady state (averaged over
//! 0.1 s after 0.35 s of settling). Besides the report's columns, each row
//! has the mean bus current at the source's terminals and the energy
//! regenerated into the source over the 0.1 s window. Writes the
//! Performance Curve Report as `<out>/dyno-<sweep>.{csv,md,svg}` and
//! prints the table.

use std::path::{Path, PathBuf};

use clap::{Args, ValueEnum};
use foc_bench::dyno::{self, Sweep};
use foc_bench::mission::Setup;
use foc_bench::report;

use crate::sim::{progress_bar, resolve, DEFAULT_MOTOR};
use crate::util::{banner, root, Error, Result};

/// Which quantity the sweep steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SweepArg {
    /// Load-torque steps, 0 to rated torque, at half the no-load speed.
    Load,
    /// Supply-voltage steps, nominal down to a tenth, speed command proportional.
    Voltage,
    /// Overhauling-load steps, 0 to rated torque driving the shaft, at half
    /// the no-load speed: the drive regenerates.
    Regen,
    /// The load and voltage sweeps.
    Both,
    /// All three sweeps.
    All,
}

/// Arguments of `cargo xtask dyno`.
#[derive(Debug, Args)]
pub struct DynoArgs {
    /// Motor file (default: tests/motors/m153-source.toml).
    #[arg(long, value_name = "FILE")]
    pub motor: Option<PathBuf>,
    /// Output directory (default: out/dyno at the workspace root).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Which sweep.
    #[arg(long, value_enum, default_value_t = SweepArg::Load)]
    pub sweep: SweepArg,
    /// Number of steps (rows: steps + 1 for the load and regen sweeps, steps for the voltage sweep).
    #[arg(long, default_value_t = 10)]
    pub steps: usize,
}

/// `cargo xtask dyno`.
pub fn run_cmd(args: &DynoArgs) -> Result {
    let motor = resolve(args.motor.as_deref().unwrap_or(Path::new(DEFAULT_MOTOR)));
    let out = args
        .out
        .as_deref()
        .map_or_else(|| root().join("out/dyno"), Path::to_path_buf);
    let setup = Setup::load(&motor).map_err(|e| Error(e.to_string()))?;
    let sweeps: &[Sweep] = match args.sweep {
        SweepArg::Load => &[Sweep::Load],
        SweepArg::Voltage => &[Sweep::Voltage],
        SweepArg::Regen => &[Sweep::Regen],
        SweepArg::Both => &[Sweep::Load, Sweep::Voltage],
        SweepArg::All => &[Sweep::Load, Sweep::Voltage, Sweep::Regen],
    };
    for &sweep in sweeps {
        banner(&format!("dyno ({} sweep): {}", sweep.name(), setup.name));
        let pb = progress_bar(sweep.name());
        let run = dyno::run_dyno(&setup, sweep, args.steps, &mut |f| {
            pb.set_position((f * 1000.0) as u64)
        });
        pb.finish_and_clear();
        let files = report::write_dyno_report(
            &out,
            &format!("dyno-{}", sweep.name()),
            &run.header,
            &run.rows,
        )?;
        print!("{}", report::dyno_markdown(&run.header, &run.rows));
        for f in &files {
            println!("  wrote {}", f.display());
        }
        if !run.faults.is_empty() {
            return Err(Error(format!(
                "faults latched during the {} sweep: {}",
                sweep.name(),
                run.faults.join(", ")
            )));
        }
    }
    Ok(())
}
