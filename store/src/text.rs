//! TOML export and import of a [`DriveRecord`] (host side, feature `std`).
//!
//! One table per part, units in the key names, and a top-level
//! `schema_version` so a file written for another schema is refused. In
//! the `[field]` table a key left out is the motor's default (foc-core's
//! `FieldConfig::for_motor` of the file's motor, current limit and PWM
//! rate), so `[field]` with `field_weakening = true` alone turns field
//! weakening on; an export writes every key. The tables (schema 9:
//! `[cogging]`, `[angle_correction]`) are written as their switch, their
//! scale and their counts (`table = [...]`, 512 and 256 integers); a table
//! of another length is refused by name:
//!
//! ```
//! use foc_store::text::{from_toml, to_toml};
//! # let r = foc_store::record::example();
//! let text = to_toml(&r);
//! assert!(text.contains("schema_version = 9"));
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

use std::vec::Vec;

use crate::record::{
    AngleRecord, CoggingRecord, CorrectionRecord, Counts, CurrentGainsRecord, DividersRecord,
    DriveRecord, FieldRecord, JointRecord, Label, LimitsRecord, MechanicsRecord, MotorRecord,
    PositionRecord, PowerRecord, SensorlessRecord, SpeedRecord, WatchdogRecord, SCHEMA_VERSION,
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
    field: Option<FieldText>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    cogging: Option<CoggingText>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    angle_correction: Option<CorrectionText>,
}

/// The `[cogging]` table: the map's counts as a TOML array.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CoggingText {
    enabled: bool,
    scale_a: f32,
    table: Vec<i16>,
}

/// The `[angle_correction]` table: the correction's counts as a TOML
/// array.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CorrectionText {
    enabled: bool,
    scale_rad: f32,
    table: Vec<i16>,
}

/// `table` as `N` counts, or the sentence that says how many it has.
fn counts<const N: usize>(table: &[i16], field: &str) -> Result<Counts<N>, String> {
    Counts::from_slice(table).ok_or_else(|| {
        format!(
            "`{field}` has {} values; it takes {N} (one per point of the table)",
            table.len()
        )
    })
}

impl CoggingText {
    fn of(r: &CoggingRecord) -> Self {
        Self {
            enabled: r.enabled,
            scale_a: r.scale_a,
            table: r.table.as_slice().to_vec(),
        }
    }

    fn record(&self) -> Result<CoggingRecord, String> {
        Ok(CoggingRecord {
            enabled: self.enabled,
            scale_a: self.scale_a,
            table: counts(&self.table, "cogging.table")?,
        })
    }
}

impl CorrectionText {
    fn of(r: &CorrectionRecord) -> Self {
        Self {
            enabled: r.enabled,
            scale_rad: r.scale_rad,
            table: r.table.as_slice().to_vec(),
        }
    }

    fn record(&self) -> Result<CorrectionRecord, String> {
        Ok(CorrectionRecord {
            enabled: self.enabled,
            scale_rad: self.scale_rad,
            table: counts(&self.table, "angle_correction.table")?,
        })
    }
}

/// The `[field]` table as read: every key optional (a key left out is
/// the motor's default, see [`FieldText::or_defaults`]).
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FieldText {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    mtpa: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    field_weakening: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    max_id_a: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    voltage_margin: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    bandwidth_rad_s: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    short_circuit: Option<bool>,
}

impl FieldText {
    /// Every key of `f`.
    fn of(f: &FieldRecord) -> Self {
        Self {
            mtpa: Some(f.mtpa),
            field_weakening: Some(f.field_weakening),
            max_id_a: Some(f.max_id_a),
            voltage_margin: Some(f.voltage_margin),
            bandwidth_rad_s: Some(f.bandwidth_rad_s),
            short_circuit: Some(f.short_circuit),
        }
    }

    /// The keys given, the rest `d`'s.
    fn or_defaults(&self, d: &FieldRecord) -> FieldRecord {
        FieldRecord {
            mtpa: self.mtpa.unwrap_or(d.mtpa),
            field_weakening: self.field_weakening.unwrap_or(d.field_weakening),
            max_id_a: self.max_id_a.unwrap_or(d.max_id_a),
            voltage_margin: self.voltage_margin.unwrap_or(d.voltage_margin),
            bandwidth_rad_s: self.bandwidth_rad_s.unwrap_or(d.bandwidth_rad_s),
            short_circuit: self.short_circuit.unwrap_or(d.short_circuit),
        }
    }
}

/// The record as a TOML document (no `[calibration]`, `[power]`,
/// `[mechanics]`, `[joint]`, `[sensorless]`, `[field]`, `[cogging]` or
/// `[angle_correction]` table when the record has none; no
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
        field: r.field.as_ref().map(FieldText::of),
        cogging: r.cogging.as_ref().map(CoggingText::of),
        angle_correction: r.angle_correction.as_ref().map(CorrectionText::of),
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
        // version-7 record); version 8 no `[cogging]` nor
        // `[angle_correction]`.
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
        field: None,
        cogging: f.cogging.as_ref().map(CoggingText::record).transpose()?,
        angle_correction: f
            .angle_correction
            .as_ref()
            .map(CorrectionText::record)
            .transpose()?,
    };
    // The `[field]` keys left out: the motor's defaults, as for a record
    // without the table.
    let r = DriveRecord {
        field: f.field.as_ref().map(|t| {
            let d = foc_core::control::field::FieldConfig::for_motor(
                &r.motor.to_params(),
                r.limits.max_current_a,
                r.pwm_frequency_hz as f32,
            );
            t.or_defaults(&FieldRecord::from_config(&d))
        }),
        ..r
    };
    r.validate().map_err(|e| e.to_string())?;
    Ok(r)
}
