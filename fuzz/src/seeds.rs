//! The seed corpus (`seeds/<target>/`), built with [`encode`].
//!
//! `FOC_FUZZ_WRITE_SEEDS=1 cargo test --no-default-features` (in `fuzz/`)
//! writes the files; without it the test checks that they are up to date.
//! Files in `seeds/` that this list does not name (crash inputs kept by
//! hand) are left alone.

use std::path::Path;

use foc_core::angle::ElectricalAngle;
use foc_core::control::homing::{EndStop, HomingMethod};
use foc_core::control::joint::Impedance;
use foc_core::control::{Command, Limits, Mode};
use foc_protocol::config::{Chunk, ConfigSource, StoreOp};
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::message::{
    Calibration, CurrentGains, ErrorCode, FaultReport, Hello, HomingFailure, HomingStart,
    HomingState, JointSettings, Message, ParamId, PositionGains, Request, Response, SpeedGains,
    Telemetry, TelemetryRate, WatchdogConfig,
};

use foc_core::control::stage::TimeoutReaction;
use foc_core::control::FaultSet;

fn frame<M: Message>(seq: u16, msg: &M) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME];
    let n = encode(seq, msg, &mut buf).expect("seed fits MAX_FRAME");
    buf[..n].to_vec()
}

fn frames(msgs: &[Request]) -> Vec<u8> {
    msgs.iter()
        .zip(1u16..)
        .flat_map(|(m, seq)| frame(seq, m))
        .collect()
}

/// `tag | seq | body` of a message: its frame un-stuffed, CRC removed.
fn payload_without_crc<M: Message>(seq: u16, msg: &M) -> Vec<u8> {
    let mut dec = FrameDecoder::new();
    let mut out = None;
    for b in frame(seq, msg) {
        if let Some(r) = dec.feed_raw(b) {
            out = Some(r.expect("own frame").to_vec());
        }
    }
    let mut p = out.expect("one frame");
    p.truncate(p.len() - 4);
    p
}

fn requests() -> Vec<(&'static str, Request)> {
    vec![
        ("ping", Request::Ping),
        ("keep-alive", Request::KeepAlive),
        (
            "set-command-velocity",
            Request::SetCommand(Command::Velocity { rad_s: 10.0 }),
        ),
        (
            "set-command-open-loop",
            Request::SetCommand(Command::OpenLoop {
                v_d_v: 0.5,
                v_q_v: 1.0,
                theta_e: ElectricalAngle::from_bits(0x4000_0000),
                omega_e_rad_s: 100.0,
            }),
        ),
        (
            "set-limits",
            Request::SetLimits(Limits {
                max_current_a: 5.0,
                max_velocity_rad_s: 300.0,
                min_position_rad: -50.0,
                max_position_rad: 50.0,
                max_open_loop_voltage_v: 6.0,
                max_open_loop_omega_e_rad_s: 500.0,
                max_kp_nm_per_rad: 20.0,
                max_kd_nm_s_per_rad: 0.5,
            }),
        ),
        (
            "set-current-gains",
            Request::SetCurrentGains(CurrentGains {
                kp_d: 1.0,
                ki_d: 100.0,
                kp_q: 1.0,
                ki_q: 100.0,
            }),
        ),
        (
            "set-speed-gains",
            Request::SetSpeedGains(SpeedGains {
                kp_a_per_rad_s: 0.05,
                ki_a_per_rad: 1.0,
            }),
        ),
        (
            "set-position-gains",
            Request::SetPositionGains(PositionGains {
                kp_per_s: 20.0,
                max_velocity_rad_s: 100.0,
                max_acceleration_rad_s2: 1000.0,
            }),
        ),
        (
            "set-dividers",
            Request::SetDividers {
                speed: 10,
                position: 20,
            },
        ),
        (
            "set-watchdog",
            Request::SetWatchdog(WatchdogConfig {
                timeout_periods: 2000,
                reaction: TimeoutReaction::Hold,
            }),
        ),
        (
            "run-calibration",
            Request::RunCalibration(Calibration::Alignment),
        ),
        ("read-faults", Request::ReadFaults),
        ("clear-faults", Request::ClearFaults),
        ("read-param", Request::ReadParam(ParamId::PwmFrequencyHz)),
        ("read-telemetry", Request::ReadTelemetry),
        (
            "start-telemetry-periods",
            Request::StartTelemetry(TelemetryRate::EveryPeriods(100)),
        ),
        (
            "start-telemetry-hz",
            Request::StartTelemetry(TelemetryRate::Hz(50.0)),
        ),
        ("stop-telemetry", Request::StopTelemetry),
        (
            "read-config",
            Request::ReadConfig {
                source: ConfigSource::Stored,
                offset: 48,
            },
        ),
        ("write-config", Request::WriteConfig(config_chunk())),
        (
            "store-apply-and-save",
            Request::Store(StoreOp::ApplyAndSave),
        ),
        (
            "set-command-impedance",
            Request::SetCommand(Command::Impedance(impedance())),
        ),
        ("set-joint", Request::SetJoint(joint())),
        (
            "set-joint-no-travel",
            Request::SetJoint(JointSettings {
                travel_out_rad: None,
                ..joint()
            }),
        ),
        ("read-joint", Request::ReadJoint),
        (
            "start-homing-present",
            Request::StartHoming(homing_present()),
        ),
        (
            "start-homing-end-stop",
            Request::StartHoming(homing_end_stop()),
        ),
        ("read-homing", Request::ReadHoming),
    ]
}

/// An impedance command (output frame).
fn impedance() -> Impedance {
    Impedance {
        position_rad: 0.5,
        velocity_rad_s: 0.1,
        kp_nm_per_rad: 5.0,
        kd_nm_s_per_rad: 0.2,
        torque_ff_nm: 0.05,
        torque_limit_nm: f32::INFINITY,
    }
}

/// A 20:1 reversed joint with a travel range.
fn joint() -> JointSettings {
    JointSettings {
        gear_ratio: -20.0,
        rotor_at_zero_rad: 3.0,
        travel_out_rad: Some((-1.0, 2.0)),
        fault_margin_rad: 0.5,
        brake_accel_rad_s2: 200.0,
        kv_a_per_rad_s: 0.05,
        entry_blend_periods: 200,
        timeout_kd_nm_s_per_rad: 0.01,
    }
}

fn homing_present() -> HomingStart {
    HomingStart {
        method: HomingMethod::Present,
        home_output_rad: 0.25,
    }
}

fn homing_end_stop() -> HomingStart {
    HomingStart {
        method: HomingMethod::EndStop(EndStop {
            velocity_rad_s: -0.1,
            current_a: 2.0,
            detect_fraction: 0.7,
            confirm_s: 0.02,
            backoff_rad: 0.05,
            max_travel_rad: 1.0,
        }),
        home_output_rad: -0.5,
    }
}

/// A chunk of a configuration record.
fn config_chunk() -> Chunk {
    let bytes: Vec<u8> = (0u8..48).map(|i| i.wrapping_mul(11)).collect();
    Chunk::new(48, 120, &bytes).unwrap_or_else(|| unreachable!())
}

fn sample() -> Telemetry {
    Telemetry {
        period: 123_456,
        i_d_a: 0.01,
        i_q_a: 1.5,
        v_d_v: -0.2,
        v_q_v: 3.0,
        velocity_rad_s: 50.0,
        position_rad: 12.5,
        mode: Mode::Velocity,
        fault_code: 0,
        max_loop_cycles: 4200,
        v_bus_v: 24.0,
        ..Telemetry::ZERO
    }
}

fn responses() -> Vec<(&'static str, Response)> {
    vec![
        ("ack", Response::Ack),
        (
            "nack-out-of-range",
            Response::Nack(ErrorCode::OutOfRange { field: 1 }),
        ),
        ("nack-bad-crc", Response::Nack(ErrorCode::BadCrc)),
        (
            "hello",
            Response::Hello(Hello {
                protocol_version: 1,
                firmware_version: [0, 1, 0],
                max_payload: 64,
            }),
        ),
        (
            "faults",
            Response::Faults(FaultReport {
                set: FaultSet(0b110),
                first_code: 1,
            }),
        ),
        (
            "param",
            Response::Param {
                id: ParamId::ResistanceOhm,
                value: 0.35,
            },
        ),
        ("telemetry", Response::Telemetry(sample())),
        ("stream", Response::Stream(sample())),
        ("config-chunk", Response::ConfigChunk(config_chunk())),
        ("nack-bad-record", Response::Nack(ErrorCode::BadRecord)),
        ("joint", Response::Joint(joint())),
        ("homing-running", Response::Homing(HomingState::Running)),
        (
            "homing-failed",
            Response::Homing(HomingState::Failed(HomingFailure::NoStop)),
        ),
    ]
}

/// Every seed: (target, file name, bytes).
pub fn all() -> Vec<(&'static str, String, Vec<u8>)> {
    let mut out = Vec::new();

    // frame_decoder: whole wire frames.
    let fd = "frame_decoder";
    out.push((fd, "ping".into(), frame(1, &Request::Ping)));
    out.push((
        fd,
        "set-command-open-loop".into(),
        frame(2, &requests()[3].1),
    ));
    out.push((
        fd,
        "telemetry".into(),
        frame(3, &Response::Telemetry(sample())),
    ));
    let mut mixed = vec![0x13, 0x37, 0x42, 0x00, 0x00];
    mixed.extend(frame(4, &Request::ReadTelemetry));
    mixed.extend([0x01, 0x00]);
    mixed.extend(frame(5, &Request::KeepAlive));
    out.push((fd, "garbage-then-frames".into(), mixed));
    let mut too_long = vec![0x01; 80];
    too_long.push(0x00);
    too_long.extend(frame(6, &Request::Ping));
    out.push((fd, "too-long-then-ping".into(), too_long));
    // The regression of issue 15: `Some(Ok(&[]))` at the second delimiter.
    out.push((
        fd,
        "regression-empty-payload".into(),
        vec![0xfd, 0x00, 0x01, 0x00, 0x00],
    ));

    // message_decode: `tag | seq | body` (the check appends the CRC).
    for (name, req) in requests() {
        out.push((
            "message_decode",
            format!("request-{name}"),
            payload_without_crc(7, &req),
        ));
    }
    for (name, resp) in responses() {
        out.push((
            "message_decode",
            format!("response-{name}"),
            payload_without_crc(8, &resp),
        ));
    }

    // device_commands: header (flags, periods per poll) + a host's stream.
    let dc = "device_commands";
    let with_header = |flags: u8, step: u16, stream: Vec<u8>| {
        let mut v = vec![flags];
        v.extend(step.to_le_bytes());
        v.extend(stream);
        v
    };
    out.push((
        dc,
        "session".into(),
        with_header(
            0x01,
            10,
            frames(&[
                Request::Ping,
                Request::SetWatchdog(WatchdogConfig {
                    timeout_periods: 100,
                    reaction: TimeoutReaction::Stop,
                }),
                Request::SetCommand(Command::Velocity { rad_s: 5.0 }),
                Request::StartTelemetry(TelemetryRate::EveryPeriods(50)),
                Request::ReadTelemetry,
                Request::KeepAlive,
                Request::ReadParam(ParamId::TelemetryDivider),
                Request::SetCommand(Command::Torque { iq_a: 1e6 }),
                Request::StopTelemetry,
                Request::SetCommand(Command::Disable),
            ]),
        ),
    ));
    let calib = frame(9, &Request::RunCalibration(Calibration::Offsets));
    out.push((
        dc,
        "retransmission".into(),
        with_header(0x00, 0, [calib.clone(), calib].concat()),
    ));
    out.push((
        dc,
        "not-calibrated-refusing".into(),
        with_header(
            0x34,
            1000,
            frames(&[
                Request::SetCommand(Command::Position { rad: 1.0 }),
                requests()[4].1,
                requests()[5].1,
                Request::SetDividers {
                    speed: 0,
                    position: 1,
                },
                Request::RunCalibration(Calibration::Identification),
                Request::StartTelemetry(TelemetryRate::Hz(1e9)),
            ]),
        ),
    ));
    let mut garbage = vec![0x05, 0x01, 0x02, 0x00, 0x03, 0x11, 0x22, 0x00];
    let mut bad_crc = frame(10, &Request::Ping);
    bad_crc[2] ^= 0x40;
    garbage.extend(bad_crc);
    garbage.extend(frame(11, &Request::Ping));
    out.push((
        dc,
        "garbage-then-ping".into(),
        with_header(0x82, 7, garbage),
    ));
    let mut idle = frames(&[
        Request::SetCommand(Command::Velocity { rad_s: 1.0 }),
        Request::StartTelemetry(TelemetryRate::Hz(2000.0)),
    ]);
    idle.extend([0u8; 40]);
    idle.extend(frames(&[Request::ReadFaults, Request::ClearFaults]));
    out.push((
        dc,
        "auto-watchdog-timeout".into(),
        with_header(0x41, 200, idle),
    ));
    // The joint (issue 20): frame, impedance, homing (a present-position
    // homing, an end-stop search aborted by a command, then one left to
    // the polls and the watchdog).
    let mut joint_session = frames(&[
        Request::SetJoint(joint()),
        Request::ReadJoint,
        Request::StartHoming(homing_present()),
        Request::ReadHoming,
        Request::SetCommand(Command::Impedance(impedance())),
        Request::StartHoming(homing_end_stop()),
        Request::ReadHoming,
        Request::SetCommand(Command::Disable),
        Request::ReadHoming,
        Request::StartHoming(homing_end_stop()),
    ]);
    joint_session.extend([0u8; 40]);
    joint_session.extend(frames(&[Request::ReadHoming, Request::ReadTelemetry]));
    out.push((
        dc,
        "joint-session".into(),
        with_header(0x43, 500, joint_session),
    ));
    out
}

#[test]
fn seed_files_match_the_generator() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("seeds");
    let write = std::env::var_os("FOC_FUZZ_WRITE_SEEDS").is_some_and(|v| v == "1");
    let mut stale = Vec::new();
    for (target, name, bytes) in all() {
        let path = root.join(target).join(&name);
        if write {
            std::fs::create_dir_all(path.parent().expect("has a parent")).expect("mkdir");
            std::fs::write(&path, &bytes).expect("write seed");
        } else if std::fs::read(&path).ok().as_deref() != Some(&bytes[..]) {
            stale.push(path.display().to_string());
        }
    }
    assert!(
        stale.is_empty(),
        "seed files missing or out of date (rewrite them with \
         FOC_FUZZ_WRITE_SEEDS=1 cargo test --no-default-features in fuzz/): {stale:#?}"
    );
}
