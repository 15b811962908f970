//! `foc-ctl`: command-line host tool for the drive's command channel.
//!
//! Frames (design §21): positions, velocities, torques and stiffnesses of
//! commands (`mode position|velocity|impedance`, `home`) and telemetry are
//! the joint's **output** frame (after the gearbox; the same numbers as the
//! rotor's until `joint` sets a gear or homing an offset); the motor's
//! limits (`limits`) and the joint's rotor-side settings are the **rotor**'s.

mod cli;
mod config_cmd;
mod telemetry_cmd;

use cli::*;
use config_cmd::*;
use telemetry_cmd::*;

use clap::{Parser, Subcommand, ValueEnum};
use foc_core::angle::ElectricalAngle;
use foc_core::control::homing::{EndStop, HomingMethod};
use foc_core::control::joint::Impedance;
use foc_core::control::power::ActiveLimit;
use foc_core::control::stage::TimeoutReaction;
use foc_core::control::{Command, Fault, Limits};
use foc_ctl::joint::{error_text, homing_text, joint_text, JointEdit};
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
        (Some(addr), _) => Client::connect_tcp(addr.as_str())?,
        #[cfg(feature = "serial")]
        (None, Some(path)) => Client::open_serial(path, cli.baud)?,
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
    if let Cmd::Simulate(a) = &cli.cmd {
        return simulate(a);
    }
    let mut c = connect(&cli)?;
    match cli.cmd {
        Cmd::Ping => ping(&mut c),
        Cmd::Scope { op } => scope_cmd::scope(&mut c, op),
        Cmd::Tune(args) => scope_cmd::tune(&mut c, args),
        Cmd::Mode { mode } => set_mode(&mut c, mode),
        Cmd::KeepAlive {
            interval_ms,
            duration,
        } => keep_alive(&mut c, interval_ms, duration),
        Cmd::Faults => show_faults(&mut c),
        Cmd::Param { name } => show_params(&mut c, &name),
        Cmd::Telemetry {
            rate,
            every,
            duration,
            csv,
            plot,
            svg,
        } => {
            let r = match every {
                Some(k) => TelemetryRate::EveryPeriods(k),
                None => TelemetryRate::Hz(rate as f32),
            };
            stream_telemetry(&mut c, r, duration, csv, plot, svg)
        }
        Cmd::Calibrate { routine } => calibrate(&mut c, routine),
        Cmd::Config { op } => config(&mut c, op),
        Cmd::Joint(args) => joint(&mut c, &args),
        Cmd::Home { method } => home(&mut c, method),
        Cmd::Status => status(&mut c),
        setting => configure(&mut c, setting),
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
    eprintln!(
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
    println!(
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
        .map_err(|e| error_text(&Request::SetCommand(cmd), &e))?;
    println!("ok: {cmd:?} (positions, velocities, torques: output frame)");
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
            .map_err(|e| error_text(&Request::SetJoint(j), &e))?;
    }
    println!("{}", joint_text(&c.joint()?));
    Ok(())
}

/// `home present|end-stop`: start homing, show its progress (output
/// frame) until it ends, then the frame it set.
fn home(c: &mut Client, method: HomeCmd) -> CliResult {
    let (h, timeout) = method.request();
    let state = c
        .home(h, Duration::from_secs_f64(timeout.max(0.0)), |t| {
            println!(
                "homing: p={:.4} rad w={:.3} rad/s (output) iq={:.3} A",
                t.position_rad, t.velocity_rad_s, t.i_q_a
            )
        })
        .map_err(|e| error_text(&Request::StartHoming(h), &e))?;
    match state {
        HomingState::Done => {
            println!("homed: {}", homing_text(state));
            println!("{}", joint_text(&c.joint()?));
            Ok(())
        }
        HomingState::Running => Err("homing: no result within the timeout (still running)".into()),
        other => Err(format!("homing {}", homing_text(other)).into()),
    }
}

/// `status`: one sample (frames stated), the joint and homing.
fn status(c: &mut Client) -> CliResult {
    let t = c.read_telemetry()?;
    println!("mode           {:?}", t.mode);
    println!("position       {} rad (output)", t.position_rad);
    println!("velocity       {} rad/s (output)", t.velocity_rad_s);
    println!("currents       id {} A, iq {} A", t.i_d_a, t.i_q_a);
    println!("bus            {} V", t.v_bus_v);
    let fault = match (t.fault_code, Fault::from_code(t.fault_code)) {
        (0, _) => "none".to_string(),
        (_, Some(f)) => format!("{} ({})", f.name(), f.code()),
        (code, None) => format!("code {code}"),
    };
    println!("first fault    {fault}");
    println!("homing         {}", homing_text(c.homing_state()?));
    println!("{}", joint_text(&c.joint()?));
    Ok(())
}

/// `keep-alive`: one keep-alive every `interval_ms` for `duration` seconds.
fn keep_alive(c: &mut Client, interval_ms: u64, duration: f64) -> CliResult {
    let end = std::time::Instant::now() + Duration::from_secs_f64(duration.max(0.0));
    while std::time::Instant::now() < end {
        c.keep_alive()?;
        std::thread::sleep(Duration::from_millis(interval_ms));
    }
    Ok(())
}

/// `faults`: the latched set and the first one.
fn show_faults(c: &mut Client) -> CliResult {
    let f = c.faults()?;
    println!("latched: {}", fault_list(f.set.0));
    match f.first() {
        Some(first) => println!("first:   {} ({})", first.name(), first.code()),
        None if f.first_code != 0 => println!("first:   code {}", f.first_code),
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
            Ok(v) => println!("{:<18} {v}", id.name()),
            Err(ClientError::Nack(foc_protocol::ErrorCode::Unsupported)) => {
                println!("{:<18} (not supported)", id.name())
            }
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}

/// The commands that send one setting and print `ok`: `clear`, `limits`,
/// `gains`, `dividers`, `watchdog`.
fn configure(c: &mut Client, setting: Cmd) -> CliResult {
    match setting {
        Cmd::Clear => c.clear_faults()?,
        Cmd::Limits {
            max_current,
            max_velocity,
            min_position,
            max_position,
            max_ol_voltage,
            max_ol_omega_e,
            max_kp,
            max_kd,
        } => {
            let l = Limits {
                max_current_a: max_current,
                max_velocity_rad_s: max_velocity,
                min_position_rad: min_position,
                max_position_rad: max_position,
                max_open_loop_voltage_v: max_ol_voltage,
                max_open_loop_omega_e_rad_s: max_ol_omega_e,
                max_kp_nm_per_rad: max_kp,
                max_kd_nm_s_per_rad: max_kd,
            };
            c.set_limits(l)
                .map_err(|e| error_text(&Request::SetLimits(l), &e))?
        }
        Cmd::Gains { which } => set_gains(c, which)?,
        Cmd::Dividers { speed, position } => c.set_dividers(speed, position)?,
        Cmd::Watchdog {
            timeout_periods,
            reaction,
        } => c.set_watchdog(WatchdogConfig {
            timeout_periods,
            reaction: match reaction {
                Reaction::Disable => TimeoutReaction::Disable,
                Reaction::Stop => TimeoutReaction::Stop,
                Reaction::Hold => TimeoutReaction::Hold,
            },
        })?,
        Cmd::Simulate(_)
        | Cmd::Ping
        | Cmd::Mode { .. }
        | Cmd::KeepAlive { .. }
        | Cmd::Faults
        | Cmd::Param { .. }
        | Cmd::Telemetry { .. }
        | Cmd::Calibrate { .. }
        | Cmd::Config { .. }
        | Cmd::Joint(_)
        | Cmd::Home { .. }
        | Cmd::Scope { .. }
        | Cmd::Tune(_)
        | Cmd::Status => return Err("not a setting (handled by `run`)".into()),
    }
    println!("ok");
    Ok(())
}

/// `calibrate ROUTINE`: start it.
fn calibrate(c: &mut Client, routine: Routine) -> CliResult {
    c.calibrate(match routine {
        Routine::Offsets => Calibration::Offsets,
        Routine::Identification => Calibration::Identification,
        Routine::Alignment => Calibration::Alignment,
    })?;
    println!("started");
    Ok(())
}

/// `gains current|speed|position`.
fn set_gains(c: &mut Client, which: GainsCmd) -> Result<(), ClientError> {
    match which {
        GainsCmd::Current {
            kp_d,
            ki_d,
            kp_q,
            ki_q,
        } => c.set_current_gains(CurrentGains {
            kp_d,
            ki_d,
            kp_q,
            ki_q,
        }),
        GainsCmd::Speed { kp, ki } => c.set_speed_gains(SpeedGains {
            kp_a_per_rad_s: kp,
            ki_a_per_rad: ki,
        }),
        GainsCmd::Position {
            kp,
            max_velocity,
            max_acceleration,
        } => c.set_position_gains(PositionGains {
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
