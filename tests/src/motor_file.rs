//! Motor parameter files (`tests/motors/*.toml`).
//!
//! Each file names its source and lists which values are assumed. The flux
//! linkage is given directly (`flux_linkage_wb`) or as a speed constant
//! (`kv_rpm_per_v`, line-to-line: no-load rpm per volt of line-to-line peak
//! back-EMF), converted with
//!
//! ```text
//! psi [Wb] = 60 / (sqrt(3) * 2 pi * KV * pole_pairs)
//! ```
//!
//! (line-to-line peak EMF = sqrt(3) * omega_e * psi, omega_e = p * omega_m).
//!
//! ```no_run
//! use foc_bench::motor_file::MotorFile;
//! let f = MotorFile::load("tests/motors/m153-source.toml").unwrap();
//! let params = f.motor_params();
//! assert_eq!(params.pole_pairs, 4);
//! ```

use crate::plant::{BenchConfig, DSaturation, MotorParams, SensorConfig};
use crate::real::Real;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Every motor file in the bench's `motors/` folder (`tests/motors/`),
/// sorted by name: the set every check and controller is tested on.
pub fn all_motor_files() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("motors");
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "toml"))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// The contents of one motor file, validated.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotorFile {
    /// Motor name.
    pub name: String,
    /// Datasheet or publication the values come from.
    pub source: String,
    /// Fields (or notes) whose values are assumed, not published.
    #[serde(default)]
    pub assumed: Vec<String>,
    /// Pole pairs.
    pub pole_pairs: u8,
    /// Phase resistance \[ohm\].
    pub r_ohm: f64,
    /// d-axis inductance \[H\].
    pub ld_h: f64,
    /// q-axis inductance \[H\].
    pub lq_h: f64,
    /// Flux linkage \[Wb\] (or give `kv_rpm_per_v`).
    pub flux_linkage_wb: Option<f64>,
    /// Line-to-line speed constant [rpm/V] (or give `flux_linkage_wb`).
    pub kv_rpm_per_v: Option<f64>,
    /// Inertia [kg m^2].
    pub inertia_kg_m2: f64,
    /// Viscous friction [N m s/rad].
    pub viscous_friction_nm_s_per_rad: f64,
    /// Coulomb friction [N m].
    pub coulomb_friction_nm: f64,
    /// Rated (continuous) current \[A\].
    pub rated_current_a: f64,
    /// Maximum current \[A\].
    pub max_current_a: f64,
    /// Bus voltage \[V\].
    pub bus_voltage_v: f64,
    /// PWM frequency \[Hz\].
    pub pwm_frequency_hz: f64,
    /// Encoder counts per mechanical revolution.
    pub encoder_counts_per_rev: u32,
    /// The d axis's saturation (optional, with `ld_saturation_current_a`):
    /// the relative fall of its incremental inductance at that d current
    /// (the plant's `DSaturation`; 0 to below 1).
    #[serde(default)]
    pub ld_saturation_fraction: Option<f64>,
    /// The d current of `ld_saturation_fraction` \[A\].
    #[serde(default)]
    pub ld_saturation_current_a: Option<f64>,
}

/// Why a motor file could not be loaded.
#[derive(Debug)]
pub enum MotorFileError {
    /// The file could not be read.
    Io(PathBuf, std::io::Error),
    /// Not valid TOML, or a field is missing, unknown or of the wrong type.
    Parse(PathBuf, toml::de::Error),
    /// A field has an unphysical value.
    Invalid {
        /// The file.
        path: PathBuf,
        /// The field.
        field: &'static str,
        /// What is wrong.
        reason: &'static str,
    },
}

impl std::fmt::Display for MotorFileError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MotorFileError::Io(p, e) => write!(f, "{}: cannot read: {e}", p.display()),
            MotorFileError::Parse(p, e) => write!(f, "{}: {e}", p.display()),
            MotorFileError::Invalid {
                path,
                field,
                reason,
            } => write!(f, "{}: field `{field}` {reason}", path.display()),
        }
    }
}

impl std::error::Error for MotorFileError {}

/// Flux linkage \[Wb\] from a line-to-line KV [rpm/V]: `60 / (sqrt3 2 pi KV p)`.
pub fn flux_linkage_from_kv(kv_rpm_per_v: f64, pole_pairs: u8) -> f64 {
    60.0 / (3f64.sqrt() * std::f64::consts::TAU * kv_rpm_per_v * pole_pairs as f64)
}

impl MotorFile {
    /// Read, parse and validate a motor file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, MotorFileError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| MotorFileError::Io(path.into(), e))?;
        Self::parse(&text, path)
    }

    /// Parse and validate motor-file text (`path` only names it in errors).
    pub fn parse(text: &str, path: impl AsRef<Path>) -> Result<Self, MotorFileError> {
        let path = path.as_ref();
        let f: MotorFile =
            toml::from_str(text).map_err(|e| MotorFileError::Parse(path.into(), e))?;
        let bad = |field, reason| MotorFileError::Invalid {
            path: path.into(),
            field,
            reason,
        };
        let pos = |x: f64, field| {
            if x.is_finite() && x > 0.0 {
                Ok(())
            } else {
                Err(bad(field, "must be a finite number > 0"))
            }
        };
        let nonneg = |x: f64, field| {
            if x.is_finite() && x >= 0.0 {
                Ok(())
            } else {
                Err(bad(field, "must be a finite number >= 0"))
            }
        };
        if f.name.trim().is_empty() {
            return Err(bad("name", "must not be empty"));
        }
        if f.source.trim().is_empty() {
            return Err(bad("source", "must name the datasheet or publication"));
        }
        if f.pole_pairs == 0 {
            return Err(bad("pole_pairs", "must be >= 1"));
        }
        pos(f.r_ohm, "r_ohm")?;
        pos(f.ld_h, "ld_h")?;
        pos(f.lq_h, "lq_h")?;
        match (f.flux_linkage_wb, f.kv_rpm_per_v) {
            (Some(psi), None) => pos(psi, "flux_linkage_wb")?,
            (None, Some(kv)) => pos(kv, "kv_rpm_per_v")?,
            (Some(_), Some(_)) => {
                return Err(bad(
                    "flux_linkage_wb",
                    "and `kv_rpm_per_v` are both given: give one",
                ))
            }
            (None, None) => {
                return Err(bad(
                    "flux_linkage_wb",
                    "is missing (or give `kv_rpm_per_v`)",
                ))
            }
        }
        pos(f.inertia_kg_m2, "inertia_kg_m2")?;
        nonneg(
            f.viscous_friction_nm_s_per_rad,
            "viscous_friction_nm_s_per_rad",
        )?;
        nonneg(f.coulomb_friction_nm, "coulomb_friction_nm")?;
        pos(f.rated_current_a, "rated_current_a")?;
        pos(f.max_current_a, "max_current_a")?;
        if f.max_current_a < f.rated_current_a {
            return Err(bad("max_current_a", "must be >= rated_current_a"));
        }
        pos(f.bus_voltage_v, "bus_voltage_v")?;
        pos(f.pwm_frequency_hz, "pwm_frequency_hz")?;
        if f.encoder_counts_per_rev == 0 {
            return Err(bad("encoder_counts_per_rev", "must be >= 1"));
        }
        match (f.ld_saturation_fraction, f.ld_saturation_current_a) {
            (None, None) => {}
            (Some(fr), Some(c)) => {
                if !(fr.is_finite() && (0.0..1.0).contains(&fr)) {
                    return Err(bad("ld_saturation_fraction", "must be 0 to below 1"));
                }
                pos(c, "ld_saturation_current_a")?;
            }
            _ => {
                return Err(bad(
                    "ld_saturation_fraction",
                    "and `ld_saturation_current_a` go together: give both or neither",
                ))
            }
        }
        Ok(f)
    }

    /// Flux linkage \[Wb\], converted from KV when the file gives KV.
    pub fn flux_linkage_wb(&self) -> f64 {
        match (self.flux_linkage_wb, self.kv_rpm_per_v) {
            (Some(psi), _) => psi,
            (None, Some(kv)) => flux_linkage_from_kv(kv, self.pole_pairs),
            (None, None) => 0.0, // rejected by `parse`
        }
    }

    /// Plant motor parameters.
    pub fn motor_params(&self) -> MotorParams {
        MotorParams {
            pole_pairs: self.pole_pairs,
            r_ohm: self.r_ohm as Real,
            ld_h: self.ld_h as Real,
            lq_h: self.lq_h as Real,
            flux_linkage_wb: self.flux_linkage_wb() as Real,
            inertia_kg_m2: self.inertia_kg_m2 as Real,
            viscous_friction_nm_s_per_rad: self.viscous_friction_nm_s_per_rad as Real,
            coulomb_friction_nm: self.coulomb_friction_nm as Real,
            d_saturation: match (self.ld_saturation_fraction, self.ld_saturation_current_a) {
                (Some(fraction), Some(c)) => DSaturation {
                    fraction: fraction as Real,
                    current_a: c as Real,
                },
                _ => DSaturation::NONE,
            },
        }
    }

    /// Bench configuration at the file's operating point (other settings default;
    /// current ADC range twice the maximum current).
    pub fn bench_config(&self) -> BenchConfig {
        BenchConfig {
            pwm_frequency_hz: self.pwm_frequency_hz as Real,
            bus_voltage_v: self.bus_voltage_v as Real,
            sensors: SensorConfig {
                encoder_counts_per_rev: self.encoder_counts_per_rev,
                current_full_scale_a: 2.0 * self.max_current_a as Real,
                bus_full_scale_v: 3.0 * self.bus_voltage_v as Real,
                ..SensorConfig::default()
            },
            ..BenchConfig::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
name = "x"
source = "y"
pole_pairs = 7
r_ohm = 0.1
ld_h = 1e-5
lq_h = 1e-5
kv_rpm_per_v = 100.0
inertia_kg_m2 = 1e-5
viscous_friction_nm_s_per_rad = 0.0
coulomb_friction_nm = 0.0
rated_current_a = 1.0
max_current_a = 2.0
bus_voltage_v = 24.0
pwm_frequency_hz = 20000.0
encoder_counts_per_rev = 4096
"#;

    #[test]
    fn kv_conversion_matches_back_emf_definition() {
        let f = MotorFile::parse(GOOD, "good").unwrap();
        // At KV * 1 V rpm, the line-to-line peak EMF is 1 V.
        let w_m = 100.0 * std::f64::consts::TAU / 60.0;
        let line_peak = 3f64.sqrt() * 7.0 * w_m * f.flux_linkage_wb();
        assert!((line_peak - 1.0).abs() < 1e-12);
    }

    #[test]
    fn clear_errors() {
        let neg = GOOD.replace("r_ohm = 0.1", "r_ohm = -0.1");
        let e = MotorFile::parse(&neg, "neg.toml").unwrap_err().to_string();
        assert!(
            e.contains("neg.toml") && e.contains("r_ohm") && e.contains("> 0"),
            "{e}"
        );
        let missing = GOOD.replace("ld_h = 1e-5\n", "");
        let e = MotorFile::parse(&missing, "m.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("ld_h"), "{e}");
        let none = GOOD.replace("kv_rpm_per_v = 100.0\n", "");
        let e = MotorFile::parse(&none, "n.toml").unwrap_err().to_string();
        assert!(e.contains("flux_linkage_wb"), "{e}");
        let both = GOOD.replace("kv_rpm_per_v", "flux_linkage_wb = 0.01\nkv_rpm_per_v");
        assert!(MotorFile::parse(&both, "b").is_err());
        let unknown = format!("{GOOD}\nfoo = 1\n");
        let e = MotorFile::parse(&unknown, "u").unwrap_err().to_string();
        assert!(e.contains("foo"), "{e}");
        let e = MotorFile::load("/nonexistent/x.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("cannot read"), "{e}");
    }
}
