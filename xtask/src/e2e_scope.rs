//! `cargo xtask e2e`, the scope step: a current step on the emulated
//! firmware through `foc-ctl tune current` (the client library's
//! [`foc_ctl::tune::run`]: the drive's scope, triggered by the step's
//! command), and the same step on the bench ([`foc_bench::scope_step`]:
//! the emulated board's motor and inverter, the drive's current gains, the
//! same scope). The figures must agree: overshoot within
//! [`OVERSHOOT_TOL_PP`] percentage points, settling within
//! [`SETTLING_TOL_PERIODS`] PWM period (the firmware's median of
//! [`FIRMWARE_STEPS`] steps).

use foc_core::scope::{Signal, State};
use foc_ctl::scope::ScopeCapture;
use foc_ctl::tune::{self, Loop, StepFigures, TuneReport};
use foc_ctl::Client;
use foc_protocol::message::ParamId;
use foc_protocol::scope::ScopeReport;
use std::path::Path;
use std::time::Duration;

use crate::util::{Error, Result};

/// The step [A] (5 % of it is well above the ADC's noise).
pub const STEP_A: f32 = 5.0;
/// Overshoot agreement [percentage points].
pub const OVERSHOOT_TOL_PP: f64 = 1.0;
/// Settling agreement [PWM periods].
pub const SETTLING_TOL_PERIODS: i64 = 1;
/// Steps taken on the firmware: the one with the median settling time is
/// compared (the emulated ADC's noise moves the 5 % band's crossing by a
/// period or two from one capture to the next; the bench is
/// deterministic).
pub const FIRMWARE_STEPS: usize = 3;

/// Run the step on the drive ([`FIRMWARE_STEPS`] times) and on the bench,
/// write both captures to `out` (CSV, SVG), compare.
pub fn current_step(client: &mut Client, backstop: Duration, out: &Path) -> Result {
    let report = median_firmware_step(client, backstop)?;
    let param = |c: &mut Client, id| {
        c.param(id)
            .map_err(|e| Error(format!("FAIL scope: read {id:?}: {e}")))
    };
    let kp = param(client, ParamId::CurrentKp)?;
    let ki = param(client, ParamId::CurrentKi)?;
    let pwm_hz = param(client, ParamId::PwmFrequencyHz)?;
    let bench = bench_step(kp, ki, pwm_hz)?;
    let b = StepFigures::of(&bench, Signal::IqA, f64::from(STEP_A))
        .ok_or_else(|| Error("FAIL scope: no iq in the bench's capture".into()))?;
    let f = report.figures;
    write_captures(out, &report.capture, &bench)?;
    print!("{report}");
    compare(&f, &b, (kp, ki), out)
}

/// The step on the drive, [`FIRMWARE_STEPS`] times (each one's figures
/// printed): the run with the median settling time.
fn median_firmware_step(client: &mut Client, backstop: Duration) -> Result<TuneReport> {
    let mut reports = Vec::with_capacity(FIRMWARE_STEPS);
    for _ in 0..FIRMWARE_STEPS {
        let r = match tune::run(client, Loop::Current, STEP_A, backstop) {
            Ok(r) => r,
            Err(e) => {
                let fault = client.read_telemetry().map(|t| t.fault_code);
                return Err(Error(format!(
                    "FAIL scope: tune current: {e} (fault code {fault:?})"
                )));
            }
        };
        reports.push(r);
    }
    let all: Vec<String> = reports
        .iter()
        .map(|r| {
            format!(
                "{:.2} % / {}",
                r.figures.overshoot_pct,
                fmt_periods(r.figures.settling_periods)
            )
        })
        .collect();
    println!(
        "firmware steps (overshoot / settling periods): {}",
        all.join(", ")
    );
    // Not settled sorts last.
    reports.sort_by_key(|r| r.figures.settling_periods.unwrap_or(u32::MAX));
    Ok(reports.swap_remove(FIRMWARE_STEPS / 2))
}

/// The same step on the bench with the drive's gains `kp`, `ki`, sampled
/// at the drive's PWM frequency `pwm_hz`: its capture.
fn bench_step(kp: f32, ki: f32, pwm_hz: f32) -> Result<ScopeCapture> {
    let (status, values) = foc_bench::scope_step::emulated_current_step(STEP_A, Some((kp, ki)));
    if status.state != State::Done {
        return Err(Error(
            "FAIL scope: the bench's capture did not finish".into(),
        ));
    }
    Ok(ScopeCapture {
        report: ScopeReport {
            status,
            sample_period_s: 1.0 / pwm_hz,
        },
        values,
    })
}

/// Both captures to `out`: `current_step_{firmware,bench}.csv` and `.svg`.
fn write_captures(out: &Path, firmware: &ScopeCapture, bench: &ScopeCapture) -> Result {
    std::fs::create_dir_all(out)?;
    for (name, cap) in [("firmware", firmware), ("bench", bench)] {
        let csv = out.join(format!("current_step_{name}.csv"));
        let mut w = std::io::BufWriter::new(std::fs::File::create(&csv)?);
        cap.write_csv(&mut w)?;
        std::io::Write::flush(&mut w)?;
        let svg = out.join(format!("current_step_{name}.svg"));
        foc_ctl::scope::plot(cap, &svg, &format!("q-current step of {STEP_A} A, {name}"))?;
    }
    Ok(())
}

/// The firmware's figures `f` against the bench's `b` (gains `(kp, ki)`,
/// captures in `out`, for the report line): both settled, overshoot within
/// [`OVERSHOOT_TOL_PP`] and settling within [`SETTLING_TOL_PERIODS`].
fn compare(f: &StepFigures, b: &StepFigures, (kp, ki): (f32, f32), out: &Path) -> Result {
    let d_os = (f.overshoot_pct - b.overshoot_pct).abs();
    // Both must settle within the capture, and agree.
    let ok = match (f.settling_periods, b.settling_periods) {
        (Some(x), Some(y)) => {
            d_os <= OVERSHOOT_TOL_PP && (i64::from(x) - i64::from(y)).abs() <= SETTLING_TOL_PERIODS
        }
        _ => false,
    };
    let line = format!(
        "scope current step {STEP_A} A (kp {kp:.4} V/A, ki {ki:.1} V/(A s)): firmware overshoot {:.2} %, 5 % settling {} periods, rise {}; bench {:.2} %, {} periods, rise {} (tolerances {OVERSHOOT_TOL_PP} pp, {SETTLING_TOL_PERIODS} period); captures in {}",
        f.overshoot_pct,
        fmt_periods(f.settling_periods),
        fmt_ms(f.rise_s),
        b.overshoot_pct,
        fmt_periods(b.settling_periods),
        fmt_ms(b.rise_s),
        out.display()
    );
    if ok {
        println!("PASS {line}");
        Ok(())
    } else {
        Err(Error(format!("FAIL {line}")))
    }
}

fn fmt_periods(p: Option<u32>) -> String {
    p.map_or("-".into(), |p| p.to_string())
}

fn fmt_ms(x: Option<f64>) -> String {
    x.map_or("-".into(), |v| format!("{:.3} ms", v * 1e3))
}
