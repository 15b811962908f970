//! The command line: commands, their arguments and help.

use super::*;

#[derive(Parser)]
#[command(
    name = "foc-ctl",
    version,
    about = "Command and telemetry tool for the FOC drive"
)]
pub(super) struct Cli {
    /// Connect over TCP, e.g. QEMU's `-serial tcp:127.0.0.1:4444,server,nowait`.
    #[arg(
        long,
        value_name = "HOST:PORT",
        global = true,
        conflicts_with = "serial"
    )]
    pub(super) tcp: Option<String>,
    /// Serial port of a real board, e.g. /dev/ttyACM0.
    #[arg(long, value_name = "PATH", global = true)]
    pub(super) serial: Option<String>,
    /// Serial baud rate.
    #[arg(long, default_value_t = 115_200, global = true)]
    pub(super) baud: u32,
    /// Reply timeout per attempt \[ms\].
    #[arg(long, default_value_t = 250, global = true)]
    pub(super) timeout_ms: u64,
    /// Retransmissions after the first attempt.
    #[arg(long, default_value_t = 3, global = true)]
    pub(super) retries: u32,
    /// Reply timeout per attempt of flash operations (`config save|load|erase|import`,
    /// reads of the stored record) \[ms\]: an erase stalls a board for seconds.
    #[arg(long, default_value_t = 10000, global = true)]
    pub(super) store_timeout_ms: u64,
    #[command(subcommand)]
    pub(super) cmd: Cmd,
}

#[derive(Subcommand)]
pub(super) enum Cmd {
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
        /// Interval \[ms\].
        #[arg(long, default_value_t = 100)]
        interval_ms: u64,
        /// How long \[ms\].
        #[arg(long = "duration-ms", default_value_t = 10_000.0)]
        duration_ms: f64,
    },
    /// Clear latched faults.
    Clear,
    /// Show latched faults.
    Faults,
    /// Read a parameter (`all` for every one), or write one: the
    /// d-current reference's (design §30) `field-weakening`, `mtpa`,
    /// `short-circuit` (on/off, 1/0) and `max-id` (A), the tables'
    /// switches `anticogging` and `encoder-linearisation` (on/off; design
    /// §32, §33), only while disabled.
    Param {
        /// pole-pairs, r, ld, lq, psi, pwm-frequency, speed-divider,
        /// position-divider, firmware-version, protocol-version, bus-voltage,
        /// calibrated, max-loop-cycles, telemetry-divider, watchdog-timeout,
        /// field-weakening, mtpa, max-id, short-circuit, anticogging,
        /// encoder-linearisation, anticogging-peak, encoder-correction-peak,
        /// ... (`param all` lists them), all
        name: String,
        /// A new value (writable parameters only): a number in the
        /// parameter's unit, or on/off for a switch.
        #[arg(allow_hyphen_values = true)]
        value: Option<String>,
    },
    /// Stream telemetry.
    Telemetry {
        /// Rate \[Hz\] (converted by the device to whole current-loop periods).
        #[arg(long, default_value_t = 100.0, conflicts_with = "every")]
        rate: f64,
        /// Instead of a rate: one sample every K current-loop periods.
        #[arg(long, value_name = "K")]
        every: Option<u32>,
        /// How long \[ms\].
        #[arg(long = "duration-ms", default_value_t = 5000.0)]
        duration_ms: f64,
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
    /// The motor's command limits (rotor frame): change the ones given,
    /// keep the others; without options, show them.
    Limits(LimitsArgs),
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
    /// Link watchdog: the reaction after TIMEOUT_MS without a request
    /// (0 = off).
    Watchdog {
        /// Timeout \[ms\] (converted to whole PWM periods).
        #[arg(value_name = "TIMEOUT_MS")]
        after_ms: f64,
        /// Reaction.
        #[arg(value_enum, default_value_t = Reaction::Disable)]
        reaction: Reaction,
    },
    /// Run a calibration routine and wait for its end, showing each step
    /// and the result (the identification: the motor's values and the
    /// loops' gains; a failure: its reason and what to do).
    Calibrate {
        /// Routine.
        #[arg(value_enum)]
        routine: Routine,
        /// Return once the drive has taken the request.
        #[arg(long)]
        no_wait: bool,
        /// Longest wait \[ms\] (the identification of a large motor takes a
        /// minute).
        #[arg(long = "wait-ms", default_value_t = 180_000.0)]
        wait_ms: f64,
    },
    /// Identify the motor (as `calibrate identification`): wait for the end,
    /// showing each step, then the motor's values and the loops' gains.
    Identify {
        /// Return once the drive has taken the request.
        #[arg(long)]
        no_wait: bool,
        /// Longest wait \[ms\].
        #[arg(long = "wait-ms", default_value_t = 180_000.0)]
        wait_ms: f64,
    },
    /// The drive's configuration record: show, save, load, erase, export, import.
    Config {
        #[command(subcommand)]
        op: ConfigCmd,
    },
    /// Serve a simulated drive on a TCP address: the real drive (foc-core's
    /// control, identification included) on the bench's motor and inverter
    /// model, in real time; several clients at once. It starts as a board
    /// powers up: uncalibrated until `calibrate identification`.
    Simulate(SimulateArgs),
    /// A live web page for the drive: plots of any telemetry signal,
    /// status and faults (what each means, what to do), a console for any
    /// foc-ctl command, and a setup wizard (offsets, sensor check,
    /// identification, tuning report, save). With `--simulate`, on the
    /// simulated drive.
    Dashboard(DashboardArgs),
}

/// `limits`' options: each one given replaces that limit.
#[derive(clap::Args)]
pub(super) struct LimitsArgs {
    /// Current limit \[A\].
    #[arg(long)]
    pub(super) max_current: Option<f32>,
    /// Velocity limit [rad/s].
    #[arg(long)]
    pub(super) max_velocity: Option<f32>,
    /// Lowest position \[rad\].
    #[arg(long, allow_hyphen_values = true)]
    pub(super) min_position: Option<f32>,
    /// Highest position \[rad\].
    #[arg(long, allow_hyphen_values = true)]
    pub(super) max_position: Option<f32>,
    /// Open-loop voltage limit \[V\].
    #[arg(long)]
    pub(super) max_ol_voltage: Option<f32>,
    /// Open-loop electrical speed limit [rad/s].
    #[arg(long)]
    pub(super) max_ol_omega_e: Option<f32>,
    /// Largest impedance stiffness [N m/rad, rotor].
    #[arg(long, allow_hyphen_values = true)]
    pub(super) max_kp: Option<f32>,
    /// Largest impedance damping [N m s/rad, rotor].
    #[arg(long, allow_hyphen_values = true)]
    pub(super) max_kd: Option<f32>,
}

impl LimitsArgs {
    /// `l` with the given limits replaced; `None` when none is given.
    pub(super) fn apply(&self, l: Limits) -> Option<Limits> {
        let given = [
            self.max_current,
            self.max_velocity,
            self.min_position,
            self.max_position,
            self.max_ol_voltage,
            self.max_ol_omega_e,
            self.max_kp,
            self.max_kd,
        ];
        if given.iter().all(Option::is_none) {
            return None;
        }
        Some(Limits {
            max_current_a: self.max_current.unwrap_or(l.max_current_a),
            max_velocity_rad_s: self.max_velocity.unwrap_or(l.max_velocity_rad_s),
            min_position_rad: self.min_position.unwrap_or(l.min_position_rad),
            max_position_rad: self.max_position.unwrap_or(l.max_position_rad),
            max_open_loop_voltage_v: self.max_ol_voltage.unwrap_or(l.max_open_loop_voltage_v),
            max_open_loop_omega_e_rad_s: self
                .max_ol_omega_e
                .unwrap_or(l.max_open_loop_omega_e_rad_s),
            max_kp_nm_per_rad: self.max_kp.unwrap_or(l.max_kp_nm_per_rad),
            max_kd_nm_s_per_rad: self.max_kd.unwrap_or(l.max_kd_nm_s_per_rad),
        })
    }
}

/// `dashboard`'s options.
#[derive(clap::Args)]
pub(super) struct DashboardArgs {
    /// Address the page is served on (open it in a browser).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub(super) listen: String,
    /// Run the simulated drive (as `foc-ctl simulate`) instead of
    /// connecting with --tcp or --serial.
    #[arg(long)]
    pub(super) simulate: bool,
    /// With --simulate: the motor file to simulate.
    #[arg(long, requires = "simulate")]
    pub(super) motor: Option<std::path::PathBuf>,
    /// With --simulate: simulated seconds per real second.
    #[arg(long, default_value_t = 1.0, requires = "simulate")]
    pub(super) time_scale: f64,
    /// Telemetry rate the page plots \[Hz\] (changeable on the page; a
    /// board's 115200-baud UART carries at most 192 Hz).
    #[arg(long, default_value_t = 100.0)]
    pub(super) rate: f32,
}

/// `simulate`'s options.
#[derive(clap::Args)]
pub(super) struct SimulateArgs {
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:4444")]
    pub(super) listen: String,
    /// Motor file (tests/motors/*.toml) to simulate (default: the
    /// emulated board's motor, as in QEMU).
    #[arg(long)]
    pub(super) motor: Option<std::path::PathBuf>,
    /// Simulated seconds per real second (default 1: real time; a
    /// machine too slow for the pace slows the simulation down).
    #[arg(long, default_value_t = 1.0)]
    pub(super) time_scale: f64,
    /// Start calibrated from the model's exact values, as after an
    /// identification (skips its few seconds; for trying the tool).
    #[arg(long)]
    pub(super) calibrated: bool,
    /// Mechanical end stops of the simulated rotor [rad, rotor] (to try
    /// `home end-stop`).
    #[arg(long, num_args = 2, value_names = ["LOW", "HIGH"], allow_hyphen_values = true)]
    pub(super) end_stops: Option<Vec<f32>>,
}

#[derive(clap::Args)]
pub(super) struct JointArgs {
    /// Rotor turns per output turn; negative when the output turns the other way.
    #[arg(long, allow_hyphen_values = true)]
    pub(super) gear_ratio: Option<f32>,
    /// Home offset: the rotor position where the output reads 0 [rad, rotor].
    #[arg(long, allow_hyphen_values = true)]
    pub(super) offset: Option<f32>,
    /// Travel range at the output [rad, output] (soft stop at its ends).
    #[arg(long, num_args = 2, value_names = ["MIN", "MAX"], allow_hyphen_values = true, conflicts_with = "no_travel")]
    pub(super) travel: Option<Vec<f32>>,
    /// Remove the travel range (the motor's position range applies).
    #[arg(long)]
    pub(super) no_travel: bool,
    /// Fault (TravelLimit) beyond the travel range by more than this [rad, rotor].
    #[arg(long, allow_hyphen_values = true)]
    pub(super) fault_margin: Option<f32>,
    /// Soft stop's deceleration [rad/s^2, rotor].
    #[arg(long, allow_hyphen_values = true)]
    pub(super) brake_accel: Option<f32>,
    /// Soft stop's velocity gain [A/(rad/s), rotor].
    #[arg(long, allow_hyphen_values = true)]
    pub(super) kv: Option<f32>,
    /// Impedance entry blend [current-loop periods].
    #[arg(long)]
    pub(super) entry_blend: Option<u32>,
    /// Least damping after an impedance command times out [N m s/rad, rotor].
    #[arg(long, allow_hyphen_values = true)]
    pub(super) timeout_kd: Option<f32>,
}

#[derive(Subcommand)]
pub(super) enum HomeCmd {
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
        /// Homing current \[A\]: the most the stop is pressed with.
        #[arg(long, allow_hyphen_values = true)]
        current: f32,
        /// Share of the homing current, held with the joint still, that
        /// means the stop is reached.
        #[arg(long, allow_hyphen_values = true, default_value_t = 0.7)]
        detect: f32,
        /// How long the stop must be held \[ms\].
        #[arg(
            long = "confirm-ms",
            allow_hyphen_values = true,
            default_value_t = 50.0
        )]
        confirm_ms: f32,
        /// Distance to back off from the stop [rad, output].
        #[arg(long, allow_hyphen_values = true)]
        backoff: f32,
        /// Longest search before giving up [rad, output].
        #[arg(long, allow_hyphen_values = true)]
        max_travel: f32,
        /// The output position the stop reads [rad, output].
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        at: f32,
        /// Longest wait for the result \[ms\].
        #[arg(long = "wait-ms", default_value_t = 60_000.0)]
        wait_ms: f64,
    },
}

impl HomeCmd {
    /// The request (output frame) and the longest wait for its result \[s\].
    pub(super) fn request(self) -> (HomingStart, f64) {
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
                confirm_ms,
                backoff,
                max_travel,
                at,
                wait_ms,
            } => (
                HomingStart {
                    method: HomingMethod::EndStop(EndStop {
                        velocity_rad_s: velocity,
                        current_a: current,
                        detect_fraction: detect,
                        confirm_s: confirm_ms * 1e-3,
                        backoff_rad: backoff,
                        max_travel_rad: max_travel,
                    }),
                    home_output_rad: at,
                },
                wait_ms * 1e-3,
            ),
        }
    }
}

#[derive(Subcommand)]
pub(super) enum ModeCmd {
    /// Bridge off.
    Disable,
    /// Torque: q current \[A\].
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
    /// Open-loop dq voltage \[V\] at an electrical angle, rotating at omega_e.
    OpenLoop {
        #[arg(allow_hyphen_values = true)]
        v_d: f32,
        #[arg(allow_hyphen_values = true)]
        v_q: f32,
        /// Starting electrical angle \[deg\].
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        theta_deg: f32,
        /// Electrical speed [rad/s].
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        omega_e: f32,
    },
}

#[derive(Subcommand)]
pub(super) enum GainsCmd {
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
pub(super) enum ConfigCmd {
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
pub(super) enum Reaction {
    Disable,
    Stop,
    Hold,
}

#[derive(Clone, Copy, ValueEnum)]
pub(super) enum Routine {
    /// The current sensors' offsets (bridge off).
    Offsets,
    /// The motor's identification (resistance, inductances, alignment,
    /// flux linkage, mechanics, gains).
    Identification,
    /// Part of the identification (refused alone).
    Alignment,
    /// The anticogging map (design §32): a slow sweep both ways on the
    /// closed loop, about 24 s; then switched on. Needs a calibrated
    /// drive on a fine angle sensor; `config save` keeps it.
    Cogging,
    /// Encoder linearisation (design §33): the angle sensor's error,
    /// learnt turning at a constant speed both ways, about 6 s; then
    /// switched on. Needs a calibrated drive on a fine angle sensor;
    /// `config save` keeps it.
    Encoder,
}
