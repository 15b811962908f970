//! TOML export and import of a [`DriveRecord`] (host side, feature `std`).
//!
//! One table per part, units in the key names, and a top-level
//! `schema_version` so a file written for another schema is refused:
//!
//! ```
//! use foc_store::text::{from_toml, to_toml};
//! # let r = foc_store::record::example();
//! let text = to_toml(&r);
//! assert!(text.contains("schema_version = 8"));
//! assert!(text.contains("[field]\nmtpa = false\nfield_weakening = true\nmax_id_a = 4.0"));
//! assert!(text.contains("[joint]"));
//! assert!(text.contains("[motor]"));
//! assert_eq!(from_toml(&text), Ok(r));
//! let bad = text.replace("r_ohm = 0.2", "r_ohm = -0.2");
//! assert!(from_toml(&bad).unwrap_err().contains("motor.r_ohm"));
//! ```

use std::format;
use std::string::{String, ToString};

use serde::{Deserialize, Serialize};

use crate::record::{
    AngleRecord, CurrentGainsRecord, DividersRecord, DriveRecord, FieldRecord, JointRecord, Label,
    LimitsRecord, MechanicsRecord, MotorRecord, PositionRecord, PowerRecord, SensorlessRecord,
    SpeedRecord, WatchdogRecord, SCHEMA_VERSION,
};

/// The file layout: the record's fields with the schema version first.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlFile {
    schema_version: u16,
    label: Label,
    pwm_frequency_hz: u32,
    motor: MotorRecord,
    current_gains: CurrentGainsRecord,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    calibration: Option<AngleRecord>,
    limits: LimitsRecord,
    speed: SpeedRecord,
    position: PositionRecord,
    dividers: DividersRecord,
    watchdog: WatchdogRecord,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    power: Option<PowerRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    mechanics: Option<MechanicsRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    joint: Option<JointRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    sensorless: Option<SensorlessRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    field: Option<FieldRecord>,
}

/// The record as a TOML document (no `[calibration]`, `[power]`,
/// `[mechanics]`, `[joint]`, `[sensorless]` or `[field]` table when the
/// record has none; no
/// `travel_out_rad` key in `[joint]` without a travel range).
pub fn to_toml(r: &DriveRecord) -> String {
    let file = TomlFile {
        schema_version: SCHEMA_VERSION,
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
    };
    match toml::to_string(&file) {
        Ok(s) => s,
        // The record has no maps or other shapes TOML cannot hold.
        Err(e) => format!("# cannot export the record: {e}\n"),
    }
}

/// Parse and validate a TOML document written by [`to_toml`] (or by hand).
/// The error is a sentence that names the field (or the TOML parser's
/// message, with line and column).
pub fn from_toml(s: &str) -> Result<DriveRecord, String> {
    let table: toml::Table = toml::from_str(s).map_err(|e| e.to_string())?;
    match table.get("schema_version") {
        None => return Err("missing top-level key `schema_version`".to_string()),
        // Version 1 is version 8 without the `[power]`, `[mechanics]`,
        // `[joint]`, `[sensorless]` and `[field]` tables, version 2
        // without `[mechanics]` and what follows, and so on; version 4 has
        // no `[sensorless]`; version 5 has no roles beside the sensor;
        // version 7 no `[field]` (the motor's defaults, as a stored
        // version-7 record).
        Some(toml::Value::Integer(v)) if (1..=i64::from(SCHEMA_VERSION)).contains(v) => {}
        Some(v) => {
            return Err(format!(
                "`schema_version` is {v}; this build reads schema versions 1 to {SCHEMA_VERSION}"
            ))
        }
    }
    let f: TomlFile = toml::from_str(s).map_err(|e| e.to_string())?;
    let r = DriveRecord {
        label: f.label,
        pwm_frequency_hz: f.pwm_frequency_hz,
        motor: f.motor,
        current_gains: f.current_gains,
        calibration: f.calibration,
        limits: f.limits,
        speed: f.speed,
        position: f.position,
        dividers: f.dividers,
        watchdog: f.watchdog,
        power: f.power,
        mechanics: f.mechanics,
        joint: f.joint,
        sensorless: f.sensorless,
        field: f.field,
    };
    r.validate().map_err(|e| e.to_string())?;
    Ok(r)
}
