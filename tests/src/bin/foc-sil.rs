//! `foc-sil`: the `foc-core` cascade as a software-in-the-loop process.
//!
//! Reads one JSON sample per line on stdin, writes one JSON decision per line
//! on stdout (flushed after each line); see `foc_bench::sil` for the protocol.
//! Refused lines and commands are reported on stderr; the process never
//! stops on bad input, only at the end of stdin (or on a read error). A
//! line longer than 64 KiB (`foc_bench::sil::MAX_LINE`) is never held in
//! memory: it is skipped up to its newline and answered like an invalid
//! line (one output line with an `error`, bridge off).
//!
//! The controller starts calibrated with a *supplied* permit: the
//! current-loop gains from the motor values, the angle calibration from
//! `--zero-offset-deg` / `--reversed` (default: encoder zero on the d axis).
//! `--uncalibrated` starts without one (open loop only). `--sensor
//! sensorless` runs on the flux observer (design §27): the lines' angle is
//! ignored and may be left out.
//!
//! ```text
//! foc-sil --motor tests/motors/dji-m2006.toml
//! foc-sil --pole-pairs 7 --r-ohm 0.1 --ld-h 30e-6 --lq-h 30e-6 --flux-wb 0.0024 \
//!         --pwm-hz 20000 --max-current-a 10 --bus-v 24
//! ```

use clap::Parser;
use foc_bench::mission::Setup;
use foc_bench::plant::{BenchConfig, MotorParams};
use foc_bench::sil::{read_line_bounded, BoundedLine, SilRunner, MAX_LINE};
use foc_core::angle::ElectricalAngle;
use foc_core::calibration::Calibrated;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

/// The foc-core cascade driven by JSON lines (stdin -> stdout).
#[derive(Debug, Parser)]
#[command(name = "foc-sil")]
struct Args {
    /// Motor file (tests/motors/*.toml); the flags below override its values.
    #[arg(long)]
    motor: Option<PathBuf>,
    /// Pole pairs.
    #[arg(long)]
    pole_pairs: Option<u8>,
    /// Phase resistance \[ohm\].
    #[arg(long)]
    r_ohm: Option<f64>,
    /// d-axis inductance \[H\].
    #[arg(long)]
    ld_h: Option<f64>,
    /// q-axis inductance \[H\].
    #[arg(long)]
    lq_h: Option<f64>,
    /// Flux linkage \[Wb\].
    #[arg(long)]
    flux_wb: Option<f64>,
    /// Rotor + load inertia [kg m^2] (speed-loop tuning).
    #[arg(long)]
    inertia: Option<f64>,
    /// PWM (= current-loop, = one input line) frequency \[Hz\].
    #[arg(long)]
    pwm_hz: Option<f64>,
    /// Speed loop every N periods (default: near 2 kHz).
    #[arg(long)]
    speed_div: Option<u16>,
    /// Position loop every M periods (default: near 1 kHz).
    #[arg(long)]
    position_div: Option<u16>,
    /// Current limit \[A\] (over-current trips at 1.5x).
    #[arg(long)]
    max_current_a: Option<f32>,
    /// Nominal bus voltage \[V\] (under/over-voltage at 60 % / 125 %).
    #[arg(long)]
    bus_v: Option<f64>,
    /// Electrical angle the encoder reads with the d axis on phase A \[deg\].
    #[arg(long, default_value_t = 0.0)]
    zero_offset_deg: f32,
    /// The encoder counts against A -> B -> C.
    #[arg(long)]
    reversed: bool,
    /// Start uncalibrated: only `disable` and `open_loop` are accepted
    /// (closed-loop commands are refused with `NotCalibrated`).
    #[arg(long)]
    uncalibrated: bool,
    /// Where the rotor angle comes from: `encoder` (each line's `theta_m`)
    /// or `sensorless` (the flux observer, design §27: `theta_m` is
    /// ignored and may be left out; the start at the rated current; only
    /// `disable`, `velocity` and `open_loop` commands).
    #[arg(long, value_enum, default_value_t = Sensor::Encoder)]
    sensor: Sensor,
    /// Field weakening on (design §30): above base speed the d current
    /// holds the voltage margin, up to the configured largest `|id|`
    /// (the smaller of the current limit and `psi / Ld`).
    #[arg(long)]
    field_weakening: bool,
    /// MTPA off (design §30; on by default where `Lq` exceeds `Ld` by
    /// more than 5 %): `id = 0` below base speed.
    #[arg(long)]
    no_mtpa: bool,
}

/// The angle source.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Sensor {
    /// The encoder reading on each line.
    Encoder,
    /// The flux observer; the lines' angle is ignored.
    Sensorless,
}

fn setup(a: &Args) -> Result<Setup, String> {
    let mut s = match &a.motor {
        Some(p) => Setup::load(p).map_err(|e| e.to_string())?,
        None => Setup {
            name: "command line".into(),
            motor: MotorParams::example(),
            bench: BenchConfig::default(),
            rated_current_a: 5.0,
            max_current_a: 10.0,
        },
    };
    let m = &mut s.motor;
    m.pole_pairs = a.pole_pairs.unwrap_or(m.pole_pairs);
    m.r_ohm = a.r_ohm.unwrap_or(m.r_ohm);
    m.ld_h = a.ld_h.unwrap_or(m.ld_h);
    m.lq_h = a.lq_h.unwrap_or(m.lq_h);
    m.flux_linkage_wb = a.flux_wb.unwrap_or(m.flux_linkage_wb);
    m.inertia_kg_m2 = a.inertia.unwrap_or(m.inertia_kg_m2);
    m.validate().map_err(|e| e.to_string())?;
    s.bench.pwm_frequency_hz = a.pwm_hz.unwrap_or(s.bench.pwm_frequency_hz);
    s.bench.bus_voltage_v = a.bus_v.unwrap_or(s.bench.bus_voltage_v);
    s.max_current_a = a.max_current_a.unwrap_or(s.max_current_a);
    s.rated_current_a = s.rated_current_a.min(s.max_current_a);
    let ok = |x: f64| x.is_finite() && x > 0.0;
    if !ok(s.bench.pwm_frequency_hz) || !ok(s.bench.bus_voltage_v) || !ok(s.max_current_a as f64) {
        return Err("--pwm-hz, --bus-v and --max-current-a must be > 0".into());
    }
    Ok(s)
}

fn main() -> ExitCode {
    let args = Args::parse();
    let s = match setup(&args) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("foc-sil: {e}");
            return ExitCode::FAILURE;
        }
    };
    let mut config = match args.sensor {
        Sensor::Encoder => s.cascade_config(),
        Sensor::Sensorless => s.sensorless_config(),
    };
    if args.sensor == Sensor::Sensorless && config.current.sensorless.is_none() {
        eprintln!("foc-sil: cannot run sensorless: the motor needs a flux linkage > 0");
        return ExitCode::FAILURE;
    }
    if let Some(n) = args.speed_div {
        config.rates.speed_divider = n.max(1);
    }
    if let Some(m) = args.position_div {
        config.rates.position_divider = m.max(1);
    }
    config.speed.ts_s = config.rates.speed_ts_s();
    config.position.ts_s = config.rates.position_ts_s();
    config.current.angle.zero_offset = ElectricalAngle::from_degrees(args.zero_offset_deg);
    config.current.angle.reversed = args.reversed;
    config.current.field.field_weakening = args.field_weakening;
    if args.no_mtpa {
        config.current.field.mtpa = false;
    }
    eprintln!(
        "foc-sil: {} | {} pole pairs, R {} ohm, Ld {} H, Lq {} H, psi {} Wb | PWM {} Hz, speed loop /{}, position loop /{} | {} | {} | ready",
        s.name,
        s.motor.pole_pairs,
        s.motor.r_ohm,
        s.motor.ld_h,
        s.motor.lq_h,
        s.motor.flux_linkage_wb,
        s.bench.pwm_frequency_hz,
        config.rates.speed_divider,
        config.rates.position_divider,
        match config.current.sensorless {
            None => "angle from theta_m".to_string(),
            Some(c) => format!(
                "sensorless: start at {:.2} A, hand-over at {:.0} rad/s (electrical)",
                c.current_a, c.handover_rad_s
            ),
        },
        if args.uncalibrated {
            "uncalibrated (open loop only)".to_string()
        } else {
            format!(
                "calibration supplied: zero offset {} deg(e){}",
                args.zero_offset_deg,
                if args.reversed { ", reversed" } else { "" }
            )
        }
    );
    // The calibration is supplied: the motor file / flags give the
    // current-loop configuration (technical optimum of R, Ld, Lq), the
    // flags the angle calibration. Checked for plausibility.
    let mut sil = if args.uncalibrated {
        SilRunner::new(config)
    } else {
        match Calibrated::supplied(config.current.angle, config.current.current) {
            Ok(permit) => SilRunner::with_calibration(config, &permit),
            Err(e) => {
                eprintln!("foc-sil: implausible calibration ({e:?}): check the motor values");
                return ExitCode::FAILURE;
            }
        }
    };
    let stdin = std::io::stdin();
    let mut input = stdin.lock();
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    let mut buf = Vec::new();
    loop {
        let (reply, err) = match read_line_bounded(&mut input, &mut buf, MAX_LINE) {
            Ok(BoundedLine::Eof) => break,
            Ok(BoundedLine::Line) => match std::str::from_utf8(&buf) {
                Ok(line) => sil.line(line),
                // Still one period without a sample.
                Err(e) => sil.refuse(&format!("unreadable input line: not UTF-8 ({e})")),
            },
            Ok(BoundedLine::TooLong(n)) => sil.refuse(&format!(
                "input line too long: {n} bytes (at most {MAX_LINE})"
            )),
            Err(e) => {
                eprintln!("foc-sil: cannot read stdin: {e}");
                return ExitCode::FAILURE;
            }
        };
        if let Some(e) = err {
            eprintln!("foc-sil: {e}");
        }
        if writeln!(out, "{reply}").and_then(|()| out.flush()).is_err() {
            break; // the reader went away
        }
    }
    ExitCode::SUCCESS
}
