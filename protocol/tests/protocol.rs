//! Round trips, decoder robustness (property tests) and device-side validation.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::angle::ElectricalAngle;
use foc_core::control::homing::{EndStop, HomingMethod};
use foc_core::control::joint::Impedance;
use foc_core::control::power::ActiveLimit;
use foc_core::control::stage::TimeoutReaction;
use foc_core::control::{AngleInUse, Command, Fault, FaultSet, Limits, Mode};
use foc_core::scope::{ScopeConfig, ScopeStatus, Signal, State, TriggerKind};
use foc_protocol::config::{Chunk, ConfigSource, StoreOp};
use foc_protocol::device::tests_support::RecordingContext;
use foc_protocol::device::{CommandWatchdog, DeviceState, WatchdogConfig};
use foc_protocol::frame::{
    cobs_encode, decode_payload, encode, FrameDecoder, FrameErrorKind, Packet, CRC, MAX_FRAME,
    MAX_PAYLOAD,
};
use foc_protocol::message::*;
use proptest::prelude::*;

fn wire<M: Message>(seq: u16, m: &M) -> Vec<u8> {
    let mut b = [0u8; MAX_FRAME];
    let n = encode(seq, m, &mut b).unwrap();
    b[..n].to_vec()
}

fn decode_stream<M: Message>(bytes: &[u8]) -> Vec<Result<Packet<M>, FrameErrorKind>> {
    let mut d = FrameDecoder::new();
    let mut out = Vec::new();
    d.feed_slice::<M>(bytes, |r| out.push(r.map_err(|e| e.kind)));
    out
}

fn limits() -> Limits {
    Limits {
        max_current_a: 5.0,
        max_velocity_rad_s: 300.0,
        min_position_rad: -10.0,
        max_position_rad: 10.0,
        max_open_loop_voltage_v: 6.0,
        max_open_loop_omega_e_rad_s: 2000.0,
        max_kp_nm_per_rad: 40.0,
        max_kd_nm_s_per_rad: 1.5,
    }
}

fn impedance() -> Impedance {
    Impedance {
        position_rad: 1.5,
        velocity_rad_s: -0.25,
        kp_nm_per_rad: 20.0,
        kd_nm_s_per_rad: 0.5,
        torque_ff_nm: 0.125,
        torque_limit_nm: f32::INFINITY,
    }
}

fn joint_settings() -> JointSettings {
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

fn end_stop() -> EndStop {
    EndStop {
        velocity_rad_s: -0.1,
        current_a: 2.0,
        detect_fraction: 0.7,
        confirm_s: 0.02,
        backoff_rad: 0.05,
        max_travel_rad: 1.0,
    }
}

fn telemetry() -> Telemetry {
    Telemetry {
        period: 123_456,
        i_d_a: -0.25,
        i_q_a: 3.5,
        v_d_v: -1.0,
        v_q_v: 7.25,
        velocity_rad_s: 99.5,
        position_rad: -12.75,
        mode: Mode::Velocity,
        fault_code: 9,
        max_loop_cycles: 1234,
        v_bus_v: 24.5,
        power_limit: ActiveLimit::Regen,
        limit_left_pct: 37,
        brake_on: true,
        brake_locked: false,
        winding_c: 81.3,
        stage_c: -12.5,
        angle_in_use: AngleInUse::LimpHome,
    }
}

fn all_requests() -> Vec<Request> {
    vec![
        Request::Ping,
        Request::KeepAlive,
        Request::SetCommand(Command::Disable),
        Request::SetCommand(Command::Torque { iq_a: -2.5 }),
        Request::SetCommand(Command::Velocity { rad_s: 120.0 }),
        Request::SetCommand(Command::Position { rad: -3.25 }),
        Request::SetCommand(Command::Impedance(impedance())),
        Request::SetCommand(Command::OpenLoop {
            v_d_v: 1.0,
            v_q_v: -0.5,
            theta_e: ElectricalAngle::from_bits(0xDEAD_BEEF),
            omega_e_rad_s: 314.0,
        }),
        Request::SetLimits(limits()),
        Request::SetCurrentGains(CurrentGains {
            kp_d: 0.1,
            ki_d: 200.0,
            kp_q: 0.2,
            ki_q: 300.0,
        }),
        Request::SetSpeedGains(SpeedGains {
            kp_a_per_rad_s: 0.05,
            ki_a_per_rad: 1.5,
        }),
        Request::SetPositionGains(PositionGains {
            kp_per_s: 30.0,
            max_velocity_rad_s: 50.0,
            max_acceleration_rad_s2: 500.0,
        }),
        Request::SetDividers {
            speed: 10,
            position: 40,
        },
        Request::SetWatchdog(WatchdogConfig {
            timeout_periods: 2000,
            reaction: TimeoutReaction::Hold,
        }),
        Request::SetJoint(joint_settings()),
        Request::SetJoint(JointSettings {
            travel_out_rad: None,
            ..joint_settings()
        }),
        Request::ReadJoint,
        Request::StartHoming(HomingStart {
            method: HomingMethod::Present,
            home_output_rad: 0.5,
        }),
        Request::StartHoming(HomingStart {
            method: HomingMethod::EndStop(end_stop()),
            home_output_rad: -1.0,
        }),
        Request::ReadHoming,
        Request::RunCalibration(Calibration::Offsets),
        Request::RunCalibration(Calibration::Identification),
        Request::RunCalibration(Calibration::Alignment),
        Request::RunCalibration(Calibration::Anticogging),
        Request::RunCalibration(Calibration::EncoderLinearisation),
        Request::ReadFaults,
        Request::ClearFaults,
        Request::ReadParam(ParamId::FluxLinkageWb),
        Request::SetParam {
            id: ParamId::MaxIdA,
            value: 12.5,
        },
        Request::SetParam {
            id: ParamId::FieldWeakening,
            value: 1.0,
        },
        Request::ReadTelemetry,
        Request::StartTelemetry(TelemetryRate::EveryPeriods(200)),
        Request::StartTelemetry(TelemetryRate::Hz(100.0)),
        Request::StopTelemetry,
        Request::ReadConfig {
            source: ConfigSource::Stored,
            offset: 96,
        },
        Request::WriteConfig(Chunk::new(48, 130, &[0xA5; 48]).unwrap()),
        Request::WriteConfig(Chunk::new(96, 130, &[1, 2, 3]).unwrap()),
        Request::Store(StoreOp::Save),
        Request::Store(StoreOp::Load),
        Request::Store(StoreOp::Erase),
        Request::Store(StoreOp::Apply),
        Request::Store(StoreOp::ApplyAndSave),
        Request::SetScope(scope_config()),
        Request::ArmScope,
        Request::TriggerScope,
        Request::ReadScope,
        Request::ReadScopeData { offset: 4095 },
    ]
}

fn scope_config() -> ScopeConfig {
    let mut c = ScopeConfig::new(&Signal::ALL[..8]);
    c.divider = 3;
    c.samples = 500;
    c.pre_trigger = 50;
    c.trigger = TriggerKind::Either;
    c.trigger_signal = Signal::VelocityRadS;
    c.level = -12.5;
    c
}

fn scope_report() -> ScopeReport {
    ScopeReport {
        status: ScopeStatus {
            state: State::Done,
            config: scope_config(),
            captured: 480,
            trigger_index: 30,
            trigger_period: 0xDEAD_BEEF,
            capacity: 4096,
        },
        sample_period_s: 150e-6,
    }
}

fn all_responses() -> Vec<Response> {
    vec![
        Response::Ack,
        Response::Nack(ErrorCode::Malformed),
        Response::Nack(ErrorCode::BadCrc),
        Response::Nack(ErrorCode::StoreFailed),
        Response::Nack(ErrorCode::BadRecord),
        Response::Nack(ErrorCode::NothingStored),
        Response::ConfigChunk(Chunk::new(0, 200, &[0x00; 48]).unwrap()),
        Response::ConfigChunk(Chunk::new(192, 200, &[7; 8]).unwrap()),
        Response::Nack(ErrorCode::UnknownMessage),
        Response::Nack(ErrorCode::OutOfRange { field: 3 }),
        Response::Nack(ErrorCode::Faulted),
        Response::Nack(ErrorCode::Busy),
        Response::Nack(ErrorCode::NotCalibrated),
        Response::Nack(ErrorCode::NotDisabled),
        Response::Nack(ErrorCode::Unsupported),
        Response::Nack(ErrorCode::Other(200)),
        Response::Hello(Hello {
            protocol_version: 1,
            firmware_version: [1, 2, 3],
            max_payload: 64,
        }),
        Response::Faults(FaultReport::new(
            FaultSet(0b110),
            Some(Fault::OverCurrentPhase),
        )),
        Response::Param {
            id: ParamId::PolePairs,
            value: 7.0,
        },
        Response::Telemetry(telemetry()),
        Response::Stream(telemetry()),
        Response::Joint(joint_settings()),
        Response::Homing(HomingState::Idle),
        Response::Homing(HomingState::Running),
        Response::Homing(HomingState::Done),
        Response::Homing(HomingState::Failed(HomingFailure::NoStop)),
        Response::Homing(HomingState::Failed(HomingFailure::Aborted)),
        Response::Nack(ErrorCode::ScopeState),
        Response::Scope(scope_report()),
        Response::ScopeData(ScopeData {
            offset: 4084,
            count: 12,
            values: core::array::from_fn(|i| i as f32 * -0.25),
        }),
        Response::ScopeData(ScopeData {
            offset: 7,
            count: 0,
            values: [0.0; 12],
        }),
    ]
}

#[test]
fn every_message_round_trips() {
    let reqs = all_requests();
    for (i, r) in reqs.iter().enumerate() {
        let seq = 1000 + i as u16;
        let got = decode_stream::<Request>(&wire(seq, r));
        assert_eq!(got.len(), 1, "{r:?}");
        let p = got[0].unwrap();
        assert_eq!((p.seq, p.msg), (seq, *r));
    }
    for (i, r) in all_responses().iter().enumerate() {
        let seq = i as u16;
        let got = decode_stream::<Response>(&wire(seq, r));
        assert_eq!(got.len(), 1, "{r:?}");
        let p = got[0].unwrap();
        assert_eq!((p.seq, p.msg), (seq, *r));
    }
    // Every tag is distinct.
    let mut tags: Vec<u8> = reqs.iter().map(Message::tag).collect();
    tags.extend(all_responses().iter().map(Message::tag));
    tags.sort();
    tags.dedup();
    assert_eq!(tags.len(), 29 + 12);
}

#[test]
fn frames_back_to_back_and_after_garbage() {
    let mut bytes = vec![0x55, 0x13, 0x00];
    for r in all_requests() {
        bytes.extend(wire(9, &r));
    }
    let got = decode_stream::<Request>(&bytes);
    assert_eq!(got[0], Err(FrameErrorKind::Cobs));
    let ok: Vec<Request> = got[1..].iter().map(|r| r.unwrap().msg).collect();
    assert_eq!(ok, all_requests());
}

#[test]
fn largest_message_fits() {
    for r in all_responses() {
        assert!(wire(1, &r).len() <= MAX_FRAME);
    }
}

#[test]
fn truncated_frames_are_rejected() {
    let full = wire(5, &Request::SetLimits(limits()));
    let payload_len = full.len() - 2; // minus COBS code byte and delimiter (no zeros inside? any)
    assert!(payload_len > 0);
    // Cut the encoded frame anywhere and terminate it: never a message.
    for cut in 1..full.len() - 1 {
        let mut f = full[..cut].to_vec();
        f.push(0);
        let got = decode_stream::<Request>(&f);
        assert_eq!(got.len(), 1);
        assert!(got[0].is_err(), "cut at {cut} decoded");
    }
    // A well-formed frame (good CRC) whose body is too short for its tag.
    let mut payload = vec![0x11u8, 5, 0, 1, 2, 3]; // SetLimits with a 3-byte body
    let crc = CRC.checksum(&payload);
    payload.extend(crc.to_le_bytes());
    let e = decode_payload::<Request>(&payload).unwrap_err();
    assert_eq!((e.kind, e.seq), (FrameErrorKind::ShortBody, Some(5)));
    // Unknown tag with a good CRC.
    let mut payload = vec![0x7Fu8, 6, 0];
    let crc = CRC.checksum(&payload);
    payload.extend(crc.to_le_bytes());
    let e = decode_payload::<Request>(&payload).unwrap_err();
    assert_eq!((e.kind, e.seq), (FrameErrorKind::UnknownTag(0x7F), Some(6)));
    // Too short for tag + seq + CRC.
    assert_eq!(
        decode_payload::<Request>(&[1, 2, 3]).unwrap_err().kind,
        FrameErrorKind::Truncated
    );
}

// ---------------------------------------------------------------- properties

fn finite() -> impl Strategy<Value = f32> + Clone {
    -1.0e6f32..1.0e6
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::Disable),
        any::<f32>().prop_map(|iq_a| Command::Torque { iq_a }),
        any::<f32>().prop_map(|rad_s| Command::Velocity { rad_s }),
        any::<f32>().prop_map(|rad| Command::Position { rad }),
        (any::<f32>(), any::<f32>(), any::<u32>(), any::<f32>()).prop_map(|(a, b, t, w)| {
            Command::OpenLoop {
                v_d_v: a,
                v_q_v: b,
                theta_e: ElectricalAngle::from_bits(t),
                omega_e_rad_s: w,
            }
        }),
        proptest::array::uniform6(any::<f32>()).prop_map(|v| Command::Impedance(Impedance {
            position_rad: v[0],
            velocity_rad_s: v[1],
            kp_nm_per_rad: v[2],
            kd_nm_s_per_rad: v[3],
            torque_ff_nm: v[4],
            torque_limit_nm: v[5],
        })),
    ]
}

fn joint() -> impl Strategy<Value = JointSettings> {
    joint_of(any::<f32>())
}

fn joint_of(x: impl Strategy<Value = f32> + Clone) -> impl Strategy<Value = JointSettings> {
    (proptest::array::uniform8(x), any::<bool>(), any::<u32>()).prop_map(|(v, travel, blend)| {
        JointSettings {
            gear_ratio: v[0],
            rotor_at_zero_rad: v[1],
            travel_out_rad: travel.then_some((v[2], v[3])),
            fault_margin_rad: v[4],
            brake_accel_rad_s2: v[5],
            kv_a_per_rad_s: v[6],
            entry_blend_periods: blend,
            timeout_kd_nm_s_per_rad: v[7],
        }
    })
}

fn homing() -> impl Strategy<Value = HomingStart> {
    (
        any::<f32>(),
        proptest::option::of(proptest::array::uniform6(any::<f32>())),
    )
        .prop_map(|(home, stop)| HomingStart {
            method: match stop {
                None => HomingMethod::Present,
                Some(v) => HomingMethod::EndStop(EndStop {
                    velocity_rad_s: v[0],
                    current_a: v[1],
                    detect_fraction: v[2],
                    confirm_s: v[3],
                    backoff_rad: v[4],
                    max_travel_rad: v[5],
                }),
            },
            home_output_rad: home,
        })
}

fn homing_state() -> impl Strategy<Value = HomingState> {
    prop_oneof![
        Just(HomingState::Idle),
        Just(HomingState::Running),
        Just(HomingState::Done),
        (1u8..=4).prop_map(|c| HomingState::Failed(HomingFailure::from_code(c).unwrap())),
    ]
}

fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        Just(Request::Ping),
        Just(Request::KeepAlive),
        command().prop_map(Request::SetCommand),
        proptest::array::uniform8(any::<f32>()).prop_map(|v| Request::SetLimits(Limits {
            max_current_a: v[0],
            max_velocity_rad_s: v[1],
            min_position_rad: v[2],
            max_position_rad: v[3],
            max_open_loop_voltage_v: v[4],
            max_open_loop_omega_e_rad_s: v[5],
            max_kp_nm_per_rad: v[6],
            max_kd_nm_s_per_rad: v[7],
        })),
        joint().prop_map(Request::SetJoint),
        Just(Request::ReadJoint),
        homing().prop_map(Request::StartHoming),
        Just(Request::ReadHoming),
        proptest::array::uniform4(finite()).prop_map(|v| Request::SetCurrentGains(CurrentGains {
            kp_d: v[0],
            ki_d: v[1],
            kp_q: v[2],
            ki_q: v[3]
        })),
        (finite(), finite()).prop_map(|(a, b)| Request::SetSpeedGains(SpeedGains {
            kp_a_per_rad_s: a,
            ki_a_per_rad: b
        })),
        (finite(), finite(), finite()).prop_map(|(a, b, c)| Request::SetPositionGains(
            PositionGains {
                kp_per_s: a,
                max_velocity_rad_s: b,
                max_acceleration_rad_s2: c
            }
        )),
        (any::<u16>(), any::<u16>())
            .prop_map(|(speed, position)| Request::SetDividers { speed, position }),
        (any::<u32>(), 0u8..3).prop_map(|(t, r)| Request::SetWatchdog(WatchdogConfig {
            timeout_periods: t,
            reaction: reaction_from_code(r).unwrap(),
        })),
        (0u8..5).prop_map(|c| Request::RunCalibration(Calibration::from_code(c).unwrap())),
        Just(Request::ReadFaults),
        Just(Request::ClearFaults),
        proptest::sample::select(ParamId::ALL.to_vec()).prop_map(Request::ReadParam),
        (
            proptest::sample::select(ParamId::ALL.to_vec()),
            any::<f32>()
        )
            .prop_map(|(id, value)| Request::SetParam { id, value }),
        Just(Request::ReadTelemetry),
        any::<u32>().prop_map(|k| Request::StartTelemetry(TelemetryRate::EveryPeriods(k))),
        finite().prop_map(|h| Request::StartTelemetry(TelemetryRate::Hz(h))),
        Just(Request::StopTelemetry),
        scope_cfg().prop_map(Request::SetScope),
        Just(Request::ArmScope),
        Just(Request::TriggerScope),
        Just(Request::ReadScope),
        any::<u16>().prop_map(|offset| Request::ReadScopeData { offset }),
    ]
}

fn signal() -> impl Strategy<Value = Signal> {
    proptest::sample::select(Signal::ALL.to_vec())
}

fn scope_cfg() -> impl Strategy<Value = ScopeConfig> {
    (
        proptest::collection::vec(signal(), 1..=8),
        (any::<u16>(), any::<u16>(), any::<u16>()),
        (0u8..6, signal(), finite()),
    )
        .prop_map(|(sig, (divider, samples, pre_trigger), (t, ts, level))| {
            let mut c = ScopeConfig::new(&sig);
            c.divider = divider;
            c.samples = samples;
            c.pre_trigger = pre_trigger;
            c.trigger = TriggerKind::from_code(t).unwrap();
            c.trigger_signal = ts;
            c.level = level;
            c
        })
}

fn tel() -> impl Strategy<Value = Telemetry> {
    (
        any::<u32>(),
        proptest::array::uniform6(finite()),
        0u8..6,
        any::<u8>(),
        any::<u32>(),
        finite(),
        (
            0u8..10,
            0u8..=100,
            any::<bool>(),
            any::<bool>(),
            -32767i16..=32767,
            -32767i16..=32767,
        ),
    )
        .prop_map(
            |(p, v, m, f, c, b, (l, pct, brake, locked, tw, ts))| Telemetry {
                period: p,
                i_d_a: v[0],
                i_q_a: v[1],
                v_d_v: v[2],
                v_q_v: v[3],
                velocity_rad_s: v[4],
                position_rad: v[5],
                mode: mode_from_code(m).unwrap(),
                fault_code: f,
                max_loop_cycles: c,
                v_bus_v: b,
                power_limit: active_limit_from_code(l).unwrap(),
                limit_left_pct: pct,
                brake_on: brake,
                brake_locked: locked,
                winding_c: f32::from(tw) / 10.0,
                stage_c: f32::from(ts) / 10.0,
                angle_in_use: AngleInUse::from_code((p % 4) as u8).unwrap(),
            },
        )
}

fn response() -> impl Strategy<Value = Response> {
    prop_oneof![
        Just(Response::Ack),
        (any::<u8>(), any::<u8>()).prop_map(|(c, f)| {
            // Normalise: the field is only carried for out-of-range.
            Response::Nack(ErrorCode::from_wire(c, if c == 4 { f } else { 0 }))
        }),
        (any::<u8>(), any::<[u8; 3]>(), any::<u8>()).prop_map(|(p, fw, m)| Response::Hello(
            Hello {
                protocol_version: p,
                firmware_version: fw,
                max_payload: m
            }
        )),
        (any::<u32>(), any::<u8>()).prop_map(|(b, f)| Response::Faults(FaultReport {
            set: FaultSet(b),
            first_code: f
        })),
        (proptest::sample::select(ParamId::ALL.to_vec()), finite())
            .prop_map(|(id, value)| Response::Param { id, value }),
        tel().prop_map(Response::Telemetry),
        tel().prop_map(Response::Stream),
        // Finite values: compared with `==` after the round trip.
        joint_of(finite()).prop_map(Response::Joint),
        homing_state().prop_map(Response::Homing),
        (scope_cfg(), 0u8..4, any::<(u16, u16, u32, u16)>(), finite()).prop_map(
            |(config, st, (captured, trigger_index, trigger_period, capacity), dt)| {
                Response::Scope(ScopeReport {
                    status: ScopeStatus {
                        state: State::from_code(st).unwrap(),
                        config,
                        captured,
                        trigger_index,
                        trigger_period,
                        capacity,
                    },
                    sample_period_s: dt,
                })
            }
        ),
        (any::<u16>(), proptest::collection::vec(finite(), 0..=12)).prop_map(|(offset, v)| {
            let mut values = [0.0; 12];
            values[..v.len()].copy_from_slice(&v);
            Response::ScopeData(ScopeData {
                offset,
                count: v.len() as u8,
                values,
            })
        }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Any byte stream: no panic, and every frame yielded has a correct CRC.
    #[test]
    fn decoder_accepts_any_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut raw = FrameDecoder::new();
        let mut typed = FrameDecoder::new();
        for &b in &bytes {
            let payload = raw.feed_raw(b).map(|r| r.map(<[u8]>::to_vec));
            let msg = typed.feed::<Response>(b);
            prop_assert_eq!(payload.is_some(), msg.is_some());
            if let (Some(Ok(p)), Some(Ok(_))) = (payload, msg) {
                prop_assert!(p.len() >= 7 && p.len() <= MAX_PAYLOAD);
                let (data, crc) = p.split_at(p.len() - 4);
                let want = CRC.checksum(data).to_le_bytes();
                prop_assert_eq!(&want[..], crc);
            }
            let _ = FrameDecoder::new().feed::<Request>(b);
        }
    }

    /// Random byte streams with many delimiters (short frames): same.
    #[test]
    fn decoder_accepts_short_random_frames(bytes in proptest::collection::vec(prop_oneof![Just(0u8), any::<u8>(), 1u8..4], 0..400)) {
        let mut d = FrameDecoder::new();
        for &b in &bytes {
            let _ = d.feed::<Request>(b);
        }
    }

    #[test]
    fn random_requests_round_trip(seq in any::<u16>(), r in request()) {
        let w = wire(seq, &r);
        prop_assert_eq!(w.iter().filter(|&&b| b == 0).count(), 1);
        let got = decode_stream::<Request>(&w);
        prop_assert_eq!(got.len(), 1);
        let p = got[0].unwrap();
        prop_assert_eq!(p.seq, seq);
        // Compare through the encoding (NaN != NaN, but its bits survive).
        prop_assert_eq!(wire(p.seq, &p.msg), w);
    }

    #[test]
    fn random_responses_round_trip(seq in any::<u16>(), r in response()) {
        let w = wire(seq, &r);
        let got = decode_stream::<Response>(&w);
        prop_assert_eq!(got.len(), 1);
        let p = got[0].unwrap();
        prop_assert_eq!((p.seq, p.msg), (seq, r));
    }

    /// Any change of one payload byte is caught by the CRC.
    #[test]
    fn one_corrupt_payload_byte_is_detected(r in request(), seq in any::<u16>(), at in any::<prop::sample::Index>(), flip in 1u8..=255) {
        let mut payload = [0u8; MAX_PAYLOAD];
        let w = wire(seq, &r);
        // Recover the payload by decoding the good frame.
        let mut d = FrameDecoder::new();
        let mut n = 0;
        for &b in &w {
            if let Some(Ok(p)) = d.feed_raw(b) {
                payload[..p.len()].copy_from_slice(p);
                n = p.len();
            }
        }
        let i = at.index(n);
        payload[i] ^= flip;
        let mut enc = [0u8; MAX_FRAME];
        let m = cobs_encode(&payload[..n], &mut enc).unwrap();
        let mut frame = enc[..m].to_vec();
        frame.push(0);
        let got = decode_stream::<Request>(&frame);
        prop_assert_eq!(got.len(), 1);
        prop_assert_eq!(got[0].unwrap_err(), FrameErrorKind::BadCrc);
    }

    /// Any change of one byte on the wire never yields a different message.
    #[test]
    fn one_corrupt_wire_byte_never_yields_another_message(r in request(), at in any::<prop::sample::Index>(), flip in 1u8..=255) {
        let mut w = wire(77, &r);
        let i = at.index(w.len());
        w[i] ^= flip;
        w.push(0);
        for p in decode_stream::<Request>(&w).into_iter().flatten() {
            prop_assert_eq!(wire(p.seq, &p.msg), wire(77, &r));
        }
    }
}

// ---------------------------------------------------------------- device side

fn handle(dev: &mut DeviceState, ctx: &mut RecordingContext, seq: u16, r: Request) -> Response {
    dev.handle(ctx, seq, u32::from(seq), &r)
}

#[test]
fn out_of_range_requests_are_nacked_and_change_nothing() {
    let oor = |field| Response::Nack(ErrorCode::OutOfRange { field });
    let cases: Vec<(Request, Response)> = vec![
        (Request::SetCommand(Command::Torque { iq_a: 10.5 }), oor(1)),
        (
            Request::SetCommand(Command::Torque { iq_a: f32::NAN }),
            oor(1),
        ),
        (
            Request::SetCommand(Command::Velocity { rad_s: -501.0 }),
            oor(1),
        ),
        (
            Request::SetCommand(Command::Velocity {
                rad_s: f32::INFINITY,
            }),
            oor(1),
        ),
        (
            Request::SetCommand(Command::Position { rad: 100.5 }),
            oor(1),
        ),
        (
            Request::SetCommand(Command::OpenLoop {
                v_d_v: 0.0,
                v_q_v: f32::NAN,
                theta_e: ElectricalAngle::ZERO,
                omega_e_rad_s: 0.0,
            }),
            oor(2),
        ),
        (
            Request::SetCommand(Command::OpenLoop {
                v_d_v: 10.0,
                v_q_v: 10.0,
                theta_e: ElectricalAngle::ZERO,
                omega_e_rad_s: 0.0,
            }),
            oor(1),
        ),
        (
            Request::SetCommand(Command::OpenLoop {
                v_d_v: 1.0,
                v_q_v: 0.0,
                theta_e: ElectricalAngle::ZERO,
                omega_e_rad_s: 1e5,
            }),
            oor(4),
        ),
        (
            Request::SetLimits(Limits {
                max_current_a: -1.0,
                ..limits()
            }),
            oor(0),
        ),
        (
            Request::SetLimits(Limits {
                max_velocity_rad_s: f32::NAN,
                ..limits()
            }),
            oor(1),
        ),
        (
            Request::SetLimits(Limits {
                min_position_rad: 5.0,
                max_position_rad: 5.0,
                ..limits()
            }),
            oor(3),
        ),
        (
            Request::SetLimits(Limits {
                max_open_loop_omega_e_rad_s: -2.0,
                ..limits()
            }),
            oor(5),
        ),
        (
            Request::SetCurrentGains(CurrentGains {
                kp_d: 1.0,
                ki_d: 1.0,
                kp_q: 1.0,
                ki_q: -1.0,
            }),
            oor(3),
        ),
        (
            Request::SetSpeedGains(SpeedGains {
                kp_a_per_rad_s: f32::NAN,
                ki_a_per_rad: 0.0,
            }),
            oor(0),
        ),
        (
            Request::SetPositionGains(PositionGains {
                kp_per_s: 1.0,
                max_velocity_rad_s: 0.0,
                max_acceleration_rad_s2: 1.0,
            }),
            oor(1),
        ),
        (
            Request::SetDividers {
                speed: 0,
                position: 10,
            },
            oor(0),
        ),
        (
            Request::SetDividers {
                speed: 10,
                position: 0,
            },
            oor(1),
        ),
        (
            Request::StartTelemetry(TelemetryRate::EveryPeriods(0)),
            oor(1),
        ),
        (Request::StartTelemetry(TelemetryRate::Hz(0.0)), oor(1)),
        (Request::StartTelemetry(TelemetryRate::Hz(30_000.0)), oor(1)),
        (Request::StartTelemetry(TelemetryRate::Hz(f32::NAN)), oor(1)),
    ];
    for (i, (req, want)) in cases.into_iter().enumerate() {
        let mut ctx = RecordingContext::default();
        let mut dev = DeviceState::new();
        let before = ctx;
        let got = handle(&mut dev, &mut ctx, i as u16 + 1, req);
        assert_eq!(got, want, "{req:?}");
        assert_eq!(ctx, before, "context touched by {req:?}");
        assert_eq!(dev.telemetry_every(), 0);
    }
}

#[test]
fn state_refusals_change_nothing() {
    let mut dev = DeviceState::new();
    // Faulted: only Disable is accepted; calibration refused.
    let mut ctx = RecordingContext {
        faults: FaultSet(1 << 9),
        first_fault: Some(Fault::LoopOverrun),
        ..Default::default()
    };
    let before = ctx;
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            1,
            Request::SetCommand(Command::Torque { iq_a: 1.0 })
        ),
        Response::Nack(ErrorCode::Faulted)
    );
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            2,
            Request::RunCalibration(Calibration::Offsets)
        ),
        Response::Nack(ErrorCode::Faulted)
    );
    assert_eq!(ctx, before);
    assert_eq!(
        handle(&mut dev, &mut ctx, 3, Request::SetCommand(Command::Disable)),
        Response::Ack
    );
    // Not calibrated: closed loop refused, open loop allowed.
    let mut ctx = RecordingContext {
        calibrated: false,
        ..Default::default()
    };
    let before = ctx;
    for (s, c) in [
        (4, Command::Torque { iq_a: 1.0 }),
        (5, Command::Velocity { rad_s: 1.0 }),
        (6, Command::Position { rad: 1.0 }),
    ] {
        assert_eq!(
            handle(&mut dev, &mut ctx, s, Request::SetCommand(c)),
            Response::Nack(ErrorCode::NotCalibrated)
        );
    }
    assert_eq!(ctx, before);
    let ol = Command::OpenLoop {
        v_d_v: 1.0,
        v_q_v: 0.0,
        theta_e: ElectricalAngle::ZERO,
        omega_e_rad_s: 10.0,
    };
    assert_eq!(
        handle(&mut dev, &mut ctx, 7, Request::SetCommand(ol)),
        Response::Ack
    );
    assert_eq!(ctx.posted, Some(ol));
    // Enabled: dividers and calibration need the drive disabled.
    let before = ctx;
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            8,
            Request::SetDividers {
                speed: 5,
                position: 5
            }
        ),
        Response::Nack(ErrorCode::NotDisabled)
    );
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            9,
            Request::RunCalibration(Calibration::Alignment)
        ),
        Response::Nack(ErrorCode::NotDisabled)
    );
    assert_eq!(ctx, before);
    // Busy context.
    let mut ctx = RecordingContext {
        refuse: Some(foc_protocol::Refusal::Busy),
        ..Default::default()
    };
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            10,
            Request::RunCalibration(Calibration::Offsets)
        ),
        Response::Nack(ErrorCode::Busy)
    );
    assert_eq!(ctx.calibration, None);
    // Unknown parameter.
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            11,
            Request::ReadParam(ParamId::FluxLinkageWb)
        ),
        Response::Nack(ErrorCode::Unsupported)
    );
}

#[test]
fn valid_requests_reach_the_context() {
    let mut dev = DeviceState::new();
    let mut ctx = RecordingContext::default();
    assert!(
        matches!(handle(&mut dev, &mut ctx, 1, Request::Ping), Response::Hello(h) if h.protocol_version == foc_protocol::PROTOCOL_VERSION)
    );
    assert_eq!(
        handle(&mut dev, &mut ctx, 2, Request::SetLimits(limits())),
        Response::Ack
    );
    assert_eq!(ctx.limits, limits());
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            3,
            Request::SetDividers {
                speed: 4,
                position: 8
            }
        ),
        Response::Ack
    );
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            4,
            Request::ReadParam(ParamId::PositionDivider)
        ),
        Response::Param {
            id: ParamId::PositionDivider,
            value: 8.0
        }
    );
    let g = SpeedGains {
        kp_a_per_rad_s: 0.1,
        ki_a_per_rad: 2.0,
    };
    assert_eq!(
        handle(&mut dev, &mut ctx, 5, Request::SetSpeedGains(g)),
        Response::Ack
    );
    assert_eq!(ctx.speed_gains, Some(g));
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            6,
            Request::SetCommand(Command::Velocity { rad_s: 50.0 })
        ),
        Response::Ack
    );
    assert_eq!(ctx.posted, Some(Command::Velocity { rad_s: 50.0 }));
    assert_eq!(
        handle(&mut dev, &mut ctx, 7, Request::KeepAlive),
        Response::Ack
    );
    assert_eq!(ctx.keep_alives, 1);
    ctx.faults = FaultSet(1 << 2);
    ctx.first_fault = Some(Fault::OverCurrentVector);
    assert_eq!(
        handle(&mut dev, &mut ctx, 8, Request::ReadFaults),
        Response::Faults(FaultReport::new(
            FaultSet(1 << 2),
            Some(Fault::OverCurrentVector)
        ))
    );
    assert_eq!(
        handle(&mut dev, &mut ctx, 9, Request::ClearFaults),
        Response::Ack
    );
    assert!(ctx.faults.is_empty());
    ctx.sample = telemetry();
    assert_eq!(
        handle(&mut dev, &mut ctx, 10, Request::ReadTelemetry),
        Response::Telemetry(telemetry())
    );
}

#[test]
fn retransmission_is_answered_from_cache_not_run_twice() {
    let mut dev = DeviceState::new();
    let mut ctx = RecordingContext::default();
    let req = Request::RunCalibration(Calibration::Alignment);
    assert_eq!(dev.handle(&mut ctx, 42, 0xABCD, &req), Response::Ack);
    let calls = ctx.calls;
    // Same seq and CRC: cached Ack, the context is not called again.
    assert_eq!(dev.handle(&mut ctx, 42, 0xABCD, &req), Response::Ack);
    assert_eq!(ctx.calls, calls);
    // A new seq runs again.
    assert_eq!(dev.handle(&mut ctx, 43, 0x1234, &req), Response::Ack);
    assert_eq!(ctx.calls, calls + 1);
}

#[test]
fn frame_errors_become_nacks() {
    let mut dev = DeviceState::new();
    let mut ctx = RecordingContext::default();
    let mut w = wire(12, &Request::ClearFaults);
    w[1] ^= 0x40; // corrupt a payload byte on the wire
    let mut d = FrameDecoder::new();
    let mut replies = Vec::new();
    let mut tx = [0u8; MAX_FRAME];
    for &b in &w {
        if let Some(n) = dev.on_byte(&mut ctx, &mut d, b, &mut tx) {
            replies.extend(decode_stream::<Response>(&tx[..n]));
        }
    }
    assert_eq!(replies.len(), 1);
    let p = replies[0].unwrap();
    assert_eq!(p.seq, 0);
    assert!(matches!(
        p.msg,
        Response::Nack(ErrorCode::BadCrc | ErrorCode::Malformed)
    ));
    assert_eq!(ctx.clears, 0);
}

#[test]
fn telemetry_is_streamed_at_the_requested_divider() {
    let mut dev = DeviceState::new();
    let mut ctx = RecordingContext::default();
    assert_eq!(dev.poll(&mut ctx, 0), None);
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            1,
            Request::StartTelemetry(TelemetryRate::Hz(1000.0))
        ),
        Response::Ack
    );
    assert_eq!(dev.telemetry_every(), 20); // 20 kHz / 1 kHz
    let mut seqs = Vec::new();
    for period in (0..=2000).step_by(5) {
        if let Some((s, r)) = dev.poll(&mut ctx, period) {
            assert!(matches!(r, Response::Stream(_)));
            seqs.push(s);
        }
    }
    assert_eq!(seqs.len(), 101);
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1));
    assert_eq!(
        handle(&mut dev, &mut ctx, 2, Request::StopTelemetry),
        Response::Ack
    );
    assert_eq!(dev.poll(&mut ctx, 5000), None);
}

#[test]
fn watchdog_reactions() {
    let mut wd = CommandWatchdog::new(WatchdogConfig {
        timeout_periods: 10,
        reaction: TimeoutReaction::Disable,
    });
    assert_eq!(wd.tick(100, false), None); // disabled drive: no timeout
    assert_eq!(wd.tick(10, true), None);
    assert_eq!(wd.tick(1, true), Some(TimeoutReaction::Disable));
    assert!(wd.expired());

    for (reaction, expect) in [
        (
            TimeoutReaction::Stop,
            Some(Command::Velocity { rad_s: 0.0 }),
        ),
        (TimeoutReaction::Hold, Some(Command::Position { rad: 2.5 })),
        (TimeoutReaction::Disable, None),
    ] {
        let mut dev = DeviceState::with_watchdog(WatchdogConfig {
            timeout_periods: 100,
            reaction,
        });
        let mut ctx = RecordingContext::default();
        ctx.sample.position_rad = 2.5;
        dev.poll(&mut ctx, 0);
        assert_eq!(
            handle(
                &mut dev,
                &mut ctx,
                1,
                Request::SetCommand(Command::Velocity { rad_s: 30.0 })
            ),
            Response::Ack
        );
        dev.poll(&mut ctx, 60);
        // Keep-alive feeds the watchdog and refreshes the command.
        assert_eq!(
            handle(&mut dev, &mut ctx, 2, Request::KeepAlive),
            Response::Ack
        );
        dev.poll(&mut ctx, 120);
        assert_eq!(ctx.posted, Some(Command::Velocity { rad_s: 30.0 }));
        assert!(ctx.faults.is_empty());
        // Queries do not feed it.
        assert!(matches!(
            handle(&mut dev, &mut ctx, 3, Request::Ping),
            Response::Hello(_)
        ));
        dev.poll(&mut ctx, 170);
        match expect {
            Some(c) => {
                assert_eq!(ctx.posted, Some(c));
                assert!(ctx.faults.is_empty());
            }
            None => {
                assert!(ctx.faults.contains(Fault::CommandTimeout));
                assert_eq!(ctx.mode, Mode::Disabled);
            }
        }
    }
}

/// Sensorless (the device reports `angle-source` 1): a torque, position or
/// impedance command is refused with `NeedsAngleSensor`; the link
/// watchdog's `Hold` stops (velocity 0) instead of holding a position it
/// cannot know, and latches nothing.
#[test]
fn a_sensorless_device_refuses_what_needs_the_sensor_and_stops_on_hold() {
    let mut dev = DeviceState::with_watchdog(WatchdogConfig {
        timeout_periods: 100,
        reaction: TimeoutReaction::Hold,
    });
    let mut ctx = RecordingContext {
        sensorless: true,
        ..RecordingContext::default()
    };
    dev.poll(&mut ctx, 0);
    for cmd in [
        Command::Torque { iq_a: 1.0 },
        Command::Position { rad: 1.0 },
    ] {
        assert_eq!(
            handle(&mut dev, &mut ctx, 1, Request::SetCommand(cmd)),
            Response::Nack(ErrorCode::NeedsAngleSensor)
        );
    }
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            2,
            Request::SetCommand(Command::Velocity { rad_s: 30.0 })
        ),
        Response::Ack
    );
    dev.poll(&mut ctx, 150);
    assert_eq!(ctx.posted, Some(Command::Velocity { rad_s: 0.0 }));
    assert!(ctx.faults.is_empty());
}

/// Sensorless with injection (a salient motor, design §28): torque and
/// position commands are taken, and the watchdog's `Hold` holds the
/// position.
#[test]
fn a_sensorless_device_with_injection_takes_torque_and_holds_on_hold() {
    let mut dev = DeviceState::with_watchdog(WatchdogConfig {
        timeout_periods: 100,
        reaction: TimeoutReaction::Hold,
    });
    let mut ctx = RecordingContext {
        sensorless: true,
        injection: true,
        ..RecordingContext::default()
    };
    dev.poll(&mut ctx, 0);
    for cmd in [
        Command::Torque { iq_a: 1.0 },
        Command::Position { rad: 1.0 },
    ] {
        assert_eq!(
            handle(&mut dev, &mut ctx, 1, Request::SetCommand(cmd)),
            Response::Ack
        );
    }
    dev.poll(&mut ctx, 150);
    assert!(
        matches!(ctx.posted, Some(Command::Position { .. })),
        "{:?}",
        ctx.posted
    );
}

/// The firmware's default: a command that runs the motor arms the link
/// watchdog
/// (Stop, then Disable after a second timeout of silence); a keep-alive
/// feeds it; a host's own `SetWatchdog` (even off) is never overridden.
#[test]
fn closed_loop_command_arms_the_link_watchdog_stop_then_disable() {
    let auto = WatchdogConfig {
        timeout_periods: 100,
        reaction: TimeoutReaction::Stop,
    };
    let mut dev = DeviceState::with_auto_watchdog(auto);
    let mut ctx = RecordingContext::default();
    dev.poll(&mut ctx, 0);
    let ol = Command::OpenLoop {
        v_d_v: 1.0,
        v_q_v: 0.0,
        theta_e: ElectricalAngle::ZERO,
        omega_e_rad_s: 0.0,
    };
    // Disable does not arm it; open loop does (a spinning field too).
    assert_eq!(
        handle(&mut dev, &mut ctx, 1, Request::SetCommand(Command::Disable)),
        Response::Ack
    );
    assert_eq!(dev.watchdog().config(), WatchdogConfig::OFF);
    let mut dev_ol = DeviceState::with_auto_watchdog(auto);
    assert_eq!(
        handle(&mut dev_ol, &mut ctx, 1, Request::SetCommand(ol)),
        Response::Ack
    );
    assert_eq!(dev_ol.watchdog().config(), auto);
    let v = Command::Velocity { rad_s: 10.0 };
    assert_eq!(
        handle(&mut dev, &mut ctx, 2, Request::SetCommand(v)),
        Response::Ack
    );
    assert_eq!(dev.watchdog().config(), auto);
    // A keep-alive within the timeout feeds it.
    dev.poll(&mut ctx, 90);
    assert_eq!(
        handle(&mut dev, &mut ctx, 3, Request::KeepAlive),
        Response::Ack
    );
    dev.poll(&mut ctx, 180);
    assert_eq!(ctx.posted, Some(v));
    // Silence: Stop after the timeout, Disable (fault) after a second one.
    dev.poll(&mut ctx, 300);
    assert_eq!(ctx.posted, Some(Command::Velocity { rad_s: 0.0 }));
    assert!(ctx.faults.is_empty());
    dev.poll(&mut ctx, 400);
    assert!(ctx.faults.contains(Fault::CommandTimeout));

    // The host said off: it stays off.
    let mut dev = DeviceState::with_auto_watchdog(auto);
    let mut ctx = RecordingContext::default();
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            1,
            Request::SetWatchdog(WatchdogConfig::OFF)
        ),
        Response::Ack
    );
    assert_eq!(
        handle(&mut dev, &mut ctx, 2, Request::SetCommand(v)),
        Response::Ack
    );
    assert_eq!(dev.watchdog().config(), WatchdogConfig::OFF);
}

mod config_transfer {
    use foc_core::control::stage::TimeoutReaction;
    use foc_core::control::Mode;
    use foc_protocol::config::{Chunk, ConfigSource, StoreOp, CHUNK_BYTES};
    use foc_protocol::device::tests_support::{record_byte, RecordingContext};
    use foc_protocol::message::{ErrorCode, Request, Response};
    use foc_protocol::{DeviceState, WatchdogConfig};

    const AUTO: WatchdogConfig = WatchdogConfig {
        timeout_periods: 20_000,
        reaction: TimeoutReaction::Stop,
    };

    fn read_all(dev: &mut DeviceState, ctx: &mut RecordingContext) -> Vec<u8> {
        let mut out = Vec::new();
        let mut seq = 1;
        loop {
            let r = dev.handle(
                ctx,
                seq,
                0,
                &Request::ReadConfig {
                    source: ConfigSource::Live,
                    offset: out.len() as u16,
                },
            );
            seq += 1;
            let Response::ConfigChunk(c) = r else {
                panic!("{r:?}")
            };
            assert_eq!(usize::from(c.offset), out.len());
            out.extend_from_slice(c.data());
            if out.len() >= usize::from(c.total) {
                assert!(c.data().len() <= CHUNK_BYTES);
                return out;
            }
        }
    }

    #[test]
    fn a_record_is_read_in_chunks() {
        let mut ctx = RecordingContext {
            record_len: 130,
            ..Default::default()
        };
        let mut dev = DeviceState::with_auto_watchdog(AUTO);
        let rec = read_all(&mut dev, &mut ctx);
        assert_eq!(rec, (0..130).map(record_byte).collect::<Vec<_>>());
        // The live record carries the automatic link watchdog.
        assert_eq!(ctx.link, Some(AUTO));
        // Past the end: out of range, field 1 (the offset).
        let r = dev.handle(
            &mut ctx,
            99,
            0,
            &Request::ReadConfig {
                source: ConfigSource::Live,
                offset: 131,
            },
        );
        assert_eq!(r, Response::Nack(ErrorCode::OutOfRange { field: 1 }));
        // A device without a store says so.
        let mut bare = RecordingContext::default();
        let r = dev.handle(
            &mut bare,
            100,
            0,
            &Request::ReadConfig {
                source: ConfigSource::Live,
                offset: 0,
            },
        );
        assert_eq!(r, Response::Nack(ErrorCode::Unsupported));
    }

    fn write_all(dev: &mut DeviceState, ctx: &mut RecordingContext, rec: &[u8], seq0: u16) {
        for (i, part) in rec.chunks(CHUNK_BYTES).enumerate() {
            let c = Chunk::new((i * CHUNK_BYTES) as u16, rec.len() as u16, part).unwrap();
            let r = dev.handle(ctx, seq0 + i as u16, i as u32, &Request::WriteConfig(c));
            assert_eq!(r, Response::Ack);
        }
    }

    #[test]
    fn a_staged_record_reaches_the_device_whole_and_only_once() {
        let mut ctx = RecordingContext::default();
        let mut dev = DeviceState::new();
        let rec: Vec<u8> = (0..200u32).map(|i| (i * 13) as u8).collect();
        write_all(&mut dev, &mut ctx, &rec, 10);
        // A retransmitted chunk is answered from the cache, not appended twice.
        let last = Chunk::new(192, 200, &rec[192..]).unwrap();
        assert_eq!(
            dev.handle(&mut ctx, 10 + 4, 4, &Request::WriteConfig(last)),
            Response::Ack
        );
        let r = dev.handle(&mut ctx, 50, 0, &Request::Store(StoreOp::ApplyAndSave));
        assert_eq!(r, Response::Ack);
        assert_eq!(ctx.last_store, Some(StoreOp::ApplyAndSave));
        assert_eq!(&ctx.staged[..ctx.staged_len], &rec[..]);
        // Used once: applying again finds nothing staged.
        let calls = ctx.calls;
        let r = dev.handle(&mut ctx, 51, 0, &Request::Store(StoreOp::Apply));
        assert_eq!(r, Response::Nack(ErrorCode::BadRecord));
        assert_eq!(ctx.calls, calls, "nothing handed on");
    }

    #[test]
    fn an_incomplete_record_is_never_applied() {
        let mut ctx = RecordingContext::default();
        let mut dev = DeviceState::new();
        let rec = [0x42u8; 100];
        // Announces 100 bytes, sends 48.
        let c = Chunk::new(0, 100, &rec[..48]).unwrap();
        assert_eq!(
            dev.handle(&mut ctx, 20, 0, &Request::WriteConfig(c)),
            Response::Ack
        );
        let r = dev.handle(&mut ctx, 21, 0, &Request::Store(StoreOp::Apply));
        assert_eq!(r, Response::Nack(ErrorCode::BadRecord));
        assert_eq!(ctx.last_store, None);
        // A chunk that skips ahead drops the staging.
        let c = Chunk::new(0, 100, &rec[..48]).unwrap();
        dev.handle(&mut ctx, 22, 0, &Request::WriteConfig(c));
        let c = Chunk::new(96, 100, &rec[96..]).unwrap();
        let r = dev.handle(&mut ctx, 23, 0, &Request::WriteConfig(c));
        assert_eq!(r, Response::Nack(ErrorCode::OutOfRange { field: 0 }));
    }

    #[test]
    fn store_operations_need_a_started_disabled_drive() {
        let mut ctx = RecordingContext {
            mode: Mode::Torque,
            ..Default::default()
        };
        let mut dev = DeviceState::new();
        for (i, op) in [StoreOp::Save, StoreOp::Load, StoreOp::Erase]
            .into_iter()
            .enumerate()
        {
            let r = dev.handle(&mut ctx, 1 + i as u16, 0, &Request::Store(op));
            assert_eq!(r, Response::Nack(ErrorCode::NotDisabled));
        }
        let r = dev.handle(
            &mut ctx,
            9,
            0,
            &Request::ReadConfig {
                source: ConfigSource::Stored,
                offset: 0,
            },
        );
        assert_eq!(r, Response::Nack(ErrorCode::NotDisabled));
        assert_eq!(ctx.calls, 0);
        assert_eq!(ctx.last_store, None);
    }

    #[test]
    fn an_applied_record_sets_the_link_watchdog() {
        let hold = WatchdogConfig {
            timeout_periods: 5000,
            reaction: TimeoutReaction::Hold,
        };
        let mut ctx = RecordingContext {
            applied_link: Some(hold),
            ..Default::default()
        };
        let mut dev = DeviceState::with_auto_watchdog(AUTO);
        assert_eq!(dev.link_setting(), AUTO);
        assert_eq!(
            dev.handle(&mut ctx, 1, 0, &Request::Store(StoreOp::Load)),
            Response::Ack
        );
        assert_eq!(dev.link_setting(), hold);
        assert_eq!(dev.watchdog().config(), hold);
        // Saving hands the setting in force to the store.
        dev.handle(&mut ctx, 2, 0, &Request::Store(StoreOp::Save));
        assert_eq!(ctx.link, Some(hold));
        // A record carrying the automatic setting keeps it automatic.
        let mut ctx = RecordingContext {
            applied_link: Some(AUTO),
            ..Default::default()
        };
        let mut dev = DeviceState::with_auto_watchdog(AUTO);
        dev.handle(&mut ctx, 1, 0, &Request::Store(StoreOp::Load));
        assert_eq!(
            dev.watchdog().config(),
            WatchdogConfig::OFF,
            "not armed yet"
        );
        assert_eq!(dev.link_setting(), AUTO);
    }
}

#[test]
fn telemetry_power_fields_on_the_wire() {
    // NaN temperatures travel as "none" and come back NaN; out-of-range
    // ones saturate; the percentage is rounded down and capped.
    let mut t = telemetry();
    t.winding_c = f32::NAN;
    t.stage_c = 1e6;
    let bytes = wire(7, &Response::Telemetry(t));
    let back = decode_stream::<Response>(&bytes);
    let Some(Ok(Packet {
        msg: Response::Telemetry(b),
        ..
    })) = back.first()
    else {
        panic!("{back:?}")
    };
    assert!(b.winding_c.is_nan());
    assert_eq!(b.stage_c, 3276.7);
    assert_eq!(
        (b.power_limit, b.limit_left_pct, b.brake_on),
        (ActiveLimit::Regen, 37, true)
    );
    assert_eq!(temperature_to_wire(-0.04), 0);
    assert_eq!(temperature_to_wire(-0.06), -1);
    assert_eq!(temperature_to_wire(f32::NEG_INFINITY), -i16::MAX);
    assert_eq!(
        temperature_from_wire(NO_TEMPERATURE).to_bits(),
        f32::NAN.to_bits()
    );
    // From the feedback: the power report's fields.
    let mut fb = foc_core::control::Feedback::INIT;
    fb.power.active = ActiveLimit::BusCurrentRegen;
    fb.power.factor = 0.4567;
    fb.power.brake_on = true;
    fb.power.winding_c = 55.0;
    let t = Telemetry::from_feedback(&fb, 0);
    assert_eq!(
        (t.power_limit, t.limit_left_pct, t.brake_on, t.winding_c),
        (ActiveLimit::BusCurrentRegen, 45, true, 55.0)
    );
    fb.power.factor = f32::NAN;
    assert_eq!(Telemetry::from_feedback(&fb, 0).limit_left_pct, 0);
}

#[test]
fn the_stream_rate_is_capped_at_what_the_link_carries() {
    use foc_protocol::device::{max_stream_hz, stream_frame_bytes};
    // 52-byte payload: COBS adds one byte, the delimiter another.
    assert_eq!(stream_frame_bytes(), 54);
    let at_115200 = max_stream_hz(115_200);
    assert!(
        (at_115200 - 0.9 * 11_520.0 / 54.0).abs() < 1e-3,
        "{at_115200}"
    );
    assert!(max_stream_hz(2_000_000) > 3000.0);
    // A device on such a link refuses faster streams, field 1, and keeps
    // its divider.
    let mut dev = DeviceState::new();
    let mut ctx = RecordingContext {
        max_stream_hz: Some(at_115200),
        ..Default::default()
    };
    let start = |dev: &mut DeviceState, ctx: &mut RecordingContext, seq, r| {
        dev.handle(ctx, seq, seq as u32, &Request::StartTelemetry(r))
    };
    assert_eq!(
        start(&mut dev, &mut ctx, 1, TelemetryRate::Hz(150.0)),
        Response::Ack
    );
    let every = dev.telemetry_every();
    assert_eq!(every, 133);
    // The cap itself is accepted (its divider rounded up, not down past it).
    assert_eq!(
        start(&mut dev, &mut ctx, 4, TelemetryRate::Hz(at_115200)),
        Response::Ack
    );
    assert!(20_000.0 / dev.telemetry_every() as f32 <= at_115200);
    assert_eq!(
        start(&mut dev, &mut ctx, 5, TelemetryRate::Hz(150.0)),
        Response::Ack
    );
    for (seq, r) in [
        (2, TelemetryRate::Hz(250.0)),
        (3, TelemetryRate::EveryPeriods(20)),
    ] {
        assert_eq!(
            start(&mut dev, &mut ctx, seq, r),
            Response::Nack(ErrorCode::OutOfRange { field: 1 })
        );
        assert_eq!(dev.telemetry_every(), every);
    }
}

#[test]
fn a_stream_polled_every_20_periods_is_evenly_spaced_from_its_first_sample() {
    let mut dev = DeviceState::new();
    let mut ctx = RecordingContext::default();
    let mut periods = vec![];
    for k in 0..200u32 {
        let now = 7 + 20 * k;
        if k == 13 {
            let r = dev.handle(
                &mut ctx,
                1,
                1,
                &Request::StartTelemetry(TelemetryRate::EveryPeriods(160)),
            );
            assert_eq!(r, Response::Ack);
        }
        // Housekeeping's poll every 400 periods, the stream task every 20.
        let sample = if now % 400 == 7 {
            dev.poll(&mut ctx, now)
        } else {
            dev.poll_stream(&mut ctx, now)
        };
        if sample.is_some() {
            periods.push(now);
        }
    }
    assert!(periods.len() > 20);
    assert_eq!(periods[0], 7 + 20 * 13);
    assert!(
        periods.windows(2).all(|w| w[1] - w[0] == 160),
        "{periods:?}"
    );
}

/// `SetParam` (the d-current reference's parameters, design §30; the
/// tables' switches, design §32, §33): a parameter that is not writable
/// (the tables' peaks are read-only) points at `id`, a value it does not
/// take (NaN, negative, a switch not 0 or 1, `max-id` beyond foc-core's
/// bound) at `value`; both change nothing, nor does a drive that is not
/// disabled; the rest reaches the context, whose refusal is the reply.
#[test]
fn set_param_checks_the_id_and_the_value_then_asks_the_drive() {
    let mut dev = DeviceState::new();
    let mut ctx = RecordingContext::default();
    let set = |id, value| Request::SetParam { id, value };
    for p in ParamId::ALL {
        assert_eq!(
            p.is_writable(),
            matches!(
                p,
                ParamId::FieldWeakening
                    | ParamId::Mtpa
                    | ParamId::MaxIdA
                    | ParamId::ShortCircuit
                    | ParamId::Anticogging
                    | ParamId::EncoderLinearisation
            ),
            "{p:?}"
        );
    }
    let mut seq = 1;
    for (r, field) in [
        (set(ParamId::MaxCurrentA, 5.0), 0),
        (set(ParamId::PolePairs, 7.0), 0),
        (set(ParamId::MaxIdA, f32::NAN), 1),
        (set(ParamId::MaxIdA, -0.5), 1),
        (set(ParamId::MaxIdA, f32::INFINITY), 1),
        (set(ParamId::MaxIdA, 1.0e6), 1),
        (set(ParamId::FieldWeakening, 0.5), 1),
        (set(ParamId::FieldWeakening, f32::NAN), 1),
        (set(ParamId::Mtpa, 2.0), 1),
        (set(ParamId::ShortCircuit, -1.0), 1),
        (set(ParamId::AnticoggingPeakA, 0.0), 0),
        (set(ParamId::EncoderCorrectionPeakRad, 0.0), 0),
        (set(ParamId::Anticogging, 0.5), 1),
        (set(ParamId::EncoderLinearisation, 2.0), 1),
    ] {
        assert_eq!(
            handle(&mut dev, &mut ctx, seq, r),
            Response::Nack(ErrorCode::OutOfRange { field }),
            "{r:?}"
        );
        assert_eq!(
            r.field_name(field),
            Some(["id", "value"][usize::from(field)])
        );
        seq += 1;
    }
    assert_eq!((ctx.calls, ctx.written), (0, None));
    // Running: only while disabled.
    ctx.mode = Mode::Torque;
    assert_eq!(
        handle(&mut dev, &mut ctx, seq, set(ParamId::Mtpa, 1.0)),
        Response::Nack(ErrorCode::NotDisabled)
    );
    assert_eq!((ctx.calls, ctx.written), (0, None));
    ctx.mode = Mode::Disabled;
    for (id, value) in [
        (ParamId::FieldWeakening, 1.0),
        (ParamId::Mtpa, 0.0),
        (ParamId::MaxIdA, 0.0),
        (ParamId::MaxIdA, 15.5),
        (ParamId::ShortCircuit, 1.0),
        (ParamId::Anticogging, 1.0),
        (ParamId::EncoderLinearisation, 0.0),
    ] {
        seq += 1;
        assert_eq!(
            handle(&mut dev, &mut ctx, seq, set(id, value)),
            Response::Ack
        );
        assert_eq!(ctx.written, Some((id, value)));
    }
    // The drive's refusal (e.g. field weakening on halls) is the reply.
    ctx.refuse = Some(foc_protocol::Refusal::Unsupported);
    ctx.written = None;
    seq += 1;
    assert_eq!(
        handle(&mut dev, &mut ctx, seq, set(ParamId::FieldWeakening, 1.0)),
        Response::Nack(ErrorCode::Unsupported)
    );
    assert_eq!(ctx.written, None);
}

/// `RunCalibration` of the sweeps (design §32, §33): routines 3 and 4 on
/// the wire, judged like every calibration (started, disabled, not
/// faulted), then handed to the drive, whose refusal (`NotCalibrated`,
/// `Unsupported`: `Status::check_sweep`) is the reply.
#[test]
fn the_sweep_calibrations_are_routines_3_and_4_and_the_drive_decides() {
    assert_eq!(Calibration::from_code(3), Some(Calibration::Anticogging));
    assert_eq!(
        Calibration::from_code(4),
        Some(Calibration::EncoderLinearisation)
    );
    assert_eq!(Calibration::from_code(5), None);
    assert_eq!(
        Calibration::Anticogging.sweep(),
        Some(foc_core::drive::Sweep::Cogging)
    );
    assert_eq!(Calibration::Identification.sweep(), None);
    let mut dev = DeviceState::new();
    let mut seq = 1;
    for c in [Calibration::Anticogging, Calibration::EncoderLinearisation] {
        let mut ctx = RecordingContext::default();
        assert_eq!(
            handle(&mut dev, &mut ctx, seq, Request::RunCalibration(c)),
            Response::Ack
        );
        assert_eq!(ctx.calibration, Some(c));
        for (refusal, code) in [
            (
                foc_protocol::Refusal::NotCalibrated,
                ErrorCode::NotCalibrated,
            ),
            (foc_protocol::Refusal::Unsupported, ErrorCode::Unsupported),
        ] {
            seq += 1;
            let mut ctx = RecordingContext {
                refuse: Some(refusal),
                ..Default::default()
            };
            assert_eq!(
                handle(&mut dev, &mut ctx, seq, Request::RunCalibration(c)),
                Response::Nack(code)
            );
            assert_eq!(ctx.calibration, None);
        }
        // Enabled: refused before the drive is asked.
        seq += 1;
        let mut ctx = RecordingContext {
            mode: Mode::Velocity,
            ..Default::default()
        };
        assert_eq!(
            handle(&mut dev, &mut ctx, seq, Request::RunCalibration(c)),
            Response::Nack(ErrorCode::NotDisabled)
        );
        assert_eq!(ctx.calibration, None);
        seq += 1;
    }
}
