//! `foc-ctl tune current|speed|position` (design §22): a small step on the
//! connected drive, captured by its scope, and the figures it shows
//! (overshoot, 10-90 % rise, 5 % settling, the bandwidth the rise implies),
//! with gain suggestions from stated rules.
//!
//! The figures are [`foc_core::response`]'s, the bench's own, so a tuning
//! report and a bench test of the same motor measure the same thing.

use crate::scope::ScopeCapture;
use crate::{Client, ClientError};
use foc_core::control::{Command, Mode};
use foc_core::response::{bandwidth_hz_from_rise, overshoot_percent, rise_time, settling_index};
use foc_core::scope::{ScopeConfig, Signal, State, TriggerKind};
use foc_protocol::message::ParamId;
use std::fmt;
use std::time::{Duration, Instant};

/// The settling band: 5 % of the step. (2 % is common too; on a free
/// rotor the current's approach to its set-point has a slow tail of a few
/// per cent while the back-EMF ramps up, and the ADC's noise is about 1 %
/// of a few-ampere step: 5 % measures the loop, not those.)
pub const SETTLING_BAND: f64 = 0.05;

/// Which loop to step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Loop {
    /// q current (torque mode), from 0 A.
    Current,
    /// Velocity, from standstill.
    Speed,
    /// Position, from where the rotor is.
    Position,
}

impl Loop {
    /// The signal whose response is measured.
    pub const fn response(self) -> Signal {
        match self {
            Loop::Current => Signal::IqA,
            Loop::Speed => Signal::VelocityRadS,
            Loop::Position => Signal::PositionRad,
        }
    }

    /// The mode the step runs in.
    pub const fn mode(self) -> Mode {
        match self {
            Loop::Current => Mode::Torque,
            Loop::Speed => Mode::Velocity,
            Loop::Position => Mode::Position,
        }
    }

    /// The scope's configuration: the response, its reference and the
    /// q current, sampled fast enough for the loop, a tenth before the step.
    pub fn scope_config(self) -> ScopeConfig {
        let (signals, divider, samples): (&[Signal], u16, u16) = match self {
            Loop::Current => (
                &[Signal::IqRefA, Signal::IqA, Signal::IdA, Signal::VqV],
                1,
                200,
            ),
            Loop::Speed => (
                &[
                    Signal::Target,
                    Signal::VelocityRadS,
                    Signal::IqRefA,
                    Signal::IqA,
                ],
                5,
                800,
            ),
            Loop::Position => (
                &[
                    Signal::Target,
                    Signal::PositionRad,
                    Signal::VelocityRadS,
                    Signal::IqRefA,
                ],
                20,
                1000,
            ),
        };
        let mut c = ScopeConfig::new(signals);
        c.divider = divider;
        c.samples = samples;
        c.pre_trigger = samples / 10;
        c.trigger = TriggerKind::Command;
        c
    }

    /// The command before the step and the step itself (`step` in A,
    /// rad/s or rad; a position step from `position_rad`, output frame).
    pub fn commands(self, step: f32, position_rad: f32) -> (Command, Command) {
        match self {
            Loop::Current => (
                Command::Torque { iq_a: 0.0 },
                Command::Torque { iq_a: step },
            ),
            Loop::Speed => (
                Command::Velocity { rad_s: 0.0 },
                Command::Velocity { rad_s: step },
            ),
            Loop::Position => (
                Command::Position { rad: position_rad },
                Command::Position {
                    rad: position_rad + step,
                },
            ),
        }
    }
}

/// Figures of one step response.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepFigures {
    /// Value before the step (mean of the pre-trigger samples).
    pub initial: f64,
    /// The step's target.
    pub target: f64,
    /// Overshoot past the target [% of the step].
    pub overshoot_pct: f64,
    /// 10-90 % rise time \[s\].
    pub rise_s: Option<f64>,
    /// Time from the step into the 5 % band for good \[s\] (`None`: not
    /// within the capture).
    pub settling_s: Option<f64>,
    /// The same in PWM periods.
    pub settling_periods: Option<u32>,
    /// Bandwidth the rise time implies (first order) \[Hz\].
    pub bandwidth_hz: Option<f64>,
    /// Time between samples \[s\].
    pub sample_period_s: f64,
}

impl StepFigures {
    /// Figures of `response` in `capture`, towards `target` (the trigger
    /// sample is the step's first period).
    pub fn of(capture: &ScopeCapture, response: Signal, target: f64) -> Option<Self> {
        let y = capture.channel(response)?;
        let k0 = usize::from(capture.report.status.trigger_index).min(y.len());
        let (before, after) = y.split_at(k0);
        let initial = if before.is_empty() {
            *after.first()?
        } else {
            before.iter().sum::<f64>() / before.len() as f64
        };
        let dt = f64::from(capture.report.sample_period_s);
        let divider = u32::from(capture.report.status.config.divider);
        let settle = settling_index(after, initial, target, SETTLING_BAND);
        let rise_s = rise_time(after, initial, target, 0.1, 0.9).map(|n| n * dt);
        Some(Self {
            initial,
            target,
            overshoot_pct: overshoot_percent(after, initial, target),
            rise_s,
            settling_s: settle.map(|n| n as f64 * dt),
            settling_periods: settle.map(|n| n as u32 * divider),
            bandwidth_hz: rise_s.and_then(bandwidth_hz_from_rise),
            sample_period_s: dt,
        })
    }
}

/// A tuning run's result.
#[derive(Clone, Debug)]
pub struct TuneReport {
    /// The loop stepped.
    pub which: Loop,
    /// The capture.
    pub capture: ScopeCapture,
    /// Its figures.
    pub figures: StepFigures,
    /// The gains in force, by name.
    pub gains: Vec<(&'static str, f32)>,
    /// Suggestions (each with its rule).
    pub suggestions: Vec<String>,
}

/// Run a step of `step` (A, rad/s or rad) on `loop`, capture it, and
/// work out the figures. The drive must be calibrated and not faulted; it
/// is left disabled. `timeout` is a host-time backstop for each wait.
pub fn run(
    client: &mut Client,
    which: Loop,
    step: f32,
    timeout: Duration,
) -> Result<TuneReport, ClientError> {
    let result = step_and_capture(client, which, step, timeout);
    // Whatever happened: bridge off.
    let off = client.set_command(Command::Disable);
    let capture = result?;
    off?;
    let target = match which {
        Loop::Current => f64::from(step),
        _ => capture
            .channel(Signal::Target)
            .and_then(|t| t.last().copied())
            .unwrap_or(f64::from(step)),
    };
    let figures = StepFigures::of(&capture, which.response(), target).ok_or_else(|| {
        ClientError::Io(std::io::Error::other("the capture has no response signal"))
    })?;
    let gains = read_gains(client, which)?;
    let suggestions = suggest(client, which, &figures, &gains)?;
    Ok(TuneReport {
        which,
        capture,
        figures,
        gains,
        suggestions,
    })
}

fn step_and_capture(
    client: &mut Client,
    which: Loop,
    step: f32,
    timeout: Duration,
) -> Result<ScopeCapture, ClientError> {
    let position = client.read_telemetry()?.position_rad;
    let (before, after) = which.commands(step, position);
    client.set_command(before)?;
    wait_for_mode(client, which.mode(), timeout)?;
    if which != Loop::Current {
        // Let the loop come to rest on the first command.
        std::thread::sleep(Duration::from_millis(100));
    }
    let config = which.scope_config();
    client.set_scope(&config)?;
    client.arm_scope()?;
    wait_for_pre_trigger(client, config.pre_trigger, timeout)?;
    client.set_command(after)?;
    let deadline = Instant::now() + timeout;
    loop {
        client.keep_alive()?;
        let st = client.read_scope()?.status;
        match st.state {
            State::Done => break,
            State::Idle => return Err(ClientError::Nack(foc_protocol::ErrorCode::ScopeState)),
            State::Armed | State::Triggered => {}
        }
        if Instant::now() >= deadline {
            return Err(ClientError::Io(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                format!("scope not done ({:?}, {} samples)", st.state, st.captured),
            )));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    // The step is over: bridge off before the (slow) read-out.
    client.set_command(Command::Disable)?;
    client.read_scope_values()
}

/// Poll the scope until it holds `n` samples before any trigger (the
/// drive's own time; host-time backstop).
fn wait_for_pre_trigger(client: &mut Client, n: u16, timeout: Duration) -> Result<(), ClientError> {
    let deadline = Instant::now() + timeout;
    loop {
        let st = client.read_scope()?.status;
        if st.captured >= n || st.state != State::Armed {
            return Ok(());
        }
        if Instant::now() >= deadline {
            return Err(ClientError::Io(std::io::Error::other(format!(
                "the scope recorded {} of {n} samples before the step",
                st.captured
            ))));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Poll the telemetry until the drive is in `mode` (host-time backstop).
fn wait_for_mode(client: &mut Client, mode: Mode, timeout: Duration) -> Result<(), ClientError> {
    let deadline = Instant::now() + timeout;
    loop {
        let t = client.read_telemetry()?;
        if t.mode == mode {
            return Ok(());
        }
        if t.fault_code != 0 || Instant::now() >= deadline {
            return Err(ClientError::Io(std::io::Error::other(format!(
                "the drive did not enter {mode:?} (mode {:?}, fault code {})",
                t.mode, t.fault_code
            ))));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn read_gains(client: &mut Client, which: Loop) -> Result<Vec<(&'static str, f32)>, ClientError> {
    let ids: &[(&str, ParamId)] = match which {
        Loop::Current => &[
            ("kp [V/A]", ParamId::CurrentKp),
            ("ki [V/(A s)]", ParamId::CurrentKi),
        ],
        Loop::Speed => &[
            ("kp [A/(rad/s)]", ParamId::SpeedKp),
            ("ki [A/rad]", ParamId::SpeedKi),
        ],
        Loop::Position => &[("kp [(rad/s)/rad]", ParamId::PositionKp)],
    };
    ids.iter()
        .map(|(n, id)| client.param(*id).map(|v| (*n, v)))
        .collect()
}

/// Suggestions, each naming its rule.
fn suggest(
    client: &mut Client,
    which: Loop,
    f: &StepFigures,
    gains: &[(&'static str, f32)],
) -> Result<Vec<String>, ClientError> {
    let mut out = vec![];
    let g = |i: usize| gains.get(i).map_or(f32::NAN, |x| x.1);
    match which {
        Loop::Current => {
            let pwm = client.param(ParamId::PwmFrequencyHz)?;
            let r = client.param(ParamId::ResistanceOhm)?;
            let l = client.param(ParamId::LqH)?;
            let designed = g(0) / (2.0 * std::f32::consts::PI * l);
            out.push(format!(
                "designed bandwidth kp / (2 pi L) = {designed:.0} Hz (L = {:.1} uH); measured {}",
                l * 1e6,
                f.bandwidth_hz.map_or("-".into(), |b| format!("{b:.0} Hz"))
            ));
            let target = pwm / 20.0;
            let w = 2.0 * std::f32::consts::PI * target;
            out.push(format!(
                "for {target:.0} Hz (a twentieth of the PWM frequency; rule: kp = 2 pi f L, ki = 2 pi f R, the PI's zero on the winding's pole): `foc-ctl gains current --kp {:.4} --ki {:.1}`",
                w * l,
                w * r
            ));
            if f.overshoot_pct > 10.0 {
                out.push(format!(
                    "overshoot {:.1} % > 10 %: the inductance or the delay is larger than assumed; lower kp (e.g. {:.4})",
                    f.overshoot_pct,
                    0.7 * g(0)
                ));
            }
        }
        Loop::Speed => {
            if f.overshoot_pct > 15.0 {
                out.push(format!(
                    "overshoot {:.1} % > 15 %: halve ki (rule: ki / kp at most a quarter of the bandwidth in rad/s): `foc-ctl gains speed --kp {:.4} --ki {:.3}`",
                    f.overshoot_pct,
                    g(0),
                    0.5 * g(1)
                ));
            } else if f.overshoot_pct < 2.0 {
                out.push(format!(
                    "overshoot {:.1} %: room for a faster loop, kp x 1.5 (rule: raise kp while the overshoot stays under 15 %): `foc-ctl gains speed --kp {:.4} --ki {:.3}`",
                    f.overshoot_pct,
                    1.5 * g(0),
                    1.5 * g(1)
                ));
            } else {
                out.push("overshoot within 2..15 %: keep the gains".into());
            }
        }
        Loop::Position => {
            if f.overshoot_pct > 5.0 {
                out.push(format!(
                    "overshoot {:.1} % > 5 %: lower kp to {:.2} (rule: a position loop should not overshoot)",
                    f.overshoot_pct,
                    0.7 * g(0)
                ));
            } else {
                out.push(format!(
                    "no significant overshoot ({:.1} %): the move is paced by the trajectory limits; kp may rise while it stays under 5 %",
                    f.overshoot_pct
                ));
            }
        }
    }
    Ok(out)
}

impl fmt::Display for TuneReport {
    fn fmt(&self, out: &mut fmt::Formatter<'_>) -> fmt::Result {
        let f = &self.figures;
        let ms = |x: Option<f64>| x.map_or("not reached".into(), |v| format!("{:.3} ms", v * 1e3));
        writeln!(
            out,
            "{:?} step {:.4} -> {:.4}",
            self.which, f.initial, f.target
        )?;
        writeln!(out, "  overshoot      {:.2} %", f.overshoot_pct)?;
        writeln!(out, "  rise 10-90 %   {}", ms(f.rise_s))?;
        writeln!(
            out,
            "  settling 5 %   {}{}",
            ms(f.settling_s),
            f.settling_periods
                .map_or(String::new(), |p| format!(" ({p} PWM periods)"))
        )?;
        writeln!(
            out,
            "  bandwidth      {}",
            f.bandwidth_hz
                .map_or("-".into(), |b| format!("{b:.1} Hz (0.35 / rise)"))
        )?;
        for (n, v) in &self.gains {
            writeln!(out, "  gain {n} = {v}")?;
        }
        for s in &self.suggestions {
            writeln!(out, "  suggestion: {s}")?;
        }
        Ok(())
    }
}
