//! Envelope, validation and settings conversion.

use super::{largest_record, record_a, record_b};
use crate::record::{
    angle_to_e_rad, e_rad_to_angle, DriveRecord, Invalid, MechanicsRecord, RecordError,
    MAX_RECORD_BYTES, SCHEMA_VERSION,
};
use core::f32::consts::TAU;
use foc_core::angle::ElectricalAngle;

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
    // It is valid apart from the calibration's pole pairs vs the motor's
    // and the mechanics beyond their plausible ranges: make them agree and
    // check validation accepts the extremes.
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
    assert_eq!(r.validate(), Ok(()));
    assert_eq!(encoded(&r).len(), bytes.len());
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
        assert!(
            !(1..SCHEMA_VERSION).contains(&v),
            "versions 1 and 2 migrate"
        );
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

/// `r` in the version-1 layout (what it loses: `power`, `mechanics`).
fn as_v1(r: &DriveRecord) -> crate::record::v1::DriveRecordV1 {
    crate::record::v1::DriveRecordV1 {
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
    }
}

/// `r` in the version-2 layout (what it loses: `mechanics`).
fn as_v2(r: &DriveRecord) -> crate::record::v2::DriveRecordV2 {
    crate::record::v2::DriveRecordV2 {
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
    }
}

/// The payload of an envelope (without version, length and CRC).
fn payload(envelope: &[u8]) -> &[u8] {
    &envelope[4..envelope.len() - 4]
}

#[test]
fn a_version_1_record_migrates_with_the_build_default_power_limits() {
    let v3 = record_a();
    assert!(v3.power.is_some() && v3.mechanics.is_some());
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let p1 = postcard::to_slice(&as_v1(&v3), &mut buf).unwrap();
    // 1 -> 2 -> 3.
    let migrated = DriveRecord::decode(&envelope(1, p1)).unwrap();
    assert_eq!((migrated.power, migrated.mechanics), (None, None));
    assert_eq!(
        DriveRecord {
            power: v3.power,
            mechanics: v3.mechanics,
            ..migrated.clone()
        },
        v3
    );
    assert_eq!(migrated.validate(), Ok(()));
    // A version-2 or -3 payload under version 1 is not a version-1 record.
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let p2 = postcard::to_slice(&as_v2(&v3), &mut buf).unwrap();
    for p in [&p2[..], payload(&encoded(&v3))] {
        assert_eq!(
            DriveRecord::decode(&envelope(1, p)),
            Err(RecordError::Malformed)
        );
    }
}

#[test]
fn a_version_2_record_migrates_without_mechanics() {
    for v3 in [record_a(), record_b()] {
        let mut buf = [0u8; MAX_RECORD_BYTES];
        let p2 = postcard::to_slice(&as_v2(&v3), &mut buf).unwrap();
        let migrated = DriveRecord::decode(&envelope(2, p2)).unwrap();
        assert_eq!(migrated.mechanics, None);
        assert_eq!(migrated.power, v3.power);
        assert_eq!(
            DriveRecord {
                mechanics: v3.mechanics,
                ..migrated.clone()
            },
            v3
        );
        assert_eq!(migrated.validate(), Ok(()));
        // The frozen struct's own step.
        assert_eq!(as_v2(&v3).into_v3(), migrated);
        // A version-3 payload (with or without mechanics) under version 2
        // is not a version-2 record, nor a version-1 one under version 2.
        let mut none = v3.clone();
        none.mechanics = None;
        let mut buf = [0u8; MAX_RECORD_BYTES];
        let p1 = postcard::to_slice(&as_v1(&v3), &mut buf).unwrap();
        for p in [payload(&encoded(&v3)), payload(&encoded(&none)), &p1[..]] {
            assert_eq!(
                DriveRecord::decode(&envelope(2, p)),
                Err(RecordError::Malformed)
            );
        }
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
    use foc_core::control::cascade::CascadeConfig;
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
    use foc_core::control::cascade::CascadeConfig;
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
            ..record_a()
        }
    );
    assert_eq!(r.validate(), Ok(()));
    // The frozen version-2 struct still writes exactly these bytes.
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let p2 = postcard::to_slice(&as_v2(&record_a()), &mut buf).unwrap();
    assert_eq!(envelope(2, p2), V2_GOLDEN);
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
            ..record_a()
        }
    );
    assert_eq!(r.validate(), Ok(()));
}
