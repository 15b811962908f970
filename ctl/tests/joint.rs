//! Robot joints end to end on the host (design §21): the client library and
//! the `foc-ctl` binary against the simulated device over TCP: the output
//! frame, impedance mode, the joint's settings, homing to an end stop and
//! the link watchdog's impedance reaction.

use foc_bench::scope_step::emulated_setup;
use foc_core::control::joint::Impedance;
use foc_core::control::stage::TimeoutReaction;
use foc_core::control::{Command, Fault, Mode};
use foc_ctl::sim::{Options, SimDevice, SimServer};
use foc_ctl::{Client, ClientError};
use foc_protocol::message::{ErrorCode, HomingState, JointSettings, WatchdogConfig};
use std::net::{SocketAddr, TcpListener};
use std::process::Output;
use std::time::{Duration, Instant};

/// A calibrated simulated drive, with end stops at `stops_rad` \[rotor\].
fn server(stops_rad: (f32, f32)) -> SimServer {
    let mut opts = Options::simulator(emulated_setup());
    opts.end_stops_rad = stops_rad;
    let mut dev = SimDevice::new(opts);
    assert!(dev.drive.calibrate_from_bench());
    SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap()
}

fn client(addr: SocketAddr) -> Client {
    let mut c = Client::connect_tcp(addr).unwrap();
    c.set_timeout(Duration::from_millis(500));
    c
}

fn foc_ctl(addr: SocketAddr, args: &[&str]) -> Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_foc-ctl"))
        .arg("--tcp")
        .arg(addr.to_string())
        .arg("--timeout-ms")
        .arg("500")
        .args(args)
        .output()
        .unwrap()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= 1e-5 * (1.0 + b.abs())
}

/// 20:1 reversed, the output's zero at rotor 3 rad.
fn geared(c: &mut Client) -> JointSettings {
    let j = JointSettings {
        gear_ratio: -20.0,
        rotor_at_zero_rad: 3.0,
        ..c.joint().unwrap()
    };
    c.set_joint(j).unwrap();
    j
}

#[test]
fn impedance_and_telemetry_in_the_output_frame() {
    let server = server((f32::NEG_INFINITY, f32::INFINITY));
    let mut c = client(server.addr());
    let j = geared(&mut c);
    assert_eq!(c.joint().unwrap(), j);
    // The rotor at 0 is the output at (0 - 3) / -20 (the encoder reads
    // the rotor within half a count, 0.77 mrad, 38 urad at the output).
    let t = c.read_telemetry().unwrap();
    assert!((t.position_rad - 0.15).abs() < 4e-5, "{t:?}");
    // Hold the output at 0.1 (rotor 1.0): 2 N m/rad at the output is
    // 5e-3 at the rotor.
    let cmd = Impedance {
        position_rad: 0.1,
        velocity_rad_s: 0.0,
        kp_nm_per_rad: 2.0,
        kd_nm_s_per_rad: 0.02,
        torque_ff_nm: 0.0,
        torque_limit_nm: f32::INFINITY,
    };
    c.set_command(Command::Impedance(cmd)).unwrap();
    let end = Instant::now() + Duration::from_secs(5);
    loop {
        let t = c.read_telemetry().unwrap();
        if t.mode == Mode::Impedance && (t.position_rad - 0.1).abs() < 1e-3 {
            break;
        }
        assert!(Instant::now() < end, "{t:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
    // Far above the rotor's stiffness limit: refused.
    let stiff = Impedance {
        kp_nm_per_rad: 1.0e9,
        ..cmd
    };
    match c.set_command(Command::Impedance(stiff)) {
        Err(ClientError::Nack(ErrorCode::OutOfRange { field: 3 })) => {}
        r => panic!("{r:?}"),
    }
    drop(c);
    let dev = server.stop().unwrap();
    let active = dev.drive.sim.cascade.feedback().active;
    let Command::Impedance(rot) = active else {
        panic!("{active:?}")
    };
    assert!(close(rot.position_rad, 1.0) && close(rot.kp_nm_per_rad, 5e-3));
    assert!(close(rot.kd_nm_s_per_rad, 5e-5));
}

#[test]
fn cli_sets_a_joint_homes_to_an_end_stop_and_shows_the_frames() {
    // The rotor starts at 0; a stop at rotor +1 is output -0.05 with the
    // gear below; the search runs at -0.1 rad/s output = +2 rad/s rotor.
    let server = server((-100.0, 1.0));
    let addr = server.addr();
    let o = foc_ctl(addr, &["joint", "--gear-ratio", "-20", "--offset", "0"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    assert!(out.contains("gear ratio     -20 (rotor turns per output turn, reversed)"));
    assert!(out.contains("travel         none"), "{out}");
    let o = foc_ctl(
        addr,
        &[
            "home",
            "end-stop",
            "--velocity",
            "-0.1",
            "--current",
            "2",
            "--backoff",
            "0.05",
            "--max-travel",
            "0.5",
            "--at",
            "-0.25",
            "--wait-ms",
            "20000",
        ],
    );
    let out = text(&o.stdout);
    assert!(o.status.success(), "{out}\n{}", text(&o.stderr));
    assert!(out.contains("homing: p="), "no progress shown:\n{out}");
    assert!(out.contains("homed: done"), "{out}");
    // The stop (rotor 1) reads -0.25: zero at 1 - (-20)(-0.25) = -4.
    let mut c = client(addr);
    assert_eq!(c.homing_state().unwrap(), HomingState::Done);
    let j = c.joint().unwrap();
    assert!((j.rotor_at_zero_rad + 4.0).abs() < 1e-2, "{j:?}");
    // Backed off 0.05 towards the output's positive side.
    let t = c.read_telemetry().unwrap();
    assert!(t.position_rad > -0.25 && t.position_rad < -0.19, "{t:?}");
    // One connection at a time.
    drop(c);
    // A travel range at the output, then the status with the frames.
    let o = foc_ctl(addr, &["joint", "--travel", "-0.5", "0.5"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stdout).contains("travel         -0.5 .. 0.5 rad (output)"));
    let o = foc_ctl(addr, &["status"]);
    let out = text(&o.stdout);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(
        out.contains("rad (output)") && out.contains("rad (rotor"),
        "{out}"
    );
    assert!(out.contains("homing         done"), "{out}");
}

#[test]
fn homing_without_a_stop_fails_and_disables() {
    let server = server((f32::NEG_INFINITY, f32::INFINITY));
    let o = foc_ctl(
        server.addr(),
        &[
            "home",
            "end-stop",
            "--velocity",
            "2",
            "--current",
            "2",
            "--backoff",
            "0.5",
            "--max-travel",
            "0.5",
        ],
    );
    assert!(!o.status.success());
    assert!(
        text(&o.stderr).contains("no end stop within the longest travel"),
        "{}",
        text(&o.stderr)
    );
    let mut c = client(server.addr());
    assert_eq!(c.read_telemetry().unwrap().mode, Mode::Disabled);
}

#[test]
fn cli_refuses_bad_input_with_the_field_and_changes_nothing() {
    let server = server((f32::NEG_INFINITY, f32::INFINITY));
    let addr = server.addr();
    for (args, field) in [
        (
            &[
                "mode",
                "impedance",
                "--position",
                "0",
                "--kp",
                "-1",
                "--kd",
                "0",
            ][..],
            "`kp_nm_per_rad`",
        ),
        (
            &[
                "mode",
                "impedance",
                "--position",
                "NaN",
                "--kp",
                "1",
                "--kd",
                "0",
            ][..],
            "`position_rad`",
        ),
        (
            &[
                "mode",
                "impedance",
                "--position",
                "0",
                "--kp",
                "1",
                "--kd",
                "9",
            ][..],
            "`kd_nm_s_per_rad`",
        ),
        (&["joint", "--gear-ratio", "0"][..], "`gear_ratio`"),
        (&["joint", "--travel", "1", "-1"][..], "`travel_max_rad`"),
        (&["home", "present", "--at", "inf"][..], "`home_output_rad`"),
    ] {
        let o = foc_ctl(addr, args);
        let err = text(&o.stderr);
        assert!(!o.status.success(), "{args:?}");
        assert!(
            err.contains(field) && err.contains("nothing changed"),
            "{args:?}: {err}"
        );
    }
    let mut c = client(addr);
    let j = c.joint().unwrap();
    assert_eq!((j.gear_ratio, j.travel_out_rad), (1.0, None));
    assert_eq!(c.read_telemetry().unwrap().mode, Mode::Disabled);
    assert_eq!(c.homing_state().unwrap(), HomingState::Idle);
    // A valid one (one connection at a time).
    drop(c);
    let o = foc_ctl(
        addr,
        &[
            "mode",
            "impedance",
            "--position",
            "0.5",
            "--kp",
            "1",
            "--kd",
            "0.1",
        ],
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    let mut c = client(addr);
    assert_eq!(c.read_telemetry().unwrap().mode, Mode::Impedance);
}

#[test]
fn link_watchdog_in_impedance_mode_damps_then_disables() {
    let server = server((f32::NEG_INFINITY, f32::INFINITY));
    let mut c = client(server.addr());
    // 0.2 s (4000 periods at 20 kHz); the configured reaction is replaced
    // by damping in impedance mode.
    c.set_watchdog(WatchdogConfig {
        timeout_periods: 4000,
        reaction: TimeoutReaction::Hold,
    })
    .unwrap();
    c.set_command(Command::Impedance(Impedance {
        position_rad: 1.0,
        velocity_rad_s: 0.0,
        kp_nm_per_rad: 0.5,
        kd_nm_s_per_rad: 0.01,
        torque_ff_nm: 0.0,
        torque_limit_nm: f32::INFINITY,
    }))
    .unwrap();
    // Between the two timeouts: still impedance (damping only), no fault.
    std::thread::sleep(Duration::from_millis(300));
    let t = c.read_telemetry().unwrap();
    assert_eq!(t.mode, Mode::Impedance);
    assert!(c.faults().unwrap().set.is_empty());
    let end = Instant::now() + Duration::from_secs(3);
    while c.faults().unwrap().first() != Some(Fault::CommandTimeout) {
        assert!(Instant::now() < end, "no second reaction");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(c.read_telemetry().unwrap().mode, Mode::Disabled);
}
