//! `cargo xtask qemu`: the firmware in the loop under QEMU.
//!
//! Builds the `qemu` board (QEMU's `netduinoplus2`, an STM32F405, with the
//! bench's motor and inverter plant running on the emulated Cortex-M4F) and
//! drives it from the host ([`crate::fil`]): the firmware is the product
//! with the emulated board and nothing else. Each scenario commands the
//! drive over its command link (USART2) and loads the motor, injects faults
//! and reads the true state through the emulated board's instrument port
//! (USART1):
//!
//! 1. the main scenario: start-up identification checked against the
//!    plant, velocity step, load step, position move, an encoder jump and
//!    its clear, the timer's break input and its clear, a run without the
//!    encoder (a `[sensorless]` record applied over the link: start,
//!    reversal, back on the encoder), no overrun;
//! 2. a panic of the emulated hardware during a position move: the
//!    firmware's panic handler must leave the bridge safe (exit status 3);
//! 3. two braking runs (design §18) on a DC link fed by a supply that
//!    cannot sink current (`supply=nonsinking`), once on the regen limit,
//!    once with a 2 ohm brake resistor (`brake=2`): the true bus stays
//!    below the over-voltage trip, no fault, the rotor stops within its
//!    bound;
//! 4. three runs on one configuration store (a host file under
//!    `target/qemu-store/`, semihosting `store=`) with the emulated absolute
//!    sensor: identify and save; boot from the store with the rotor
//!    elsewhere (calibrated within 100 ms, no identification, no motion
//!    before the first command, torque as the torque constant says); boot
//!    from the damaged file (`identify=off`, as a real board boots):
//!    uncalibrated, the torque command refused.
//!
//! QEMU runs with `-icount shift=0,align=off,sleep=off`: virtual time is
//! 1 ns per instruction and idle time is skipped, so every run executes the
//! same instructions in the same order (deterministic, independent of the
//! host's load).
//!
//! Every wait is bounded in emulated time (the firmware's period counter or
//! the plant's clock); host time is only a backstop for a hung emulator.

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

/// `cargo xtask qemu` options.
#[derive(Debug, Args, Clone, Default)]
pub struct QemuArgs {
    /// Echo the firmware's whole log (default: warnings and errors).
    #[arg(long)]
    pub verbose: bool,
    /// Skip the forced-panic run.
    #[arg(long)]
    pub no_panic_run: bool,
    /// Skip the three store runs (save, boot from the store, damaged store).
    #[arg(long)]
    pub no_store_runs: bool,
    /// Only the three store runs (no main, panic or braking run).
    #[arg(long, conflicts_with = "no_store_runs")]
    pub store_runs_only: bool,
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
    Ok(RunResult { code, lines })
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
    let v = args.verbose;
    if args.store_runs_only {
        crate::fil::store_scenarios(&elf, v)?;
        println!("cargo xtask qemu: store saved, booted from it, damaged store refused");
        return Ok(());
    }
    crate::fil::main_scenario(&elf, v)?;
    if !args.no_panic_run {
        crate::fil::panic_scenario(&elf, v)?;
    }
    let regen = crate::fil::brake_scenario(&elf, false, v)?;
    let chopper = crate::fil::brake_scenario(&elf, true, v)?;
    if chopper.1 >= regen.1 {
        return Err(Error(format!(
            "the stop with the brake resistor ({:.3} s) is not faster than on the regen limit alone ({:.3} s)",
            chopper.1, regen.1
        )));
    }
    if !args.no_store_runs {
        crate::fil::store_scenarios(&elf, v)?;
    }
    println!(
        "cargo xtask qemu: main scenario passed{}; braked into a non-sinking supply: peak {:.2} V / {:.2} V, stopped in {:.3} s / {:.3} s (regen limit / brake resistor, {:.2} J in the resistor){}",
        if args.no_panic_run {
            " (forced-panic run skipped)"
        } else {
            "; forced panic left the bridge safe"
        },
        regen.0,
        chopper.0,
        regen.1,
        chopper.1,
        chopper.2,
        if args.no_store_runs {
            " (store runs skipped)"
        } else {
            "; store saved, booted from it, damaged store refused"
        }
    );
    Ok(())
}
