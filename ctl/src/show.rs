//! Values for people: numbers without denormals or noise digits, each
//! parameter with its unit or its code's meaning.

use foc_protocol::message::ParamId;

/// A value for people: 6 significant digits, no exponent in the usual
/// range, tiny values (denormals, noise) as 0.
pub(super) fn num(v: f32) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    if v == f32::MAX {
        return "unbounded".into();
    }
    let a = v.abs();
    if a < 1e-9 {
        return "0".into();
    }
    if !(1e-4..1e7).contains(&a) {
        let s = format!("{v:.5e}");
        return match s.split_once('e') {
            Some((m, e)) if m.contains('.') => {
                format!("{}e{e}", m.trim_end_matches('0').trim_end_matches('.'))
            }
            _ => s,
        };
    }
    let digits = (5 - a.log10().floor() as i32).clamp(0, 9) as usize;
    let s = format!("{v:.digits$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    };
    if s == "-0" {
        "0".into()
    } else {
        s
    }
}

/// A parameter's value with its unit (times also in ms, codes in words).
pub(super) fn param_text(id: ParamId, v: f32) -> String {
    use foc_ctl::calibration::result_name;
    use foc_protocol::message::step_name;
    match id {
        ParamId::CalibrationStep => format!("{} ({})", num(v), step_name(v as u8)),
        ParamId::CalibrationResult => format!("{} ({})", num(v), result_name(v as u8)),
        ParamId::Calibrated => format!("{} ({})", num(v), if v == 1.0 { "yes" } else { "no" }),
        ParamId::AngleSource => format!(
            "{} ({})",
            num(v),
            match v as u8 {
                0 => "the angle sensor",
                1 => "sensorless",
                2 => "the observer beside the sensor",
                3 => "limp-home",
                _ => "unknown",
            }
        ),
        _ if id.is_switch() => format!(
            "{} ({})",
            num(v),
            match v as u8 {
                1 => "on",
                0 => "off",
                _ => "unknown",
            }
        ),
        _ if id.unit().is_empty() => num(v),
        _ => format!("{} {}", num(v), id.unit()),
    }
}

#[cfg(test)]
mod tests {
    use super::num;

    #[test]
    fn numbers_for_people() {
        assert_eq!(num(1.0e-40), "0"); // a denormal
        assert_eq!(num(-3.2e-12), "0");
        assert_eq!(num(0.000_766_990_4), "0.00076699");
        assert_eq!(num(23.994_14), "23.9941");
        assert_eq!(num(6.0e-5), "6e-5");
        assert_eq!(num(20_000.0), "20000");
        assert_eq!(num(-0.0), "0");
        assert_eq!(num(f32::MAX), "unbounded");
        assert_eq!(num(f32::NAN), "NaN");
    }
}
