//! `cargo xtask sim`: the real `foc-core` cascade against the bench plant
//! through the scripted mission of `foc_bench::mission` (identification:
//! current offsets, R, L, gains, alignment, flux linkage; then q-current
//! step, speed step and ramp, load step, position move, all on the
//! identification's permit; then the braking segment: stops into a supply
//! that cannot sink current with the ODrive v3's bus capacitor, the regen
//! limit on, into the capacitor alone and with the brake resistor, design
//! §18; then field weakening, design §30: from rest to 2.2 x base speed
//! where the model allows it, a load step there, back to rest, skipped on
//! halls and where base speed is beyond the bench's resolved speed; last,
//! low-speed smoothness, design §32, §33: on a separate simulation with the
//! motor file's cogging, sensor error and dead time, the zero-torque
//! ripple, the speed ripple at 1 % and 5 % of the no-load speed and the
//! sensor's angle error before and after the encoder linearisation and
//! the anticogging calibration, skipped on halls; `--sensorless` states
//! that it does not run there).
//!
//! Writes `identification.csv` / `identification.svg` (the identify
//! segment, decimated), `mission.csv` (every PWM period after the
//! identification), `current_step.csv`, SVG plots (`mission.svg`,
//! `current_step.svg`, `speed.svg`, `position.svg`, `braking.svg`,
//! `field_weakening.svg`, `smoothness.svg`) and `summary.md` into the
//! output directory and prints the summary. Fails when the mission's pass
//! criteria fail (the braking segment's: the bus at or above the
//! over-voltage threshold, no stop, a fault; the field-weakening
//! segment's: a fault, the speed more than 2 % off the command, the phase
//! current at 1.1 x the limit; the smoothness segment's: a calibration
//! that does not finish, the zero-torque ripple down less than 3 times,
//! the angle error neither smaller nor within two counts, a fault). `--all` runs every motor file in `tests/motors` (one
//! sub-directory each); `--bench` also measures the simulation speed.
//! `--save-config FILE.toml` writes the configuration the mission ended
//! with (the identified calibration included) as `foc-ctl config export`
//! does; `--config FILE.toml` starts from such a file instead of
//! identifying: its settings, and its calibration installed by the drive's
//! start-up (design §17).
//!
//! It runs in this process: a mission is about 100 000 to 500 000 PWM
//! periods (the identification is most of them: its alignment sweeps run at
//! a quarter of an electrical turn per second on high-flux motors), 1 to 4 s
//! each in xtask's dev profile (opt-level 1), plus the smoothness segment's
//! 50 to 62 s simulated (0.9 to 2.4 million periods, 10 to 30 s), so no
//! release build is spawned.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use foc_bench::mission::{self, Setup};
use foc_bench::motor_file::MotorFile;
use indicatif::{ProgressBar, ProgressStyle};

use crate::util::{banner, root, Error, Result};

/// The default motor: the source design's M153 at its 15 kHz / 26 V point.
pub const DEFAULT_MOTOR: &str = "tests/motors/m153-source.toml";

/// Arguments of `cargo xtask sim`.
#[derive(Debug, Args)]
pub struct SimArgs {
    /// Motor file (default: tests/motors/m153-source.toml).
    #[arg(long, value_name = "FILE")]
    pub motor: Option<PathBuf>,
    /// Run every motor file in tests/motors (outputs in <out>/<motor>/).
    #[arg(long, conflicts_with = "motor")]
    pub all: bool,
    /// Output directory (default: out/sim at the workspace root).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Also measure the simulation speed (controller steps/s, plant+controller periods/s).
    #[arg(long)]
    pub bench: bool,
    /// Start from a saved configuration (TOML, as `foc-ctl config export`
    /// or `--save-config` writes it): its settings and its calibration,
    /// installed at start-up without an identification.
    #[arg(long, value_name = "FILE.toml", conflicts_with = "all")]
    pub config: Option<PathBuf>,
    /// Write the configuration the mission ended with (identified or
    /// restored) to FILE.toml.
    #[arg(long, value_name = "FILE.toml", conflicts_with = "all")]
    pub save_config: Option<PathBuf>,
    /// Run the sensorless mission instead (design §27): no angle sensor,
    /// a start from standstill, a speed step, a load step, a reversal
    /// through zero; on the motor file's values.
    #[arg(long, conflicts_with_all = ["config", "save_config", "bench"])]
    pub sensorless: bool,
}

/// `path` as given if absolute or existing from the current directory, else
/// from the workspace root.
pub fn resolve(path: &Path) -> PathBuf {
    if path.is_absolute() || path.exists() {
        path.to_path_buf()
    } else {
        root().join(path)
    }
}

/// Every motor file in tests/motors, sorted.
pub fn motor_files() -> Result<Vec<PathBuf>> {
    let dir = root().join("tests/motors");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map_err(|e| Error(format!("{}: {e}", dir.display())))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    v.sort();
    Ok(v)
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
pub fn progress_bar(label: &str) -> ProgressBar {
    let pb = ProgressBar::new(1000);
    pb.set_style(
        ProgressStyle::with_template("{prefix:>12} [{bar:40}] {percent:>3}% {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_prefix(label.to_string());
    pb
}

fn stem(p: &Path) -> String {
    p.file_stem()
        .map_or("motor".into(), |s| s.to_string_lossy().into_owned())
}

/// The configuration file at `path`, parsed and checked.
fn read_config(path: &Path) -> Result<foc_store::DriveRecord> {
    let text =
        std::fs::read_to_string(path).map_err(|e| Error(format!("{}: {e}", path.display())))?;
    foc_store::text::from_toml(&text).map_err(|e| Error(format!("{}: {e}", path.display())))
}

/// The sensorless mission; whether it passed, and its summary.
fn run_sensorless(setup: &Setup, motor: &Path, out: &Path) -> Result<(bool, String)> {
    let pb = progress_bar(&stem(motor));
    let result =
        mission::run_sensorless_mission(setup, &mut |f| pb.set_position((f * 1000.0) as u64));
    pb.finish_and_clear();
    let summary = result.to_markdown();
    print!("{summary}");
    std::fs::create_dir_all(out).map_err(|e| Error(format!("{}: {e}", out.display())))?;
    let file = out.join(format!("sensorless-{}.md", stem(motor)));
    std::fs::write(&file, &summary).map_err(|e| Error(format!("{}: {e}", file.display())))?;
    println!("  wrote {}", file.display());
    let fails = result.failures();
    if !fails.is_empty() {
        println!("FAILED: {}", fails.join("; "));
    }
    Ok((fails.is_empty(), summary))
}

/// One mission; whether it passed, and its summary.
fn run_one(motor: &Path, out: &Path, args: &SimArgs) -> Result<(bool, String)> {
    let file = MotorFile::load(motor).map_err(|e| Error(e.to_string()))?;
    let setup = Setup::from_file(&file);
    if args.sensorless {
        banner(&format!("sim --sensorless: {}", setup.name));
        return run_sensorless(&setup, motor, out);
    }
    banner(&format!("sim: {}", setup.name));
    let stored = args.config.as_deref().map(read_config).transpose()?;
    if let Some(p) = &args.config {
        println!("starting from the configuration in {}", p.display());
    }
    let pb = progress_bar(&stem(motor));
    let t = Instant::now();
    // The low-speed smoothness segment on the file's imperfections.
    let imperfections = file.imperfections();
    let result =
        mission::run_mission_with(&setup, stored.as_ref(), Some(&imperfections), &mut |f| {
            pb.set_position((f * 1000.0) as u64)
        })
        .map_err(|e| Error(format!("the stored configuration does not apply: {e}")))?;
    pb.finish_and_clear();
    if let Some(p) = &args.save_config {
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| Error(format!("{}: {e}", dir.display())))?;
        }
        std::fs::write(p, foc_store::text::to_toml(&result.record))
            .map_err(|e| Error(format!("{}: {e}", p.display())))?;
        println!("  wrote the configuration to {}", p.display());
    }
    let bench = args.bench;
    let files = result.write(out)?;
    let summary = result.summary.to_markdown();
    print!("{summary}");
    // A motor file of this repository, identified (not restored): its
    // figures in the book.
    let in_repo = |p: &Path| p.canonicalize().ok();
    let dir = motor.parent().and_then(in_repo);
    if args.config.is_none() && dir.is_some() && dir == in_repo(&root().join("tests/motors")) {
        crate::figures::write(
            &format!("sim-{}.md", stem(motor)),
            &format!(
                "`cargo xtask sim --motor tests/motors/{}.toml`",
                stem(motor)
            ),
            &crate::figures::without_wall_time(&summary),
        )?;
    }
    println!(
        "(mission {:.2} s wall time, this build)",
        t.elapsed().as_secs_f64()
    );
    for f in &files {
        println!("  wrote {}", f.display());
    }
    if bench {
        let (ctrl, both) = mission::bench_speed(&setup, 1.0);
        let line = format!(
            "simulation speed ({} build): controller alone {:.0} steps/s ({:.2} us/step); plant + controller {:.0} periods/s ({:.1} x real time at {:.0} Hz)",
            if cfg!(debug_assertions) { "dev, opt-level 1" } else { "release" },
            ctrl,
            1e6 / ctrl,
            both,
            both / setup.pwm_hz() as f64,
            setup.pwm_hz()
        );
        println!("{line}");
        std::fs::write(out.join("bench.txt"), format!("{line}\n"))?;
    }
    let fails = result.summary.failures();
    if !fails.is_empty() {
        println!("FAILED: {}", fails.join("; "));
    }
    Ok((fails.is_empty(), summary))
}

/// `cargo xtask sim`.
pub fn run_cmd(args: &SimArgs) -> Result {
    let out = args
        .out
        .as_deref()
        .map_or_else(|| root().join("out/sim"), Path::to_path_buf);
    let motors = if args.all {
        motor_files()?
    } else {
        vec![resolve(
            args.motor.as_deref().unwrap_or(Path::new(DEFAULT_MOTOR)),
        )]
    };
    let mut failed = Vec::new();
    let mut summaries = Vec::new();
    for m in &motors {
        let dir = if args.all {
            out.join(stem(m))
        } else {
            out.clone()
        };
        let (passed, summary) = run_one(m, &dir, args)?;
        if !passed {
            failed.push(stem(m));
        }
        summaries.push((stem(m), summary));
    }
    if args.all && !args.sensorless {
        let table = crate::figures::side_by_side(&summaries);
        crate::figures::write("sim-all.md", "`cargo xtask sim --all`", &table)?;
    }
    if failed.is_empty() {
        Ok(())
    } else {
        Err(Error(format!("mission failed for: {}", failed.join(", "))))
    }
}
