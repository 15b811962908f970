//! `cargo xtask qemu`: the firmware in the loop under QEMU.
//!
//! Builds the `qemu` board (QEMU's `netduinoplus2`, an STM32F405, with the
//! bench's motor and inverter plant running on the emulated Cortex-M4F),
//! runs it twice under `qemu-system-arm` with semihosting, decodes its defmt
//! output with `defmt-print`, and checks the exit status:
//!
//! 1. the scripted mission (start-up calibration, velocity step, load step,
//!    position move, injected encoder fault and its clear): must exit 0
//!    (every check passed, no overrun);
//! 2. the same firmware told to panic during the position move: must exit
//!    3 (the panic handler left the bridge in the safe state).
//!
//! QEMU runs with `-icount shift=0,align=off,sleep=off`: virtual time is
//! 1 ns per instruction and idle time is skipped, so every run executes the
//! same instructions in the same order (deterministic, independent of the
//! host's load).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::thread;
use std::time::{Duration, Instant};

use clap::Args;

use crate::boards;
use crate::build::{self, Profile};
use crate::toolchain;
use crate::util::{Error, Result};

/// Exit status of a passed mission.
pub const EXIT_PASSED: i32 = 0;
/// Exit status of the panic run when the bridge ended in the safe state.
pub const EXIT_PANIC_SAFE: i32 = 3;

/// `cargo xtask qemu` options.
#[derive(Debug, Args, Clone)]
pub struct QemuArgs {
    /// Wall-clock limit per run [s].
    #[arg(long, default_value_t = 300)]
    pub timeout: u64,
    /// Run only the mission (skip the forced-panic run).
    #[arg(long)]
    pub no_panic_run: bool,
}

impl Default for QemuArgs {
    fn default() -> Self {
        Self {
            timeout: 300,
            no_panic_run: false,
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

/// Installs `defmt-print` with cargo when it is missing (saying so).
pub fn ensure_defmt_print() -> Result {
    let ok = Command::new("defmt-print")
        .arg("--version")
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if ok {
        return Ok(());
    }
    println!("defmt-print not found: installing it (cargo install defmt-print --locked, about 2 minutes)");
    let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .args(["install", "defmt-print", "--locked", "--version", "^1.2"])
        .status()?;
    if status.success() {
        Ok(())
    } else {
        Err(Error("cargo install defmt-print failed".into()))
    }
}

/// One emulator run: exit status and decoded log lines.
pub struct RunResult {
    /// QEMU's exit status (the firmware's semihosting exit code).
    pub code: Option<i32>,
    /// defmt-print's decoded lines.
    pub lines: Vec<String>,
    /// Wall time.
    pub elapsed: Duration,
}

/// Start `elf` under QEMU (`netduinoplus2`, semihosting arguments `args`,
/// `-icount icount`, USART1 to null, USART2 to `usart2`, e.g. `null` or
/// `tcp:127.0.0.1:PORT,server,nowait`) with its output piped into
/// `defmt-print`. Returns (QEMU, decoder); the decoder's stdout is piped.
pub fn spawn_decoded(
    elf: &Path,
    args: &[&str],
    icount: &str,
    usart2: &str,
) -> Result<(std::process::Child, std::process::Child)> {
    let mut semi = String::from("enable=on,target=native,arg=firmware");
    for a in args {
        semi.push_str(",arg=");
        semi.push_str(a);
    }
    let mut qemu = Command::new("qemu-system-arm")
        .args(["-M", "netduinoplus2", "-nographic", "-monitor", "none"])
        .args(["-serial", "null", "-serial", usart2])
        .args(["-semihosting-config", &semi, "-icount", icount, "-kernel"])
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .map_err(|e| Error(format!("could not start qemu-system-arm: {e}")))?;
    let qemu_out = qemu.stdout.take();
    let decoder = qemu_out
        .ok_or_else(|| Error("no qemu stdout".into()))
        .and_then(|out| {
            Command::new("defmt-print")
                .arg("-e")
                .arg(elf)
                .stdin(Stdio::from(out))
                .stdout(Stdio::piped())
                .stderr(Stdio::inherit())
                .spawn()
                .map_err(|e| Error(format!("could not start defmt-print: {e}")))
        });
    match decoder {
        Ok(d) => Ok((qemu, d)),
        Err(e) => {
            let _ = qemu.kill();
            let _ = qemu.wait();
            Err(e)
        }
    }
}

/// Run `elf` under QEMU with semihosting arguments `args` and `icount`
/// options, streaming the decoded defmt log (echoed when `echo`).
pub fn run(
    elf: &Path,
    args: &[&str],
    icount: &str,
    timeout: Duration,
    echo: bool,
) -> Result<RunResult> {
    let start = Instant::now();
    let (mut qemu, mut decoder) = spawn_decoded(elf, args, icount, "null")?;
    let out = decoder
        .stdout
        .take()
        .ok_or_else(|| Error("no defmt-print stdout".into()))?;
    let reader = thread::spawn(move || {
        let mut lines = Vec::new();
        for line in BufReader::new(out).lines().map_while(|l| l.ok()) {
            if echo {
                println!("  | {line}");
            }
            lines.push(line);
        }
        lines
    });
    let code = loop {
        if let Some(status) = qemu.try_wait()? {
            break status.code();
        }
        if start.elapsed() > timeout {
            let _ = qemu.kill();
            let _ = qemu.wait();
            let _ = decoder.kill();
            return Err(Error(format!(
                "QEMU did not finish within {} s ({})",
                timeout.as_secs(),
                elf.display()
            )));
        }
        thread::sleep(Duration::from_millis(20));
    };
    let _ = decoder.wait();
    let lines = reader
        .join()
        .map_err(|_| Error("log reader panicked".into()))?;
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
    ensure_defmt_print()?;
    let elf = build::build_board(board()?, Profile::Release)?;
    let bench = build::cargo_elf(Profile::Release).with_file_name("bench");
    Ok((elf, bench))
}

/// `cargo xtask qemu`.
pub fn run_cmd(args: &QemuArgs) -> Result {
    let (elf, _) = build_emulated()?;
    let timeout = Duration::from_secs(args.timeout);
    let icount = "shift=0,align=off,sleep=off";

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
        let r = run(&elf, &["panic"], icount, timeout, true)?;
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
    if args.no_panic_run {
        println!("cargo xtask qemu: mission passed (forced-panic run skipped)");
    } else {
        println!("cargo xtask qemu: mission passed; forced panic left the bridge safe");
    }
    Ok(())
}
