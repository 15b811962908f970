//! `cargo xtask e2e`: the command channel end to end, in emulation.
//!
//! Builds the `qemu` board, starts QEMU with the firmware's mission passive
//! (semihosting argument `e2e`) and the emulated USART2 on a loopback TCP
//! socket (`-serial null -serial tcp:127.0.0.1:PORT,server,nowait`: QEMU's
//! `-serial` devices map in order onto USART1, USART2, ...), then drives the
//! drive through [`foc_ctl::Client`] only:
//!
//! 1. ping (protocol version), wait for start-up (parameter `calibrated`);
//! 2. velocity 50 rad/s, read back from telemetry (within 2 rad/s), and a
//!    streamed-telemetry check (sample spacing = the requested rate);
//! 3. position move of +20 rad, read back (within 0.05 rad, at rest);
//! 4. a frame with a bad CRC and one with broken COBS: Nack (bad CRC /
//!    malformed, `seq` 0), nothing changed;
//! 5. an out-of-range velocity (1e6 rad/s) and dividers while running:
//!    Nack (field 1 out of range / not disabled), nothing changed;
//! 6. faults read (none latched), disable;
//! 7. the configuration store (a fresh file, semihosting `store=`): save,
//!    read back equal; export as TOML, edit, import (applied and saved),
//!    read back equal; erase, nothing stored; a velocity command and a
//!    save in one burst: the save refused (not disabled), nothing stored;
//! 8. the link watchdog; QEMU killed.
//!
//! Every wait is bounded in emulated time, counted in the firmware's own
//! PWM periods (telemetry `period`, at the PWM frequency the firmware
//! reports, `ParamId::PwmFrequencyHz`), so a slow or loaded host cannot
//! make a check fail; host-time limits are only backstops, several times
//! larger (a hung emulator), and the whole run is bounded ([`TOTAL_LIMIT`]).
//!
//! **Emulated time.** QEMU runs with `-icount shift=0,align=off,sleep=off`,
//! as for `cargo xtask qemu`: one instruction is 1 ns of virtual time, so
//! every current-loop run takes the same virtual time whatever the host
//! does, and a busy host cannot make a TIM2 period pass during a run (no
//! spurious overrun). With `sleep=off` the idle time between TIM2 periods
//! is skipped, so the emulation runs as fast as the host CPU allows
//! (measured here: about 8,800 simulated PWM periods per host second, i.e.
//! the simulated motor at about 0.44x real time). The host tool then sees
//! the drive evolve at a steady rate it can follow, and reads the emulated
//! time from the firmware's period counter. `sleep=on` (virtual time waits
//! for the host while idle) ran about 10x slower here (about 800 periods per
//! host second, host timer granularity), and no `-icount` at all ties TIM2
//! to host time, so a loaded host overruns the current loop.

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::{Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::path::Path;
use std::process::Child;
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

use clap::Args;
use foc_core::control::{Command as DriveCommand, Fault, Mode};
use foc_ctl::{Client, ClientError, TcpTransport};
use foc_protocol::config::{ConfigSource, StoreOp};
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::message::{ErrorCode, ParamId, Request, Response, Telemetry, TelemetryRate};
use foc_store::DriveRecord;

use crate::qemu;
use crate::util::{Error, Result};

/// The whole test, QEMU start to kill (host-time backstop).
pub const TOTAL_LIMIT: Duration = Duration::from_secs(360);
/// Start-up (offsets, sensor check, identification) must end within this
/// emulated time [s] (bounded in the firmware's own periods, not host time).
const STARTUP_EMULATED_S: f32 = 20.0;
/// Host-time backstop of the start-up wait (a hung emulator).
const STARTUP_HOST_BACKSTOP: Duration = Duration::from_secs(240);
/// Host-time backstop of the other waits, per emulated second waited for:
/// the emulation takes about 2.3 host seconds per emulated second on an
/// idle host here (0.44x real time) and measured 8.7 on a two-core host
/// busy compiling, so this is several times either.
const BACKSTOP_HOST_S_PER_EMULATED_S: f32 = 30.0;
/// The shortest host-time backstop of a wait [s].
const BACKSTOP_MIN_HOST_S: f32 = 20.0;
/// Velocity target [rad/s] and tolerance.
const VELOCITY_RAD_S: f32 = 50.0;
const VELOCITY_TOL_RAD_S: f32 = 2.0;
/// The velocity must be read back within this emulated time [s].
const VELOCITY_EMULATED_S: f32 = 2.0;
/// Streamed telemetry: rate [Hz] (above the old 50 Hz cap; a whole number
/// of the 1 kHz stream task's runs) and samples collected (0.6 s emulated).
const STREAM_RATE_HZ: f32 = 125.0;
const STREAM_SAMPLES: usize = 75;
/// A rate beyond what the UART carries at 115200 baud (about 190 Hz):
/// refused.
const STREAM_TOO_FAST_HZ: f32 = 250.0;
/// Position step [rad] and tolerance.
const MOVE_RAD: f32 = 20.0;
const POSITION_TOL_RAD: f32 = 0.05;
/// The move must end (at rest, within tolerance) within this emulated time [s].
const MOVE_EMULATED_S: f32 = 3.0;
/// After refused commands, the drive must stay put for this emulated time [s].
const HOLD_EMULATED_S: f32 = 0.15;
/// Disabled on command within this emulated time [s].
const DISABLE_EMULATED_S: f32 = 0.5;
/// Host-time limit of a reply to a raw frame (a backstop: the firmware
/// answers within about a millisecond of emulated time).
const RAW_REPLY_HOST_LIMIT: Duration = Duration::from_secs(3);

/// Host-time backstop of a wait of `emulated_s` emulated seconds.
pub(crate) fn host_backstop(emulated_s: f32) -> Duration {
    Duration::from_secs_f32((emulated_s * BACKSTOP_HOST_S_PER_EMULATED_S).max(BACKSTOP_MIN_HOST_S))
}

/// `cargo xtask e2e` options.
#[derive(Debug, Args, Clone, Default)]
pub struct E2eArgs {
    /// Echo the firmware's whole defmt log (default: warnings and errors).
    #[arg(long)]
    pub verbose: bool,
}

/// QEMU (its defmt log decoded in process), killed on drop.
pub(crate) struct Emulator {
    pub(crate) qemu: Child,
    log: Arc<Mutex<VecDeque<String>>>,
    /// Every decoded line so far.
    all: Arc<Mutex<Vec<String>>>,
}

impl Drop for Emulator {
    fn drop(&mut self) {
        let _ = self.qemu.kill();
        let _ = self.qemu.wait();
    }
}

impl Emulator {
    fn start(elf: &Path, port: u16, verbose: bool) -> Result<Self> {
        let serial = format!("tcp:127.0.0.1:{port},server,nowait");
        // A fresh configuration store for this run (semihosting `store=`),
        // and the absolute sensor, whose calibration a record can carry.
        let dir = crate::util::target_dir().join("qemu-store");
        std::fs::create_dir_all(&dir).map_err(|e| Error(format!("{}: {e}", dir.display())))?;
        let store = dir.join("e2e-store.bin");
        let _ = std::fs::remove_file(&store);
        let store_arg = format!("store={}", store.display());
        Self::start_with(
            elf,
            &["sensor=absolute", store_arg.as_str()],
            &["null", serial.as_str()],
            verbose,
        )
    }

    /// QEMU with semihosting arguments `args` and `-serial` devices
    /// `serials` (USART1, USART2, ...), its log decoded (echoed when
    /// `verbose`, else warnings and errors only).
    pub(crate) fn start_with(
        elf: &Path,
        args: &[&str],
        serials: &[&str],
        verbose: bool,
    ) -> Result<Self> {
        let (qemu, lines) =
            qemu::spawn_decoded_serials(elf, args, "shift=0,align=off,sleep=off", serials)?;
        let log = Arc::new(Mutex::new(VecDeque::new()));
        let all = Arc::new(Mutex::new(Vec::new()));
        let (tail, every) = (log.clone(), all.clone());
        // Ends when QEMU's output closes (QEMU killed).
        thread::spawn(move || {
            for line in lines {
                if verbose || line.contains("WARN") || line.contains("ERROR") {
                    println!("  | {line}");
                }
                if let Ok(mut l) = tail.lock() {
                    if l.len() >= 40 {
                        l.pop_front();
                    }
                    l.push_back(line.clone());
                }
                if let Ok(mut a) = every.lock() {
                    a.push(line);
                }
            }
        });
        Ok(Self { qemu, log, all })
    }

    /// The first log line so far that contains `needle`.
    pub(crate) fn log_line(&self, needle: &str) -> Option<String> {
        self.all
            .lock()
            .ok()
            .and_then(|a| a.iter().find(|l| l.contains(needle)).cloned())
    }

    /// QEMU's exit status once it has exited, within `backstop` host time
    /// (`None`: still running then, or killed by a signal).
    pub(crate) fn wait_exit(&mut self, backstop: Duration) -> Result<Option<i32>> {
        let end = Instant::now() + backstop;
        while Instant::now() < end {
            if let Some(st) = self.qemu.try_wait()? {
                return Ok(st.code());
            }
            thread::sleep(Duration::from_millis(20));
        }
        Ok(None)
    }

    pub(crate) fn alive(&mut self) -> Result {
        match self.qemu.try_wait()? {
            None => Ok(()),
            Some(s) => Err(Error(format!("QEMU exited early ({s})"))),
        }
    }

    pub(crate) fn print_log_tail(&self) {
        if let Ok(l) = self.log.lock() {
            println!("last firmware log lines:");
            for line in l.iter() {
                println!("  | {line}");
            }
        }
    }
}

/// A free loopback port (bound and released; QEMU binds it next).
pub fn free_port() -> Result<u16> {
    let l = TcpListener::bind((Ipv4Addr::LOCALHOST, 0))?;
    Ok(l.local_addr()?.port())
}

/// Connect to QEMU's server socket, retrying while it starts.
pub(crate) fn connect(port: u16, deadline: Instant) -> Result<TcpStream> {
    let addr = SocketAddr::from((Ipv4Addr::LOCALHOST, port));
    loop {
        match TcpStream::connect_timeout(&addr, Duration::from_secs(1)) {
            Ok(s) => return Ok(s),
            Err(e) if Instant::now() > deadline => {
                return Err(Error(format!("could not connect to QEMU on {addr}: {e}")))
            }
            Err(_) => thread::sleep(Duration::from_millis(100)),
        }
    }
}

pub(crate) fn check(ok: bool, what: impl AsRef<str>) -> Result {
    if ok {
        println!("PASS {}", what.as_ref());
        Ok(())
    } else {
        Err(Error(format!("FAIL {}", what.as_ref())))
    }
}

pub(crate) fn client_err(what: &str) -> impl Fn(ClientError) -> Error + '_ {
    move |e| Error(format!("{what}: {e}"))
}

/// The test proper, on a running emulator.
pub(crate) struct Session {
    pub(crate) client: Client,
    raw: TcpStream,
    deadline: Instant,
    /// The firmware's PWM frequency [Hz] (periods per emulated second),
    /// read once.
    pwm_hz: Option<f32>,
}

impl Session {
    /// The firmware's PWM frequency [Hz], read from the device once.
    pub(crate) fn pwm_hz(&mut self) -> Result<f32> {
        if let Some(hz) = self.pwm_hz {
            return Ok(hz);
        }
        let hz = self
            .client
            .param(ParamId::PwmFrequencyHz)
            .map_err(client_err("read the PWM frequency"))?;
        if !(hz.is_finite() && hz > 0.0) {
            return Err(Error(format!("implausible PWM frequency {hz} Hz")));
        }
        self.pwm_hz = Some(hz);
        Ok(hz)
    }

    /// Emulated seconds from period `p0` to `p` (the firmware's counter).
    pub(crate) fn emulated_s(&mut self, p0: u32, p: u32) -> Result<f32> {
        Ok(p.wrapping_sub(p0) as f32 / self.pwm_hz()?)
    }

    pub(crate) fn telemetry(&mut self) -> Result<Telemetry> {
        self.client
            .read_telemetry()
            .map_err(client_err("read telemetry"))
    }

    fn remaining(&self) -> Result<Duration> {
        let left = self.deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            Err(Error(format!(
                "e2e exceeded its {} s limit",
                TOTAL_LIMIT.as_secs()
            )))
        } else {
            Ok(left)
        }
    }

    /// Poll telemetry until `ok` holds for `n` consecutive samples, within
    /// `emulated_s` of emulated time (the firmware's period counter, from
    /// the first sample); the host time is only a backstop
    /// ([`host_backstop`]). Returns the last sample and the emulated
    /// seconds it took.
    pub(crate) fn wait_for(
        &mut self,
        what: &str,
        emulated_s: f32,
        n: u32,
        ok: impl Fn(&Telemetry) -> bool,
    ) -> Result<(Telemetry, f32)> {
        let backstop = host_backstop(emulated_s);
        let t0 = Instant::now();
        let end = t0 + backstop.min(self.remaining()?);
        let mut t = self.telemetry()?;
        let p0 = t.period;
        let mut good = 0;
        loop {
            good = if ok(&t) { good + 1 } else { 0 };
            let elapsed = self.emulated_s(p0, t.period)?;
            if good >= n {
                return Ok((t, elapsed));
            }
            let last = format!(
                "last: mode {:?}, {:.3} rad/s, {:.4} rad, fault {}",
                t.mode, t.velocity_rad_s, t.position_rad, t.fault_code
            );
            if elapsed > emulated_s {
                return Err(Error(format!(
                    "FAIL {what}: not reached within {emulated_s} s emulated \
                     ({elapsed:.3} s emulated, {:.1} s host; {last})",
                    t0.elapsed().as_secs_f32()
                )));
            }
            if Instant::now() > end {
                return Err(Error(format!(
                    "FAIL {what}: host-time backstop: only {elapsed:.3} of {emulated_s} s \
                     emulated in {:.1} s host (emulator hung or far too slow; {last})",
                    t0.elapsed().as_secs_f32()
                )));
            }
            thread::sleep(Duration::from_millis(50));
            t = self.telemetry()?;
        }
    }

    /// Let `emulated_s` of emulated time pass (the firmware's period
    /// counter), with a host-time backstop. Returns the last sample.
    pub(crate) fn let_pass(&mut self, emulated_s: f32) -> Result<Telemetry> {
        let p0 = self.telemetry()?.period;
        let pwm_hz = self.pwm_hz()?;
        let (t, _) = self.wait_for("letting emulated time pass", emulated_s * 2.0, 1, |t| {
            t.period.wrapping_sub(p0) as f32 >= emulated_s * pwm_hz
        })?;
        Ok(t)
    }

    /// Send raw bytes and wait for one non-stream reply (seq, response).
    fn raw_exchange(&mut self, bytes: &[u8]) -> Result<(u16, Response)> {
        let mut replies = self.raw_replies(bytes, 1)?;
        replies
            .pop()
            .ok_or_else(|| Error("no reply to a raw frame".into()))
    }

    /// Write `bytes` (one or more frames) on the raw socket and read `n`
    /// replies (streamed telemetry skipped).
    fn raw_replies(&mut self, bytes: &[u8], n: usize) -> Result<Vec<(u16, Response)>> {
        self.raw.write_all(bytes)?;
        self.raw.flush()?;
        let end = Instant::now() + RAW_REPLY_HOST_LIMIT.min(self.remaining()?);
        let mut dec = FrameDecoder::new();
        let mut buf = [0u8; 256];
        let mut replies = Vec::new();
        while Instant::now() < end {
            self.raw
                .set_read_timeout(Some(Duration::from_millis(100)))?;
            let got = match self.raw.read(&mut buf) {
                Ok(0) => return Err(Error("QEMU closed the connection".into())),
                Ok(got) => got,
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    continue
                }
                Err(e) => return Err(e.into()),
            };
            for &b in &buf[..got] {
                if let Some(Ok(p)) = dec.feed::<Response>(b) {
                    if !matches!(p.msg, Response::Stream(_)) {
                        replies.push((p.seq, p.msg));
                        if replies.len() == n {
                            return Ok(replies);
                        }
                    }
                }
            }
        }
        Err(Error(format!(
            "no reply to a raw frame within {} s host time",
            RAW_REPLY_HOST_LIMIT.as_secs()
        )))
    }
}

/// `cargo xtask e2e`.
pub fn run_cmd(args: &E2eArgs) -> Result {
    let (elf, _) = qemu::build_emulated()?;
    let port = free_port()?;
    let start = Instant::now();
    println!("== QEMU with the mission passive, USART2 on 127.0.0.1:{port}");
    let mut emu = Emulator::start(&elf, port, args.verbose)?;
    let result = run_session(&mut emu, port, start);
    if result.is_err() {
        emu.print_log_tail();
    }
    drop(emu);
    match &result {
        Ok(()) => println!(
            "cargo xtask e2e: command channel passed end to end ({:.1} s)",
            start.elapsed().as_secs_f32()
        ),
        Err(_) => println!(
            "cargo xtask e2e: FAILED after {:.1} s",
            start.elapsed().as_secs_f32()
        ),
    }
    result
}

fn run_session(emu: &mut Emulator, port: u16, start: Instant) -> Result {
    let mut s = Session::open(port, start + TOTAL_LIMIT)?;
    s.ping()?;
    s.startup(emu)?;
    s.scope_current_step()?;
    s.velocity()?;
    s.telemetry_stream()?;
    let target = s.position_move()?;
    s.malformed_frames(target)?;
    s.refused_commands(target)?;
    s.faults_and_disable()?;
    s.configuration_store()?;
    s.link_watchdog()?;
    emu.alive()
}

/// The checked scenarios, in order.
impl Session {
    /// Connect the client (and a raw clone of its socket) to QEMU.
    pub(crate) fn open(port: u16, deadline: Instant) -> Result<Self> {
        let stream = connect(port, Instant::now() + Duration::from_secs(10))?;
        let raw = stream.try_clone()?;
        let mut client = Client::new(Box::new(TcpTransport::from_stream(stream)?))
            .map_err(client_err("client"))?;
        client.set_timeout(Duration::from_millis(500));
        client.set_retries(3);
        Ok(Self {
            client,
            raw,
            deadline,
            pwm_hz: None,
        })
    }

    /// Step 1a, ping: the protocol version matches.
    pub(crate) fn ping(&mut self) -> Result {
        let hello = self.client.ping().map_err(client_err("ping"))?;
        check(
            hello.protocol_version == foc_protocol::PROTOCOL_VERSION,
            format!(
                "ping: protocol {} (host {}), firmware {}.{}.{}",
                hello.protocol_version,
                foc_protocol::PROTOCOL_VERSION,
                hello.firmware_version[0],
                hello.firmware_version[1],
                hello.firmware_version[2]
            ),
        )
    }

    /// Step 1b, start-up: `calibrated` = 1 within [`STARTUP_EMULATED_S`] of
    /// emulated time (the firmware's period counter), then disabled, no fault.
    pub(crate) fn startup(&mut self, emu: &mut Emulator) -> Result {
        let t0 = Instant::now();
        let pwm_hz = self.pwm_hz()?;
        loop {
            emu.alive()?;
            let cal = self
                .client
                .param(ParamId::Calibrated)
                .map_err(client_err("read calibrated"))?;
            if cal == 1.0 {
                break;
            }
            let emulated_s = self.telemetry()?.period as f32 / pwm_hz;
            if emulated_s > STARTUP_EMULATED_S
                || t0.elapsed() > STARTUP_HOST_BACKSTOP
                || self.remaining().is_err()
            {
                return Err(Error(format!(
                    "FAIL start-up: the firmware did not report `calibrated` = 1 within \
                     {STARTUP_EMULATED_S} s emulated ({emulated_s:.1} s emulated, {:.0} s host) \
                     (closed-loop modes locked: no calibration permit installed at start-up)",
                    t0.elapsed().as_secs_f32()
                )));
            }
            thread::sleep(Duration::from_millis(200));
        }
        let t = self.telemetry()?;
        check(
            t.mode == Mode::Disabled && t.fault_code == 0,
            format!(
                "start-up done in {:.1} s host time: calibrated, disabled, no fault (period {})",
                t0.elapsed().as_secs_f32(),
                t.period
            ),
        )?;
        let faults = self.client.faults().map_err(client_err("read faults"))?;
        check(faults.set.is_empty(), "no fault latched after start-up")
    }

    /// Step 1c, the scope: a current step through `tune current`, its
    /// figures against the bench's (see `e2e_scope`). The capture ends in
    /// emulated time (200 periods); the host-time limit is a backstop.
    fn scope_current_step(&mut self) -> Result {
        let out = crate::util::root().join("out/e2e");
        crate::e2e_scope::current_step(&mut self.client, host_backstop(1.0), &out)
    }

    /// Step 2a, velocity: the target read back from telemetry.
    fn velocity(&mut self) -> Result {
        self.client
            .set_command(DriveCommand::Velocity {
                rad_s: VELOCITY_RAD_S,
            })
            .map_err(client_err("velocity command"))?;
        let (t, took) = self.wait_for("velocity", VELOCITY_EMULATED_S, 3, |t| {
            t.mode == Mode::Velocity
                && (t.velocity_rad_s - VELOCITY_RAD_S).abs() < VELOCITY_TOL_RAD_S
        })?;
        check(
            true,
            format!(
                "velocity {VELOCITY_RAD_S} rad/s: read back {:.3} rad/s (tolerance {VELOCITY_TOL_RAD_S}) after {took:.3} s simulated (limit {VELOCITY_EMULATED_S} s)",
                t.velocity_rad_s,
            ),
        )
    }

    /// Step 2b, streamed telemetry at that velocity: [`STREAM_SAMPLES`]
    /// samples (a fixed stretch of emulated time), spacing = the requested
    /// rate.
    fn telemetry_stream(&mut self) -> Result {
        let rate_hz = STREAM_RATE_HZ;
        let pwm_hz = self.pwm_hz()?;
        let emulated_s = STREAM_SAMPLES as f32 / rate_hz;
        let backstop = host_backstop(emulated_s);
        let end = Instant::now() + backstop.min(self.remaining()?);
        let mut samples = Vec::with_capacity(STREAM_SAMPLES);
        self.client.clear_stream_queue();
        self.client
            .start_telemetry(TelemetryRate::Hz(rate_hz))
            .map_err(client_err("start telemetry"))?;
        let collected = loop {
            if samples.len() >= STREAM_SAMPLES {
                break Ok(());
            }
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break Err(Error(format!(
                    "FAIL stream at {rate_hz} Hz: host-time backstop: {} of {STREAM_SAMPLES} \
                     samples in {:.0} s host (emulator hung or far too slow)",
                    samples.len(),
                    backstop.as_secs_f32()
                )));
            }
            match self
                .client
                .next_stream(left.min(Duration::from_millis(500)))
            {
                Ok(Some(s)) => samples.push(s),
                Ok(None) => {}
                Err(e) => break Err(client_err("stream telemetry")(e)),
            }
        };
        let stopped = self
            .client
            .stop_telemetry()
            .map_err(client_err("stop telemetry"));
        collected.and(stopped)?;
        let n = samples.len();
        let spacing: Vec<u32> = samples
            .windows(2)
            .map(|w| w[1].sample.period.wrapping_sub(w[0].sample.period))
            .collect();
        let want = (pwm_hz / rate_hz).round() as u32;
        // Each sample within 2 periods of its slot (the stream task shares
        // priority 1 with the channel and housekeeping), none lost: the
        // first-to-last span is exact.
        let span = samples.last().map_or(0, |l| {
            l.sample.period.wrapping_sub(samples[0].sample.period)
        });
        let spaced = spacing.iter().all(|&d| d.abs_diff(want) <= 2)
            && span.abs_diff(want * (n.max(1) - 1) as u32) <= 2;
        let worst = samples
            .iter()
            .map(|x| (x.sample.velocity_rad_s - VELOCITY_RAD_S).abs())
            .fold(0.0f32, f32::max);
        check(
            n == STREAM_SAMPLES && spaced && worst < VELOCITY_TOL_RAD_S,
            format!(
                "stream at {rate_hz} Hz: {n} samples ({emulated_s:.1} s emulated), every {want} periods (spacing {}..{}), worst velocity error {worst:.3} rad/s, {} lost",
                spacing.iter().min().unwrap_or(&0),
                spacing.iter().max().unwrap_or(&0),
                self.client.stats().stream_lost
            ),
        )?;
        let refused = self
            .client
            .start_telemetry(TelemetryRate::Hz(STREAM_TOO_FAST_HZ));
        check(
            matches!(refused, Err(ClientError::Nack(ErrorCode::OutOfRange { field: 1 }))),
            format!("stream at {STREAM_TOO_FAST_HZ} Hz refused, beyond the UART at 115200 baud ({refused:?})"),
        )
    }

    /// Step 3, position move of [`MOVE_RAD`]: read back at rest. Returns the
    /// target [rad].
    fn position_move(&mut self) -> Result<f32> {
        let start_pos = self.telemetry()?.position_rad;
        let target = start_pos + MOVE_RAD;
        self.client
            .set_command(DriveCommand::Position { rad: target })
            .map_err(client_err("position command"))?;
        let (t, took) = self.wait_for("position move", MOVE_EMULATED_S, 3, |t| {
            t.mode == Mode::Position
                && (t.position_rad - target).abs() < POSITION_TOL_RAD
                && t.velocity_rad_s.abs() < 1.0
        })?;
        check(
            true,
            format!(
                "position {target:.3} rad (+{MOVE_RAD} rad): read back {:.4} rad (error {:.4}, tolerance {POSITION_TOL_RAD}), {:.3} rad/s, after {took:.3} s simulated (limit {MOVE_EMULATED_S} s)",
                t.position_rad,
                t.position_rad - target,
                t.velocity_rad_s,
            ),
        )?;
        Ok(target)
    }

    /// Step 4, malformed frames (bad CRC, broken COBS): Nack with seq 0, the
    /// drive still holds `target`.
    fn malformed_frames(&mut self, target: f32) -> Result {
        let mut frame = [0u8; MAX_FRAME];
        let len = encode(
            0x1234,
            &Request::SetCommand(DriveCommand::Disable),
            &mut frame,
        )
        .map_err(|e| Error(format!("encode: {e:?}")))?;
        // Flip bits in the last CRC byte (the byte before the delimiter): stays
        // non-zero after COBS, so the frame still parses but fails its CRC.
        let i = len - 2;
        frame[i] = if frame[i] == 0x55 { 0xAA } else { 0x55 };
        let (seq, r) = self.raw_exchange(&frame[..len])?;
        check(
            seq == 0 && r == Response::Nack(ErrorCode::BadCrc),
            format!("frame with a bad CRC (a Disable): {r:?} with seq {seq}"),
        )?;
        // COBS block claims 9 bytes, only 2 follow before the delimiter.
        let (seq, r) = self.raw_exchange(&[0x09, 0x01, 0x02, 0x00])?;
        check(
            seq == 0 && r == Response::Nack(ErrorCode::Malformed),
            format!("truncated COBS frame: {r:?} with seq {seq}"),
        )?;
        let t = self.telemetry()?;
        check(
            t.mode == Mode::Position && (t.position_rad - target).abs() < POSITION_TOL_RAD,
            format!(
                "nothing changed: still position mode at {:.4} rad",
                t.position_rad
            ),
        )
    }

    /// Step 5, out-of-range velocity and dividers while running: refused, the
    /// drive still at rest at `target` with its speed divider.
    fn refused_commands(&mut self, target: f32) -> Result {
        match self
            .client
            .set_command(DriveCommand::Velocity { rad_s: 1.0e6 })
        {
            Err(ClientError::Nack(ErrorCode::OutOfRange { field: 1 })) => {
                println!("PASS velocity 1e6 rad/s refused: field 1 out of range")
            }
            other => return Err(Error(format!("FAIL velocity 1e6 rad/s: got {other:?}"))),
        }
        match self.client.set_dividers(5, 10) {
            Err(ClientError::Nack(ErrorCode::NotDisabled)) => {
                println!("PASS dividers while running refused: not disabled")
            }
            other => return Err(Error(format!("FAIL dividers while running: got {other:?}"))),
        }
        let speed_div = self
            .client
            .param(ParamId::SpeedDivider)
            .map_err(client_err("read speed divider"))?;
        let t = self.let_pass(HOLD_EMULATED_S)?;
        check(
            t.mode == Mode::Position
                && (t.position_rad - target).abs() < POSITION_TOL_RAD
                && t.velocity_rad_s.abs() < 1.0
                && speed_div == 10.0,
            format!(
                "nothing changed: position {:.4} rad, {:.3} rad/s, speed divider {speed_div}, \
                 {HOLD_EMULATED_S} s emulated later",
                t.position_rad, t.velocity_rad_s
            ),
        )
    }

    /// Step 6: no fault latched, disable on command, link statistics.
    fn faults_and_disable(&mut self) -> Result {
        let faults = self.client.faults().map_err(client_err("read faults"))?;
        check(
            faults.set.is_empty() && faults.first_code == 0,
            format!(
                "faults read: {:#x} (first {})",
                faults.set.0, faults.first_code
            ),
        )?;
        self.client
            .set_command(DriveCommand::Disable)
            .map_err(client_err("disable"))?;
        let (t, _) = self.wait_for("disable", DISABLE_EMULATED_S, 1, |t| {
            t.mode == Mode::Disabled
        })?;
        check(t.mode == Mode::Disabled, "disabled on command")?;
        let st = self.client.stats();
        println!(
            "link: {} requests, {} retransmissions, {} bad frames, {} stale replies, {} streamed samples",
            st.requests, st.retransmissions, st.bad_frames, st.stale_replies, st.stream_samples
        );
        Ok(())
    }

    /// Step 7, the configuration store (drive disabled): save and read the
    /// stored record back equal to the live one; export it as TOML, edit
    /// the label and a gain, import it (checked on the host, then applied
    /// and saved by the drive) and read both records back equal to the
    /// edit; erase: nothing stored, and a load says so.
    fn configuration_store(&mut self) -> Result {
        let rec = self.config_save()?;
        self.config_import(&rec)?;
        self.config_erase()?;
        self.config_save_refused_in_burst()
    }

    /// Step 7, save: the live record (calibrated by the start-up
    /// identification) saved and read back equal; returns it decoded.
    fn config_save(&mut self) -> Result<DriveRecord> {
        let live = self
            .client
            .read_config(ConfigSource::Live)
            .map_err(client_err("read the live configuration"))?;
        let rec = DriveRecord::decode(&live)
            .map_err(|e| Error(format!("FAIL live configuration record: {e}")))?;
        check(
            rec.calibration.is_some(),
            format!(
                "live configuration: {} bytes, calibration from the start-up identification",
                live.len()
            ),
        )?;
        self.client
            .store(StoreOp::Save)
            .map_err(client_err("config save"))?;
        let stored = self
            .client
            .read_config(ConfigSource::Stored)
            .map_err(client_err("read the stored configuration"))?;
        check(stored == live, "config save: stored record read back equal")?;
        Ok(rec)
    }

    /// Step 7, import: `rec` exported as TOML, its label and speed gain
    /// edited, imported (applied and saved); the live and stored records
    /// read back equal to the edit.
    fn config_import(&mut self, rec: &DriveRecord) -> Result {
        // Export, edit, import (as `foc-ctl config export` / `import`):
        // through the TOML text, checked on the host.
        let mut want = rec.clone();
        want.label = foc_store::Label::try_from("e2e joint 3")
            .map_err(|_| Error("label too long".into()))?;
        want.speed.kp_a_per_rad_s *= 0.5;
        let edited = foc_store::text::from_toml(&foc_store::text::to_toml(&want))
            .map_err(|e| Error(format!("FAIL import: the edited file is refused: {e}")))?;
        check(
            edited == want,
            "export -> TOML -> edit (label, speed kp) -> checked on the host",
        )?;
        let mut bytes = [0u8; foc_store::MAX_RECORD_BYTES];
        let n = edited
            .encode(&mut bytes)
            .map_err(|e| Error(format!("FAIL encode: {e}")))?;
        self.client
            .write_config(&bytes[..n])
            .map_err(client_err("config import (write)"))?;
        self.client
            .store(StoreOp::ApplyAndSave)
            .map_err(client_err("config import (apply and save)"))?;
        let live = self
            .client
            .read_config(ConfigSource::Live)
            .map_err(client_err("read the live configuration"))?;
        let stored = self
            .client
            .read_config(ConfigSource::Stored)
            .map_err(client_err("read the stored configuration"))?;
        check(
            live == bytes[..n] && stored == live,
            "config import: live and stored records read back equal to the edit",
        )
    }

    /// Step 7, erase: nothing stored afterwards, and a load says so.
    fn config_erase(&mut self) -> Result {
        self.client
            .store(StoreOp::Erase)
            .map_err(client_err("config erase"))?;
        let after = self.client.read_config(ConfigSource::Stored);
        let load = self.client.store(StoreOp::Load);
        check(
            matches!(after, Err(ClientError::Nack(ErrorCode::NothingStored)))
                && matches!(load, Err(ClientError::Nack(ErrorCode::NothingStored))),
            format!("config erase: nothing stored (read {after:?}, load {load:?})"),
        )
    }

    /// Step 7, a velocity command and a save in one burst: the save is
    /// refused and nothing is stored; the drive disabled again.
    fn config_save_refused_in_burst(&mut self) -> Result {
        // A command and a save in one burst: whether or not the current
        // loop has taken the command when the save is handled (the firmware
        // checks the mailbox too, not only the last period's status), the
        // save is refused, so a flash stall never meets a running bridge.
        let mut burst = [0u8; 2 * MAX_FRAME];
        let a = encode(
            61_000,
            &Request::SetCommand(DriveCommand::Velocity { rad_s: 5.0 }),
            &mut burst,
        )
        .map_err(|e| Error(format!("encode: {e:?}")))?;
        let b = encode(61_001, &Request::Store(StoreOp::Save), &mut burst[a..])
            .map_err(|e| Error(format!("encode: {e:?}")))?;
        let replies = self.raw_replies(&burst[..a + b], 2)?;
        self.client
            .set_command(DriveCommand::Disable)
            .map_err(client_err("disable"))?;
        self.wait_for("disable", DISABLE_EMULATED_S, 1, |t| {
            t.mode == Mode::Disabled
        })?;
        let after = self.client.read_config(ConfigSource::Stored);
        check(
            replies
                == [
                    (61_000, Response::Ack),
                    (61_001, Response::Nack(ErrorCode::NotDisabled)),
                ]
                && matches!(after, Err(ClientError::Nack(ErrorCode::NothingStored))),
            format!("velocity + save in one burst: save refused, nothing stored ({replies:?})"),
        )
    }

    /// The link watchdog armed by the first closed-loop command (1 s, Stop
    /// then Disable): the host sends a velocity command and goes silent
    /// (telemetry reads do not feed it); the motor is stopped, then
    /// disabled with `CommandTimeout` readable; a clear recovers.
    fn link_watchdog(&mut self) -> Result {
        self.client
            .set_command(DriveCommand::Velocity { rad_s: 30.0 })
            .map_err(client_err("velocity"))?;
        self.wait_for("velocity before the silence", 1.0, 3, |t| {
            (t.velocity_rad_s - 30.0).abs() < 2.0
        })?;
        // Silent from here: only reads.
        let (t, after) = self.wait_for("watchdog stop", 2.5, 1, |t| {
            t.mode == Mode::Velocity && t.velocity_rad_s.abs() < 2.0
        })?;
        check(
            t.fault_code == 0,
            format!("silent host: stopped (velocity 0) after {after:.2} s emulated, no fault yet"),
        )?;
        let (t, after2) = self.wait_for("watchdog disable", 2.5, 1, |t| {
            t.mode == Mode::Disabled && t.fault_code != 0
        })?;
        let faults = self.client.faults().map_err(client_err("read faults"))?;
        check(
            faults.set.contains(Fault::CommandTimeout)
                && t.fault_code == Fault::CommandTimeout.code(),
            format!(
                "still silent: disabled with CommandTimeout after {:.2} s more emulated",
                after2
            ),
        )?;
        self.client
            .clear_faults()
            .map_err(client_err("clear faults"))?;
        let faults = self.client.faults().map_err(client_err("read faults"))?;
        check(faults.set.is_empty(), "watchdog fault cleared")
    }
}
