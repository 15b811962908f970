//! The `foc-sil` binary driven through its pipes: the bench plant on this
//! side, the controller in the child process, one JSON line each way per
//! PWM period.

use foc_bench::motor_file::MotorFile;
use foc_bench::plant::{Measurements, Mechanics, Plant};
use serde_json::Value;
use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Command, Stdio};

fn line_of(m: &Measurements, extra: &str) -> String {
    let i = m.currents.to_abc();
    format!(
        r#"{{"t":{},"i_abc":[{},{},{}],"v_bus":{},"theta_m":{}{extra}}}"#,
        m.time_s,
        i.a,
        i.b,
        i.c,
        m.v_bus_v,
        m.angle.to_radians()
    )
}

#[test]
fn sil_binary_closes_the_loop_and_survives_bad_lines() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/motors/dji-m2006.toml");
    let file = MotorFile::load(path).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_foc-sil"))
        .args(["--motor", path])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let mut exchange = |line: &str| -> Value {
        writeln!(stdin, "{line}").unwrap();
        stdin.flush().unwrap();
        let mut reply = String::new();
        stdout.read_line(&mut reply).unwrap();
        serde_json::from_str(&reply).unwrap_or_else(|e| panic!("{e}: {reply}"))
    };

    // Plant with the encoder on the d axis (the binary's default calibration).
    let mut plant = Plant::new(file.motor_params(), file.bench_config());
    plant.set_mechanics(Mechanics::Locked);
    plant.set_rotor_angle(0.4);
    let mut m = plant.step_period([0.5; 3], false, 0.0);
    let target = 2.0;
    let mut last = Value::Null;
    for k in 0..300 {
        let extra = if k == 0 {
            format!(r#","cmd":{{"mode":"torque","target":{target}}}"#)
        } else {
            String::new()
        };
        let out = exchange(&line_of(&m, &extra));
        let d: Vec<f32> = out["duties"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap() as f32)
            .collect();
        assert_eq!(d.len(), 3);
        assert!(d.iter().all(|x| (0.0..=1.0).contains(x)));
        let on = out["bridge"].as_bool().unwrap();
        m = plant.step_period([d[0], d[1], d[2]], on, 0.0);
        last = out;
    }
    assert_eq!(last["mode"], "torque");
    assert!(last["fault"].is_null());
    // The controller's iq and the plant's true iq are at the target.
    assert!(
        (last["iq"].as_f64().unwrap() - target).abs() < 0.05,
        "{last}"
    );
    assert!((plant.iq_a() - target).abs() < 0.05, "iq {}", plant.iq_a());
    assert!(plant.id_a().abs() < 0.05);
    // theta_e reported for the d axis: p * 0.4 rad.
    let th = last["theta_e"].as_f64().unwrap();
    let expect = (7.0 * 0.4f64).rem_euclid(std::f64::consts::TAU);
    assert!((th - expect).abs() < 0.01, "theta_e {th} vs {expect}");

    // A malformed line: safe output line, latched fault, process alive.
    let out = exchange(r#"{"t": 1.0, "i_abc": [0.1, oops"#);
    assert_eq!(out["duties"], serde_json::json!([0.5, 0.5, 0.5]));
    assert_eq!(out["bridge"], false);
    assert_eq!(out["mode"], "disabled");
    assert_eq!(out["fault"], "CurrentSenseError");
    assert!(out["error"].as_str().unwrap().contains("bad input line"));
    // Unknown mode: refused, reported, the fault stays latched.
    let out = exchange(&line_of(&m, r#","cmd":{"mode":"warp","target":1}"#));
    assert!(out["error"].as_str().unwrap().contains("unknown mode"));
    assert_eq!(out["bridge"], false);
    // Clear and command again: running.
    let out = exchange(&line_of(
        &m,
        r#","clear_faults":true,"cmd":{"mode":"torque","target":1.0}"#,
    ));
    assert!(out["fault"].is_null(), "{out}");
    assert!(out["error"].is_null(), "{out}");
    // Cleared and commanded in the same period.
    assert_eq!(out["mode"], "torque", "{out}");
    assert_eq!(out["bridge"], true);
    let out = exchange(&line_of(&m, ""));
    assert_eq!(out["mode"], "torque", "{out}");
    assert_eq!(out["bridge"], true);

    drop(stdin);
    let status = child.wait().unwrap();
    assert!(status.success());
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert!(err.contains("line 301: bad input line"), "{err}");
    assert!(err.contains("unknown mode"), "{err}");
}

/// Without a calibration permit the SIL runner refuses closed-loop commands
/// (`NotCalibrated`) and runs open loop; with one it runs torque mode.
#[test]
fn sil_runner_needs_a_calibration_for_closed_loop() {
    use foc_bench::mission::Setup;
    use foc_bench::sil::SilRunner;
    use foc_core::calibration::Calibrated;
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/motors/dji-m2006.toml");
    let config = Setup::load(path).unwrap().cascade_config();
    let line =
        |cmd: &str| format!(r#"{{"t":0,"i_abc":[0,0,0],"v_bus":24,"theta_m":0,"cmd":{cmd}}}"#);
    let mut sil = SilRunner::new(config);
    let (out, err) = sil.line(&line(r#"{"mode":"torque","target":1}"#));
    assert!(err.unwrap().contains("NotCalibrated"), "{out}");
    assert!(out.contains(r#""mode":"disabled""#), "{out}");
    let (out, err) = sil.line(&line(r#"{"mode":"open_loop","v_d":0.5}"#));
    assert!(
        err.is_none() && out.contains(r#""mode":"open_loop""#),
        "{out}"
    );
    let permit = Calibrated::supplied(config.current.angle, config.current.current).unwrap();
    let mut sil = SilRunner::with_calibration(config, &permit);
    let (out, err) = sil.line(&line(r#"{"mode":"torque","target":1}"#));
    assert!(err.is_none() && out.contains(r#""mode":"torque""#), "{out}");
}

/// `foc-sil --sensor sensorless` (design §27): lines without an angle,
/// a torque command refused (`NeedsAngleSensor`), a velocity command that
/// starts the free plant from standstill and brings it to 0.3 of the top
/// speed in the commanded direction, the angle a line still carries
/// ignored (a frozen encoder here), and a line without an angle on a
/// controller that needs one refused.
#[test]
fn sil_binary_runs_sensorless_without_the_angle() {
    use foc_bench::mission::Setup;
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/motors/dji-m2006.toml");
    let setup = Setup::load(path).unwrap();
    let file = MotorFile::load(path).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_foc-sil"))
        .args(["--motor", path, "--sensor", "sensorless"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let mut exchange = |line: &str| -> Value {
        writeln!(stdin, "{line}").unwrap();
        stdin.flush().unwrap();
        let mut reply = String::new();
        stdout.read_line(&mut reply).unwrap();
        serde_json::from_str(&reply).unwrap_or_else(|e| panic!("{e}: {reply}"))
    };
    let no_angle = |m: &Measurements, extra: &str| {
        let i = m.currents.to_abc();
        format!(
            r#"{{"t":{},"i_abc":[{},{},{}],"v_bus":{}{extra}}}"#,
            m.time_s, i.a, i.b, i.c, m.v_bus_v
        )
    };
    let mut plant = Plant::new(file.motor_params(), file.bench_config());
    plant.set_rotor_angle(1.0);
    let mut m = plant.step_period([0.5; 3], false, 0.0);
    let out = exchange(&no_angle(&m, r#","cmd":{"mode":"torque","target":1}"#));
    assert!(
        out["error"].as_str().unwrap().contains("NeedsAngleSensor"),
        "{out}"
    );
    assert_eq!(out["mode"], "disabled");
    let target = -0.3 * setup.max_speed_rad_s().min(setup.max_mission_speed_rad_s());
    let hz = setup.pwm_hz();
    let mut held = 0;
    let mut reached = None;
    let mut backward = 0.0f64;
    let x0 = plant.position_rad();
    for k in 0..(2.0 * hz) as usize {
        let extra = if k == 0 {
            format!(r#","cmd":{{"mode":"velocity","target":{target}}}"#)
        } else if k % 2 == 0 {
            // Every other line carries a frozen encoder reading: ignored.
            r#","theta_m":0.0"#.to_string()
        } else {
            String::new()
        };
        let out = exchange(&no_angle(&m, &extra));
        assert!(
            out["fault"].is_null() && out["error"].is_null(),
            "{k}: {out}"
        );
        let d: Vec<f32> = out["duties"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap() as f32)
            .collect();
        m = plant.step_period([d[0], d[1], d[2]], out["bridge"].as_bool().unwrap(), 0.0);
        backward = backward.max(plant.position_rad() - x0);
        let w = plant.omega_m_rad_s() as f32;
        held = if (w - target).abs() <= 0.05 * target.abs() {
            held + 1
        } else {
            0
        };
        if held as f32 > 0.1 * hz {
            reached = Some(k as f32 / hz);
            break;
        }
    }
    let pp = f64::from(setup.motor.pole_pairs);
    println!(
        "foc-sil sensorless: {target:.1} rad/s held from {reached:?} s, backward {:.0} deg(e)",
        backward * pp * 180.0 / std::f64::consts::PI
    );
    assert!(reached.is_some(), "{target} rad/s not reached");
    assert!(
        backward * pp <= 200f64.to_radians(),
        "backward {backward} rad"
    );
    drop(stdin);
    assert!(child.wait().unwrap().success());
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert!(err.contains("sensorless: start at"), "{err}");

    // The same line on a controller that reads its angle: refused.
    let config = setup.cascade_config();
    let mut sil = foc_bench::sil::SilRunner::new(config);
    let (out, err) = sil.line(r#"{"t":0,"i_abc":[0,0,0],"v_bus":24}"#);
    assert!(err.unwrap().contains("missing field `theta_m`"), "{out}");
}

/// A line over the 64 KiB bound (here 1 MB) is refused with one error
/// reply in the safe state (bridge off, `CurrentSenseError` latched, like
/// any invalid line), and the next line is read and answered normally.
#[test]
fn sil_binary_refuses_an_over_long_line_then_goes_on() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/motors/dji-m2006.toml");
    let mut child = Command::new(env!("CARGO_BIN_EXE_foc-sil"))
        .args(["--motor", path])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let valid = |t: f64, extra: &str| {
        format!(r#"{{"t":{t},"i_abc":[0,0,0],"v_bus":24,"theta_m":0{extra}}}"#)
    };
    // A valid start (closed loop), then 1 MB on one line (a JSON prefix
    // and padding), then a valid line, written in one go.
    let mut input = valid(0.0, r#","cmd":{"mode":"torque","target":0.5}"#);
    input.push('\n');
    input.push_str(r#"{"t":1,"i_abc":[0,0,0],"v_bus":24,"theta_m":0,"pad":""#);
    input.push_str(&"x".repeat(1 << 20));
    input.push_str("\"}\n");
    input.push_str(&valid(2.0, ""));
    input.push('\n');
    stdin.write_all(input.as_bytes()).unwrap();
    stdin.flush().unwrap();
    let mut read = || -> Value {
        let mut reply = String::new();
        stdout.read_line(&mut reply).unwrap();
        serde_json::from_str(&reply).unwrap_or_else(|e| panic!("{e}: {reply}"))
    };
    let first = read();
    assert_eq!(first["bridge"], true, "{first}");
    assert_eq!(first["mode"], "torque", "{first}");

    let refused = read();
    let msg = refused["error"].as_str().unwrap();
    assert!(msg.contains("input line too long"), "{refused}");
    assert!(msg.contains("65536"), "{refused}");
    assert_eq!(refused["bridge"], false);
    assert_eq!(refused["duties"], serde_json::json!([0.5, 0.5, 0.5]));
    assert_eq!(refused["mode"], "disabled");
    assert_eq!(refused["fault"], "CurrentSenseError");
    assert!(refused["t"].is_null());

    let next = read();
    assert!(next["error"].is_null(), "{next}");
    assert_eq!(next["t"], 2.0);
    // Still safe: the refused period latched its fault until a clear.
    assert_eq!(next["bridge"], false);
    assert_eq!(next["fault"], "CurrentSenseError");
    // A clear and a command: running again.
    writeln!(
        stdin,
        "{}",
        valid(
            3.0,
            r#","clear_faults":true,"cmd":{"mode":"torque","target":0.5}"#
        )
    )
    .unwrap();
    stdin.flush().unwrap();
    let run = read();
    assert!(run["error"].is_null() && run["fault"].is_null(), "{run}");
    assert_eq!(run["bridge"], true);

    drop(stdin);
    // Exactly one reply per line: nothing more.
    let mut rest = String::new();
    stdout.read_to_string(&mut rest).unwrap();
    assert!(rest.is_empty(), "{rest}");
    assert!(child.wait().unwrap().success());
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert_eq!(err.matches("too long").count(), 1, "{err}");
    assert!(err.contains("line 2: input line too long"), "{err}");
}

/// The bounded line reader itself: the bound is inclusive, a longer line
/// is dropped through its newline without growing the buffer past the
/// bound, `\r\n` is stripped, and a last line without a newline counts.
#[test]
fn bounded_line_reader() {
    use foc_bench::sil::{read_line_bounded, BoundedLine, MAX_LINE};
    let mut text = Vec::new();
    text.extend(std::iter::repeat_n(b'a', MAX_LINE));
    text.push(b'\n');
    text.extend(std::iter::repeat_n(b'b', MAX_LINE + 1));
    text.push(b'\n');
    text.extend(std::iter::repeat_n(b'c', 1 << 20));
    text.extend_from_slice(b"\nok\r\n\nlast");
    // A small read buffer: the long lines arrive in many chunks.
    let mut r = BufReader::with_capacity(1000, &text[..]);
    let mut buf = Vec::new();
    let mut next = |buf: &mut Vec<u8>| read_line_bounded(&mut r, buf, MAX_LINE).unwrap();
    assert_eq!(next(&mut buf), BoundedLine::Line);
    assert_eq!(buf.len(), MAX_LINE);
    assert!(buf.iter().all(|&b| b == b'a'));
    assert_eq!(next(&mut buf), BoundedLine::TooLong(MAX_LINE as u64 + 1));
    assert!(buf.is_empty());
    assert_eq!(next(&mut buf), BoundedLine::TooLong(1 << 20));
    assert!(buf.capacity() <= MAX_LINE, "{}", buf.capacity());
    assert_eq!(next(&mut buf), BoundedLine::Line);
    assert_eq!(buf, b"ok");
    assert_eq!(next(&mut buf), BoundedLine::Line);
    assert!(buf.is_empty());
    assert_eq!(next(&mut buf), BoundedLine::Line);
    assert_eq!(buf, b"last");
    assert_eq!(next(&mut buf), BoundedLine::Eof);
    assert_eq!(next(&mut buf), BoundedLine::Eof);
}
