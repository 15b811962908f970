//! The contract between this crate and the Python client (issue 34): every
//! message layout of the current protocol version, rendered from the
//! crate's own encoder into `python/tests/vectors/protocol-v<N>.json`,
//! which `python/tests/test_layouts.py` checks the Python package
//! (`python/foc_drive/messages.py`) against.
//!
//! One instance (or one per case of an enum field) of every [`Request`] and
//! [`Response`] variant is encoded with [`Message::encode_body`] (what
//! [`foc_protocol::frame::encode`] puts between tag and CRC), decoded back,
//! and written with its tag, its fields and its body bytes; so are the code
//! tables and constants the Python package mirrors. The test fails when
//! the rendered document differs from the committed file; with
//! `FOC_BLESS=1` it writes the file instead (then run the Python tests).
//!
//! Coverage: [`request_fields`] and [`response_fields`] match every variant
//! without a wildcard (a new variant does not compile until it is rendered),
//! and [`every_tag_has_a_vector`] asks the decoder which tags exist (a new
//! tag without a sample fails the test). Code tables are read from the
//! `from_code` functions over every byte value, so they are complete.
//!
//! JSON conventions: floats are the exact `f32` value (printed as the
//! shortest `f64` that reads back to it; `"inf"`, `"-inf"`, `"nan"` for
//! the non-finite ones, which JSON has no number for), enumerations are
//! their wire codes, byte strings are lower-case hex.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::PathBuf;

use foc_core::angle::ElectricalAngle;
use foc_core::control::homing::{EndStop, HomingMethod};
use foc_core::control::joint::Impedance;
use foc_core::control::power::ActiveLimit;
use foc_core::control::stage::TimeoutReaction;
use foc_core::control::{AngleInUse, Command, Fault, FaultSet, Limits};
use foc_core::scope::{ScopeConfig, ScopeStatus, Signal, State, TriggerKind, MAX_CHANNELS};
use foc_protocol::config::{Chunk, ConfigSource, StoreOp, CHUNK_BYTES, MAX_RECORD};
use foc_protocol::frame::{
    encode, FrameDecoder, Reader, Writer, MAX_BODY, MAX_FRAME, MAX_PAYLOAD, OVERHEAD,
};
use foc_protocol::message::*;
use foc_protocol::scope::{DATA_PER_FRAME, UNUSED};
use foc_protocol::PROTOCOL_VERSION;

// ------------------------------------------------------------------ JSON

/// A JSON value whose objects keep their keys in insertion order (body
/// order for fields).
#[derive(Clone, Debug)]
enum Json {
    Null,
    Bool(bool),
    Int(i64),
    F32(f32),
    Str(String),
    Arr(Vec<Json>),
    Obj(Vec<(String, Json)>),
}

fn obj(pairs: Vec<(&str, Json)>) -> Json {
    Json::Obj(pairs.into_iter().map(|(k, v)| (k.to_string(), v)).collect())
}

fn int(v: impl Into<i64>) -> Json {
    Json::Int(v.into())
}

fn f(v: f32) -> Json {
    Json::F32(v)
}

fn s(v: &str) -> Json {
    Json::Str(v.to_string())
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().fold(String::new(), |mut out, b| {
        let _ = write!(out, "{b:02x}");
        out
    })
}

fn quote(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

fn float(v: f32) -> String {
    if v.is_nan() {
        "\"nan\"".into()
    } else if v.is_infinite() {
        if v > 0.0 { "\"inf\"" } else { "\"-inf\"" }.into()
    } else {
        // Debug of an f64: the shortest text that reads back to the same
        // f64 (exactly the f32's value), always with a '.' or an exponent.
        let t = format!("{:?}", f64::from(v));
        assert!(t.parse::<f64>().unwrap() == f64::from(v));
        t
    }
}

impl Json {
    fn compact(&self) -> String {
        match self {
            Json::Null => "null".into(),
            Json::Bool(b) => b.to_string(),
            Json::Int(i) => i.to_string(),
            Json::F32(v) => float(*v),
            Json::Str(s) => quote(s),
            Json::Arr(a) => {
                let items: Vec<String> = a.iter().map(Json::compact).collect();
                format!("[{}]", items.join(", "))
            }
            Json::Obj(o) => {
                let items: Vec<String> = o
                    .iter()
                    .map(|(k, v)| format!("{}: {}", quote(k), v.compact()))
                    .collect();
                format!("{{{}}}", items.join(", "))
            }
        }
    }

    /// Pretty: a container on one line when that line is short, else one
    /// item per line.
    fn pretty(&self, indent: usize, out: &mut String) {
        let c = self.compact();
        if c.len() + indent <= 100 {
            out.push_str(&c);
            return;
        }
        let pad = " ".repeat(indent + 2);
        match self {
            Json::Arr(a) => {
                out.push_str("[\n");
                for (i, v) in a.iter().enumerate() {
                    out.push_str(&pad);
                    v.pretty(indent + 2, out);
                    out.push_str(if i + 1 < a.len() { ",\n" } else { "\n" });
                }
                out.push_str(&" ".repeat(indent));
                out.push(']');
            }
            Json::Obj(o) => {
                out.push_str("{\n");
                for (i, (k, v)) in o.iter().enumerate() {
                    out.push_str(&pad);
                    out.push_str(&quote(k));
                    out.push_str(": ");
                    v.pretty(indent + 2, out);
                    out.push_str(if i + 1 < o.len() { ",\n" } else { "\n" });
                }
                out.push_str(&" ".repeat(indent));
                out.push('}');
            }
            _ => out.push_str(&c),
        }
    }
}

// ---------------------------------------------------------- the encoder

/// The body of `m` as the crate encodes it, checked to decode back to `m`
/// (body and whole frame); returns the bytes and the decoded message.
fn body<M: Message + Clone + PartialEq + std::fmt::Debug>(m: &M) -> (Vec<u8>, M) {
    let mut buf = [0u8; MAX_BODY];
    let mut w = Writer::new(&mut buf);
    m.encode_body(&mut w);
    assert!(!w.overflowed(), "{m:?}: body longer than {MAX_BODY} bytes");
    let bytes = w.written().to_vec();
    let mut r = Reader::new(&bytes);
    let back = M::decode_body(m.tag(), &mut r).unwrap_or_else(|e| panic!("{m:?}: {e:?}"));
    r.finish().unwrap();
    assert_eq!(&back, m, "body round trip");
    // The same body inside a frame.
    let mut wire = [0u8; MAX_FRAME];
    let n = encode(0x1234, m, &mut wire).unwrap();
    let mut got = Vec::new();
    FrameDecoder::new().feed_slice::<M>(&wire[..n], |p| got.push(p.unwrap().msg));
    assert_eq!(got, vec![back.clone()], "frame round trip");
    assert_eq!(n, wire_len(&bytes), "frame of {m:?}");
    (bytes, back)
}

/// Length of the frame of a body (COBS of tag, seq 0x1234, body, CRC, and
/// the delimiter): checks the frame carries exactly the body's bytes.
fn wire_len(body: &[u8]) -> usize {
    let payload = OVERHEAD + body.len();
    // No zero in tag and seq 0x1234; a body or CRC zero does not change
    // the COBS length below 254 bytes: payload + 1 code byte + delimiter.
    assert!(payload <= MAX_PAYLOAD);
    payload + 2
}

/// `SetCommand` and friends: CamelCase variant name to the Python `Tag`
/// member name (`SET_COMMAND`).
fn tag_name(variant: &str) -> String {
    let mut out = String::new();
    for (i, c) in variant.chars().enumerate() {
        if c.is_ascii_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(c.to_ascii_uppercase());
    }
    out
}

// --------------------------------------------------------------- fields

fn joint_fields(j: &JointSettings) -> Vec<(&'static str, Json)> {
    let (travel, (lo, hi)) = match j.travel_out_rad {
        Some(r) => (1, r),
        None => (0, (0.0, 0.0)),
    };
    vec![
        ("gear_ratio", f(j.gear_ratio)),
        ("rotor_at_zero_rad", f(j.rotor_at_zero_rad)),
        ("travel", int(travel)),
        ("travel_min_rad", f(lo)),
        ("travel_max_rad", f(hi)),
        ("fault_margin_rad", f(j.fault_margin_rad)),
        ("brake_accel_rad_s2", f(j.brake_accel_rad_s2)),
        ("kv_a_per_rad_s", f(j.kv_a_per_rad_s)),
        ("entry_blend_periods", int(j.entry_blend_periods)),
        ("timeout_kd_nm_s_per_rad", f(j.timeout_kd_nm_s_per_rad)),
    ]
}

fn scope_config_fields(c: &ScopeConfig) -> Vec<(String, Json)> {
    let used = c.used();
    let mut out: Vec<(String, Json)> = (0..MAX_CHANNELS)
        .map(|i| {
            let code = used.get(i).map_or(UNUSED, |s| *s as u8);
            (format!("signal{i}"), int(code))
        })
        .collect();
    for (k, v) in [
        ("divider", int(c.divider)),
        ("samples", int(c.samples)),
        ("pre_trigger", int(c.pre_trigger)),
        ("trigger", int(c.trigger as u8)),
        ("trigger_signal", int(c.trigger_signal as u8)),
        ("level", f(c.level)),
    ] {
        out.push((k.to_string(), v));
    }
    out
}

/// Name and wire fields (names as [`Request::field_name`] gives them, in
/// body order) of a request. No wildcard: a new variant fails to compile
/// here until it is rendered.
fn request_fields(r: &Request) -> (&'static str, Vec<(String, Json)>) {
    fn own(v: Vec<(&str, Json)>) -> Vec<(String, Json)> {
        v.into_iter().map(|(k, v)| (k.to_string(), v)).collect()
    }
    let (name, fields) = match *r {
        Request::Ping => ("Ping", vec![]),
        Request::KeepAlive => ("KeepAlive", vec![]),
        Request::SetCommand(c) => {
            let mode = ("mode", int(c.mode() as u8));
            let rest = match c {
                Command::Disable => vec![],
                Command::Torque { iq_a } => vec![("iq_a", f(iq_a))],
                Command::Velocity { rad_s } => vec![("rad_s", f(rad_s))],
                Command::Position { rad } => vec![("rad", f(rad))],
                Command::OpenLoop {
                    v_d_v,
                    v_q_v,
                    theta_e,
                    omega_e_rad_s,
                } => vec![
                    ("v_d_v", f(v_d_v)),
                    ("v_q_v", f(v_q_v)),
                    ("theta_e", int(theta_e.to_bits())),
                    ("omega_e_rad_s", f(omega_e_rad_s)),
                ],
                Command::Impedance(i) => vec![
                    ("position_rad", f(i.position_rad)),
                    ("velocity_rad_s", f(i.velocity_rad_s)),
                    ("kp_nm_per_rad", f(i.kp_nm_per_rad)),
                    ("kd_nm_s_per_rad", f(i.kd_nm_s_per_rad)),
                    ("torque_ff_nm", f(i.torque_ff_nm)),
                    ("torque_limit_nm", f(i.torque_limit_nm)),
                ],
            };
            (
                "SetCommand",
                own(std::iter::once(mode).chain(rest).collect()),
            )
        }
        Request::SetLimits(l) => (
            "SetLimits",
            own(vec![
                ("max_current_a", f(l.max_current_a)),
                ("max_velocity_rad_s", f(l.max_velocity_rad_s)),
                ("min_position_rad", f(l.min_position_rad)),
                ("max_position_rad", f(l.max_position_rad)),
                ("max_open_loop_voltage_v", f(l.max_open_loop_voltage_v)),
                (
                    "max_open_loop_omega_e_rad_s",
                    f(l.max_open_loop_omega_e_rad_s),
                ),
                ("max_kp_nm_per_rad", f(l.max_kp_nm_per_rad)),
                ("max_kd_nm_s_per_rad", f(l.max_kd_nm_s_per_rad)),
            ]),
        ),
        Request::SetCurrentGains(g) => (
            "SetCurrentGains",
            own(vec![
                ("kp_d", f(g.kp_d)),
                ("ki_d", f(g.ki_d)),
                ("kp_q", f(g.kp_q)),
                ("ki_q", f(g.ki_q)),
            ]),
        ),
        Request::SetSpeedGains(g) => (
            "SetSpeedGains",
            own(vec![
                ("kp_a_per_rad_s", f(g.kp_a_per_rad_s)),
                ("ki_a_per_rad", f(g.ki_a_per_rad)),
            ]),
        ),
        Request::SetPositionGains(g) => (
            "SetPositionGains",
            own(vec![
                ("kp_per_s", f(g.kp_per_s)),
                ("max_velocity_rad_s", f(g.max_velocity_rad_s)),
                ("max_acceleration_rad_s2", f(g.max_acceleration_rad_s2)),
            ]),
        ),
        Request::SetDividers { speed, position } => (
            "SetDividers",
            own(vec![("speed", int(speed)), ("position", int(position))]),
        ),
        Request::SetWatchdog(c) => (
            "SetWatchdog",
            own(vec![
                ("timeout_periods", int(c.timeout_periods)),
                ("reaction", int(reaction_code(c.reaction))),
            ]),
        ),
        Request::SetJoint(j) => ("SetJoint", own(joint_fields(&j))),
        Request::SetParam { id, value } => (
            "SetParam",
            own(vec![("id", int(id as u8)), ("value", f(value))]),
        ),
        Request::ReadJoint => ("ReadJoint", vec![]),
        Request::StartHoming(h) => {
            let mut v = vec![];
            match h.method {
                HomingMethod::Present => {
                    v.push(("method", int(0)));
                    v.push(("home_output_rad", f(h.home_output_rad)));
                }
                HomingMethod::EndStop(e) => {
                    v.push(("method", int(1)));
                    v.push(("home_output_rad", f(h.home_output_rad)));
                    v.push(("velocity_rad_s", f(e.velocity_rad_s)));
                    v.push(("current_a", f(e.current_a)));
                    v.push(("detect_fraction", f(e.detect_fraction)));
                    v.push(("confirm_s", f(e.confirm_s)));
                    v.push(("backoff_rad", f(e.backoff_rad)));
                    v.push(("max_travel_rad", f(e.max_travel_rad)));
                }
            }
            ("StartHoming", own(v))
        }
        Request::ReadHoming => ("ReadHoming", vec![]),
        Request::RunCalibration(c) => ("RunCalibration", own(vec![("routine", int(c as u8))])),
        Request::ReadFaults => ("ReadFaults", vec![]),
        Request::ClearFaults => ("ClearFaults", vec![]),
        Request::ReadParam(p) => ("ReadParam", own(vec![("id", int(p as u8))])),
        Request::ReadTelemetry => ("ReadTelemetry", vec![]),
        Request::StartTelemetry(rate) => (
            "StartTelemetry",
            own(match rate {
                TelemetryRate::EveryPeriods(k) => vec![("kind", int(0)), ("value", int(k))],
                TelemetryRate::Hz(hz) => vec![("kind", int(1)), ("value", f(hz))],
            }),
        ),
        Request::StopTelemetry => ("StopTelemetry", vec![]),
        Request::ReadConfig { source, offset } => (
            "ReadConfig",
            own(vec![("source", int(source as u8)), ("offset", int(offset))]),
        ),
        Request::WriteConfig(c) => (
            "WriteConfig",
            own(vec![
                ("offset", int(c.offset)),
                ("total", int(c.total)),
                ("len", int(c.data().len() as u8)),
                ("data", s(&hex(c.data()))),
            ]),
        ),
        Request::Store(op) => ("Store", own(vec![("op", int(op as u8))])),
        Request::SetScope(c) => ("SetScope", scope_config_fields(&c)),
        Request::ArmScope => ("ArmScope", vec![]),
        Request::TriggerScope => ("TriggerScope", vec![]),
        Request::ReadScope => ("ReadScope", vec![]),
        Request::ReadScopeData { offset } => ("ReadScopeData", own(vec![("offset", int(offset))])),
    };
    // The names are the crate's own field names (what a Nack points at);
    // `data` (a chunk's bytes) is not a numbered field.
    for (i, (k, _)) in fields.iter().filter(|(k, _)| k != "data").enumerate() {
        assert_eq!(
            r.field_name(i as u8),
            Some(k.as_str()),
            "{name}: field {i} of the rendering is not the crate's field {i}"
        );
    }
    (name, fields)
}

/// Name and fields (of the decoded value, as the Python package's decoders
/// name them) of a response. No wildcard: a new variant fails to compile
/// here until it is rendered.
fn response_fields(r: &Response) -> (&'static str, Vec<(&'static str, Json)>) {
    match *r {
        Response::Ack => ("Ack", vec![]),
        Response::Nack(e) => {
            let (code, field) = e.to_wire();
            ("Nack", vec![("code", int(code)), ("field", int(field))])
        }
        Response::Hello(h) => (
            "Hello",
            vec![
                ("protocol_version", int(h.protocol_version)),
                (
                    "firmware_version",
                    Json::Arr(h.firmware_version.iter().map(|v| int(*v)).collect()),
                ),
                ("max_payload", int(h.max_payload)),
            ],
        ),
        Response::Faults(r) => (
            "Faults",
            vec![("bits", int(r.set.0)), ("first_code", int(r.first_code))],
        ),
        Response::Param { id, value } => {
            ("Param", vec![("id", int(id as u8)), ("value", f(value))])
        }
        Response::Telemetry(t) => ("Telemetry", telemetry_fields(&t)),
        Response::Stream(t) => ("Stream", telemetry_fields(&t)),
        Response::ConfigChunk(c) => (
            "ConfigChunk",
            vec![
                ("offset", int(c.offset)),
                ("total", int(c.total)),
                ("data", s(&hex(c.data()))),
            ],
        ),
        Response::Joint(j) => (
            "Joint",
            vec![
                ("gear_ratio", f(j.gear_ratio)),
                ("rotor_at_zero_rad", f(j.rotor_at_zero_rad)),
                (
                    "travel_out_rad",
                    match j.travel_out_rad {
                        Some((lo, hi)) => Json::Arr(vec![f(lo), f(hi)]),
                        None => Json::Null,
                    },
                ),
                ("fault_margin_rad", f(j.fault_margin_rad)),
                ("brake_accel_rad_s2", f(j.brake_accel_rad_s2)),
                ("kv_a_per_rad_s", f(j.kv_a_per_rad_s)),
                ("entry_blend_periods", int(j.entry_blend_periods)),
                ("timeout_kd_nm_s_per_rad", f(j.timeout_kd_nm_s_per_rad)),
            ],
        ),
        Response::Homing(h) => {
            let (state, reason) = h.to_wire();
            (
                "Homing",
                vec![("state", int(state)), ("reason", int(reason))],
            )
        }
        Response::Scope(r) => {
            let st = &r.status;
            let c = &st.config;
            (
                "Scope",
                vec![
                    ("state", int(st.state as u8)),
                    (
                        "signals",
                        Json::Arr(c.used().iter().map(|s| int(*s as u8)).collect()),
                    ),
                    ("divider", int(c.divider)),
                    ("samples", int(c.samples)),
                    ("pre_trigger", int(c.pre_trigger)),
                    ("trigger", int(c.trigger as u8)),
                    ("trigger_signal", int(c.trigger_signal as u8)),
                    ("level", f(c.level)),
                    ("captured", int(st.captured)),
                    ("trigger_index", int(st.trigger_index)),
                    ("trigger_period", int(st.trigger_period)),
                    ("sample_period_s", f(r.sample_period_s)),
                    ("capacity", int(st.capacity)),
                ],
            )
        }
        Response::ScopeData(d) => (
            "ScopeData",
            vec![
                ("offset", int(d.offset)),
                (
                    "values",
                    Json::Arr(d.values().iter().map(|v| f(*v)).collect()),
                ),
            ],
        ),
    }
}

fn telemetry_fields(t: &Telemetry) -> Vec<(&'static str, Json)> {
    vec![
        ("period", int(t.period)),
        ("i_d_a", f(t.i_d_a)),
        ("i_q_a", f(t.i_q_a)),
        ("v_d_v", f(t.v_d_v)),
        ("v_q_v", f(t.v_q_v)),
        ("velocity_rad_s", f(t.velocity_rad_s)),
        ("position_rad", f(t.position_rad)),
        ("mode", int(t.mode as u8)),
        ("fault_code", int(t.fault_code)),
        ("max_loop_cycles", int(t.max_loop_cycles)),
        ("v_bus_v", f(t.v_bus_v)),
        ("power_limit", int(t.power_limit as u8)),
        ("limit_left_pct", int(t.limit_left_pct)),
        ("brake_on", Json::Bool(t.brake_on)),
        ("brake_locked", Json::Bool(t.brake_locked)),
        ("winding_c", f(t.winding_c)),
        ("stage_c", f(t.stage_c)),
        ("angle_in_use", int(t.angle_in_use.code())),
    ]
}

// -------------------------------------------------------------- samples

fn scope_config(
    signals: &[Signal],
    divider: u16,
    samples: u16,
    pre_trigger: u16,
    trigger: TriggerKind,
    trigger_signal: Signal,
    level: f32,
) -> ScopeConfig {
    let mut c = ScopeConfig::new(signals);
    c.divider = divider;
    c.samples = samples;
    c.pre_trigger = pre_trigger;
    c.trigger = trigger;
    c.trigger_signal = trigger_signal;
    c.level = level;
    c
}

/// Six configurations, one per trigger kind, that use every signal.
fn scope_configs() -> Vec<ScopeConfig> {
    use Signal::*;
    let all = Signal::ALL;
    vec![
        scope_config(&all[..8], 1, 0, 0, TriggerKind::Manual, IdA, 0.0),
        scope_config(&all[8..], 7, 300, 30, TriggerKind::Command, IdA, 0.0),
        scope_config(
            &[ModeCode],
            u16::MAX,
            u16::MAX,
            u16::MAX - 1,
            TriggerKind::Fault,
            VqV,
            -0.0,
        ),
        scope_config(
            &[IqA, IqRefA],
            2,
            1000,
            999,
            TriggerKind::Rising,
            VelocityRadS,
            -12.5,
        ),
        scope_config(
            &[PositionRad, Target, BusV],
            3,
            2,
            1,
            TriggerKind::Falling,
            PositionRad,
            1.0e-3,
        ),
        scope_config(
            &[DutyA, DutyB, DutyC, ThetaERad],
            10,
            100,
            50,
            TriggerKind::Either,
            ThetaERad,
            f32::MAX,
        ),
    ]
}

fn joints() -> [JointSettings; 2] {
    [
        JointSettings {
            gear_ratio: -3.5,
            rotor_at_zero_rad: 0.25,
            travel_out_rad: None,
            fault_margin_rad: 0.5,
            brake_accel_rad_s2: 1000.0,
            kv_a_per_rad_s: 0.02,
            entry_blend_periods: u32::MAX,
            timeout_kd_nm_s_per_rad: 0.001,
        },
        JointSettings {
            gear_ratio: 121.0,
            rotor_at_zero_rad: -1.0e6,
            travel_out_rad: Some((-1.25, 2.5)),
            fault_margin_rad: 0.1,
            brake_accel_rad_s2: 2.5e4,
            kv_a_per_rad_s: 0.75,
            entry_blend_periods: 200,
            timeout_kd_nm_s_per_rad: 0.0,
        },
    ]
}

fn requests() -> Vec<Request> {
    let mut v = vec![
        Request::Ping,
        Request::KeepAlive,
        Request::SetCommand(Command::Disable),
        Request::SetCommand(Command::Torque { iq_a: -1.5 }),
        Request::SetCommand(Command::Velocity { rad_s: 123.456 }),
        Request::SetCommand(Command::Position { rad: -0.1 }),
        Request::SetCommand(Command::OpenLoop {
            v_d_v: 0.75,
            v_q_v: -2.25,
            theta_e: ElectricalAngle::from_bits(0xDEAD_BEEF),
            omega_e_rad_s: -1000.125,
        }),
        Request::SetCommand(Command::Impedance(Impedance {
            position_rad: 1.0e-3,
            velocity_rad_s: -3.5,
            kp_nm_per_rad: 12.5,
            kd_nm_s_per_rad: 0.0625,
            torque_ff_nm: -0.3,
            torque_limit_nm: f32::INFINITY,
        })),
        Request::SetLimits(Limits {
            max_current_a: 20.5,
            max_velocity_rad_s: 1000.0,
            min_position_rad: f32::MIN,
            max_position_rad: f32::MAX,
            max_open_loop_voltage_v: 12.0,
            max_open_loop_omega_e_rad_s: 6283.185,
            max_kp_nm_per_rad: 1.0e-7,
            max_kd_nm_s_per_rad: 0.0,
        }),
        Request::SetCurrentGains(CurrentGains {
            kp_d: 0.35,
            ki_d: 1234.5,
            kp_q: -0.4,
            ki_q: -0.0,
        }),
        Request::SetSpeedGains(SpeedGains {
            kp_a_per_rad_s: 0.0123,
            ki_a_per_rad: 4.5e-5,
        }),
        Request::SetPositionGains(PositionGains {
            kp_per_s: 25.0,
            max_velocity_rad_s: 300.0,
            max_acceleration_rad_s2: 1.0e4,
        }),
        Request::SetDividers {
            speed: 1,
            position: u16::MAX,
        },
    ];
    for (timeout_periods, reaction) in [
        (u32::MAX, TimeoutReaction::Disable),
        (0, TimeoutReaction::Stop),
        (20_000, TimeoutReaction::Hold),
    ] {
        v.push(Request::SetWatchdog(WatchdogConfig {
            timeout_periods,
            reaction,
        }));
    }
    v.extend(joints().map(Request::SetJoint));
    for (id, value) in [
        (ParamId::FieldWeakening, 1.0),
        (ParamId::Mtpa, 0.0),
        (ParamId::MaxIdA, 12.5),
        (ParamId::ShortCircuit, 1.0),
        (ParamId::Anticogging, 1.0),
        (ParamId::EncoderLinearisation, 0.0),
    ] {
        v.push(Request::SetParam { id, value });
    }
    v.push(Request::ReadJoint);
    v.push(Request::StartHoming(HomingStart {
        method: HomingMethod::Present,
        home_output_rad: -0.5,
    }));
    v.push(Request::StartHoming(HomingStart {
        method: HomingMethod::EndStop(EndStop {
            velocity_rad_s: -2.0,
            current_a: 3.25,
            detect_fraction: 0.8,
            confirm_s: 0.125,
            backoff_rad: 0.2,
            max_travel_rad: 6.5,
        }),
        home_output_rad: 1.5,
    }));
    v.push(Request::ReadHoming);
    for c in [
        Calibration::Offsets,
        Calibration::Identification,
        Calibration::Alignment,
        Calibration::Anticogging,
        Calibration::EncoderLinearisation,
    ] {
        v.push(Request::RunCalibration(c));
    }
    v.push(Request::ReadFaults);
    v.push(Request::ClearFaults);
    v.extend(ParamId::ALL.iter().map(|p| Request::ReadParam(*p)));
    v.push(Request::ReadTelemetry);
    v.push(Request::StartTelemetry(TelemetryRate::EveryPeriods(20)));
    v.push(Request::StartTelemetry(TelemetryRate::EveryPeriods(
        u32::MAX,
    )));
    v.push(Request::StartTelemetry(TelemetryRate::Hz(333.25)));
    v.push(Request::StopTelemetry);
    v.push(Request::ReadConfig {
        source: ConfigSource::Live,
        offset: 0,
    });
    v.push(Request::ReadConfig {
        source: ConfigSource::Stored,
        offset: 272,
    });
    let record: Vec<u8> = (0..CHUNK_BYTES as u32)
        .map(|i| (i * 37 + 11) as u8)
        .collect();
    v.push(Request::WriteConfig(Chunk::new(48, 300, &record).unwrap()));
    v.push(Request::WriteConfig(
        Chunk::new(0, 5, &[0x00, 0x01, 0x7f, 0xfe, 0xff]).unwrap(),
    ));
    for op in [
        StoreOp::Save,
        StoreOp::Load,
        StoreOp::Erase,
        StoreOp::Apply,
        StoreOp::ApplyAndSave,
    ] {
        v.push(Request::Store(op));
    }
    v.extend(scope_configs().into_iter().map(Request::SetScope));
    v.push(Request::ArmScope);
    v.push(Request::TriggerScope);
    v.push(Request::ReadScope);
    v.push(Request::ReadScopeData { offset: 12 });
    v.push(Request::ReadScopeData { offset: u16::MAX });
    v
}

/// Every [`ErrorCode`] this version knows, and one it does not.
fn error_codes() -> Vec<ErrorCode> {
    let known: Vec<ErrorCode> = (0..=u8::MAX)
        .map(|c| ErrorCode::from_wire(c, 13))
        .filter(|e| !matches!(e, ErrorCode::Other(_)))
        .collect();
    known.into_iter().chain([ErrorCode::Other(200)]).collect()
}

/// A name for each error code (Python's `ErrorCode` member names).
fn error_code_name(e: ErrorCode) -> Option<&'static str> {
    Some(match e {
        ErrorCode::Malformed => "Malformed",
        ErrorCode::BadCrc => "BadCrc",
        ErrorCode::UnknownMessage => "UnknownMessage",
        ErrorCode::OutOfRange { .. } => "OutOfRange",
        ErrorCode::Faulted => "Faulted",
        ErrorCode::Busy => "Busy",
        ErrorCode::NotCalibrated => "NotCalibrated",
        ErrorCode::NotDisabled => "NotDisabled",
        ErrorCode::Unsupported => "Unsupported",
        ErrorCode::StoreFailed => "StoreFailed",
        ErrorCode::BadRecord => "BadRecord",
        ErrorCode::NothingStored => "NothingStored",
        ErrorCode::ScopeState => "ScopeState",
        ErrorCode::NeedsAngleSensor => "NeedsAngleSensor",
        ErrorCode::Other(_) => return None,
    })
}

fn telemetry_samples() -> Vec<Response> {
    let limits: Vec<ActiveLimit> = (0..=u8::MAX).filter_map(active_limit_from_code).collect();
    let temps = [
        (f32::NAN, f32::NAN),
        (-40.5, 125.3),
        (3276.7, -3276.7),
        (25.0, f32::NAN),
        (f32::NAN, -0.1),
    ];
    limits
        .iter()
        .enumerate()
        .map(|(i, &power_limit)| {
            let k = i as u32;
            let (winding_c, stage_c) = temps[i % temps.len()];
            let t = Telemetry {
                period: u32::MAX - k * 977,
                i_d_a: -0.125 * (k as f32 + 1.0),
                i_q_a: 10.1 + k as f32,
                v_d_v: -1.0e-3,
                v_q_v: 23.9,
                velocity_rad_s: -314.159_27 + k as f32,
                position_rad: 1.0e5 / (k as f32 + 3.0),
                mode: mode_from_code((i % 6) as u8).unwrap(),
                fault_code: [0, 10, 21, 255][i % 4],
                max_loop_cycles: 1000 + 37 * k,
                v_bus_v: 48.2,
                power_limit,
                limit_left_pct: [100, 0, 99, 37][i % 4],
                brake_on: i % 2 == 1,
                brake_locked: i % 4 >= 2,
                winding_c,
                stage_c,
                angle_in_use: AngleInUse::from_code((i % 4) as u8).unwrap(),
            };
            if i % 2 == 0 {
                Response::Telemetry(t)
            } else {
                Response::Stream(t)
            }
        })
        .collect()
}

fn responses() -> Vec<Response> {
    let mut v = vec![Response::Ack];
    v.extend(error_codes().into_iter().map(Response::Nack));
    v.push(Response::Hello(Hello {
        protocol_version: PROTOCOL_VERSION,
        firmware_version: [1, 22, 255],
        max_payload: MAX_PAYLOAD as u8,
    }));
    let some = FaultSet(
        (1 << Fault::OverCurrentPhase.code())
            | (1 << Fault::CommandTimeout.code())
            | (1 << Fault::TravelLimit.code()),
    );
    for (set, first_code) in [
        (FaultSet(0), 0),
        (some, Fault::CommandTimeout.code()),
        (FaultSet(u32::MAX - 1), 31),
    ] {
        v.push(Response::Faults(FaultReport { set, first_code }));
    }
    for (id, value) in [
        (ParamId::PolePairs, 7.0),
        (ParamId::ResistanceOhm, 0.0123),
        (ParamId::FirmwareVersion, 10203.0),
        (ParamId::SpeedKi, -4.5e-5),
        (ParamId::ScopeCapacity, 4096.0),
        (ParamId::AngleSource, 1.0),
        (ParamId::FieldWeakening, 1.0),
        (ParamId::MaxIdA, 15.138889),
        (ParamId::Anticogging, 1.0),
        (ParamId::AnticoggingPeakA, 0.3125),
        (ParamId::EncoderCorrectionPeakRad, 0.0048828125),
    ] {
        v.push(Response::Param { id, value });
    }
    v.extend(telemetry_samples());
    let record: Vec<u8> = (0..CHUNK_BYTES as u32)
        .map(|i| (255 - i * 5) as u8)
        .collect();
    v.push(Response::ConfigChunk(
        Chunk::new(96, MAX_RECORD as u16, &record).unwrap(),
    ));
    v.push(Response::ConfigChunk(Chunk::new(320, 320, &[]).unwrap()));
    v.extend(joints().map(Response::Joint));
    v.push(Response::Homing(HomingState::Idle));
    v.push(Response::Homing(HomingState::Running));
    v.push(Response::Homing(HomingState::Done));
    v.extend(
        (0..=u8::MAX)
            .filter_map(HomingFailure::from_code)
            .map(|f| Response::Homing(HomingState::Failed(f))),
    );
    let states: Vec<State> = (0..=u8::MAX).filter_map(State::from_code).collect();
    for (i, (state, config)) in states.iter().zip(scope_configs()).enumerate() {
        let k = i as u16;
        let mut config = config;
        if config.samples == 0 {
            config.samples = 512; // resolved
        }
        v.push(Response::Scope(ScopeReport {
            status: ScopeStatus {
                state: *state,
                config,
                captured: 17 * k,
                trigger_index: 3 * k,
                trigger_period: u32::MAX - u32::from(k),
                capacity: 4096 + k,
            },
            sample_period_s: 5.0e-5 * f32::from(k + 1),
        }));
    }
    let mut values = [0.0f32; DATA_PER_FRAME];
    for (i, x) in values.iter_mut().enumerate() {
        *x = (i as f32 - 5.5) * 0.3;
    }
    values[11] = f32::MIN;
    v.push(Response::ScopeData(ScopeData {
        offset: 0,
        count: DATA_PER_FRAME as u8,
        values,
    }));
    v.push(Response::ScopeData(ScopeData {
        offset: u16::MAX,
        count: 0,
        values: [0.0; DATA_PER_FRAME],
    }));
    let mut five = [0.0f32; DATA_PER_FRAME];
    five[..5].copy_from_slice(&[1.0, -2.5, 1.0e-6, 65504.0, f32::INFINITY]);
    v.push(Response::ScopeData(ScopeData {
        offset: 4092,
        count: 5,
        values: five,
    }));
    v
}

// ----------------------------------------------------------------- tables

/// `(code, name)` of every code `from_code` knows.
fn table<T: std::fmt::Debug>(from_code: impl Fn(u8) -> Option<T>) -> Json {
    Json::Arr(
        (0..=u8::MAX)
            .filter_map(|c| from_code(c).map(|v| Json::Arr(vec![int(c), s(&format!("{v:?}"))])))
            .collect(),
    )
}

/// The telemetry body's fields in wire order with their types (the
/// Python package's `TELEMETRY_LAYOUT`), checked against the encoder.
const TELEMETRY_LAYOUT: [(&str, &str); 16] = [
    ("period", "u32"),
    ("i_d_a", "f32"),
    ("i_q_a", "f32"),
    ("v_d_v", "f32"),
    ("v_q_v", "f32"),
    ("velocity_rad_s", "f32"),
    ("position_rad", "f32"),
    ("mode", "u8"),
    ("fault_code", "u8"),
    ("max_loop_cycles", "u32"),
    ("v_bus_v", "f32"),
    ("power_limit", "u8"),
    ("limit_left_pct", "u8"),
    ("flags", "u8"),
    ("winding_dC", "i16"),
    ("stage_dC", "i16"),
];

/// Read `body` with [`TELEMETRY_LAYOUT`] and compare with `t`.
fn check_telemetry_layout(t: &Telemetry, body: &[u8]) {
    let mut r = Reader::new(body);
    for (name, ty) in TELEMETRY_LAYOUT {
        let got: f64 = match ty {
            "u8" => f64::from(r.u8().unwrap()),
            "i16" => f64::from(r.u16().unwrap() as i16),
            "u32" => f64::from(r.u32().unwrap()),
            "f32" => f64::from(r.f32().unwrap()),
            _ => panic!("type {ty}"),
        };
        let want: f64 = match name {
            "period" => f64::from(t.period),
            "i_d_a" => f64::from(t.i_d_a),
            "i_q_a" => f64::from(t.i_q_a),
            "v_d_v" => f64::from(t.v_d_v),
            "v_q_v" => f64::from(t.v_q_v),
            "velocity_rad_s" => f64::from(t.velocity_rad_s),
            "position_rad" => f64::from(t.position_rad),
            "mode" => f64::from(t.mode as u8),
            "fault_code" => f64::from(t.fault_code),
            "max_loop_cycles" => f64::from(t.max_loop_cycles),
            "v_bus_v" => f64::from(t.v_bus_v),
            "power_limit" => f64::from(t.power_limit as u8),
            "limit_left_pct" => f64::from(t.limit_left_pct),
            "flags" => f64::from(
                u8::from(t.brake_on)
                    | (u8::from(t.brake_locked) << 1)
                    | (t.angle_in_use.code() << 2),
            ),
            "winding_dC" => f64::from(temperature_to_wire(t.winding_c)),
            "stage_dC" => f64::from(temperature_to_wire(t.stage_c)),
            _ => panic!("field {name}"),
        };
        assert_eq!(got.to_bits(), want.to_bits(), "telemetry field {name}");
    }
    r.finish().unwrap();
}

fn constants(telemetry_bytes: usize, scope_bytes: usize) -> Json {
    let u = |v: usize| int(v as i64);
    obj(vec![
        ("MAX_PAYLOAD", u(MAX_PAYLOAD)),
        ("OVERHEAD", u(OVERHEAD)),
        ("MAX_BODY", u(MAX_BODY)),
        ("CHUNK_BYTES", u(CHUNK_BYTES)),
        ("MAX_RECORD", u(MAX_RECORD)),
        ("SCOPE_DATA_MAX", u(DATA_PER_FRAME)),
        ("SCOPE_SLOTS", u(MAX_CHANNELS)),
        ("SCOPE_UNUSED", int(UNUSED)),
        ("NO_TEMPERATURE", int(NO_TEMPERATURE)),
        ("TELEMETRY_BYTES", u(telemetry_bytes)),
        ("SCOPE_BYTES", u(scope_bytes)),
    ])
}

fn code_tables() -> Json {
    let error_codes: Vec<Json> = error_codes()
        .into_iter()
        .filter_map(|e| error_code_name(e).map(|n| Json::Arr(vec![int(e.to_wire().0), s(n)])))
        .collect();
    let homing_states = Json::Arr(
        [
            HomingState::Idle,
            HomingState::Running,
            HomingState::Done,
            HomingState::Failed(HomingFailure::NoStop),
        ]
        .iter()
        .map(|h| {
            let name = match h {
                HomingState::Idle => "Idle",
                HomingState::Running => "Running",
                HomingState::Done => "Done",
                HomingState::Failed(_) => "Failed",
            };
            Json::Arr(vec![int(h.to_wire().0), s(name)])
        })
        .collect(),
    );
    obj(vec![
        ("ErrorCode", Json::Arr(error_codes)),
        ("Mode", table(mode_from_code)),
        ("Fault", table(Fault::from_code)),
        ("ActiveLimit", table(active_limit_from_code)),
        ("Calibration", table(Calibration::from_code)),
        ("TimeoutReaction", table(reaction_from_code)),
        ("ConfigSource", table(ConfigSource::from_code)),
        ("StoreOp", table(StoreOp::from_code)),
        ("ParamId", table(ParamId::from_code)),
        ("ScopeSignal", table(Signal::from_code)),
        ("ScopeTrigger", table(TriggerKind::from_code)),
        ("ScopeState", table(State::from_code)),
        ("HomingState", homing_states),
        ("HomingFailure", table(HomingFailure::from_code)),
    ])
}

// ------------------------------------------------------------- document

fn render() -> String {
    let mut messages = Vec::new();
    let mut tags: Vec<(String, u8)> = Vec::new();
    let mut request_fields_table: Vec<(String, Json)> = Vec::new();
    let mut command_fields: Vec<(String, Json)> = Vec::new();
    fn add_tag(name: &str, tag: u8, tags: &mut Vec<(String, u8)>) {
        let t = tag_name(name);
        if let Some((_, old)) = tags.iter().find(|(n, _)| *n == t) {
            assert_eq!(*old, tag, "{name}: two tags");
        } else {
            assert!(
                tags.iter().all(|(_, x)| *x != tag),
                "{name}: tag 0x{tag:02x} taken"
            );
            tags.push((t, tag));
        }
    }
    for r in requests() {
        let (bytes, back) = body(&r);
        let (name, fields) = request_fields(&back);
        add_tag(name, r.tag(), &mut tags);
        let names = Json::Arr(
            (0..=u8::MAX)
                .map_while(|i| r.field_name(i))
                .map(s)
                .collect(),
        );
        if let Request::SetCommand(c) = r {
            let key = (c.mode() as u8).to_string();
            if !command_fields.iter().any(|(k, _)| *k == key) {
                command_fields.push((key, names));
            }
        } else if !matches!(names, Json::Arr(ref a) if a.is_empty())
            && !request_fields_table
                .iter()
                .any(|(k, _)| *k == tag_name(name))
        {
            request_fields_table.push((tag_name(name), names));
        }
        messages.push(Json::Obj(vec![
            ("direction".into(), s("request")),
            ("name".into(), s(name)),
            ("tag".into(), int(r.tag())),
            ("fields".into(), Json::Obj(fields)),
            ("body_hex".into(), s(&hex(&bytes))),
        ]));
    }
    let mut telemetry_bytes = 0;
    let mut scope_bytes = 0;
    for r in responses() {
        let (bytes, back) = body(&r);
        let (name, fields) = response_fields(&back);
        add_tag(name, r.tag(), &mut tags);
        match back {
            Response::Telemetry(t) | Response::Stream(t) => {
                check_telemetry_layout(&t, &bytes);
                telemetry_bytes = bytes.len();
            }
            Response::Scope(_) => scope_bytes = bytes.len(),
            _ => {}
        }
        messages.push(obj(vec![
            ("direction", s("response")),
            ("name", s(name)),
            ("tag", int(r.tag())),
            ("fields", obj(fields)),
            ("body_hex", s(&hex(&bytes))),
        ]));
    }
    tags.sort_by_key(|(_, t)| *t);
    let doc = obj(vec![
        ("protocol_version", int(PROTOCOL_VERSION)),
        (
            "generated_by",
            s("protocol/tests/layouts.rs (FOC_BLESS=1 cargo test -p foc-protocol --test layouts); do not edit"),
        ),
        ("constants", constants(telemetry_bytes, scope_bytes)),
        (
            "tags",
            Json::Obj(tags.into_iter().map(|(n, t)| (n, int(t))).collect()),
        ),
        ("codes", code_tables()),
        (
            "calibration",
            Json::Obj(vec![
                ("steps".into(), Json::Arr(foc_protocol::message::STEP_NAMES.iter().map(|n| s(n)).collect())),
                ("results".into(), Json::Arr(foc_protocol::message::RESULT_NAMES.iter().map(|n| s(n)).collect())),
                ("failed_base".into(), int(foc_protocol::message::FAILED_BASE)),
                ("failures".into(), Json::Arr(foc_protocol::message::FAILURE_REASONS.iter().map(|n| s(n)).collect())),
            ]),
        ),
        (
            "param_names",
            Json::Obj(
                ParamId::ALL
                    .iter()
                    .map(|p| (format!("{p:?}"), s(p.name())))
                    .collect(),
            ),
        ),
        (
            "param_units",
            Json::Obj(
                ParamId::ALL
                    .iter()
                    .filter(|p| !p.unit().is_empty())
                    .map(|p| (format!("{p:?}"), s(p.unit())))
                    .collect(),
            ),
        ),
        (
            "writable_params",
            Json::Arr(
                ParamId::ALL
                    .iter()
                    .filter(|p| p.is_writable())
                    .map(|p| {
                        Json::Arr(vec![s(&format!("{p:?}")), Json::Bool(p.is_switch())])
                    })
                    .collect(),
            ),
        ),
        (
            "telemetry_layout",
            Json::Arr(
                TELEMETRY_LAYOUT
                    .iter()
                    .map(|(n, t)| Json::Arr(vec![s(n), s(t)]))
                    .collect(),
            ),
        ),
        ("request_fields", Json::Obj(request_fields_table)),
        ("command_fields", Json::Obj(command_fields)),
        ("messages", Json::Arr(messages)),
    ]);
    let mut out = String::new();
    doc.pretty(0, &mut out);
    out.push('\n');
    out
}

fn vectors_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("python")
        .join("tests")
        .join("vectors")
        .join(format!("protocol-v{PROTOCOL_VERSION}.json"))
}

// ------------------------------------------------------------------ tests

/// Every tag the decoder knows (anything but `UnknownTag` for an empty
/// body) has at least one message in the document.
#[test]
fn every_tag_has_a_vector() {
    fn known<M: Message>() -> BTreeSet<u8> {
        (0..=u8::MAX)
            .filter(|&t| {
                !matches!(
                    M::decode_body(t, &mut Reader::new(&[])),
                    Err(DecodeError::UnknownTag)
                )
            })
            .collect()
    }
    let req: BTreeSet<u8> = requests().iter().map(Message::tag).collect();
    let resp: BTreeSet<u8> = responses().iter().map(Message::tag).collect();
    assert_eq!(
        req,
        known::<Request>(),
        "requests without a vector (or unknown tags)"
    );
    assert_eq!(
        resp,
        known::<Response>(),
        "responses without a vector (or unknown tags)"
    );
    // Every case of the enums inside messages.
    let modes: BTreeSet<u8> = requests()
        .iter()
        .filter_map(|r| match r {
            Request::SetCommand(c) => Some(c.mode() as u8),
            _ => None,
        })
        .collect();
    assert_eq!(
        modes.len(),
        (0..=u8::MAX).filter_map(mode_from_code).count()
    );
    let triggers: BTreeSet<u8> = scope_configs().iter().map(|c| c.trigger as u8).collect();
    assert_eq!(
        triggers.len(),
        (0..=u8::MAX).filter_map(TriggerKind::from_code).count()
    );
    let signals: BTreeSet<u8> = scope_configs()
        .iter()
        .flat_map(|c| c.used().iter().map(|s| *s as u8).collect::<Vec<_>>())
        .collect();
    assert_eq!(signals.len(), Signal::ALL.len());
}

/// The rendered document is the committed one (`FOC_BLESS=1` writes it).
#[test]
fn layouts_match_the_committed_vectors() {
    let doc = render();
    let path = vectors_path();
    if std::env::var("FOC_BLESS").as_deref() == Ok("1") {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, &doc).unwrap();
        eprintln!("wrote {}", path.display());
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "cannot read {} ({e}); generate it with `FOC_BLESS=1 cargo test -p foc-protocol --test layouts`",
            path.display()
        )
    });
    if committed != doc {
        let line = committed
            .lines()
            .zip(doc.lines())
            .position(|(a, b)| a != b)
            .unwrap_or_else(|| committed.lines().count().min(doc.lines().count()));
        let at = |t: &str| t.lines().nth(line).unwrap_or("<end of file>").to_string();
        panic!(
            "the message layouts differ from {} at line {}:\n  committed: {}\n  now:       {}\n\
             If the protocol changed on purpose, bump PROTOCOL_VERSION when the change is \
             incompatible, regenerate with `FOC_BLESS=1 cargo test -p foc-protocol --test layouts`, \
             update python/foc_drive/messages.py and run python/tests/test_layouts.py.",
            path.display(),
            line + 1,
            at(&committed),
            at(&doc),
        );
    }
}
