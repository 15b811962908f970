//! `foc-ctl`: command-line host tool for the drive's command channel.
//!
//! Frames (design §21): positions, velocities, torques and stiffnesses of
//! commands (`mode position|velocity|impedance`, `home`) and telemetry are
//! the joint's **output** frame (after the gearbox; the same numbers as the
//! rotor's until `joint` sets a gear or homing an offset); the motor's
//! limits (`limits`) and the joint's rotor-side settings are the **rotor**'s.

#[macro_use]
mod out;
mod cli;
mod config_cmd;
mod dashboard;
mod show;
mod telemetry_cmd;

use cli::*;
use config_cmd::*;
use show::{num, param_text};
use telemetry_cmd::*;

use clap::{Parser, Subcommand, ValueEnum};
use foc_core::angle::ElectricalAngle;
use foc_core::control::homing::{EndStop, HomingMethod};
use foc_core::control::joint::Impedance;
use foc_core::control::power::ActiveLimit;
use foc_core::control::stage::TimeoutReaction;
use foc_core::control::{Command, Fault, Limits};
use foc_ctl::calibration::{self, CalProgress, WaitEnd};
use foc_ctl::joint::{error_text, homing_text, joint_text, JointEdit};
use foc_ctl::refusal;
use foc_ctl::{describe_error, sim::SimServer, Client, ClientError, StreamSample};
use foc_protocol::config::{ConfigSource, StoreOp};
use foc_protocol::message::{
    Calibration, CurrentGains, ErrorCode, HomingStart, HomingState, ParamId, PositionGains,
    Request, SpeedGains, TelemetryRate, WatchdogConfig,
};
use foc_store::text::{from_toml, to_toml};
use foc_store::{DriveRecord, MAX_RECORD_BYTES};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

mod scope_cmd;

fn connect(cli: &Cli) -> Result<Client, Box<dyn std::error::Error>> {
    let mut c = match (&cli.tcp, &cli.serial) {
        (Some(addr), _) => Client::connect_tcp(addr.as_str())
            .map_err(|e| format!("cannot connect to {addr}: {e}"))?,
        #[cfg(feature = "serial")]
        (None, Some(path)) => Client::open_serial(path, cli.baud)
            .map_err(|e| format!("cannot open serial port {path} at {} baud: {e}", cli.baud))?,
        #[cfg(not(feature = "serial"))]
        (None, Some(_)) => return Err("built without the `serial` feature".into()),
        (None, None) => return Err("give --tcp HOST:PORT or --serial PATH".into()),
    };
    c.set_timeout(Duration::from_millis(cli.timeout_ms));
    c.set_retries(cli.retries);
    c.set_store_timeout(Duration::from_millis(cli.store_timeout_ms));
    Ok(c)
}

fn fault_list(bits: u32) -> String {
    let names: Vec<String> = Fault::ALL
        .iter()
        .filter(|f| bits & (1 << f.code()) != 0)
        .map(|f| format!("{} ({})", f.name(), f.code()))
        .collect();
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}

type CliResult = Result<(), Box<dyn std::error::Error>>;

fn run(cli: Cli) -> CliResult {
    match &cli.cmd {
        Cmd::Simulate(a) => return simulate(a),
        Cmd::Dashboard(a) => return dashboard::serve(&cli, a),
        _ => {}
    }
    let mut c = connect(&cli)?;
    dispatch(&mut c, cli.cmd)
}

/// Run one command on the link `c` (the dashboard's console does too).
fn dispatch(c: &mut Client, cmd: Cmd) -> CliResult {
    match cmd {
        Cmd::Ping => ping(c),
        Cmd::Scope { op } => scope_cmd::scope(c, op),
        Cmd::Tune(args) => scope_cmd::tune(c, args),
        Cmd::Mode { mode } => set_mode(c, mode),
        Cmd::KeepAlive {
            interval_ms,
            duration_ms,
        } => keep_alive(c, interval_ms, duration_ms * 1e-3),
        Cmd::Faults => show_faults(c),
        Cmd::Param { name, value: None } => show_params(c, &name),
        Cmd::Param {
            name,
            value: Some(v),
        } => write_param(c, &name, &v),
        Cmd::Telemetry {
            rate,
            every,
            duration_ms,
            csv,
            plot,
            svg,
        } => {
            let r = match every {
                Some(k) => TelemetryRate::EveryPeriods(k),
                None => TelemetryRate::Hz(rate as f32),
            };
            stream_telemetry(c, r, duration_ms * 1e-3, csv, plot, svg)
        }
        Cmd::Calibrate {
            routine,
            no_wait,
            wait_ms,
        } => calibrate(c, routine, no_wait, wait_ms),
        Cmd::Identify { no_wait, wait_ms } => {
            calibrate(c, Routine::Identification, no_wait, wait_ms)
        }
        Cmd::Config { op } => config(c, op),
        Cmd::Joint(args) => joint(c, &args),
        Cmd::Home { method } => home(c, method),
        Cmd::Status => status(c),
        Cmd::Limits(a) => limits(c, &a),
        Cmd::Watchdog { after_ms, reaction } => watchdog(c, after_ms, reaction),
        setting => configure(c, setting),
    }
}

/// `simulate`: serve the simulated drive until killed.
fn simulate(a: &SimulateArgs) -> CliResult {
    let setup = match &a.motor {
        Some(p) => foc_bench::mission::Setup::load(p)
            .map_err(|e| format!("motor file {}: {e}", p.display()))?,
        None => foc_bench::scope_step::emulated_setup(),
    };
    if !(a.time_scale > 0.0 && a.time_scale <= 100.0) {
        return Err(format!("--time-scale {} is outside (0, 100]", a.time_scale).into());
    }
    let mut opts = foc_ctl::sim::Options::simulator(setup);
    if let Some(&[lo, hi]) = a.end_stops.as_deref() {
        if lo.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
            return Err(
                format!("--end-stops {lo} {hi}: the low stop must be below the high one").into(),
            );
        }
        opts.end_stops_rad = (lo, hi);
    }
    let name = opts.setup.name.clone();
    let mut dev = foc_ctl::sim::SimDevice::new(opts);
    if a.calibrated && !dev.drive.calibrate_from_bench() {
        return Err("the simulated drive refused its calibration".into());
    }
    let listener = std::net::TcpListener::bind(&a.listen)
        .map_err(|e| format!("cannot listen on {}: {e}", a.listen))?;
    let server = SimServer::spawn_scaled(listener, dev, a.time_scale)?;
    say_err!(
        "simulated drive ({name}) on {} (Ctrl-C to stop)",
        server.addr()
    );
    server.wait();
    Ok(())
}

/// `ping`: versions; fails on a protocol mismatch.
fn ping(c: &mut Client) -> CliResult {
    let h = c.ping()?;
    let [a, b, p] = h.firmware_version;
    say!(
        "protocol {} (host {}), firmware {a}.{b}.{p}, max payload {} bytes",
        h.protocol_version,
        foc_protocol::PROTOCOL_VERSION,
        h.max_payload
    );
    if h.protocol_version != foc_protocol::PROTOCOL_VERSION {
        return Err("protocol version mismatch".into());
    }
    Ok(())
}

/// `mode ...`: send the command.
fn set_mode(c: &mut Client, mode: ModeCmd) -> CliResult {
    let cmd = match mode {
        ModeCmd::Disable => Command::Disable,
        ModeCmd::Torque { iq_a } => Command::Torque { iq_a },
        ModeCmd::Velocity { rad_s } => Command::Velocity { rad_s },
        ModeCmd::Position { rad } => Command::Position { rad },
        ModeCmd::OpenLoop {
            v_d,
            v_q,
            theta_deg,
            omega_e,
        } => Command::OpenLoop {
            v_d_v: v_d,
            v_q_v: v_q,
            theta_e: ElectricalAngle::from_degrees(theta_deg),
            omega_e_rad_s: omega_e,
        },
        ModeCmd::Impedance {
            position,
            velocity,
            kp,
            kd,
            torque_ff,
            torque_limit,
        } => Command::Impedance(Impedance {
            position_rad: position,
            velocity_rad_s: velocity,
            kp_nm_per_rad: kp,
            kd_nm_s_per_rad: kd,
            torque_ff_nm: torque_ff,
            torque_limit_nm: torque_limit,
        }),
    };
    c.set_command(cmd)
        .map_err(|e| refusal::explain(c, &Request::SetCommand(cmd), &e))?;
    say!("ok: {cmd:?} (positions, velocities, torques: output frame)");
    Ok(())
}

/// `joint [...]`: change what is given (read, edit, send), then show the
/// joint in force.
fn joint(c: &mut Client, a: &JointArgs) -> CliResult {
    let edit = JointEdit {
        gear_ratio: a.gear_ratio,
        rotor_at_zero_rad: a.offset,
        travel_out_rad: match (&a.travel, a.no_travel) {
            (Some(v), _) => Some(v.first().copied().zip(v.get(1).copied())),
            (None, true) => Some(None),
            (None, false) => None,
        },
        fault_margin_rad: a.fault_margin,
        brake_accel_rad_s2: a.brake_accel,
        kv_a_per_rad_s: a.kv,
        entry_blend_periods: a.entry_blend,
        timeout_kd_nm_s_per_rad: a.timeout_kd,
    };
    if !edit.is_empty() {
        let j = edit.apply(c.joint()?);
        c.set_joint(j)
            .map_err(|e| refusal::explain(c, &Request::SetJoint(j), &e))?;
    }
    say!("{}", joint_text(&c.joint()?));
    Ok(())
}

/// `home present|end-stop`: start homing, show its progress (output
/// frame) until it ends, then the frame it set.
fn home(c: &mut Client, method: HomeCmd) -> CliResult {
    let (h, timeout) = method.request();
    let state = c
        .home(h, Duration::from_secs_f64(timeout.max(0.0)), |t| {
            say!(
                "homing: p={:.4} rad w={:.3} rad/s (output) iq={:.3} A",
                t.position_rad,
                t.velocity_rad_s,
                t.i_q_a
            )
        })
        .map_err(|e| error_text(&Request::StartHoming(h), &e))?;
    match state {
        HomingState::Done => {
            say!("homed: {}", homing_text(state));
            say!("{}", joint_text(&c.joint()?));
            Ok(())
        }
        HomingState::Running => Err("homing: no result within the timeout (still running)".into()),
        other => Err(format!("homing {}", homing_text(other)).into()),
    }
}

/// `status`: one sample (frames stated), the joint and homing.
fn status(c: &mut Client) -> CliResult {
    let t = c.read_telemetry()?;
    say!("mode           {:?}", t.mode);
    say!("position       {} rad (output)", num(t.position_rad));
    say!("velocity       {} rad/s (output)", num(t.velocity_rad_s));
    say!(
        "currents       id {} A, iq {} A",
        num(t.i_d_a),
        num(t.i_q_a)
    );
    say!("bus            {} V", num(t.v_bus_v));
    let fault = match (t.fault_code, Fault::from_code(t.fault_code)) {
        (0, _) => "none".to_string(),
        (_, Some(f)) => format!("{} ({})", f.name(), f.code()),
        (code, None) => format!("code {code}"),
    };
    say!("first fault    {fault}");
    say!("homing         {}", homing_text(c.homing_state()?));
    say!("{}", joint_text(&c.joint()?));
    Ok(())
}

/// `limits [...]`: change the limits given, keep the others; show them.
fn limits(c: &mut Client, a: &LimitsArgs) -> CliResult {
    if let Some(l) = a.apply(c.limits()?) {
        c.set_limits(l)
            .map_err(|e| refusal::explain(c, &Request::SetLimits(l), &e))?;
    }
    let l = c.limits()?;
    say!("max current      {} A", num(l.max_current_a));
    say!(
        "max velocity     {} rad/s (rotor)",
        num(l.max_velocity_rad_s)
    );
    say!(
        "position range   {} .. {} rad (rotor)",
        num(l.min_position_rad),
        num(l.max_position_rad)
    );
    say!(
        "open-loop        {} V, {} rad/s (electrical)",
        num(l.max_open_loop_voltage_v),
        num(l.max_open_loop_omega_e_rad_s)
    );
    say!(
        "impedance        kp <= {} N m/rad, kd <= {} N m s/rad (rotor)",
        num(l.max_kp_nm_per_rad),
        num(l.max_kd_nm_s_per_rad)
    );
    Ok(())
}

/// `watchdog TIMEOUT_MS [REACTION]`: the link watchdog, converted to whole
/// PWM periods at the drive's rate.
fn watchdog(c: &mut Client, timeout_ms: f64, reaction: Reaction) -> CliResult {
    let pwm_hz = f64::from(c.param(ParamId::PwmFrequencyHz)?);
    if !(timeout_ms.is_finite() && timeout_ms >= 0.0) {
        return Err(format!("timeout {timeout_ms} ms: give 0 (off) or a positive time").into());
    }
    let periods = (timeout_ms * 1e-3 * pwm_hz).round();
    if periods > f64::from(u32::MAX) || (timeout_ms > 0.0 && periods < 1.0) {
        return Err(format!(
            "timeout {timeout_ms} ms is outside 0 (off) or {:.3} .. {:.0} ms at {pwm_hz} Hz",
            1e3 / pwm_hz,
            f64::from(u32::MAX) / pwm_hz * 1e3
        )
        .into());
    }
    let w = WatchdogConfig {
        timeout_periods: periods as u32,
        reaction: match reaction {
            Reaction::Disable => TimeoutReaction::Disable,
            Reaction::Stop => TimeoutReaction::Stop,
            Reaction::Hold => TimeoutReaction::Hold,
        },
    };
    c.set_watchdog(w)
        .map_err(|e| refusal::explain(c, &Request::SetWatchdog(w), &e))?;
    if w.timeout_periods == 0 {
        say!("ok: link watchdog off");
    } else {
        say!(
            "ok: {} ms ({} periods at {pwm_hz} Hz), then {:?}",
            num((periods / pwm_hz * 1e3) as f32),
            w.timeout_periods,
            w.reaction
        );
    }
    Ok(())
}

/// `keep-alive`: one keep-alive every `interval_ms` for `duration` seconds.
fn keep_alive(c: &mut Client, interval_ms: u64, duration: f64) -> CliResult {
    let end = std::time::Instant::now()
        + Duration::try_from_secs_f64(duration.max(0.0))
            .map_err(|_| "--duration-ms: not a time")?;
    while std::time::Instant::now() < end {
        c.keep_alive()?;
        std::thread::sleep(Duration::from_millis(interval_ms));
    }
    Ok(())
}

/// `faults`: the latched set and the first one.
fn show_faults(c: &mut Client) -> CliResult {
    let f = c.faults()?;
    say!("latched: {}", fault_list(f.set.0));
    match f.first() {
        Some(first) => say!("first:   {} ({})", first.name(), first.code()),
        None if f.first_code != 0 => say!("first:   code {}", f.first_code),
        None => {}
    }
    Ok(())
}

/// `param NAME|all`: one line per parameter.
fn show_params(c: &mut Client, name: &str) -> CliResult {
    let ids: Vec<ParamId> = if name == "all" {
        ParamId::ALL.to_vec()
    } else {
        vec![ParamId::from_name(name).ok_or_else(|| {
            let names: Vec<&str> = ParamId::ALL.iter().map(|p| p.name()).collect();
            format!(
                "unknown parameter `{name}`; one of: {}, all",
                names.join(", ")
            )
        })?]
    };
    for id in ids {
        match c.param(id) {
            Ok(v) => say!("{:<18} {}", id.name(), param_text(id, v)),
            Err(ClientError::Nack(foc_protocol::ErrorCode::Unsupported)) => {
                say!("{:<18} (not supported)", id.name())
            }
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}

/// `param NAME VALUE`: write a writable parameter (on/off for a switch),
/// refused in words; then its value in force.
fn write_param(c: &mut Client, name: &str, text: &str) -> CliResult {
    let id = ParamId::from_name(name)
        .filter(|p| p.is_writable())
        .ok_or_else(|| {
            let names: Vec<&str> = ParamId::ALL
                .iter()
                .filter(|p| p.is_writable())
                .map(|p| p.name())
                .collect();
            format!(
                "`{name}` is not a parameter that can be written; these are: {}",
                names.join(", ")
            )
        })?;
    let value = refusal::param_value(id, text).map_err(|e| format!("{name}: {e}"))?;
    let r = Request::SetParam { id, value };
    c.send(&r).map_err(|e| refusal::explain(c, &r, &e))?;
    say!("{:<18} {}", id.name(), param_text(id, c.param(id)?));
    Ok(())
}

/// The commands that send one setting and print `ok`: `clear`, `limits`,
/// `gains`, `dividers`, `watchdog`.
fn configure(c: &mut Client, setting: Cmd) -> CliResult {
    match setting {
        Cmd::Clear => c.clear_faults()?,
        Cmd::Gains { which } => {
            let r = gains_request(which);
            c.send(&r).map_err(|e| refusal::explain(c, &r, &e))?
        }
        Cmd::Dividers { speed, position } => {
            let r = Request::SetDividers { speed, position };
            c.send(&r).map_err(|e| refusal::explain(c, &r, &e))?
        }
        Cmd::Simulate(_)
        | Cmd::Dashboard(_)
        | Cmd::Ping
        | Cmd::Mode { .. }
        | Cmd::KeepAlive { .. }
        | Cmd::Faults
        | Cmd::Param { .. }
        | Cmd::Telemetry { .. }
        | Cmd::Calibrate { .. }
        | Cmd::Identify { .. }
        | Cmd::Config { .. }
        | Cmd::Joint(_)
        | Cmd::Home { .. }
        | Cmd::Scope { .. }
        | Cmd::Tune(_)
        | Cmd::Limits(_)
        | Cmd::Watchdog { .. }
        | Cmd::Status => return Err("not a setting (handled by `run`)".into()),
    }
    say!("ok");
    Ok(())
}

/// `calibrate ROUTINE [--no-wait]`: start it; unless told not to, show
/// its steps as the drive reports them and the result.
fn calibrate(c: &mut Client, routine: Routine, no_wait: bool, wait_ms: f64) -> CliResult {
    let r = match routine {
        Routine::Offsets => Calibration::Offsets,
        Routine::Identification => Calibration::Identification,
        Routine::Alignment => Calibration::Alignment,
        Routine::Cogging => Calibration::Anticogging,
        Routine::Encoder => Calibration::EncoderLinearisation,
    };
    if no_wait {
        c.calibrate(r)
            .map_err(|e| refusal::explain(c, &Request::RunCalibration(r), &e))?;
        say!("started (follow it: `foc-ctl param calibration-step`, `calibration-result`)");
        return Ok(());
    }
    let before = CalProgress::read(c)?;
    c.calibrate(r)
        .map_err(|e| refusal::explain(c, &Request::RunCalibration(r), &e))?;
    say!("{r:?}: started");
    if !(wait_ms.is_finite() && wait_ms >= 0.0) {
        return Err(format!("--wait-ms {wait_ms}: give a time in ms").into());
    }
    let timeout = Duration::from_secs_f64((wait_ms * 1e-3).min(3600.0));
    let end = calibration::wait(c, r, before, timeout, &mut |p, t| {
        if p.running() {
            say!("{:6.1} s  {}", t.as_secs_f64(), p.step_name());
        }
    })?;
    match end {
        WaitEnd::NotStarted(_) => Err(format!(
            "the drive took the {r:?} request but did not start it: `foc-ctl faults` and `status` say why"
        )
        .into()),
        WaitEnd::TimedOut(p) => Err(format!(
            "still running at {} after {wait_ms} ms (`foc-ctl param calibration-step` follows it)",
            p.step_name()
        )
        .into()),
        WaitEnd::Ended(p) if p.done() => {
            say!("done");
            match r {
                Calibration::Identification => print_identified(c)?,
                Calibration::Anticogging | Calibration::EncoderLinearisation => {
                    print_table(c, r)?
                }
                Calibration::Offsets | Calibration::Alignment => {}
            }
            Ok(())
        }
        WaitEnd::Ended(p) => Err(format!(
            "{r:?} {} (at {}): {}",
            p.result_text(),
            p.step_name(),
            p.advice()
        )
        .into()),
    }
}

/// The table a sweep calibration measured: its peak, switched on, and
/// how to keep it.
fn print_table(c: &mut Client, r: Calibration) -> CliResult {
    let (switch, peak) = if r == Calibration::Anticogging {
        (ParamId::Anticogging, ParamId::AnticoggingPeakA)
    } else {
        (
            ParamId::EncoderLinearisation,
            ParamId::EncoderCorrectionPeakRad,
        )
    };
    let p = c.param(peak)?;
    say!("{:<24}{}", peak.name(), show::param_text(peak, p));
    say!(
        "{:<24}{}",
        switch.name(),
        show::param_text(switch, c.param(switch)?)
    );
    say!(
        "keep it: `foc-ctl config save` (off: `foc-ctl param {} off`)",
        switch.name()
    );
    Ok(())
}

/// The identified motor and the gains derived from it.
fn print_identified(c: &mut Client) -> CliResult {
    let mut v = |id: ParamId| c.param(id);
    let (r, ld, lq, psi) = (
        v(ParamId::ResistanceOhm)?,
        v(ParamId::LdH)?,
        v(ParamId::LqH)?,
        v(ParamId::FluxLinkageWb)?,
    );
    say!(
        "motor          R {r:.4} ohm, Ld {:.4} mH, Lq {:.4} mH, psi {:.5} Wb",
        ld * 1e3,
        lq * 1e3,
        psi
    );
    let (kp, ki) = (v(ParamId::CurrentKp)?, v(ParamId::CurrentKi)?);
    say!("current loop   kp {kp:.4} V/A, ki {ki:.1} V/(A s)");
    let (skp, ski) = (v(ParamId::SpeedKp)?, v(ParamId::SpeedKi)?);
    say!("speed loop     kp {skp:.5} A/(rad/s), ki {ski:.4} A/rad");
    say!("position loop  kp {:.3} 1/s", v(ParamId::PositionKp)?);
    say!("keep it: `foc-ctl config save`");
    Ok(())
}

/// The request of `gains current|speed|position`.
fn gains_request(which: GainsCmd) -> Request {
    match which {
        GainsCmd::Current {
            kp_d,
            ki_d,
            kp_q,
            ki_q,
        } => Request::SetCurrentGains(CurrentGains {
            kp_d,
            ki_d,
            kp_q,
            ki_q,
        }),
        GainsCmd::Speed { kp, ki } => Request::SetSpeedGains(SpeedGains {
            kp_a_per_rad_s: kp,
            ki_a_per_rad: ki,
        }),
        GainsCmd::Position {
            kp,
            max_velocity,
            max_acceleration,
        } => Request::SetPositionGains(PositionGains {
            kp_per_s: kp,
            max_velocity_rad_s: max_velocity,
            max_acceleration_rad_s2: max_acceleration,
        }),
    }
}

/// A reader that closed the pipe (`foc-ctl status | head -1`) ends the
/// program quietly: `print!` panics on a broken pipe, and this hook turns
/// that one panic into a silent exit (status 0: the reader has what it
/// wanted); every other panic is reported as usual.
fn quiet_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let msg = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.contains("Broken pipe") {
            std::process::exit(0);
        }
        default(info);
    }));
}

fn main() -> ExitCode {
    quiet_on_broken_pipe();
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("foc-ctl: {e}");
            ExitCode::FAILURE
        }
    }
}
