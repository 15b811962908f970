//! The command line's behaviour (issue 36): refusals that name the field,
//! the value and the range; partial limit changes; the watchdog in ms;
//! values with units and without denormals; quiet broken pipes; errors
//! that name the port; a scope read that says what it waits for; the
//! telemetry's rate asked and given.

use foc_ctl::sim::{SimDevice, SimServer};
use foc_ctl::Client;
use foc_protocol::message::ParamId;
use std::net::{SocketAddr, TcpListener};
use std::process::{Command, Output, Stdio};

fn calibrated_server() -> SimServer {
    let mut dev = SimDevice::default();
    assert!(dev.drive.calibrate_from_bench());
    SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap()
}

fn foc_ctl(addr: SocketAddr, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_foc-ctl"))
        .args(["--tcp", &addr.to_string()])
        .args(args)
        .output()
        .unwrap()
}

fn out(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn refusals_name_the_field_the_value_and_the_range() {
    let server = calibrated_server();
    let a = server.addr();
    let o = foc_ctl(a, &["mode", "torque", "500"]);
    assert!(!o.status.success());
    assert!(
        err(&o).contains("`iq_a` = 500 A is out of range (allowed: -10 .. 10 A, the current limit); nothing changed"),
        "{}",
        err(&o)
    );
    let o = foc_ctl(a, &["limits", "--max-current", "50"]);
    assert!(
        err(&o).contains("`max_current_a` = 50 A is above this board's hardware limit of 10 A"),
        "{}",
        err(&o)
    );
    let o = foc_ctl(a, &["dividers", "0", "5"]);
    assert!(
        err(&o).contains("`speed` = 0 periods is out of range (allowed: at least 1)"),
        "{}",
        err(&o)
    );
    let o = foc_ctl(a, &["gains", "speed", "--kp", "NaN", "--ki", "0"]);
    assert!(err(&o).contains("`kp_a_per_rad_s` = NaN"), "{}", err(&o));
    // Nothing changed: the current limit is still the board's 10 A.
    let mut c = Client::connect_tcp(a).unwrap();
    assert_eq!(c.limits().unwrap().max_current_a, 10.0);
}

#[test]
fn limits_change_only_what_is_given() {
    let server = calibrated_server();
    let a = server.addr();
    let mut c = Client::connect_tcp(a).unwrap();
    let before = c.limits().unwrap();
    let o = foc_ctl(a, &["limits", "--max-current", "4"]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(out(&o).contains("max current      4 A"), "{}", out(&o));
    let after = c.limits().unwrap();
    assert_eq!(after.max_current_a, 4.0);
    assert_eq!(
        foc_core::control::Limits {
            max_current_a: before.max_current_a,
            ..after
        },
        before
    );
    // Without options: shown, nothing sent.
    let o = foc_ctl(a, &["limits"]);
    assert!(o.status.success() && out(&o).contains("max current      4 A"));
}

#[test]
fn the_watchdog_is_set_in_ms_and_params_have_units() {
    let server = calibrated_server();
    let a = server.addr();
    let o = foc_ctl(a, &["watchdog", "100", "stop"]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(
        out(&o).contains("ok: 100 ms (2000 periods at 20000 Hz), then Stop"),
        "{}",
        out(&o)
    );
    let mut c = Client::connect_tcp(a).unwrap();
    // This connection's own watchdog is its own: read the record's.
    let o = foc_ctl(a, &["param", "all"]);
    let text = out(&o);
    for line in [
        "r                  0.2 ohm",
        "ld                 6e-5 H",
        "pwm-frequency      20000 Hz",
        "calibrated         1 (yes)",
        "board-max-current  10 A",
        "calibration-result 2 (done)",
    ] {
        assert!(text.contains(line), "no `{line}` in:\n{text}");
    }
    assert!(c.param(ParamId::PolePairs).is_ok());
    let o = foc_ctl(a, &["watchdog", "0.01", "stop"]);
    assert!(!o.status.success());
    assert!(
        err(&o).contains("is outside 0 (off) or 0.050"),
        "{}",
        err(&o)
    );
}

#[test]
fn status_prints_plain_numbers() {
    let server = calibrated_server();
    let o = foc_ctl(server.addr(), &["status"]);
    assert!(o.status.success());
    let text = out(&o);
    for line in text.lines().take(5) {
        assert!(!line.contains("e-"), "{line}");
    }
    assert!(
        text.contains("bus            23.9") || text.contains("bus            24"),
        "{text}"
    );
}

#[test]
fn a_closed_pipe_ends_quietly() {
    let server = calibrated_server();
    let mut child = Command::new(env!("CARGO_BIN_EXE_foc-ctl"))
        .args(["--tcp", &server.addr().to_string(), "param", "all"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", err(&o));
    assert!(!err(&o).contains("panicked"), "{}", err(&o));
}

#[test]
fn connection_errors_name_the_port() {
    let o = Command::new(env!("CARGO_BIN_EXE_foc-ctl"))
        .args(["--serial", "/dev/no-such-port", "status"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(err(&o).contains("/dev/no-such-port"), "{}", err(&o));
}

#[test]
fn a_scope_read_says_what_it_waits_for_and_telemetry_states_its_rate() {
    let server = calibrated_server();
    let a = server.addr();
    let o = foc_ctl(a, &["scope", "arm"]);
    assert!(o.status.success(), "{}", err(&o));
    let o = foc_ctl(a, &["scope", "read", "--wait-ms", "300"]);
    assert!(!o.status.success());
    assert!(
        err(&o).contains("armed and waiting for its trigger"),
        "{}",
        err(&o)
    );
    assert!(!err(&o).contains("transport error"), "{}", err(&o));
    let o = foc_ctl(a, &["telemetry", "--rate", "300", "--duration-ms", "500"]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(
        err(&o).contains("asked 300 Hz, given every 67 periods = 298.5 Hz at 20000 Hz PWM"),
        "{}",
        err(&o)
    );
    assert!(err(&o).contains(", 0 lost in the stream"), "{}", err(&o));
}

#[test]
fn a_refused_range_is_given_in_the_frame_of_the_value() {
    let server = calibrated_server();
    let a = server.addr();
    // 20:1 reversed: the rotor's 10000 rad/s is 500 rad/s at the output.
    assert!(
        foc_ctl(a, &["joint", "--gear-ratio", "-20", "--offset", "0"])
            .status
            .success()
    );
    let o = foc_ctl(a, &["mode", "velocity", "1000"]);
    assert!(
        err(&o).contains("`rad_s` = 1000 rad/s is out of range (allowed: -500 .. 500 rad/s, the velocity limit (output frame, through the joint))"),
        "{}",
        err(&o)
    );
    let o = foc_ctl(a, &["limits", "--max-velocity", "0"]);
    assert!(
        err(&o).contains("allowed: above 0 and finite"),
        "{}",
        err(&o)
    );
}

/// The d-current reference's parameters (design §30): read with units and
/// on/off, written by name (on/off or a number), refused in words naming
/// the parameter, the value and what it takes; nothing changes on a
/// refusal. On halls field weakening is refused with the reason, by
/// parameter and by record (`config import`).
#[test]
fn field_parameters_are_written_by_name_and_refused_in_words() {
    let server = calibrated_server();
    let a = server.addr();
    let o = foc_ctl(a, &["param", "field-weakening"]);
    assert!(
        out(&o).contains("field-weakening    0 (off)"),
        "{}",
        out(&o)
    );
    let o = foc_ctl(a, &["param", "field-weakening", "on"]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(out(&o).contains("field-weakening    1 (on)"), "{}", out(&o));
    let o = foc_ctl(a, &["param", "max-id", "3.5"]);
    assert!(out(&o).contains("max-id             3.5 A"), "{}", out(&o));
    let o = foc_ctl(a, &["param", "short-circuit", "1"]);
    assert!(out(&o).contains("short-circuit      1 (on)"), "{}", out(&o));
    for (args, want) in [
        (
            ["param", "max-id", "nan"],
            "`max-id` = NaN A is out of range (allowed: 0 .. 1e6 A, finite",
        ),
        (
            ["param", "max-id", "-2"],
            "`max-id` = -2 A is out of range",
        ),
        (
            ["param", "mtpa", "0.5"],
            "`mtpa` = 0.5 is out of range (allowed: 0 (off) or 1 (on))",
        ),
        (["param", "mtpa", "maybe"], "`maybe` is not on, off, 1 or 0"),
        (
            ["param", "max-current", "3"],
            "`max-current` is not a parameter that can be written; these are: field-weakening, mtpa, max-id, short-circuit, anticogging, encoder-linearisation",
        ),
        (
            ["param", "max-id", "0"],
            "`max-id` = 0 A is refused while field weakening is on",
        ),
    ] {
        let o = foc_ctl(a, &args);
        assert!(!o.status.success(), "{args:?}");
        assert!(err(&o).contains(want), "{args:?}: {}", err(&o));
    }
    // Nothing changed.
    let mut c = Client::connect_tcp(a).unwrap();
    assert_eq!(c.param(ParamId::MaxIdA).unwrap(), 3.5);
    assert_eq!(c.param(ParamId::FieldWeakening).unwrap(), 1.0);
    // The live record carries them.
    let o = foc_ctl(a, &["config", "show"]);
    assert!(
        out(&o).contains("[field]\nmtpa = ") && out(&o).contains("max_id_a = 3.5"),
        "{}",
        out(&o)
    );
    // Not while running.
    let o = foc_ctl(a, &["mode", "velocity", "5"]);
    assert!(o.status.success(), "{}", err(&o));
    let o = foc_ctl(a, &["param", "mtpa", "off"]);
    assert!(!o.status.success());
    assert!(err(&o).contains("disable"), "{}", err(&o));
}

#[test]
fn field_weakening_is_refused_on_halls_with_the_reason() {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/motors/cute-q85sx-hub.toml");
    let dev = SimDevice::from_motor_file(&path).unwrap();
    let server = SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap();
    let a = server.addr();
    let o = foc_ctl(a, &["param", "field-weakening", "on"]);
    assert!(!o.status.success());
    assert!(
        err(&o).contains(
            "`field-weakening` = 1 is refused: field weakening needs a fine angle sensor"
        ),
        "{}",
        err(&o)
    );
    assert!(err(&o).contains("nothing changed"), "{}", err(&o));
    let o = foc_ctl(a, &["param", "field-weakening"]);
    assert!(out(&o).contains("0 (off)"), "{}", out(&o));
    // MTPA is fine on halls.
    let o = foc_ctl(a, &["param", "mtpa", "on"]);
    assert!(o.status.success(), "{}", err(&o));
    // A record that turns it on: the host's checks pass, the drive
    // refuses it whole and the reason is given.
    let file = std::env::temp_dir().join(format!("foc-ctl-halls-{}.toml", std::process::id()));
    let o = foc_ctl(a, &["config", "export", file.to_str().unwrap()]);
    assert!(o.status.success(), "{}", err(&o));
    let text = std::fs::read_to_string(&file).unwrap();
    assert!(text.contains("field_weakening = false"), "{text}");
    std::fs::write(
        &file,
        text.replace("field_weakening = false", "field_weakening = true"),
    )
    .unwrap();
    let o = foc_ctl(
        a,
        &["config", "import", file.to_str().unwrap(), "--no-save"],
    );
    assert!(!o.status.success());
    assert!(
        err(&o).contains("the record turns field weakening on (`field.field_weakening`)"),
        "{}",
        err(&o)
    );
    let _ = std::fs::remove_file(&file);
    let o = foc_ctl(a, &["param", "field-weakening"]);
    assert!(out(&o).contains("0 (off)"), "{}", out(&o));
}

/// The sweep calibrations and the tables' switches (design §32, §33):
/// a switch without its table is refused with what to do; `calibrate
/// encoder` and `calibrate cogging` show their steps, the table's peak and
/// the switch; the switches are written by name; the configuration keeps
/// both; a running drive refuses them in words. (The simulation runs at 8
/// times real time: the map's sweep is 24 s simulated.)
#[test]
fn the_sweep_calibrations_keep_their_tables_and_switch_by_name() {
    let mut dev = SimDevice::default();
    assert!(dev.drive.calibrate_from_bench());
    let server =
        SimServer::spawn_scaled(TcpListener::bind("127.0.0.1:0").unwrap(), dev, 8.0).unwrap();
    let a = server.addr();
    for (name, want) in [
        (
            "anticogging",
            "`anticogging` = 1 is refused: the drive holds no anticogging map; measure one with `foc-ctl calibrate cogging`",
        ),
        (
            "encoder-linearisation",
            "`encoder-linearisation` = 1 is refused: the drive holds no angle correction; learn one with `foc-ctl calibrate encoder`",
        ),
    ] {
        let o = foc_ctl(a, &["param", name, "on"]);
        assert!(!o.status.success(), "{name}");
        assert!(err(&o).contains(want), "{name}: {}", err(&o));
        let o = foc_ctl(a, &["param", name]);
        assert!(out(&o).contains("0 (off)"), "{}", out(&o));
    }
    let o = foc_ctl(a, &["calibrate", "encoder"]);
    assert!(o.status.success(), "{}", err(&o));
    for want in [
        "EncoderLinearisation: started",
        "encoder linearisation",
        "done",
        "encoder-correction-peak ",
        "encoder-linearisation   1 (on)",
        "keep it: `foc-ctl config save`",
    ] {
        assert!(out(&o).contains(want), "{want}: {}", out(&o));
    }
    let o = foc_ctl(a, &["calibrate", "cogging"]);
    assert!(o.status.success(), "{}", err(&o));
    for want in [
        "anticogging",
        "done",
        "anticogging-peak",
        " A\n",
        "anticogging             1 (on)",
    ] {
        assert!(out(&o).contains(want), "{want}: {}", out(&o));
    }
    let o = foc_ctl(a, &["param", "anticogging", "off"]);
    assert!(o.status.success(), "{}", err(&o));
    assert!(
        out(&o).contains("anticogging        0 (off)"),
        "{}",
        out(&o)
    );
    // Kept with the configuration, each with its switch.
    let o = foc_ctl(a, &["config", "save"]);
    assert!(o.status.success(), "{}", err(&o));
    let o = foc_ctl(a, &["config", "show", "--stored"]);
    let text = out(&o);
    assert!(
        text.contains("[cogging]\nenabled = false\nscale_a = ")
            && text.contains("[angle_correction]\nenabled = true\nscale_rad = "),
        "{text}"
    );
    // Not while running.
    let o = foc_ctl(a, &["mode", "velocity", "5"]);
    assert!(o.status.success(), "{}", err(&o));
    let o = foc_ctl(a, &["calibrate", "cogging", "--no-wait"]);
    assert!(!o.status.success());
    assert!(err(&o).contains("disable"), "{}", err(&o));
    let o = foc_ctl(a, &["param", "anticogging", "on"]);
    assert!(!o.status.success());
    assert!(err(&o).contains("disable"), "{}", err(&o));
}

/// On halls the sweeps are refused with the reason, before anything moves.
#[test]
fn the_sweep_calibrations_are_refused_on_halls_with_the_reason() {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/motors/cute-q85sx-hub.toml");
    let mut dev = SimDevice::from_motor_file(&path).unwrap();
    // Uncalibrated first.
    let server = SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap();
    let o = foc_ctl(server.addr(), &["calibrate", "cogging"]);
    assert!(!o.status.success());
    assert!(
        err(&o).contains("the anticogging calibration runs on the closed loop and the drive is not calibrated: run `foc-ctl identify` first"),
        "{}",
        err(&o)
    );
    drop(server);
    dev = SimDevice::from_motor_file(&path).unwrap();
    assert!(dev.drive.calibrate_from_bench());
    let server = SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap();
    for (routine, want) in [
        ("cogging", "the anticogging calibration needs the rotor's angle at low speed: refused on halls"),
        ("encoder", "encoder linearisation learns the angle sensor's own error, so it needs a fine sensor that is read: refused on halls"),
    ] {
        let o = foc_ctl(server.addr(), &["calibrate", routine]);
        assert!(!o.status.success(), "{routine}");
        assert!(err(&o).contains(want), "{routine}: {}", err(&o));
        assert!(err(&o).contains("nothing changed"), "{}", err(&o));
    }
}
