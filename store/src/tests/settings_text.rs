//! Settings conversion rules and the TOML file.

use super::{record_a, record_b};
use crate::record::{Invalid, Label, SCHEMA_VERSION};
use crate::settings::Settings;
use crate::text::{from_toml, to_toml};
use crate::DriveRecord;
use foc_core::control::cascade::CascadeConfig;
use foc_core::control::MotorParams;

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
        s.position.accel_ff_a_per_rad_s2,
        b.position.accel_ff_a_per_rad_s2
    );
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
}

#[test]
fn toml_is_readable_and_checked() {
    let r = record_a();
    let text = to_toml(&r);
    std::eprintln!("{text}");
    for key in [
        "schema_version = 2",
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
    // No power limits: no table, and back to None (the build's defaults).
    let mut n = r.clone();
    n.power = None;
    let t = to_toml(&n);
    assert!(!t.contains("[power]"));
    assert_eq!(from_toml(&t), Ok(n.clone()));
    // A version-1 file (before the power limits) reads as version 2
    // without them.
    assert_eq!(
        from_toml(&t.replace("schema_version = 2", "schema_version = 1")),
        Ok(n)
    );
    // Another schema version.
    for v in ["0", "3"] {
        let e =
            from_toml(&text.replace("schema_version = 2", &std::format!("schema_version = {v}")))
                .unwrap_err();
        assert!(e.contains("schema_version") && e.contains(v), "{e}");
    }
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
    let e = from_toml(&text.replace("schema_version = 2\n", "")).unwrap_err();
    assert!(e.contains("schema_version"), "{e}");
    // A bad value names the field.
    let e = from_toml(&text.replace("max_current_a = 5.0", "max_current_a = -5.0")).unwrap_err();
    assert_eq!(e, "record value `limits.max_current_a` is out of range");
    // A typo or a missing key is an error naming the key.
    let e = from_toml(&text.replace("r_ohm", "r_ohms")).unwrap_err();
    assert!(e.contains("r_ohm"), "{e}");
    let e = from_toml(&text.replace("lq_h", "# lq_h")).unwrap_err();
    assert!(e.contains("lq_h"), "{e}");
    assert_eq!(SCHEMA_VERSION, 2);
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
    assert_eq!(d.current.limits, s.limits);
    assert_eq!(d.current.current, s.current);
    assert_eq!(d.current.angle, s.angle);
    assert_eq!((d.speed, d.position), (s.speed, s.position));
    assert_eq!(
        (d.rates.speed_divider, d.rates.position_divider),
        s.dividers
    );
    assert_eq!(d.current.supervisor, c.current.supervisor);
}
