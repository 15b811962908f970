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
