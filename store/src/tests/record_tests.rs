//! Envelope, validation and settings conversion.

use super::{largest_record, record_a, record_b};
use crate::record::{
    angle_to_e_rad, e_rad_to_angle, AngleRecord, DriveRecord, Invalid, JointRecord,
    MechanicsRecord, RecordError, SensorlessRecord, MAX_RECORD_BYTES, SCHEMA_VERSION,
};
use core::f32::consts::TAU;
use foc_core::angle::ElectricalAngle;
use foc_core::control::joint::JointConfig;

/// A hand-built envelope with a valid CRC around any payload and version.
pub(crate) fn envelope(version: u16, payload: &[u8]) -> std::vec::Vec<u8> {
    let mut v = std::vec::Vec::new();
    v.extend_from_slice(&version.to_le_bytes());
    v.extend_from_slice(&(payload.len() as u16).to_le_bytes());
    v.extend_from_slice(payload);
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&v);
    v.extend_from_slice(&crc.to_le_bytes());
    v
}

fn encoded(r: &DriveRecord) -> std::vec::Vec<u8> {
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let n = r.encode(&mut buf).unwrap();
    buf[..n].to_vec()
}

#[test]
fn largest_record_fits() {
    let r = largest_record();
    let bytes = encoded(&r);
    assert!(bytes.len() <= MAX_RECORD_BYTES, "{} bytes", bytes.len());
    std::eprintln!(
        "largest envelope: {} bytes (limit {MAX_RECORD_BYTES})",
        bytes.len()
    );
    assert_eq!(DriveRecord::decode(&bytes), Ok(r));
    // It is valid apart from the calibration's pole pairs vs the motor's,
    // the mechanics beyond their plausible ranges and the joint's frame and
    // travel range: make them agree and check validation accepts the
    // extremes.
    let mut r = largest_record();
    r.calibration.as_mut().unwrap().pole_pairs = r.motor.pole_pairs;
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "mechanics.inertia_kg_m2"
        })
    );
    r.mechanics = Some(MechanicsRecord {
        inertia_kg_m2: 10.0,
        viscous_friction_nm_s_per_rad: MechanicsRecord::MAX_VISCOUS_FRICTION_NM_S_PER_RAD,
        coulomb_friction_nm: MechanicsRecord::MAX_COULOMB_FRICTION_NM,
    });
    // 1.5 p psi overflows: no torque constant to derive the loops with.
    assert_eq!(r.validate(), Err(Invalid { field: "mechanics" }));
    r.motor.flux_linkage_wb = 1.0;
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "joint.gear_ratio"
        })
    );
    let j = r.joint.as_mut().unwrap();
    j.gear_ratio = -10_000.0;
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "joint.entry_blend_periods"
        })
    );
    // (The longest valid blend is a shorter varint.)
    let j = r.joint.as_mut().unwrap();
    j.entry_blend_periods = JointConfig::MAX_ENTRY_BLEND_PERIODS;
    j.rotor_at_zero_rad = -1e30;
    j.travel_out_rad = Some((-1e30, 1e30));
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "sensorless.bus_voltage_v"
        })
    );
    r.sensorless.as_mut().unwrap().bus_voltage_v = 1000.0;
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "sensorless.observer_above_rad_s"
        })
    );
    r.sensorless.as_mut().unwrap().observer_above_rad_s =
        Some(SensorlessRecord::MAX_OBSERVER_ABOVE_RAD_S);
    // The d-current reference: foc-core's bounds, value by value.
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "field.max_id_a"
        })
    );
    let f = r.field.as_mut().unwrap();
    f.max_id_a = 9.99e5;
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "field.voltage_margin"
        })
    );
    let f = r.field.as_mut().unwrap();
    f.voltage_margin = 0.5;
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "field.bandwidth_rad_s"
        })
    );
    r.field.as_mut().unwrap().bandwidth_rad_s = 9.99e5;
    // The tables: foc-core's checks (a peak within the current limit, a
    // correction within its bound), named.
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "cogging.table"
        })
    );
    r.cogging.as_mut().unwrap().scale_a = 1e30;
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "angle_correction.table"
        })
    );
    r.angle_correction.as_mut().unwrap().scale_rad = 2e-6;
    // Beside the sensor, a travel range is fine.
    assert_eq!(r.validate(), Ok(()));
    r.sensorless.as_mut().unwrap().beside_sensor = None;
    r.sensorless.as_mut().unwrap().observer_above_rad_s = None;
    // Sensorless with a travel range: refused (no fixed zero).
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "sensorless"
        })
    );
    r.joint.as_mut().unwrap().travel_out_rad = None;
    assert_eq!(r.validate(), Ok(()));
    assert!(encoded(&r).len() <= bytes.len());
}

#[test]
fn the_joint_costs_its_size_and_no_more() {
    // Schema 4 adds at most 47 bytes (tag, 9 f32, range tag, u32 varint)
    // to the largest version-3 record (229 bytes), schema 5 at most 9
    // (tag, 2 f32), schema 6 at most 7 (role tag and variant, speed tag
    // and f32), schema 7 one (the calibration's `sensorless_only`),
    // schema 8 at most 16 (tag, 3 bool, 3 f32), schema 9 the tables at
    // their fixed size: the map 1032 (tag, bool, f32, a 2-byte length
    // and 512 x 2 bytes), the correction 520 (256 x 2 bytes), two tags
    // without them.
    let mut r = largest_record();
    let with = encoded(&r).len();
    assert_eq!(with, 229 + 47 + 9 + 7 + 1 + 16 + 1032 + 520);
    assert_eq!(with, 1861);
    r.cogging = None;
    assert_eq!(encoded(&r).len(), 229 + 47 + 9 + 7 + 1 + 16 + 1 + 520);
    r.angle_correction = None;
    assert_eq!(encoded(&r).len(), 229 + 47 + 9 + 7 + 1 + 16 + 1 + 1);
    r.field = None;
    assert_eq!(encoded(&r).len(), 229 + 47 + 9 + 7 + 1 + 1 + 2);
    r.sensorless = None;
    assert_eq!(encoded(&r).len(), 229 + 47 + 1 + 1 + 1 + 2);
    r.joint = None;
    // Without a joint: its `None` tag only.
    assert_eq!(encoded(&r).len(), 229 + 1 + 1 + 1 + 1 + 2);
    assert!(with <= MAX_RECORD_BYTES);
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let v3 = postcard::to_slice(&as_v3(&largest_record()), &mut buf).unwrap();
    assert_eq!(v3.len() + 8, 229);
}

#[test]
fn envelope_layout_and_errors() {
    let r = record_a();
    let bytes = encoded(&r);
    assert_eq!(u16::from_le_bytes([bytes[0], bytes[1]]), SCHEMA_VERSION);
    assert_eq!(
        usize::from(u16::from_le_bytes([bytes[2], bytes[3]])),
        bytes.len() - 8
    );
    // Every truncation is refused.
    for n in 0..bytes.len() {
        assert!(DriveRecord::decode(&bytes[..n]).is_err(), "{n}");
    }
    assert_eq!(DriveRecord::decode(&bytes[..3]), Err(RecordError::TooShort));
    let mut long = bytes.clone();
    long.push(0);
    assert_eq!(DriveRecord::decode(&long), Err(RecordError::TooLong));
    // Every single-bit flip is refused.
    for i in 0..bytes.len() * 8 {
        let mut b = bytes.clone();
        b[i / 8] ^= 1 << (i % 8);
        assert!(DriveRecord::decode(&b).is_err(), "bit {i}");
    }
    let mut b = bytes.clone();
    let last = b.len() - 1;
    b[last] ^= 0x80;
    assert_eq!(DriveRecord::decode(&b), Err(RecordError::BadChecksum));
    // A buffer too small to encode into.
    let mut small = [0u8; 20];
    assert_eq!(r.encode(&mut small), Err(RecordError::TooLong));
}

#[test]
fn versions_other_than_ours_are_refused() {
    let payload = &encoded(&record_a())[4..];
    let payload = &payload[..payload.len() - 4];
    assert_eq!(
        DriveRecord::decode(&envelope(SCHEMA_VERSION, payload)),
        Ok(record_a())
    );
    for v in [0, SCHEMA_VERSION + 1, u16::MAX] {
        assert!(!(1..SCHEMA_VERSION).contains(&v), "versions 1 to 3 migrate");
        assert_eq!(
            DriveRecord::decode(&envelope(v, payload)),
            Err(RecordError::UnsupportedVersion {
                found: v,
                supported: SCHEMA_VERSION
            })
        );
    }
}

#[test]
fn trailing_payload_bytes_are_malformed() {
    let payload = &encoded(&record_a())[4..];
    let mut p = payload[..payload.len() - 4].to_vec();
    p.push(0);
    assert_eq!(
        DriveRecord::decode(&envelope(SCHEMA_VERSION, &p)),
        Err(RecordError::Malformed)
    );
    assert_eq!(
        DriveRecord::decode(&envelope(SCHEMA_VERSION, &[1, 2, 3])),
        Err(RecordError::Malformed)
    );
}

#[test]
fn validation_names_the_field() {
    let ok = record_a();
    assert_eq!(ok.validate(), Ok(()));
    assert_eq!(record_b().validate(), Ok(()));
    type Spoil = fn(&mut DriveRecord);
    let cases: [(&str, Spoil); 24] = [
        ("label", |r| {
            r.label = crate::Label::try_from("tab\there").unwrap()
        }),
        ("pwm_frequency_hz", |r| r.pwm_frequency_hz = 0),
        ("motor.pole_pairs", |r| r.motor.pole_pairs = 0),
        ("motor.r_ohm", |r| r.motor.r_ohm = f32::NAN),
        ("motor.r_ohm", |r| r.motor.r_ohm = 0.0),
        ("motor.ld_h", |r| r.motor.ld_h = -1e-6),
        ("motor.lq_h", |r| r.motor.lq_h = f32::INFINITY),
        ("motor.flux_linkage_wb", |r| r.motor.flux_linkage_wb = -0.1),
        ("current_gains.kp_d_v_per_a", |r| {
            r.current_gains.kp_d_v_per_a = 0.0
        }),
        ("current_gains.ki_q_v_per_a_s", |r| {
            r.current_gains.ki_q_v_per_a_s = f32::NAN
        }),
        ("limits.max_current_a", |r| r.limits.max_current_a = 0.0),
        ("limits.max_velocity_rad_s", |r| {
            r.limits.max_velocity_rad_s = f32::NAN
        }),
        ("limits.min_position_rad", |r| {
            r.limits.min_position_rad = f32::NEG_INFINITY
        }),
        ("limits.max_position_rad", |r| {
            r.limits.max_position_rad = -200.0
        }),
        ("limits.max_open_loop_voltage_v", |r| {
            r.limits.max_open_loop_voltage_v = -1.0
        }),
        ("speed.kp_a_per_rad_s", |r| r.speed.kp_a_per_rad_s = -0.1),
        ("speed.ki_a_per_rad", |r| r.speed.ki_a_per_rad = f32::NAN),
        ("position.kp_per_s", |r| r.position.kp_per_s = 0.0),
        ("position.max_velocity_rad_s", |r| {
            r.position.max_velocity_rad_s = 301.0
        }),
        ("position.max_acceleration_rad_s2", |r| {
            r.position.max_acceleration_rad_s2 = 0.0
        }),
        ("dividers.speed", |r| r.dividers.speed = 0),
        ("dividers.position", |r| r.dividers.position = 0),
        ("calibration.pole_pairs", |r| {
            r.calibration.as_mut().unwrap().pole_pairs = 8
        }),
        ("calibration.zero_offset_e_rad", |r| {
            r.calibration.as_mut().unwrap().zero_offset_e_rad = TAU
        }),
    ];
    for (field, spoil) in cases {
        let mut r = ok.clone();
        spoil(&mut r);
        assert_eq!(r.validate(), Err(Invalid { field }), "{field}");
    }
    let mut r = ok.clone();
    r.calibration = None;
    assert_eq!(r.validate(), Ok(()));
    assert_eq!(
        std::format!(
            "{}",
            Invalid {
                field: "motor.r_ohm"
            }
        ),
        "record value `motor.r_ohm` is out of range"
    );
}

#[test]
fn error_messages_are_sentences() {
    let e = RecordError::UnsupportedVersion {
        found: 2,
        supported: 1,
    };
    assert_eq!(
        std::format!("{e}"),
        "the record has schema version 2, this firmware reads version 1"
    );
    for e in [
        RecordError::TooShort,
        RecordError::TooLong,
        RecordError::BadChecksum,
        RecordError::Malformed,
    ] {
        assert!(std::format!("{e}").starts_with("the "));
    }
    // Field weakening is refused by a rule, not a range: it says why.
    let e = Invalid {
        field: "field.field_weakening",
    };
    assert!(std::format!("{e}").contains("not halls"), "{e}");
    let e = Invalid {
        field: "field.max_id_a",
    };
    assert_eq!(
        std::format!("{e}"),
        "record value `field.max_id_a` is out of range"
    );
}

#[test]
fn electrical_angle_round_trip_is_exact_to_f32_precision() {
    // Angle -> radians -> angle: within one f32 step of 2 pi (the coarsest
    // radians spacing in [0, 2 pi)).
    let step = TAU - f32::from_bits(TAU.to_bits() - 1);
    let mut bits: u32 = 0x1234_5678;
    for i in 0..200_000u32 {
        bits = bits.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let a = ElectricalAngle::from_bits(if i < 4 {
            [0, 1, u32::MAX, 1 << 31][i as usize]
        } else {
            bits
        });
        let r = angle_to_e_rad(a);
        assert!((0.0..TAU).contains(&r), "{r}");
        let back = e_rad_to_angle(r);
        assert!(back.diff_radians(a).abs() <= step, "{:?} {:?}", a, back);
    }
    // Radians -> angle -> radians: exact from 0.02 rad, within one angle
    // step below.
    let lsb = TAU / 4_294_967_296.0;
    let mut x: u32 = 1;
    for i in 0..200_000u32 {
        x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let r = match i {
            0 => 0.0,
            1 => f32::from_bits(TAU.to_bits() - 1),
            2 => 0.02,
            3 => 1e-30,
            _ if i % 2 == 0 => (x >> 8) as f32 * (TAU / 16_777_216.0),
            _ => f32::from_bits(x % TAU.to_bits()),
        };
        let back = angle_to_e_rad(e_rad_to_angle(r));
        if r >= 0.02 {
            assert_eq!(back.to_bits(), r.to_bits(), "{r}");
        } else {
            assert!((back - r).abs() <= lsb, "{r} {back}");
        }
    }
    // Wrapping and non-finite input.
    assert!(
        e_rad_to_angle(-0.5)
            .diff_radians(e_rad_to_angle(TAU - 0.5))
            .abs()
            < 1e-6
    );
    assert_eq!(e_rad_to_angle(f32::NAN), ElectricalAngle::ZERO);
    assert_eq!(angle_to_e_rad(ElectricalAngle::from_bits(u32::MAX)), 0.0);
}

/// `r` in the version-1 layout (what it loses: `power`, `mechanics`,
/// `joint`).
fn as_v1(r: &DriveRecord) -> crate::record::v1::DriveRecordV1 {
    crate::record::v1::DriveRecordV1 {
        label: r.label.clone(),
        pwm_frequency_hz: r.pwm_frequency_hz,
        motor: r.motor,
        current_gains: r.current_gains,
        calibration: r.calibration.map(as_v6_angle),
        limits: r.limits,
        speed: r.speed,
        position: r.position,
        dividers: r.dividers,
        watchdog: r.watchdog,
    }
}

/// `r` in the version-2 layout (what it loses: `mechanics`, `joint`).
fn as_v2(r: &DriveRecord) -> crate::record::v2::DriveRecordV2 {
    crate::record::v2::DriveRecordV2 {
        label: r.label.clone(),
        pwm_frequency_hz: r.pwm_frequency_hz,
        motor: r.motor,
        current_gains: r.current_gains,
        calibration: r.calibration.map(as_v6_angle),
        limits: r.limits,
        speed: r.speed,
        position: r.position,
        dividers: r.dividers,
        watchdog: r.watchdog,
        power: r.power,
    }
}

/// `r` in the version-3 layout (what it loses: `joint`).
fn as_v3(r: &DriveRecord) -> crate::record::v3::DriveRecordV3 {
    crate::record::v3::DriveRecordV3 {
        label: r.label.clone(),
        pwm_frequency_hz: r.pwm_frequency_hz,
        motor: r.motor,
        current_gains: r.current_gains,
        calibration: r.calibration.map(as_v6_angle),
        limits: r.limits,
        speed: r.speed,
        position: r.position,
        dividers: r.dividers,
        watchdog: r.watchdog,
        power: r.power,
        mechanics: r.mechanics,
    }
}

/// `a` in the layout of versions 1 to 6 (what it loses:
/// `sensorless_only`).
fn as_v6_angle(a: crate::record::AngleRecord) -> crate::record::AngleRecordV6 {
    crate::record::AngleRecordV6 {
        zero_offset_e_rad: a.zero_offset_e_rad,
        reversed: a.reversed,
        pole_pairs: a.pole_pairs,
        sensor_counts_per_rev: a.sensor_counts_per_rev,
    }
}

/// The payload of an envelope (without version, length and CRC).
fn payload(envelope: &[u8]) -> &[u8] {
    &envelope[4..envelope.len() - 4]
}

/// `layout` postcard-encoded.
fn postcard_of<T: serde::Serialize>(layout: &T) -> std::vec::Vec<u8> {
    let mut buf = [0u8; MAX_RECORD_BYTES];
    postcard::to_slice(layout, &mut buf).unwrap().to_vec()
}

#[test]
fn a_version_1_record_migrates_with_the_build_default_power_limits() {
    let now = record_a();
    assert!(now.power.is_some() && now.mechanics.is_some() && now.joint.is_some());
    let p1 = postcard_of(&as_v1(&now));
    // 1 -> 2 -> 3 -> 4.
    let migrated = DriveRecord::decode(&envelope(1, &p1)).unwrap();
    assert_eq!(
        (migrated.power, migrated.mechanics, migrated.joint),
        (None, None, None)
    );
    assert_eq!(
        DriveRecord {
            power: now.power,
            mechanics: now.mechanics,
            joint: now.joint,
            ..migrated.clone()
        },
        now
    );
    assert_eq!(migrated.validate(), Ok(()));
    assert_eq!(
        as_v1(&now)
            .into_v2()
            .into_v3()
            .into_v4()
            .into_v5()
            .into_v6()
            .into_v7()
            .into_v8()
            .into_v9(),
        migrated
    );
    // A version-2, -3 or -4 payload under version 1 is not a version-1
    // record.
    let p2 = postcard_of(&as_v2(&now));
    let p3 = postcard_of(&as_v3(&now));
    for p in [&p2[..], &p3[..], payload(&encoded(&now))] {
        assert_eq!(
            DriveRecord::decode(&envelope(1, p)),
            Err(RecordError::Malformed)
        );
    }
}

#[test]
fn a_version_2_record_migrates_without_mechanics() {
    for now in [record_a(), record_b()] {
        let p2 = postcard_of(&as_v2(&now));
        // 2 -> 3 -> 4.
        let migrated = DriveRecord::decode(&envelope(2, &p2)).unwrap();
        assert_eq!((migrated.mechanics, migrated.joint), (None, None));
        assert_eq!(migrated.power, now.power);
        assert_eq!(
            DriveRecord {
                mechanics: now.mechanics,
                joint: now.joint,
                ..migrated.clone()
            },
            now
        );
        assert_eq!(migrated.validate(), Ok(()));
        // The frozen structs' own steps.
        assert_eq!(
            as_v2(&now)
                .into_v3()
                .into_v4()
                .into_v5()
                .into_v6()
                .into_v7()
                .into_v8()
                .into_v9(),
            migrated
        );
        // A version-3 or -4 payload (with or without mechanics) under
        // version 2 is not a version-2 record, nor a version-1 one under
        // version 2.
        let mut none = now.clone();
        none.mechanics = None;
        let p1 = postcard_of(&as_v1(&now));
        let p3 = postcard_of(&as_v3(&now));
        let p3_none = postcard_of(&as_v3(&none));
        for p in [
            payload(&encoded(&now)),
            payload(&encoded(&none)),
            &p3[..],
            &p3_none[..],
            &p1[..],
        ] {
            assert_eq!(
                DriveRecord::decode(&envelope(2, p)),
                Err(RecordError::Malformed)
            );
        }
    }
}

#[test]
fn a_version_3_record_migrates_without_the_joint() {
    let mut no_mechanics = record_a();
    no_mechanics.mechanics = None;
    for now in [record_a(), record_b(), no_mechanics] {
        let p3 = postcard_of(&as_v3(&now));
        let migrated = DriveRecord::decode(&envelope(3, &p3)).unwrap();
        assert_eq!(migrated.joint, None);
        assert_eq!(
            (migrated.power, migrated.mechanics),
            (now.power, now.mechanics)
        );
        assert_eq!(
            DriveRecord {
                joint: now.joint,
                ..migrated.clone()
            },
            now
        );
        assert_eq!(migrated.validate(), Ok(()));
        assert_eq!(
            as_v3(&now)
                .into_v4()
                .into_v5()
                .into_v6()
                .into_v7()
                .into_v8()
                .into_v9(),
            migrated
        );
        // A version-4 payload (with or without the joint) under version 3
        // is not a version-3 record, nor a version-2 one.
        let mut none = now.clone();
        none.joint = None;
        let p2 = postcard_of(&as_v2(&now));
        for p in [payload(&encoded(&now)), payload(&encoded(&none)), &p2[..]] {
            assert_eq!(
                DriveRecord::decode(&envelope(3, p)),
                Err(RecordError::Malformed)
            );
        }
        // Nor is a version-3 payload one of version 4.
        assert_eq!(
            DriveRecord::decode(&envelope(SCHEMA_VERSION, &p3)),
            Err(RecordError::Malformed)
        );
    }
}

#[test]
fn a_migrated_record_applies_with_the_builds_joint() {
    use crate::Settings;
    use foc_core::control::joint::OutputFrame;
    use foc_core::drive::cascade::CascadeConfig;
    let now = record_a();
    let migrated = DriveRecord::decode(&envelope(3, &postcard_of(&as_v3(&now)))).unwrap();
    let mut base = Settings::from_cascade(&CascadeConfig::for_motor(
        now.motor.to_params(),
        20_000.0,
        5.0,
    ));
    base.joint.frame = OutputFrame::new(3.0, 0.5).unwrap();
    base.limits.max_kp_nm_per_rad = 7.0;
    let s = migrated.apply(&base, 20_000).unwrap();
    assert_eq!(s.joint, base.joint);
    assert_eq!(
        (s.limits.max_kp_nm_per_rad, s.limits.max_kd_nm_s_per_rad),
        (7.0, base.limits.max_kd_nm_s_per_rad)
    );
    // Saved again: with the joint (and the d-current reference), schema 9
    // (no tables measured: none).
    let again = DriveRecord::from_settings(&migrated.label, 20_000, &s);
    assert_eq!(
        again.joint,
        Some(JointRecord::from_setup(&base.joint, &base.limits))
    );
    assert!(again.field.is_some());
    assert_eq!((again.cogging, again.angle_correction), (None, None));
    assert_eq!(encoded(&again)[0], 9);
}

/// `r` in the version-4 layout (what it loses: `sensorless`).
fn as_v4(r: &DriveRecord) -> crate::record::v4::DriveRecordV4 {
    let v3 = as_v3(r);
    crate::record::v4::DriveRecordV4 {
        joint: r.joint,
        ..v3.into_v4()
    }
}

#[test]
fn a_version_4_record_migrates_on_the_angle_sensor() {
    let sensorless = sensorless_record();
    assert_eq!(sensorless.validate(), Ok(()));
    for now in [record_a(), record_b(), sensorless.clone()] {
        let p4 = postcard_of(&as_v4(&now));
        let migrated = DriveRecord::decode(&envelope(4, &p4)).unwrap();
        assert_eq!(migrated.sensorless, None);
        assert_eq!(
            DriveRecord {
                sensorless: now.sensorless,
                ..migrated.clone()
            },
            now
        );
        assert_eq!(
            as_v4(&now)
                .into_v5()
                .into_v6()
                .into_v7()
                .into_v8()
                .into_v9(),
            migrated
        );
        // A version-5 payload under version 4 is not a version-4 record,
        // nor a version-4 payload one of version 5.
        assert_eq!(
            DriveRecord::decode(&envelope(4, payload(&encoded(&now)))),
            Err(RecordError::Malformed)
        );
        assert_eq!(
            DriveRecord::decode(&envelope(SCHEMA_VERSION, &p4)),
            Err(RecordError::Malformed)
        );
    }
}

#[test]
fn the_sensorless_setting_is_checked_and_needs_mechanics() {
    use crate::Settings;
    use foc_core::drive::cascade::CascadeConfig;
    let mut r = sensorless_record();
    let ok = SensorlessRecord {
        start_current_a: r.limits.max_current_a,
        bus_voltage_v: 24.0,
        beside_sensor: None,
        observer_above_rad_s: None,
    };
    type Spoil = fn(&mut SensorlessRecord);
    let spoils: [(Spoil, &str); 5] = [
        (|s| s.start_current_a = 0.0, "sensorless.start_current_a"),
        (|s| s.start_current_a = 5.01, "sensorless.start_current_a"),
        (
            |s| s.start_current_a = f32::NAN,
            "sensorless.start_current_a",
        ),
        (|s| s.bus_voltage_v = 0.5, "sensorless.bus_voltage_v"),
        (
            |s| s.bus_voltage_v = f32::INFINITY,
            "sensorless.bus_voltage_v",
        ),
    ];
    for (spoil, field) in spoils {
        let mut bad = ok;
        spoil(&mut bad);
        r.sensorless = Some(bad);
        assert_eq!(r.validate(), Err(Invalid { field }), "{bad:?}");
    }
    r.sensorless = Some(ok);
    // No travel range without the sensor.
    let mut travel = r.clone();
    if let Some(j) = travel.joint.as_mut() {
        j.travel_out_rad = Some((-1.0, 1.0));
    }
    assert_eq!(
        travel.validate(),
        Err(Invalid {
            field: "sensorless"
        })
    );
    let mut no_flux = r.clone();
    no_flux.motor.flux_linkage_wb = 0.0;
    no_flux.mechanics = None;
    assert_eq!(
        no_flux.validate(),
        Err(Invalid {
            field: "sensorless"
        })
    );
    // Applied: the cascade runs on the observer, derived from the motor,
    // the record's inertia and bus.
    let base_cascade = CascadeConfig::for_motor(r.motor.to_params(), 20_000.0, 5.0);
    let base = Settings::from_cascade(&base_cascade);
    assert_eq!(base.sensorless, None);
    let s = r.apply(&base, 20_000).unwrap();
    assert_eq!(s.sensorless, Some(ok));
    let c = s.apply_to(&base_cascade);
    let sl = c.current.sensorless.expect("derived");
    assert_eq!((sl.current_a, sl.bus_voltage_v), (5.0, 24.0));
    assert_eq!(sl.observer.motor, r.motor.to_params());
    // Round trip through the settings.
    assert_eq!(Settings::from_cascade(&c).sensorless, Some(ok));
    assert_eq!(
        DriveRecord::from_settings(&r.label, 20_000, &s).sensorless,
        Some(ok)
    );
    // Without mechanics (the record's or the build's) it is refused whole.
    let mut bare = r.clone();
    bare.mechanics = None;
    assert_eq!(
        bare.apply(&base, 20_000),
        Err(Invalid {
            field: "sensorless"
        })
    );
    // On the angle sensor again.
    r.sensorless = None;
    let back = r.apply(&s, 20_000).unwrap();
    assert_eq!(back.apply_to(&c).current.sensorless, None);
}

/// The observer beside the sensor (schema 6): each role reaches foc-core's
/// `BesideConfig` (the drive stays on its sensor), round-trips through the
/// settings, allows a travel range, and a speed only with
/// `hall+sensorless`.
#[test]
fn the_observer_beside_the_sensor_is_stored_in_its_role() {
    use crate::record::BesideRole;
    use crate::Settings;
    use foc_core::drive::cascade::CascadeConfig;
    let mut r = record_a();
    assert!(r.joint.is_some_and(|j| j.travel_out_rad.is_some()));
    let base_cascade = CascadeConfig::for_motor(r.motor.to_params(), 20_000.0, 5.0);
    let base = Settings::from_cascade(&base_cascade);
    let pp = f32::from(r.motor.pole_pairs);
    for (role, above) in [
        (BesideRole::Check, None),
        (BesideRole::LimpHome, None),
        (BesideRole::HallSensorless, None),
        (BesideRole::HallSensorless, Some(40.0)),
    ] {
        let sl = SensorlessRecord {
            start_current_a: 4.0,
            bus_voltage_v: 24.0,
            beside_sensor: Some(role),
            observer_above_rad_s: above,
        };
        r.sensorless = Some(sl);
        assert_eq!(r.validate(), Ok(()), "{role:?}: a travel range is fine");
        let s = r.apply(&base, 20_000).unwrap();
        let c = s.apply_to(&base_cascade);
        assert_eq!(c.current.sensorless, None, "{role:?}: on the sensor");
        let b = c.current.fallback.expect("the observer beside the sensor");
        assert_eq!(b.limp_home, role != BesideRole::Check);
        let derived = crate::settings::sensorless_config(&c, &sl).unwrap();
        assert_eq!(b.sensorless, derived);
        let expect_above = match (role, above) {
            (BesideRole::HallSensorless, Some(w)) => Some(w * pp),
            (BesideRole::HallSensorless, None) => Some(2.0 * derived.handover_rad_s),
            _ => None,
        };
        assert_eq!(b.observer_above_rad_s, expect_above, "{role:?}");
        // Back to a record: the role and the speed (the default one
        // written out).
        let back = Settings::from_cascade(&c).sensorless.unwrap();
        assert_eq!(back.beside_sensor, Some(role));
        assert_eq!(back.observer_above_rad_s.map(|w| w * pp), expect_above);
    }
    // A speed without `hall+sensorless`, or one not usable, is refused.
    for (role, above) in [
        (None, 40.0),
        (Some(BesideRole::LimpHome), 40.0),
        (Some(BesideRole::HallSensorless), 0.0),
        (Some(BesideRole::HallSensorless), f32::NAN),
        (Some(BesideRole::HallSensorless), 1e6),
    ] {
        r.sensorless = Some(SensorlessRecord {
            start_current_a: 4.0,
            bus_voltage_v: 24.0,
            beside_sensor: role,
            observer_above_rad_s: Some(above),
        });
        assert_eq!(
            r.validate(),
            Err(Invalid {
                field: "sensorless.observer_above_rad_s"
            }),
            "{role:?} {above}"
        );
    }
}

#[test]
fn mechanics_are_checked_field_by_field() {
    let ok = record_a();
    assert_eq!(ok.validate(), Ok(()));
    type Spoil = fn(&mut DriveRecord);
    let cases: [(&str, Spoil); 17] = [
        ("mechanics.inertia_kg_m2", |r| {
            r.mechanics.as_mut().unwrap().inertia_kg_m2 = f32::NAN
        }),
        ("mechanics.inertia_kg_m2", |r| {
            r.mechanics.as_mut().unwrap().inertia_kg_m2 = f32::INFINITY
        }),
        ("mechanics.inertia_kg_m2", |r| {
            r.mechanics.as_mut().unwrap().inertia_kg_m2 = 0.0
        }),
        ("mechanics.inertia_kg_m2", |r| {
            r.mechanics.as_mut().unwrap().inertia_kg_m2 = -1e-5
        }),
        ("mechanics.inertia_kg_m2", |r| {
            r.mechanics.as_mut().unwrap().inertia_kg_m2 = 1e-10
        }),
        ("mechanics.inertia_kg_m2", |r| {
            r.mechanics.as_mut().unwrap().inertia_kg_m2 = 10.5
        }),
        ("mechanics.viscous_friction_nm_s_per_rad", |r| {
            r.mechanics.as_mut().unwrap().viscous_friction_nm_s_per_rad = f32::NAN
        }),
        ("mechanics.viscous_friction_nm_s_per_rad", |r| {
            r.mechanics.as_mut().unwrap().viscous_friction_nm_s_per_rad = -1e-6
        }),
        ("mechanics.viscous_friction_nm_s_per_rad", |r| {
            r.mechanics.as_mut().unwrap().viscous_friction_nm_s_per_rad = f32::INFINITY
        }),
        ("mechanics.viscous_friction_nm_s_per_rad", |r| {
            r.mechanics.as_mut().unwrap().viscous_friction_nm_s_per_rad = 101.0
        }),
        ("mechanics.coulomb_friction_nm", |r| {
            r.mechanics.as_mut().unwrap().coulomb_friction_nm = f32::NAN
        }),
        ("mechanics.coulomb_friction_nm", |r| {
            r.mechanics.as_mut().unwrap().coulomb_friction_nm = -0.001
        }),
        ("mechanics.coulomb_friction_nm", |r| {
            r.mechanics.as_mut().unwrap().coulomb_friction_nm = f32::NEG_INFINITY
        }),
        ("mechanics.coulomb_friction_nm", |r| {
            r.mechanics.as_mut().unwrap().coulomb_friction_nm = 1001.0
        }),
        // No torque constant (a motor without flux): the mechanics cannot
        // be installed.
        ("mechanics", |r| r.motor.flux_linkage_wb = 0.0),
        ("mechanics", |r| r.motor.flux_linkage_wb = 1e38),
        // The motor's own checks come first.
        ("motor.flux_linkage_wb", |r| {
            r.motor.flux_linkage_wb = f32::NAN
        }),
    ];
    for (field, spoil) in cases {
        let mut r = ok.clone();
        spoil(&mut r);
        assert_eq!(r.validate(), Err(Invalid { field }), "{field}");
    }
    // The bounds themselves, and zero frictions, are accepted.
    for (j, b, c) in [(1e-9, 0.0, 0.0), (10.0, 100.0, 1000.0)] {
        let mut r = ok.clone();
        r.mechanics = Some(MechanicsRecord {
            inertia_kg_m2: j,
            viscous_friction_nm_s_per_rad: b,
            coulomb_friction_nm: c,
        });
        assert_eq!(r.validate(), Ok(()), "{j} {b} {c}");
        assert!(r.mechanics.unwrap().to_mechanics().is_usable());
    }
    // Without mechanics a motor without flux is still a record.
    let mut r = ok.clone();
    r.mechanics = None;
    r.motor.flux_linkage_wb = 0.0;
    assert_eq!(r.validate(), Ok(()));
}

#[test]
fn joint_is_checked_field_by_field() {
    let ok = record_a();
    assert_eq!(ok.validate(), Ok(()));
    type Spoil = fn(&mut JointRecord);
    let cases: [(&str, Spoil); 27] = [
        ("joint.gear_ratio", |j| j.gear_ratio = 0.0),
        ("joint.gear_ratio", |j| j.gear_ratio = f32::NAN),
        ("joint.gear_ratio", |j| j.gear_ratio = f32::NEG_INFINITY),
        ("joint.gear_ratio", |j| j.gear_ratio = 1e-3),
        ("joint.gear_ratio", |j| j.gear_ratio = -2e4),
        ("joint.rotor_at_zero_rad", |j| {
            j.rotor_at_zero_rad = f32::NAN
        }),
        ("joint.rotor_at_zero_rad", |j| {
            j.rotor_at_zero_rad = f32::INFINITY
        }),
        ("joint.travel_out_rad", |j| {
            j.travel_out_rad = Some((1.0, 1.0))
        }),
        ("joint.travel_out_rad", |j| {
            j.travel_out_rad = Some((2.0, -1.0))
        }),
        ("joint.travel_out_rad", |j| {
            j.travel_out_rad = Some((f32::NAN, 1.0))
        }),
        ("joint.travel_out_rad", |j| {
            j.travel_out_rad = Some((-1.0, f32::INFINITY))
        }),
        // Finite at the output, not in the rotor frame.
        ("joint.travel_out_rad", |j| {
            j.travel_out_rad = Some((-1e38, 1e38))
        }),
        ("joint.fault_margin_rad", |j| j.fault_margin_rad = -0.1),
        ("joint.fault_margin_rad", |j| j.fault_margin_rad = f32::NAN),
        ("joint.fault_margin_rad", |j| {
            j.fault_margin_rad = f32::INFINITY
        }),
        ("joint.brake_accel_rad_s2", |j| j.brake_accel_rad_s2 = 0.0),
        ("joint.brake_accel_rad_s2", |j| j.brake_accel_rad_s2 = -1.0),
        ("joint.brake_accel_rad_s2", |j| {
            j.brake_accel_rad_s2 = f32::NAN
        }),
        ("joint.kv_a_per_rad_s", |j| j.kv_a_per_rad_s = 0.0),
        ("joint.kv_a_per_rad_s", |j| j.kv_a_per_rad_s = f32::INFINITY),
        ("joint.timeout_kd_nm_s_per_rad", |j| {
            j.timeout_kd_nm_s_per_rad = -1e-3
        }),
        ("joint.timeout_kd_nm_s_per_rad", |j| {
            j.timeout_kd_nm_s_per_rad = f32::NAN
        }),
        ("joint.max_kp_nm_per_rad", |j| j.max_kp_nm_per_rad = -1.0),
        ("joint.max_kp_nm_per_rad", |j| {
            j.max_kp_nm_per_rad = f32::INFINITY
        }),
        ("joint.max_kp_nm_per_rad", |j| {
            j.max_kp_nm_per_rad = f32::NAN
        }),
        ("joint.max_kd_nm_s_per_rad", |j| {
            j.max_kd_nm_s_per_rad = -0.5
        }),
        ("joint.max_kd_nm_s_per_rad", |j| {
            j.max_kd_nm_s_per_rad = f32::INFINITY
        }),
    ];
    for (field, spoil) in cases {
        let mut r = ok.clone();
        spoil(r.joint.as_mut().unwrap());
        assert_eq!(r.validate(), Err(Invalid { field }), "{field}");
    }
    // Without a travel range the soft stop is not used: not checked (a
    // build with a zero speed gain has a zero soft-stop gain).
    let mut r = ok.clone();
    let j = r.joint.as_mut().unwrap();
    j.travel_out_rad = None;
    j.kv_a_per_rad_s = 0.0;
    j.brake_accel_rad_s2 = f32::NAN;
    assert_eq!(r.validate(), Ok(()));
    // The bounds, zeros and the longest entry blend are accepted.
    for (g, kp, kd, blend) in [
        (0.01, 0.0, 0.0, 0),
        (
            -10_000.0,
            f32::MAX,
            f32::MAX,
            JointConfig::MAX_ENTRY_BLEND_PERIODS,
        ),
        (1.0, 1e-9, 1e-9, 1),
    ] {
        let mut r = ok.clone();
        let j = r.joint.as_mut().unwrap();
        j.gear_ratio = g;
        j.max_kp_nm_per_rad = kp;
        j.max_kd_nm_s_per_rad = kd;
        j.entry_blend_periods = blend;
        j.fault_margin_rad = 0.0;
        assert_eq!(r.validate(), Ok(()), "{g} {kp} {kd} {blend}");
    }
    // An entry blend so long its f32 weight would never reach 0: refused.
    let mut r = ok.clone();
    r.joint.as_mut().unwrap().entry_blend_periods = JointConfig::MAX_ENTRY_BLEND_PERIODS + 1;
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "joint.entry_blend_periods"
        })
    );
    // The record's own limits come first.
    let mut r = ok.clone();
    r.limits.max_position_rad = f32::NAN;
    r.joint.as_mut().unwrap().gear_ratio = f32::NAN;
    assert_eq!(
        r.validate(),
        Err(Invalid {
            field: "limits.max_position_rad"
        })
    );
}

#[test]
fn joint_round_trips_through_settings() {
    use crate::Settings;
    use foc_core::drive::cascade::CascadeConfig;
    // (With its `[field]` table: settings always write one; its tables
    // are not settings: added back.)
    let r = crate::record::example();
    let build = CascadeConfig::for_motor(r.motor.to_params(), 20_000.0, 5.0);
    let base = Settings::from_cascade(&build);
    let j = r.joint.unwrap();
    let s = r.apply(&base, 20_000).unwrap();
    assert_eq!(s.joint.frame.gear_ratio(), -9.0);
    assert_eq!(s.joint.frame.rotor_at_zero_rad(), 1.5);
    assert_eq!(s.joint.travel_out_rad, Some((-1.5, 2.0)));
    assert_eq!(s.joint.travel, j.soft_stop());
    assert_eq!(s.joint.joint.travel, Some(j.soft_stop()));
    assert_eq!(s.joint.joint.entry_blend_periods, 200);
    assert_eq!(s.joint.joint.timeout_kd_nm_s_per_rad, 0.001);
    assert_eq!(
        (s.limits.max_kp_nm_per_rad, s.limits.max_kd_nm_s_per_rad),
        (20.0, 0.5)
    );
    // The record's own position range stays the limits' (the build's
    // without a travel range).
    assert_eq!(
        (s.limits.min_position_rad, s.limits.max_position_rad),
        (-100.0, 100.0)
    );
    let tables = crate::settings::Tables::of_record(&r);
    assert_eq!(
        DriveRecord::from_settings(&r.label, 20_000, &s).with_tables(&tables),
        r
    );
    assert_eq!(r.apply(&s, 20_000), Ok(s));
    // In the stage: the travel range in the rotor frame, reversed by the
    // negative ratio: 1.5 - 9 * 2 ..= 1.5 + 9 * 1.5.
    let c = s.apply_to(&build);
    assert_eq!(
        (
            c.current.limits.min_position_rad,
            c.current.limits.max_position_rad
        ),
        (-16.5, 15.0)
    );
    assert_eq!(c.current.joint.travel, Some(j.soft_stop()));
    assert_eq!(c.current.limits.max_kp_nm_per_rad, 20.0);
    // Without a travel range: the record's range, no travel limits.
    let mut free = r.clone();
    free.joint.as_mut().unwrap().travel_out_rad = None;
    let s = free.apply(&base, 20_000).unwrap();
    assert_eq!(s.joint.joint.travel, None);
    let c = s.apply_to(&build);
    assert_eq!(
        (
            c.current.limits.min_position_rad,
            c.current.limits.max_position_rad
        ),
        (-100.0, 100.0)
    );
    assert_eq!(c.current.joint.travel, None);
    assert_eq!(
        DriveRecord::from_settings(&r.label, 20_000, &s).with_tables(&tables),
        free
    );
    // None keeps base's joint and maxima (a reload keeps the ones in
    // force).
    let mut none = r.clone();
    none.joint = None;
    let kept = none.apply(&base, 20_000).unwrap();
    assert_eq!(kept.joint, base.joint);
    assert_eq!(
        (
            kept.limits.max_kp_nm_per_rad,
            kept.limits.max_kd_nm_s_per_rad
        ),
        (
            base.limits.max_kp_nm_per_rad,
            base.limits.max_kd_nm_s_per_rad
        )
    );
    let on_loaded = none
        .apply(&r.apply(&base, 20_000).unwrap(), 20_000)
        .unwrap();
    assert_eq!(on_loaded.joint.frame.gear_ratio(), -9.0);
    assert_eq!(on_loaded.limits.max_kp_nm_per_rad, 20.0);
    // A bad joint refuses the whole record.
    let mut bad = r.clone();
    bad.joint.as_mut().unwrap().gear_ratio = 0.0;
    assert_eq!(
        bad.apply(&base, 20_000),
        Err(Invalid {
            field: "joint.gear_ratio"
        })
    );
    // The build's settings are a valid record with the identity frame.
    let b = DriveRecord::from_settings(&r.label, 20_000, &base);
    assert_eq!(b.validate(), Ok(()));
    let bj = b.joint.unwrap();
    assert_eq!(
        (bj.gear_ratio, bj.rotor_at_zero_rad, bj.travel_out_rad),
        (1.0, 0.0, None)
    );
    assert_eq!(bj.max_kp_nm_per_rad, base.limits.max_kp_nm_per_rad);
    assert_eq!(b.apply(&base, 20_000), Ok(base));
}

#[test]
fn power_limits_are_checked_field_by_field() {
    let ok = record_a();
    assert_eq!(ok.validate(), Ok(()));
    type Spoil = fn(&mut crate::record::PowerRecord);
    let cases: [(&str, Spoil); 8] = [
        ("power.regen_start_v", |p| {
            p.regen_start_v = p.regen_end_v + 1.0
        }),
        ("power.regen_start_v", |p| p.regen_end_v = f32::NAN),
        ("power.bus_current_motoring_max_a", |p| {
            p.bus_current_motoring_max_a = -1.0
        }),
        ("power.power_regen_max_w", |p| {
            p.power_regen_max_w = f32::NAN
        }),
        ("power.thermal_resistance_k_per_w", |p| {
            p.thermal_resistance_k_per_w = 0.0
        }),
        ("power.ambient_c", |p| p.ambient_c = f32::INFINITY),
        ("power.winding_derate_start_c", |p| {
            p.winding_derate_start_c = 130.0
        }),
        ("power.brake_off_v", |p| p.brake_off_v = 30.0),
    ];
    for (field, f) in cases {
        let mut r = ok.clone();
        let mut p = r.power.unwrap();
        // brake thresholds finite for the last case
        p.brake_on_v = 27.0;
        p.brake_off_v = 26.0;
        r.power = Some(p);
        assert_eq!(r.validate(), Ok(()), "{field}: base");
        f(r.power.as_mut().unwrap());
        assert_eq!(r.validate(), Err(Invalid { field }), "{field}");
    }
}

#[test]
fn power_limits_round_trip_through_settings_with_the_records_motor() {
    use crate::Settings;
    use foc_core::drive::cascade::CascadeConfig;
    let r = record_a();
    let base = Settings::from_cascade(&CascadeConfig::for_motor(
        r.motor.to_params(),
        20_000.0,
        5.0,
    ));
    assert_eq!(base.power, None);
    let s = r.apply(&base, 20_000).unwrap();
    let p = s.power.expect("the record's limits");
    assert_eq!(p.motor, r.motor.to_params());
    assert_eq!(p.bus_current_regen_max_a, 2.0);
    assert_eq!(
        DriveRecord::from_settings(&r.label, 20_000, &s).power,
        r.power
    );
    // None in the record keeps the build's (here: none).
    let mut n = r.clone();
    n.power = None;
    assert_eq!(n.apply(&base, 20_000).unwrap().power, None);
}

#[test]
fn mechanics_round_trip_through_settings() {
    use crate::Settings;
    use foc_core::drive::cascade::CascadeConfig;
    let r = record_a();
    let base = Settings::from_cascade(&CascadeConfig::for_motor(
        r.motor.to_params(),
        20_000.0,
        5.0,
    ));
    assert_eq!(base.mechanics, None);
    let s = r.apply(&base, 20_000).unwrap();
    assert_eq!(s.mechanics, Some(r.mechanics.unwrap().to_mechanics()));
    assert_eq!(
        DriveRecord::from_settings(&r.label, 20_000, &s).mechanics,
        r.mechanics
    );
    // None in the record keeps base's: none here, the loaded ones on a
    // reload.
    let mut n = r.clone();
    n.mechanics = None;
    assert_eq!(n.apply(&base, 20_000).unwrap().mechanics, None);
    assert_eq!(n.apply(&s, 20_000).unwrap().mechanics, s.mechanics);
    assert_eq!(
        DriveRecord::from_settings(&r.label, 20_000, &base).mechanics,
        None
    );
}

/// The envelope of `example()` as the version-2 build wrote it (captured
/// from commit 5b20272, the last version-2 build, with `power` and without
/// `mechanics`): it must still decode, without mechanics.
const V2_GOLDEN: [u8; 183] = [
    0x02, 0x00, 0xaf, 0x00, 0x0b, 0x62, 0x65, 0x6e, 0x63, 0x68, 0x20, 0x6d, 0x6f, 0x74, 0x6f, 0x72,
    0xa0, 0x9c, 0x01, 0x07, 0xcd, 0xcc, 0x4c, 0x3e, 0x82, 0xa8, 0x7b, 0x38, 0xf7, 0xcc, 0x92, 0x38,
    0x6f, 0x12, 0x83, 0x3b, 0x9a, 0x99, 0x99, 0x3e, 0x00, 0x00, 0x7a, 0x44, 0x33, 0x33, 0xb3, 0x3e,
    0x00, 0x00, 0x7a, 0x44, 0x01, 0x00, 0x00, 0xa0, 0x3f, 0x01, 0x07, 0x80, 0x20, 0x00, 0x00, 0xa0,
    0x40, 0x00, 0x00, 0x96, 0x43, 0x00, 0x00, 0xc8, 0xc2, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x40,
    0x40, 0x00, 0x00, 0xfa, 0x43, 0xcd, 0xcc, 0x4c, 0x3d, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0xf0,
    0x41, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x7a, 0x44, 0x0a, 0x14, 0xd0, 0x0f, 0x01, 0x01, 0x00,
    0x00, 0xcc, 0x41, 0x00, 0x00, 0xe4, 0x41, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x20, 0x41, 0x00,
    0x00, 0x00, 0x40, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x00, 0x40, 0x00,
    0x00, 0x70, 0x42, 0x00, 0x00, 0x20, 0x42, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0xf0, 0x42, 0x00,
    0x00, 0x82, 0x42, 0x00, 0x00, 0xaa, 0x42, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00,
    0x00, 0x80, 0x3f, 0x9a, 0x5e, 0xc7, 0xf1,
];

#[test]
fn a_record_written_by_the_version_2_build_still_loads() {
    let r = DriveRecord::decode(&V2_GOLDEN).expect("version 2 decodes");
    assert_eq!(
        r,
        DriveRecord {
            mechanics: None,
            joint: None,
            ..record_a()
        }
    );
    assert_eq!(r.validate(), Ok(()));
    // The frozen version-2 struct still writes exactly these bytes.
    assert_eq!(envelope(2, &postcard_of(&as_v2(&record_a()))), V2_GOLDEN);
}

/// The envelope of `example()` as the version-3 build wrote it (captured
/// from commit 9f19a91, the last version-3 build, with `power` and
/// `mechanics`, without the joint): it must still decode, without the
/// joint.
const V3_GOLDEN: [u8; 196] = [
    0x03, 0x00, 0xbc, 0x00, 0x0b, 0x62, 0x65, 0x6e, 0x63, 0x68, 0x20, 0x6d, 0x6f, 0x74, 0x6f, 0x72,
    0xa0, 0x9c, 0x01, 0x07, 0xcd, 0xcc, 0x4c, 0x3e, 0x82, 0xa8, 0x7b, 0x38, 0xf7, 0xcc, 0x92, 0x38,
    0x6f, 0x12, 0x83, 0x3b, 0x9a, 0x99, 0x99, 0x3e, 0x00, 0x00, 0x7a, 0x44, 0x33, 0x33, 0xb3, 0x3e,
    0x00, 0x00, 0x7a, 0x44, 0x01, 0x00, 0x00, 0xa0, 0x3f, 0x01, 0x07, 0x80, 0x20, 0x00, 0x00, 0xa0,
    0x40, 0x00, 0x00, 0x96, 0x43, 0x00, 0x00, 0xc8, 0xc2, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x40,
    0x40, 0x00, 0x00, 0xfa, 0x43, 0xcd, 0xcc, 0x4c, 0x3d, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0xf0,
    0x41, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x7a, 0x44, 0x0a, 0x14, 0xd0, 0x0f, 0x01, 0x01, 0x00,
    0x00, 0xcc, 0x41, 0x00, 0x00, 0xe4, 0x41, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x20, 0x41, 0x00,
    0x00, 0x00, 0x40, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x00, 0x40, 0x00,
    0x00, 0x70, 0x42, 0x00, 0x00, 0x20, 0x42, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0xf0, 0x42, 0x00,
    0x00, 0x82, 0x42, 0x00, 0x00, 0xaa, 0x42, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00,
    0x00, 0x80, 0x3f, 0x01, 0x17, 0xb7, 0xd1, 0x37, 0xac, 0xc5, 0x27, 0x37, 0x6f, 0x12, 0x03, 0x3b,
    0x90, 0xbd, 0xfd, 0xbe,
];

#[test]
fn a_record_written_by_the_version_3_build_still_loads() {
    let r = DriveRecord::decode(&V3_GOLDEN).expect("version 3 decodes");
    assert_eq!(
        r,
        DriveRecord {
            joint: None,
            ..record_a()
        }
    );
    assert_eq!(r.validate(), Ok(()));
    // The frozen version-3 struct still writes exactly these bytes.
    assert_eq!(envelope(3, &postcard_of(&as_v3(&record_a()))), V3_GOLDEN);
}

/// The envelope of `example()` as the version-1 build wrote it (captured
/// from commit efaada8, the last version-1 build): it must still decode,
/// with the build's default power limits.
const V1_GOLDEN: [u8; 114] = [
    0x01, 0x00, 0x6a, 0x00, 0x0b, 0x62, 0x65, 0x6e, 0x63, 0x68, 0x20, 0x6d, 0x6f, 0x74, 0x6f, 0x72,
    0xa0, 0x9c, 0x01, 0x07, 0xcd, 0xcc, 0x4c, 0x3e, 0x82, 0xa8, 0x7b, 0x38, 0xf7, 0xcc, 0x92, 0x38,
    0x6f, 0x12, 0x83, 0x3b, 0x9a, 0x99, 0x99, 0x3e, 0x00, 0x00, 0x7a, 0x44, 0x33, 0x33, 0xb3, 0x3e,
    0x00, 0x00, 0x7a, 0x44, 0x01, 0x00, 0x00, 0xa0, 0x3f, 0x01, 0x07, 0x80, 0x20, 0x00, 0x00, 0xa0,
    0x40, 0x00, 0x00, 0x96, 0x43, 0x00, 0x00, 0xc8, 0xc2, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x40,
    0x40, 0x00, 0x00, 0xfa, 0x43, 0xcd, 0xcc, 0x4c, 0x3d, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0xf0,
    0x41, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x7a, 0x44, 0x0a, 0x14, 0xd0, 0x0f, 0x01, 0xf4, 0xaf,
    0xb1, 0xb2,
];

#[test]
fn a_record_written_by_the_version_1_build_still_loads() {
    let r = DriveRecord::decode(&V1_GOLDEN).expect("version 1 decodes");
    assert_eq!(
        r,
        DriveRecord {
            power: None,
            mechanics: None,
            joint: None,
            ..record_a()
        }
    );
    assert_eq!(r.validate(), Ok(()));
    // The frozen version-1 struct still writes exactly these bytes.
    assert_eq!(envelope(1, &postcard_of(&as_v1(&record_a()))), V1_GOLDEN);
}

/// The envelope of `record_a()` as schema version 4 wrote it (frozen when
/// schema 5 added `sensorless`).
const V4_GOLDEN: [u8; 240] = [
    0x04, 0x00, 0xe8, 0x00, 0x0b, 0x62, 0x65, 0x6e, 0x63, 0x68, 0x20, 0x6d, 0x6f, 0x74, 0x6f, 0x72,
    0xa0, 0x9c, 0x01, 0x07, 0xcd, 0xcc, 0x4c, 0x3e, 0x82, 0xa8, 0x7b, 0x38, 0xf7, 0xcc, 0x92, 0x38,
    0x6f, 0x12, 0x83, 0x3b, 0x9a, 0x99, 0x99, 0x3e, 0x00, 0x00, 0x7a, 0x44, 0x33, 0x33, 0xb3, 0x3e,
    0x00, 0x00, 0x7a, 0x44, 0x01, 0x00, 0x00, 0xa0, 0x3f, 0x01, 0x07, 0x80, 0x20, 0x00, 0x00, 0xa0,
    0x40, 0x00, 0x00, 0x96, 0x43, 0x00, 0x00, 0xc8, 0xc2, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x40,
    0x40, 0x00, 0x00, 0xfa, 0x43, 0xcd, 0xcc, 0x4c, 0x3d, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0xf0,
    0x41, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x7a, 0x44, 0x0a, 0x14, 0xd0, 0x0f, 0x01, 0x01, 0x00,
    0x00, 0xcc, 0x41, 0x00, 0x00, 0xe4, 0x41, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x20, 0x41, 0x00,
    0x00, 0x00, 0x40, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x00, 0x40, 0x00,
    0x00, 0x70, 0x42, 0x00, 0x00, 0x20, 0x42, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0xf0, 0x42, 0x00,
    0x00, 0x82, 0x42, 0x00, 0x00, 0xaa, 0x42, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00,
    0x00, 0x80, 0x3f, 0x01, 0x17, 0xb7, 0xd1, 0x37, 0xac, 0xc5, 0x27, 0x37, 0x6f, 0x12, 0x03, 0x3b,
    0x01, 0x00, 0x00, 0x10, 0xc1, 0x00, 0x00, 0xc0, 0x3f, 0x01, 0x00, 0x00, 0xc0, 0xbf, 0x00, 0x00,
    0x00, 0x40, 0x00, 0x00, 0x80, 0x3e, 0x00, 0x00, 0xfa, 0x44, 0xcd, 0xcc, 0x4c, 0x3d, 0xc8, 0x01,
    0x6f, 0x12, 0x83, 0x3a, 0x00, 0x00, 0xa0, 0x41, 0x00, 0x00, 0x00, 0x3f, 0x58, 0x76, 0x36, 0xce,
];

/// The envelope of `record_a()` with a sensorless setting (start 4 A, bus
/// 24 V, no travel range) as schema version 5 wrote it (frozen: decoded by
/// [`crate::record::v5::DriveRecordV5`] and migrated).
const V5_GOLDEN: [u8; 241] = [
    0x05, 0x00, 0xe9, 0x00, 0x0b, 0x62, 0x65, 0x6e, 0x63, 0x68, 0x20, 0x6d, 0x6f, 0x74, 0x6f, 0x72,
    0xa0, 0x9c, 0x01, 0x07, 0xcd, 0xcc, 0x4c, 0x3e, 0x82, 0xa8, 0x7b, 0x38, 0xf7, 0xcc, 0x92, 0x38,
    0x6f, 0x12, 0x83, 0x3b, 0x9a, 0x99, 0x99, 0x3e, 0x00, 0x00, 0x7a, 0x44, 0x33, 0x33, 0xb3, 0x3e,
    0x00, 0x00, 0x7a, 0x44, 0x01, 0x00, 0x00, 0xa0, 0x3f, 0x01, 0x07, 0x80, 0x20, 0x00, 0x00, 0xa0,
    0x40, 0x00, 0x00, 0x96, 0x43, 0x00, 0x00, 0xc8, 0xc2, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x40,
    0x40, 0x00, 0x00, 0xfa, 0x43, 0xcd, 0xcc, 0x4c, 0x3d, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0xf0,
    0x41, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x7a, 0x44, 0x0a, 0x14, 0xd0, 0x0f, 0x01, 0x01, 0x00,
    0x00, 0xcc, 0x41, 0x00, 0x00, 0xe4, 0x41, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x20, 0x41, 0x00,
    0x00, 0x00, 0x40, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x00, 0x40, 0x00,
    0x00, 0x70, 0x42, 0x00, 0x00, 0x20, 0x42, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0xf0, 0x42, 0x00,
    0x00, 0x82, 0x42, 0x00, 0x00, 0xaa, 0x42, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00,
    0x00, 0x80, 0x3f, 0x01, 0x17, 0xb7, 0xd1, 0x37, 0xac, 0xc5, 0x27, 0x37, 0x6f, 0x12, 0x03, 0x3b,
    0x01, 0x00, 0x00, 0x10, 0xc1, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0x00, 0x80, 0x3e, 0x00, 0x00,
    0xfa, 0x44, 0xcd, 0xcc, 0x4c, 0x3d, 0xc8, 0x01, 0x6f, 0x12, 0x83, 0x3a, 0x00, 0x00, 0xa0, 0x41,
    0x00, 0x00, 0x00, 0x3f, 0x01, 0x00, 0x00, 0x80, 0x40, 0x00, 0x00, 0xc0, 0x41, 0xcd, 0x53, 0xa0,
    0x57,
];

/// `record_a()` with the sensorless setting of [`V5_GOLDEN`] (and no
/// travel range: without the sensor the position has no fixed zero).
fn sensorless_record() -> DriveRecord {
    let mut r = record_a();
    if let Some(j) = r.joint.as_mut() {
        j.travel_out_rad = None;
    }
    r.sensorless = Some(SensorlessRecord {
        start_current_a: 4.0,
        bus_voltage_v: 24.0,
        beside_sensor: None,
        observer_above_rad_s: None,
    });
    r
}

/// `record_a()` with the observer beside its sensor as halls +
/// sensorless above 40 rad/s (start 4 A, bus 24 V; the travel range kept).
fn hybrid_record() -> DriveRecord {
    let mut r = record_a();
    r.sensorless = Some(SensorlessRecord {
        start_current_a: 4.0,
        bus_voltage_v: 24.0,
        beside_sensor: Some(crate::record::BesideRole::HallSensorless),
        observer_above_rad_s: Some(40.0),
    });
    r
}

/// [`hybrid_record`] as schema version 6 wrote it (frozen).
const V6_GOLDEN: [u8; 256] = [
    0x06, 0x00, 0xf8, 0x00, 0x0b, 0x62, 0x65, 0x6e, 0x63, 0x68, 0x20, 0x6d, 0x6f, 0x74, 0x6f, 0x72,
    0xa0, 0x9c, 0x01, 0x07, 0xcd, 0xcc, 0x4c, 0x3e, 0x82, 0xa8, 0x7b, 0x38, 0xf7, 0xcc, 0x92, 0x38,
    0x6f, 0x12, 0x83, 0x3b, 0x9a, 0x99, 0x99, 0x3e, 0x00, 0x00, 0x7a, 0x44, 0x33, 0x33, 0xb3, 0x3e,
    0x00, 0x00, 0x7a, 0x44, 0x01, 0x00, 0x00, 0xa0, 0x3f, 0x01, 0x07, 0x80, 0x20, 0x00, 0x00, 0xa0,
    0x40, 0x00, 0x00, 0x96, 0x43, 0x00, 0x00, 0xc8, 0xc2, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x40,
    0x40, 0x00, 0x00, 0xfa, 0x43, 0xcd, 0xcc, 0x4c, 0x3d, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0xf0,
    0x41, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x7a, 0x44, 0x0a, 0x14, 0xd0, 0x0f, 0x01, 0x01, 0x00,
    0x00, 0xcc, 0x41, 0x00, 0x00, 0xe4, 0x41, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x20, 0x41, 0x00,
    0x00, 0x00, 0x40, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x00, 0x40, 0x00,
    0x00, 0x70, 0x42, 0x00, 0x00, 0x20, 0x42, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0xf0, 0x42, 0x00,
    0x00, 0x82, 0x42, 0x00, 0x00, 0xaa, 0x42, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00,
    0x00, 0x80, 0x3f, 0x01, 0x17, 0xb7, 0xd1, 0x37, 0xac, 0xc5, 0x27, 0x37, 0x6f, 0x12, 0x03, 0x3b,
    0x01, 0x00, 0x00, 0x10, 0xc1, 0x00, 0x00, 0xc0, 0x3f, 0x01, 0x00, 0x00, 0xc0, 0xbf, 0x00, 0x00,
    0x00, 0x40, 0x00, 0x00, 0x80, 0x3e, 0x00, 0x00, 0xfa, 0x44, 0xcd, 0xcc, 0x4c, 0x3d, 0xc8, 0x01,
    0x6f, 0x12, 0x83, 0x3a, 0x00, 0x00, 0xa0, 0x41, 0x00, 0x00, 0x00, 0x3f, 0x01, 0x00, 0x00, 0x80,
    0x40, 0x00, 0x00, 0xc0, 0x41, 0x01, 0x02, 0x01, 0x00, 0x00, 0x20, 0x42, 0x4f, 0x22, 0x6f, 0x97,
];

/// [`hybrid_record`] as schema version 7 wrote it (frozen: decoded by
/// [`crate::record::v7::DriveRecordV7`] and migrated).
const V7_GOLDEN: [u8; 257] = [
    0x07, 0x00, 0xf9, 0x00, 0x0b, 0x62, 0x65, 0x6e, 0x63, 0x68, 0x20, 0x6d, 0x6f, 0x74, 0x6f, 0x72,
    0xa0, 0x9c, 0x01, 0x07, 0xcd, 0xcc, 0x4c, 0x3e, 0x82, 0xa8, 0x7b, 0x38, 0xf7, 0xcc, 0x92, 0x38,
    0x6f, 0x12, 0x83, 0x3b, 0x9a, 0x99, 0x99, 0x3e, 0x00, 0x00, 0x7a, 0x44, 0x33, 0x33, 0xb3, 0x3e,
    0x00, 0x00, 0x7a, 0x44, 0x01, 0x00, 0x00, 0xa0, 0x3f, 0x01, 0x07, 0x80, 0x20, 0x00, 0x00, 0x00,
    0xa0, 0x40, 0x00, 0x00, 0x96, 0x43, 0x00, 0x00, 0xc8, 0xc2, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00,
    0x40, 0x40, 0x00, 0x00, 0xfa, 0x43, 0xcd, 0xcc, 0x4c, 0x3d, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00,
    0xf0, 0x41, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x7a, 0x44, 0x0a, 0x14, 0xd0, 0x0f, 0x01, 0x01,
    0x00, 0x00, 0xcc, 0x41, 0x00, 0x00, 0xe4, 0x41, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x20, 0x41,
    0x00, 0x00, 0x00, 0x40, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x00, 0x40,
    0x00, 0x00, 0x70, 0x42, 0x00, 0x00, 0x20, 0x42, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0xf0, 0x42,
    0x00, 0x00, 0x82, 0x42, 0x00, 0x00, 0xaa, 0x42, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f,
    0x00, 0x00, 0x80, 0x3f, 0x01, 0x17, 0xb7, 0xd1, 0x37, 0xac, 0xc5, 0x27, 0x37, 0x6f, 0x12, 0x03,
    0x3b, 0x01, 0x00, 0x00, 0x10, 0xc1, 0x00, 0x00, 0xc0, 0x3f, 0x01, 0x00, 0x00, 0xc0, 0xbf, 0x00,
    0x00, 0x00, 0x40, 0x00, 0x00, 0x80, 0x3e, 0x00, 0x00, 0xfa, 0x44, 0xcd, 0xcc, 0x4c, 0x3d, 0xc8,
    0x01, 0x6f, 0x12, 0x83, 0x3a, 0x00, 0x00, 0xa0, 0x41, 0x00, 0x00, 0x00, 0x3f, 0x01, 0x00, 0x00,
    0x80, 0x40, 0x00, 0x00, 0xc0, 0x41, 0x01, 0x02, 0x01, 0x00, 0x00, 0x20, 0x42, 0x0b, 0x6b, 0x3e,
    0x8b,
];

/// [`hybrid_record`] with a d-current reference: MTPA, field weakening
/// up to 4 A with a 10 % margin and a 2000 rad/s loop, the short circuit.
fn field_record() -> DriveRecord {
    let mut r = hybrid_record();
    r.field = Some(crate::record::FieldRecord {
        mtpa: true,
        field_weakening: true,
        max_id_a: 4.0,
        voltage_margin: 0.1,
        bandwidth_rad_s: 2000.0,
        short_circuit: true,
    });
    r
}

/// [`field_record`] as schema version 8 wrote it (frozen: decoded by
/// [`crate::record::v8::DriveRecordV8`] and migrated).
const V8_GOLDEN: [u8; 273] = [
    0x08, 0x00, 0x09, 0x01, 0x0b, 0x62, 0x65, 0x6e, 0x63, 0x68, 0x20, 0x6d, 0x6f, 0x74, 0x6f, 0x72,
    0xa0, 0x9c, 0x01, 0x07, 0xcd, 0xcc, 0x4c, 0x3e, 0x82, 0xa8, 0x7b, 0x38, 0xf7, 0xcc, 0x92, 0x38,
    0x6f, 0x12, 0x83, 0x3b, 0x9a, 0x99, 0x99, 0x3e, 0x00, 0x00, 0x7a, 0x44, 0x33, 0x33, 0xb3, 0x3e,
    0x00, 0x00, 0x7a, 0x44, 0x01, 0x00, 0x00, 0xa0, 0x3f, 0x01, 0x07, 0x80, 0x20, 0x00, 0x00, 0x00,
    0xa0, 0x40, 0x00, 0x00, 0x96, 0x43, 0x00, 0x00, 0xc8, 0xc2, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00,
    0x40, 0x40, 0x00, 0x00, 0xfa, 0x43, 0xcd, 0xcc, 0x4c, 0x3d, 0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00,
    0xf0, 0x41, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0x7a, 0x44, 0x0a, 0x14, 0xd0, 0x0f, 0x01, 0x01,
    0x00, 0x00, 0xcc, 0x41, 0x00, 0x00, 0xe4, 0x41, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x20, 0x41,
    0x00, 0x00, 0x00, 0x40, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x00, 0x40,
    0x00, 0x00, 0x70, 0x42, 0x00, 0x00, 0x20, 0x42, 0x00, 0x00, 0xc8, 0x42, 0x00, 0x00, 0xf0, 0x42,
    0x00, 0x00, 0x82, 0x42, 0x00, 0x00, 0xaa, 0x42, 0x00, 0x00, 0x80, 0x7f, 0x00, 0x00, 0x80, 0x7f,
    0x00, 0x00, 0x80, 0x3f, 0x01, 0x17, 0xb7, 0xd1, 0x37, 0xac, 0xc5, 0x27, 0x37, 0x6f, 0x12, 0x03,
    0x3b, 0x01, 0x00, 0x00, 0x10, 0xc1, 0x00, 0x00, 0xc0, 0x3f, 0x01, 0x00, 0x00, 0xc0, 0xbf, 0x00,
    0x00, 0x00, 0x40, 0x00, 0x00, 0x80, 0x3e, 0x00, 0x00, 0xfa, 0x44, 0xcd, 0xcc, 0x4c, 0x3d, 0xc8,
    0x01, 0x6f, 0x12, 0x83, 0x3a, 0x00, 0x00, 0xa0, 0x41, 0x00, 0x00, 0x00, 0x3f, 0x01, 0x00, 0x00,
    0x80, 0x40, 0x00, 0x00, 0xc0, 0x41, 0x01, 0x02, 0x01, 0x00, 0x00, 0x20, 0x42, 0x01, 0x01, 0x01,
    0x00, 0x00, 0x80, 0x40, 0xcd, 0xcc, 0xcc, 0x3d, 0x00, 0x00, 0xfa, 0x44, 0x01, 0xe5, 0xa0, 0x98,
    0xa8,
];

/// [`field_record`] with both tables: a map of 1e-5 A per count (on)
/// with counts 1000, -1 at points 0, 1 and 32767 at point 511; a
/// correction of 1e-6 rad per count (off) with -32767 at point 0 and 5
/// at point 255; every other count 0.
fn tables_record() -> DriveRecord {
    use crate::record::{CoggingRecord, CorrectionRecord, Counts};
    let mut map = Counts::ZERO;
    map.0[0] = 1000;
    map.0[1] = -1;
    map.0[511] = 32767;
    let mut correction = Counts::ZERO;
    correction.0[0] = -32767;
    correction.0[255] = 5;
    DriveRecord {
        cogging: Some(CoggingRecord {
            enabled: true,
            scale_a: 1e-5,
            table: map,
        }),
        angle_correction: Some(CorrectionRecord {
            enabled: false,
            scale_rad: 1e-6,
            table: correction,
        }),
        ..field_record()
    }
}

/// The CRC of [`v9_golden`], captured when it was added.
const V9_GOLDEN_CRC: [u8; 4] = [0xe9, 0x08, 0xb9, 0xf2];

/// [`tables_record`] as this build (schema version 9) writes it, spelled
/// out: the header (version 9, a payload of 1817 bytes), the schema-8
/// payload of [`V8_GOLDEN`] unchanged, then each table: its `Some` tag,
/// its switch, its scale (f32 LE), the length varint of its bytes
/// (1024: `0x80 0x08`; 512: `0x80 0x04`) and its counts as i16 LE; the
/// CRC. When the layout changes, the schema version goes up and this
/// becomes a frozen version's golden; until then any change to
/// `DriveRecord` or a sub-record's layout fails here.
fn v9_golden() -> std::vec::Vec<u8> {
    let mut v = std::vec![0x09, 0x00, 0x19, 0x07];
    v.extend_from_slice(&V8_GOLDEN[4..V8_GOLDEN.len() - 4]);
    v.extend_from_slice(&[0x01, 0x01, 0xac, 0xc5, 0x27, 0x37, 0x80, 0x08]);
    let mut map = [0u8; 1024];
    map[..4].copy_from_slice(&[0xe8, 0x03, 0xff, 0xff]);
    map[1022..].copy_from_slice(&[0xff, 0x7f]);
    v.extend_from_slice(&map);
    v.extend_from_slice(&[0x01, 0x00, 0xbd, 0x37, 0x86, 0x35, 0x80, 0x04]);
    let mut correction = [0u8; 512];
    correction[..2].copy_from_slice(&[0x01, 0x80]);
    correction[510..].copy_from_slice(&[0x05, 0x00]);
    v.extend_from_slice(&correction);
    v.extend_from_slice(&V9_GOLDEN_CRC);
    v
}

#[test]
fn the_current_schema_writes_and_reads_its_golden_envelope() {
    let golden = v9_golden();
    assert_eq!(golden.len(), 1825);
    let mut buf = [0u8; crate::MAX_RECORD_BYTES];
    let n = tables_record().encode(&mut buf).expect("encodes");
    assert_eq!(&buf[..n], &golden[..], "{:#04x?}", &buf[n - 4..n]);
    let r = DriveRecord::decode(&golden).expect("version 9 decodes");
    assert_eq!(r, tables_record());
    assert_eq!(r.validate(), Ok(()));
    assert_eq!(crate::SCHEMA_VERSION, 9, "a new version freezes v9_golden");
}

/// The frozen version-8 layout of `r`.
fn as_v8(r: &DriveRecord) -> crate::record::v8::DriveRecordV8 {
    crate::record::v8::DriveRecordV8 {
        label: r.label.clone(),
        pwm_frequency_hz: r.pwm_frequency_hz,
        motor: r.motor,
        current_gains: r.current_gains,
        calibration: r.calibration,
        limits: r.limits,
        speed: r.speed,
        position: r.position,
        dividers: r.dividers,
        watchdog: r.watchdog,
        power: r.power,
        mechanics: r.mechanics,
        joint: r.joint,
        sensorless: r.sensorless,
        field: r.field,
    }
}

/// A version-8 record (before the tables) migrates with none; applied,
/// it installs none; saved again, it is schema 9 with none.
#[test]
fn the_version_8_golden_envelope_migrates_without_tables() {
    use crate::settings::Tables;
    let r = DriveRecord::decode(&V8_GOLDEN).expect("version 8 migrates");
    assert_eq!(r, field_record());
    assert_eq!((r.cogging, r.angle_correction), (None, None));
    assert_eq!(r.validate(), Ok(()));
    // The frozen version-8 struct still writes exactly these bytes.
    let p = postcard_of(&as_v8(&field_record()));
    assert_eq!(envelope(8, &p), V8_GOLDEN);
    assert_eq!(as_v8(&field_record()).into_v9(), r);
    assert_eq!(Tables::of_record(&r), Tables::NONE);
    // A version-9 payload is not a version-8 record, nor the reverse.
    assert_eq!(
        DriveRecord::decode(&envelope(8, payload(&v9_golden()))),
        Err(RecordError::Malformed)
    );
    assert_eq!(
        DriveRecord::decode(&envelope(9, &p)),
        Err(RecordError::Malformed)
    );
    // Saved again without tables: two `None` tags more.
    assert_eq!(encoded(&r).len(), V8_GOLDEN.len() + 2);
    assert_eq!(encoded(&r)[0], 9);
    // Every older golden migrates without tables.
    for g in [
        &V1_GOLDEN[..],
        &V2_GOLDEN[..],
        &V3_GOLDEN[..],
        &V4_GOLDEN[..],
        &V5_GOLDEN[..],
        &V6_GOLDEN[..],
        &V7_GOLDEN[..],
    ] {
        let r = DriveRecord::decode(g).unwrap();
        assert_eq!(
            (r.cogging, r.angle_correction),
            (None, None),
            "version {}",
            g[0]
        );
    }
}

/// The frozen version-7 layout of `r`.
fn as_v7(r: &DriveRecord) -> crate::record::v7::DriveRecordV7 {
    crate::record::v7::DriveRecordV7 {
        label: r.label.clone(),
        pwm_frequency_hz: r.pwm_frequency_hz,
        motor: r.motor,
        current_gains: r.current_gains,
        calibration: r.calibration,
        limits: r.limits,
        speed: r.speed,
        position: r.position,
        dividers: r.dividers,
        watchdog: r.watchdog,
        power: r.power,
        mechanics: r.mechanics,
        joint: r.joint,
        sensorless: r.sensorless,
    }
}

/// A version-7 record (before the d-current reference) migrates with the
/// motor's defaults: `field: None`, applied as foc-core's
/// `FieldConfig::for_motor` of the record's motor, current limit and PWM
/// rate (no field weakening; MTPA and the short circuit as foc-core
/// decides for the motor), and saved again with them written out.
#[test]
fn the_version_7_golden_envelope_migrates_with_the_motors_field_defaults() {
    use crate::Settings;
    use foc_core::control::field::FieldConfig;
    use foc_core::drive::cascade::CascadeConfig;
    let r = DriveRecord::decode(&V7_GOLDEN).expect("version 7 migrates");
    assert_eq!(r, hybrid_record());
    assert_eq!(r.field, None);
    assert_eq!(r.validate(), Ok(()));
    // The frozen version-7 struct still writes exactly these bytes.
    let p = postcard_of(&as_v7(&hybrid_record()));
    assert_eq!(envelope(7, &p), V7_GOLDEN);
    assert_eq!(as_v7(&hybrid_record()).into_v8().into_v9(), r);
    // A version-8 payload is not a version-7 record, nor the reverse.
    assert_eq!(
        DriveRecord::decode(&envelope(7, payload(&encoded(&field_record())))),
        Err(RecordError::Malformed)
    );
    assert_eq!(
        DriveRecord::decode(&envelope(8, &p)),
        Err(RecordError::Malformed)
    );
    // Applied: the record's motor's defaults (on a base built for
    // another current limit, whose own defaults differ).
    let m = r.motor.to_params();
    let base = Settings::from_cascade(&CascadeConfig::for_motor(m, 20_000.0, 2.0));
    let s = r.apply(&base, 20_000).unwrap();
    let defaults = FieldConfig::for_motor(&m, r.limits.max_current_a, 20_000.0);
    assert_eq!(s.field, defaults);
    assert!(!s.field.field_weakening);
    assert_ne!(base.field, defaults, "the base's are not the record's");
    // Saved again: the defaults written out (schema 8).
    let again = DriveRecord::from_settings(&r.label, 20_000, &s);
    assert_eq!(
        again.field,
        Some(crate::record::FieldRecord::from_config(&defaults))
    );
    assert_eq!(again.apply(&base, 20_000), Ok(s));
    // Every older golden migrates the same way.
    for g in [
        &V1_GOLDEN[..],
        &V2_GOLDEN[..],
        &V3_GOLDEN[..],
        &V4_GOLDEN[..],
        &V5_GOLDEN[..],
        &V6_GOLDEN[..],
    ] {
        let r = DriveRecord::decode(g).unwrap();
        assert_eq!(r.field, None, "version {}", g[0]);
    }
}

/// The d-current reference: every value checked with foc-core's rule and
/// named, applied whole to the settings and the cascade, back to the
/// same record; field weakening refused on a coarse angle sensor (halls)
/// where the record is applied.
#[test]
fn the_field_table_is_checked_applied_and_refused_on_halls() {
    use crate::record::FieldRecord;
    use crate::Settings;
    use foc_core::drive::cascade::CascadeConfig;
    let r = field_record();
    let f = r.field.unwrap();
    let base_cascade = CascadeConfig::for_motor(r.motor.to_params(), 20_000.0, 5.0);
    let base = Settings::from_cascade(&base_cascade);
    let s = r.apply(&base, 20_000).unwrap();
    assert_eq!(s.field, f.to_config());
    assert_eq!(s.apply_to(&base_cascade).current.field, f.to_config());
    assert_eq!(
        DriveRecord::from_settings(&r.label, 20_000, &s).field,
        Some(f)
    );
    let bad: [(FieldRecord, &str); 10] = [
        (
            FieldRecord {
                max_id_a: f32::NAN,
                ..f
            },
            "field.max_id_a",
        ),
        (
            FieldRecord {
                max_id_a: -0.5,
                ..f
            },
            "field.max_id_a",
        ),
        (
            FieldRecord {
                max_id_a: f32::INFINITY,
                ..f
            },
            "field.max_id_a",
        ),
        (
            FieldRecord {
                voltage_margin: 0.51,
                ..f
            },
            "field.voltage_margin",
        ),
        (
            FieldRecord {
                voltage_margin: -0.01,
                ..f
            },
            "field.voltage_margin",
        ),
        (
            FieldRecord {
                voltage_margin: f32::NAN,
                ..f
            },
            "field.voltage_margin",
        ),
        (
            FieldRecord {
                bandwidth_rad_s: f32::NAN,
                ..f
            },
            "field.bandwidth_rad_s",
        ),
        (FieldRecord { max_id_a: 0.0, ..f }, "field.field_weakening"),
        (
            FieldRecord {
                bandwidth_rad_s: 0.0,
                ..f
            },
            "field.field_weakening",
        ),
        (
            FieldRecord {
                voltage_margin: 0.01,
                ..f
            },
            "field.field_weakening",
        ),
    ];
    for (b, field) in bad {
        let mut r = field_record();
        r.field = Some(b);
        assert_eq!(r.validate(), Err(Invalid { field }), "{b:?}");
        assert_eq!(r.apply(&base, 20_000), Err(Invalid { field }), "{b:?}");
    }
    // Without field weakening, no current or bandwidth is needed.
    let mut off = field_record();
    off.field = Some(FieldRecord {
        field_weakening: false,
        max_id_a: 0.0,
        bandwidth_rad_s: 0.0,
        ..f
    });
    assert_eq!(off.validate(), Ok(()));
    // Halls (48 counts a turn on 7 pole pairs): field weakening refused,
    // by the calibration's sensor or, without one, the board's.
    let mut halls = field_record();
    halls.calibration.as_mut().unwrap().sensor_counts_per_rev = 48;
    assert_eq!(halls.validate(), Ok(()), "the record alone is fine");
    let refused = Err(Invalid {
        field: "field.field_weakening",
    });
    assert_eq!(halls.apply(&base, 20_000), refused);
    let mut hall_board = base;
    hall_board.angle.sensor_counts_per_rev = 48;
    let mut uncalibrated = field_record();
    uncalibrated.calibration = None;
    assert_eq!(uncalibrated.apply(&hall_board, 20_000), refused);
    assert!(uncalibrated.apply(&base, 20_000).is_ok());
    // MTPA and the short circuit are fine on halls; so are the defaults.
    halls.field = Some(FieldRecord {
        field_weakening: false,
        ..f
    });
    assert!(halls.apply(&base, 20_000).is_ok());
    halls.field = None;
    assert!(halls.apply(&base, 20_000).is_ok());
}

/// The frozen version-6 layout of `r`.
fn as_v6(r: &DriveRecord) -> crate::record::v6::DriveRecordV6 {
    crate::record::v6::DriveRecordV6 {
        label: r.label.clone(),
        pwm_frequency_hz: r.pwm_frequency_hz,
        motor: r.motor,
        current_gains: r.current_gains,
        calibration: r.calibration.map(as_v6_angle),
        limits: r.limits,
        speed: r.speed,
        position: r.position,
        dividers: r.dividers,
        watchdog: r.watchdog,
        power: r.power,
        mechanics: r.mechanics,
        joint: r.joint,
        sensorless: r.sensorless,
    }
}

#[test]
fn the_version_6_golden_envelope_migrates() {
    let r = DriveRecord::decode(&V6_GOLDEN).expect("version 6 migrates");
    assert_eq!(r, hybrid_record());
    assert_eq!(r.validate(), Ok(()));
    // Its calibration was made with the sensor.
    assert!(r.calibration.is_some_and(|c| !c.sensorless_only));
    // The frozen version-6 struct still writes exactly these bytes.
    let p = postcard_of(&as_v6(&hybrid_record()));
    assert_eq!(envelope(6, &p), V6_GOLDEN);
    // A version-7 payload is not a version-6 record.
    assert_eq!(
        DriveRecord::decode(&envelope(6, payload(&encoded(&hybrid_record())))),
        Err(RecordError::Malformed)
    );
}

/// A calibration made without a sensor is stored as such.
#[test]
fn a_calibration_made_without_a_sensor_round_trips() {
    let mut r = sensorless_record();
    r.calibration = Some(AngleRecord {
        zero_offset_e_rad: 0.0,
        reversed: false,
        pole_pairs: r.motor.pole_pairs,
        sensor_counts_per_rev: 0,
        sensorless_only: true,
    });
    assert_eq!(r.validate(), Ok(()));
    let back = DriveRecord::decode(&encoded(&r)).unwrap();
    assert_eq!(back, r);
    assert!(back.calibration.unwrap().to_calibration().sensorless_only);
}

/// The frozen version-5 layout of `r`.
fn as_v5(r: &DriveRecord) -> crate::record::v5::DriveRecordV5 {
    let v4 = as_v4(r);
    crate::record::v5::DriveRecordV5 {
        sensorless: r
            .sensorless
            .map(|sl| crate::record::v5::SensorlessRecordV5 {
                start_current_a: sl.start_current_a,
                bus_voltage_v: sl.bus_voltage_v,
            }),
        ..v4.into_v5()
    }
}

#[test]
fn the_version_5_golden_envelope_migrates() {
    let r = DriveRecord::decode(&V5_GOLDEN).expect("version 5 migrates");
    assert_eq!(r, sensorless_record());
    assert_eq!(r.validate(), Ok(()));
    // It replaces the sensor, as it did.
    assert!(r.sensorless.is_some_and(|sl| sl.replaces_sensor()));
    // The frozen version-5 struct still writes exactly these bytes.
    let p = postcard_of(&as_v5(&sensorless_record()));
    assert_eq!(envelope(5, &p), V5_GOLDEN);
    // A version-6 payload is not a version-5 record.
    assert_eq!(
        DriveRecord::decode(&envelope(5, payload(&encoded(&hybrid_record())))),
        Err(RecordError::Malformed)
    );
}

#[test]
fn the_version_4_golden_envelope_migrates() {
    let r = DriveRecord::decode(&V4_GOLDEN).expect("version 4 migrates");
    assert_eq!(r, record_a());
    assert_eq!(r.sensorless, None);
    // The frozen version-4 struct still writes exactly these bytes.
    let mut buf = [0u8; crate::MAX_RECORD_BYTES];
    let p = postcard::to_slice(&as_v4(&record_a()), &mut buf)
        .unwrap()
        .to_vec();
    assert_eq!(envelope(4, &p), V4_GOLDEN);
}

/// The tables: round trip through the envelope, the settings' tables and
/// TOML; a bad scale (NaN, infinite, negative), a peak foc-core's check
/// refuses (above the record's current limit, beyond the correction's
/// bound) and a table of the wrong length are refused by name, whole,
/// never decoded into a record.
#[test]
fn the_tables_are_checked_and_refused_whole() {
    use crate::settings::Tables;
    let r = tables_record();
    assert_eq!(r.validate(), Ok(()));
    assert_eq!(DriveRecord::decode(&encoded(&r)), Ok(r.clone()));
    let t = Tables::of_record(&r);
    assert!(t.cogging.enabled && !t.angle_correction.enabled);
    assert!((t.cogging.peak_a() - 0.32767).abs() < 1e-6);
    assert_eq!(
        DriveRecord {
            cogging: None,
            angle_correction: None,
            ..r.clone()
        }
        .with_tables(&t),
        r
    );
    // Tables zero everywhere are none.
    assert_eq!(r.clone().with_tables(&Tables::NONE), field_record());

    for (bad, field) in [
        (f32::NAN, "cogging.scale_a"),
        (f32::INFINITY, "cogging.scale_a"),
        (-1e-5, "cogging.scale_a"),
        // 32767 counts of 2e-4 A: 6.6 A, above the 5 A limit.
        (2e-4, "cogging.table"),
    ] {
        let mut b = r.clone();
        b.cogging.as_mut().unwrap().scale_a = bad;
        assert_eq!(b.validate(), Err(Invalid { field }), "{bad}");
        // The envelope is sound: it decodes; validation refuses it.
        assert!(DriveRecord::decode(&encoded(&b)).is_ok());
    }
    // The same map with the current limit lowered below its peak.
    let mut low = r.clone();
    low.limits.max_current_a = 0.3;
    low.sensorless = None;
    assert_eq!(
        low.validate(),
        Err(Invalid {
            field: "cogging.table"
        })
    );
    for (bad, field) in [
        (f32::NAN, "angle_correction.scale_rad"),
        (f32::NEG_INFINITY, "angle_correction.scale_rad"),
        // 32767 counts of 3e-6 rad: 0.098 rad, beyond 0.087.
        (3e-6, "angle_correction.table"),
    ] {
        let mut b = r.clone();
        b.angle_correction.as_mut().unwrap().scale_rad = bad;
        assert_eq!(b.validate(), Err(Invalid { field }), "{bad}");
    }
    let msg = std::format!(
        "{}",
        Invalid {
            field: "cogging.table"
        }
    );
    assert!(msg.contains("limits.max_current_a"), "{msg}");
    let msg = std::format!(
        "{}",
        Invalid {
            field: "angle_correction.table"
        }
    );
    assert!(msg.contains("0.087"), "{msg}");

    // A table of another length (a CRC-valid envelope, so not a damaged
    // one): malformed, never a record. The map's length varint `0x80 0x08`
    // (1024 bytes) sits right after the schema-8 payload, its tag, switch
    // and scale.
    let good = payload(&v9_golden()).to_vec();
    let at = V8_GOLDEN.len() - 8 + 6;
    assert_eq!(&good[at..at + 2], &[0x80, 0x08]);
    let mut short = good.clone();
    short[at] = 0xfe; // 1022 bytes
    short[at + 1] = 0x07;
    short.remove(at + 2);
    short.remove(at + 2);
    let mut long = good.clone();
    long[at] = 0x82; // 1026 bytes
    long.insert(at + 2, 0);
    long.insert(at + 2, 0);
    for p in [&short, &long] {
        assert_eq!(
            DriveRecord::decode(&envelope(9, p)),
            Err(RecordError::Malformed)
        );
    }
    // Cut anywhere in the tables: malformed too, never a panic.
    for n in (good.len() - 1560..good.len()).step_by(7) {
        assert_eq!(
            DriveRecord::decode(&envelope(9, &good[..n])),
            Err(RecordError::Malformed),
            "{n}"
        );
    }
}
