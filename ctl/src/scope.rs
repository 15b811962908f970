//! The drive's scope from the host (design §22): configure, arm, trigger,
//! wait, read the capture out, write it as CSV.
//!
//! ```no_run
//! use foc_core::control::Command;
//! use foc_core::scope::{ScopeConfig, Signal};
//! use std::time::Duration;
//! let mut c = foc_ctl::Client::connect_tcp("127.0.0.1:4444")?;
//! let mut cfg = ScopeConfig::new(&[Signal::IqRefA, Signal::IqA]);
//! cfg.samples = 200;
//! cfg.pre_trigger = 20;
//! c.set_scope(&cfg)?;
//! c.arm_scope()?;
//! c.set_command(Command::Torque { iq_a: 1.0 })?;
//! let capture = c.scope_capture(Duration::from_secs(2))?;
//! println!("{} samples, trigger at {}", capture.samples(), capture.report.status.trigger_index);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::{Client, ClientError};
use foc_core::scope::{ScopeConfig, Signal, State};
use foc_protocol::message::{Request, Response};
use foc_protocol::scope::ScopeReport;
use std::io::{self, Write};
use std::path::Path;
use std::time::{Duration, Instant};

/// A finished capture.
#[derive(Clone, Debug, PartialEq)]
pub struct ScopeCapture {
    /// The scope's report when it was read (state done).
    pub report: ScopeReport,
    /// The values, sample-major (value `k n + c` is signal `c` of sample `k`).
    pub values: Vec<f32>,
}

impl ScopeCapture {
    /// The recorded signals.
    pub fn signals(&self) -> &[Signal] {
        self.report.status.config.used()
    }

    /// Samples per signal.
    pub fn samples(&self) -> usize {
        self.values.len() / self.signals().len().max(1)
    }

    /// One signal's samples, oldest first (`None`: not recorded).
    pub fn channel(&self, s: Signal) -> Option<Vec<f64>> {
        let n = self.signals().len();
        let c = self.signals().iter().position(|x| *x == s)?;
        Some(
            self.values
                .iter()
                .skip(c)
                .step_by(n.max(1))
                .map(|v| f64::from(*v))
                .collect(),
        )
    }

    /// Sample times \[s\] relative to the trigger sample.
    pub fn time_s(&self) -> Vec<f64> {
        let dt = f64::from(self.report.sample_period_s);
        let t0 = f64::from(self.report.status.trigger_index);
        (0..self.samples()).map(|k| (k as f64 - t0) * dt).collect()
    }

    /// CSV: `time_s` then one column per signal (`name_unit`).
    pub fn write_csv(&self, mut w: impl Write) -> io::Result<()> {
        write!(w, "time_s")?;
        for s in self.signals() {
            write!(w, ",{}", column_name(*s))?;
        }
        writeln!(w)?;
        let n = self.signals().len().max(1);
        for (t, row) in self.time_s().iter().zip(self.values.chunks(n)) {
            write!(w, "{t:.7}")?;
            for v in row {
                write!(w, ",{v}")?;
            }
            writeln!(w)?;
        }
        Ok(())
    }
}

/// CSV column of a signal: its name and unit.
pub fn column_name(s: Signal) -> String {
    let unit = match s.unit() {
        "rad/s" => "rad_s",
        "A | rad/s | rad" => "setpoint",
        "1" => "frac",
        u => u,
    };
    format!("{}_{}", s.name(), unit)
}

/// A signal by its short name (`iq`, `iq_ref`, `velocity`...) or code.
pub fn signal_by_name(name: &str) -> Option<Signal> {
    Signal::ALL
        .iter()
        .copied()
        .find(|s| s.name() == name)
        .or_else(|| name.parse::<u8>().ok().and_then(Signal::from_code))
}

impl Client {
    /// Configure the scope (it goes idle; a capture is dropped).
    pub fn set_scope(&mut self, c: &ScopeConfig) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetScope(*c))
    }

    /// Arm the scope: it records, waiting for its trigger.
    pub fn arm_scope(&mut self) -> Result<(), ClientError> {
        self.expect_ack(&Request::ArmScope)
    }

    /// Trigger the armed scope now.
    pub fn trigger_scope(&mut self) -> Result<(), ClientError> {
        self.expect_ack(&Request::TriggerScope)
    }

    /// The scope's state and configuration.
    pub fn read_scope(&mut self) -> Result<ScopeReport, ClientError> {
        match self.request(&Request::ReadScope)? {
            Response::Scope(r) => Ok(r),
            r => Err(ClientError::Unexpected(r)),
        }
    }

    /// Read a finished capture out, 12 values a frame.
    pub fn read_scope_values(&mut self) -> Result<ScopeCapture, ClientError> {
        let report = self.read_scope()?;
        let st = report.status;
        if st.state != State::Done {
            return Err(ClientError::Nack(foc_protocol::ErrorCode::ScopeState));
        }
        let total = usize::from(st.captured) * usize::from(st.config.channels);
        let mut values = Vec::with_capacity(total);
        while values.len() < total {
            let offset = u16::try_from(values.len())
                .map_err(|_| ClientError::Nack(foc_protocol::ErrorCode::Malformed))?;
            match self.request(&Request::ReadScopeData { offset })? {
                Response::ScopeData(d) if d.offset == offset && d.count > 0 => {
                    values.extend_from_slice(d.values());
                }
                r => return Err(ClientError::Unexpected(r)),
            }
        }
        values.truncate(total);
        Ok(ScopeCapture { report, values })
    }

    /// Wait (polling, host time at most `timeout`) until the capture is
    /// done, then read it. The capture itself ends in the drive's own time
    /// (its samples), so `timeout` is only a backstop.
    pub fn scope_capture(&mut self, timeout: Duration) -> Result<ScopeCapture, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            let r = self.read_scope()?;
            match r.status.state {
                State::Done => return self.read_scope_values(),
                State::Idle => return Err(ClientError::Nack(foc_protocol::ErrorCode::ScopeState)),
                State::Armed | State::Triggered => {}
            }
            if Instant::now() >= deadline {
                let t = timeout.as_secs_f32();
                return Err(ClientError::NotReady(match r.status.state {
                    State::Armed => format!(
                        "the scope is armed and waiting for its trigger ({:?}): nothing triggered it in {t:.1} s \
                         (`foc-ctl scope trigger` forces it; `--wait-ms` waits longer)",
                        r.status.config.trigger
                    ),
                    _ => format!(
                        "the scope triggered but is still recording after {t:.1} s ({} samples): wait longer (`--wait-ms`)",
                        r.status.captured
                    ),
                }));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

/// One panel per unit (currents, voltages, velocity, position, the rest
/// each alone), against time from the trigger.
pub fn plot(cap: &ScopeCapture, path: &Path, title: &str) -> std::io::Result<()> {
    let t: Vec<f64> = cap.time_s().iter().map(|x| x * 1e3).collect();
    let chans: Vec<(Signal, Vec<f64>)> = cap
        .signals()
        .iter()
        .filter_map(|s| cap.channel(*s).map(|v| (*s, v)))
        .collect();
    let mut units: Vec<&str> = vec![];
    for (s, _) in &chans {
        if !units.contains(&s.unit()) {
            units.push(s.unit());
        }
    }
    let labels: Vec<String> = units.iter().map(|u| unit_label(u)).collect();
    let panels = units
        .iter()
        .zip(&labels)
        .map(|(u, label)| foc_plot::Panel {
            y_label: label,
            series: chans
                .iter()
                .filter(|(s, _)| s.unit() == *u)
                .map(|(s, v)| foc_plot::Series {
                    name: s.name(),
                    x: &t,
                    y: v,
                })
                .collect(),
        })
        .collect();
    foc_plot::write_svg(
        path,
        &foc_plot::Figure {
            title,
            x_label: "time from the trigger [ms]",
            panels,
            x_marker: Some((0.0, "trigger")),
        },
    )
}

fn unit_label(unit: &str) -> String {
    match unit {
        "A" => "current [A]".into(),
        "V" => "voltage [V]".into(),
        "rad/s" => "velocity [rad/s] (rotor)".into(),
        "rad" => "angle / position [rad] (rotor)".into(),
        "1" => "duty [0..1]".into(),
        "code" => "mode [code]".into(),
        u => format!("set-point [{u}]"),
    }
}
