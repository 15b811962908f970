//! The motor's parameters and their checks.

use super::*;

/// Motor parameters (per phase, star equivalent, amplitude-invariant dq).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorParams {
    /// Pole pairs `p`.
    pub pole_pairs: u8,
    /// Phase resistance \[ohm\].
    pub r_ohm: Real,
    /// d-axis inductance \[H\].
    pub ld_h: Real,
    /// q-axis inductance \[H\].
    pub lq_h: Real,
    /// Permanent-magnet flux linkage `psi` \[Wb\] (peak phase back-EMF over `w_e`).
    pub flux_linkage_wb: Real,
    /// Rotor (plus load) inertia [kg m^2].
    pub inertia_kg_m2: Real,
    /// Viscous friction [N m s/rad].
    pub viscous_friction_nm_s_per_rad: Real,
    /// Coulomb (dry) friction [N m].
    pub coulomb_friction_nm: Real,
}

/// Why a parameter set was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParamError {
    /// The named field must be finite and strictly positive.
    NotPositive(&'static str),
    /// The named field must be finite and zero or positive.
    Negative(&'static str),
}

impl core::fmt::Display for ParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ParamError::NotPositive(n) => write!(f, "`{n}` must be finite and > 0"),
            ParamError::Negative(n) => write!(f, "`{n}` must be finite and >= 0"),
        }
    }
}

/// `x` finite and positive, else [`ParamError::NotPositive`] naming it.
pub(crate) fn positive(x: Real, name: &'static str) -> Result<(), ParamError> {
    if x.is_finite() && x > 0.0 {
        Ok(())
    } else {
        Err(ParamError::NotPositive(name))
    }
}

/// `x` finite and not negative, else [`ParamError::Negative`] naming it.
pub(crate) fn non_negative(x: Real, name: &'static str) -> Result<(), ParamError> {
    if x.is_finite() && x >= 0.0 {
        Ok(())
    } else {
        Err(ParamError::Negative(name))
    }
}

impl MotorParams {
    /// A small 7-pole-pair outrunner (about 0.1 ohm, 30 uH), for examples and tests.
    pub const fn example() -> Self {
        Self {
            pole_pairs: 7,
            r_ohm: 0.1,
            ld_h: 30e-6,
            lq_h: 30e-6,
            flux_linkage_wb: 0.0024,
            inertia_kg_m2: 1e-4,
            viscous_friction_nm_s_per_rad: 1e-5,
            coulomb_friction_nm: 0.0,
        }
    }

    /// Check every field is physical.
    pub fn validate(&self) -> Result<(), ParamError> {
        if self.pole_pairs == 0 {
            return Err(ParamError::NotPositive("pole_pairs"));
        }
        positive(self.r_ohm, "r_ohm")?;
        positive(self.ld_h, "ld_h")?;
        positive(self.lq_h, "lq_h")?;
        non_negative(self.flux_linkage_wb, "flux_linkage_wb")?;
        positive(self.inertia_kg_m2, "inertia_kg_m2")?;
        non_negative(
            self.viscous_friction_nm_s_per_rad,
            "viscous_friction_nm_s_per_rad",
        )?;
        non_negative(self.coulomb_friction_nm, "coulomb_friction_nm")
    }

    /// Torque `1.5 p (psi iq + (Ld - Lq) id iq)` [N m].
    pub fn torque_nm(&self, id_a: Real, iq_a: Real) -> Real {
        1.5 * self.pole_pairs as Real
            * (self.flux_linkage_wb * iq_a + (self.ld_h - self.lq_h) * id_a * iq_a)
    }
}
