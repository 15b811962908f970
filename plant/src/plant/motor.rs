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
    /// Saturation of the d axis by its own current ([`DSaturation::NONE`]:
    /// none; the salient motor files set it, HFI's polarity test reads it).
    pub d_saturation: DSaturation,
}

/// The d axis's saturation: its incremental inductance falls linearly with
/// the d current, by `fraction` of `ld_h` at `+current_a` (the current
/// adds to the magnet's flux and saturates the iron more) and rises by the
/// same at `-current_a` (it takes the magnet's flux away), flat beyond:
///
/// ```text
/// Ld_inc(id) = Ld (1 - fraction clamp(id / current_a, -1, 1))
/// psi_d(id)  = psi + integral_0^id Ld_inc(x) dx
/// ```
///
/// At `id = 0` the inductance is `ld_h`: a drive running with `id = 0`
/// sees no change. This is what a saturation test (HFI's magnet polarity)
/// relies on: a d current along the magnet meets less inductance than one
/// against it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DSaturation {
    /// Relative change of the incremental d inductance at `current_a`
    /// (0 to below 1).
    pub fraction: Real,
    /// The d current of that change \[A\] (> 0).
    pub current_a: Real,
}

impl DSaturation {
    /// No saturation.
    pub const NONE: Self = Self {
        fraction: 0.0,
        current_a: 1.0,
    };

    /// `clamp(id / current_a, -1, 1)`.
    fn share(&self, id_a: Real) -> Real {
        (id_a / self.current_a).clamp(-1.0, 1.0)
    }

    /// `integral_0^id (1 - f clamp(x / c)) dx` \[A\] (the d flux over `Ld`,
    /// less the magnet's).
    fn flux_per_h(&self, id_a: Real) -> Real {
        let (f, c) = (self.fraction, self.current_a);
        let inside = self.share(id_a) * c; // id clamped to +-c
        let beyond = id_a - inside;
        inside - f * inside * inside / (2.0 * c) - f * inside.signum() * beyond + beyond
    }

    /// `integral_0^id x (1 - f clamp(x / c)) dx` \[A^2\] (the d field's
    /// energy over `1.5 Ld`).
    fn energy_per_h(&self, id_a: Real) -> Real {
        let (f, c) = (self.fraction, self.current_a);
        let inside = self.share(id_a) * c;
        let k = 1.0 - f * inside.signum();
        inside * inside / 2.0 - f * inside * inside * inside / (3.0 * c)
            + k * (id_a * id_a - inside * inside) / 2.0
    }
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
            d_saturation: DSaturation::NONE,
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
        non_negative(self.coulomb_friction_nm, "coulomb_friction_nm")?;
        let s = self.d_saturation;
        if !(s.fraction.is_finite() && (0.0..1.0).contains(&s.fraction)) {
            return Err(ParamError::Negative("d_saturation.fraction (0 to below 1)"));
        }
        positive(s.current_a, "d_saturation.current_a")
    }

    /// The d axis's incremental inductance at `id_a` \[H\] (`ld_h` at 0;
    /// [`DSaturation`]).
    pub fn ld_incremental_h(&self, id_a: Real) -> Real {
        self.ld_h * (1.0 - self.d_saturation.fraction * self.d_saturation.share(id_a))
    }

    /// The d flux linkage at `id_a` \[Wb\]: `psi + Ld id` without saturation.
    pub fn d_flux_wb(&self, id_a: Real) -> Real {
        self.flux_linkage_wb + self.ld_h * self.d_saturation.flux_per_h(id_a)
    }

    /// The d axis's magnetic energy at `id_a` \[J\]: `0.75 Ld id^2` without
    /// saturation.
    pub fn d_energy_j(&self, id_a: Real) -> Real {
        if self.d_saturation.fraction == 0.0 {
            return 0.75 * self.ld_h * id_a * id_a;
        }
        1.5 * self.ld_h * self.d_saturation.energy_per_h(id_a)
    }

    /// Torque `1.5 p (psi_d(id) iq - Lq id iq)` [N m]: `1.5 p (psi iq + (Ld -
    /// Lq) id iq)` without saturation.
    pub fn torque_nm(&self, id_a: Real, iq_a: Real) -> Real {
        let p = 1.5 * self.pole_pairs as Real;
        if self.d_saturation.fraction == 0.0 {
            // In the order it always was (bit for bit).
            return p * (self.flux_linkage_wb * iq_a + (self.ld_h - self.lq_h) * id_a * iq_a);
        }
        p * (self.d_flux_wb(id_a) * iq_a - self.lq_h * id_a * iq_a)
    }
}
