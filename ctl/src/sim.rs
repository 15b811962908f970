//! A simulated device for tests and demos: the real
//! [`foc_protocol::DeviceState`] in front of [`SimDrive`], a *kinematic*
//! drive model (first-order velocity and position tracking, rigid rotor in
//! torque mode). It exercises the protocol, not the control: the motor and
//! inverter physics live in the `foc-bench` crate.
//!
//! ```no_run
//! use std::net::TcpListener;
//! let server = foc_ctl::sim::SimServer::spawn(TcpListener::bind("127.0.0.1:0")?)?;
//! let mut client = foc_ctl::Client::connect_tcp(server.addr())?;
//! client.ping()?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use foc_core::control::{Command, CommandError, Fault, FaultSet, Limits, Mode};
use foc_protocol::device::{DeviceContext, DeviceState, Refusal};
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::message::{
    Calibration, CurrentGains, ParamId, PositionGains, SpeedGains, Telemetry,
};
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Motor constants of the simulated drive.
pub const POLE_PAIRS: u8 = 7;
/// Phase resistance [ohm].
pub const R_OHM: f32 = 0.1;
/// Inductance [H].
pub const L_H: f32 = 40e-6;
/// Flux linkage [Wb].
pub const PSI_WB: f32 = 0.004;
/// PWM frequency [Hz].
pub const PWM_HZ: f32 = 20_000.0;
/// Rotor inertia [kg m^2].
pub const J_KG_M2: f32 = 1e-5;
/// Viscous friction [N m s].
pub const B_NM_S: f32 = 1e-5;
/// Time constant of velocity tracking [s].
pub const TAU_S: f32 = 0.02;
/// Time a calibration routine keeps the simulated drive busy [s].
pub const CALIBRATION_S: f32 = 0.05;

/// The kinematic drive model, a [`DeviceContext`].
#[derive(Clone, Debug)]
pub struct SimDrive {
    /// Active command.
    pub command: Command,
    /// Keep-alives received.
    pub keep_alives: u32,
    /// Latched faults.
    pub faults: FaultSet,
    /// First fault.
    pub first_fault: Option<Fault>,
    /// Limits.
    pub limits: Limits,
    /// Current gains (stored, reported; the model does not use them).
    pub current_gains: CurrentGains,
    /// Speed gains (stored).
    pub speed_gains: SpeedGains,
    /// Position gain and trajectory limits (used by the model).
    pub position_gains: PositionGains,
    /// Loop dividers.
    pub dividers: (u16, u16),
    /// Calibrated (alignment done).
    pub calibrated: bool,
    /// Remaining calibration time [s] and routine.
    pub calibrating: Option<(f32, Calibration)>,
    /// Mechanical position [rad].
    pub position_rad: f32,
    /// Mechanical velocity [rad/s].
    pub velocity_rad_s: f32,
    /// q current [A].
    pub iq_a: f32,
    /// Period counter.
    pub period: u32,
    /// Bus voltage [V].
    pub v_bus_v: f32,
}

impl Default for SimDrive {
    fn default() -> Self {
        Self {
            command: Command::Disable,
            keep_alives: 0,
            faults: FaultSet::EMPTY,
            first_fault: None,
            limits: Limits {
                max_current_a: 10.0,
                max_velocity_rad_s: 1000.0,
                min_position_rad: -1000.0,
                max_position_rad: 1000.0,
                max_open_loop_voltage_v: 12.0,
                max_open_loop_omega_e_rad_s: 5000.0,
            },
            current_gains: CurrentGains {
                kp_d: 0.4,
                ki_d: 1000.0,
                kp_q: 0.4,
                ki_q: 1000.0,
            },
            speed_gains: SpeedGains {
                kp_a_per_rad_s: 0.05,
                ki_a_per_rad: 1.0,
            },
            position_gains: PositionGains {
                kp_per_s: 20.0,
                max_velocity_rad_s: 100.0,
                max_acceleration_rad_s2: 1000.0,
            },
            dividers: (10, 20),
            calibrated: false,
            calibrating: None,
            position_rad: 0.0,
            velocity_rad_s: 0.0,
            iq_a: 0.0,
            period: 0,
            v_bus_v: 24.0,
        }
    }
}

impl SimDrive {
    /// Latch a fault as the supervisor would (bridge off).
    pub fn trip(&mut self, f: Fault) {
        self.faults.insert(f);
        self.first_fault = self.first_fault.or(Some(f));
        self.command = Command::Disable;
    }

    fn kt(&self) -> f32 {
        1.5 * POLE_PAIRS as f32 * PSI_WB
    }

    /// Advance by `periods` current-loop periods.
    pub fn advance(&mut self, periods: u32) {
        let mut left = periods;
        while left > 0 {
            let n = left.min(20); // sub-step of 1 ms at 20 kHz
            left -= n;
            self.step(n as f32 / PWM_HZ);
            self.period = self.period.wrapping_add(n);
        }
    }

    fn step(&mut self, dt: f32) {
        if let Some((t, routine)) = self.calibrating {
            let t = t - dt;
            if t <= 0.0 {
                self.calibrating = None;
                if routine == Calibration::Alignment {
                    self.calibrated = true;
                }
            } else {
                self.calibrating = Some((t, routine));
            }
        }
        let w0 = self.velocity_rad_s;
        let follow = |w: f32, target: f32| w + (target - w) * (dt / TAU_S).min(1.0);
        let w = match self.command {
            Command::Disable => follow(w0, 0.0),
            Command::Torque { iq_a } => w0 + (self.kt() * iq_a - B_NM_S * w0) / J_KG_M2 * dt,
            Command::Velocity { rad_s } => follow(w0, rad_s),
            Command::Position { rad } => {
                let g = self.position_gains;
                let w_ref = (g.kp_per_s * (rad - self.position_rad))
                    .clamp(-g.max_velocity_rad_s, g.max_velocity_rad_s);
                follow(w0, w_ref)
            }
            Command::OpenLoop { omega_e_rad_s, .. } => omega_e_rad_s / POLE_PAIRS as f32,
        };
        self.iq_a = match self.command {
            Command::Disable | Command::OpenLoop { .. } => 0.0,
            Command::Torque { iq_a } => iq_a,
            _ => (J_KG_M2 * (w - w0) / dt + B_NM_S * w) / self.kt(),
        };
        self.position_rad += 0.5 * (w0 + w) * dt;
        self.velocity_rad_s = w;
    }
}

impl DeviceContext for SimDrive {
    fn post(&mut self, cmd: Command) -> Result<(), CommandError> {
        if !self.faults.is_empty() && cmd != Command::Disable {
            return Err(CommandError::Faulted);
        }
        cmd.validate(&self.limits)?;
        self.command = cmd;
        Ok(())
    }
    fn keep_alive(&mut self) {
        self.keep_alives += 1;
    }
    fn mode(&self) -> Mode {
        self.command.mode()
    }
    fn faults(&self) -> (FaultSet, Option<Fault>) {
        (self.faults, self.first_fault)
    }
    fn clear_faults(&mut self) {
        self.faults = FaultSet::EMPTY;
        self.first_fault = None;
    }
    fn report_fault(&mut self, fault: Fault) {
        self.trip(fault);
    }
    fn limits(&self) -> Limits {
        self.limits
    }
    fn set_limits(&mut self, limits: Limits) -> Result<(), Refusal> {
        self.limits = limits;
        Ok(())
    }
    fn set_current_gains(&mut self, gains: CurrentGains) -> Result<(), Refusal> {
        self.current_gains = gains;
        Ok(())
    }
    fn set_speed_gains(&mut self, gains: SpeedGains) -> Result<(), Refusal> {
        self.speed_gains = gains;
        Ok(())
    }
    fn set_position_gains(&mut self, gains: PositionGains) -> Result<(), Refusal> {
        self.position_gains = gains;
        Ok(())
    }
    fn set_dividers(&mut self, speed: u16, position: u16) -> Result<(), Refusal> {
        self.dividers = (speed, position);
        Ok(())
    }
    fn start_calibration(&mut self, routine: Calibration) -> Result<(), Refusal> {
        if self.calibrating.is_some() {
            return Err(Refusal::Busy);
        }
        self.calibrating = Some((CALIBRATION_S, routine));
        Ok(())
    }
    fn is_calibrated(&self) -> bool {
        self.calibrated
    }
    fn param(&self, id: ParamId) -> Option<f32> {
        Some(match id {
            ParamId::PolePairs => f32::from(POLE_PAIRS),
            ParamId::ResistanceOhm => R_OHM,
            ParamId::LdH | ParamId::LqH => L_H,
            ParamId::FluxLinkageWb => PSI_WB,
            ParamId::PwmFrequencyHz => PWM_HZ,
            ParamId::SpeedDivider => f32::from(self.dividers.0),
            ParamId::PositionDivider => f32::from(self.dividers.1),
            ParamId::FirmwareVersion => 100.0,
            ParamId::BusVoltageV => self.v_bus_v,
            ParamId::Calibrated => f32::from(u8::from(self.calibrated)),
            // Not simulated; protocol-layer parameters are answered before.
            ParamId::MaxLoopCycles
            | ParamId::ProtocolVersion
            | ParamId::TelemetryDivider
            | ParamId::WatchdogTimeout => return None,
        })
    }
    fn telemetry(&self) -> Telemetry {
        let w_e = self.velocity_rad_s * POLE_PAIRS as f32;
        let (v_d, v_q) = match self.command {
            Command::Disable => (0.0, 0.0),
            Command::OpenLoop { v_d_v, v_q_v, .. } => (v_d_v, v_q_v),
            _ => (-w_e * L_H * self.iq_a, R_OHM * self.iq_a + w_e * PSI_WB),
        };
        Telemetry {
            period: self.period,
            i_d_a: 0.0,
            i_q_a: self.iq_a,
            v_d_v: v_d,
            v_q_v: v_q,
            velocity_rad_s: self.velocity_rad_s,
            position_rad: self.position_rad,
            mode: self.command.mode(),
            fault_code: self.first_fault.map_or(0, Fault::code),
            max_loop_cycles: 0,
            v_bus_v: self.v_bus_v,
        }
    }
    fn firmware_version(&self) -> [u8; 3] {
        [0, 1, 0]
    }
}

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
