//! `foc-ctl`: command-line host tool for the drive's command channel.
//!
//! Frames (design §21): positions, velocities, torques and stiffnesses of
//! commands (`mode position|velocity|impedance`, `home`) and telemetry are
//! the joint's **output** frame (after the gearbox; the same numbers as the
//! rotor's until `joint` sets a gear or homing an offset); the motor's
//! limits (`limits`) and the joint's rotor-side settings are the **rotor**'s.

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

#[derive(Parser)]
#[command(
    name = "foc-ctl",
    version,
    about = "Command and telemetry tool for the FOC drive"
)]
struct Cli {
    /// Connect over TCP, e.g. QEMU's `-serial tcp:127.0.0.1:4444,server,nowait`.
    #[arg(
        long,
        value_name = "HOST:PORT",
        global = true,
        conflicts_with = "serial"
    )]
    tcp: Option<String>,
    /// Serial port of a real board, e.g. /dev/ttyACM0.
    #[arg(long, value_name = "PATH", global = true)]
    serial: Option<String>,
    /// Serial baud rate.
    #[arg(long, default_value_t = 115_200, global = true)]
    baud: u32,
    /// Reply timeout per attempt [ms].
    #[arg(long, default_value_t = 250, global = true)]
    timeout_ms: u64,
    /// Retransmissions after the first attempt.
    #[arg(long, default_value_t = 3, global = true)]
    retries: u32,
    /// Reply timeout per attempt of flash operations (`config save|load|erase|import`,
    /// reads of the stored record) [ms]: an erase stalls a board for seconds.
    #[arg(long, default_value_t = 10000, global = true)]
    store_timeout_ms: u64,
    #[command(subcommand)]
    cmd: Cmd,
}

mod scope_cmd;

#[derive(Subcommand)]
enum Cmd {
    /// Protocol and firmware version.
    Ping,
    /// The drive's scope: PWM-rate capture of selected signals (set, arm,
    /// trigger, status, read to CSV / SVG).
    Scope {
        #[command(subcommand)]
        op: scope_cmd::ScopeCmd,
    },
    /// Step a loop, capture it with the scope, report overshoot, rise,
    /// settling and bandwidth, suggest gains (leaves the drive disabled).
    Tune(scope_cmd::TuneArgs),
    /// Set mode and target.
    Mode {
        #[command(subcommand)]
        mode: ModeCmd,
    },
    /// Send keep-alives (feeds the device's watchdog) for a while.
    KeepAlive {
        /// Interval [ms].
        #[arg(long, default_value_t = 100)]
        interval_ms: u64,
        /// How long [s].
        #[arg(long, default_value_t = 10.0)]
        duration: f64,
    },
    /// Clear latched faults.
    Clear,
    /// Show latched faults.
    Faults,
    /// Read a parameter (`all` for every one).
    Param {
        /// pole-pairs, r, ld, lq, psi, pwm-frequency, speed-divider,
        /// position-divider, firmware-version, protocol-version, bus-voltage,
        /// calibrated, max-loop-cycles, telemetry-divider, watchdog-timeout, all
        name: String,
    },
    /// Stream telemetry.
    Telemetry {
        /// Rate [Hz] (converted by the device to whole current-loop periods).
        #[arg(long, default_value_t = 100.0, conflicts_with = "every")]
        rate: f64,
        /// Instead of a rate: one sample every K current-loop periods.
        #[arg(long, value_name = "K")]
        every: Option<u32>,
        /// How long [s].
        #[arg(long, default_value_t = 5.0)]
        duration: f64,
        /// Write the samples to a CSV file.
        #[arg(long, value_name = "FILE")]
        csv: Option<PathBuf>,
        /// Live terminal sparklines of velocity and iq (on stderr).
        #[arg(long)]
        plot: bool,
        /// Write an SVG plot at the end.
        #[arg(long, value_name = "FILE")]
        svg: Option<PathBuf>,
    },
    /// Set the motor's command limits (all eight; rotor frame).
    Limits {
        /// Current limit [A].
        #[arg(long)]
        max_current: f32,
        /// Velocity limit [rad/s].
        #[arg(long)]
        max_velocity: f32,
        /// Lowest position [rad].
        #[arg(long, allow_hyphen_values = true)]
        min_position: f32,
        /// Highest position [rad].
        #[arg(long, allow_hyphen_values = true)]
        max_position: f32,
        /// Open-loop voltage limit [V].
        #[arg(long)]
        max_ol_voltage: f32,
        /// Open-loop electrical speed limit [rad/s].
        #[arg(long)]
        max_ol_omega_e: f32,
        /// Largest impedance stiffness [N m/rad, rotor].
        #[arg(long, allow_hyphen_values = true)]
        max_kp: f32,
        /// Largest impedance damping [N m s/rad, rotor].
        #[arg(long, allow_hyphen_values = true)]
        max_kd: f32,
    },
    /// The joint: output frame (gear, home offset), travel range, soft stop;
    /// shown after a change, or alone without options.
    Joint(JointArgs),
    /// Home the joint (sets the output frame's zero) and wait for the result.
    Home {
        #[command(subcommand)]
        method: HomeCmd,
    },
    /// One telemetry sample, the joint and homing, each value with its frame.
    Status,
    /// Set loop gains.
    Gains {
        #[command(subcommand)]
        which: GainsCmd,
    },
    /// Loop dividers: speed loop every N, position loop every M periods (drive disabled).
    Dividers {
        /// N.
        speed: u16,
        /// M.
        position: u16,
    },
    /// Link watchdog: reaction after TIMEOUT periods without a command or keep-alive (0 = off).
    Watchdog {
        /// Timeout [current-loop periods].
        timeout_periods: u32,
        /// Reaction.
        #[arg(value_enum, default_value_t = Reaction::Disable)]
        reaction: Reaction,
    },
    /// Start a calibration routine.
    Calibrate {
        /// Routine.
        #[arg(value_enum)]
        routine: Routine,
    },
    /// The drive's configuration record: show, save, load, erase, export, import.
    Config {
        #[command(subcommand)]
        op: ConfigCmd,
    },
    /// Serve a simulated device (kinematic model) on a TCP address, for trying the tool.
    Simulate {
        /// Address to listen on.
        #[arg(long, default_value = "127.0.0.1:4444")]
        listen: String,
        /// Mechanical end stops of the simulated rotor [rad, rotor] (to try
        /// `home end-stop`).
        #[arg(long, num_args = 2, value_names = ["LOW", "HIGH"], allow_hyphen_values = true)]
        end_stops: Option<Vec<f32>>,
    },
}

#[derive(clap::Args)]
struct JointArgs {
    /// Rotor turns per output turn; negative when the output turns the other way.
    #[arg(long, allow_hyphen_values = true)]
    gear_ratio: Option<f32>,
    /// Home offset: the rotor position where the output reads 0 [rad, rotor].
    #[arg(long, allow_hyphen_values = true)]
    offset: Option<f32>,
    /// Travel range at the output [rad, output] (soft stop at its ends).
    #[arg(long, num_args = 2, value_names = ["MIN", "MAX"], allow_hyphen_values = true, conflicts_with = "no_travel")]
    travel: Option<Vec<f32>>,
    /// Remove the travel range (the motor's position range applies).
    #[arg(long)]
    no_travel: bool,
    /// Fault (TravelLimit) beyond the travel range by more than this [rad, rotor].
    #[arg(long, allow_hyphen_values = true)]
    fault_margin: Option<f32>,
    /// Soft stop's deceleration [rad/s^2, rotor].
    #[arg(long, allow_hyphen_values = true)]
    brake_accel: Option<f32>,
    /// Soft stop's velocity gain [A/(rad/s), rotor].
    #[arg(long, allow_hyphen_values = true)]
    kv: Option<f32>,
    /// Impedance entry blend [current-loop periods].
    #[arg(long)]
    entry_blend: Option<u32>,
    /// Least damping after an impedance command times out [N m s/rad, rotor].
    #[arg(long, allow_hyphen_values = true)]
    timeout_kd: Option<f32>,
}

#[derive(Subcommand)]
enum HomeCmd {
    /// The present position is home.
    Present {
        /// The output position home reads [rad, output].
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        at: f32,
    },
    /// Search an end stop at a slow speed, found by the current it takes
    /// (at most the homing current), then back off. After it the joint
    /// holds the back-off point until the next command (or the link
    /// watchdog: damping, then disable).
    EndStop {
        /// Search velocity [rad/s, output]; its sign is the direction.
        #[arg(long, allow_hyphen_values = true)]
        velocity: f32,
        /// Homing current [A]: the most the stop is pressed with.
        #[arg(long, allow_hyphen_values = true)]
        current: f32,
        /// Share of the homing current, held with the joint still, that
        /// means the stop is reached.
        #[arg(long, allow_hyphen_values = true, default_value_t = 0.7)]
        detect: f32,
        /// How long the stop must be held [s].
        #[arg(long, allow_hyphen_values = true, default_value_t = 0.05)]
        confirm: f32,
        /// Distance to back off from the stop [rad, output].
        #[arg(long, allow_hyphen_values = true)]
        backoff: f32,
        /// Longest search before giving up [rad, output].
        #[arg(long, allow_hyphen_values = true)]
        max_travel: f32,
        /// The output position the stop reads [rad, output].
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        at: f32,
        /// Longest wait for the result [s].
        #[arg(long, default_value_t = 60.0)]
        timeout: f64,
    },
}

impl HomeCmd {
    /// The request (output frame) and the longest wait for its result [s].
    fn request(self) -> (HomingStart, f64) {
        match self {
            HomeCmd::Present { at } => (
                HomingStart {
                    method: HomingMethod::Present,
                    home_output_rad: at,
                },
                0.0,
            ),
            HomeCmd::EndStop {
                velocity,
                current,
                detect,
                confirm,
                backoff,
                max_travel,
                at,
                timeout,
            } => (
                HomingStart {
                    method: HomingMethod::EndStop(EndStop {
                        velocity_rad_s: velocity,
                        current_a: current,
                        detect_fraction: detect,
                        confirm_s: confirm,
                        backoff_rad: backoff,
                        max_travel_rad: max_travel,
                    }),
                    home_output_rad: at,
                },
                timeout,
            ),
        }
    }
}

#[derive(Subcommand)]
enum ModeCmd {
    /// Bridge off.
    Disable,
    /// Torque: q current [A].
    Torque {
        #[arg(allow_hyphen_values = true)]
        iq_a: f32,
    },
    /// Velocity [rad/s, output].
    Velocity {
        #[arg(allow_hyphen_values = true)]
        rad_s: f32,
    },
    /// Position [rad, output].
    Position {
        #[arg(allow_hyphen_values = true)]
        rad: f32,
    },
    /// Impedance: torque = kp (position - p) + kd (velocity - v) + torque-ff
    /// (output frame), clamped to the torque limit and the current limit.
    Impedance {
        /// Position reference [rad, output].
        #[arg(long, allow_hyphen_values = true)]
        position: f32,
        /// Velocity reference [rad/s, output] (the reference advances with it).
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        velocity: f32,
        /// Stiffness [N m/rad, output].
        #[arg(long, allow_hyphen_values = true)]
        kp: f32,
        /// Damping [N m s/rad, output].
        #[arg(long, allow_hyphen_values = true)]
        kd: f32,
        /// Feed-forward torque [N m, output].
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        torque_ff: f32,
        /// Largest torque [N m, output] (default: the current limit's).
        #[arg(long, allow_hyphen_values = true, default_value_t = f32::INFINITY)]
        torque_limit: f32,
    },
    /// Open-loop dq voltage [V] at an electrical angle, rotating at omega_e.
    OpenLoop {
        #[arg(allow_hyphen_values = true)]
        v_d: f32,
        #[arg(allow_hyphen_values = true)]
        v_q: f32,
        /// Starting electrical angle [deg].
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        theta_deg: f32,
        /// Electrical speed [rad/s].
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        omega_e: f32,
    },
}

#[derive(Subcommand)]
enum GainsCmd {
    /// Current loop [V/A, V/(A s)].
    Current {
        #[arg(long)]
        kp_d: f32,
        #[arg(long)]
        ki_d: f32,
        #[arg(long)]
        kp_q: f32,
        #[arg(long)]
        ki_q: f32,
    },
    /// Speed loop [A/(rad/s), A/rad].
    Speed {
        #[arg(long)]
        kp: f32,
        #[arg(long)]
        ki: f32,
    },
    /// Position loop [1/s] and trajectory limits.
    Position {
        #[arg(long)]
        kp: f32,
        /// [rad/s]
        #[arg(long)]
        max_velocity: f32,
        /// [rad/s^2]
        #[arg(long)]
        max_acceleration: f32,
    },
}

#[derive(Subcommand)]
enum ConfigCmd {
    /// Print the configuration in force (or the stored one) as TOML.
    Show {
        /// The record in the drive's flash store instead (drive disabled).
        #[arg(long)]
        stored: bool,
    },
    /// Write the configuration in force to the flash store (drive disabled).
    Save,
    /// Apply the stored record (drive disabled; validated whole first).
    Load,
    /// Erase the flash store (the configuration in force is kept; the next
    /// boot starts from the build-time defaults, uncalibrated).
    Erase,
    /// Write the configuration in force (or the stored one) to a TOML file.
    Export {
        /// The file to write.
        file: PathBuf,
        /// The record in the drive's flash store instead (drive disabled).
        #[arg(long)]
        stored: bool,
    },
    /// Check a TOML file on the host, send it, apply it and save it (drive disabled).
    Import {
        /// The file to read.
        file: PathBuf,
        /// Apply only; the flash store keeps its record.
        #[arg(long)]
        no_save: bool,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum Reaction {
    Disable,
    Stop,
    Hold,
}

#[derive(Clone, Copy, ValueEnum)]
enum Routine {
    Offsets,
    Identification,
    Alignment,
}

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

const SPARK: [char; 8] = ['▁', '▂', '▃', '▄', '▅', '▆', '▇', '█'];

fn sparkline(v: &[f32]) -> String {
    let (lo, hi) = v
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    v.iter()
        .map(|&x| {
            let t = if hi > lo { (x - lo) / (hi - lo) } else { 0.5 };
            SPARK[((t * 7.0).round() as usize).min(7)]
        })
        .collect()
}

fn write_csv(path: &Path, samples: &[StreamSample]) -> std::io::Result<()> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(
        f,
        "host_time_s,seq,period,i_d_a,i_q_a,v_d_v,v_q_v,velocity_out_rad_s,position_out_rad,mode,fault_code,max_loop_cycles,v_bus_v,bus_power_w,bus_current_a,power_limit,limit_left_pct,brake_on,winding_c,stage_c"
    )?;
    for s in samples {
        let t = &s.sample;
        writeln!(
            f,
            "{:.6},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:?},{},{},{},{}",
            s.host_time.as_secs_f64(),
            s.seq,
            t.period,
            t.i_d_a,
            t.i_q_a,
            t.v_d_v,
            t.v_q_v,
            t.velocity_rad_s,
            t.position_rad,
            t.mode as u8,
            t.fault_code,
            t.max_loop_cycles,
            t.v_bus_v,
            bus_power_w(t),
            bus_power_w(t) / t.v_bus_v,
            t.power_limit,
            t.limit_left_pct,
            u8::from(t.brake_on),
            t.winding_c,
            t.stage_c
        )?;
    }
    f.flush()
}

fn write_svg(path: &Path, samples: &[StreamSample]) -> Result<(), Box<dyn std::error::Error>> {
    use foc_plot::{Figure, Panel, Series};
    // One frame per panel: on the wire the velocity and position are the
    // output's (after the joint's gear ratio and offset, mechanical), the
    // currents the rotor's dq frame.
    let t0 = samples.first().map_or(0.0, |s| s.host_time.as_secs_f64());
    let t: Vec<f64> = samples
        .iter()
        .map(|s| s.host_time.as_secs_f64() - t0)
        .collect();
    let col = |get: fn(&StreamSample) -> f32| -> Vec<f64> {
        samples.iter().map(|s| f64::from(get(s))).collect()
    };
    let velocity = col(|s| s.sample.velocity_rad_s);
    let position = col(|s| s.sample.position_rad);
    let i_d = col(|s| s.sample.i_d_a);
    let i_q = col(|s| s.sample.i_q_a);
    let fig = Figure {
        title: "foc-ctl telemetry",
        x_label: "host time [s] (from the first sample)",
        panels: vec![
            Panel {
                y_label: "velocity [rad/s] (output, mechanical)",
                series: vec![Series {
                    name: "velocity",
                    x: &t,
                    y: &velocity,
                }],
            },
            Panel {
                y_label: "position [rad] (output, mechanical, multi-turn)",
                series: vec![Series {
                    name: "position",
                    x: &t,
                    y: &position,
                }],
            },
            Panel {
                y_label: "current [A] (rotor dq frame, measured)",
                series: vec![
                    Series {
                        name: "i_q",
                        x: &t,
                        y: &i_q,
                    },
                    Series {
                        name: "i_d",
                        x: &t,
                        y: &i_d,
                    },
                ],
            },
        ],
        x_marker: None,
    };
    foc_plot::write_svg(path, &fig)?;
    Ok(())
}

type CliResult = Result<(), Box<dyn std::error::Error>>;

fn run(cli: Cli) -> CliResult {
    if let Cmd::Simulate { listen, end_stops } = &cli.cmd {
        return simulate(listen, end_stops.as_deref());
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

/// `simulate`: serve the simulated device until killed.
fn simulate(listen: &str, end_stops: Option<&[f32]>) -> CliResult {
    let mut dev = foc_ctl::sim::SimDevice::default();
    if let Some(&[lo, hi]) = end_stops {
        dev.drive.stops_rad = (lo, hi);
    }
    let server = SimServer::spawn_with(std::net::TcpListener::bind(listen)?, dev)?;
    eprintln!("simulated device on {} (Ctrl-C to stop)", server.addr());
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

/// `telemetry`: stream for `duration` seconds, showing each sample (a line,
/// or sparklines with `plot`), then the optional CSV and SVG files.
fn stream_telemetry(
    c: &mut Client,
    rate: TelemetryRate,
    duration: f64,
    csv: Option<PathBuf>,
    plot: bool,
    svg: Option<PathBuf>,
) -> CliResult {
    let mut samples: Vec<StreamSample> = Vec::new();
    let mut stderr = std::io::stderr();
    c.telemetry_with(rate, Duration::from_secs_f64(duration.max(0.0)), |s| {
        samples.push(*s);
        if plot && samples.len().is_multiple_of(5) {
            plot_tail(&mut stderr, &samples, s);
        } else if !plot && csv.is_none() {
            print_sample(s);
        }
    })?;
    if plot {
        eprintln!();
    }
    let st = c.stats();
    eprintln!(
        "{} samples, {} lost in the stream",
        samples.len(),
        st.stream_lost
    );
    if let Some(p) = csv {
        write_csv(&p, &samples)?;
        eprintln!("wrote {}", p.display());
    }
    if let Some(p) = svg {
        write_svg(&p, &samples)?;
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}

/// One live line of velocity and iq sparklines over the last 60 samples.
fn plot_tail(out: &mut impl Write, samples: &[StreamSample], s: &StreamSample) {
    let tail = &samples[samples.len().saturating_sub(60)..];
    let w: Vec<f32> = tail.iter().map(|s| s.sample.velocity_rad_s).collect();
    let i: Vec<f32> = tail.iter().map(|s| s.sample.i_q_a).collect();
    let _ = write!(
        out,
        "\rw {:>9.2} rad/s (output) {}  iq {:>7.3} A {}",
        s.sample.velocity_rad_s,
        sparkline(&w),
        s.sample.i_q_a,
        sparkline(&i)
    );
}

/// The bus power of a sample [W]: the dq power `1.5 (v_d i_d + v_q i_q)`
/// of the commanded voltages and measured currents (inverter losses not
/// included; > 0 motoring, < 0 regenerating).
fn bus_power_w(t: &foc_protocol::message::Telemetry) -> f32 {
    1.5 * (t.v_d_v * t.i_d_a + t.v_q_v * t.i_q_a)
}

/// The power limit of a sample, when one cuts the current, e.g.
/// ` limit=Regen(37%)`; empty otherwise. ` brake` while the chopper conducts.
fn power_text(t: &foc_protocol::message::Telemetry) -> String {
    let mut s = String::new();
    if t.power_limit != ActiveLimit::None {
        s += &format!(" limit={:?}({}%)", t.power_limit, t.limit_left_pct);
    }
    if t.brake_on {
        s += " brake";
    }
    if t.brake_locked {
        s += " brake-locked-out";
    }
    s
}

/// One sample as a line on stdout.
fn print_sample(s: &StreamSample) {
    let t = &s.sample;
    println!(
        "{:>10} {:?} w_out={:.3} p_out={:.4} id={:.3} iq={:.3} vd={:.3} vq={:.3} vbus={:.2} pbus={:.1} twind={:.1} tstage={:.1} fault={} cyc={}{}",
        t.period, t.mode, t.velocity_rad_s, t.position_rad, t.i_d_a, t.i_q_a,
        t.v_d_v, t.v_q_v, t.v_bus_v, bus_power_w(t), t.winding_c, t.stage_c,
        t.fault_code, t.max_loop_cycles, power_text(t)
    );
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
        Cmd::Simulate { .. }
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

/// What a `config` Nack means for the operation `what`, with a hint.
fn config_error(what: &str, e: ClientError) -> Box<dyn std::error::Error> {
    let ClientError::Nack(code) = e else {
        return format!("{what}: {e}").into();
    };
    let hint = match code {
        ErrorCode::NotDisabled => "disable the drive first (`foc-ctl mode disable`)",
        ErrorCode::Busy => "the drive is starting up or calibrating; try again when it is done",
        ErrorCode::NothingStored => {
            "the flash store is empty; `foc-ctl config save` writes the configuration in force"
        }
        ErrorCode::BadRecord if what == "config save" => {
            "a value in force is out of range for a record (see `config show`); nothing was written"
        }
        ErrorCode::BadRecord if what.starts_with("reading") => {
            "the stored record is corrupt, from another version or out of range; \
             `config erase` clears it, `config import FILE` sends a good one"
        }
        ErrorCode::BadRecord => {
            "the configuration in force is unchanged; `config erase` clears a bad stored record, \
             `config import FILE` sends a good one"
        }
        ErrorCode::StoreFailed => {
            "the configuration in force is unchanged; the stored record may be the old one, \
             check it with `config show --stored`"
        }
        ErrorCode::Unsupported => "this device has no configuration store",
        _ => "nothing was changed",
    };
    format!(
        "{what}: refused by the device: {} ({hint})",
        describe_error(code)
    )
    .into()
}

fn source_name(source: ConfigSource) -> &'static str {
    match source {
        ConfigSource::Live => "live",
        ConfigSource::Stored => "stored",
    }
}

/// The live or stored record from the device, decoded; a record that
/// fails its CRC or version check is an error that says so, an
/// out-of-range one a warning.
fn read_record(
    c: &mut Client,
    source: ConfigSource,
) -> Result<DriveRecord, Box<dyn std::error::Error>> {
    let name = source_name(source);
    let bytes = c
        .read_config(source)
        .map_err(|e| config_error(&format!("reading the {name} record"), e))?;
    let r = DriveRecord::decode(&bytes).map_err(|e| {
        format!(
            "the {name} record from the device ({} bytes) is not readable: {e}",
            bytes.len()
        )
    })?;
    if let Err(e) = r.validate() {
        eprintln!(
            "warning: the {name} record has a value out of range ({e}); it would be refused on import"
        );
    }
    Ok(r)
}

/// `config ...`.
fn config(c: &mut Client, op: ConfigCmd) -> CliResult {
    let source = |stored: bool| {
        if stored {
            ConfigSource::Stored
        } else {
            ConfigSource::Live
        }
    };
    match op {
        ConfigCmd::Show { stored } => {
            let r = read_record(c, source(stored))?;
            print!("{}", to_toml(&r));
        }
        ConfigCmd::Export { file, stored } => {
            let r = read_record(c, source(stored))?;
            std::fs::write(&file, to_toml(&r))
                .map_err(|e| format!("cannot write {}: {e}", file.display()))?;
            println!("wrote {}", file.display());
        }
        ConfigCmd::Save => {
            c.store(StoreOp::Save)
                .map_err(|e| config_error("config save", e))?;
            println!("saved the configuration in force");
        }
        ConfigCmd::Load => {
            c.store(StoreOp::Load)
                .map_err(|e| config_error("config load", e))?;
            println!("loaded and applied the stored record");
        }
        ConfigCmd::Erase => {
            c.store(StoreOp::Erase)
                .map_err(|e| config_error("config erase", e))?;
            println!(
                "erased the store (the configuration in force is kept; the next boot starts from the defaults)"
            );
        }
        ConfigCmd::Import { file, no_save } => import(c, &file, no_save)?,
    }
    Ok(())
}

/// `config import FILE [--no-save]`: parse and validate on the host (nothing
/// is sent for a bad file), check the PWM frequency, then send, apply and
/// (unless `no_save`) save.
fn import(c: &mut Client, file: &Path, no_save: bool) -> CliResult {
    let text = std::fs::read_to_string(file)
        .map_err(|e| format!("cannot read {}: {e}", file.display()))?;
    let r = from_toml(&text)
        .map_err(|e| format!("{}: {e} (nothing was sent to the device)", file.display()))?;
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let n = r
        .encode(&mut buf)
        .map_err(|e| format!("{}: cannot encode the record: {e:?}", file.display()))?;
    match c.param(ParamId::PwmFrequencyHz) {
        Ok(pwm) if pwm != r.pwm_frequency_hz as f32 => {
            return Err(format!(
                "{}: made for a PWM frequency of {} Hz, the drive runs at {pwm} Hz                  (the gains and watchdog periods would be wrong; nothing was sent)",
                file.display(),
                r.pwm_frequency_hz
            )
            .into())
        }
        Ok(_) | Err(ClientError::Nack(ErrorCode::Unsupported)) => {}
        Err(e) => return Err(e.into()),
    }
    c.write_config(&buf[..n])
        .map_err(|e| config_error("config import (sending the record)", e))?;
    let op = if no_save {
        StoreOp::Apply
    } else {
        StoreOp::ApplyAndSave
    };
    c.store(op).map_err(|e| config_error("config import", e))?;
    if no_save {
        println!(
            "applied {} (not saved: `foc-ctl config save` keeps it)",
            file.display()
        );
    } else {
        println!("applied and saved {}", file.display());
    }
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

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("foc-ctl: {e}");
            ExitCode::FAILURE
        }
    }
}
