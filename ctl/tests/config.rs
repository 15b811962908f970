//! The configuration record end to end: the client library and the
//! `foc-ctl` binary against the simulated device over TCP (its store is a
//! RAM flash), and against a misbehaving fake device.

use foc_bench::scope_step::emulated_setup;
use foc_core::control::stage::TimeoutReaction;
use foc_core::control::Command;
use foc_ctl::config::TransferError;
use foc_ctl::sim::{HostDrive, Options, SimDevice, SimServer};
use foc_ctl::{Client, ClientError};
use foc_protocol::config::{Chunk, ConfigSource, StoreOp, CHUNK_BYTES};
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::message::{ErrorCode, ParamId, Request, Response, WatchdogConfig};
use foc_store::text::{from_toml, to_toml};
use foc_store::{DriveRecord, MAX_RECORD_BYTES, SCHEMA_VERSION};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener};
use std::path::PathBuf;
use std::process::Output;
use std::time::{Duration, Instant};

fn server(calibrated: bool) -> SimServer {
    let mut dev = SimDevice::default();
    if calibrated {
        assert!(dev.drive.calibrate_from_bench());
    }
    SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap()
}

fn client(addr: SocketAddr) -> Client {
    let mut c = Client::connect_tcp(addr).unwrap();
    c.set_timeout(Duration::from_millis(500));
    c
}

fn encoded(r: &DriveRecord) -> Vec<u8> {
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let n = r.encode(&mut buf).unwrap();
    buf[..n].to_vec()
}

fn nack<T: std::fmt::Debug>(r: Result<T, ClientError>) -> ErrorCode {
    match r {
        Err(ClientError::Nack(e)) => e,
        r => panic!("expected a Nack, got {r:?}"),
    }
}

/// `text` with `key = value` set in `[table]` (`""`: the top level).
fn set_key(text: &str, table: &str, key: &str, value: &str) -> String {
    let mut current = String::new();
    let mut found = false;
    let lines: Vec<String> = text
        .lines()
        .map(|l| {
            if let Some(t) = l.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
                current = t.to_string();
            } else if current == table && l.split('=').next().map(str::trim) == Some(key) {
                found = true;
                return format!("{key} = {value}");
            }
            l.to_string()
        })
        .collect();
    assert!(found, "no {table}.{key} in\n{text}");
    lines.join("\n") + "\n"
}

fn tmp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("foc-ctl-{}-{name}", std::process::id()))
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

#[test]
fn export_edit_import_takes_effect_and_is_saved() {
    let server = server(true);
    let mut c = client(server.addr());
    let before = DriveRecord::decode(&c.read_config(ConfigSource::Live).unwrap()).unwrap();
    assert_eq!(before.label.as_str(), foc_ctl::sim::DEFAULT_LABEL);
    assert_eq!(before.pwm_frequency_hz, 20_000);
    assert!(before.calibration.is_some());
    // The live record carries the link watchdog in force.
    let wd = WatchdogConfig {
        timeout_periods: 4000,
        reaction: TimeoutReaction::Stop,
    };
    c.set_watchdog(wd).unwrap();

    let mut t = to_toml(&DriveRecord::decode(&c.read_config(ConfigSource::Live).unwrap()).unwrap());
    assert!(t.contains("timeout_periods = 4000"), "{t}");
    t = set_key(&t, "", "label", "\"bench 7\"");
    t = set_key(&t, "current_gains", "kp_q_v_per_a", "0.75");
    t = set_key(&t, "motor", "r_ohm", "0.25");
    t = set_key(&t, "limits", "max_current_a", "4.0");
    t = set_key(&t, "dividers", "speed", "5");
    t = set_key(&t, "watchdog", "timeout_periods", "6000");
    // The joint: a 6:1 reversing gearbox, homed at 0.75 rad.
    t = set_key(&t, "joint", "gear_ratio", "-6.0");
    t = set_key(&t, "joint", "rotor_at_zero_rad", "0.75");
    let edited = from_toml(&t).unwrap();
    c.write_config(&encoded(&edited)).unwrap();
    c.store(StoreOp::ApplyAndSave).unwrap();

    let live = DriveRecord::decode(&c.read_config(ConfigSource::Live).unwrap()).unwrap();
    assert_eq!(live.label.as_str(), "bench 7");
    assert_eq!(live.current_gains.kp_q_v_per_a, 0.75);
    assert_eq!(live, edited);
    // What the drive reports and checks commands against changed.
    assert_eq!(c.param(ParamId::ResistanceOhm).unwrap(), 0.25);
    assert_eq!(c.param(ParamId::SpeedDivider).unwrap(), 5.0);
    assert_eq!(c.param(ParamId::WatchdogTimeout).unwrap(), 6000.0);
    assert_eq!(
        nack(c.set_command(Command::Torque { iq_a: 5.0 })),
        ErrorCode::OutOfRange { field: 1 }
    );
    c.set_command(Command::Torque { iq_a: 3.0 }).unwrap();
    c.set_command(Command::Disable).unwrap();
    // Saved too.
    let stored = DriveRecord::decode(&c.read_config(ConfigSource::Stored).unwrap()).unwrap();
    assert_eq!(stored, edited);
    drop(c);
    let dev = server.stop().unwrap();
    assert_eq!(dev.drive.settings().limits.max_current_a, 4.0);
    assert_eq!(dev.drive.settings().speed.current_limit_a, 4.0);
    assert_eq!(dev.drive.settings().current.q_gains.kp_v_per_a, 0.75);
}

#[test]
fn apply_without_save_leaves_the_store_alone() {
    let server = server(false);
    let mut c = client(server.addr());
    let mut r = DriveRecord::decode(&c.read_config(ConfigSource::Live).unwrap()).unwrap();
    assert!(r.calibration.is_none());
    r.motor.flux_linkage_wb = 0.006;
    c.write_config(&encoded(&r)).unwrap();
    c.store(StoreOp::Apply).unwrap();
    assert_eq!(c.param(ParamId::FluxLinkageWb).unwrap(), 0.006);
    assert_eq!(
        nack(c.read_config(ConfigSource::Stored)),
        ErrorCode::NothingStored
    );
    // A staged record is used once.
    assert_eq!(nack(c.store(StoreOp::Apply)), ErrorCode::BadRecord);
}

#[test]
fn save_change_load_restores() {
    let server = server(true);
    let mut c = client(server.addr());
    c.store(StoreOp::Save).unwrap();
    let saved = c.read_config(ConfigSource::Live).unwrap();
    assert_eq!(c.read_config(ConfigSource::Stored).unwrap(), saved);

    c.set_dividers(3, 9).unwrap();
    let mut l = DriveRecord::decode(&saved).unwrap().limits.to_limits();
    l.max_current_a = 2.0;
    c.set_limits(l).unwrap();
    assert_eq!(c.param(ParamId::SpeedDivider).unwrap(), 3.0);
    assert_ne!(c.read_config(ConfigSource::Live).unwrap(), saved);

    c.store(StoreOp::Load).unwrap();
    assert_eq!(c.read_config(ConfigSource::Live).unwrap(), saved);
    assert_eq!(c.param(ParamId::SpeedDivider).unwrap(), 10.0);
    assert_eq!(c.param(ParamId::PositionDivider).unwrap(), 20.0);
    c.set_command(Command::Torque { iq_a: 5.0 }).unwrap();
    c.set_command(Command::Disable).unwrap();
}

#[test]
fn erase_then_load_answers_nothing_stored() {
    let server = server(true);
    let mut c = client(server.addr());
    assert_eq!(nack(c.store(StoreOp::Load)), ErrorCode::NothingStored);
    c.store(StoreOp::Save).unwrap();
    c.store(StoreOp::Load).unwrap();
    c.store(StoreOp::Erase).unwrap();
    assert_eq!(nack(c.store(StoreOp::Load)), ErrorCode::NothingStored);
    assert_eq!(
        nack(c.read_config(ConfigSource::Stored)),
        ErrorCode::NothingStored
    );
    // The configuration in force is kept.
    assert_eq!(c.param(ParamId::Calibrated).unwrap(), 1.0);
}

#[test]
fn stored_read_and_store_while_running_are_refused() {
    let server = server(true);
    let mut c = client(server.addr());
    c.store(StoreOp::Save).unwrap();
    c.set_command(Command::Velocity { rad_s: 10.0 }).unwrap();
    assert_eq!(
        nack(c.read_config(ConfigSource::Stored)),
        ErrorCode::NotDisabled
    );
    assert_eq!(nack(c.store(StoreOp::Save)), ErrorCode::NotDisabled);
    assert_eq!(nack(c.store(StoreOp::Load)), ErrorCode::NotDisabled);
    // The live record can be read while running.
    c.read_config(ConfigSource::Live).unwrap();
    // And through the tool (the sim serves one connection at a time): a
    // clear message, a failure exit.
    drop(c);
    let out = foc_ctl(server.addr(), &["config", "show", "--stored"]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(err.contains("only allowed while disabled"), "{err}");
    assert!(err.contains("mode disable"), "{err}");
    let mut c = client(server.addr());
    c.set_command(Command::Disable).unwrap();
    c.read_config(ConfigSource::Stored).unwrap();
}

#[test]
fn truncated_or_corrupt_staged_records_are_refused() {
    let server = server(true);
    let mut c = client(server.addr());
    let live = c.read_config(ConfigSource::Live).unwrap();
    assert!(live.len() > CHUNK_BYTES, "{} bytes", live.len());
    let mut r = DriveRecord::decode(&live).unwrap();
    r.limits.max_current_a = 3.0;
    let bytes = encoded(&r);

    // Completely staged but truncated: the envelope is short.
    c.write_config(&bytes[..bytes.len() - 3]).unwrap();
    assert_eq!(nack(c.store(StoreOp::Apply)), ErrorCode::BadRecord);
    // Only the first chunk arrived: the staging is incomplete.
    let first = Chunk::of(&bytes, 0).unwrap();
    assert_eq!(
        c.request(&Request::WriteConfig(first)).unwrap(),
        Response::Ack
    );
    assert_eq!(nack(c.store(StoreOp::ApplyAndSave)), ErrorCode::BadRecord);
    // A flipped bit: the CRC fails.
    let mut bad = bytes.clone();
    bad[10] ^= 0x40;
    c.write_config(&bad).unwrap();
    assert_eq!(nack(c.store(StoreOp::ApplyAndSave)), ErrorCode::BadRecord);
    // Valid envelope, out-of-range value (the device validates too).
    let mut neg = r.clone();
    neg.motor.r_ohm = -1.0;
    c.write_config(&encoded(&neg)).unwrap();
    assert_eq!(nack(c.store(StoreOp::Apply)), ErrorCode::BadRecord);
    // Made for another PWM frequency.
    let mut other = r.clone();
    other.pwm_frequency_hz = 16_000;
    c.write_config(&encoded(&other)).unwrap();
    assert_eq!(nack(c.store(StoreOp::ApplyAndSave)), ErrorCode::BadRecord);

    // Nothing changed, nothing saved.
    assert_eq!(c.read_config(ConfigSource::Live).unwrap(), live);
    assert_eq!(
        nack(c.read_config(ConfigSource::Stored)),
        ErrorCode::NothingStored
    );
    // The good one is taken.
    c.write_config(&bytes).unwrap();
    c.store(StoreOp::Apply).unwrap();
    assert_eq!(c.read_config(ConfigSource::Live).unwrap(), bytes);
}

#[test]
fn cli_export_edit_import_show() {
    let server = server(true);
    let file = tmp("cli.toml");
    let f = file.to_str().unwrap();
    let out = foc_ctl(server.addr(), &["config", "export", f]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let t = std::fs::read_to_string(&file).unwrap();
    assert!(
        t.contains(&format!("schema_version = {SCHEMA_VERSION}")),
        "{t}"
    );
    assert!(t.contains("[joint]"), "{t}");
    let t = set_key(&t, "", "label", "\"from the cli\"");
    let t = set_key(&t, "current_gains", "ki_d_v_per_a_s", "1234.0");
    let t = set_key(&t, "motor", "ld_h", "5e-5");
    std::fs::write(&file, t).unwrap();

    let out = foc_ctl(server.addr(), &["config", "import", f, "--no-save"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("not saved"));
    let out = foc_ctl(server.addr(), &["config", "show"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let shown = text(&out.stdout);
    assert!(shown.contains("label = \"from the cli\""), "{shown}");
    let r = from_toml(&shown).unwrap();
    assert_eq!(r.current_gains.ki_d_v_per_a_s, 1234.0);
    let mut c = client(server.addr());
    assert_eq!(c.param(ParamId::LdH).unwrap(), 5e-5);
    drop(c);

    // Not saved: `show --stored` says the store is empty.
    let out = foc_ctl(server.addr(), &["config", "show", "--stored"]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("nothing is stored"));
    // Save, export the stored one: the same document.
    let out = foc_ctl(server.addr(), &["config", "save"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stored = tmp("cli-stored.toml");
    let out = foc_ctl(
        server.addr(),
        &["config", "export", stored.to_str().unwrap(), "--stored"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(std::fs::read_to_string(&stored).unwrap(), shown);
    // Erase, then load: refused with a clear message.
    assert!(foc_ctl(server.addr(), &["config", "erase"])
        .status
        .success());
    let out = foc_ctl(server.addr(), &["config", "load"]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("nothing is stored"));
    let _ = std::fs::remove_file(&file);
    let _ = std::fs::remove_file(&stored);
}

#[test]
fn cli_refuses_invalid_files_on_the_host() {
    let server = server(true);
    let mut c = client(server.addr());
    let good = to_toml(&DriveRecord::decode(&c.read_config(ConfigSource::Live).unwrap()).unwrap());
    let before = c.read_config(ConfigSource::Live).unwrap();
    let cases = [
        (set_key(&good, "motor", "r_ohm", "nan"), "motor.r_ohm"),
        (set_key(&good, "motor", "r_ohm", "-0.1"), "motor.r_ohm"),
        (
            set_key(
                &good,
                "",
                "schema_version",
                &(SCHEMA_VERSION + 1).to_string(),
            ),
            "schema_version",
        ),
        (
            set_key(&good, "joint", "gear_ratio", "0.0"),
            "joint.gear_ratio",
        ),
        (
            set_key(&good, "", "pwm_frequency_hz", "16000"),
            "PWM frequency",
        ),
        (good.replace("[motor]", "[motor]\nextra = 1"), "extra"),
    ];
    drop(c);
    let file = tmp("bad.toml");
    let f = file.to_str().unwrap();
    for (doc, why) in &cases {
        std::fs::write(&file, doc).unwrap();
        let out = foc_ctl(server.addr(), &["config", "import", f]);
        assert!(!out.status.success(), "{why}");
        let err = text(&out.stderr);
        assert!(err.contains(why), "{why}: {err}");
        assert!(err.contains("nothing was sent"), "{why}: {err}");
    }
    let _ = std::fs::remove_file(&file);
    let mut c = client(server.addr());
    assert_eq!(c.read_config(ConfigSource::Live).unwrap(), before);
    assert_eq!(
        nack(c.read_config(ConfigSource::Stored)),
        ErrorCode::NothingStored
    );
}

#[test]
fn the_link_moves_the_largest_record() {
    // The device encodes its live record into a `MAX_RECORD` buffer and
    // the host stages at most that much: every record the store can write
    // must fit.
    // (Checked when this test compiles; the firmware checks it too.)
    const {
        assert!(
            MAX_RECORD_BYTES <= foc_protocol::config::MAX_RECORD,
            "foc-store writes records larger than the link moves"
        )
    };
}

/// CRC-32/ISO-HDLC (the envelope's CRC).
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// A fake device on a TCP port: every request is answered by `reply`
/// (connections served one after the other, until the test ends).
fn fake_device(reply: impl Fn(&Request) -> Response + Send + 'static) -> SocketAddr {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap();
    std::thread::spawn(move || {
        for s in l.incoming() {
            let Ok(mut s) = s else { return };
            let mut dec = FrameDecoder::new();
            let mut buf = [0u8; 256];
            while let Ok(n) = s.read(&mut buf) {
                if n == 0 {
                    break;
                }
                for &b in &buf[..n] {
                    if let Some(Ok(p)) = dec.feed::<Request>(b) {
                        let mut tx = [0u8; MAX_FRAME];
                        let k = encode(p.seq, &reply(&p.msg), &mut tx).unwrap();
                        if s.write_all(&tx[..k]).is_err() {
                            break;
                        }
                    }
                }
            }
        }
    });
    addr
}

/// A device that serves `record` as its live and stored record.
fn serving(record: Vec<u8>) -> SocketAddr {
    fake_device(move |req| match *req {
        Request::ReadConfig { offset, .. } => {
            Response::ConfigChunk(Chunk::of(&record, offset).unwrap())
        }
        Request::ReadParam(id) => Response::Param { id, value: 20e3 },
        _ => Response::Ack,
    })
}

#[test]
fn show_says_when_a_record_fails_its_crc_or_version() {
    let good = encoded(&foc_store::record::example());
    let mut bad_crc = good.clone();
    bad_crc[12] ^= 1;
    let newer = SCHEMA_VERSION + 1;
    let mut v_newer = good.clone();
    v_newer[..2].copy_from_slice(&newer.to_le_bytes());
    let n = v_newer.len();
    let crc = crc32(&v_newer[..n - 4]);
    v_newer[n - 4..].copy_from_slice(&crc.to_le_bytes());

    let out = foc_ctl(serving(good), &["config", "show", "--stored"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("label = \"bench motor\""));
    let out = foc_ctl(serving(bad_crc), &["config", "show"]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(
        err.contains("not readable") && err.contains("checksum"),
        "{err}"
    );
    let out = foc_ctl(serving(v_newer), &["config", "show", "--stored"]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(err.contains(&format!("schema version {newer}")), "{err}");
}

#[test]
fn reads_that_do_not_add_up_are_errors() {
    // The length changes midway.
    let changing = fake_device(|req| match *req {
        Request::ReadConfig { offset, .. } => {
            let total = if offset == 0 { 100 } else { 120 };
            Response::ConfigChunk(Chunk::of(&vec![0u8; total], offset).unwrap())
        }
        _ => Response::Ack,
    });
    let mut c = client(changing);
    match c.read_config(ConfigSource::Live) {
        Err(ClientError::Transfer(TransferError::TotalChanged {
            first: 100,
            now: 120,
        })) => {}
        r => panic!("{r:?}"),
    }
    // Never finishes: empty chunks before the end.
    let stuck = fake_device(|req| match *req {
        Request::ReadConfig { offset, .. } => {
            Response::ConfigChunk(Chunk::new(offset, 100, &[]).unwrap())
        }
        _ => Response::Ack,
    });
    let mut c = client(stuck);
    let t0 = Instant::now();
    match c.read_config(ConfigSource::Stored) {
        Err(ClientError::Transfer(TransferError::BadLength { .. })) => {}
        r => panic!("{r:?}"),
    }
    assert!(t0.elapsed() < Duration::from_secs(2));
    // Always the first chunk again.
    let repeating = fake_device(|req| match *req {
        Request::ReadConfig { .. } => Response::ConfigChunk(Chunk::of(&[1u8; 100], 0).unwrap()),
        _ => Response::Ack,
    });
    let mut c = client(repeating);
    match c.read_config(ConfigSource::Live) {
        Err(ClientError::Transfer(TransferError::WrongOffset { asked: 48, got: 0 })) => {}
        r => panic!("{r:?}"),
    }
    // A record too long to send is refused on the host.
    let too_long = foc_protocol::config::MAX_RECORD + 1;
    match c.write_config(&vec![0u8; too_long]) {
        Err(ClientError::Transfer(TransferError::RecordSize { len })) if len == too_long => {}
        r => panic!("{r:?}"),
    }
}

#[test]
fn store_requests_wait_longer_than_others() {
    // A device that answers Store after 600 ms (a flash erase), everything
    // else at once.
    let slow = fake_device(|req| {
        if matches!(req, Request::Store(_)) {
            std::thread::sleep(Duration::from_millis(600));
        }
        Response::Ack
    });
    let mut c = Client::connect_tcp(slow).unwrap();
    c.set_timeout(Duration::from_millis(100));
    c.set_retries(0);
    c.set_store_timeout(Duration::from_secs(3));
    c.store(StoreOp::Erase).unwrap();
    assert_eq!(c.stats().retransmissions, 0);
    c.set_store_timeout(Duration::from_millis(100));
    match c.store(StoreOp::Erase) {
        Err(ClientError::Timeout { attempts: 1 }) => {}
        r => panic!("{r:?}"),
    }
}

#[test]
fn a_damaged_stored_record_is_refused_and_changes_nothing() {
    // A sim whose flash holds a saved record with one bit flipped in it.
    let mut drive =
        HostDrive::with_options(Options::simulator(emulated_setup()), Default::default());
    let mut r = drive.live_record(WatchdogConfig::OFF);
    r.label = foc_store::Label::try_from("to be damaged").unwrap();
    let store = drive.store_mut().unwrap();
    store.save(&r).unwrap();
    let mut flash = drive.flash_copy().unwrap();
    let image: Vec<u8> = flash.bytes_mut().map(|b| *b).collect();
    let at = image
        .windows(13)
        .position(|w| w == b"to be damaged")
        .expect("the label in the flash image");
    // Programming can only clear bits: clear the lowest set bit of the
    // label's first byte.
    let byte = flash.bytes_mut().nth(at).unwrap();
    *byte &= *byte - 1;
    let dev = SimDevice::with_drive(HostDrive::with_options(
        Options::simulator(emulated_setup()),
        flash,
    ));
    let server = SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap();

    let mut c = client(server.addr());
    let live = c.read_config(ConfigSource::Live).unwrap();
    assert_eq!(nack(c.store(StoreOp::Load)), ErrorCode::BadRecord);
    assert_eq!(
        nack(c.read_config(ConfigSource::Stored)),
        ErrorCode::BadRecord
    );
    assert_eq!(c.read_config(ConfigSource::Live).unwrap(), live);
    // Erase clears it; a save then works.
    c.store(StoreOp::Erase).unwrap();
    assert_eq!(nack(c.store(StoreOp::Load)), ErrorCode::NothingStored);
    c.store(StoreOp::Save).unwrap();
    assert_eq!(c.read_config(ConfigSource::Stored).unwrap(), live);
}
