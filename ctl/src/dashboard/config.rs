//! The configuration as a browsable tree (the live record's TOML, each key
//! with its unit, range and meaning from the book's table
//! `docs/src/tables/config-fields.md`), and one key changed: checked on
//! the host as `config import` checks a file, then sent and applied, the
//! device's own validation deciding.

use foc_ctl::{describe_error, Client, ClientError};
use foc_protocol::config::{ConfigSource, StoreOp};
use foc_protocol::message::{ErrorCode, ParamId};
use foc_store::text::{from_toml, to_toml};
use foc_store::{DriveRecord, MAX_RECORD_BYTES};
use serde_json::{json, Value};

const FIELDS: &str = include_str!("../../../docs/src/tables/config-fields.md");

/// The book's unit, range and meaning of TOML key `key`.
fn field_doc(key: &str) -> Option<(String, String, String)> {
    FIELDS
        .lines()
        .filter(|l| l.starts_with("| `"))
        .find_map(|l| {
            let cells: Vec<&str> = l
                .trim()
                .trim_matches('|')
                .split(" | ")
                .map(str::trim)
                .collect();
            let keys = cells.first()?;
            keys.split(", ")
                .any(|k| k.trim_matches('`') == key)
                .then(|| {
                    (
                        cells.get(1).unwrap_or(&"").to_string(),
                        cells.get(2).unwrap_or(&"").to_string(),
                        cells.get(3).unwrap_or(&"").to_string(),
                    )
                })
        })
}

/// The live record as TOML text.
fn live_toml(c: &mut Client) -> Result<String, String> {
    let bytes = c
        .read_config(ConfigSource::Live)
        .map_err(|e| e.to_string())?;
    let r = DriveRecord::decode(&bytes)
        .map_err(|e| format!("the live record does not decode: {e:?}"))?;
    Ok(to_toml(&r))
}

/// The tree: one entry per key, in the record's order.
pub(super) fn tree(c: &mut Client) -> Value {
    let text = match live_toml(c) {
        Ok(t) => t,
        Err(e) => return json!({"ok": false, "error": e}),
    };
    let table: toml::Table = match toml::from_str(&text) {
        Ok(t) => t,
        Err(e) => return json!({"ok": false, "error": e.to_string()}),
    };
    // In the record's order: the keys as the TOML text lists them.
    let mut rows = Vec::new();
    let mut section: Option<&str> = None;
    for line in text.lines().map(str::trim) {
        if let Some(s) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = Some(s);
            continue;
        }
        let Some((k, _)) = line.split_once('=') else {
            continue;
        };
        let k = k.trim();
        let v = match section {
            Some(s) => table.get(s).and_then(|t| t.get(k)),
            None => table.get(k),
        };
        if let Some(v) = v {
            let key = section.map_or_else(|| k.to_string(), |s| format!("{s}.{k}"));
            rows.push(row(&key, v));
        }
    }
    json!({"ok": true, "rows": rows})
}

fn row(key: &str, v: &toml::Value) -> Value {
    let (unit, range, what) = field_doc(key).unwrap_or_default();
    json!({
        "key": key,
        "section": key.split_once('.').map_or("", |(s, _)| s),
        "value": v.to_string(),
        "unit": unit,
        "range": range,
        "what": what,
    })
}

/// Change `key` to `text` (as the TOML value of the key's type), check,
/// send and apply (not saved).
pub(super) fn set(c: &mut Client, key: &str, text: &str) -> Value {
    set_many(c, &[(key.to_string(), text.to_string())])
}

/// Change several keys at once (one record: all taken or none).
pub(super) fn set_many(c: &mut Client, pairs: &[(String, String)]) -> Value {
    match try_set(c, pairs) {
        Ok(msg) => json!({"ok": true, "message": msg}),
        Err(e) => json!({"ok": false, "error": e}),
    }
}

/// The wizard's motor step: a motor file's text (the bench's format,
/// `tests/motors/*.toml`: pole pairs, R, Ld, Lq, flux linkage or KV, the
/// maximum current) as configuration keys.
pub(super) fn motor_file_pairs(text: &str) -> Result<Vec<(String, String)>, String> {
    let f = foc_bench::motor_file::MotorFile::parse(text, "the motor file")
        .map_err(|e| e.to_string())?;
    Ok(vec![
        ("motor.pole_pairs".into(), f.pole_pairs.to_string()),
        ("motor.r_ohm".into(), f.r_ohm.to_string()),
        ("motor.ld_h".into(), f.ld_h.to_string()),
        ("motor.lq_h".into(), f.lq_h.to_string()),
        (
            "motor.flux_linkage_wb".into(),
            f.flux_linkage_wb().to_string(),
        ),
        ("limits.max_current_a".into(), f.max_current_a.to_string()),
    ])
}

fn try_set(c: &mut Client, pairs: &[(String, String)]) -> Result<String, String> {
    let mut table: toml::Table = toml::from_str(&live_toml(c)?).map_err(|e| e.to_string())?;
    for (key, text) in pairs {
        let (section, name) = key
            .split_once('.')
            .map_or((None, key.as_str()), |(s, n)| (Some(s), n));
        let slot = match section {
            Some(s) => table
                .get_mut(s)
                .and_then(toml::Value::as_table_mut)
                .and_then(|t| t.get_mut(name)),
            None => table.get_mut(name),
        }
        .ok_or_else(|| format!("the record has no `{key}`"))?;
        *slot = parse_like(slot, text)
            .map_err(|why| format!("`{key}` = {text}: {why}; nothing was sent"))?;
    }
    let edited = toml::to_string(&table).map_err(|e| e.to_string())?;
    // The host's checks first (the same as `config import`): the first
    // bad value named by its key.
    let r = from_toml(&edited).map_err(|e| format!("{e}; nothing was sent"))?;
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let n = r
        .encode(&mut buf)
        .map_err(|e| format!("cannot encode the record: {e:?}"))?;
    let bytes = buf.get(..n).unwrap_or_default();
    c.write_config(bytes).map_err(|e| e.to_string())?;
    let what: Vec<String> = pairs.iter().map(|(k, v)| format!("`{k}` = {v}")).collect();
    match c.store(StoreOp::Apply) {
        Ok(()) => Ok(format!(
            "{} applied (not saved: the wizard's Save, or `config save`, keeps it)",
            what.join(", ")
        )),
        Err(ClientError::Nack(code)) => Err(refusal(c, pairs, &r, code)),
        Err(e) => Err(e.to_string()),
    }
}

/// A refused record in words, with the board's rule where it is known.
fn refusal(c: &mut Client, pairs: &[(String, String)], r: &DriveRecord, code: ErrorCode) -> String {
    let current = pairs
        .iter()
        .find(|(k, _)| k == "limits.max_current_a")
        .and_then(|(_, v)| v.parse::<f32>().ok());
    if let (Some(v), Ok(hw)) = (current, c.param(ParamId::BoardMaxCurrentA)) {
        if v > hw {
            return format!(
                "refused by the device: `limits.max_current_a` = {v} A is above this board's hardware limit of {hw} A; nothing changed"
            );
        }
    }
    if let (ErrorCode::BadRecord, Some(hint)) = (code, foc_ctl::refusal::record_refusal_hint(r)) {
        return format!(
            "refused by the device: {}: {hint}; nothing changed",
            describe_error(code)
        );
    }
    format!(
        "refused by the device: {}; nothing changed",
        describe_error(code)
    )
}

/// `text` as a TOML value of `old`'s type.
fn parse_like(old: &toml::Value, text: &str) -> Result<toml::Value, &'static str> {
    let t = text.trim();
    Ok(match old {
        toml::Value::Integer(_) => {
            toml::Value::Integer(t.parse().map_err(|_| "a whole number is needed")?)
        }
        toml::Value::Float(_) => toml::Value::Float(t.parse().map_err(|_| "a number is needed")?),
        toml::Value::Boolean(_) => {
            toml::Value::Boolean(t.parse().map_err(|_| "true or false is needed")?)
        }
        toml::Value::String(_) => toml::Value::String(t.trim_matches('"').to_string()),
        _ => return Err("this key is not edited here: use `config export` and `config import`"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_find_their_units_and_ranges() {
        let (unit, range, _) = field_doc("motor.lq_h").unwrap();
        assert_eq!(unit, "H");
        assert!(range.contains("> 0"), "{range}");
        assert_eq!(field_doc("limits.max_current_a").unwrap().0, "A");
        // The d-current reference (schema 8).
        assert_eq!(field_doc("field.max_id_a").unwrap().0, "A");
        for key in [
            "field.mtpa",
            "field.field_weakening",
            "field.voltage_margin",
            "field.bandwidth_rad_s",
            "field.short_circuit",
            // The tables (schema 9).
            "cogging.enabled",
            "cogging.scale_a",
            "cogging.table",
            "angle_correction.enabled",
            "angle_correction.scale_rad",
            "angle_correction.table",
        ] {
            assert!(field_doc(key).is_some(), "{key}");
        }
        assert_eq!(field_doc("cogging.scale_a").unwrap().0, "A per count");
        assert!(field_doc("no.such").is_none());
    }

    #[test]
    fn a_motor_file_becomes_configuration_keys() {
        let text = include_str!("../../../tests/motors/dji-m2006.toml");
        let pairs = motor_file_pairs(text).unwrap();
        let get = |k: &str| pairs.iter().find(|(x, _)| x == k).map(|(_, v)| v.clone());
        assert_eq!(get("motor.pole_pairs").as_deref(), Some("7"));
        assert!(get("limits.max_current_a").is_some());
        assert!(
            get("motor.flux_linkage_wb")
                .unwrap()
                .parse::<f64>()
                .unwrap()
                > 0.0
        );
        let err = motor_file_pairs("name = \"x\"").unwrap_err();
        assert!(err.contains("the motor file"), "{err}");
    }

    #[test]
    fn values_keep_their_type() {
        assert_eq!(
            parse_like(&toml::Value::Float(1.0), " 2.5 ").unwrap(),
            toml::Value::Float(2.5)
        );
        assert!(parse_like(&toml::Value::Integer(1), "2.5").is_err());
        assert_eq!(
            parse_like(&toml::Value::Boolean(false), "true").unwrap(),
            toml::Value::Boolean(true)
        );
    }
}
