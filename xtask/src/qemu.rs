//! `cargo xtask qemu`: the firmware in the loop under QEMU.
//!
//! Builds the `qemu` board (QEMU's `netduinoplus2`, an STM32F405, with the
//! bench's motor and inverter plant running on the emulated Cortex-M4F),
//! runs it under `qemu-system-arm` with semihosting, decodes its defmt
//! output in process (the `defmt-decoder` library, lines formatted as
//! `defmt-print` prints them), and checks the exit status:
//!
//! 1. the scripted mission (start-up calibration, velocity step, load step,
//!    position move, injected encoder fault and its clear): must exit 0
//!    (every check passed, no overrun);
//! 2. the same firmware told to panic during the position move: must exit
//!    3 (the panic handler left the bridge in the safe state);
//! 3. three runs on one configuration store (a host file under
//!    `target/qemu-store/`, semihosting `store=`), with the emulated
//!    absolute sensor (`sensor=absolute`): `store-save` identifies and
//!    saves; `store-boot` starts with the rotor elsewhere and must boot
//!    calibrated from the store, without identifying, within 100 ms, with
//!    no rotor motion before its torque command, which must accelerate the
//!    rotor as the torque constant says; `store-corrupt` (the file
//!    overwritten with pseudo-random bytes) must boot uncalibrated, say so,
//!    and refuse the torque command;
//! 4. two braking runs (`mission=brake`, design §18): the emulated plant
//!    gets a DC link fed by a supply that cannot sink current
//!    (`supply=nonsinking`); the firmware spins the motor up to three
//!    quarters of its no-load speed and commands 0 rad/s, once with the
//!    regen limit only and once with a brake resistor on its chopper
//!    (`brake=2`, ohm). Each must keep the true bus voltage below the
//!    over-voltage threshold, latch no fault and stop within its bound (the
//!    resistor must absorb energy); the run with the resistor must also
//!    stop sooner than the one without. Their figures (peak bus voltage,
//!    stop time, brake energy) are printed.
//!
//! QEMU runs with `-icount shift=0,align=off,sleep=off`: virtual time is
//! 1 ns per instruction and idle time is skipped, so every run executes the
//! same instructions in the same order (deterministic, independent of the
//! host's load).
//!
//! Both runs end in emulated time: the mission bounds every step in its own
//! PWM periods and exits with its verdict, so `--timeout` (host time) is only
//! a backstop for a hung emulator, several times the normal run time.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::thread;
use std::time::{Duration, Instant};

use defmt_decoder::{DecodeError, Frame, Table};

use clap::Args;

use crate::boards;
use crate::build::{self, Profile};
use crate::toolchain;
use crate::util::{Error, Result};

/// Exit status of a passed mission.
pub const EXIT_PASSED: i32 = 0;
/// Exit status of the panic run when the bridge ended in the safe state.
pub const EXIT_PANIC_SAFE: i32 = 3;

/// Default host-time backstop per run [s]. A run takes about a minute
/// here; the mission itself ends in emulated time.
pub const DEFAULT_TIMEOUT_S: u64 = 600;

/// `cargo xtask qemu` options.
#[derive(Debug, Args, Clone)]
pub struct QemuArgs {
    /// Host-time backstop per run [s], for a hung emulator only (the
    /// mission bounds itself in emulated time).
    #[arg(long, default_value_t = DEFAULT_TIMEOUT_S)]
    pub timeout: u64,
    /// Run only the mission (skip the forced-panic run).
    #[arg(long)]
    pub no_panic_run: bool,
    /// Skip the three store runs (save, boot from the store, damaged store).
    #[arg(long)]
    pub no_store_runs: bool,
    /// Only the three store runs (no mission, panic or braking run).
    #[arg(long, conflicts_with = "no_store_runs")]
    pub store_runs_only: bool,
}

impl Default for QemuArgs {
    fn default() -> Self {
        Self {
            timeout: DEFAULT_TIMEOUT_S,
            no_panic_run: false,
            no_store_runs: false,
            store_runs_only: false,
        }
    }
}

/// The emulated board.
pub fn board() -> Result<&'static boards::Board> {
    boards::find("qemu").ok_or_else(|| Error("no `qemu` board in boards.rs".into()))
}

fn qemu_present() -> bool {
    Command::new("qemu-system-arm")
        .arg("--version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

/// Installs `qemu-system-arm` with apt-get when it is missing (Debian and
/// Ubuntu; with sudo when not root), saying so; elsewhere fails with an
/// install hint.
pub fn ensure_qemu() -> Result {
    if qemu_present() {
        return Ok(());
    }
    let hint = "qemu-system-arm not found: install it (Debian/Ubuntu: `sudo apt-get install qemu-system-arm`)";
    let apt = Command::new("apt-get")
        .arg("--version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !apt {
        return Err(Error(hint.into()));
    }
    let root = Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false);
    println!("qemu-system-arm not found: installing it with apt-get (Debian's qemu-system-arm)");
    let apt_get = |args: &[&str]| -> bool {
        let mut cmd = if root {
            Command::new("apt-get")
        } else {
            let mut c = Command::new("sudo");
            c.arg("apt-get");
            c
        };
        cmd.args(args)
            .env("DEBIAN_FRONTEND", "noninteractive")
            .stdin(Stdio::null())
            .status()
            .map(|s| s.success())
            .unwrap_or(false)
    };
    let ok = apt_get(&["update"])
        && apt_get(&[
            "install",
            "-y",
            "--no-install-recommends",
            "qemu-system-arm",
        ]);
    if ok && qemu_present() {
        Ok(())
    } else {
        Err(Error(format!("installing qemu-system-arm failed; {hint}")))
    }
}

/// One emulator run: exit status and decoded log lines.
pub struct RunResult {
    /// QEMU's exit status (the firmware's semihosting exit code).
    pub code: Option<i32>,
    /// The decoded defmt log, one line per message (see [`format_frame`]).
    pub lines: Vec<String>,
    /// Wall time.
    pub elapsed: Duration,
}

/// Reads the defmt table of `elf` (its `.defmt` section).
pub fn defmt_table(elf: &Path) -> Result<Table> {
    let bytes =
        std::fs::read(elf).map_err(|e| Error(format!("could not read {}: {e}", elf.display())))?;
    Table::parse(&bytes)
        .map_err(|e| Error(format!("defmt table of {}: {e}", elf.display())))?
        .ok_or_else(|| Error(format!("{}: no defmt data (.defmt section)", elf.display())))
}

/// One decoded frame as `defmt-print` prints it by default: `LEVEL message`
/// with the level padded to five columns (`INFO  ...`, `ERROR ...`), the
/// message alone for a frame without level (`defmt::println!`), preceded by
/// the timestamp when the firmware defines one.
pub fn format_frame(frame: &Frame<'_>, with_timestamp: bool) -> String {
    let mut line = String::new();
    if with_timestamp {
        if let Some(ts) = frame.display_timestamp() {
            line.push_str(&format!("{ts} "));
        }
    }
    match frame.level() {
        Some(level) => {
            let level = level.as_str().to_uppercase();
            line.push_str(&format!("{level:<5} {}", frame.display_message()));
        }
        None => line.push_str(&frame.display_message().to_string()),
    }
    line
}

/// Decodes the defmt stream of `out` with `table` and sends one line per
/// message (a message with line breaks gives several) until `out` ends.
/// Malformed frames are skipped (rzCOBS resynchronises at the next frame);
/// with an encoding that cannot recover, one line says so and the rest is
/// read and dropped, so that QEMU never blocks on a full pipe.
fn decode_stream(table: Table, mut out: impl Read, tx: Sender<String>) {
    let with_timestamp = table.has_timestamp();
    let can_recover = table.encoding().can_recover();
    let mut decoder = table.new_stream_decoder();
    let mut broken = false;
    let mut buf = [0u8; 4096];
    loop {
        let n = match out.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(_) => break,
        };
        if broken {
            continue;
        }
        decoder.received(&buf[..n]);
        loop {
            match decoder.decode() {
                Ok(frame) => {
                    for line in format_frame(&frame, with_timestamp).lines() {
                        // A closed receiver: keep draining QEMU's output.
                        let _ = tx.send(line.to_string());
                    }
                }
                Err(DecodeError::UnexpectedEof) => break,
                Err(DecodeError::Malformed) if can_recover => continue,
                Err(DecodeError::Malformed) => {
                    let _ = tx.send(
                        "(HOST) malformed defmt frame: the encoding cannot recover, \
                         decoding stopped"
                            .to_string(),
                    );
                    broken = true;
                    break;
                }
            }
        }
    }
}

/// Decode `out` (QEMU's stdout, the firmware's defmt frames) with `table`
/// in a thread; returns the receiving end of its lines, which closes when
/// `out` does (QEMU exited or was killed).
fn spawn_decoder(table: Table, out: ChildStdout) -> Result<Receiver<String>> {
    let (tx, rx) = mpsc::channel();
    thread::Builder::new()
        .name("defmt-decoder".into())
        .spawn(move || decode_stream(table, out, tx))
        .map_err(|e| Error(format!("could not start the defmt decoder thread: {e}")))?;
    Ok(rx)
}

/// Start `elf` under QEMU (`netduinoplus2`, semihosting arguments `args`,
/// `-icount icount`, USART1 to null, USART2 to `usart2`, e.g. `null` or
/// `tcp:127.0.0.1:PORT,server,nowait`) with its output decoded in process.
/// Returns QEMU and the decoded log lines (see [`format_frame`]); the
/// channel closes when QEMU exits.
pub fn spawn_decoded(
    elf: &Path,
    args: &[&str],
    icount: &str,
    usart2: &str,
) -> Result<(Child, Receiver<String>)> {
    spawn_decoded_serials(elf, args, icount, &["null", usart2])
}

/// [`spawn_decoded`] with every `-serial` device given, in order: QEMU's
/// stm32f405 maps them onto USART1, USART2, USART3, ... (the emulated
/// board's CAN port is the third, USART3).
pub fn spawn_decoded_serials(
    elf: &Path,
    args: &[&str],
    icount: &str,
    serials: &[&str],
) -> Result<(Child, Receiver<String>)> {
    // Read the table first: a bad ELF fails before QEMU starts.
    let table = defmt_table(elf)?;
    let mut semi = String::from("enable=on,target=native,arg=firmware");
    for a in args {
        semi.push_str(",arg=");
        semi.push_str(a);
    }
    let mut qemu = Command::new("qemu-system-arm");
    qemu.args(["-M", "netduinoplus2", "-nographic", "-monitor", "none"]);
    for s in serials {
        qemu.args(["-serial", s]);
    }
    let mut qemu = qemu
        .args(["-semihosting-config", &semi, "-icount", icount, "-kernel"])
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| Error(format!("could not start qemu-system-arm: {e}")))?;
    let lines = qemu
        .stdout
        .take()
        .ok_or_else(|| Error("no qemu stdout".into()))
        .and_then(|out| spawn_decoder(table, out));
    match lines {
        Ok(rx) => Ok((qemu, rx)),
        Err(e) => {
            let _ = qemu.kill();
            let _ = qemu.wait();
            Err(e)
        }
    }
}

/// Run `elf` under QEMU with semihosting arguments `args` and `icount`
/// options, collecting the decoded defmt log (echoed when `echo`). `timeout`
/// is a host-time backstop: QEMU is killed and the run fails past it.
pub fn run(
    elf: &Path,
    args: &[&str],
    icount: &str,
    timeout: Duration,
    echo: bool,
) -> Result<RunResult> {
    let start = Instant::now();
    let (mut qemu, rx) = spawn_decoded(elf, args, icount, "null")?;
    let mut lines = Vec::new();
    loop {
        match rx.recv_timeout(Duration::from_millis(20)) {
            Ok(line) => {
                if echo {
                    println!("  | {line}");
                }
                lines.push(line);
            }
            // QEMU's stdout closed: it exited (or closed it); wait below.
            Err(RecvTimeoutError::Disconnected) => break,
            Err(RecvTimeoutError::Timeout) => {}
        }
        if start.elapsed() > timeout {
            let _ = qemu.kill();
            let _ = qemu.wait();
            return Err(Error(format!(
                "QEMU did not finish within {} s host time (backstop; {})",
                timeout.as_secs(),
                elf.display()
            )));
        }
    }
    let code = loop {
        if let Some(status) = qemu.try_wait()? {
            break status.code();
        }
        if start.elapsed() > timeout {
            let _ = qemu.kill();
            let _ = qemu.wait();
            return Err(Error(format!(
                "QEMU did not exit within {} s host time (backstop; {})",
                timeout.as_secs(),
                elf.display()
            )));
        }
        thread::sleep(Duration::from_millis(20));
    };
    Ok(RunResult {
        code,
        lines,
        elapsed: start.elapsed(),
    })
}

/// Build the emulated board's firmware; returns the firmware and bench ELFs.
pub fn build_emulated() -> Result<(PathBuf, PathBuf)> {
    toolchain::ensure(true, &["llvm-tools"])?;
    ensure_qemu()?;
    let elf = build::build_board(board()?, Profile::Release)?;
    let bench = build::cargo_elf(Profile::Release).with_file_name("bench");
    Ok((elf, bench))
}

/// `cargo xtask qemu`.
pub fn run_cmd(args: &QemuArgs) -> Result {
    let (elf, _) = build_emulated()?;
    let timeout = Duration::from_secs(args.timeout);
    let icount = "shift=0,align=off,sleep=off";
    if args.store_runs_only {
        store_runs(&elf, icount, timeout)?;
        println!("cargo xtask qemu: store saved, booted from it, damaged store refused");
        return Ok(());
    }

    println!("== mission run (expect exit status {EXIT_PASSED})");
    let r = run(&elf, &[], icount, timeout, true)?;
    let passes = r
        .lines
        .iter()
        .filter(|l| l.contains("mission: PASS"))
        .count();
    let fails = r
        .lines
        .iter()
        .filter(|l| l.contains("mission: FAIL"))
        .count();
    println!(
        "mission: exit status {:?}, {passes} checks passed, {fails} failed, {:.1} s",
        r.code,
        r.elapsed.as_secs_f32()
    );
    if r.code != Some(EXIT_PASSED) || fails > 0 || passes == 0 {
        return Err(Error(format!(
            "QEMU mission failed (exit status {:?}, {fails} failed checks)",
            r.code
        )));
    }

    if !args.no_panic_run {
        println!("== forced-panic run (expect exit status {EXIT_PANIC_SAFE}: bridge safe)");
        let r = run(&elf, &["mission=panic"], icount, timeout, true)?;
        println!(
            "panic run: exit status {:?}, {:.1} s",
            r.code,
            r.elapsed.as_secs_f32()
        );
        if r.code != Some(EXIT_PANIC_SAFE) {
            return Err(Error(format!(
                "forced panic did not end in the safe state (exit status {:?}, expected {EXIT_PANIC_SAFE})",
                r.code
            )));
        }
    }
    let brake = brake_runs(&elf, icount, timeout)?;
    if !args.no_store_runs {
        store_runs(&elf, icount, timeout)?;
    }
    println!(
        "cargo xtask qemu: mission passed{}; {brake}{}",
        if args.no_panic_run {
            " (forced-panic run skipped)"
        } else {
            "; forced panic left the bridge safe"
        },
        if args.no_store_runs {
            " (store runs skipped)"
        } else {
            "; store saved, booted from it, damaged store refused"
        }
    );
    Ok(())
}

/// The braking runs (design §18): `mission=brake` on a DC link fed by a
/// supply that cannot sink current, without and with a brake resistor.
/// Returns a one-line summary.
fn brake_runs(elf: &Path, icount: &str, timeout: Duration) -> Result<String> {
    let regen = brake_run(elf, icount, timeout, "regen limit only", &[])?;
    let chopper = brake_run(
        elf,
        icount,
        timeout,
        "brake resistor 2 ohm",
        &[BRAKE_RESISTOR_ARG],
    )?;
    if chopper.stop_s >= regen.stop_s {
        return Err(Error(format!(
            "the stop with the brake resistor ({:.3} s) is not faster than on the regen limit alone ({:.3} s)",
            chopper.stop_s, regen.stop_s
        )));
    }
    Ok(format!(
        "braked into a non-sinking supply: peak {:.2} V / {:.2} V, stopped in {:.3} s / {:.3} s (regen limit / brake resistor, {:.2} J in the resistor)",
        regen.peak_v, chopper.peak_v, regen.stop_s, chopper.stop_s, chopper.brake_j
    ))
}

/// The brake resistor of the second braking run [ohm]: the ODrive v3's
/// (and the plant preset's) 2 ohm.
const BRAKE_RESISTOR_ARG: &str = "brake=2";

/// Figures of one braking run, parsed from its `brake:` line.
struct BrakeFigures {
    peak_v: f32,
    stop_s: f32,
    brake_j: f32,
}

/// The number that follows `key` in `line` (`"peak bus "` -> 28.61).
fn figure_after(line: &str, key: &str) -> Option<f32> {
    let rest = &line[line.find(key)? + key.len()..];
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || matches!(c, '.' | '-' | 'e' | '+')))
        .unwrap_or(rest.len());
    rest[..end].parse().ok()
}

/// One braking run with the extra semihosting arguments `extra`: passes
/// when the mission exits 0 with no failed check and its figures were
/// logged.
fn brake_run(
    elf: &Path,
    icount: &str,
    timeout: Duration,
    what: &str,
    extra: &[&str],
) -> Result<BrakeFigures> {
    let mut args = vec!["mission=brake", "supply=nonsinking"];
    args.extend_from_slice(extra);
    println!(
        "== braking run, {what} ({}; expect exit status {EXIT_PASSED})",
        args.join(" ")
    );
    let r = run(elf, &args, icount, timeout, true)?;
    let count = |t: &str| r.lines.iter().filter(|l| l.contains(t)).count();
    let (passes, fails) = (count("mission: PASS"), count("mission: FAIL"));
    let line = r.lines.iter().find(|l| l.contains("brake: peak bus"));
    let figures = line.and_then(|l| {
        Some(BrakeFigures {
            peak_v: figure_after(l, "peak bus ")?,
            stop_s: figure_after(l, " after ")?,
            brake_j: figure_after(l, "brake energy ")?,
        })
    });
    let simulated_s = r
        .lines
        .iter()
        .find_map(|l| figure_after(l, "brake: run ended at "));
    println!(
        "brake ({what}): exit status {:?}, {passes} checks passed, {fails} failed, {:.1} s simulated, {:.1} s wall",
        r.code,
        simulated_s.unwrap_or(f32::NAN),
        r.elapsed.as_secs_f32()
    );
    if let Some(l) = line {
        println!("brake ({what}): {}", l.trim_start_matches("INFO  brake: "));
    }
    match figures {
        Some(f) if r.code == Some(EXIT_PASSED) && fails == 0 && passes > 0 => Ok(f),
        _ => Err(Error(format!(
            "braking run ({what}) failed (exit status {:?}, {fails} failed checks{})",
            r.code,
            if line.is_none() {
                ", no figures logged"
            } else {
                ""
            }
        ))),
    }
}

/// Rotor angle at reset of the boot runs [rad]: not where run 1 identified
/// (0 rad), so a stored electrical zero is only right if the sensor really
/// reads the absolute angle.
const BOOT_ROTOR_RAD: &str = "2.1";

/// One store run: `mission` on the store file `store`; passes when the
/// mission exits 0 with no failed check and every `must` text appears in
/// the log and no `must_not` text does.
fn store_run(
    elf: &Path,
    icount: &str,
    timeout: Duration,
    store: &Path,
    (mission, rotor): (&str, &str),
    must: &[&str],
    must_not: &[&str],
) -> Result<RunResult> {
    println!("== store run `{mission}` (rotor at {rotor} rad, absolute sensor)");
    let store_arg = format!("store={}", store.display());
    let mission_arg = format!("mission={mission}");
    let rotor_arg = format!("rotor={rotor}");
    let args = [
        store_arg.as_str(),
        "sensor=absolute",
        rotor_arg.as_str(),
        mission_arg.as_str(),
    ];
    let r = run(elf, &args, icount, timeout, true)?;
    let fails = r
        .lines
        .iter()
        .filter(|l| l.contains("mission: FAIL"))
        .count();
    let passes = r
        .lines
        .iter()
        .filter(|l| l.contains("mission: PASS"))
        .count();
    println!(
        "{mission}: exit status {:?}, {passes} checks passed, {fails} failed, {:.1} s",
        r.code,
        r.elapsed.as_secs_f32()
    );
    let has = |t: &str| r.lines.iter().any(|l| l.contains(t));
    let missing: Vec<_> = must.iter().filter(|t| !has(t)).collect();
    let present: Vec<_> = must_not.iter().filter(|t| has(t)).collect();
    if r.code != Some(EXIT_PASSED)
        || fails > 0
        || passes == 0
        || !missing.is_empty()
        || !present.is_empty()
    {
        return Err(Error(format!(
            "store run `{mission}` failed (exit status {:?}, {fails} failed checks; log lacks {missing:?}; log has {present:?})",
            r.code
        )));
    }
    Ok(r)
}

/// Overwrite `file` with pseudo-random bytes (a fixed xorshift sequence):
/// a store damaged beyond what a power cut can do.
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

/// The store runs (design §17): three boots of the firmware on one store
/// file (semihosting `store=`), with the emulated absolute sensor.
fn store_runs(elf: &Path, icount: &str, timeout: Duration) -> Result {
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
    store_run(
        elf,
        icount,
        timeout,
        &store,
        ("store-save", "0"),
        &["store: empty", "identifying the motor", "store: saved"],
        &[],
    )?;
    let r = store_run(
        elf,
        icount,
        timeout,
        &store,
        ("store-boot", BOOT_ROTOR_RAD),
        &["store: loaded", "calibrated from the store"],
        &["identifying the motor"],
    )?;
    for l in r.lines.iter().filter(|l| {
        l.contains("calibrated from the store") && l.contains("ms after reset")
            || l.contains("speed gained")
    }) {
        println!("store-boot: {}", l.trim_start_matches("INFO  mission: "));
    }
    damage(&store)?;
    store_run(
        elf,
        icount,
        timeout,
        &store,
        ("store-corrupt", BOOT_ROTOR_RAD),
        &["build-time defaults, uncalibrated"],
        &[
            "store: loaded",
            "store: empty",
            "identifying the motor",
            "calibrated from the store",
        ],
    )?;
    Ok(())
}
