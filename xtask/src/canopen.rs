//! CANopen on the host test bus (issue 22): a third-party master (the
//! Python `canopen` package over `python-can`) against several drives, each
//! the real drive code with its own simulated motor, on `foc-canbus`'s
//! virtual bus; the EDS is the checked-in one the drive's object
//! dictionary generates (checked by `cargo test -p foc-canopen --test eds`).
//!
//! Then the emulated firmware joins the bus ([`firmware_on_bus`]): the
//! `qemu` board (release) runs under QEMU with its CAN port (SLCAN on
//! USART3, QEMU's third `-serial`) on a loopback TCP server, and
//! `foc-canbus --relay` makes it a participant next to two hosted drives
//! (node IDs 2 and 3; the firmware is node 1, its stored default). The
//! master's tests of it are `canbus/master/test_firmware.py` (skipped
//! without `FOC_FIRMWARE_BUS`, so the discovery run above leaves them out).
//!
//! The Python packages are pinned and installed into the project's virtual
//! environment (target/python-venv) from PyPI when missing.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::thread;
use std::time::{Duration, Instant};

use crate::util::{cargo, display, root, run, target_dir, Error, Result};
use crate::{e2e, qemu};

/// The master's packages, pinned (the versions the tests were written
/// against).
pub const PACKAGES: [&str; 3] = ["python-can==4.6.1", "canopen==2.4.1", "pyserial==3.5"];

/// Host-time limit of the firmware's tests (QEMU start to the last
/// check); QEMU and the bus are killed past it.
pub const FIRMWARE_LIMIT: Duration = Duration::from_secs(600);

/// Build the bus, install the master's packages, run the master's tests,
/// then the emulated firmware's on the same bus.
pub fn run_tests() -> Result {
    run(cargo(["build", "-p", "foc-canbus"]))?;
    let bus = target_dir().join("debug").join("foc-canbus");
    if !bus.exists() {
        return Err(Error(format!("{} was not built", bus.display())));
    }
    let python = crate::python::venv()?;
    let mut pip = crate::python::pip(&python);
    pip.args(PACKAGES);
    run(pip)?;
    let mut t = master(&python, &bus);
    t.args(["-m", "unittest", "discover", "-s", "canbus/master", "-v"]);
    run(t)?;
    firmware_on_bus(&python, &bus)
}

/// The master's Python with the rig's environment.
fn master(python: &Path, bus: &Path) -> Command {
    let mut t = Command::new(python);
    t.current_dir(root())
        .env("FOC_CANBUS", bus)
        .env("FOC_EDS", root().join("docs/canopen/foc-drive.eds"))
        .env("PYTHONPATH", root().join("canbus/master"));
    t
}

/// A child process killed (and reaped) on drop.
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The emulated firmware on the host test bus (module docs): QEMU with
/// USART3 on `tcp:127.0.0.1:PORT,server=on,wait=on` (the guest starts
/// once the bus has connected, so its boot-up message reaches the bus),
/// `foc-canbus --nodes 2 --first-id 2 --relay tcp:127.0.0.1:PORT`, then
/// `test_firmware.py` with `FOC_FIRMWARE_BUS` = the bus's port. Bounded by
/// [`FIRMWARE_LIMIT`]; QEMU and the bus are killed at the end.
pub fn firmware_on_bus(python: &Path, bus: &Path) -> Result {
    let (elf, _) = qemu::build_emulated()?;
    let port = e2e::free_port()?;
    let mut qemu = spawn_firmware(&elf, port)?;
    let (mut child, bus_port) = spawn_relay(bus, port)?;
    let mut t = firmware_tests(python, bus, bus_port);
    println!("$ {}", display(&t));
    let mut tests = Killed(t.spawn()?);
    let start = Instant::now();
    let status = wait_for_tests(&mut tests, &mut qemu, start)?;
    // Shut the bus down (QEMU is killed when `qemu` drops).
    if let Some(stdin) = child.0.stdin.as_mut() {
        let _ = writeln!(stdin, "quit");
    }
    match status {
        Some(s) if s.success() => {
            println!(
                "firmware on the CAN bus: passed ({:.0} s)",
                start.elapsed().as_secs_f32()
            );
            Ok(())
        }
        Some(s) => Err(Error(format!("the firmware's CAN tests failed ({s})"))),
        None => Err(Error("the firmware's CAN tests did not finish".into())),
    }
}

/// QEMU running the firmware `elf` with USART3 (the CAN port, SLCAN) on a
/// TCP server at `port` that waits for the bus; the firmware's warnings,
/// errors and CAN lines are printed as they come.
fn spawn_firmware(elf: &Path, port: u16) -> Result<Killed> {
    let usart3 = format!("tcp:127.0.0.1:{port},server=on,wait=on");
    println!("QEMU: USART3 (CAN as SLCAN) on {usart3}");
    // The drive is run from outside only (the firmware has no scripts).
    let (qemu, lines) = qemu::spawn_decoded_serials(
        elf,
        &[],
        "shift=0,align=off,sleep=off",
        &["null", "null", &usart3],
    )?;
    let qemu = Killed(qemu);
    // The firmware's log: warnings, errors and the CAN lines (ends when
    // QEMU's output closes).
    thread::spawn(move || {
        for line in lines {
            if line.contains("WARN") || line.contains("ERROR") || line.contains("can:") {
                println!("  | {line}");
            }
        }
    });
    Ok(qemu)
}

/// `foc-canbus` (`bus`) with two hosted drives (node IDs 2 and 3),
/// relaying to the firmware's port `port`; returns it and the port its
/// master side listens on (from its first line, `listening ADDR:PORT`).
fn spawn_relay(bus: &Path, port: u16) -> Result<(Killed, u16)> {
    let relay = format!("tcp:127.0.0.1:{port}");
    let mut cmd = Command::new(bus);
    cmd.args([
        "--nodes",
        "2",
        "--first-id",
        "2",
        "--port",
        "0",
        "--relay",
        &relay,
    ])
    .stdin(Stdio::piped())
    .stdout(Stdio::piped());
    println!("$ {}", display(&cmd));
    let mut child = Killed(
        cmd.spawn()
            .map_err(|e| Error(format!("could not start {}: {e}", bus.display())))?,
    );
    let out = child
        .0
        .stdout
        .take()
        .ok_or_else(|| Error("no foc-canbus stdout".into()))?;
    let mut out = BufReader::new(out);
    let mut line = String::new();
    out.read_line(&mut line)?;
    let bus_port = line
        .trim()
        .strip_prefix("listening ")
        .and_then(|a| a.rsplit(':').next())
        .and_then(|p| p.parse::<u16>().ok())
        .ok_or_else(|| Error(format!("foc-canbus did not start: {line:?}")))?;
    Ok((child, bus_port))
}

/// The master's `test_firmware.py`, against the bus at `bus_port`
/// (`FOC_FIRMWARE_BUS`).
fn firmware_tests(python: &Path, bus: &Path, bus_port: u16) -> Command {
    let mut t = master(python, bus);
    t.env("FOC_FIRMWARE_BUS", bus_port.to_string()).args([
        "-m",
        "unittest",
        "discover",
        "-s",
        "canbus/master",
        "-p",
        "test_firmware.py",
        "-v",
    ]);
    t
}

/// Wait for the master's `tests` to end: their exit status, or `None` if
/// QEMU exited first or [`FIRMWARE_LIMIT`] passed since `start`.
fn wait_for_tests(
    tests: &mut Killed,
    qemu: &mut Killed,
    start: Instant,
) -> Result<Option<ExitStatus>> {
    Ok(loop {
        if let Some(s) = tests.0.try_wait()? {
            break Some(s);
        }
        if let Some(s) = qemu.0.try_wait()? {
            println!("QEMU exited early ({s})");
            break None;
        }
        if start.elapsed() > FIRMWARE_LIMIT {
            println!(
                "the firmware's tests did not end within {} s: stopped",
                FIRMWARE_LIMIT.as_secs()
            );
            break None;
        }
        thread::sleep(Duration::from_millis(100));
    })
}
