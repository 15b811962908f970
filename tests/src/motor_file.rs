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
//! A file may also state the motor's and board's imperfections (stator
//! slots and cogging, the angle sensor's error, the board's dead time):
//! [`MotorFile::imperfections`]. [`MotorFile::motor_params`] and
//! [`MotorFile::bench_config`] leave them out (the ideal bench); a test
//! that wants them applies them with [`Imperfections::apply_bench`] and
//! [`Imperfections::apply_plant`].
//!
//! ```no_run
//! use foc_bench::motor_file::MotorFile;
//! let f = MotorFile::load("tests/motors/m153-source.toml").unwrap();
//! let params = f.motor_params();
//! assert_eq!(params.pole_pairs, 4);
//! let imperfect = f.imperfections();
//! assert_eq!(imperfect.cogging.map(|c| c.cycles_per_turn), Some(24));
//! ```

use crate::plant::{
    BenchConfig, Cogging, DSaturation, MotorParams, Plant, SensorConfig, SensorError,
};
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
    /// Stator slots (optional; a positive multiple of 3): with the poles
    /// they set the cogging's cycles per turn, `lcm(slots, 2 pole_pairs)`.
    #[serde(default)]
    pub slots: Option<u32>,
    /// Peak of the cogging torque's fundamental \[N m\] (optional, needs
    /// `slots`; >= 0).
    #[serde(default)]
    pub cogging_torque_nm: Option<f64>,
    /// Amplitude of the cogging's second harmonic over its fundamental's
    /// (optional, with `cogging_torque_nm`; 0 to 1; 0 when absent).
    #[serde(default)]
    pub cogging_second_harmonic_share: Option<f64>,
    /// The angle sensor's once-per-turn error (eccentricity), amplitude in
    /// mechanical radians (optional; 0 to 0.1).
    #[serde(default)]
    pub sensor_first_harmonic_rad: Option<f64>,
    /// The angle sensor's twice-per-turn error, amplitude in mechanical
    /// radians (optional; 0 to 0.1).
    #[serde(default)]
    pub sensor_second_harmonic_rad: Option<f64>,
    /// The board's dead time at this operating point \[ns\] (optional; 0 to
    /// a tenth of the PWM period).
    #[serde(default)]
    pub dead_time_ns: Option<f64>,
}

/// A motor file's imperfections ([`MotorFile::imperfections`]), for the
/// tests that want a real motor rather than the ideal one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Imperfections {
    /// Cogging torque (`None` without `slots` and `cogging_torque_nm`, or
    /// with a zero amplitude).
    pub cogging: Option<Cogging>,
    /// The angle sensor's error (`None` when both harmonics are 0 or absent).
    pub sensor_error: Option<SensorError>,
    /// The board's dead time \[s\] (0 when absent).
    pub dead_time_s: Real,
}

impl Imperfections {
    /// Put the board's dead time into `cfg`.
    pub fn apply_bench(&self, cfg: &mut BenchConfig) {
        cfg.dead_time_s = self.dead_time_s;
    }

    /// Give `plant` the cogging and the angle sensor's error.
    pub fn apply_plant(&self, plant: &mut Plant) {
        plant.set_cogging(self.cogging);
        plant.set_angle_sensor_error(self.sensor_error);
    }
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

/// An optional field `x` named `field` within `(lo, hi)` (inclusive), or
/// the field and `reason`.
fn in_range(
    x: Option<f64>,
    field: &'static str,
    (lo, hi): (f64, f64),
    reason: &'static str,
) -> Result<(), (&'static str, &'static str)> {
    match x {
        Some(v) if !(v.is_finite() && (lo..=hi).contains(&v)) => Err((field, reason)),
        _ => Ok(()),
    }
}

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
        f.check_imperfections()
            .map_err(|(field, reason)| bad(field, reason))?;
        Ok(f)
    }

    /// The optional imperfection fields: the bad field and why.
    fn check_imperfections(&self) -> Result<(), (&'static str, &'static str)> {
        self.check_cogging()?;
        let rad = "must be 0 to 0.1 rad";
        let first = self.sensor_first_harmonic_rad;
        in_range(first, "sensor_first_harmonic_rad", (0.0, 0.1), rad)?;
        let second = self.sensor_second_harmonic_rad;
        in_range(second, "sensor_second_harmonic_rad", (0.0, 0.1), rad)?;
        let tenth_of_period_ns = 0.1e9 / self.pwm_frequency_hz;
        in_range(
            self.dead_time_ns,
            "dead_time_ns",
            (0.0, tenth_of_period_ns),
            "must be 0 to a tenth of the PWM period",
        )
    }

    /// `slots`, `cogging_torque_nm` and `cogging_second_harmonic_share`:
    /// the bad field and why.
    fn check_cogging(&self) -> Result<(), (&'static str, &'static str)> {
        if self.slots.is_some_and(|s| s == 0 || !s.is_multiple_of(3)) {
            return Err(("slots", "must be a positive multiple of 3 (three phases)"));
        }
        let amplitude = self.cogging_torque_nm;
        in_range(
            amplitude,
            "cogging_torque_nm",
            (0.0, f64::MAX),
            "must be a finite number >= 0",
        )?;
        if amplitude.is_some() && self.slots.is_none() {
            return Err(("cogging_torque_nm", "needs `slots` (the cycles per turn)"));
        }
        let share = self.cogging_second_harmonic_share;
        in_range(
            share,
            "cogging_second_harmonic_share",
            (0.0, 1.0),
            "must be 0 to 1",
        )?;
        if share.is_some() && amplitude.is_none() {
            return Err(("cogging_second_harmonic_share", "needs `cogging_torque_nm`"));
        }
        Ok(())
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

    /// The file's imperfections: cogging from `slots` and
    /// `cogging_torque_nm` (phase 0), the angle sensor's error (phases 0)
    /// and the dead time. Absent fields are ideal.
    pub fn imperfections(&self) -> Imperfections {
        let cogging = match (self.slots, self.cogging_torque_nm) {
            (Some(slots), Some(a)) if a > 0.0 => Some(Cogging::from_slots(
                slots,
                self.pole_pairs,
                a as Real,
                self.cogging_second_harmonic_share.unwrap_or(0.0) as Real,
            )),
            _ => None,
        };
        let first = self.sensor_first_harmonic_rad.unwrap_or(0.0) as Real;
        let second = self.sensor_second_harmonic_rad.unwrap_or(0.0) as Real;
        let sensor_error = (first > 0.0 || second > 0.0).then(|| SensorError::new(first, second));
        Imperfections {
            cogging,
            sensor_error,
            dead_time_s: self.dead_time_ns.unwrap_or(0.0) as Real * 1e-9,
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

    const IMPERFECT: &str = r#"
slots = 12
cogging_torque_nm = 0.002
cogging_second_harmonic_share = 0.3
sensor_first_harmonic_rad = 0.005
sensor_second_harmonic_rad = 0.002
dead_time_ns = 250.0
"#;

    #[test]
    fn imperfections_parse_and_apply() {
        let f = MotorFile::parse(&format!("{GOOD}{IMPERFECT}"), "i").unwrap();
        let imp = f.imperfections();
        let c = imp.cogging.unwrap();
        assert_eq!(c.cycles_per_turn, 84); // lcm(12, 14)
        assert_eq!((c.amplitude_nm, c.second_harmonic_share), (0.002, 0.3));
        let s = imp.sensor_error.unwrap();
        assert_eq!((s.first_rad, s.second_rad), (0.005, 0.002));
        assert!((imp.dead_time_s - 250e-9).abs() < 1e-15);
        // The ideal bench stays ideal; the imperfections opt in.
        let mut cfg = f.bench_config();
        assert_eq!(cfg.dead_time_s, 0.0);
        imp.apply_bench(&mut cfg);
        assert_eq!(cfg.dead_time_s, imp.dead_time_s);
        let mut plant = Plant::new(f.motor_params(), cfg);
        assert!(plant.cogging().is_none());
        imp.apply_plant(&mut plant);
        assert_eq!(plant.cogging(), Some(&c));
        assert_eq!(plant.angle_sensor_error(), Some(&s));
        // Without the fields: ideal.
        let ideal = MotorFile::parse(GOOD, "g").unwrap().imperfections();
        assert_eq!(
            ideal,
            Imperfections {
                cogging: None,
                sensor_error: None,
                dead_time_s: 0.0
            }
        );
    }

    #[test]
    fn imperfection_errors_name_the_field() {
        let full = format!("{GOOD}{IMPERFECT}");
        for (from, to, field) in [
            ("slots = 12", "slots = 0", "slots"),
            ("slots = 12", "slots = 13", "slots"),
            ("slots = 12\n", "", "cogging_torque_nm"),
            ("0.002\n", "-0.002\n", "cogging_torque_nm"),
            (
                "share = 0.3",
                "share = 1.5",
                "cogging_second_harmonic_share",
            ),
            (
                "share = 0.3",
                "share = -0.1",
                "cogging_second_harmonic_share",
            ),
            (
                "first_harmonic_rad = 0.005",
                "first_harmonic_rad = -1e-3",
                "sensor_first_harmonic_rad",
            ),
            (
                "second_harmonic_rad = 0.002",
                "second_harmonic_rad = 0.5",
                "sensor_second_harmonic_rad",
            ),
            (
                "dead_time_ns = 250.0",
                "dead_time_ns = -1.0",
                "dead_time_ns",
            ),
            (
                "dead_time_ns = 250.0",
                "dead_time_ns = 6000.0",
                "dead_time_ns",
            ),
            ("dead_time_ns = 250.0", "dead_time_ns = nan", "dead_time_ns"),
        ] {
            assert!(full.contains(from), "{from}");
            let text = full.replacen(from, to, 1);
            let e = MotorFile::parse(&text, "bad.toml").unwrap_err().to_string();
            assert!(
                e.contains("bad.toml") && e.contains(&format!("`{field}`")),
                "{from} -> {to}: {e}"
            );
        }
        // The share needs an amplitude.
        let lone = format!("{GOOD}cogging_second_harmonic_share = 0.3\n");
        let e = MotorFile::parse(&lone, "l").unwrap_err().to_string();
        assert!(e.contains("cogging_second_harmonic_share"), "{e}");
    }
}
