//! `foc-ctl simulate` as a drive (issue 36): several clients at once, the
//! link watchdog armed as on a board, the board's hardware limit on every
//! path, telemetry at the rate asked with honest counts, a motor file.

use foc_core::control::{Command, Mode};
use foc_ctl::sim::{SimDevice, SimServer};
use foc_ctl::{Client, ClientError};
use foc_protocol::config::{ConfigSource, StoreOp};
use foc_protocol::message::{ErrorCode, ParamId, TelemetryRate};
use foc_store::DriveRecord;
use std::net::{SocketAddr, TcpListener};
use std::path::PathBuf;
use std::time::{Duration, Instant};

fn calibrated_server() -> SimServer {
    let mut dev = SimDevice::default();
    assert!(dev.drive.calibrate_from_bench());
    SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap()
}

fn client(addr: SocketAddr) -> Client {
    let mut c = Client::connect_tcp(addr).unwrap();
    c.set_timeout(Duration::from_millis(500));
    c
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn a_second_client_is_answered_while_the_first_streams() {
    let server = calibrated_server();
    let mut a = client(server.addr());
    a.set_command(Command::Velocity { rad_s: 30.0 }).unwrap();
    let addr = server.addr();
    // The second client asks while the first streams (0.4 s at 200 Hz).
    let other = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(100));
        let mut b = client(addr);
        let mut answered = 0;
        for _ in 0..10 {
            b.param(ParamId::PolePairs).unwrap();
            b.read_telemetry().unwrap();
            answered += 1;
        }
        (answered, b.stats().retransmissions)
    });
    let samples = a
        .telemetry(TelemetryRate::Hz(200.0), Duration::from_millis(400))
        .unwrap();
    let (answered, retrans) = other.join().unwrap();
    assert_eq!((answered, retrans), (10, 0));
    // Every sample 100 periods after the last (200 Hz at 20 kHz), none
    // lost, the stream counter without a gap (80 in real time; fewer
    // only on a machine that cannot keep the simulation's pace).
    assert!(samples.len() >= 10, "{} samples", samples.len());
    for w in samples.windows(2) {
        assert_eq!(w[1].sample.period.wrapping_sub(w[0].sample.period), 100);
    }
    assert_eq!(a.stats().stream_lost, 0);
    a.set_command(Command::Disable).unwrap();
}

#[test]
fn a_one_shot_command_stops_after_about_a_second() {
    let server = calibrated_server();
    let addr = server.addr();
    let before;
    {
        let mut c = client(addr);
        // The period just before the command: the watchdog counts from
        // the command, which lands between this sample and the
        // watcher's first one (`lag` periods later).
        before = c.read_telemetry().unwrap().period;
        c.set_command(Command::Velocity { rad_s: 50.0 }).unwrap();
        // The client leaves without a keep-alive.
    }
    let mut watcher = client(addr);
    let first = watcher.read_telemetry().unwrap();
    assert_eq!(first.mode, Mode::Velocity);
    let lag = first.period.wrapping_sub(before);
    let (mut reached, mut slowed, mut disabled) = (false, None, None);
    let end = Instant::now() + Duration::from_secs(30);
    while disabled.is_none() {
        let t = watcher.read_telemetry().unwrap();
        let since = t.period.wrapping_sub(before);
        reached |= t.velocity_rad_s > 45.0;
        if reached && slowed.is_none() && t.velocity_rad_s < 25.0 {
            slowed = Some(since);
        }
        if t.mode == Mode::Disabled {
            disabled = Some((since, t.fault_code));
        }
        assert!(Instant::now() < end, "still running: {t:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
    // The watcher's own requests did not keep it alive: the watchdog
    // belongs to the client that commanded. After 1 s (20 000 periods)
    // it stops the motor (velocity 0), after another second of silence
    // it disables with `CommandTimeout`, as the firmware's does.
    // Counted from before the command, so each figure is at least the
    // watchdog's and at most `lag` periods more.
    let slowed = slowed.unwrap();
    assert!(
        (20_000..=26_000 + lag).contains(&slowed),
        "slowed after {slowed} periods (lag {lag})"
    );
    let (off, code) = disabled.unwrap();
    assert!(
        (40_000..=42_000 + lag).contains(&off),
        "disabled after {off} periods (lag {lag})"
    );
    assert_eq!(code, foc_core::control::Fault::CommandTimeout.code());
}

#[test]
fn a_record_above_the_boards_hardware_limit_is_refused_whole() {
    let server = calibrated_server();
    let mut c = client(server.addr());
    let live = c.read_config(ConfigSource::Live).unwrap();
    let mut r = DriveRecord::decode(&live).unwrap();
    r.limits.max_current_a = 5000.0;
    let mut buf = [0u8; foc_store::MAX_RECORD_BYTES];
    let n = r.encode(&mut buf).unwrap();
    c.write_config(&buf[..n]).unwrap();
    match c.store(StoreOp::ApplyAndSave) {
        Err(ClientError::Nack(ErrorCode::Unsupported | ErrorCode::BadRecord)) => {}
        other => panic!("{other:?}"),
    }
    assert_eq!(c.read_config(ConfigSource::Live).unwrap(), live);
    match c.read_config(ConfigSource::Stored) {
        Err(ClientError::Nack(ErrorCode::NothingStored)) => {}
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_motor_file_is_simulated_and_identified() {
    // The 2.2 kW interior-PM motor on its 540 V bus, identified by the
    // drive itself (in simulated time here).
    let path = repo().join("tests/motors/ipm-2k2-540v.toml");
    let mut dev = SimDevice::from_motor_file(&path).unwrap();
    let setup = dev.drive.setup().clone();
    // About 40 s simulated (a slow alignment turn on 3 pole pairs), some
    // seconds here.
    assert!(dev.drive.identify(60.0), "not identified");
    let m = dev.drive.settings().current.motor;
    assert_eq!(m.pole_pairs, setup.motor.pole_pairs);
    let rel = |a: f32, b: f64| (f64::from(a) / b - 1.0).abs();
    assert!(rel(m.r_ohm, setup.motor.r_ohm) < 0.1, "{m:?}");
    assert!(
        rel(m.flux_linkage_wb, setup.motor.flux_linkage_wb) < 0.1,
        "{m:?}"
    );
    let server = SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap();
    let mut c = client(server.addr());
    assert_eq!(c.param(ParamId::Calibrated).unwrap(), 1.0);
    assert_eq!(
        c.param(ParamId::PolePairs).unwrap(),
        f32::from(setup.motor.pole_pairs)
    );
    assert!((c.param(ParamId::BusVoltageV).unwrap() - 540.0).abs() < 20.0);
}

fn foc_ctl(addr: SocketAddr, args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_foc-ctl"))
        .args(["--tcp", &addr.to_string()])
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn calibrate_waits_shows_the_steps_and_the_result() {
    // The drive's own identification, at up to 4 times real time.
    let server = SimServer::spawn_scaled(
        TcpListener::bind("127.0.0.1:0").unwrap(),
        SimDevice::default(),
        4.0,
    )
    .unwrap();
    let o = foc_ctl(server.addr(), &["identify"]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    for step in [
        "resistance",
        "inductance",
        "sensor alignment",
        "flux linkage",
        "done",
    ] {
        assert!(out.contains(step), "no `{step}` in:\n{out}");
    }
    assert!(out.contains("motor          R 0.2"), "{out}");
    assert!(out.contains("keep it: `foc-ctl config save`"), "{out}");
    let mut c = client(server.addr());
    assert_eq!(c.param(ParamId::Calibrated).unwrap(), 1.0);
    assert_eq!(c.param(ParamId::CalibrationResult).unwrap(), 2.0);
}

#[test]
fn a_failed_identification_names_its_step_and_reason() {
    // Phase C's lead disconnected: the resistance step finds no current.
    let mut dev = SimDevice::default();
    dev.drive.inject(foc_simdrive::FaultKind::OpenPhase);
    let server =
        SimServer::spawn_scaled(TcpListener::bind("127.0.0.1:0").unwrap(), dev, 4.0).unwrap();
    let o = foc_ctl(server.addr(), &["calibrate", "identification"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("failed: OpenPhase(C)") && err.contains("(at resistance)"),
        "{err}"
    );
    assert!(err.contains("check its wire"), "{err}");
    // The failure latched `CalibrationFailed`: refused until cleared.
    let o = foc_ctl(server.addr(), &["calibrate", "offsets", "--no-wait"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("a fault is latched"), "{err}");
    assert!(foc_ctl(server.addr(), &["clear"]).status.success());
    // Without waiting: at once.
    let o = foc_ctl(server.addr(), &["calibrate", "offsets", "--no-wait"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).starts_with("started"));
}

#[test]
fn a_hosts_watchdog_setting_holds_for_later_connections() {
    let server = calibrated_server();
    let a = server.addr();
    assert!(foc_ctl(a, &["watchdog", "0", "stop"]).status.success());
    assert!(foc_ctl(a, &["mode", "velocity", "30"]).status.success());
    // Watched from a third connection: still running 2.5 s later (the
    // automatic 1 s watchdog would have stopped it after 1 s).
    let mut c = client(a);
    let t0 = c.read_telemetry().unwrap();
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        let t = c.read_telemetry().unwrap();
        assert_eq!(t.mode, Mode::Velocity, "{t:?}");
        if t.period.wrapping_sub(t0.period) > 50_000 {
            assert!((t.velocity_rad_s - 30.0).abs() < 1.0, "{t:?}");
            break;
        }
        assert!(Instant::now() < end);
        std::thread::sleep(Duration::from_millis(20));
    }
    c.set_command(Command::Disable).unwrap();
}

#[test]
fn a_client_that_does_not_read_holds_up_no_one() {
    use foc_protocol::frame::{encode, MAX_FRAME};
    use foc_protocol::message::Request;
    use std::io::Write;
    let server = calibrated_server();
    // A client asks for every period's sample, then never reads.
    let mut quiet = std::net::TcpStream::connect(server.addr()).unwrap();
    let mut buf = [0u8; MAX_FRAME];
    let n = encode(
        7,
        &Request::StartTelemetry(TelemetryRate::EveryPeriods(1)),
        &mut buf,
    )
    .unwrap();
    quiet.write_all(&[0]).unwrap();
    quiet.write_all(&buf[..n]).unwrap();
    // The others are answered meanwhile, and the drive's time goes on.
    let mut c = client(server.addr());
    let p0 = c.read_telemetry().unwrap().period;
    // 4 s of every period's sample (about 1 MB/s) fill the kernel's
    // buffers: a server that blocked on them would stop answering here.
    for _ in 0..160 {
        c.param(ParamId::PolePairs).unwrap();
        std::thread::sleep(Duration::from_millis(25));
    }
    let p1 = c.read_telemetry().unwrap().period;
    assert!(
        p1.wrapping_sub(p0) > 2_000,
        "the drive's time stood still: {p0} -> {p1}"
    );
    drop(c);
    let dev = server.stop().unwrap();
    assert!(
        dev.dropped() > 0,
        "the quiet client's samples were not dropped"
    );
    drop(quiet);
}

#[test]
fn the_sensor_check_passes_on_every_motor_file_and_fails_on_a_stuck_encoder() {
    use foc_ctl::sensor_check;
    use std::sync::atomic::AtomicBool;
    // Every motor file, each on its own simulated drive (in parallel):
    // open loop needs no calibration.
    let files = foc_bench::motor_file::all_motor_files();
    assert!(files.len() >= 6, "{files:?}");
    let runs: Vec<_> = files
        .into_iter()
        .map(|path| {
            std::thread::spawn(move || {
                let dev = SimDevice::from_motor_file(&path).unwrap();
                let server =
                    SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap();
                let mut c = client(server.addr());
                let r = sensor_check::run(&mut c, &AtomicBool::new(false)).unwrap();
                let mode = c.read_telemetry().unwrap().mode;
                (path, r, mode)
            })
        })
        .collect();
    for run in runs {
        let (path, r, mode) = run.join().unwrap();
        eprintln!("{}: {}", path.display(), r.text);
        assert!(r.pass && !r.skipped, "{}: {r:?}", path.display());
        assert_eq!(
            mode,
            Mode::Disabled,
            "{}: the bridge left on",
            path.display()
        );
    }
    // A frozen encoder: the check says so, the bridge is off.
    let mut dev = SimDevice::default();
    dev.drive.inject(foc_simdrive::FaultKind::EncoderStuck);
    let server = SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap();
    let mut c = client(server.addr());
    let r = sensor_check::run(&mut c, &AtomicBool::new(false)).unwrap();
    assert!(!r.pass && r.text.contains("saw no motion"), "{r:?}");
    assert_eq!(c.read_telemetry().unwrap().mode, Mode::Disabled);
}

/// The simulated drive takes the d-current reference through the same
/// service path as a board (design §30): a parameter written over the
/// link reaches the drive's current stage at the next period, a save
/// keeps it across a power cycle, and on the hub motor's halls field
/// weakening is refused with the stage unchanged.
#[test]
fn the_d_current_reference_reaches_the_simulated_drive_and_survives_a_power_cycle() {
    use foc_ctl::sim::{HostDrive, Options};
    use foc_protocol::device::{DeviceContext, WatchdogConfig};
    let mut d = HostDrive::new();
    let before = d.sim.cascade.current.config().field;
    assert!(!before.field_weakening);
    d.set_param(ParamId::MaxIdA, 4.0).unwrap();
    d.set_param(ParamId::FieldWeakening, 1.0).unwrap();
    d.step_periods(1);
    let f = d.sim.cascade.current.config().field;
    assert!(f.field_weakening && f.max_id_a == 4.0, "{f:?}");
    assert_eq!(*d.sim.cascade.current.field().config(), f);
    assert_eq!(d.settings().field, f);
    // A bad value through the link changes nothing (the protocol's check
    // is the device state's; the link's rule refuses max-id 0 here).
    assert!(d.set_param(ParamId::MaxIdA, 0.0).is_err());
    d.step_periods(1);
    assert_eq!(d.sim.cascade.current.config().field, f);
    // Saved, power-cycled: the booted drive runs with it.
    d.with_link(|l| l.store(StoreOp::Save, &[], WatchdogConfig::OFF))
        .unwrap();
    d.power_cycle();
    assert_eq!(d.sim.cascade.current.config().field, f);
    assert_eq!(d.param(ParamId::FieldWeakening), Some(1.0));
    // Halls: refused, the stage unchanged; MTPA taken.
    let hub =
        foc_bench::mission::Setup::load(repo().join("tests/motors/cute-q85sx-hub.toml")).unwrap();
    let mut h = HostDrive::with_options(Options::simulator(hub), Default::default());
    h.start_up();
    let before = h.sim.cascade.current.config().field;
    assert_eq!(
        h.set_param(ParamId::FieldWeakening, 1.0),
        Err(foc_protocol::Refusal::Unsupported)
    );
    h.set_param(ParamId::Mtpa, 1.0).unwrap();
    h.step_periods(1);
    let after = h.sim.cascade.current.config().field;
    assert!(!after.field_weakening && after.mtpa);
    assert_eq!(
        foc_core::control::field::FieldConfig {
            mtpa: before.mtpa,
            ..after
        },
        before
    );
}

/// Run the simulated drive until the calibration it runs ends (at most
/// `max_s` simulated seconds): how it ended.
fn calibration_end(d: &mut foc_ctl::sim::HostDrive, max_s: f32) -> foc_core::drive::Progress {
    use foc_core::drive::Progress;
    for _ in 0..(max_s * 10.0) as u32 {
        d.step_periods(d.pwm_hz() / 10);
        let p = d.status().calibration;
        if !matches!(p, Progress::Running(_)) {
            return p;
        }
    }
    d.status().calibration
}

/// The tables take the firmware's path on the simulated drive (design
/// §32, §33): each calibration, asked over the link, measures its table
/// in the stage, which becomes the one in force (a save stores it);
/// after a power cycle the stored tables are in the stage before the
/// first period; a switch written over the link reaches the stage at
/// once (outside the period's mailbox); a record applied over the link
/// brings its tables; refusals are the drive's rule.
#[test]
fn the_tables_reach_the_simulated_drive_and_come_back_with_a_save() {
    use foc_core::drive::Progress;
    use foc_ctl::sim::{HostDrive, Options};
    use foc_protocol::device::{DeviceContext, WatchdogConfig};
    use foc_protocol::message::Calibration;
    use foc_store::settings::Tables;
    let stage_tables = |d: &HostDrive| Tables::of_stage(&d.sim.cascade.current);
    let gl80 = foc_bench::mission::Setup::load(repo().join("tests/motors/gl80-kv30.toml")).unwrap();
    let mut d = HostDrive::with_options(Options::simulator(gl80), Default::default());
    // Uncalibrated: refused at once, nothing asked of the drive.
    d.start_up();
    assert_eq!(
        d.start_calibration(Calibration::Anticogging),
        Err(foc_protocol::Refusal::NotCalibrated)
    );
    assert_eq!(
        d.set_param(ParamId::Anticogging, 1.0),
        Err(foc_protocol::Refusal::NotCalibrated)
    );
    assert!(d.calibrate_from_bench());
    // The anticogging map, then the angle correction.
    d.start_calibration(Calibration::Anticogging).unwrap();
    assert_eq!(calibration_end(&mut d, 60.0), Progress::Done);
    assert!(d.tables().cogging.enabled && d.tables().has_cogging());
    assert_eq!(d.tables().cogging, *d.sim.cascade.current.cogging());
    d.start_calibration(Calibration::EncoderLinearisation)
        .unwrap();
    assert_eq!(calibration_end(&mut d, 30.0), Progress::Done);
    let measured = stage_tables(&d);
    assert!(measured.has_angle_correction() && measured.angle_correction.enabled);
    assert_eq!(*d.tables(), measured);
    let peak = d.param(ParamId::AnticoggingPeakA).unwrap();
    assert!(peak > 0.0 && peak == measured.cogging.peak_a(), "{peak}");
    // Saved: the record holds them; power-cycled: in the stage before the
    // first period.
    d.with_link(|l| l.store(StoreOp::Save, &[], WatchdogConfig::OFF))
        .unwrap();
    let saved = d.stored_record().unwrap().unwrap();
    assert_eq!(Tables::of_record(&saved), measured);
    d.power_cycle();
    assert_eq!(d.periods(), 0);
    assert_eq!(stage_tables(&d), measured);
    assert_eq!(d.param(ParamId::EncoderLinearisation), Some(1.0));
    // A switch over the link: in the stage at once, no period needed.
    d.start_up();
    d.set_param(ParamId::Anticogging, 0.0).unwrap();
    assert!(!d.sim.cascade.current.cogging().enabled);
    assert_eq!(d.param(ParamId::Anticogging), Some(0.0));
    // A record without tables applied over the link: none in the stage.
    let mut bare = saved.clone();
    bare.cogging = None;
    bare.angle_correction = None;
    let mut buf = [0u8; foc_store::MAX_RECORD_BYTES];
    let n = bare.encode(&mut buf).unwrap();
    d.with_link(|l| l.store(StoreOp::Apply, &buf[..n], WatchdogConfig::OFF))
        .unwrap();
    assert_eq!(stage_tables(&d), Tables::NONE);
    // And back with them.
    let n = saved.encode(&mut buf).unwrap();
    d.with_link(|l| l.store(StoreOp::Apply, &buf[..n], WatchdogConfig::OFF))
        .unwrap();
    assert_eq!(stage_tables(&d), measured);
}
