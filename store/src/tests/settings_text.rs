//! Settings conversion rules and the TOML file.

use super::{record_a, record_b};
use crate::record::{Invalid, Label, SCHEMA_VERSION};
use crate::settings::Settings;
use crate::text::{from_toml, to_toml};
use crate::DriveRecord;
use foc_core::control::{Limits, Mechanics, MotorParams};
use foc_core::drive::cascade::CascadeConfig;

fn base(pwm: f32) -> Settings {
    let motor = MotorParams {
        pole_pairs: 7,
        r_ohm: 0.2,
        ld_h: 60e-6,
        lq_h: 60e-6,
        flux_linkage_wb: 0.004,
    };
    let mut s = Settings::from_cascade(&CascadeConfig::for_motor(motor, pwm, 5.0));
    s.angle.sensor_counts_per_rev = 2048;
    s
}

#[test]
fn apply_takes_the_record_and_keeps_the_rest() {
    let b = base(20_000.0);
    let r = record_a();
    let s = r.apply(&b, 20_000).unwrap();
    assert!(s.calibrated);
    assert!(s.permit().is_some());
    assert_eq!(s.current.motor, r.motor.to_params());
    assert_eq!(s.current.ts_s, b.current.ts_s);
    assert_eq!(s.current.max_modulation, b.current.max_modulation);
    assert_eq!(s.current.anti_windup, b.current.anti_windup);
    assert_eq!(s.speed.anti_windup, b.speed.anti_windup);
    assert_eq!(
        s.speed.reference_bandwidth_rad_s,
        b.speed.reference_bandwidth_rad_s
    );
    // The record's mechanics, and the feed-forwards J / kt of its motor;
    // the record's speed gains, not the ones derived from J.
    let m = r.mechanics.unwrap();
    let kt = r.motor.to_params().torque_constant_nm_per_a();
    assert_eq!(s.mechanics, Some(m.to_mechanics()));
    assert_eq!(s.position.accel_ff_a_per_rad_s2, m.inertia_kg_m2 / kt);
    assert_eq!(s.speed.accel_ff_a_per_rad_s2, m.inertia_kg_m2 / kt);
    assert_eq!(s.speed.kp_a_per_rad_s, r.speed.kp_a_per_rad_s);
    assert_eq!(s.speed.ki_a_per_rad, r.speed.ki_a_per_rad);
    assert_eq!(s.speed.ts_s, 10.0 / 20_000.0);
    assert_eq!(s.position.ts_s, 20.0 / 20_000.0);
    assert_eq!(s.speed.current_limit_a, r.limits.max_current_a);
    assert_eq!(s.angle.sensor_counts_per_rev, 4096);
    assert_eq!(s.dividers, (10, 20));
    assert_eq!(s.watchdog, r.watchdog);
    // Without a calibration: base's angle (its counts), uncalibrated.
    let mut r = record_a();
    r.calibration = None;
    let s = r.apply(&b, 20_000).unwrap();
    assert!(!s.calibrated);
    assert_eq!(s.permit(), None);
    assert_eq!(s.angle.sensor_counts_per_rev, 2048);
    assert_eq!(s.angle.zero_offset, b.angle.zero_offset);
    // Without mechanics: base's (none), and base's feed-forwards.
    let mut r = record_a();
    r.mechanics = None;
    let s = r.apply(&b, 20_000).unwrap();
    assert_eq!(s.mechanics, None);
    assert_eq!(
        (
            s.speed.accel_ff_a_per_rad_s2,
            s.position.accel_ff_a_per_rad_s2
        ),
        (
            b.speed.accel_ff_a_per_rad_s2,
            b.position.accel_ff_a_per_rad_s2
        )
    );
}

#[test]
fn apply_refuses_other_pwm_and_invalid_records() {
    let b = base(20_000.0);
    assert_eq!(
        record_b().apply(&b, 20_000),
        Err(Invalid {
            field: "pwm_frequency_hz"
        })
    );
    let mut r = record_a();
    r.dividers.speed = 0;
    assert_eq!(
        r.apply(&b, 20_000),
        Err(Invalid {
            field: "dividers.speed"
        })
    );
    // Bad mechanics refuse the whole record.
    let mut r = record_a();
    r.mechanics.as_mut().unwrap().inertia_kg_m2 = f32::NAN;
    assert_eq!(
        r.apply(&b, 20_000),
        Err(Invalid {
            field: "mechanics.inertia_kg_m2"
        })
    );
}

#[test]
fn toml_is_readable_and_checked() {
    let r = record_a();
    let text = to_toml(&r);
    std::eprintln!("{text}");
    for key in [
        "schema_version = 9",
        "label = \"bench motor\"",
        "[motor]",
        "r_ohm = ",
        "[current_gains]",
        "[calibration]",
        "zero_offset_e_rad = 1.25",
        "[limits]",
        "[speed]",
        "[position]",
        "[dividers]",
        "[watchdog]",
        "reaction = \"Stop\"",
        "[power]",
        "power_regen_max_w = inf",
        "[mechanics]",
        "inertia_kg_m2 = 0.000025",
        "viscous_friction_nm_s_per_rad = ",
        "coulomb_friction_nm = 0.002",
        "[joint]",
        "gear_ratio = -9.0",
        "rotor_at_zero_rad = 1.5",
        "travel_out_rad = [-1.5, 2.0]",
        "fault_margin_rad = 0.25",
        "brake_accel_rad_s2 = 2000.0",
        "kv_a_per_rad_s = 0.05",
        "entry_blend_periods = 200",
        "timeout_kd_nm_s_per_rad = 0.001",
        "max_kp_nm_per_rad = 20.0",
        "max_kd_nm_s_per_rad = 0.5",
    ] {
        assert!(text.contains(key), "{key} missing in\n{text}");
    }
    assert_eq!(from_toml(&text), Ok(r.clone()));
    // No calibration: no table, and back to None.
    let mut u = r.clone();
    u.calibration = None;
    let t = to_toml(&u);
    assert!(!t.contains("[calibration]"));
    assert_eq!(from_toml(&t), Ok(u));
    // No travel range: no key, and back to None.
    let mut free = r.clone();
    free.joint.as_mut().unwrap().travel_out_rad = None;
    let t = to_toml(&free);
    assert!(
        t.contains("[joint]") && !t.contains("travel_out_rad"),
        "{t}"
    );
    assert_eq!(from_toml(&t), Ok(free));
    // Sensorless: its table, read back; a version-4 file (before it) has
    // none and reads as on the angle sensor.
    let mut sl = r.clone();
    if let Some(j) = sl.joint.as_mut() {
        j.travel_out_rad = None;
    }
    sl.sensorless = Some(crate::record::SensorlessRecord {
        start_current_a: 3.5,
        bus_voltage_v: 48.0,
        beside_sensor: None,
        observer_above_rad_s: None,
    });
    let t = to_toml(&sl);
    assert!(
        t.contains("[sensorless]\nstart_current_a = 3.5\nbus_voltage_v = 48.0"),
        "{t}"
    );
    assert_eq!(from_toml(&t), Ok(sl.clone()));
    assert!(!to_toml(&r).contains("[sensorless]"));
    assert_eq!(
        from_toml(&to_toml(&r).replace("schema_version = 9", "schema_version = 4")),
        Ok(r.clone())
    );
    let e = from_toml(&t.replace("start_current_a = 3.5", "start_current_a = 50.0")).unwrap_err();
    assert!(e.contains("sensorless.start_current_a"), "{e}");
    // Beside the sensor (schema 6): the role by name, the speed; a
    // version-5 file's table (without them) replaces the sensor.
    let mut beside = r.clone();
    beside.sensorless = Some(crate::record::SensorlessRecord {
        start_current_a: 3.5,
        bus_voltage_v: 48.0,
        beside_sensor: Some(crate::record::BesideRole::HallSensorless),
        observer_above_rad_s: Some(40.0),
    });
    let tb = to_toml(&beside);
    assert!(
        tb.contains("beside_sensor = \"hall+sensorless\"\nobserver_above_rad_s = 40.0"),
        "{tb}"
    );
    assert_eq!(from_toml(&tb), Ok(beside.clone()));
    for role in ["check", "limp-home"] {
        let t = tb
            .replace("hall+sensorless", role)
            .replace("observer_above_rad_s = 40.0\n", "");
        assert!(from_toml(&t).is_ok(), "{role}: {t}");
    }
    let e = from_toml(&tb.replace("hall+sensorless", "halls")).unwrap_err();
    assert!(e.contains("halls"), "{e}");
    assert_eq!(
        from_toml(&t.replace("schema_version = 9", "schema_version = 5")),
        Ok(sl.clone())
    );
    // No joint: no table, and back to None (the build's).
    let mut n = r.clone();
    n.joint = None;
    let t = to_toml(&n);
    assert!(!t.contains("[joint]"));
    assert_eq!(from_toml(&t), Ok(n.clone()));
    // A version-3 file (before the joint) reads as version 4 without it.
    assert_eq!(
        from_toml(&t.replace("schema_version = 9", "schema_version = 3")),
        Ok(n.clone())
    );
    // No mechanics: no table, and back to None (not identified).
    n.mechanics = None;
    let t = to_toml(&n);
    assert!(!t.contains("[mechanics]"));
    assert_eq!(from_toml(&t), Ok(n.clone()));
    // A version-2 file (before the mechanics) reads as version 4 without
    // them.
    assert_eq!(
        from_toml(&t.replace("schema_version = 9", "schema_version = 2")),
        Ok(n.clone())
    );
    // No power limits: no table, and back to None (the build's defaults).
    n.power = None;
    let t = to_toml(&n);
    assert!(!t.contains("[power]"));
    assert_eq!(from_toml(&t), Ok(n.clone()));
    // A version-1 file (before the power limits) reads as version 4
    // without them.
    assert_eq!(
        from_toml(&t.replace("schema_version = 9", "schema_version = 1")),
        Ok(n)
    );
    // The d-current reference (schema 8): a `[field]` table, every value
    // named when out of range; none: the motor's defaults (a version-7
    // file has none).
    assert!(!text.contains("[field]"));
    let mut f = r.clone();
    f.field = Some(crate::record::FieldRecord {
        mtpa: true,
        field_weakening: true,
        max_id_a: 4.5,
        voltage_margin: 0.1,
        bandwidth_rad_s: 700.0,
        short_circuit: false,
    });
    let tf = to_toml(&f);
    assert!(
        tf.contains(
            "[field]\nmtpa = true\nfield_weakening = true\nmax_id_a = 4.5\n\
             voltage_margin = 0.1\nbandwidth_rad_s = 700.0\nshort_circuit = false"
        ),
        "{tf}"
    );
    assert_eq!(from_toml(&tf), Ok(f.clone()));
    for (from, to, field) in [
        ("max_id_a = 4.5", "max_id_a = nan", "field.max_id_a"),
        ("max_id_a = 4.5", "max_id_a = -1.0", "field.max_id_a"),
        ("max_id_a = 4.5", "max_id_a = inf", "field.max_id_a"),
        (
            "voltage_margin = 0.1",
            "voltage_margin = 0.6",
            "field.voltage_margin",
        ),
        (
            "bandwidth_rad_s = 700.0",
            "bandwidth_rad_s = -1.0",
            "field.bandwidth_rad_s",
        ),
        ("max_id_a = 4.5", "max_id_a = 0.0", "field.field_weakening"),
    ] {
        let e = from_toml(&tf.replace(from, to)).unwrap_err();
        assert!(e.contains(field), "{to}: {e}");
    }
    let e = from_toml(&tf.replace("mtpa = true", "mtpa = 1")).unwrap_err();
    assert!(e.contains("mtpa"), "{e}");
    let e = from_toml(&tf.replace("short_circuit = false", "short_circut = false")).unwrap_err();
    assert!(e.contains("short_circut"), "{e}");
    // A key left out is the motor's default (`FieldConfig::for_motor` of
    // the file's motor, current limit and PWM rate).
    let d =
        crate::record::FieldRecord::from_config(&foc_core::control::field::FieldConfig::for_motor(
            &f.motor.to_params(),
            f.limits.max_current_a,
            f.pwm_frequency_hz as f32,
        ));
    let only = tf.replace(
        "[field]\nmtpa = true\nfield_weakening = true\nmax_id_a = 4.5\n\
         voltage_margin = 0.1\nbandwidth_rad_s = 700.0\nshort_circuit = false",
        "[field]\nfield_weakening = true\nmax_id_a = 4.5",
    );
    assert_ne!(only, tf);
    let back = from_toml(&only).unwrap().field.unwrap();
    assert_eq!(
        back,
        crate::record::FieldRecord {
            field_weakening: true,
            max_id_a: 4.5,
            ..d
        }
    );
    let empty = tf.replace(
        "[field]\nmtpa = true\nfield_weakening = true\nmax_id_a = 4.5\n\
         voltage_margin = 0.1\nbandwidth_rad_s = 700.0\nshort_circuit = false",
        "[field]",
    );
    assert_eq!(from_toml(&empty).unwrap().field, Some(d));
    for older in ["schema_version = 7", "schema_version = 8"] {
        assert_eq!(
            from_toml(&text.replace("schema_version = 9", older)),
            Ok(r.clone())
        );
    }
    // Another schema version.
    for v in ["0", "10"] {
        let e =
            from_toml(&text.replace("schema_version = 9", &std::format!("schema_version = {v}")))
                .unwrap_err();
        assert!(e.contains("schema_version") && e.contains(v), "{e}");
    }
    // Joint values out of range name their field.
    for (from, to, field) in [
        ("gear_ratio = -9.0", "gear_ratio = 0.0", "joint.gear_ratio"),
        (
            "rotor_at_zero_rad = 1.5",
            "rotor_at_zero_rad = nan",
            "joint.rotor_at_zero_rad",
        ),
        (
            "travel_out_rad = [-1.5, 2.0]",
            "travel_out_rad = [2.0, -1.5]",
            "joint.travel_out_rad",
        ),
        (
            "fault_margin_rad = 0.25",
            "fault_margin_rad = -0.25",
            "joint.fault_margin_rad",
        ),
        (
            "brake_accel_rad_s2 = 2000.0",
            "brake_accel_rad_s2 = 0.0",
            "joint.brake_accel_rad_s2",
        ),
        (
            "kv_a_per_rad_s = 0.05",
            "kv_a_per_rad_s = inf",
            "joint.kv_a_per_rad_s",
        ),
        (
            "timeout_kd_nm_s_per_rad = 0.001",
            "timeout_kd_nm_s_per_rad = -1.0",
            "joint.timeout_kd_nm_s_per_rad",
        ),
        (
            "max_kp_nm_per_rad = 20.0",
            "max_kp_nm_per_rad = inf",
            "joint.max_kp_nm_per_rad",
        ),
        (
            "max_kd_nm_s_per_rad = 0.5",
            "max_kd_nm_s_per_rad = -0.5",
            "joint.max_kd_nm_s_per_rad",
        ),
    ] {
        assert!(text.contains(from), "{from}");
        let e = from_toml(&text.replace(from, to)).unwrap_err();
        assert_eq!(e, std::format!("record value `{field}` is out of range"));
    }
    // A missing joint key, a typo, or a travel range that is not a pair
    // are errors naming the key.
    for (from, to, key) in [
        ("gear_ratio = -9.0\n", "", "gear_ratio"),
        (
            "entry_blend_periods",
            "entry_blend_period",
            "entry_blend_period",
        ),
        (
            "travel_out_rad = [-1.5, 2.0]",
            "travel_out_rad = [-1.5]",
            "travel_out_rad",
        ),
        (
            "entry_blend_periods = 200",
            "entry_blend_periods = -1",
            "entry_blend_periods",
        ),
    ] {
        let e = from_toml(&text.replace(from, to)).unwrap_err();
        assert!(e.contains(key), "{key}: {e}");
    }
    // Mechanics out of range name their field.
    for (from, to, field) in [
        (
            "inertia_kg_m2 = 0.000025",
            "inertia_kg_m2 = nan",
            "mechanics.inertia_kg_m2",
        ),
        (
            "inertia_kg_m2 = 0.000025",
            "inertia_kg_m2 = 0.0",
            "mechanics.inertia_kg_m2",
        ),
        (
            "inertia_kg_m2 = 0.000025",
            "inertia_kg_m2 = 20.0",
            "mechanics.inertia_kg_m2",
        ),
        (
            "coulomb_friction_nm = 0.002",
            "coulomb_friction_nm = -0.002",
            "mechanics.coulomb_friction_nm",
        ),
        (
            "coulomb_friction_nm = 0.002",
            "coulomb_friction_nm = inf",
            "mechanics.coulomb_friction_nm",
        ),
    ] {
        assert!(text.contains(from), "{from}");
        let e = from_toml(&text.replace(from, to)).unwrap_err();
        assert_eq!(e, std::format!("record value `{field}` is out of range"));
    }
    let viscous = text
        .lines()
        .find(|l| l.starts_with("viscous_friction_nm_s_per_rad = "))
        .unwrap();
    let e = from_toml(&text.replace(viscous, "viscous_friction_nm_s_per_rad = -1.0")).unwrap_err();
    assert_eq!(
        e,
        "record value `mechanics.viscous_friction_nm_s_per_rad` is out of range"
    );
    // A missing mechanics key is an error naming it.
    let e = from_toml(&text.replace("coulomb_friction_nm", "# coulomb_friction_nm")).unwrap_err();
    assert!(e.contains("coulomb_friction_nm"), "{e}");
    // A NaN power limit names its field.
    let e = from_toml(&text.replace(
        "bus_current_regen_max_a = 2.0",
        "bus_current_regen_max_a = nan",
    ))
    .unwrap_err();
    assert_eq!(
        e,
        "record value `power.bus_current_regen_max_a` is out of range"
    );
    let e = from_toml(&text.replace("schema_version = 9\n", "")).unwrap_err();
    assert!(e.contains("schema_version"), "{e}");
    // A bad value names the field.
    let e = from_toml(&text.replace("max_current_a = 5.0", "max_current_a = -5.0")).unwrap_err();
    assert_eq!(e, "record value `limits.max_current_a` is out of range");
    // A typo or a missing key is an error naming the key.
    let e = from_toml(&text.replace("r_ohm", "r_ohms")).unwrap_err();
    assert!(e.contains("r_ohm"), "{e}");
    let e = from_toml(&text.replace("lq_h", "# lq_h")).unwrap_err();
    assert!(e.contains("lq_h"), "{e}");
    // A calibration without `sensorless_only` (a file of schema 6 or
    // older) was made with the sensor.
    assert!(text.contains("sensorless_only = false\n"), "{text}");
    assert_eq!(
        from_toml(&text.replace("sensorless_only = false\n", "")),
        from_toml(&text)
    );
    assert_eq!(SCHEMA_VERSION, 9);
}

#[test]
fn from_settings_marks_calibration() {
    let s = base(20_000.0);
    let r = DriveRecord::from_settings(&Label::new(), 20_000, &s);
    assert_eq!(r.calibration, None);
    assert_eq!(r.validate(), Ok(()));
}

#[test]
fn settings_go_back_into_the_cascade_configuration() {
    let motor = MotorParams {
        pole_pairs: 7,
        r_ohm: 0.2,
        ld_h: 60e-6,
        lq_h: 60e-6,
        flux_linkage_wb: 0.005,
    };
    let c = CascadeConfig::for_motor(motor, 20_000.0, 5.0);
    // Unchanged settings give the same configuration back.
    assert_eq!(Settings::from_cascade(&c).apply_to(&c), c);
    // A record's settings land where the drive reads them.
    let s = record_a().apply(&base(20_000.0), 20_000).unwrap();
    let d = s.apply_to(&c);
    // The limits, with the joint's travel range in the rotor frame as the
    // position range.
    let j = s
        .joint
        .rotor_change((s.limits.min_position_rad, s.limits.max_position_rad));
    assert_eq!(
        d.current.limits,
        Limits {
            min_position_rad: j.min_position_rad,
            max_position_rad: j.max_position_rad,
            ..s.limits
        }
    );
    assert_eq!(d.current.joint, j.joint);
    assert_eq!(d.current.current, s.current);
    assert_eq!(d.current.angle, s.angle);
    assert_eq!((d.speed, d.position), (s.speed, s.position));
    assert_eq!(
        (d.rates.speed_divider, d.rates.position_divider),
        s.dividers
    );
    assert_eq!(d.current.supervisor, c.current.supervisor);
}

fn motor() -> MotorParams {
    MotorParams {
        pole_pairs: 7,
        r_ohm: 0.2,
        ld_h: 60e-6,
        lq_h: 60e-6,
        flux_linkage_wb: 0.005,
    }
}

#[test]
fn a_configuration_with_mechanics_comes_back_unchanged() {
    let mut c = CascadeConfig::for_motor_with_inertia(motor(), 20_000.0, 5.0, 3e-5);
    assert!(c.mechanics.is_some());
    assert_eq!(Settings::from_cascade(&c).apply_to(&c), c);
    // With friction and a tuned speed gain too.
    assert!(c.set_mechanics(&Mechanics {
        inertia_kg_m2: 4e-5,
        viscous_friction_nm_s_per_rad: 2e-5,
        coulomb_friction_nm: 0.003,
    }));
    c.speed.kp_a_per_rad_s *= 0.5;
    let s = Settings::from_cascade(&c);
    assert_eq!(s.mechanics, c.mechanics);
    assert_eq!(s.apply_to(&c), c);
    // ... and applied on the build's configuration, without mechanics.
    let build = CascadeConfig::for_motor(motor(), 20_000.0, 5.0);
    assert_eq!(s.apply_to(&build), c);
}

#[test]
fn stored_mechanics_derive_the_loops_and_the_users_gains_win() {
    let build = CascadeConfig::for_motor(motor(), 20_000.0, 5.0);
    assert_eq!(build.mechanics, None);
    let m = Mechanics {
        inertia_kg_m2: 2e-4,
        viscous_friction_nm_s_per_rad: 1e-4,
        coulomb_friction_nm: 0.01,
    };
    // What the drive has after an identification: J installed, then the
    // user tunes the speed and position gains.
    let mut identified = build;
    assert!(identified.set_mechanics(&m));
    identified.speed.kp_a_per_rad_s = 0.123;
    identified.speed.ki_a_per_rad = 4.56;
    identified.position.kp_per_s = 17.0;
    identified.position.max_acceleration_rad_s2 = 321.0;
    let record =
        DriveRecord::from_settings(&Label::new(), 20_000, &Settings::from_cascade(&identified));
    assert_eq!(record.mechanics.map(|r| r.to_mechanics()), Some(m));
    // After a power cycle: the build's configuration with the record.
    let s = record
        .apply(&Settings::from_cascade(&build), 20_000)
        .unwrap();
    let c = s.apply_to(&build);
    assert_eq!(c.mechanics, Some(m));
    assert_eq!(c, identified);
    let kt = motor().torque_constant_nm_per_a();
    // Derived from J: the speed observer's torque input and the
    // feed-forwards.
    assert_ne!(c.current.observer, build.current.observer);
    assert_eq!(
        c.current.observer.accel_per_a_rad_s2,
        identified.current.observer.accel_per_a_rad_s2
    );
    assert_eq!(c.speed.accel_ff_a_per_rad_s2, m.inertia_kg_m2 / kt);
    assert_eq!(c.position.accel_ff_a_per_rad_s2, m.inertia_kg_m2 / kt);
    // Stored: the user's gains, not the ones J gives.
    let mut derived = build;
    assert!(derived.set_mechanics(&m));
    assert_ne!(derived.speed.kp_a_per_rad_s, 0.123);
    assert_eq!(
        (c.speed.kp_a_per_rad_s, c.speed.ki_a_per_rad),
        (0.123, 4.56)
    );
    assert_eq!(
        (c.position.kp_per_s, c.position.max_acceleration_rad_s2),
        (17.0, 321.0)
    );
    // The settings show what is in force.
    assert_eq!(Settings::from_cascade(&c).speed, s.speed);
    assert_eq!(Settings::from_cascade(&c).position, s.position);
}

#[test]
fn settings_without_mechanics_keep_the_configurations() {
    let m = Mechanics::inertia(5e-5);
    let with = CascadeConfig::for_motor_with_inertia(motor(), 20_000.0, 5.0, 5e-5);
    let s = Settings::from_cascade(&CascadeConfig::for_motor(motor(), 20_000.0, 5.0));
    assert_eq!(s.mechanics, None);
    let c = s.apply_to(&with);
    assert_eq!(c.mechanics, Some(m));
    assert_eq!(c.current.observer, with.current.observer);
    assert_eq!(
        c.position.accel_ff_a_per_rad_s2,
        with.position.accel_ff_a_per_rad_s2
    );
    // Its gains are the settings'.
    assert_eq!(c.speed.kp_a_per_rad_s, s.speed.kp_a_per_rad_s);
    // On a configuration without mechanics: none, and nothing derived.
    let build = CascadeConfig::for_motor(motor(), 20_000.0, 5.0);
    assert_eq!(s.apply_to(&build), build);
}

#[test]
fn settings_refuse_unusable_mechanics() {
    let mut s = Settings::from_cascade(&CascadeConfig::for_motor(motor(), 20_000.0, 5.0));
    let before = s;
    for j in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert!(!s.set_mechanics(&Mechanics::inertia(j)), "{j}");
        assert_eq!(s, before);
    }
    assert!(!s.set_mechanics(&Mechanics {
        coulomb_friction_nm: -1.0,
        ..Mechanics::inertia(1e-5)
    }));
    assert_eq!(s, before);
    // A motor without a torque constant.
    let mut z = s;
    z.current.motor.flux_linkage_wb = 0.0;
    assert!(!z.set_mechanics(&Mechanics::inertia(1e-5)));
    assert_eq!(z.mechanics, None);
    assert!(s.set_mechanics(&Mechanics::inertia(1e-5)));
    assert_eq!(s.mechanics, Some(Mechanics::inertia(1e-5)));
    assert_eq!(s.speed.kp_a_per_rad_s, before.speed.kp_a_per_rad_s);
}

/// The tables in TOML: `[cogging]` and `[angle_correction]` with their
/// switch, scale and counts; round trip; a table of another length, a
/// bad scale or a peak the check refuses named.
#[test]
fn tables_in_toml_round_trip_and_are_checked() {
    let r = super::record_t();
    let text = to_toml(&r);
    for key in [
        "[cogging]\nenabled = true\nscale_a = ",
        "[angle_correction]\nenabled = false\nscale_rad = ",
        "table = [",
    ] {
        assert!(text.contains(key), "{key} missing");
    }
    assert_eq!(from_toml(&text), Ok(r.clone()));
    // A table of another length: the count named.
    let t = r.cogging.unwrap().table.0;
    let first = std::format!("table = [{}, ", t[0]);
    assert!(text.contains(&first));
    let short = text.replacen(&first, "table = [", 1);
    let e = from_toml(&short).unwrap_err();
    assert_eq!(
        e,
        "`cogging.table` has 511 values; it takes 512 (one per point of the table)"
    );
    let c = r.angle_correction.unwrap().table.0;
    let first = std::format!("table = [{}, ", c[0]);
    let long = text.replace(&first, &std::format!("table = [0, {}, ", c[0]));
    assert!(from_toml(&long)
        .unwrap_err()
        .contains("`angle_correction.table` has 257 values; it takes 256"));
    // A bad scale, a peak above the current limit.
    let scale = text.lines().find(|l| l.starts_with("scale_a = ")).unwrap();
    let e = from_toml(&text.replace(scale, "scale_a = nan")).unwrap_err();
    assert_eq!(e, "record value `cogging.scale_a` is out of range");
    let e = from_toml(&text.replace(scale, "scale_a = 1.0")).unwrap_err();
    assert!(e.contains("`cogging.table` is refused"), "{e}");
    // Without tables: no tables written, none read.
    let none = to_toml(&record_b());
    assert!(!none.contains("[cogging]") && !none.contains("[angle_correction]"));
    assert_eq!(from_toml(&none), Ok(record_b()));
}
