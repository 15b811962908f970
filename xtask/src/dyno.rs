//! `cargo xtask dyno`: the simulated dynamometer of `foc_bench::dyno`.
//!
//! Load-torque steps at a fixed speed command (`--sweep load`, default),
//! supply-voltage steps with a proportional speed command (`--sweep
//! voltage`) or overhauling-load steps at a fixed speed command, the drive
//! braking and returning energy to the supply (`--sweep regen`), each
//! operating point measured on the plant in steady state (averaged over
//! 0.1 s after 0.35 s of settling). `--speed` sets the speed command
//! [rad/s, rotor, mechanical] of the load and regen sweeps and the voltage
//! sweep's at the nominal bus; a speed above the motor's no-load speed is
//! refused. Each row has the speed command beside the speed, the phase
//! current (peak), the modulation index and the energy regenerated into the
//! source over the 0.1 s window. Writes the Performance Curve Report,
//! titled by its sweep, as `<out>/dyno-<sweep>.{csv,md,svg}` and prints the
//! table.

use std::path::{Path, PathBuf};

use clap::{Args, ValueEnum};
use foc_bench::dyno::{self, Sweep, TestSpeed};
use foc_bench::mission::Setup;

use crate::sim::{progress_bar, resolve, DEFAULT_MOTOR};
use crate::util::{banner, root, Error, Result};

/// Which quantity the sweep steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SweepArg {
    /// Load-torque steps, 0 to rated torque, at the test speed.
    Load,
    /// Supply-voltage steps, nominal down to a tenth, speed command proportional.
    Voltage,
    /// Overhauling-load steps, 0 to rated torque driving the shaft, at the
    /// test speed: the drive regenerates.
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
    /// Test speed [rad/s, rotor, mechanical]: the load and regen sweeps'
    /// speed command and the voltage sweep's at the nominal bus (default:
    /// half the no-load speed for load and regen, 80 % for voltage; at most
    /// the no-load speed).
    #[arg(long, value_name = "RAD_S")]
    pub speed: Option<f32>,
}

/// `cargo xtask dyno`.
pub fn run_cmd(args: &DynoArgs) -> Result {
    let motor = resolve(args.motor.as_deref().unwrap_or(Path::new(DEFAULT_MOTOR)));
    let out = args
        .out
        .as_deref()
        .map_or_else(|| root().join("out/dyno"), Path::to_path_buf);
    let setup = Setup::load(&motor).map_err(|e| Error(e.to_string()))?;
    // Checked before any sweep runs.
    let speed = args
        .speed
        .map(|w| TestSpeed::new(&setup, w))
        .transpose()
        .map_err(|e| Error(format!("--speed: {e}")))?;
    let sweeps: &[Sweep] = match args.sweep {
        SweepArg::Load => &[Sweep::Load],
        SweepArg::Voltage => &[Sweep::Voltage],
        SweepArg::Regen => &[Sweep::Regen],
        SweepArg::Both => &[Sweep::Load, Sweep::Voltage],
        SweepArg::All => &[Sweep::Load, Sweep::Voltage, Sweep::Regen],
    };
    for &sweep in sweeps {
        let speed = speed.unwrap_or_else(|| TestSpeed::default_for(&setup, sweep));
        banner(&format!(
            "dyno ({}): {}, speed command {:.2} rad/s ({:.0} rpm){}",
            sweep.title(),
            setup.name,
            speed.rad_s(),
            speed.rad_s() as f64 * 60.0 / std::f64::consts::TAU,
            if sweep == Sweep::Voltage {
                " at the nominal bus"
            } else {
                ""
            }
        ));
        let pb = progress_bar(sweep.name());
        let run = dyno::run_dyno(&setup, sweep, args.steps, speed, &mut |f| {
            pb.set_position((f * 1000.0) as u64)
        });
        pb.finish_and_clear();
        let report = run.report();
        let files = report.write(&out, &format!("dyno-{}", sweep.name()))?;
        print!("{}", report.markdown());
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
