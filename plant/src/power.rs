//! Power-stage models of the plant: DC link (capacitor, source with a
//! resistance, a current limit and a sinking / non-sinking choice), brake
//! chopper, and first-order thermal models of the winding and of the power
//! stage. Every model is optional and off by default: a [`Plant`] without
//! them computes exactly what it computed before they existed.
//!
//! # DC link ([`DcLinkConfig`], [`Plant::set_dc_link`])
//!
//! ```text
//!  V_source --[R_source]--+--(i_source)--+------------+------------+
//!    (EMF)   (limited)    |              |            |            |
//!                       bus V          [ESR]     [R_brake]     inverter
//!                         |              |         (chopper)    i_inv
//!                         |            [ C ] v_C      |            |
//!  -----------------------+--------------+------------+------------+
//!
//!  C dv_C/dt = i_C = i_source(V) - i_inv - i_brake(V)
//!  V         = v_C + ESR i_C
//!  i_source  = clamp((V_source - V) / R_source, lo, i_source_max_a)
//!              lo = -i_source_max_a (Sinking) or 0 (NonSinking)
//!  i_brake   = V / R_brake while the chopper is on, else 0
//!  i_inv     = sum_k h_k i_k (+ an injected phase short's DC current)
//! ```
//!
//! `v_C` is integrated by the plant's RK4 together with the currents and
//! the rotor; `V` is solved from the piecewise-linear equations above at
//! every evaluation (the source current is monotonic in `V`, so the
//! unsaturated solution is tried first and the saturated one used when it
//! falls outside the limits). With `ESR = 0`, `V = v_C`.
//!
//! A `NonSinking` source (a bench supply behind a diode, a battery behind a
//! BMS that blocks charge) cannot take current back: regenerated energy
//! charges the capacitor and the bus rises above the source voltage until
//! something (the brake chopper, the drive's regen limit, the body diodes
//! once the bridge is off) stops it. A `Sinking` source (a battery) takes it
//! back through `R_source` and the bus rises only by `R_source i`.
//!
//! Stability: the source pole `1 / (R_source C)` is integrated explicitly;
//! keep `R_source C` above about one RK4 sub-step (`1 / (f_pwm substeps)`,
//! 4.2 us at 15 kHz x 16). [`DcLinkConfig::validate`] checks the parameters
//! are physical, not this.
//!
//! Energy ([`EnergyAccount`]): `source_out_j - source_in_j` (at the source
//! terminals, `V i_source`) `= capacitor_j + esr_j + brake_j + supply_j`,
//! and `supply_j` (the inverter's DC input) feeds the motor as before.
//! `source_loss_j` is what the source dissipates inside (its resistance, or
//! its regulator while current-limiting); it is not part of that balance.
//!
//! # Brake chopper
//!
//! [`DcLinkConfig::brake_resistor_ohm`] across the bus, switched by the
//! drive through [`Plant::set_brake`] (acts at once, stays until changed).
//! Without a DC link the brake command is recorded but draws nothing (the
//! ideal source absorbs any regenerated current).
//!
//! # Thermal models ([`WindingThermal`], [`StageThermal`])
//!
//! One thermal node each, `C_th dT/dt = P - (T - T_amb) / R_th`,
//! `tau = R_th C_th`, advanced once per PWM period with the period's mean
//! loss `P` (exact for a loss constant over the period:
//! `T += (T_amb + P R_th - T) (1 - exp(-T_pwm / tau))`). They start at
//! their ambient temperature.
//!
//! - Winding: `P` is the copper loss the plant integrates
//!   (`R sum_k i_k^2`). With [`WindingThermal::copper_tempco`] the phase
//!   resistance follows `R(T) = R20 (1 + 0.00393 (T - 20))`, with
//!   [`MotorParams::r_ohm`] taken as `R20`; this changes the electrical
//!   model (updated once per period).
//! - Power stage: a loss estimate only (the electrical model's switches stay
//!   ideal): per phase, while the bridge is on, conduction
//!   `i_k^2 R_ds_on` (one of the two switches of a leg always conducts;
//!   dead-time diode conduction neglected) plus switching
//!   `k_sw V_bus |i_k| f_pwm` (`k_sw = (t_rise + t_fall) / 2`, from
//!   `E_sw = V I (t_r + t_f) / 2` per period); while it is off, the body
//!   diodes conduct: `V_f |i_k|`. Evaluated at the end of every sub-step.
//!   The stage temperature is what the board's sensor (an NTC near the
//!   switches) reads: [`Measurements::stage_temperature_c`], and
//!   `BusVoltage::read_temperature_c` of the bench adapter.
//!
//! # Presets and their sources
//!
//! Values marked *assumed* were not found in a primary source and are
//! typical for the part class; change them when the real board is measured.
//!
//! - [`DcLinkConfig::odrive_v3`]: bulk capacitance 4 x 470 uF (*assumed*: the
//!   figure the issue quotes, not confirmed against the ODrive v3.6 BOM),
//!   ESR 15 mOhm total (*assumed*, four low-ESR electrolytics in parallel),
//!   brake resistor 2 Ohm (the ODrive firmware's default `brake_resistance`,
//!   the value of the power resistor supplied with the v3 boards).
//! - [`DcLinkConfig::x_nucleo_ihm07m1`]: one bulk electrolytic on VS,
//!   100 uF (*assumed*: UM1943 was not available to check), ESR 0.3 Ohm
//!   (*assumed*, general-purpose 50 V electrolytic), no brake chopper (the
//!   board has none).
//! - Sources: [`DcLinkConfig::bench_supply`] (`NonSinking`, 20 mOhm of cable
//!   and output resistance, *assumed*) and [`DcLinkConfig::battery`]
//!   (`Sinking`, no current limit).
//! - [`StageThermal::odrive_v3`]: NTMFS4C05N MOSFETs on the 24 V board (a
//!   30 V part), `R_ds_on` 3.4 mOhm (*assumed*, datasheet order at 10 V
//!   gate drive, hot), `k_sw` 20 ns, 8 K/W and 30 s to ambient
//!   (*assumed*, bare board, no heatsink).
//! - [`StageThermal::x_nucleo_ihm07m1`]: L6230 integrated DMOS bridge,
//!   `R_ds_on` 0.73 Ohm per switch (*assumed*, the L6229/L6230 family's
//!   typical figure), `k_sw` 50 ns, 20 K/W and 20 s (*assumed*, PowerSO36
//!   on the board's copper).
//! - [`WindingThermal::example`]: 4 K/W, 120 s (*assumed*, a small
//!   outrunner in still air) for [`MotorParams::example`].
//!
//! ```
//! use foc_plant::plant::{BenchConfig, MotorParams, Plant};
//! use foc_plant::power::DcLinkConfig;
//! let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
//! plant.set_dc_link(Some(DcLinkConfig::odrive_v3().bench_supply(24.0, 5.0)));
//! plant.set_speed(600.0); // spinning; regenerate into a non-sinking supply
//! for _ in 0..200 {
//!     let th = plant.theta_e_rad() as f32;
//!     // q-axis voltage at half the back-EMF: negative torque, regeneration.
//!     let vq = 0.5 * plant.omega_e_rad_s() as f32 * 0.0024;
//!     let v_bus = plant.v_bus_v() as f32;
//!     let d = [0.0f32, 1.0, 2.0].map(|k| {
//!         0.5 - vq * libm::sinf(th - k * 2.094_395_1) / v_bus
//!     });
//!     plant.step_period(d, true, 0.0);
//! }
//! assert!(plant.v_bus_v() > 24.0 + 0.5);
//! ```
//!
//! [`Plant`]: crate::plant::Plant
//! [`Plant::set_dc_link`]: crate::plant::Plant::set_dc_link
//! [`Plant::set_brake`]: crate::plant::Plant::set_brake
//! [`EnergyAccount`]: crate::plant::EnergyAccount
//! [`MotorParams::r_ohm`]: crate::plant::MotorParams::r_ohm
//! [`MotorParams::example`]: crate::plant::MotorParams::example
//! [`Measurements::stage_temperature_c`]: crate::plant::Measurements::stage_temperature_c

use crate::plant::{non_negative, positive, ParamError};
use crate::real::{self, Real};

/// Temperature coefficient of copper's resistance near 20 deg C [1/K].
pub const COPPER_TEMPCO_PER_K: Real = 0.00393;

/// Whether the DC source can take current back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SourceKind {
    /// A battery (or a two-quadrant supply): the source current may be
    /// negative, down to `-i_source_max_a`.
    Sinking,
    /// A diode-fed bench supply or a battery behind a BMS that blocks
    /// charge: the source current is `>= 0`; regenerated energy charges the
    /// capacitor.
    NonSinking,
}

/// DC link: bulk capacitor, source, optional brake resistor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DcLinkConfig {
    /// Bulk capacitance \[F\].
    pub c_f: Real,
    /// Equivalent series resistance of the bulk capacitance \[ohm\] (0: none).
    pub esr_ohm: Real,
    /// Source open-circuit voltage \[V\] (the injected `Faults::bus_sag_v`
    /// is subtracted from it).
    pub v_source_v: Real,
    /// Source resistance (internal, cables) \[ohm\], > 0.
    pub r_source_ohm: Real,
    /// Source current limit \[A\] (a bench supply's current limit; the source
    /// current saturates there, in both directions for a sinking source).
    /// `Real::INFINITY` for none.
    pub i_source_max_a: Real,
    /// Sinking or not.
    pub source: SourceKind,
    /// Brake (chopper) resistor across the bus \[ohm\], if fitted.
    pub brake_resistor_ohm: Option<Real>,
}

impl DcLinkConfig {
    /// ODrive v3.x bus: 4 x 470 uF, 15 mOhm, 2 Ohm brake resistor, fed by
    /// a 24 V, 10 A non-sinking bench supply (see the module docs for which
    /// values are assumed). Change the source with [`Self::bench_supply`] or
    /// [`Self::battery`].
    pub const fn odrive_v3() -> Self {
        Self {
            c_f: 4.0 * 470e-6,
            esr_ohm: 0.015,
            v_source_v: 24.0,
            r_source_ohm: 0.02,
            i_source_max_a: 10.0,
            source: SourceKind::NonSinking,
            brake_resistor_ohm: Some(2.0),
        }
    }

    /// X-NUCLEO-IHM07M1 bus: 100 uF, 0.3 Ohm ESR, no brake resistor, fed by
    /// a 24 V, 3 A non-sinking bench supply (values assumed, see the module
    /// docs).
    pub const fn x_nucleo_ihm07m1() -> Self {
        Self {
            c_f: 100e-6,
            esr_ohm: 0.3,
            v_source_v: 24.0,
            r_source_ohm: 0.02,
            i_source_max_a: 3.0,
            source: SourceKind::NonSinking,
            brake_resistor_ohm: None,
        }
    }

    /// The same board fed by a non-sinking bench supply of `v_source_v`
    /// with current limit `i_limit_a` (20 mOhm output and cable resistance).
    pub const fn bench_supply(self, v_source_v: Real, i_limit_a: Real) -> Self {
        Self {
            v_source_v,
            r_source_ohm: 0.02,
            i_source_max_a: i_limit_a,
            source: SourceKind::NonSinking,
            ..self
        }
    }

    /// The same board fed by a battery (sinking, no current limit) of
    /// open-circuit voltage `v_source_v` and internal resistance `r_ohm`.
    pub const fn battery(self, v_source_v: Real, r_ohm: Real) -> Self {
        Self {
            v_source_v,
            r_source_ohm: r_ohm,
            i_source_max_a: Real::INFINITY,
            source: SourceKind::Sinking,
            ..self
        }
    }

    /// Check every field is physical.
    pub fn validate(&self) -> Result<(), ParamError> {
        positive(self.c_f, "c_f")?;
        non_negative(self.esr_ohm, "esr_ohm")?;
        non_negative(self.v_source_v, "v_source_v")?;
        positive(self.r_source_ohm, "r_source_ohm")?;
        if self.i_source_max_a.is_nan() || self.i_source_max_a <= 0.0 {
            return Err(ParamError::NotPositive("i_source_max_a"));
        }
        match self.brake_resistor_ohm {
            Some(r) => positive(r, "brake_resistor_ohm"),
            None => Ok(()),
        }
    }

    /// Source current limits `(lo, hi)` \[A\].
    pub fn source_current_limits(&self) -> (Real, Real) {
        let hi = self.i_source_max_a;
        match self.source {
            SourceKind::Sinking => (-hi, hi),
            SourceKind::NonSinking => (0.0, hi),
        }
    }

    /// Energy stored at capacitor voltage `v_c` \[J\].
    pub fn capacitor_energy_j(&self, v_c: Real) -> Real {
        0.5 * self.c_f * v_c * v_c
    }
}

/// The bus at one instant.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct BusSolution {
    /// Bus (terminal) voltage \[V\].
    pub v_bus: Real,
    /// Source current into the bus \[A\].
    pub i_source: Real,
    /// Brake-resistor current \[A\].
    pub i_brake: Real,
    /// Capacitor current (charging) \[A\].
    pub i_cap: Real,
    /// Inverter DC current (legs + short) \[A\].
    pub i_inv: Real,
}

/// Solve the bus given the capacitor voltage `v_c`, the source EMF `v_src`,
/// the legs' DC current `i_dc` and the voltage-proportional loads
/// (`g_short V` drawn by the inverter, `g_brake V` by the brake).
pub(crate) fn solve_bus(
    dc: &DcLinkConfig,
    v_c: Real,
    v_src: Real,
    i_dc: Real,
    g_short: Real,
    g_brake: Real,
) -> BusSolution {
    let esr = dc.esr_ohm;
    let rs = dc.r_source_ohm;
    let g = g_short + g_brake;
    let (lo, hi) = dc.source_current_limits();
    // Unsaturated: i_s = (v_src - V) / rs.
    let mut v = (v_c + esr * (v_src / rs - i_dc)) / (1.0 + esr / rs + esr * g);
    let mut i_s = (v_src - v) / rs;
    if i_s > hi || i_s < lo {
        i_s = if i_s > hi { hi } else { lo };
        v = (v_c + esr * (i_s - i_dc)) / (1.0 + esr * g);
    }
    let i_inv = i_dc + g_short * v;
    let i_brake = g_brake * v;
    BusSolution {
        v_bus: v,
        i_source: i_s,
        i_brake,
        i_cap: i_s - i_inv - i_brake,
        i_inv,
    }
}

/// First-order thermal model of the winding.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WindingThermal {
    /// Thermal resistance winding to ambient [K/W].
    pub r_th_k_per_w: Real,
    /// Thermal time constant `R_th C_th` \[s\].
    pub tau_s: Real,
    /// Ambient temperature [deg C].
    pub ambient_c: Real,
    /// Make the phase resistance follow the winding temperature,
    /// `R(T) = R20 (1 + 0.00393 (T - 20))` (changes the electrical model).
    pub copper_tempco: bool,
}

impl WindingThermal {
    /// For [`crate::plant::MotorParams::example`]: 4 K/W, 120 s, 25 deg C,
    /// resistance tempco off (assumed values).
    pub const fn example() -> Self {
        Self {
            r_th_k_per_w: 4.0,
            tau_s: 120.0,
            ambient_c: 25.0,
            copper_tempco: false,
        }
    }

    /// Check every field is physical.
    pub fn validate(&self) -> Result<(), ParamError> {
        positive(self.r_th_k_per_w, "r_th_k_per_w")?;
        positive(self.tau_s, "tau_s")?;
        finite(self.ambient_c, "ambient_c")
    }

    /// Phase resistance at winding temperature `t_c` given `r20_ohm` at 20 deg C.
    pub fn resistance_ohm(&self, r20_ohm: Real, t_c: Real) -> Real {
        r20_ohm * (1.0 + COPPER_TEMPCO_PER_K * (t_c - 20.0))
    }
}

/// First-order thermal model of the power stage with a conduction and
/// switching loss estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageThermal {
    /// Thermal resistance switches (sensor) to ambient [K/W].
    pub r_th_k_per_w: Real,
    /// Thermal time constant \[s\].
    pub tau_s: Real,
    /// Ambient temperature [deg C].
    pub ambient_c: Real,
    /// On resistance of one switch \[ohm\].
    pub r_ds_on_ohm: Real,
    /// Switching-loss coefficient `k_sw = (t_rise + t_fall) / 2` \[s\]:
    /// `P_sw = k_sw V_bus |i| f_pwm` per phase.
    pub k_sw_s: Real,
    /// Body-diode forward drop while the bridge is off \[V\].
    pub diode_drop_v: Real,
}

impl StageThermal {
    /// ODrive v3.x (24 V board) stage, assumed values (see the module docs).
    pub const fn odrive_v3() -> Self {
        Self {
            r_th_k_per_w: 8.0,
            tau_s: 30.0,
            ambient_c: 25.0,
            r_ds_on_ohm: 3.4e-3,
            k_sw_s: 20e-9,
            diode_drop_v: 0.8,
        }
    }

    /// X-NUCLEO-IHM07M1 (L6230) stage, assumed values (see the module docs).
    pub const fn x_nucleo_ihm07m1() -> Self {
        Self {
            r_th_k_per_w: 20.0,
            tau_s: 20.0,
            ambient_c: 25.0,
            r_ds_on_ohm: 0.73,
            k_sw_s: 50e-9,
            diode_drop_v: 1.15,
        }
    }

    /// Check every field is physical.
    pub fn validate(&self) -> Result<(), ParamError> {
        positive(self.r_th_k_per_w, "r_th_k_per_w")?;
        positive(self.tau_s, "tau_s")?;
        finite(self.ambient_c, "ambient_c")?;
        non_negative(self.r_ds_on_ohm, "r_ds_on_ohm")?;
        non_negative(self.k_sw_s, "k_sw_s")?;
        non_negative(self.diode_drop_v, "diode_drop_v")
    }

    /// Stage loss \[W\] at phase currents `i_abc`, bus `v_bus`, PWM frequency
    /// `f_pwm_hz`, bridge on (`enabled`) or off (body diodes).
    pub fn loss_w(&self, i_abc: [Real; 3], v_bus: Real, f_pwm_hz: Real, enabled: bool) -> Real {
        let mut p = 0.0;
        for i in i_abc {
            let a = if i < 0.0 { -i } else { i };
            p += if enabled {
                i * i * self.r_ds_on_ohm + self.k_sw_s * v_bus * a * f_pwm_hz
            } else {
                self.diode_drop_v * a
            };
        }
        p
    }
}

/// One period of a first-order thermal node: from `t_c` with loss `p_w`
/// held for `dt_s` [deg C].
pub(crate) fn thermal_step(
    t_c: Real,
    ambient_c: Real,
    p_w: Real,
    r_th: Real,
    tau_s: Real,
    dt_s: Real,
) -> Real {
    let t_ss = ambient_c + p_w * r_th;
    t_ss + (t_c - t_ss) * real::exp(-dt_s / tau_s)
}

fn finite(x: Real, name: &'static str) -> Result<(), ParamError> {
    if x.is_finite() {
        Ok(())
    } else {
        Err(ParamError::Negative(name))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rounding of the scalar (f64, or f32 with `plant-f32`), at a few volts.
    const TOL: Real = 1e4 * Real::EPSILON;

    #[test]
    fn bus_without_esr_is_the_capacitor() {
        let dc = DcLinkConfig {
            esr_ohm: 0.0,
            ..DcLinkConfig::odrive_v3()
        };
        let b = solve_bus(&dc, 23.9, 24.0, 3.0, 0.0, 0.0);
        assert_eq!(b.v_bus, 23.9);
        assert!((b.i_source - 5.0).abs() < TOL);
        assert!((b.i_cap - 2.0).abs() < TOL);
    }

    #[test]
    fn bus_with_esr_and_limits() {
        let dc = DcLinkConfig::odrive_v3().bench_supply(24.0, 4.0);
        // Heavy load: the source saturates at 4 A, the capacitor gives the rest.
        let b = solve_bus(&dc, 23.0, 24.0, 20.0, 0.0, 0.0);
        assert_eq!(b.i_source, 4.0);
        assert!((b.v_bus - (23.0 + dc.esr_ohm * b.i_cap)).abs() < TOL);
        assert!((b.i_cap - (4.0 - 20.0)).abs() < TOL);
        // Regeneration into a non-sinking source: no source current.
        let b = solve_bus(&dc, 30.0, 24.0, -5.0, 0.0, 0.0);
        assert_eq!(b.i_source, 0.0);
        assert!(b.v_bus > 30.0);
        // Brake: i_brake = V / R.
        let b = solve_bus(&dc, 30.0, 24.0, 0.0, 0.0, 0.5);
        assert!((b.i_brake - 0.5 * b.v_bus).abs() < TOL);
        // A sinking source takes the current back.
        let dc = dc.battery(24.0, 0.05);
        let b = solve_bus(&dc, 24.5, 24.0, -5.0, 0.0, 0.0);
        assert!(b.i_source < 0.0);
    }

    #[test]
    fn copper_resistance_tempco() {
        let w = WindingThermal::example();
        assert_eq!(w.resistance_ohm(0.1, 20.0), 0.1);
        assert!((w.resistance_ohm(0.1, 120.0) - 0.1393).abs() < TOL);
    }

    #[test]
    fn presets_are_valid() {
        assert_eq!(DcLinkConfig::odrive_v3().validate(), Ok(()));
        assert_eq!(DcLinkConfig::x_nucleo_ihm07m1().validate(), Ok(()));
        assert_eq!(
            DcLinkConfig::odrive_v3().battery(48.0, 0.1).validate(),
            Ok(())
        );
        assert_eq!(WindingThermal::example().validate(), Ok(()));
        assert_eq!(StageThermal::odrive_v3().validate(), Ok(()));
        assert_eq!(StageThermal::x_nucleo_ihm07m1().validate(), Ok(()));
        let bad = DcLinkConfig {
            r_source_ohm: 0.0,
            ..DcLinkConfig::odrive_v3()
        };
        assert_eq!(bad.validate(), Err(ParamError::NotPositive("r_source_ohm")));
    }
}
