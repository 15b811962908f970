//! Firmware in the loop, driven from the host: the emulated board's
//! firmware is the product with the emulated board and nothing else; every
//! scenario is a host program that commands the drive over its command
//! link (QEMU's second `-serial`, USART2, [`foc_ctl::Client`]) and acts on
//! and reads the simulated world through the emulated board's instrument
//! port (the first `-serial`, USART1, `board_support::logic::instrument`):
//! the bench's load, its fault injection and its oscilloscope, never seen
//! by the firmware.
//!
//! Every wait is bounded in emulated time (the firmware's period counter,
//! or the plant's own clock from the instrument port); host time is only a
//! backstop (see [`crate::e2e`]).

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::path::Path;
use std::thread;
use std::time::{Duration, Instant};

use foc_core::control::{Command as DriveCommand, Fault, Mode};
use foc_ctl::ClientError;
use foc_protocol::config::{ConfigSource, StoreOp};
use foc_protocol::message::{ErrorCode, ParamId};
use foc_store::DriveRecord;

use crate::e2e::{check, client_err, connect, free_port, host_backstop, Emulator, Session};
use crate::util::{Error, Result};

mod sensorless;

/// Host-time limit of one scenario (QEMU start to the last check).
const RUN_LIMIT: Duration = Duration::from_secs(600);

/// The true state, from the instrument port's `truth`.
#[derive(Clone, Copy, Debug)]
pub struct Truth {
    /// Simulated time [s].
    pub time_s: f32,
    /// Mechanical speed [rad/s].
    pub omega_rad_s: f32,
    /// Unwrapped mechanical position [rad].
    pub position_rad: f32,
    /// The bridge conducted last period.
    pub bridge: bool,
    /// Outputs commanded on.
    pub outputs: bool,
    /// The break latch holds.
    pub break_latched: bool,
    /// Periods conducted with the break latched.
    pub on_after_break: u64,
    /// Periods simulated.
    pub periods: u64,
    /// True bus voltage [V].
    pub v_bus_v: f32,
    /// Brake-resistor energy since reset [J].
    pub brake_energy_j: f32,
}

/// The stop watch, from `watch?`.
#[derive(Clone, Copy, Debug)]
pub struct Watch {
    /// Highest bus voltage since armed [V].
    pub peak_v_bus_v: f32,
    /// Periods from arming to the last one at or above the speed bound (0:
    /// below it since armed).
    pub settle_periods: u64,
    /// Period at which it was armed.
    pub armed_at: u64,
    /// Brake energy when armed [J].
    pub brake_energy_at_arm_j: f32,
    /// Kinetic energy when armed [J].
    pub kinetic_energy_at_arm_j: f32,
}

/// The emulated board's instrument port (USART1 over TCP).
pub struct Instrument {
    reader: BufReader<TcpStream>,
    writer: TcpStream,
}

fn fields<const N: usize>(reply: &str, tag: &str) -> Result<[f64; N]> {
    let mut it = reply.split_whitespace();
    if it.next() != Some(tag) {
        return Err(Error(format!(
            "instrument: `{reply}` is not a `{tag}` reply"
        )));
    }
    let mut out = [0.0; N];
    for v in &mut out {
        *v = it
            .next()
            .and_then(|x| x.parse().ok())
            .ok_or_else(|| Error(format!("instrument: malformed `{reply}`")))?;
    }
    Ok(out)
}

impl Instrument {
    fn open(port: u16, deadline: Instant) -> Result<Self> {
        let s = connect(port, deadline)?;
        s.set_read_timeout(Some(host_backstop(1.0)))?;
        Ok(Self {
            reader: BufReader::new(s.try_clone()?),
            writer: s,
        })
    }

    fn send(&mut self, line: &str) -> Result {
        self.writer.write_all(format!("{line}\n").as_bytes())?;
        Ok(())
    }

    /// One request, its reply line (answered within a period or two of
    /// emulated time; the host-time limit is a backstop).
    pub fn request(&mut self, line: &str) -> Result<String> {
        self.send(line)?;
        let mut reply = String::new();
        self.reader
            .read_line(&mut reply)
            .map_err(|e| Error(format!("instrument: no reply to `{line}`: {e}")))?;
        Ok(reply.trim().to_string())
    }

    /// A request answered `ok`.
    pub fn act(&mut self, line: &str) -> Result {
        match self.request(line)?.as_str() {
            "ok" => Ok(()),
            r => Err(Error(format!("instrument: `{line}` answered `{r}`"))),
        }
    }

    /// The true state now.
    pub fn truth(&mut self) -> Result<Truth> {
        let f = fields::<10>(&self.request("truth")?, "truth")?;
        Ok(Truth {
            time_s: f[0] as f32,
            omega_rad_s: f[1] as f32,
            position_rad: f[2] as f32,
            bridge: f[3] != 0.0,
            outputs: f[4] != 0.0,
            break_latched: f[5] != 0.0,
            on_after_break: f[6] as u64,
            periods: f[7] as u64,
            v_bus_v: f[8] as f32,
            brake_energy_j: f[9] as f32,
        })
    }

    /// The stop watch's record (`None` before `watch W`).
    pub fn watch(&mut self) -> Result<Option<Watch>> {
        let r = self.request("watch?")?;
        if r == "watch none" {
            return Ok(None);
        }
        let f = fields::<5>(&r, "watch")?;
        Ok(Some(Watch {
            peak_v_bus_v: f[0] as f32,
            settle_periods: f[1] as u64,
            armed_at: f[2] as u64,
            brake_energy_at_arm_j: f[3] as f32,
            kinetic_energy_at_arm_j: f[4] as f32,
        }))
    }

    /// Poll the true state until `ok` holds, within `emulated_s` of the
    /// plant's time; the last state.
    pub fn wait_truth(
        &mut self,
        what: &str,
        emulated_s: f32,
        ok: impl Fn(&Truth) -> bool,
    ) -> Result<Truth> {
        let end = Instant::now() + host_backstop(emulated_s);
        let t0 = self.truth()?;
        loop {
            let t = self.truth()?;
            if ok(&t) {
                return Ok(t);
            }
            if t.time_s - t0.time_s > emulated_s || Instant::now() > end {
                return Err(Error(format!(
                    "FAIL {what}: not within {emulated_s} s emulated (last: {t:?})"
                )));
            }
            thread::sleep(Duration::from_millis(10));
        }
    }
}

/// QEMU with both links connected.
pub struct Rig {
    /// The emulator (its log).
    pub emu: Emulator,
    /// The command link.
    pub s: Session,
    /// The instrument port.
    pub inst: Instrument,
}

impl Rig {
    /// The emulated board with semihosting arguments `args`.
    pub fn start(elf: &Path, args: &[&str], verbose: bool) -> Result<Self> {
        let (pi, pc) = (free_port()?, free_port()?);
        let si = format!("tcp:127.0.0.1:{pi},server,nowait");
        let sc = format!("tcp:127.0.0.1:{pc},server,nowait");
        let emu = Emulator::start_with(elf, args, &[si.as_str(), sc.as_str()], verbose)?;
        let deadline = Instant::now() + RUN_LIMIT;
        let inst = Instrument::open(pi, Instant::now() + Duration::from_secs(10))?;
        let s = Session::open(pc, deadline)?;
        Ok(Self { emu, s, inst })
    }

    /// Ping, then start-up with the identification: calibrated, disabled,
    /// no fault (bounded in emulated time).
    pub fn calibrated_start(&mut self) -> Result {
        self.s.ping()?;
        self.s.startup(&mut self.emu)
    }

    fn command(&mut self, cmd: DriveCommand) -> Result {
        self.s
            .client
            .set_command(cmd)
            .map_err(client_err("command"))
    }

    /// Clear the faults and wait until the drive has taken the clear (at
    /// its next period; a command sent before is refused while the fault
    /// still shows).
    fn clear(&mut self) -> Result {
        self.s.client.clear_faults().map_err(client_err("clear"))?;
        self.s
            .wait_for("faults cleared", 0.05, 1, |t| t.fault_code == 0)?;
        Ok(())
    }

    fn first_fault(&mut self) -> Result<Option<Fault>> {
        Ok(Fault::from_code(self.s.telemetry()?.fault_code))
    }

    /// Wait for the log line containing `needle` (the firmware's own log),
    /// within `backstop` host time.
    pub fn wait_log(&mut self, needle: &str, backstop: Duration) -> Result<String> {
        let end = Instant::now() + backstop;
        loop {
            if let Some(l) = self.emu.log_line(needle) {
                return Ok(l);
            }
            self.emu.alive()?;
            if Instant::now() > end {
                return Err(Error(format!("FAIL the log never said `{needle}`")));
            }
            thread::sleep(Duration::from_millis(20));
        }
    }
}

/// The emulated board's motor (the plant's).
fn motor() -> foc_plant::plant::MotorParams {
    foc_plant::emulated::MOTOR
}

/// The identified motor against the plant: R, Ld, Lq within 5 %, flux
/// linkage within 10 %, electrical zero within 2 deg(e) (the plant's
/// encoder zero is on the d axis), direction and pole pairs exact.
fn identification(r: &mut Rig) -> Result {
    let m = motor();
    let c = &mut r.s.client;
    let mut p = |id| c.param(id).map_err(client_err("read a parameter"));
    let (res, ld, lq, psi) = (
        p(ParamId::ResistanceOhm)?,
        p(ParamId::LdH)?,
        p(ParamId::LqH)?,
        p(ParamId::FluxLinkageWb)?,
    );
    let rel = |x: f32, t: f64| (f64::from(x) - t).abs() / t;
    check(
        rel(res, m.r_ohm) < 0.05 && rel(ld, m.ld_h) < 0.05 && rel(lq, m.lq_h) < 0.05,
        format!(
            "identified R {:+.2} %, Ld {:+.2} %, Lq {:+.2} % off the plant (within 5 %)",
            100.0 * (f64::from(res) / m.r_ohm - 1.0),
            100.0 * (f64::from(ld) / m.ld_h - 1.0),
            100.0 * (f64::from(lq) / m.lq_h - 1.0)
        ),
    )?;
    check(
        rel(psi, m.flux_linkage_wb) < 0.10,
        format!(
            "identified flux linkage {:+.2} % off the plant (within 10 %)",
            100.0 * (f64::from(psi) / m.flux_linkage_wb - 1.0)
        ),
    )?;
    let live = c
        .read_config(ConfigSource::Live)
        .map_err(client_err("read the live configuration"))?;
    let rec = DriveRecord::decode(&live).map_err(|e| Error(format!("live record: {e}")))?;
    let cal = rec
        .calibration
        .ok_or_else(|| Error("FAIL the live record has no calibration".into()))?;
    let zero_deg = {
        let d = cal.zero_offset_e_rad.to_degrees();
        if d > 180.0 {
            d - 360.0
        } else {
            d
        }
    };
    check(
        zero_deg.abs() < 2.0 && !cal.reversed && cal.pole_pairs == m.pole_pairs,
        format!(
            "electrical zero {zero_deg:.2} deg(e) (within 2), direction forward, {} pole pairs",
            cal.pole_pairs
        ),
    )
}

/// The main scenario: identification, velocity, load step, position move,
/// an encoder jump and its clear, the timer's break and its clear, a run
/// without the encoder ([`sensorless::sensorless_run`]) and a limp-home
/// ([`sensorless::limp_home_run`]).
pub fn main_scenario(elf: &Path, verbose: bool) -> Result {
    println!("== main scenario (identification, loops, faults)");
    let mut r = Rig::start(elf, &[], verbose)?;
    let out = main_steps(&mut r);
    if out.is_err() {
        r.emu.print_log_tail();
    }
    out
}

fn near(x: f32, target: f32, tol: f32) -> bool {
    (x - target).abs() < tol
}

fn main_steps(r: &mut Rig) -> Result {
    r.calibrated_start()?;
    identification(r)?;
    r.command(DriveCommand::Velocity { rad_s: 100.0 })?;
    let t = r.s.let_pass(0.3)?;
    let tr = r.inst.truth()?;
    check(
        near(t.velocity_rad_s, 100.0, 2.0) && near(tr.omega_rad_s, 100.0, 2.0),
        format!(
            "velocity 100 rad/s within 2 rad/s after 0.3 s ({:.2}, true {:.2})",
            t.velocity_rad_s, tr.omega_rad_s
        ),
    )?;
    r.inst.act("load 0.1")?;
    r.s.let_pass(0.3)?;
    let tr = r.inst.truth()?;
    check(
        near(tr.omega_rad_s, 100.0, 2.0),
        format!(
            "0.1 N m load step rejected within 2 rad/s ({:.2})",
            tr.omega_rad_s
        ),
    )?;
    r.inst.act("load 0")?;
    position_move(r)?;
    encoder_fault(r)?;
    break_input(r)?;
    sensorless::sensorless_run(r)?;
    sensorless::limp_home_run(r)?;
    check(
        r.first_fault()?.is_none(),
        "no fault (no overrun) at the end",
    )?;
    r.command(DriveCommand::Disable)
}

/// Position move of +30 rad from rest: within 0.05 rad and at rest after
/// 0.8 s, the true rotor moved as the drive says (both read at rest, so the
/// moment each is read does not matter).
fn position_move(r: &mut Rig) -> Result {
    r.command(DriveCommand::Velocity { rad_s: 0.0 })?;
    r.s.let_pass(0.3)?;
    let t = r.s.telemetry()?;
    let tr = r.inst.truth()?;
    check(
        tr.omega_rad_s.abs() < 1.0,
        format!("at rest before the move ({:.3} rad/s)", tr.omega_rad_s),
    )?;
    let target = t.position_rad + 30.0;
    let offset = tr.position_rad - t.position_rad;
    r.command(DriveCommand::Position { rad: target })?;
    let t = r.s.let_pass(0.8)?;
    let tr = r.inst.truth()?;
    check(
        near(t.position_rad, target, 0.05) && near(tr.position_rad - offset, t.position_rad, 0.05),
        format!(
            "position move +30 rad within 0.05 rad ({:.4} rad off, true {:.4})",
            t.position_rad - target,
            tr.position_rad - offset - target
        ),
    )?;
    check(
        tr.omega_rad_s.abs() < 1.0,
        format!("at rest after the move ({:.3} rad/s)", tr.omega_rad_s),
    )
}

/// An encoder jump of 90 deg(mech): `AngleSensorImplausible`, bridge off
/// at once; off until the explicit clear; running again after it.
fn encoder_fault(r: &mut Rig) -> Result {
    r.inst.act("jump 1024")?;
    let (t, _) = r.s.wait_for("encoder jump latched", 0.1, 1, |t| {
        t.fault_code == Fault::AngleSensorImplausible.code()
    })?;
    let tr = r.inst.truth()?;
    check(
        t.mode == Mode::Disabled && !tr.outputs && !tr.bridge,
        "encoder jump latched as implausible angle, bridge in the safe state",
    )?;
    r.inst.act("clear")?;
    let t = r.s.let_pass(0.05)?;
    let tr = r.inst.truth()?;
    check(
        t.mode == Mode::Disabled && !tr.outputs,
        "bridge still off until the explicit clear",
    )?;
    recovers(r, "fault cleared", |_| true)
}

/// The timer's break input: `GateDriverFault`, the bridge never on after
/// it; a command without a clear refused; released by the clear.
fn break_input(r: &mut Rig) -> Result {
    r.inst.act("break")?;
    r.s.wait_for("break latched", 0.05, 1, |t| {
        t.fault_code == Fault::GateDriverFault.code()
    })?;
    let tr = r.inst.truth()?;
    check(
        tr.break_latched && !tr.outputs && tr.on_after_break == 0,
        "timer break latched as a gate-driver fault, bridge never on after it",
    )?;
    let refused =
        r.s.client
            .set_command(DriveCommand::Velocity { rad_s: 50.0 });
    check(
        matches!(refused, Err(ClientError::Nack(ErrorCode::Faulted))),
        format!("a command without a clear is refused ({refused:?})"),
    )?;
    r.s.let_pass(0.05)?;
    let tr = r.inst.truth()?;
    check(
        !tr.outputs && tr.break_latched && tr.on_after_break == 0,
        "break latch holds until the explicit clear",
    )?;
    recovers(r, "break released by the clear", |tr| !tr.break_latched)
}

/// After a latched fault: the clear, then 0.4 s at 50 rad/s with no fault,
/// the speed reached and `also` true of the true state.
fn recovers(r: &mut Rig, what: &str, also: impl Fn(&Truth) -> bool) -> Result {
    r.clear()?;
    r.command(DriveCommand::Velocity { rad_s: 50.0 })?;
    r.s.let_pass(0.4)?;
    let tr = r.inst.truth()?;
    check(
        r.first_fault()?.is_none() && also(&tr) && near(tr.omega_rad_s, 50.0, 2.0),
        format!("{what}, running again at 50 rad/s ({:.2})", tr.omega_rad_s),
    )
}

/// The emulated hardware panics during a position move: the firmware's
/// panic handler must leave the bridge off (the board ends the emulation
/// with exit status 3 when it is, 2 when not).
pub fn panic_scenario(elf: &Path, verbose: bool) -> Result {
    println!("== forced panic during a move (expect exit status 3: bridge safe)");
    let mut r = Rig::start(elf, &[], verbose)?;
    r.calibrated_start()?;
    r.command(DriveCommand::Velocity { rad_s: 100.0 })?;
    r.s.let_pass(0.3)?;
    let p = r.s.telemetry()?.position_rad + 30.0;
    r.command(DriveCommand::Position { rad: p })?;
    r.s.let_pass(0.2)?;
    r.inst.send("panic")?;
    let code = r.emu.wait_exit(host_backstop(1.0))?;
    check(
        code == Some(3),
        format!("forced panic left the bridge in the safe state (exit status {code:?})"),
    )
}

/// The braking runs (design §18) on a DC link fed by a supply that cannot
/// sink current: spin up to three quarters of the no-load speed, command
/// 0 rad/s; the true bus stays below the over-voltage trip, no fault, the
/// rotor stops within the bound (0.4 s on the regen limit, 0.2 s with a
/// 2 ohm brake resistor, which must absorb energy). Returns its figures
/// (peak bus voltage [V], stop time [s], brake energy [J]).
pub fn brake_scenario(elf: &Path, resistor: bool, verbose: bool) -> Result<(f32, f32, f32)> {
    let (name, bound_s) = if resistor {
        ("brake resistor", 0.2)
    } else {
        ("regen limit only", 0.4)
    };
    println!("== braking run: {name}");
    let mut args = vec!["supply=nonsinking"];
    if resistor {
        args.push("brake=2");
    }
    let mut r = Rig::start(elf, &args, verbose)?;
    let out = brake_steps(&mut r, resistor, bound_s);
    if out.is_err() {
        r.emu.print_log_tail();
    }
    out
}

/// The emulated drive's over-voltage trip [V] (the firmware's qemu
/// configuration: the cascade's default supervisor).
fn over_voltage_v() -> f32 {
    let m = motor();
    foc_core::drive::cascade::CascadeConfig::for_motor_with_inertia(
        foc_bench::mission::control_motor(&m),
        foc_plant::emulated::PWM_FREQUENCY_HZ as f32,
        10.0,
        m.inertia_kg_m2 as f32,
    )
    .current
    .supervisor
    .bus_over_voltage_v
}

const STOP_SPEED_RAD_S: f32 = 2.0;
const HOLD_S: f32 = 0.1;

fn brake_steps(r: &mut Rig, resistor: bool, bound_s: f32) -> Result<(f32, f32, f32)> {
    let m = motor();
    let top = (0.75 * 24.0 / (3f64.sqrt() * m.flux_linkage_wb * f64::from(m.pole_pairs))) as f32;
    r.calibrated_start()?;
    r.inst.act(&format!("watch {STOP_SPEED_RAD_S}"))?;
    r.command(DriveCommand::Velocity { rad_s: top })?;
    r.inst
        .wait_truth("top speed within 2 % in 0.5 s", 0.5, |t| {
            near(t.omega_rad_s, top, 0.02 * top)
        })?;
    let spin_peak = r.inst.watch()?.map_or(f32::NAN, |w| w.peak_v_bus_v);
    r.inst.act(&format!("watch {STOP_SPEED_RAD_S}"))?;
    r.command(DriveCommand::Velocity { rad_s: 0.0 })?;
    let pwm = foc_plant::emulated::PWM_FREQUENCY_HZ as f32;
    let hold = (HOLD_S * pwm) as u64;
    let over = ((bound_s + HOLD_S) * pwm) as u64;
    let end = Instant::now() + host_backstop(bound_s + HOLD_S);
    let (w, tr) = loop {
        let w = r
            .inst
            .watch()?
            .ok_or_else(|| Error("stop watch not armed".into()))?;
        let tr = r.inst.truth()?;
        let last_above = w.armed_at + w.settle_periods;
        let held = tr.periods.saturating_sub(last_above);
        let elapsed = tr.periods.saturating_sub(w.armed_at);
        if held >= hold || elapsed >= over || r.first_fault()?.is_some() {
            break (w, tr);
        }
        if Instant::now() > end {
            return Err(Error("FAIL braking: host-time backstop".into()));
        }
        thread::sleep(Duration::from_millis(10));
    };
    let ov = over_voltage_v();
    let stop_s = w.settle_periods as f32 / pwm;
    let brake_j = tr.brake_energy_j - w.brake_energy_at_arm_j;
    println!(
        "brake: peak bus {:.2} V (spin-up {spin_peak:.2} V, over-voltage at {ov:.1} V, {:.2} V at the end), stopped below {STOP_SPEED_RAD_S} rad/s after {stop_s:.3} s, brake energy {brake_j:.3} J, kinetic energy at the command {:.3} J",
        w.peak_v_bus_v, tr.v_bus_v, w.kinetic_energy_at_arm_j
    );
    check(
        w.peak_v_bus_v < ov && spin_peak < ov,
        "peak bus voltage (spin-up and stop) below the over-voltage threshold",
    )?;
    check(
        r.first_fault()?.is_none(),
        "no fault latched during the stop",
    )?;
    check(
        w.settle_periods > 0 && stop_s <= bound_s,
        format!("stopped (below 2 rad/s for good) within {bound_s} s"),
    )?;
    if resistor {
        check(brake_j > 0.0, "the brake resistor absorbed energy")?;
    }
    r.command(DriveCommand::Disable)?;
    Ok((w.peak_v_bus_v, stop_s, brake_j))
}

/// Start angle of the rotor in the boot-from-store runs [rad].
const BOOT_ROTOR_RAD: &str = "rotor=2.1";

/// The store runs (design §17), on one store file with the emulated
/// absolute sensor: identify and save; boot from the store elsewhere
/// (calibrated within 100 ms, no identification, no motion before the
/// first command, torque as the torque constant says); boot from a damaged
/// store (uncalibrated, torque refused).
pub fn store_scenarios(elf: &Path, verbose: bool) -> Result {
    let dir = crate::util::target_dir().join("qemu-store");
    std::fs::create_dir_all(&dir).map_err(|e| Error(format!("{}: {e}", dir.display())))?;
    let store = dir.join("store.bin");
    if store.to_string_lossy().contains(' ') {
        return Err(Error(format!(
            "{}: the store path must not contain spaces (semihosting arguments are space-separated)",
            store.display()
        )));
    }
    let _ = std::fs::remove_file(&store);
    let arg = format!("store={}", store.display());
    println!("== store: identify and save");
    let mut r = Rig::start(elf, &[arg.as_str(), "sensor=absolute", "rotor=0"], verbose)?;
    r.wait_log("store: empty", host_backstop(1.0))?;
    r.calibrated_start()?;
    r.wait_log("identifying the motor", host_backstop(1.0))?;
    let c = &mut r.s.client;
    c.store(StoreOp::Save).map_err(client_err("save"))?;
    let live = c
        .read_config(ConfigSource::Live)
        .map_err(client_err("live"))?;
    let stored = c
        .read_config(ConfigSource::Stored)
        .map_err(client_err("stored"))?;
    check(live == stored, "configuration saved and read back equal")?;
    drop(r);
    println!("== store: boot from it, rotor elsewhere");
    let mut r = Rig::start(
        elf,
        &[arg.as_str(), "sensor=absolute", BOOT_ROTOR_RAD],
        verbose,
    )?;
    boot_from_store(&mut r)?;
    drop(r);
    damage(&store)?;
    println!("== store: boot from a damaged store");
    let mut r = Rig::start(
        elf,
        &[
            arg.as_str(),
            "sensor=absolute",
            BOOT_ROTOR_RAD,
            "identify=off",
        ],
        verbose,
    )?;
    damaged_store(&mut r)
}

fn boot_from_store(r: &mut Rig) -> Result {
    let t0 = r.inst.truth()?;
    let line = r.wait_log("calibrated from the store at period", host_backstop(1.0))?;
    let period: u32 = line
        .split("at period ")
        .nth(1)
        .and_then(|s| s.split(',').next())
        .and_then(|s| s.trim().parse().ok())
        .ok_or_else(|| Error(format!("no period in `{line}`")))?;
    let ms = period as f32 * 1000.0 / foc_plant::emulated::PWM_FREQUENCY_HZ as f32;
    check(
        ms < 100.0,
        format!("calibrated from the store {ms:.1} ms after reset (within 100 ms)"),
    )?;
    r.s.ping()?;
    check(
        r.s.client
            .param(ParamId::Calibrated)
            .map_err(client_err("calibrated"))?
            == 1.0
            && r.emu.log_line("identifying the motor").is_none(),
        "calibrated from the store, no identification",
    )?;
    let t1 = r.inst.truth()?;
    check(
        (t1.position_rad - t0.position_rad).abs() < 0.01 && !t0.bridge && !t1.bridge,
        format!(
            "rotor moved {:.4} rad before the first command (< 0.01), bridge off",
            t1.position_rad - t0.position_rad
        ),
    )?;
    torque_accelerates(r)
}

/// A 2 A torque command accelerates the free rotor as the plant's torque
/// constant says (within -20/+10 %): a wrong electrical zero gives less,
/// or the wrong way. Measured on the true state after the drive took the
/// command.
fn torque_accelerates(r: &mut Rig) -> Result {
    let iq = 2.0;
    r.command(DriveCommand::Torque { iq_a: iq })?;
    r.s.wait_for("torque mode", 0.05, 1, |t| t.mode == Mode::Torque)?;
    let a = r.inst.truth()?;
    r.s.let_pass(0.05)?;
    let b = r.inst.truth()?;
    let m = motor();
    let kt = 1.5 * f64::from(m.pole_pairs) * m.flux_linkage_wb;
    let dt = f64::from(b.time_s - a.time_s);
    let expected = kt * f64::from(iq) / m.inertia_kg_m2 * dt;
    let gained = f64::from(b.omega_rad_s - a.omega_rad_s);
    r.command(DriveCommand::Disable)?;
    check(
        gained > 0.8 * expected && gained < 1.1 * expected,
        format!(
            "torque command accepted: {gained:.2} rad/s gained in {dt:.3} s (rigid rotor, ideal torque: {expected:.2})"
        ),
    )
}

fn damaged_store(r: &mut Rig) -> Result {
    r.wait_log("build-time defaults, uncalibrated", host_backstop(1.0))?;
    r.wait_log("start-up done", host_backstop(1.0))?;
    r.s.ping()?;
    check(
        r.s.client
            .param(ParamId::Calibrated)
            .map_err(client_err("calibrated"))?
            == 0.0
            && r.emu.log_line("identifying the motor").is_none()
            && r.emu.log_line("store: loaded").is_none(),
        "boots uncalibrated from a damaged store, no identification",
    )?;
    let refused = r.s.client.set_command(DriveCommand::Torque { iq_a: 2.0 });
    r.s.let_pass(0.05)?;
    let t = r.inst.truth()?;
    check(
        matches!(refused, Err(ClientError::Nack(ErrorCode::NotCalibrated)))
            && !t.bridge
            && t.omega_rad_s.abs() < 0.05,
        format!("torque refused ({refused:?}): bridge off, rotor still"),
    )
}

/// Overwrite `file` with pseudo-random bytes (a damaged store).
fn damage(file: &Path) -> Result {
    let len = std::fs::metadata(file)
        .map_err(|e| Error(format!("{}: {e}", file.display())))?
        .len();
    let mut x: u32 = 0x2545_F491;
    let bytes: Vec<u8> = (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        })
        .collect();
    std::fs::write(file, bytes).map_err(|e| Error(format!("{}: {e}", file.display())))
}
