//! Running a calibration from the host and following it: its steps as the
//! drive reports them (`calibration-step`, `calibration-result`), its end,
//! and what a failure means.
//!
//! ```no_run
//! use foc_ctl::{calibration, Client};
//! use foc_protocol::message::Calibration;
//! use std::time::Duration;
//! let mut c = Client::connect_tcp("127.0.0.1:4444")?;
//! let end = calibration::run(&mut c, Calibration::Identification, Duration::from_secs(120),
//!     &mut |p, t| println!("{:5.1} s  {}", t.as_secs_f64(), p.step_name()))?;
//! if let calibration::WaitEnd::Ended(p) = end {
//!     println!("{}", p.result_text());
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::{Client, ClientError};
use foc_protocol::message::{
    failure_reason, step_name, Calibration, ParamId, FAILED_BASE, RESULT_NAMES,
};
use std::time::{Duration, Instant};

/// How often the host asks while it waits.
const POLL: Duration = Duration::from_millis(20);

/// An offset calibration started this long ago without a "running" seen
/// has ended (the offsets and the sensor check take about 50 ms: a poll
/// may miss them).
const SHORT_RUN: Duration = Duration::from_secs(1);

/// An identification not seen running this long after the request was
/// not started.
const START_WAIT: Duration = Duration::from_secs(2);

/// The drive's report: the step running (or where the last run ended)
/// and the result code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CalProgress {
    /// `calibration-step`.
    pub step: u8,
    /// `calibration-result`.
    pub result: u8,
}

impl CalProgress {
    /// Read it from the drive.
    pub fn read(c: &mut Client) -> Result<Self, ClientError> {
        let step = c.param(ParamId::CalibrationStep)? as u8;
        let result = c.param(ParamId::CalibrationResult)? as u8;
        Ok(Self { step, result })
    }
    /// A calibration runs.
    pub fn running(&self) -> bool {
        self.result == 1
    }
    /// The last one finished successfully.
    pub fn done(&self) -> bool {
        self.result == 2
    }
    /// The step's name.
    pub fn step_name(&self) -> &'static str {
        step_name(self.step)
    }
    /// The result in words (`"failed: RotorStuck"`, ...).
    pub fn result_text(&self) -> String {
        result_name(self.result)
    }
    /// A failure's reason (the drive's `CalError`), if it failed.
    pub fn failure(&self) -> Option<&'static str> {
        (self.result >= FAILED_BASE)
            .then(|| failure_reason(self.result))
            .flatten()
    }
    /// What to do about how it ended, for people.
    pub fn advice(&self) -> &'static str {
        match self.result {
            2 => "",
            3 => "stopped by a fault or a Disable: `foc-ctl faults` says which; clear it and run it again",
            4 => "the current sensing's offsets were rejected (noise or an offset too large) or it did not answer: check the supply and the sensing; `foc-ctl faults`",
            5 => "the angle sensor did not answer: its wiring and supply; `foc-ctl faults`",
            _ => self.failure().map_or("", advice_for),
        }
    }
}

/// The words for a `calibration-result` code (`"failed: <reason>"` for a
/// failure).
pub fn result_name(code: u8) -> String {
    match (RESULT_NAMES.get(usize::from(code)), failure_reason(code)) {
        (Some(r), _) => (*r).into(),
        (None, Some(reason)) => format!("failed: {reason}"),
        (None, None) => "unknown".into(),
    }
}

/// What to do about a failure's reason.
fn advice_for(reason: &str) -> &'static str {
    match reason {
        "OpenPhase(A)" | "OpenPhase(B)" | "OpenPhase(C)" => {
            "no current flows in that phase: check its wire, connector and switch"
        }
        "VoltageLimitReached" => {
            "the test current is not reached: lower the test current or raise the voltage limit (a high resistance, or a low bus)"
        }
        "PhaseImbalance" => "the phase resistances disagree: a loose connection or a damaged winding",
        "CurrentSenseMismatch" => {
            "the measured current does not follow the voltage: current-sense phase order, gain sign or motor wiring"
        }
        "PolePairMismatch" => "the configured pole-pair count is wrong: fix it in the configuration",
        "SensorReversed" => "the sensor counts the other way: set the direction in the configuration",
        "RotorStuck" | "NoAcceleration" => {
            "the rotor did not follow: free it (a brake, a load, an end stop) and run it again"
        }
        "SensorNoMotion" => "the angle sensor did not change: its wiring, supply or magnet",
        "SpeedNotReached" => "the test speed was not reached: too much friction or load for the test current",
        "OverCurrent" => "the current went past the routine's limit: check the motor file's values and the wiring",
        "Timeout" => "a step did not finish in time: the motor may be loaded or far from its configured values",
        "ImplausibleResult" => {
            "the result is implausible (an anticogging map above half the current limit is a load \
             or friction, not cogging; an angle correction beyond 5 deg a loose or broken sensor): \
             free the rotor, check the sensor's mounting and run it again"
        }
        _ => "see the identification guide (docs/src/guide/identification.md)",
    }
}

/// How a wait ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WaitEnd {
    /// The calibration ended with this report (done or not: see it).
    Ended(CalProgress),
    /// Still running at the timeout, with this report.
    TimedOut(CalProgress),
    /// The drive took the request but never showed the routine running
    /// (the report is still the one from before it).
    NotStarted(CalProgress),
}

/// Start `routine` and wait for its end (at most `timeout`), calling
/// `on_change` with each new report and the time since the start.
pub fn run(
    c: &mut Client,
    routine: Calibration,
    timeout: Duration,
    on_change: &mut dyn FnMut(&CalProgress, Duration),
) -> Result<WaitEnd, ClientError> {
    let before = CalProgress::read(c)?;
    c.calibrate(routine)?;
    wait(c, routine, before, timeout, on_change)
}

/// Wait for the calibration started after the drive reported `before`.
pub fn wait(
    c: &mut Client,
    routine: Calibration,
    before: CalProgress,
    timeout: Duration,
    on_change: &mut dyn FnMut(&CalProgress, Duration),
) -> Result<WaitEnd, ClientError> {
    let t0 = Instant::now();
    let mut seen_running = false;
    let mut last = None;
    loop {
        let now = CalProgress::read(c)?;
        let t = t0.elapsed();
        if last != Some(now) {
            on_change(&now, t);
            last = Some(now);
        }
        seen_running |= now.running();
        let quick = routine == Calibration::Offsets && t > SHORT_RUN;
        if !now.running() && (seen_running || now != before || quick) {
            return Ok(WaitEnd::Ended(now));
        }
        if !seen_running && now == before && t > START_WAIT && routine != Calibration::Offsets {
            return Ok(WaitEnd::NotStarted(now));
        }
        if t > timeout {
            return Ok(WaitEnd::TimedOut(now));
        }
        std::thread::sleep(POLL);
    }
}
