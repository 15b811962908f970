//! A simulated device for tests and demos: the real
//! [`foc_protocol::DeviceState`] in front of [`SimDrive`], a *kinematic*
//! drive model (first-order velocity and position tracking, rigid rotor in
//! torque mode). It exercises the protocol, not the control: the motor and
//! inverter physics live in the `foc-bench` crate.
//!
//! Robot joints (design §21): the joint in force is the settings' `joint`
//! (`SetJoint` replaces it; the travel range narrows the position range
//! commands are checked against); impedance mode is a spring-damper on a
//! rigid rotor integrated every current-loop period; leaving the travel
//! range by more than its margin trips `TravelLimit` (there is no soft stop
//! in this model); [`SimDrive::stops_rad`] are mechanical end stops to home
//! against (none by default). Homing itself is the protocol's
//! ([`foc_protocol::DeviceState`] runs it in `poll`), as on a board.
//!
//! The link's rules are the firmware's: [`foc_service`]'s, with this
//! model's board facts ([`sim_board`]: a 10 A hardware limit, identification
//! on command, alignment only as part of it). Its configuration is the
//! service's [`foc_store::Settings`] (limits, motor, gains, dividers,
//! calibrated flag: what the drive reports and checks commands against),
//! kept in a [`foc_store::Store`] over a RAM flash ([`SimFlash`]) that lives
//! as long as the drive model, so the `config` commands (read, save, load,
//! erase, apply) work as on a board.
//!
//! ```no_run
//! use std::net::TcpListener;
//! let server = foc_ctl::sim::SimServer::spawn(TcpListener::bind("127.0.0.1:0")?)?;
//! let mut client = foc_ctl::Client::connect_tcp(server.addr())?;
//! client.ping()?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use foc_core::calibration::identification::IdentificationResult;
use foc_core::calibration::Calibrated;
use foc_core::control::joint::Impedance;
use foc_core::control::{Command, Fault, FaultSet, Feedback, Limits, MotorParams};
use foc_core::drive::cascade::CascadeConfig;
use foc_core::drive::Status;
use foc_core::frames::Dq;
use foc_core::scope::{Scope, State};
use foc_protocol::device::{DeviceState, WatchdogConfig};
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::joint::limits_in_force;
use foc_protocol::message::Calibration;
use foc_service::{Board, Identified, Link, Outbox, Pending, Service, Snapshot};
use foc_store::fake::FakeFlash;
use foc_store::{DriveRecord, Label, Settings, Store};
use std::fmt;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Motor constants of the simulated drive.
pub const POLE_PAIRS: u8 = 7;
/// Phase resistance \[ohm\].
pub const R_OHM: f32 = 0.1;
/// Inductance \[H\].
pub const L_H: f32 = 40e-6;
/// Flux linkage \[Wb\].
pub const PSI_WB: f32 = 0.004;
/// PWM frequency \[Hz\].
pub const PWM_HZ: f32 = 20_000.0;
/// PWM frequency as the configuration record carries it \[Hz\].
pub const PWM_HZ_RECORD: u32 = 20_000;
/// Current limit of the default configuration \[A\].
pub const MAX_CURRENT_A: f32 = 10.0;
/// Label of the default configuration.
pub const DEFAULT_LABEL: &str = "simulated drive";
/// Rotor inertia [kg m^2].
pub const J_KG_M2: f32 = 1e-5;
/// Viscous friction [N m s].
pub const B_NM_S: f32 = 1e-5;
/// Time constant of velocity tracking \[s\].
pub const TAU_S: f32 = 0.02;
/// Time a calibration routine keeps the simulated drive busy \[s\].
pub const CALIBRATION_S: f32 = 0.05;

/// The simulated configuration flash: 4 pages of 1 KiB, 4-byte words.
pub type SimFlash = FakeFlash<4, 1024, 4>;

/// Bytes of [`SimFlash`] the store uses (all of it).
const SIM_FLASH_BYTES: u32 = 4 * 1024;

/// The default configuration of the simulated motor: foc-core's
/// [`CascadeConfig::for_motor`] for the constants above, with the sim's
/// command limits; uncalibrated.
pub fn default_settings() -> Settings {
    let motor = MotorParams {
        pole_pairs: POLE_PAIRS,
        r_ohm: R_OHM,
        ld_h: L_H,
        lq_h: L_H,
        flux_linkage_wb: PSI_WB,
    };
    let mut s = Settings::from_cascade(&CascadeConfig::for_motor(motor, PWM_HZ, MAX_CURRENT_A));
    s.limits = Limits {
        max_current_a: MAX_CURRENT_A,
        max_velocity_rad_s: 1000.0,
        min_position_rad: -1000.0,
        max_position_rad: 1000.0,
        max_open_loop_voltage_v: 12.0,
        max_open_loop_omega_e_rad_s: 5000.0,
        // The cascade's: full current for 0.01 rad or 1 rad/s of error.
        ..s.limits
    };
    s.calibrated = false;
    s
}

/// The simulated board's facts for the link's rules ([`foc_service`]):
/// [`default_settings`] as the build-time settings, a hardware current
/// limit of [`MAX_CURRENT_A`] (limits above it are refused, as on a
/// board), an exact angle (a stored calibration stays right across a
/// restart), identification on command, the scope's [`SCOPE_VALUES`].
pub fn sim_board() -> Board {
    let motor = default_settings().current.motor;
    let mut b = Board::new(
        CascadeConfig::for_motor(motor, PWM_HZ, MAX_CURRENT_A),
        PWM_HZ_RECORD,
        MAX_CURRENT_A,
    );
    b.base = default_settings();
    b.zero_survives_reset = true;
    b.firmware_version = FIRMWARE_VERSION;
    b.scope_values = SCOPE_VALUES as u32;
    b
}

/// Version the simulated drive reports.
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];

/// The kinematic drive model, a [`DeviceContext`](foc_protocol::DeviceContext) through the service's
/// link ([`foc_service::Link`], the firmware's rules): each request sees
/// the model now and its outbox is committed at once (a command re-checked
/// by the model as the drive re-checks its mailbox, a calibration started,
/// a fault latched; the configuration is the service's, which the model
/// reads every step).
pub struct SimDrive {
    /// Active command.
    pub command: Command,
    /// Latched faults.
    pub faults: FaultSet,
    /// First fault.
    pub first_fault: Option<Fault>,
    /// The link's rules and the configuration in force: limits (commands
    /// are checked against them), motor (reported as parameters, used by
    /// the model), gains (position gains used by the model, the others
    /// stored and reported), dividers, and the calibrated flag (an
    /// identification done or a calibrated record applied).
    pub service: Service,
    /// The configuration store; `None`: a device without one (the `config`
    /// requests answer `Unsupported`).
    pub store: Option<Store<SimFlash>>,
    /// Remaining calibration time \[s\] and routine.
    pub calibrating: Option<(f32, Calibration)>,
    /// Identifications finished.
    identifications: u32,
    /// Mechanical position \[rad\].
    pub position_rad: f32,
    /// Mechanical velocity [rad/s].
    pub velocity_rad_s: f32,
    /// q current \[A\].
    pub iq_a: f32,
    /// Period counter.
    pub period: u32,
    /// Bus voltage \[V\].
    pub v_bus_v: f32,
    /// The impedance law's position reference [rad, rotor] (advanced with
    /// the command's velocity).
    pub impedance_ref_rad: f32,
    /// Mechanical end stops `(low, high)` [rad, rotor]: the rotor stops
    /// dead there (infinite: none).
    pub stops_rad: (f32, f32),
    /// The scope (design §22), [`SCOPE_VALUES`] values, recorded every
    /// period while armed (the model then steps period by period).
    pub scope: Scope<Vec<f32>>,
}

/// Values the simulated scope holds (as the firmware's).
pub const SCOPE_VALUES: usize = 4096;

impl Default for SimDrive {
    fn default() -> Self {
        let mut service = Service::new(sim_board());
        service.set_label(Label::try_from(DEFAULT_LABEL).unwrap_or_default());
        Self {
            command: Command::Disable,
            faults: FaultSet::EMPTY,
            first_fault: None,
            service,
            // An empty, erased flash.
            store: Store::new(SimFlash::new(), 0..SIM_FLASH_BYTES).ok(),
            calibrating: None,
            identifications: 0,
            position_rad: 0.0,
            velocity_rad_s: 0.0,
            iq_a: 0.0,
            period: 0,
            v_bus_v: 24.0,
            impedance_ref_rad: 0.0,
            stops_rad: (f32::NEG_INFINITY, f32::INFINITY),
            scope: Scope::new(vec![0.0; SCOPE_VALUES]),
        }
    }
}

impl fmt::Debug for SimDrive {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SimDrive")
            .field("command", &self.command)
            .field("faults", &self.faults)
            .field("first_fault", &self.first_fault)
            .field("settings", self.settings())
            .field("label", self.service.label())
            .field("store", &self.store.as_ref().map(|_| "SimFlash"))
            .field("calibrating", &self.calibrating)
            .field("position_rad", &self.position_rad)
            .field("velocity_rad_s", &self.velocity_rad_s)
            .field("iq_a", &self.iq_a)
            .field("period", &self.period)
            .field("v_bus_v", &self.v_bus_v)
            .field("impedance_ref_rad", &self.impedance_ref_rad)
            .field("stops_rad", &self.stops_rad)
            .finish()
    }
}

impl SimDrive {
    /// The configuration in force.
    pub fn settings(&self) -> &Settings {
        self.service.settings()
    }

    /// The record of the configuration in force, with `link` (the
    /// link-watchdog setting in force) as its watchdog.
    pub fn live_record(&self, link: WatchdogConfig) -> DriveRecord {
        self.service.live_record(link)
    }

    /// Finish an identification: the model measures its own constants
    /// exactly, and the service takes them as the firmware's does an
    /// identification's result (calibrated from now on).
    pub fn identify_now(&mut self) {
        let s = *self.settings();
        let m = s.current.motor;
        let Ok(permit) = Calibrated::supplied(s.angle, s.current) else {
            return;
        };
        self.identifications = self.identifications.wrapping_add(1);
        self.service.fold_identification(Some(Identified {
            result: IdentificationResult {
                r_ohm: m.r_ohm,
                ld_h: m.ld_h,
                lq_h: m.lq_h,
                flux_linkage_wb: m.flux_linkage_wb,
                mechanics: None,
                angle: s.angle,
                pole_pairs: m.pole_pairs,
            },
            permit,
            count: self.identifications,
        }));
    }

    /// The model now, as the link sees it.
    fn snapshot(&self) -> Snapshot {
        let feedback = self.sim_feedback();
        Snapshot {
            feedback,
            max_loop_cycles: 0,
            status: Status {
                running: self.calibrating.is_none(),
                mode: feedback.mode,
                faulted: !self.faults.is_empty(),
                // A calibration made without the sensor holds only while
                // the drive runs sensorless (design §29).
                calibrated: self.settings().calibrated
                    && (!self.settings().angle.sensorless_only
                        || self.settings().sensorless.is_some()),
                sensorless: self.settings().sensorless.is_some(),
                // The kinematic model has no saliency to inject on.
                injection: false,
            },
            identified: None,
            pending: Pending {
                command: self.command,
                calibration: self.calibrating.is_some(),
            },
        }
    }

    /// The snapshot and the service (the link's read-only calls).
    pub fn view_parts(&self) -> (Snapshot, &Service) {
        (self.snapshot(), &self.service)
    }

    /// Run `f` on a link to the model now and commit its outbox.
    pub fn with_link<R>(&mut self, f: impl FnOnce(&mut Link<'_, Store<SimFlash>>) -> R) -> R {
        let snap = self.snapshot();
        let mut link = self
            .service
            .link(snap, self.store.as_mut(), None, WatchdogConfig::OFF);
        let r = f(&mut link);
        let out = link.out;
        self.commit(&out);
        r
    }

    /// An outbox into the model: the clear first, then the command (the
    /// drive's own checks: only `Disable` while faulted, the limits in
    /// force), a fault to latch, a calibration to run.
    fn commit(&mut self, out: &Outbox) {
        if out.clear {
            self.faults = FaultSet::EMPTY;
            self.first_fault = None;
        }
        if let Some(cmd) = out.post {
            self.take_command(cmd);
        }
        let Some(change) = out.config.current else {
            return;
        };
        if let Some(f) = change.fault {
            self.trip(f);
        }
        if self.calibrating.is_none() {
            if change.identify {
                self.calibrating = Some((CALIBRATION_S, Calibration::Identification));
            } else if change.calibrate_offsets {
                self.calibrating = Some((CALIBRATION_S, Calibration::Offsets));
            }
        }
    }

    /// The drive's checks of a posted command (the protocol checked it
    /// against the same state before).
    fn take_command(&mut self, cmd: Command) {
        if !self.faults.is_empty() && cmd != Command::Disable {
            return;
        }
        if cmd.validate(&self.limits_in_force()).is_err() {
            return;
        }
        if let Command::Impedance(i) = cmd {
            self.impedance_ref_rad = i.position_rad;
        }
        self.command = cmd;
    }

    /// Latch a fault as the supervisor would (bridge off).
    pub fn trip(&mut self, f: Fault) {
        self.faults.insert(f);
        self.first_fault = self.first_fault.or(Some(f));
        self.command = Command::Disable;
    }

    fn kt(&self) -> f32 {
        self.settings().current.motor.torque_constant_nm_per_a()
    }

    fn pole_pairs(&self) -> f32 {
        f32::from(self.settings().current.motor.pole_pairs.max(1))
    }

    /// The limits commands are checked against: the motor's, with the
    /// joint's travel range (rotor frame).
    pub fn limits_in_force(&self) -> Limits {
        limits_in_force(&self.settings().limits, &self.settings().joint)
    }

    /// Advance by `periods` current-loop periods.
    pub fn advance(&mut self, periods: u32) {
        let mut left = periods;
        while left > 0 {
            // Sub-steps of 1 ms at 20 kHz; impedance (a stiff spring on a
            // light rotor) and an armed scope every period.
            let recording = matches!(self.scope.status().state, State::Armed | State::Triggered);
            let n = match self.command {
                Command::Impedance(_) => 1,
                _ if recording => 1,
                _ => left.min(20),
            };
            left -= n;
            if recording {
                // As the firmware's: the period's command with what was
                // measured at its start.
                let fb = self.sim_feedback();
                self.scope.record(&fb);
            }
            self.step(n as f32 / PWM_HZ);
            self.period = self.period.wrapping_add(n);
        }
    }

    /// The impedance law's torque [N m] (within its torque limit and the
    /// current limit), its reference advanced by `dt`.
    fn impedance_torque(&mut self, c: &Impedance, dt: f32) -> f32 {
        let t_max = c
            .torque_limit_nm
            .min(self.kt() * self.settings().limits.max_current_a);
        let t = c.kp_nm_per_rad * (self.impedance_ref_rad - self.position_rad)
            + c.kd_nm_s_per_rad * (c.velocity_rad_s - self.velocity_rad_s)
            + c.torque_ff_nm;
        let l = self.limits_in_force();
        self.impedance_ref_rad = foc_core::clamp(
            self.impedance_ref_rad + c.velocity_rad_s * dt,
            l.min_position_rad,
            l.max_position_rad,
        );
        foc_core::clamp(t, -t_max, t_max)
    }

    /// The end stops: the rotor stops dead at either.
    fn apply_stops(&mut self) {
        let (lo, hi) = self.stops_rad;
        if self.position_rad < lo {
            self.position_rad = lo;
            self.velocity_rad_s = self.velocity_rad_s.max(0.0);
        }
        if self.position_rad > hi {
            self.position_rad = hi;
            self.velocity_rad_s = self.velocity_rad_s.min(0.0);
        }
    }

    /// Beyond the travel range by more than its margin with the bridge on:
    /// `TravelLimit`.
    fn check_travel(&mut self) {
        let j = &self.settings().joint;
        if j.travel_out_rad.is_none() || self.command == Command::Disable {
            return;
        }
        let l = self.limits_in_force();
        let m = j.travel.fault_margin_rad;
        let p = self.position_rad;
        if p > l.max_position_rad + m || p < l.min_position_rad - m {
            self.trip(Fault::TravelLimit);
        }
    }

    /// The model's feedback (rotor frame): the model's state, the active
    /// command, the faults, the q current and its reference, the voltages
    /// a current loop would apply (back-EMF and resistive drop).
    pub fn sim_feedback(&self) -> Feedback {
        let m = &self.settings().current.motor;
        let w_e = self.velocity_rad_s * self.pole_pairs();
        let (v_d, v_q) = match self.command {
            Command::Disable => (0.0, 0.0),
            Command::OpenLoop { v_d_v, v_q_v, .. } => (v_d_v, v_q_v),
            _ => (
                -w_e * m.lq_h * self.iq_a,
                m.r_ohm * self.iq_a + w_e * m.flux_linkage_wb,
            ),
        };
        let mut fb = Feedback::INIT;
        fb.period = self.period;
        fb.mode = self.command.mode();
        fb.active = self.command;
        fb.position_rad = self.position_rad;
        fb.velocity_rad_s = self.velocity_rad_s;
        fb.i_dq_a = Dq::new(0.0, self.iq_a);
        fb.i_dq_ref_a.q = match self.command {
            Command::Torque { iq_a } => iq_a,
            _ => self.iq_a,
        };
        fb.v_dq_v = Dq::new(v_d, v_q);
        fb.v_bus_v = self.v_bus_v;
        fb.faults = self.faults;
        fb.first_fault = self.first_fault;
        fb
    }

    /// The q current after `dt` towards `iq_ref` \[A\]: the current loop as
    /// a first-order lag of time constant `L / kp` (a PI whose zero
    /// cancels the winding's pole, design §11).
    fn current_lag(&self, iq_ref: f32, dt: f32) -> f32 {
        let kp = self.settings().current.q_gains.kp_v_per_a;
        let l = self.settings().current.motor.lq_h;
        if !(kp > 0.0 && l > 0.0) {
            return iq_ref;
        }
        let a = 1.0 - (-dt * kp / l).exp();
        self.iq_a + (iq_ref - self.iq_a) * a
    }

    fn step(&mut self, dt: f32) {
        if let Some((t, routine)) = self.calibrating {
            let t = t - dt;
            if t <= 0.0 {
                self.calibrating = None;
                if routine == Calibration::Identification {
                    self.identify_now();
                }
            } else {
                self.calibrating = Some((t, routine));
            }
        }
        let w0 = self.velocity_rad_s;
        if let Command::Impedance(c) = self.command {
            let t = self.impedance_torque(&c, dt);
            self.iq_a = t / self.kt();
            self.velocity_rad_s = w0 + (t - B_NM_S * w0) / J_KG_M2 * dt;
            self.position_rad += self.velocity_rad_s * dt;
            self.apply_stops();
            self.check_travel();
            return;
        }
        let follow = |w: f32, target: f32| w + (target - w) * (dt / TAU_S).min(1.0);
        let w = match self.command {
            Command::Disable => follow(w0, 0.0),
            Command::Torque { iq_a } => {
                let iq = self.current_lag(iq_a, dt);
                w0 + (self.kt() * iq - B_NM_S * w0) / J_KG_M2 * dt
            }
            Command::Velocity { rad_s } => follow(w0, rad_s),
            Command::Position { rad } => {
                let g = self.settings().position;
                let w_ref = (g.kp_per_s * (rad - self.position_rad))
                    .clamp(-g.max_velocity_rad_s, g.max_velocity_rad_s);
                follow(w0, w_ref)
            }
            Command::OpenLoop { omega_e_rad_s, .. } => omega_e_rad_s / self.pole_pairs(),
            // Stepped above.
            Command::Impedance(_) => w0,
        };
        self.iq_a = match self.command {
            Command::Disable | Command::OpenLoop { .. } => 0.0,
            Command::Torque { iq_a } => self.current_lag(iq_a, dt),
            _ => (J_KG_M2 * (w - w0) / dt + B_NM_S * w) / self.kt(),
        };
        self.position_rad += 0.5 * (w0 + w) * dt;
        self.velocity_rad_s = w;
        self.apply_stops();
        self.check_travel();
    }
}

foc_service::forward_device_context!(SimDrive, scope: scope);

/// The simulated device: protocol state, decoder and drive.
#[derive(Debug, Default)]
pub struct SimDevice {
    /// The drive model.
    pub drive: SimDrive,
    /// The protocol state.
    pub state: DeviceState,
    decoder: FrameDecoder,
}

impl SimDevice {
    /// Handle received bytes; append the encoded replies to `out`.
    pub fn receive(&mut self, bytes: &[u8], out: &mut Vec<u8>) {
        let mut tx = [0u8; MAX_FRAME];
        for &b in bytes {
            if let Some(n) = self
                .state
                .on_byte(&mut self.drive, &mut self.decoder, b, &mut tx)
            {
                out.extend_from_slice(&tx[..n]);
            }
        }
    }
    /// Advance the model and run the watchdog / telemetry; append streamed
    /// frames to `out`.
    pub fn advance(&mut self, periods: u32, out: &mut Vec<u8>) {
        self.drive.advance(periods);
        let mut tx = [0u8; MAX_FRAME];
        let now = self.drive.period;
        if let Some((seq, r)) = self.state.poll(&mut self.drive, now) {
            if let Ok(n) = encode(seq, &r, &mut tx) {
                out.extend_from_slice(&tx[..n]);
            }
        }
    }
}

/// Turns real time into whole current-loop periods.
#[derive(Debug)]
struct Clock {
    last: Instant,
    carry: f64,
}

impl Clock {
    fn new() -> Self {
        Self {
            last: Instant::now(),
            carry: 0.0,
        }
    }
    /// Whole periods since the last call (fractions carried over).
    fn periods(&mut self) -> u32 {
        let now = Instant::now();
        self.carry += now.duration_since(self.last).as_secs_f64() * f64::from(PWM_HZ);
        self.last = now;
        let periods = self.carry.floor().min(f64::from(u32::MAX));
        self.carry -= periods;
        periods as u32
    }
}

fn serve_connection(
    mut stream: TcpStream,
    dev: &mut SimDevice,
    clock: &mut Clock,
    stop: &AtomicBool,
) -> io::Result<()> {
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(Duration::from_micros(500)))?;
    let mut buf = [0u8; 512];
    let mut out = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        match stream.read(&mut buf) {
            Ok(0) => return Ok(()),
            Ok(n) => dev.receive(&buf[..n], &mut out),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock
                        | io::ErrorKind::TimedOut
                        | io::ErrorKind::Interrupted
                ) => {}
            Err(e) => return Err(e),
        }
        dev.advance(clock.periods(), &mut out);
        if !out.is_empty() {
            stream.write_all(&out)?;
            out.clear();
        }
    }
    Ok(())
}

/// A simulated device served on a TCP listener (one connection at a time,
/// the device state kept across connections) in a background thread.
pub struct SimServer {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<SimDevice>>,
}

impl SimServer {
    /// Serve a fresh [`SimDevice`].
    pub fn spawn(listener: TcpListener) -> io::Result<Self> {
        Self::spawn_with(listener, SimDevice::default())
    }

    /// Serve `dev`.
    pub fn spawn_with(listener: TcpListener, mut dev: SimDevice) -> io::Result<Self> {
        let addr = listener.local_addr()?;
        listener.set_nonblocking(true)?;
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut clock = Clock::new();
            let mut discard = Vec::new();
            while !flag.load(Ordering::Relaxed) {
                match listener.accept() {
                    Ok((s, _)) => {
                        let _ = s.set_nonblocking(false);
                        // A connection error ends that connection only.
                        let _ = serve_connection(s, &mut dev, &mut clock, &flag);
                    }
                    Err(_) => {
                        // Time goes on without a host (streamed frames are lost).
                        std::thread::sleep(Duration::from_millis(2));
                        dev.advance(clock.periods(), &mut discard);
                        discard.clear();
                    }
                }
            }
            dev
        });
        Ok(Self {
            addr,
            stop,
            thread: Some(thread),
        })
    }

    /// The address to connect to.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Stop serving and return the device (for inspection).
    pub fn stop(mut self) -> Option<SimDevice> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.take().and_then(|t| t.join().ok())
    }

    /// Serve until the process ends (for `foc-ctl simulate`).
    pub fn wait(mut self) {
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for SimServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
