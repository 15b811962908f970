//! End to end on the host: the client library over a TCP socket on
//! 127.0.0.1 (ephemeral port) to the device-side protocol in a thread.

use foc_core::control::{Command, Fault, Mode};
use foc_ctl::sim::{SimDevice, SimServer};
use foc_ctl::{Client, ClientError};
use foc_protocol::message::{Calibration, ErrorCode, ParamId, TelemetryRate};
use std::net::TcpListener;
use std::time::{Duration, Instant};

fn wait_for(
    c: &mut Client,
    what: &str,
    timeout: Duration,
    mut ok: impl FnMut(&foc_protocol::message::Telemetry) -> bool,
) {
    let end = Instant::now() + timeout;
    loop {
        let t = c.read_telemetry().unwrap();
        if ok(&t) {
            return;
        }
        assert!(Instant::now() < end, "{what}: last sample {t:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn velocity_and_position_over_tcp() {
    // The drive's own identification (about 6 s, real time).
    let server = SimServer::spawn(TcpListener::bind("127.0.0.1:0").unwrap()).unwrap();
    let mut c = Client::connect_tcp(server.addr()).unwrap();
    c.set_timeout(Duration::from_millis(500));

    let hello = c.ping().unwrap();
    assert_eq!(hello.protocol_version, foc_protocol::PROTOCOL_VERSION);
    assert_eq!(c.param(ParamId::PolePairs).unwrap(), 7.0);
    assert_eq!(c.param(ParamId::PwmFrequencyHz).unwrap(), 20_000.0);

    // Closed loop before calibration: refused.
    match c.set_command(Command::Velocity { rad_s: 20.0 }) {
        Err(ClientError::Nack(ErrorCode::NotCalibrated)) => {}
        r => panic!("{r:?}"),
    }
    c.calibrate(Calibration::Identification).unwrap();
    let end = Instant::now() + Duration::from_secs(60);
    while c.param(ParamId::Calibrated).unwrap() != 1.0 {
        assert!(Instant::now() < end, "calibration did not finish");
        std::thread::sleep(Duration::from_millis(10));
    }

    // Dividers while disabled, read back.
    c.set_dividers(8, 16).unwrap();
    assert_eq!(c.param(ParamId::SpeedDivider).unwrap(), 8.0);

    // Velocity.
    c.set_command(Command::Velocity { rad_s: 20.0 }).unwrap();
    wait_for(&mut c, "velocity", Duration::from_secs(5), |t| {
        t.mode == Mode::Velocity && (t.velocity_rad_s - 20.0).abs() < 0.2
    });
    // Out of range: refused, the drive keeps going.
    match c.set_command(Command::Velocity { rad_s: 1e6 }) {
        Err(ClientError::Nack(ErrorCode::OutOfRange { field: 1 })) => {}
        r => panic!("{r:?}"),
    }
    // Dividers refused while running.
    assert!(matches!(
        c.set_dividers(1, 1),
        Err(ClientError::Nack(ErrorCode::NotDisabled))
    ));

    // Streamed telemetry at 200 Hz for 0.5 s.
    let samples = c
        .telemetry(TelemetryRate::Hz(200.0), Duration::from_millis(500))
        .unwrap();
    assert!(samples.len() >= 20, "{} samples", samples.len());
    let v: Vec<f32> = samples.iter().map(|s| s.sample.velocity_rad_s).collect();
    let mean = v.iter().sum::<f32>() / v.len() as f32;
    let worst = v.iter().map(|x| (x - 20.0).abs()).fold(0.0, f32::max);
    eprintln!("streamed velocity: mean {mean} rad/s, worst error {worst} rad/s");
    assert!((mean - 20.0).abs() < 0.2 && worst < 2.0, "{v:?}");
    assert!(samples
        .windows(2)
        .all(|w| w[1].sample.period > w[0].sample.period));
    // Replies still match after the stream (stale stream frames are skipped).
    assert_eq!(c.param(ParamId::TelemetryDivider).unwrap(), 0.0);

    // Position.
    c.set_command(Command::Position { rad: 3.0 }).unwrap();
    wait_for(&mut c, "position", Duration::from_secs(5), |t| {
        t.mode == Mode::Position && (t.position_rad - 3.0).abs() < 0.01
    });

    c.set_command(Command::Disable).unwrap();
    assert_eq!(c.read_telemetry().unwrap().mode, Mode::Disabled);
    let st = c.stats();
    assert_eq!(st.retransmissions, 0);
    assert_eq!(st.bad_frames, 0);
    drop(c);
    let dev = server.stop().unwrap();
    assert_eq!(dev.drive.settings().dividers, (8, 16));
}

#[test]
fn faults_and_watchdog_over_tcp() {
    let mut dev = SimDevice::default();
    assert!(dev.drive.calibrate_from_bench());
    dev.drive.trip(Fault::BusOverVoltage);
    let server = SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap();
    let mut c = Client::connect_tcp(server.addr()).unwrap();
    c.set_timeout(Duration::from_millis(500));

    let f = c.faults().unwrap();
    assert_eq!(f.first(), Some(Fault::BusOverVoltage));
    assert!(matches!(
        c.set_command(Command::Torque { iq_a: 0.1 }),
        Err(ClientError::Nack(ErrorCode::Faulted))
    ));
    c.clear_faults().unwrap();
    let f = c.faults().unwrap();
    assert!(f.set.is_empty(), "{f:?}");

    // Watchdog: 0.1 s (2000 periods at 20 kHz), reaction disable.
    c.set_watchdog(foc_protocol::WatchdogConfig {
        timeout_periods: 2000,
        reaction: foc_core::control::stage::TimeoutReaction::Disable,
    })
    .unwrap();
    c.set_command(Command::Velocity { rad_s: 5.0 }).unwrap();
    // Keep-alives every 20 ms keep it running for 0.3 s.
    for _ in 0..15 {
        c.keep_alive().unwrap();
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(c.read_telemetry().unwrap().mode, Mode::Velocity);
    // Silence: the link watchdog trips.
    std::thread::sleep(Duration::from_millis(300));
    let f = c.faults().unwrap();
    assert_eq!(f.first(), Some(Fault::CommandTimeout));
    assert_eq!(c.read_telemetry().unwrap().mode, Mode::Disabled);
}

#[test]
fn garbage_on_the_line_and_timeouts() {
    use std::io::Write;
    let server = SimServer::spawn(TcpListener::bind("127.0.0.1:0").unwrap()).unwrap();
    // Raw socket: garbage gets a seq-0 Nack, then a good frame is answered.
    let mut s = std::net::TcpStream::connect(server.addr()).unwrap();
    s.write_all(&[0x42, 0x42, 0x00]).unwrap();
    let mut buf = [0u8; foc_protocol::MAX_FRAME];
    let n = foc_protocol::encode(9, &foc_protocol::Request::Ping, &mut buf).unwrap();
    s.write_all(&buf[..n]).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    let mut dec = foc_protocol::FrameDecoder::new();
    let mut got = Vec::new();
    let mut rx = [0u8; 256];
    while got.len() < 2 {
        let n = std::io::Read::read(&mut s, &mut rx).unwrap();
        assert!(n > 0);
        dec.feed_slice::<foc_protocol::Response>(&rx[..n], |r| got.push(r.unwrap()));
    }
    assert_eq!(got[0].seq, 0);
    assert!(matches!(got[0].msg, foc_protocol::Response::Nack(_)));
    assert_eq!(got[1].seq, 9);
    assert!(matches!(got[1].msg, foc_protocol::Response::Hello(_)));
    drop(s);
    drop(server);

    // Nobody answering: timeout after 1 + retries attempts.
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let mut c = Client::connect_tcp(l.local_addr().unwrap()).unwrap();
    c.set_timeout(Duration::from_millis(30));
    c.set_retries(2);
    match c.ping() {
        Err(ClientError::Timeout { attempts: 3 }) => {}
        r => panic!("{r:?}"),
    }
    assert_eq!(c.stats().retransmissions, 2);
}

#[test]
fn limits_above_the_simulated_boards_hardware_are_refused() {
    // The firmware's rule (foc-service), with the simulated board's
    // hardware limit (the emulated board's 10 A).
    let dev = SimDevice::default();
    let mut l = dev.drive.settings().limits;
    let server = SimServer::spawn_with(TcpListener::bind("127.0.0.1:0").unwrap(), dev).unwrap();
    let mut c = Client::connect_tcp(server.addr()).unwrap();
    let board_max_a = foc_bench::scope_step::emulated_setup().max_current_a;
    l.max_current_a = board_max_a * 2.0;
    match c.set_limits(l) {
        Err(ClientError::Nack(ErrorCode::Unsupported)) => {}
        r => panic!("{r:?}"),
    }
    l.max_current_a = board_max_a;
    c.set_limits(l).unwrap();
}
