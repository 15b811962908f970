//! `foc-ctl scope ...` and `foc-ctl tune ...` (design §22).

use clap::{Args, Subcommand, ValueEnum};
use foc_core::scope::{ScopeConfig, Signal, TriggerKind};
use foc_ctl::scope::{signal_by_name, ScopeCapture};
use foc_ctl::tune::{self, Loop};
use foc_ctl::Client;
use std::path::{Path, PathBuf};
use std::time::Duration;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// `scope`: configure, arm, trigger, read.
#[derive(Subcommand)]
pub enum ScopeCmd {
    /// Configure the scope (it goes idle).
    Set(SetArgs),
    /// Arm: record, waiting for the trigger.
    Arm,
    /// Trigger the armed scope now.
    Trigger,
    /// Show the scope's state.
    Status,
    /// Wait for the capture, read it, write CSV / SVG.
    Read(ReadArgs),
}

/// The trigger on the command line.
#[derive(Clone, Copy, ValueEnum)]
pub enum TriggerArg {
    /// Only `foc-ctl scope trigger`.
    Manual,
    /// A new active command.
    Command,
    /// A newly latched fault.
    Fault,
    /// `--trigger-signal` rises through `--level`.
    Rising,
    /// ... falls through it.
    Falling,
    /// ... crosses it either way.
    Either,
}

/// `scope set`.
#[derive(Args)]
pub struct SetArgs {
    /// Signals, comma-separated (up to 8): id, iq, id_ref, iq_ref, vd, vq,
    /// velocity, position, vbus, duty_a, duty_b, duty_c, theta_e, target, mode.
    #[arg(long, default_value = "iq_ref,iq,id,vq", value_delimiter = ',')]
    signals: Vec<String>,
    /// Record every K-th PWM period.
    #[arg(long, default_value_t = 1)]
    every: u16,
    /// Samples per signal (0: as many as fit).
    #[arg(long, default_value_t = 0)]
    samples: u16,
    /// Samples kept before the trigger (default: a tenth).
    #[arg(long)]
    pre: Option<u16>,
    /// Trigger source.
    #[arg(long, value_enum, default_value_t = TriggerArg::Command)]
    trigger: TriggerArg,
    /// Signal of a level trigger.
    #[arg(long, default_value = "iq")]
    trigger_signal: String,
    /// Level of a level trigger [the signal's unit].
    #[arg(long, default_value_t = 0.0)]
    level: f32,
}

/// `scope read`.
#[derive(Args)]
pub struct ReadArgs {
    /// Wait at most this long for the capture \[ms\] (host time).
    #[arg(long = "wait-ms", default_value_t = 10_000.0)]
    wait_ms: f64,
    /// Write the capture as CSV.
    #[arg(long, value_name = "FILE")]
    csv: Option<PathBuf>,
    /// Write an SVG plot (one panel per unit).
    #[arg(long, value_name = "FILE")]
    svg: Option<PathBuf>,
}

/// `tune`.
#[derive(Args)]
pub struct TuneArgs {
    /// Which loop.
    #[arg(value_enum)]
    which: LoopArg,
    /// Step size: A (current), rad/s (speed), rad (position; output frame).
    #[arg(long)]
    step: Option<f32>,
    /// Write the capture as CSV.
    #[arg(long, value_name = "FILE")]
    csv: Option<PathBuf>,
    /// Write an SVG plot of the step.
    #[arg(long, value_name = "FILE")]
    svg: Option<PathBuf>,
}

/// The loop on the command line.
#[derive(Clone, Copy, ValueEnum)]
pub enum LoopArg {
    /// q current, torque mode.
    Current,
    /// Velocity.
    Speed,
    /// Position.
    Position,
}

fn signal(name: &str) -> Result<Signal, String> {
    signal_by_name(name.trim()).ok_or_else(|| format!("unknown signal `{name}`"))
}

/// Run a `scope` subcommand.
pub fn scope(c: &mut Client, cmd: ScopeCmd) -> CliResult {
    match cmd {
        ScopeCmd::Set(a) => {
            let sigs = a
                .signals
                .iter()
                .map(|s| signal(s))
                .collect::<Result<Vec<_>, _>>()?;
            if sigs.is_empty() || sigs.len() > foc_core::scope::MAX_CHANNELS {
                return Err("1 to 8 signals".into());
            }
            let mut cfg = ScopeConfig::new(&sigs);
            cfg.divider = a.every;
            cfg.samples = a.samples;
            cfg.trigger = match a.trigger {
                TriggerArg::Manual => TriggerKind::Manual,
                TriggerArg::Command => TriggerKind::Command,
                TriggerArg::Fault => TriggerKind::Fault,
                TriggerArg::Rising => TriggerKind::Rising,
                TriggerArg::Falling => TriggerKind::Falling,
                TriggerArg::Either => TriggerKind::Either,
            };
            cfg.trigger_signal = signal(&a.trigger_signal)?;
            cfg.level = a.level;
            let capacity = c.param(foc_protocol::message::ParamId::ScopeCapacity)? as usize;
            let samples = if a.samples == 0 {
                capacity / sigs.len()
            } else {
                usize::from(a.samples)
            };
            cfg.pre_trigger = a.pre.unwrap_or((samples / 10) as u16);
            c.set_scope(&cfg)?;
            say!(
                "scope set: {samples} samples of {} signal(s) every {} period(s)",
                sigs.len(),
                a.every
            );
            Ok(())
        }
        ScopeCmd::Arm => Ok(c.arm_scope()?),
        ScopeCmd::Trigger => Ok(c.trigger_scope()?),
        ScopeCmd::Status => {
            let r = c.read_scope()?;
            let s = r.status;
            let names: Vec<&str> = s.config.used().iter().map(|x| x.name()).collect();
            say!(
                "{:?}: {} of {} samples, trigger at {} (period {}), {} every {} period(s) ({:.1} us), trigger {:?}",
                s.state,
                s.captured,
                s.config.samples,
                s.trigger_index,
                s.trigger_period,
                names.join(","),
                s.config.divider,
                r.sample_period_s * 1e6,
                s.config.trigger
            );
            Ok(())
        }
        ScopeCmd::Read(a) => {
            let wait = Duration::try_from_secs_f64(a.wait_ms * 1e-3)
                .map_err(|_| format!("--wait-ms {}: not a time", a.wait_ms))?;
            let cap = c.scope_capture(wait)?;
            say!(
                "{} samples of {} signal(s), trigger at sample {}",
                cap.samples(),
                cap.signals().len(),
                cap.report.status.trigger_index
            );
            write_outputs(&cap, a.csv.as_deref(), a.svg.as_deref(), "scope capture")
        }
    }
}

/// Run `tune`.
pub fn tune(c: &mut Client, a: TuneArgs) -> CliResult {
    let (which, default_step) = match a.which {
        LoopArg::Current => (Loop::Current, 1.0),
        LoopArg::Speed => (Loop::Speed, 20.0),
        LoopArg::Position => (Loop::Position, 1.0),
    };
    let r = tune::run(
        c,
        which,
        a.step.unwrap_or(default_step),
        Duration::from_secs(10),
    )?;
    say_raw!("{r}");
    let title = format!("{:?} step", r.which);
    write_outputs(&r.capture, a.csv.as_deref(), a.svg.as_deref(), &title)
}

fn write_outputs(
    cap: &ScopeCapture,
    csv: Option<&Path>,
    svg: Option<&Path>,
    title: &str,
) -> CliResult {
    if let Some(p) = csv {
        let mut w = std::io::BufWriter::new(std::fs::File::create(p)?);
        cap.write_csv(&mut w)?;
        std::io::Write::flush(&mut w)?;
        say!("wrote {}", p.display());
    }
    if let Some(p) = svg {
        foc_ctl::scope::plot(cap, p, title)?;
        say!("wrote {}", p.display());
    }
    Ok(())
}
