//! Software in the loop: the `foc-core` cascade driven by JSON lines.
//!
//! One input line is one PWM period's sample (plus an optional command), one
//! output line is what the controller decided from it. The `foc-sil` binary
//! reads stdin and writes stdout; this module does the work so tests can
//! drive it in-process too.
//!
//! Input (one JSON object per line):
//!
//! ```text
//! {"t": 0.001, "i_abc": [1.0, -0.5, -0.5], "v_bus": 24.0, "theta_m": 0.3,
//!  "cmd": {"mode": "torque", "target": 2.0}, "clear_faults": false}
//! ```
//!
//! - `t` \[s\]: sample time (echoed back; not used by the controller, which
//!   counts periods).
//! - `i_abc` \[A\]: phase currents into the motor, two (A, B: C derived) or
//!   three values.
//! - `v_bus` \[V\]: measured bus voltage.
//! - `theta_m` \[rad\]: mechanical angle as the encoder reports it (any value,
//!   wrapped to one turn; the calibration `--zero-offset-deg`/`--reversed`
//!   maps it to the rotor's d axis). A controller running sensorless
//!   (`foc-sil --sensor sensorless`, design §27) ignores it and takes lines
//!   without it; it then takes only `disable`, `velocity` and `open_loop`
//!   commands (the others are refused with `NeedsAngleSensor`).
//! - `cmd` (optional): `mode` one of `disable`, `torque` (`target` = iq \[A\]),
//!   `velocity` (`target` = mechanical rad/s), `position` (`target` =
//!   mechanical rad, multi-turn), `open_loop` (`v_d`, `v_q` \[V\], `theta_e`
//!   \[rad\], `omega_e` [rad/s], each default 0), `impedance` (`target` =
//!   position [rad, rotor, mechanical], `velocity` [rad/s], `kp` [N m/rad],
//!   `kd` [N m s/rad], `torque_ff` [N m], each default 0, `torque_limit`
//!   [N m], default none; design §21).
//! - `clear_faults` (optional): clear latched faults in this period; a
//!   command on the same line is taken right after the clear and acts in
//!   this same period (if the fault condition persists it trips again).
//!
//! Output (one JSON object per input line):
//!
//! ```text
//! {"t":0.001,"duties":[0.52,0.49,0.49],"bridge":true,"mode":"torque","fault":null,
//!  "id":0.0,"iq":0.9,"theta_e":2.1,"speed":0.0,"position":0.3,"error":null}
//! ```
//!
//! - `duties`: high-side on-time fractions of phases A, B, C in `[0, 1]`
//!   (centred `0.5` and `bridge: false` in the safe state).
//! - `mode`: `disabled`, `torque`, `velocity`, `position`, `open_loop`,
//!   `impedance`.
//! - `fault`: `null` or the first latched fault (`OverCurrentPhase`, ...).
//! - `id`, `iq` \[A\], `theta_e` [rad, `[0, 2 pi)`], `speed` [rad/s,
//!   mechanical, estimated], `position` [rad, multi-turn].
//! - `error`: `null`, or why the line or its command was refused.
//!
//! A line that is not valid JSON or lacks a measurement is a period without
//! a valid sample: the controller latches `CurrentSenseError` (bridge off,
//! duties centred) until `clear_faults`. An invalid command alone is refused
//! (the period still runs with the previous command).
//!
//! A line is at most [`MAX_LINE`] bytes (64 KiB, without its newline): a
//! longer one is read and discarded up to its newline without being held
//! in memory ([`read_line_bounded`]) and answered like an invalid line (one
//! output line with its `error`, bridge off, `CurrentSenseError` latched;
//! [`SilRunner::refuse`]).
//!
//! Frame: phase A's axis at electrical angle 0, positive rotation
//! A -> B -> C, `theta_e = p theta_m - zero_offset`.
//!
//! Calibration: closed-loop commands (`torque`, `velocity`, `position`) need
//! a calibration permit ([`SilRunner::with_calibration`]); without one they
//! are refused with `NotCalibrated` and only `disable` and `open_loop` run.
//!
//! ```
//! use foc_bench::sil::SilRunner;
//! use foc_core::calibration::Calibrated;
//! use foc_bench::mission::Setup;
//! use foc_bench::plant::{BenchConfig, MotorParams};
//! let setup = Setup { name: "x".into(), motor: MotorParams::example(), bench: BenchConfig::default(),
//!                     rated_current_a: 5.0, max_current_a: 10.0 };
//! let config = setup.cascade_config();
//! // The calibration is supplied (here: the encoder reads the d axis).
//! let permit = Calibrated::supplied(config.current.angle, config.current.current).unwrap();
//! let mut sil = SilRunner::with_calibration(config, &permit);
//! let (out, err) = sil.line(r#"{"t":0,"i_abc":[0,0,0],"v_bus":24,"theta_m":0,"cmd":{"mode":"torque","target":1}}"#);
//! assert!(err.is_none());
//! assert!(out.contains(r#""mode":"torque""#));
//! let (out, err) = sil.line("garbage");
//! assert!(err.is_some() && out.contains(r#""duties":[0.5,0.5,0.5]"#));
//! ```

use foc_core::angle::{ElectricalAngle, MechanicalAngle};
use foc_core::calibration::Calibrated;
use foc_core::control::joint::Impedance;
use foc_core::control::stage::Sample;
use foc_core::control::{BridgeCommand, Command, Mode};
use foc_core::drive::cascade::{Cascade, CascadeConfig};
use foc_core::frames::Abc;
use foc_core::hal::PhaseCurrents;
use serde::Deserialize;
use serde_json::json;
use std::io::{self, BufRead};

/// Longest input line \[bytes\], without its newline: 64 KiB.
pub const MAX_LINE: usize = 64 * 1024;

/// What [`read_line_bounded`] read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BoundedLine {
    /// A line (in the buffer, without its `\n` or `\r\n`).
    Line,
    /// A line longer than the bound: discarded up to its newline (the
    /// buffer is left empty); its length in bytes, without the newline.
    TooLong(u64),
    /// End of input, nothing read.
    Eof,
}

/// Read one line into `buf` (cleared first), holding at most `max` bytes:
/// the bytes of a longer line are consumed and dropped up to and including
/// its newline, so the next call starts at the next line. A last line
/// without a newline counts as a line. `Interrupted` reads are retried;
/// other I/O errors are returned (what was read of the line is lost).
pub fn read_line_bounded<R: BufRead + ?Sized>(
    r: &mut R,
    buf: &mut Vec<u8>,
    max: usize,
) -> io::Result<BoundedLine> {
    buf.clear();
    let mut len: u64 = 0;
    let mut too_long = false;
    let mut any = false;
    loop {
        let chunk = match r.fill_buf() {
            Ok(c) => c,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        if chunk.is_empty() {
            if !any {
                return Ok(BoundedLine::Eof);
            }
            break;
        }
        any = true;
        let (part, used, end) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (&chunk[..i], i + 1, true),
            None => (chunk, chunk.len(), false),
        };
        len = len.saturating_add(part.len() as u64);
        if !too_long {
            if buf.len() + part.len() <= max {
                // Exact growth: the buffer never holds more than `max`.
                buf.reserve_exact(part.len());
                buf.extend_from_slice(part);
            } else {
                too_long = true;
                buf.clear();
            }
        }
        r.consume(used);
        if end {
            break;
        }
    }
    if too_long {
        return Ok(BoundedLine::TooLong(len));
    }
    if buf.last() == Some(&b'\r') {
        buf.pop();
    }
    Ok(BoundedLine::Line)
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct InLine {
    #[serde(default)]
    t: Option<f64>,
    i_abc: Vec<f32>,
    v_bus: f32,
    #[serde(default)]
    theta_m: Option<f32>,
    #[serde(default)]
    cmd: Option<InCmd>,
    #[serde(default)]
    clear_faults: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct InCmd {
    mode: String,
    #[serde(default)]
    target: Option<f32>,
    #[serde(default)]
    v_d: Option<f32>,
    #[serde(default)]
    v_q: Option<f32>,
    #[serde(default)]
    theta_e: Option<f32>,
    #[serde(default)]
    omega_e: Option<f32>,
    #[serde(default)]
    velocity: Option<f32>,
    #[serde(default)]
    kp: Option<f32>,
    #[serde(default)]
    kd: Option<f32>,
    #[serde(default)]
    torque_ff: Option<f32>,
    #[serde(default)]
    torque_limit: Option<f32>,
}

/// Name of a mode in the protocol.
pub fn mode_name(m: Mode) -> &'static str {
    match m {
        Mode::Disabled => "disabled",
        Mode::Torque => "torque",
        Mode::Velocity => "velocity",
        Mode::Position => "position",
        Mode::OpenLoop => "open_loop",
        Mode::Impedance => "impedance",
    }
}

fn command_of(c: &InCmd) -> Result<Command, String> {
    let target = || {
        c.target
            .ok_or_else(|| format!("mode `{}` needs a `target`", c.mode))
    };
    Ok(match c.mode.as_str() {
        "disable" | "disabled" => Command::Disable,
        "torque" => Command::Torque { iq_a: target()? },
        "velocity" => Command::Velocity { rad_s: target()? },
        "position" => Command::Position { rad: target()? },
        "open_loop" => Command::OpenLoop {
            v_d_v: c.v_d.unwrap_or(0.0),
            v_q_v: c.v_q.unwrap_or(0.0),
            theta_e: ElectricalAngle::from_radians(c.theta_e.unwrap_or(0.0)),
            omega_e_rad_s: c.omega_e.unwrap_or(0.0),
        },
        "impedance" => Command::Impedance(Impedance {
            position_rad: target()?,
            velocity_rad_s: c.velocity.unwrap_or(0.0),
            kp_nm_per_rad: c.kp.unwrap_or(0.0),
            kd_nm_s_per_rad: c.kd.unwrap_or(0.0),
            torque_ff_nm: c.torque_ff.unwrap_or(0.0),
            torque_limit_nm: c.torque_limit.unwrap_or(f32::INFINITY),
        }),
        other => {
            return Err(format!(
                "unknown mode `{other}` (disable, torque, velocity, position, open_loop, impedance)"
            ))
        }
    })
}

/// The cascade behind the JSON-lines protocol (see the module docs).
#[derive(Clone, Debug)]
pub struct SilRunner {
    cascade: Cascade,
    lines: u64,
}

impl SilRunner {
    /// A runner with this controller configuration (disabled, no fault),
    /// uncalibrated: open loop only, closed-loop commands are refused
    /// (`NotCalibrated`).
    pub fn new(config: CascadeConfig) -> Self {
        Self {
            cascade: Cascade::new(config),
            lines: 0,
        }
    }

    /// A runner with a calibration permit installed (closed loop allowed).
    pub fn with_calibration(config: CascadeConfig, calibration: &Calibrated) -> Self {
        let mut r = Self::new(config);
        r.cascade.set_calibration(calibration);
        r
    }

    /// The controller.
    pub fn cascade(&self) -> &Cascade {
        &self.cascade
    }

    /// Handle one input line: returns the output line (no newline) and,
    /// when the line or its command was refused, the reason (for stderr).
    pub fn line(&mut self, text: &str) -> (String, Option<String>) {
        let parsed: Result<InLine, String> =
            serde_json::from_str::<InLine>(text).map_err(|e| format!("bad input line: {e}"));
        let parsed = parsed.and_then(|l| match l.i_abc.len() {
            2 | 3 => Ok(l),
            n => Err(format!("bad input line: `i_abc` has {n} values (2 or 3)")),
        });
        match parsed {
            Err(e) => self.refuse(&e),
            Ok(l) => self.period(l),
        }
    }

    /// A line that could not be used (unreadable, too long...): a period
    /// without a valid sample, answered like an invalid line (bridge off,
    /// `CurrentSenseError` latched) with `reason` as its `error`.
    pub fn refuse(&mut self, reason: &str) -> (String, Option<String>) {
        let sample = Sample {
            currents: None,
            angle: None,
            v_bus_v: None,
            temperature_c: None,
        };
        self.run(&sample, None, Some(reason.to_string()))
    }

    /// One period on a parsed line.
    fn period(&mut self, l: InLine) -> (String, Option<String>) {
        if l.clear_faults {
            self.cascade.clear_faults();
        }
        let mut error = None;
        if let Some(c) = &l.cmd {
            match command_of(c) {
                // After `clear_faults` above the cascade accepts the
                // command: its step clears first, then takes it.
                Ok(cmd) => {
                    if let Err(e) = self.cascade.command(cmd) {
                        error = Some(format!("command refused: {e:?}"));
                    }
                }
                Err(e) => error = Some(format!("command refused: {e}")),
            }
        }
        let currents = match l.i_abc[..] {
            [a, b] => PhaseCurrents::TwoPhase { a_a: a, b_a: b },
            [a, b, c] => PhaseCurrents::ThreePhase(Abc::new(a, b, c)),
            _ => PhaseCurrents::TwoPhase { a_a: 0.0, b_a: 0.0 }, // excluded above
        };
        let sensorless = self.cascade.current.sensorless().is_some();
        let angle = match l.theta_m {
            // A non-finite angle is a failed read (angle-sensor error).
            Some(theta_m) => MechanicalAngle::try_from_radians(theta_m),
            // Not read: the observer gives the angle.
            None if sensorless => None,
            None => return self.refuse("bad input line: missing field `theta_m`"),
        };
        let sample = Sample {
            currents: Some(currents),
            angle,
            v_bus_v: Some(l.v_bus),
            temperature_c: None,
        };
        self.run(&sample, l.t, error)
    }

    /// Step the cascade on `sample` and format the output line.
    fn run(
        &mut self,
        sample: &Sample,
        t: Option<f64>,
        error: Option<String>,
    ) -> (String, Option<String>) {
        self.lines += 1;
        let bridge = self.cascade.step(sample);
        let fb = *self.cascade.feedback();
        let (duties, on) = match bridge {
            BridgeCommand::SafeState => ([0.5f32; 3], false),
            BridgeCommand::ShortCircuit => ([0.0f32; 3], true),
            BridgeCommand::Duties(d) => (d, true),
        };
        let fault = fb.first_fault.map(|f| format!("{f:?}"));
        let out = json!({
            "t": t,
            "duties": duties,
            "bridge": on,
            "mode": mode_name(fb.mode),
            "fault": fault,
            "id": fb.i_dq_a.d,
            "iq": fb.i_dq_a.q,
            "theta_e": fb.theta_e.to_radians(),
            "speed": fb.velocity_rad_s,
            "position": fb.position_rad,
            "error": error.clone(),
        });
        let error = error.map(|e| format!("line {}: {e}", self.lines));
        (out.to_string(), error)
    }
}
