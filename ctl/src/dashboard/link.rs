//! The dashboard's link thread: it alone owns the [`Client`]. It keeps the
//! drive's telemetry streaming into a buffer the page reads, refreshes the
//! status a few times a second, and runs the page's jobs (a console
//! command, a calibration, the wizard's steps) between stream reads.

use super::faults::fault_json;
use super::wizard;
use crate::{dispatch, out, Cli};
use clap::Parser;
use foc_ctl::calibration::CalProgress;
use foc_ctl::{Client, StreamSample};
use foc_protocol::message::{Calibration, ParamId, Request, TelemetryRate};
use serde_json::{json, Value};
use std::collections::VecDeque;
use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Samples kept for the page (about a minute at 200 Hz).
const KEEP: usize = 12_000;

/// How often the status is refreshed (and the link kept alive while a
/// page is open).
const STATUS_EVERY: Duration = Duration::from_millis(250);

/// A page that has not asked for samples for this long is gone: the link
/// watchdog is no longer fed, and the drive stops as it would without a
/// host.
const PAGE_GONE: Duration = Duration::from_secs(1);

/// How often the link is kept alive while a page is open (and how long
/// the stream is read between jobs).
const KEEP_ALIVE_EVERY: Duration = Duration::from_millis(50);

/// A job that waited longer than this for the link is dropped unrun (the
/// page has given up on it: it must not move the motor later).
pub(super) const JOB_EXPIRES: Duration = Duration::from_secs(30);

/// The telemetry columns the page can plot, with their units.
pub(super) const SIGNALS: [(&str, &str); 12] = [
    ("velocity", "rad/s (output)"),
    ("position", "rad (output)"),
    ("iq", "A"),
    ("id", "A"),
    ("vq", "V"),
    ("vd", "V"),
    ("bus", "V"),
    ("mode", "code"),
    ("fault", "code"),
    ("limit_left", "%"),
    ("winding", "degC"),
    ("stage", "degC"),
];

/// A page's request to the link thread.
pub(super) enum Job {
    /// A foc-ctl command line (without `foc-ctl` and the connection).
    Console(String),
    /// Start a calibration (its progress shows in the status).
    Calibrate(Calibration),
    /// The wizard's sensor check (a slow open-loop turn).
    SensorCheck,
    /// Disable the drive (the page's button: a running job has been told
    /// to stop).
    Disable,
    /// The wizard's tuning report (a current step).
    Tune,
    /// Stream at this rate \[Hz\].
    SetRate(f32),
    /// The configuration tree.
    ConfigTree,
    /// One configuration key changed and applied.
    ConfigSet(String, String),
    /// The wizard's motor step: a motor file's text, or nameplate values
    /// (configuration keys), applied as one record.
    Motor(Option<String>, Vec<(String, String)>),
    /// The scope's state, and its capture when done.
    ScopeData,
}

/// What the link thread shares with the server.
#[derive(Default)]
pub(super) struct Shared {
    /// Streamed samples: the index of the first kept, then the rows.
    pub samples: Mutex<Samples>,
    /// The last status (JSON).
    pub status: Mutex<Value>,
    /// When a page last asked for samples.
    pub page_seen: Mutex<Option<Instant>>,
    /// The page asked to disable the drive: a running job stops at its
    /// next check and the bridge goes off.
    pub abort: std::sync::atomic::AtomicBool,
}

/// The kept samples.
#[derive(Default)]
pub(super) struct Samples {
    /// Index of `rows[0]` since the dashboard started.
    pub first: u64,
    /// Device time \[s\] and the [`SIGNALS`] per row.
    pub rows: VecDeque<(f64, [f32; 12])>,
    /// Lost in the stream (its counter's gaps).
    pub lost: u64,
    /// The rate asked \[Hz\] and the drive's divider \[periods\].
    pub rate_hz: f32,
    pub every_periods: f32,
}

impl Samples {
    /// Rows from index `since` on (at most `max`): the next index and the
    /// columns as JSON.
    pub fn since(&self, since: u64, max: usize) -> Value {
        let end = self.first + self.rows.len() as u64;
        let from = since.clamp(self.first, end);
        let skip = (from - self.first) as usize;
        let rows: Vec<&(f64, [f32; 12])> = self.rows.iter().skip(skip).take(max).collect();
        let t: Vec<f64> = rows.iter().map(|r| r.0).collect();
        let mut cols = serde_json::Map::new();
        for (k, (name, _)) in SIGNALS.iter().enumerate() {
            let v: Vec<Value> = rows
                .iter()
                .map(|r| r.1.get(k).map_or(Value::Null, |x| finite(*x)))
                .collect();
            cols.insert((*name).into(), Value::Array(v));
        }
        json!({
            "next": from + rows.len() as u64,
            "skipped": from - since.min(from),
            "t": t,
            "data": cols,
            "lost": self.lost,
            "rate_hz": self.rate_hz,
            "every_periods": self.every_periods,
        })
    }
}

/// A number for JSON (`null` for NaN and infinities).
pub(super) fn finite(x: f32) -> Value {
    if x.is_finite() {
        json!(x)
    } else {
        Value::Null
    }
}

/// The link thread's state.
pub(super) struct Link {
    c: Client,
    shared: Arc<Shared>,
    pwm_hz: f64,
    rate_hz: f32,
    /// Unwrapped period counter of the last sample.
    last_period: Option<u32>,
    periods: u64,
    last_status: Instant,
}

impl Link {
    pub(super) fn new(mut c: Client, shared: Arc<Shared>, rate_hz: f32) -> Self {
        let pwm_hz = c.param(ParamId::PwmFrequencyHz).map_or(20_000.0, f64::from);
        Self {
            c,
            shared,
            pwm_hz,
            rate_hz,
            last_period: None,
            periods: 0,
            last_status: Instant::now() - STATUS_EVERY,
        }
    }

    /// A page asked for samples within [`PAGE_GONE`].
    fn page_open(&self) -> bool {
        self.shared
            .page_seen
            .lock()
            .ok()
            .and_then(|g| *g)
            .is_some_and(|t| t.elapsed() < PAGE_GONE)
    }

    /// Serve until the job channel closes.
    pub(super) fn run(mut self, jobs: Receiver<(Job, Instant, Sender<Value>)>) {
        self.start_stream();
        loop {
            loop {
                match jobs.try_recv() {
                    Ok((job, asked, reply)) => {
                        let v = if asked.elapsed() > JOB_EXPIRES {
                            json!({"ok": false, "error": "dropped: it waited too long for the link"})
                        } else {
                            self.job(job)
                        };
                        let _ = reply.send(v);
                        self.start_stream();
                    }
                    Err(std::sync::mpsc::TryRecvError::Empty) => break,
                    Err(std::sync::mpsc::TryRecvError::Disconnected) => return,
                }
            }
            self.pump(KEEP_ALIVE_EVERY);
            // The page is the host: while it is open, the drive's link
            // watchdog is fed, as a GUI that stays connected does (every
            // 50 ms: a simulated drive may run faster than real time).
            if self.page_open() {
                let _ = self.c.keep_alive();
            }
            if self.last_status.elapsed() >= STATUS_EVERY {
                self.last_status = Instant::now();
                let s = self.status();
                if let Ok(mut g) = self.shared.status.lock() {
                    *g = s;
                }
            }
        }
    }

    /// (Re)start the stream at the rate in force; a refusal is kept in the
    /// status.
    fn start_stream(&mut self) {
        let r = TelemetryRate::Hz(self.rate_hz);
        let every = match self.c.start_telemetry(r) {
            Ok(()) => self.c.param(ParamId::TelemetryDivider).unwrap_or(0.0),
            Err(_) => 0.0,
        };
        if let Ok(mut s) = self.shared.samples.lock() {
            s.rate_hz = self.rate_hz;
            s.every_periods = every;
        }
    }

    /// Read streamed samples for about `d`.
    fn pump(&mut self, d: Duration) {
        let end = Instant::now() + d;
        while let Ok(Some(s)) = self
            .c
            .next_stream(end.saturating_duration_since(Instant::now()))
        {
            self.keep(&s);
            if Instant::now() >= end {
                break;
            }
        }
        self.keep_lost();
    }

    fn keep_lost(&mut self) {
        let lost = self.c.stats().stream_lost;
        if let Ok(mut g) = self.shared.samples.lock() {
            g.lost = lost;
        }
    }

    /// One sample into the buffer, on the device's time axis.
    fn keep(&mut self, s: &StreamSample) {
        let t = &s.sample;
        if let Some(p) = self.last_period {
            self.periods += u64::from(t.period.wrapping_sub(p));
        }
        self.last_period = Some(t.period);
        let row = [
            t.velocity_rad_s,
            t.position_rad,
            t.i_q_a,
            t.i_d_a,
            t.v_q_v,
            t.v_d_v,
            t.v_bus_v,
            f32::from(t.mode as u8),
            f32::from(t.fault_code),
            f32::from(t.limit_left_pct),
            t.winding_c,
            t.stage_c,
        ];
        if let Ok(mut g) = self.shared.samples.lock() {
            g.rows.push_back((self.periods as f64 / self.pwm_hz, row));
            while g.rows.len() > KEEP {
                g.rows.pop_front();
                g.first += 1;
            }
        }
    }

    /// The status: mode, faults with what they mean, calibration progress,
    /// the last sample.
    fn status(&mut self) -> Value {
        let c = &mut self.c;
        let faults = c.faults().ok();
        let progress = CalProgress::read(c).ok();
        let calibrated = c.param(ParamId::Calibrated).ok();
        let source = c.param(ParamId::AngleSource).ok();
        let last = self
            .shared
            .samples
            .lock()
            .ok()
            .and_then(|g| g.rows.back().map(|r| r.1));
        json!({
            "connected": faults.is_some(),
            "mode": last.map(|r| mode_name(r[7] as u8)),
            "velocity": last.map(|r| finite(r[0])),
            "position": last.map(|r| finite(r[1])),
            "iq": last.map(|r| finite(r[2])),
            "bus": last.map(|r| finite(r[6])),
            "calibrated": calibrated.map(|v| v == 1.0),
            "angle_source": source,
            "faults": faults.map(|f| fault_json(f.set.0, f.first_code)),
            "calibration": progress.map(|p| json!({
                "step": p.step,
                "step_name": p.step_name(),
                "result": p.result,
                "result_text": p.result_text(),
                "running": p.running(),
                "done": p.done(),
                "advice": p.advice(),
            })),
        })
    }

    /// Run one job.
    fn job(&mut self, job: Job) -> Value {
        use std::sync::atomic::Ordering;
        match job {
            Job::Disable => {
                let r = self.c.set_command(foc_core::control::Command::Disable);
                self.shared.abort.store(false, Ordering::Relaxed);
                match r {
                    Ok(()) => json!({"ok": true, "output": "disabled"}),
                    Err(e) => json!({"ok": false, "output": e.to_string()}),
                }
            }
            Job::Console(line) => self.console(&line),
            Job::Calibrate(r) => match self.c.calibrate(r) {
                Ok(()) => json!({"ok": true}),
                Err(e) => {
                    json!({"ok": false, "error": foc_ctl::refusal::explain(&mut self.c, &Request::RunCalibration(r), &e)})
                }
            },
            Job::SensorCheck => wizard::sensor_check(&mut self.c, &self.shared.abort),
            Job::Tune => wizard::tune_report(&mut self.c),
            Job::ConfigTree => super::config::tree(&mut self.c),
            Job::ConfigSet(key, value) => super::config::set(&mut self.c, &key, &value),
            Job::Motor(file, mut pairs) => {
                if let Some(text) = file {
                    match super::config::motor_file_pairs(&text) {
                        Ok(p) => pairs.extend(p),
                        Err(e) => {
                            return json!({"ok": false, "error": format!("{e}; nothing was sent")})
                        }
                    }
                }
                if pairs.is_empty() {
                    return json!({"ok": true, "message": "the drive's values kept"});
                }
                super::config::set_many(&mut self.c, &pairs)
            }
            Job::ScopeData => scope_data(&mut self.c),
            Job::SetRate(hz) => {
                let r = TelemetryRate::Hz(hz);
                match self.c.start_telemetry(r) {
                    Ok(()) => {
                        self.rate_hz = hz;
                        json!({"ok": true})
                    }
                    Err(e) => {
                        json!({"ok": false, "error": foc_ctl::refusal::explain(&mut self.c, &Request::StartTelemetry(r), &e)})
                    }
                }
            }
        }
    }

    /// A foc-ctl command line on this link: its output and whether it
    /// succeeded.
    fn console(&mut self, line: &str) -> Value {
        let words = match split_words(line) {
            Ok(w) => w,
            Err(e) => return json!({"ok": false, "output": e}),
        };
        let cli = match Cli::try_parse_from(std::iter::once("foc-ctl".to_string()).chain(words)) {
            Ok(c) => c,
            Err(e) => return json!({"ok": false, "output": e.to_string()}),
        };
        let mut cmd = cli.cmd;
        match &mut cmd {
            crate::Cmd::Simulate(_) | crate::Cmd::Dashboard(_) => {
                return json!({"ok": false, "output": "not from the console: run it in a terminal"})
            }
            crate::Cmd::KeepAlive { .. } | crate::Cmd::Telemetry { .. } => {
                return json!({"ok": false, "output": "not from the console: the page keeps the link alive and plots the telemetry"})
            }
            // The page follows a calibration in its status: the console
            // does not hold the link while it runs.
            crate::Cmd::Calibrate { no_wait, .. } | crate::Cmd::Identify { no_wait, .. } => {
                *no_wait = true
            }
            _ => {}
        }
        let c = &mut self.c;
        let (r, text) = out::capture(|| dispatch(c, cmd));
        // Samples that arrived while the command ran.
        while let Ok(Some(s)) = self.c.next_stream(Duration::ZERO) {
            self.keep(&s);
        }
        match r {
            Ok(()) => json!({"ok": true, "output": text}),
            Err(e) => json!({"ok": false, "output": format!("{text}foc-ctl: {e}\n")}),
        }
    }
}

/// The scope's state; with a finished capture, its signals on the time
/// axis of the trigger (0 at the trigger).
fn scope_data(c: &mut Client) -> Value {
    use foc_core::scope::State;
    let r = match c.read_scope() {
        Ok(r) => r,
        Err(e) => return json!({"ok": false, "error": e.to_string()}),
    };
    let st = r.status;
    if st.state != State::Done {
        return json!({"ok": true, "state": format!("{:?}", st.state), "captured": st.captured,
            "trigger": format!("{:?}", st.config.trigger)});
    }
    match c.read_scope_values() {
        Ok(cap) => {
            let channels: Vec<Value> = cap
                .signals()
                .iter()
                .map(|&s| {
                    json!({
                        "name": foc_ctl::scope::column_name(s),
                        "values": cap.channel(s).unwrap_or_default(),
                    })
                })
                .collect();
            json!({"ok": true, "state": "Done", "t": cap.time_s(), "channels": channels,
                "trigger_index": cap.report.status.trigger_index,
                "sample_period_s": cap.report.sample_period_s})
        }
        Err(e) => json!({"ok": false, "error": e.to_string()}),
    }
}

/// A mode code's name.
fn mode_name(code: u8) -> &'static str {
    match code {
        0 => "Disabled",
        1 => "Torque",
        2 => "Velocity",
        3 => "Position",
        4 => "OpenLoop",
        5 => "Impedance",
        _ => "unknown",
    }
}

/// Words of a command line: spaces separate, double or single quotes group.
pub(super) fn split_words(line: &str) -> Result<Vec<String>, String> {
    let mut words = Vec::new();
    let mut cur = String::new();
    let mut quote: Option<char> = None;
    let mut any = false;
    for ch in line.chars() {
        match (quote, ch) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => cur.push(c),
            (None, '"' | '\'') => {
                quote = Some(ch);
                any = true;
            }
            (None, c) if c.is_whitespace() => {
                if any || !cur.is_empty() {
                    words.push(std::mem::take(&mut cur));
                    any = false;
                }
            }
            (None, c) => cur.push(c),
        }
    }
    if quote.is_some() {
        return Err("an unclosed quote".into());
    }
    if any || !cur.is_empty() {
        words.push(cur);
    }
    Ok(words)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_split_on_spaces_and_group_in_quotes() {
        assert_eq!(
            split_words(" mode  torque -- -1.5 ").unwrap(),
            ["mode", "torque", "--", "-1.5"]
        );
        assert_eq!(
            split_words("config show 'a b' \"\"").unwrap(),
            ["config", "show", "a b", ""]
        );
        assert!(split_words("x 'y").is_err());
    }
}
