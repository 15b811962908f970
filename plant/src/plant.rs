//! PMSM + three-phase inverter + sensors, simulated one PWM period at a time.
//!
//! This module is `no_std` (core + `libm`) so the same plant can run on an
//! emulated Cortex-M4F. Its scalar is [`Real`] (`f64`, or `f32` with the
//! `plant-f32` feature).
//!
//! # Frame (independent of `foc-core`)
//!
//! Phase A's axis is at electrical angle 0, B at +120 deg, C at +240 deg;
//! positive rotation goes A -> B -> C. The rotor d axis is at
//! `theta_e = pole_pairs * theta_m`. Phase `k` (axis angle `phi_k`) relates to
//! the rotor frame through
//!
//! ```text
//! i_k = i_d cos(theta_e - phi_k) - i_q sin(theta_e - phi_k)
//! v_d =  2/3 sum_k v_k cos(theta_e - phi_k)
//! v_q = -2/3 sum_k v_k sin(theta_e - phi_k)
//! e_k = -omega_e psi sin(theta_e - phi_k)          (open-circuit back-EMF)
//! ```
//!
//! written here with `cos(theta - 2 pi/3)` sums, never through
//! `foc_core::transforms`, so a frame error on either side shows up in a
//! closed-loop test. Zero-sequence voltage (the floating star point) drops out
//! of the sums by construction.
//!
//! # Model
//!
//! - Electrical: `Ld did/dt = vd - R id + w_e Lq iq`,
//!   `Lq diq/dt = vq - R iq - w_e Ld id - w_e psi`.
//! - Torque: `Te = 1.5 p (psi iq + (Ld - Lq) id iq)`.
//! - Mechanical: `J dw/dt = Te - B w - Tc sgn(w) - T_load`, with stiction
//!   (the rotor stays stopped while `|Te - T_load| <= Tc`). Or [`Mechanics`]
//!   `Locked` / `ConstantSpeed` for tests.
//! - Integration: classic RK4 at [`BenchConfig::substeps`] sub-steps per PWM
//!   period, terminal voltages held over each sub-step.
//! - Inverter: each phase terminal is connected to the bus for a fraction `h`
//!   of the sub-step (`v_k = h V_bus`). [`PwmMode::Averaged`] uses the
//!   period-average fraction in every sub-step; [`PwmMode::CarrierCompared`]
//!   compares with a centre-aligned triangle carrier and uses the exact overlap
//!   of the switch intervals with each sub-step (so ripple is resolved at
//!   sub-step resolution and duty is not quantised to sub-steps).
//!   Carrier: the high-side pulse of width `d T` is centred in the period;
//!   the period boundary (where [`Plant::step_period`] samples) is the centre
//!   of the zero vector 000 (all low sides on).
//! - Dead time `t_d`: each rising edge (of high and low side) is delayed by
//!   `t_d`; during the dead interval the phase follows its current through the
//!   body diodes: low (0 V) when the current flows into the motor (`i > 0`),
//!   bus when `i < 0`. The sign is taken at the start of each sub-step. The
//!   average error is `-sgn(i) V_bus t_d / T`.
//! - Computation delay: with `compute_delay_periods = 1` (default) the duties
//!   passed to [`Plant::step_period`] are applied in the *next* period, as a
//!   timer's shadow compare registers do. Enable/disable acts at once.
//! - Disabled bridge (all six switches off): each phase is modelled by its two
//!   body diodes (no forward drop): a phase carrying current conducts through
//!   the diode its current sign selects until the current reaches zero, then
//!   it is open. With one phase open the remaining two carry equal and opposite
//!   currents (the open phase's terminal voltage is solved from `di/dt = 0`);
//!   with two open no current flows. An open phase starts conducting again only
//!   when its terminal voltage would leave `[0, V_bus]`, and with all three
//!   open, only when the line-to-line back-EMF exceeds `V_bus`: below the bus
//!   the back-EMF cannot drive current, above it the bridge rectifies and brakes.
//! - DC source (default): `V_bus = V_source - bus_sag - R_source i_dc`, where
//!   `i_dc = sum_k h_k i_k` is the (sub-step average) supply current. Regenerated
//!   current is absorbed by the source (no capacitor, no over-voltage).
//! - DC link (optional, [`Plant::set_dc_link`]): a bulk capacitor whose voltage
//!   is integrated with the rest of the state, fed by a resistive,
//!   current-limited, sinking or non-sinking source, with an optional brake
//!   chopper ([`Plant::set_brake`]): see [`crate::power`].
//! - Thermal models (optional, [`Plant::set_winding_thermal`],
//!   [`Plant::set_stage_thermal`]): winding and power-stage temperatures fed
//!   by the copper and switch losses; the winding's can make the phase
//!   resistance follow its temperature. See [`crate::power`].
//! - Sensors: see [`SensorConfig`] and [`Faults`].
//!
//! ```
//! use foc_plant::plant::{BenchConfig, MotorParams, Plant};
//! let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
//! let mut duties = [0.5f32; 3];
//! for _ in 0..10 {
//!     let m = plant.step_period(duties, true, 0.0);
//!     assert!(m.v_bus_v > 0.0);
//!     duties = [0.5, 0.5, 0.5]; // a controller would compute these from `m`
//! }
//! assert!(plant.time_s() > 0.0);
//! ```

// Loops over the three phases index several parallel arrays.
#![allow(clippy::needless_range_loop)]

use crate::power::{self, BusSolution, DcLinkConfig, StageThermal, WindingThermal};
use crate::real::{self, Real, TAU, TWO_PI_3};
use crate::rng::Rng;
use foc_core::angle::{ElectricalAngle, MechanicalAngle};
use foc_core::frames::Abc;
use foc_core::hal::PhaseCurrents;

/// Axis angles of phases A, B, C.
const PHASE_AXIS: [Real; 3] = [0.0, TWO_PI_3, -TWO_PI_3];

/// A current below this is zero for the diode model [A].
const I_ZERO_A: Real = 1e-9;

/// One of the three phases.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Phase A.
    A,
    /// Phase B.
    B,
    /// Phase C.
    C,
}

impl Phase {
    /// Index 0, 1, 2.
    pub const fn index(self) -> usize {
        match self {
            Phase::A => 0,
            Phase::B => 1,
            Phase::C => 2,
        }
    }
}

/// Motor parameters (per phase, star equivalent, amplitude-invariant dq).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorParams {
    /// Pole pairs `p`.
    pub pole_pairs: u8,
    /// Phase resistance [ohm].
    pub r_ohm: Real,
    /// d-axis inductance [H].
    pub ld_h: Real,
    /// q-axis inductance [H].
    pub lq_h: Real,
    /// Permanent-magnet flux linkage `psi` [Wb] (peak phase back-EMF over `w_e`).
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

/// How the inverter output is modelled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PwmMode {
    /// Period-average terminal voltage in every sub-step (no ripple).
    Averaged,
    /// Centre-aligned triangle carrier compared per sub-step (ripple resolved).
    CarrierCompared,
}

/// Current-shunt arrangement.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shunts {
    /// Phases A and B measured ([`PhaseCurrents::TwoPhase`]).
    Two,
    /// All three measured ([`PhaseCurrents::ThreePhase`]).
    Three,
}

/// Sensor models.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorConfig {
    /// ADC resolution [bits] (12 on an STM32F4).
    pub adc_bits: u8,
    /// Current ADC range: `-fs .. +fs` maps to `0 .. 2^bits - 1` [A].
    pub current_full_scale_a: Real,
    /// Current-ADC noise, RMS [LSB].
    pub current_noise_lsb_rms: Real,
    /// Hardware offset of each current channel [A] (what calibration removes).
    pub current_offset_a: [Real; 3],
    /// Shunt arrangement.
    pub shunts: Shunts,
    /// Encoder counts per mechanical revolution.
    pub encoder_counts_per_rev: u32,
    /// Encoder zero relative to the rotor d axis (mechanical) [rad].
    pub encoder_offset_rad: Real,
    /// Bus-voltage ADC range `0 .. fs` [V].
    pub bus_full_scale_v: Real,
    /// Bus-voltage ADC noise, RMS [LSB].
    pub bus_noise_lsb_rms: Real,
    /// Seed of the noise generator.
    pub seed: u64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            adc_bits: 12,
            current_full_scale_a: 60.0,
            current_noise_lsb_rms: 0.0,
            current_offset_a: [0.0; 3],
            shunts: Shunts::Three,
            encoder_counts_per_rev: 16_384,
            encoder_offset_rad: 0.0,
            bus_full_scale_v: 72.0,
            bus_noise_lsb_rms: 0.0,
            seed: 1,
        }
    }
}

impl SensorConfig {
    /// Ideal sensors: 24-bit ADCs, no noise, 2^24-count encoder.
    pub fn ideal() -> Self {
        Self {
            adc_bits: 24,
            current_full_scale_a: 1000.0,
            encoder_counts_per_rev: 1 << 24,
            bus_full_scale_v: 1000.0,
            ..Self::default()
        }
    }
}

/// What the rotor angle sensor reads relative to the rotor (chosen with
/// [`Plant::set_angle_sensor`]; [`SensorConfig::encoder_offset_rad`] and the
/// encoder faults apply on top, in both cases).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AngleSensorKind {
    /// A counting encoder: reads 0 at power-on ([`Plant::new`],
    /// [`Plant::start_rotor_at`]) wherever the rotor is, and counts the
    /// rotor's motion from there. The default.
    Incremental,
    /// An absolute sensor (AS5047P-like): reads the true mechanical angle
    /// minus a fixed mounting offset from the first sample.
    Absolute {
        /// Mechanical angle of the rotor at which the sensor reads 0 [rad].
        mounting_offset_rad: Real,
    },
}

/// Inverter, supply and timing configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BenchConfig {
    /// PWM frequency [Hz] (one control period per PWM period).
    pub pwm_frequency_hz: Real,
    /// RK4 sub-steps per PWM period (8..32 typical).
    pub substeps: u32,
    /// DC source open-circuit voltage [V].
    pub bus_voltage_v: Real,
    /// DC source internal resistance [ohm] (the bus sags under load).
    pub source_resistance_ohm: Real,
    /// Dead time per switching edge [s].
    pub dead_time_s: Real,
    /// Inverter model.
    pub pwm_mode: PwmMode,
    /// Periods between the sample and the application of the duties (0 or 1).
    pub compute_delay_periods: u8,
    /// Sensor models.
    pub sensors: SensorConfig,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            pwm_frequency_hz: 15_000.0,
            substeps: 16,
            bus_voltage_v: 24.0,
            source_resistance_ohm: 0.0,
            dead_time_s: 0.0,
            pwm_mode: PwmMode::Averaged,
            compute_delay_periods: 1,
            sensors: SensorConfig::default(),
        }
    }
}

impl BenchConfig {
    /// PWM period [s].
    pub fn period_s(&self) -> Real {
        1.0 / self.pwm_frequency_hz
    }
}

/// A short between two motor terminals (through `r_ohm`, switches included).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseShort {
    /// First phase.
    pub a: Phase,
    /// Second phase.
    pub b: Phase,
    /// Resistance of the short [ohm].
    pub r_ohm: Real,
}

/// Encoder fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum EncoderFault {
    /// Healthy.
    #[default]
    None,
    /// The reading freezes at its last value.
    Stuck,
    /// The reading is offset by this many counts (set it once: a jump).
    Jump(i32),
}

/// Fault injection hooks (all off by default). Change them any time through
/// [`Plant::faults_mut`]; they act from the next sub-step / sample.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Faults {
    /// Phase-to-phase short at the motor terminals. The two terminals see the
    /// mean of their two bridge voltages; the legs carry the extra current
    /// `(v_a - v_b) / r_ohm` (measured by the shunts, drawn from the bus).
    pub phase_short: Option<PhaseShort>,
    /// A phase lead disconnected (its current is zero; the others carry all).
    pub disconnected_phase: Option<Phase>,
    /// Drop of the source voltage [V].
    pub bus_sag_v: Real,
    /// Encoder fault.
    pub encoder: EncoderFault,
    /// Encoder counts the wrong way.
    pub encoder_reversed: bool,
    /// This current channel reads NaN.
    pub nan_current: Option<Phase>,
    /// This current channel is wired with the wrong sign.
    pub current_reversed: Option<Phase>,
    /// Extra offset on each current channel, e.g. after calibration [A].
    pub current_offset_error_a: [Real; 3],
}

/// What the controller samples at the period boundary (centre of the zero
/// vector 000).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measurements {
    /// Phase currents [A] as the ADC reads them (quantised, noisy, with the
    /// hardware offsets: offset calibration is the controller's job).
    pub currents: PhaseCurrents,
    /// Encoder reading.
    pub angle: MechanicalAngle,
    /// Bus voltage [V] as the ADC reads it.
    pub v_bus_v: f32,
    /// Power-stage temperature [deg C] as the board's sensor reads it: `Some`
    /// only with the stage thermal model ([`Plant::set_stage_thermal`]).
    /// The bench feeds it to the drive as `Sample::temperature_c` (the bench
    /// adapter's `BusVoltage::read_temperature_c` returns it).
    pub stage_temperature_c: Option<f32>,
    /// Time of the sample [s].
    pub time_s: f64,
    /// Index of the period that just ended (0 for the first).
    pub period: u64,
}

/// Energy integrals since construction (or [`Plant::reset_energy`]) [J].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct EnergyAccount {
    /// Delivered by the DC bus to the inverter (`V_bus i_dc`).
    pub supply_j: Real,
    /// Dissipated in the winding resistance.
    pub copper_j: Real,
    /// Converted to mechanical (`Te w`).
    pub shaft_j: Real,
    /// Dissipated in viscous and coulomb friction.
    pub friction_j: Real,
    /// Delivered to the load torque (`T_load w`).
    pub load_j: Real,
    /// Dissipated in an injected phase short.
    pub short_j: Real,
    /// DC link only (zero without): delivered by the source at its
    /// terminals, `V_bus i_source` while `i_source > 0`.
    pub source_out_j: Real,
    /// DC link only: returned into the source, `-V_bus i_source` while
    /// `i_source < 0` (a sinking source).
    pub source_in_j: Real,
    /// DC link only: dissipated inside the source, `(V_source - V_bus)
    /// i_source` (its resistance, or its regulator while current-limiting).
    pub source_loss_j: Real,
    /// DC link only: into the capacitor, `v_C i_C` (the change of
    /// `C v_C^2 / 2`, see [`Plant::capacitor_energy_j`]).
    pub capacitor_j: Real,
    /// DC link only: dissipated in the capacitor's ESR.
    pub esr_j: Real,
    /// DC link only: dissipated in the brake resistor.
    pub brake_j: Real,
}

/// How the rotor moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mechanics {
    /// Free rotor: inertia, friction, load.
    Free,
    /// Rotor held at its present angle (locked-rotor tests).
    Locked,
    /// Rotor driven at this mechanical speed [rad/s] (infinite inertia).
    ConstantSpeed(Real),
}

/// Per-phase state of the bridge while it is disabled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Diode {
    /// Not conducting.
    Open,
    /// High-side diode (terminal at the bus, current out of the motor).
    High,
    /// Low-side diode (terminal at 0 V, current into the motor).
    Low,
}

/// How one phase terminal is driven over a sub-step.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Leg {
    /// Connected to the bus a fraction `h` of the time, else to 0 V.
    Bus(Real),
    /// Not connected (current held at zero).
    Open,
}

/// Derivative of the integrated state and its energy integrands.
#[derive(Clone, Copy, Debug, Default)]
struct Deriv {
    id: Real,
    iq: Real,
    omega: Real,
    theta: Real,
    p_supply: Real,
    p_copper: Real,
    p_shaft: Real,
    p_friction: Real,
    p_load: Real,
    p_short: Real,
    i_dc: Real,
    /// Capacitor voltage derivative (DC link only).
    v_cap: Real,
    /// Power at the source terminals `V i_source`.
    p_source: Real,
    /// Power dissipated inside the source.
    p_source_loss: Real,
    /// Power into the capacitor `v_C i_C`.
    p_cap: Real,
    /// Power in the ESR.
    p_esr: Real,
    /// Power in the brake resistor.
    p_brake: Real,
    i_source: Real,
    i_brake: Real,
}

/// What one sub-step integrated.
#[derive(Clone, Copy, Debug, Default)]
struct SubstepOut {
    e_in: Real,
    q_dc: Real,
    vt: [Real; 3],
    copper_j: Real,
    q_source: Real,
    q_brake: Real,
}

/// The simulated motor, inverter and sensors.
#[derive(Clone, Debug)]
pub struct Plant {
    motor: MotorParams,
    cfg: BenchConfig,
    faults: Faults,
    mechanics: Mechanics,
    rng: Rng,
    // Electrical and mechanical state.
    id: Real,
    iq: Real,
    theta_m: Real,
    turns: i64,
    omega_m: Real,
    // Inverter.
    pending: [f32; 3],
    applied: [f32; 3],
    enabled: bool,
    diodes: [Diode; 3],
    // Outputs of the last period.
    v_bus: Real,
    v_bus_avg: Real,
    i_dc_avg: Real,
    p_in_avg: Real,
    v_terminal_avg: [Real; 3],
    load_nm: Real,
    last_encoder_counts: u32,
    /// Sensor model.
    angle_sensor: AngleSensorKind,
    /// Mechanical angle at which the sensor reads 0 (before
    /// `encoder_offset_rad`) [rad]: the power-on angle of an incremental
    /// encoder, the mounting offset of an absolute sensor.
    sensor_zero_m_rad: Real,
    time_s: f64,
    period: u64,
    energy: EnergyAccount,
    // Power stage (all optional, off by default).
    dc_link: Option<DcLinkConfig>,
    /// Capacitor voltage [V] (the state; the bus when there is no DC link
    /// is not a state).
    v_cap: Real,
    brake_on: bool,
    i_source_avg: Real,
    i_brake_avg: Real,
    winding_thermal: Option<WindingThermal>,
    t_winding_c: Real,
    stage_thermal: Option<StageThermal>,
    t_stage_c: Real,
}

impl Plant {
    /// New plant at rest (rotor at `theta_m = 0`, currents zero, bridge off).
    ///
    /// Parameters are used as given; call [`MotorParams::validate`] first
    /// when they come from a user.
    pub fn new(motor: MotorParams, cfg: BenchConfig) -> Self {
        Self {
            motor,
            cfg,
            faults: Faults::default(),
            mechanics: Mechanics::Free,
            rng: Rng::new(cfg.sensors.seed),
            id: 0.0,
            iq: 0.0,
            theta_m: 0.0,
            turns: 0,
            omega_m: 0.0,
            pending: [0.5; 3],
            applied: [0.5; 3],
            enabled: false,
            diodes: [Diode::Open; 3],
            v_bus: cfg.bus_voltage_v,
            v_bus_avg: cfg.bus_voltage_v,
            i_dc_avg: 0.0,
            p_in_avg: 0.0,
            v_terminal_avg: [0.0; 3],
            load_nm: 0.0,
            last_encoder_counts: 0,
            angle_sensor: AngleSensorKind::Incremental,
            sensor_zero_m_rad: 0.0,
            time_s: 0.0,
            period: 0,
            energy: EnergyAccount::default(),
            dc_link: None,
            v_cap: cfg.bus_voltage_v,
            brake_on: false,
            i_source_avg: 0.0,
            i_brake_avg: 0.0,
            winding_thermal: None,
            t_winding_c: 20.0,
            stage_thermal: None,
            t_stage_c: 20.0,
        }
    }

    /// Motor parameters.
    pub fn motor(&self) -> &MotorParams {
        &self.motor
    }
    /// Bench configuration.
    pub fn config(&self) -> &BenchConfig {
        &self.cfg
    }
    /// Change the bench configuration (e.g. the source voltage) on the fly.
    pub fn config_mut(&mut self) -> &mut BenchConfig {
        &mut self.cfg
    }
    /// Injected faults.
    pub fn faults(&self) -> &Faults {
        &self.faults
    }
    /// Inject or clear faults.
    pub fn faults_mut(&mut self) -> &mut Faults {
        &mut self.faults
    }
    /// Choose free, locked or constant-speed mechanics.
    pub fn set_mechanics(&mut self, m: Mechanics) {
        self.mechanics = m;
        match m {
            Mechanics::Free => {}
            Mechanics::Locked => self.omega_m = 0.0,
            Mechanics::ConstantSpeed(w) => self.omega_m = w,
        }
    }
    /// Start the rotor at mechanical angle `theta_m_rad` [rad] as at
    /// power-on: position counted from here (no turns), and an incremental
    /// encoder reads 0 here. An absolute sensor keeps its mounting offset.
    pub fn start_rotor_at(&mut self, theta_m_rad: Real) {
        let (r, _) = real::wrap_tau(theta_m_rad);
        self.theta_m = r;
        self.turns = 0;
        if self.angle_sensor == AngleSensorKind::Incremental {
            self.sensor_zero_m_rad = r;
        }
    }
    /// Choose the angle sensor. [`AngleSensorKind::Incremental`] reads 0 at
    /// the rotor's present angle (as if the drive had just been powered on);
    /// [`AngleSensorKind::Absolute`] reads `theta_m - mounting_offset_rad`.
    pub fn set_angle_sensor(&mut self, kind: AngleSensorKind) {
        self.angle_sensor = kind;
        self.sensor_zero_m_rad = match kind {
            AngleSensorKind::Incremental => self.theta_m,
            AngleSensorKind::Absolute {
                mounting_offset_rad,
            } => mounting_offset_rad,
        };
    }
    /// The angle sensor model.
    pub fn angle_sensor(&self) -> AngleSensorKind {
        self.angle_sensor
    }
    /// Put the rotor at mechanical angle `theta_m` [rad] (a jump: an
    /// incremental encoder counts it, see [`Plant::start_rotor_at`]).
    pub fn set_rotor_angle(&mut self, theta_m_rad: Real) {
        let (r, _) = real::wrap_tau(theta_m_rad);
        self.theta_m = r;
    }
    /// Set the rotor speed [rad/s] (free mechanics keeps evolving from it).
    pub fn set_speed(&mut self, omega_m_rad_s: Real) {
        self.omega_m = omega_m_rad_s;
    }
    /// Set the dq currents directly [A] (initial conditions for tests).
    pub fn set_currents_dq(&mut self, id_a: Real, iq_a: Real) {
        self.id = id_a;
        self.iq = iq_a;
    }

    // ----- true state -----

    /// True d-axis current [A].
    pub fn id_a(&self) -> Real {
        self.id
    }
    /// True q-axis current [A].
    pub fn iq_a(&self) -> Real {
        self.iq
    }
    /// True phase currents [A] (into the motor).
    pub fn phase_currents_a(&self) -> [Real; 3] {
        let th = self.theta_e_rad();
        let (id, iq) = (self.id, self.iq);
        PHASE_AXIS.map(|phi| id * real::cos(th - phi) - iq * real::sin(th - phi))
    }
    /// True electrical angle [rad] in `[0, 2 pi)`.
    pub fn theta_e_rad(&self) -> Real {
        real::wrap_tau(self.theta_m * self.motor.pole_pairs as Real).0
    }
    /// True electrical angle.
    pub fn theta_e(&self) -> ElectricalAngle {
        ElectricalAngle::from_radians(self.theta_e_rad() as f32)
    }
    /// True mechanical angle [rad] in `[0, 2 pi)`.
    pub fn theta_m_rad(&self) -> Real {
        self.theta_m
    }
    /// True mechanical position over many turns [rad].
    pub fn position_rad(&self) -> Real {
        self.turns as Real * TAU + self.theta_m
    }
    /// True mechanical speed [rad/s].
    pub fn omega_m_rad_s(&self) -> Real {
        self.omega_m
    }
    /// True electrical speed [rad/s].
    pub fn omega_e_rad_s(&self) -> Real {
        self.omega_m * self.motor.pole_pairs as Real
    }
    /// Electromagnetic torque at the present currents [N m].
    pub fn torque_nm(&self) -> Real {
        self.motor.torque_nm(self.id, self.iq)
    }
    /// Bus voltage at the end of the last sub-step [V].
    pub fn v_bus_v(&self) -> Real {
        self.v_bus
    }
    /// Bus voltage averaged over the sub-steps of the last period [V].
    ///
    /// Without a DC link ([`Plant::set_dc_link`]) there is no capacitor: with
    /// a source resistance and carrier-compared PWM the instantaneous bus
    /// voltage (and so the sampled one) moves with the switching state.
    pub fn v_bus_avg_v(&self) -> Real {
        self.v_bus_avg
    }
    /// Supply (DC) current averaged over the last period [A]: the
    /// inverter's DC input (legs and an injected short), see
    /// [`Plant::inverter_current_a`].
    pub fn supply_current_a(&self) -> Real {
        self.i_dc_avg
    }
    /// Inverter DC input current averaged over the last period [A]
    /// (`sum_k h_k i_k` plus an injected short's; negative while
    /// regenerating). The same as [`Plant::supply_current_a`].
    pub fn inverter_current_a(&self) -> Real {
        self.i_dc_avg
    }
    /// Source current into the bus averaged over the last period [A]. With
    /// a DC link it differs from the inverter's by the capacitor and brake
    /// currents; without, it is the inverter's.
    pub fn source_current_a(&self) -> Real {
        match self.dc_link {
            Some(_) => self.i_source_avg,
            None => self.i_dc_avg,
        }
    }
    /// Brake-resistor current averaged over the last period [A].
    pub fn brake_current_a(&self) -> Real {
        self.i_brake_avg
    }
    /// Input power `V_bus i_dc` averaged over the last period [W].
    pub fn input_power_w(&self) -> Real {
        self.p_in_avg
    }
    /// Mechanical output power at the shaft `Te w` [W] (before friction).
    pub fn shaft_power_w(&self) -> Real {
        self.torque_nm() * self.omega_m
    }
    /// Terminal voltages (to the bus minus rail) averaged over the last period [V].
    pub fn terminal_voltages_avg_v(&self) -> [Real; 3] {
        self.v_terminal_avg
    }
    /// Magnetic energy stored in the windings, `0.75 (Ld id^2 + Lq iq^2)` [J].
    pub fn magnetic_energy_j(&self) -> Real {
        0.75 * (self.motor.ld_h * self.id * self.id + self.motor.lq_h * self.iq * self.iq)
    }
    /// Kinetic energy `J w^2 / 2` [J].
    pub fn kinetic_energy_j(&self) -> Real {
        0.5 * self.motor.inertia_kg_m2 * self.omega_m * self.omega_m
    }
    /// Energy integrals.
    pub fn energy(&self) -> &EnergyAccount {
        &self.energy
    }
    /// Zero the energy integrals.
    pub fn reset_energy(&mut self) {
        self.energy = EnergyAccount::default();
    }
    /// Simulated time [s].
    pub fn time_s(&self) -> f64 {
        self.time_s
    }
    /// Periods simulated so far.
    pub fn periods(&self) -> u64 {
        self.period
    }
    /// Duties applied during the last period.
    pub fn applied_duties(&self) -> [f32; 3] {
        self.applied
    }
    /// True when the bridge was enabled during the last period.
    pub fn bridge_enabled(&self) -> bool {
        self.enabled
    }

    // ----- power stage -----

    /// Add (`Some`) or remove (`None`) the DC link of [`crate::power`]. The
    /// capacitor starts charged to the source voltage (after the injected
    /// sag); see [`Plant::set_capacitor_voltage`]. Parameters are used as
    /// given; call [`DcLinkConfig::validate`] first when they come from a
    /// user. Without a DC link (the default) the bus is the resistive source
    /// of [`BenchConfig`]; with one, [`BenchConfig::bus_voltage_v`] and
    /// [`BenchConfig::source_resistance_ohm`] are not used (the link's
    /// `v_source_v` and `r_source_ohm` are), and [`Plant::v_bus_v`] is the
    /// voltage at the capacitor's terminals (`v_C` plus the ESR drop).
    pub fn set_dc_link(&mut self, dc: Option<DcLinkConfig>) {
        self.dc_link = dc;
        if let Some(d) = dc {
            self.v_cap = d.v_source_v - self.faults.bus_sag_v;
            self.v_bus = self.v_cap;
            self.v_bus_avg = self.v_cap;
        }
    }
    /// The DC link, if any.
    pub fn dc_link(&self) -> Option<&DcLinkConfig> {
        self.dc_link.as_ref()
    }
    /// Change the DC link's parameters (e.g. the source voltage) on the fly.
    pub fn dc_link_mut(&mut self) -> Option<&mut DcLinkConfig> {
        self.dc_link.as_mut()
    }
    /// Set the capacitor voltage [V] (an initial condition; DC link only).
    pub fn set_capacitor_voltage(&mut self, v: Real) {
        if self.dc_link.is_some() {
            self.v_cap = v;
        }
    }
    /// Capacitor voltage [V] (DC link only; without, the source voltage).
    pub fn capacitor_voltage_v(&self) -> Real {
        match self.dc_link {
            Some(_) => self.v_cap,
            None => self.source_v(),
        }
    }
    /// Energy stored in the capacitor `C v_C^2 / 2` [J] (0 without a DC link).
    pub fn capacitor_energy_j(&self) -> Real {
        match &self.dc_link {
            Some(d) => d.capacitor_energy_j(self.v_cap),
            None => 0.0,
        }
    }
    /// Switch the brake chopper (acts at once; draws `V / R` while on, with
    /// a DC link that has a brake resistor).
    pub fn set_brake(&mut self, on: bool) {
        self.brake_on = on;
    }
    /// The brake chopper's command.
    pub fn brake_on(&self) -> bool {
        self.brake_on
    }
    /// Energy dissipated in the brake resistor [J] (also in [`Plant::energy`]).
    pub fn brake_energy_j(&self) -> Real {
        self.energy.brake_j
    }

    /// Add or remove the winding thermal model; the winding starts at its
    /// ambient temperature.
    pub fn set_winding_thermal(&mut self, w: Option<WindingThermal>) {
        self.winding_thermal = w;
        if let Some(w) = w {
            self.t_winding_c = w.ambient_c;
        }
    }
    /// The winding thermal model, if any.
    pub fn winding_thermal(&self) -> Option<&WindingThermal> {
        self.winding_thermal.as_ref()
    }
    /// Set the winding temperature [deg C] (an initial condition).
    pub fn set_winding_temperature_c(&mut self, t_c: Real) {
        self.t_winding_c = t_c;
    }
    /// Winding temperature [deg C] (`None` without the model).
    pub fn winding_temperature_c(&self) -> Option<Real> {
        self.winding_thermal.map(|_| self.t_winding_c)
    }
    /// Phase resistance in use [ohm]: [`MotorParams::r_ohm`], or its value
    /// at the winding temperature when the model's `copper_tempco` is on.
    pub fn winding_resistance_ohm(&self) -> Real {
        match self.winding_thermal {
            Some(w) if w.copper_tempco => w.resistance_ohm(self.motor.r_ohm, self.t_winding_c),
            _ => self.motor.r_ohm,
        }
    }
    /// Add or remove the power-stage thermal model; the stage starts at its
    /// ambient temperature. With it, [`Measurements::stage_temperature_c`]
    /// is `Some`.
    pub fn set_stage_thermal(&mut self, s: Option<StageThermal>) {
        self.stage_thermal = s;
        if let Some(s) = s {
            self.t_stage_c = s.ambient_c;
        }
    }
    /// The power-stage thermal model, if any.
    pub fn stage_thermal(&self) -> Option<&StageThermal> {
        self.stage_thermal.as_ref()
    }
    /// Set the power-stage temperature [deg C] (an initial condition).
    pub fn set_stage_temperature_c(&mut self, t_c: Real) {
        self.t_stage_c = t_c;
    }
    /// Power-stage temperature [deg C] (`None` without the model).
    pub fn stage_temperature_c(&self) -> Option<Real> {
        self.stage_thermal.map(|_| self.t_stage_c)
    }

    // ----- stepping -----

    /// Simulate one PWM period and return what the controller samples at its end.
    ///
    /// `duties` (high-side on fraction per phase, clamped to `[0, 1]`, NaN
    /// centred) take effect after [`BenchConfig::compute_delay_periods`];
    /// `bridge_enabled = false` puts the bridge in high impedance at once.
    /// `load_torque_nm` opposes positive rotation.
    pub fn step_period(
        &mut self,
        duties: [f32; 3],
        bridge_enabled: bool,
        load_torque_nm: f32,
    ) -> Measurements {
        let clean = duties.map(|d| {
            if d.is_finite() {
                d.clamp(0.0, 1.0)
            } else {
                0.5
            }
        });
        if self.cfg.compute_delay_periods == 0 {
            self.applied = clean;
        } else {
            self.applied = self.pending;
            self.pending = clean;
        }
        if bridge_enabled != self.enabled {
            self.diodes = [Diode::Open; 3];
        }
        self.enabled = bridge_enabled;
        self.load_nm = load_torque_nm as Real;

        let n = self.cfg.substeps.max(1);
        let t_period = self.cfg.period_s();
        let dt = t_period / n as Real;
        let mut e_in = 0.0;
        let mut q_dc = 0.0;
        let mut v_term = [0.0; 3];
        let mut v_bus_sum = 0.0;
        let (mut e_copper, mut q_source, mut q_brake, mut p_stage_sum) = (0.0, 0.0, 0.0, 0.0);
        for j in 0..n {
            let u0 = j as Real / n as Real;
            let u1 = (j + 1) as Real / n as Real;
            let out = self.substep(u0, u1, dt);
            e_in += out.e_in;
            q_dc += out.q_dc;
            v_bus_sum += self.v_bus;
            for k in 0..3 {
                v_term[k] += out.vt[k] / n as Real;
            }
            e_copper += out.copper_j;
            q_source += out.q_source;
            q_brake += out.q_brake;
            if let Some(st) = &self.stage_thermal {
                p_stage_sum += st.loss_w(
                    self.phase_currents_a(),
                    self.v_bus,
                    self.cfg.pwm_frequency_hz,
                    self.enabled,
                );
            }
        }
        self.v_bus_avg = v_bus_sum / n as Real;
        self.p_in_avg = e_in / t_period;
        self.i_dc_avg = q_dc / t_period;
        self.v_terminal_avg = v_term;
        if self.dc_link.is_some() {
            self.i_source_avg = q_source / t_period;
            self.i_brake_avg = q_brake / t_period;
        }
        if let Some(w) = self.winding_thermal {
            self.t_winding_c = power::thermal_step(
                self.t_winding_c,
                w.ambient_c,
                e_copper / t_period,
                w.r_th_k_per_w,
                w.tau_s,
                t_period,
            );
        }
        if let Some(st) = self.stage_thermal {
            self.t_stage_c = power::thermal_step(
                self.t_stage_c,
                st.ambient_c,
                p_stage_sum / n as Real,
                st.r_th_k_per_w,
                st.tau_s,
                t_period,
            );
        }
        self.time_s += t_period as f64;
        let m = self.sample();
        self.period += 1;
        m
    }

    /// Drive of each phase over the sub-step `[u0, u1]` (fractions of the period).
    fn drives(&self, u0: Real, u1: Real, i_abc: [Real; 3]) -> [Leg; 3] {
        let mut out = [Leg::Open; 3];
        let delta = self.cfg.dead_time_s * self.cfg.pwm_frequency_hz;
        for k in 0..3 {
            out[k] = if self.enabled {
                let (a, b) = match self.cfg.pwm_mode {
                    PwmMode::Averaged => (0.0, 1.0),
                    PwmMode::CarrierCompared => (u0, u1),
                };
                let (high, low) = phase_fractions(self.applied[k] as Real, delta, a, b);
                let dead = (b - a) - high - low;
                let dead_high = if i_abc[k] > 0.0 {
                    0.0
                } else if i_abc[k] < 0.0 {
                    dead
                } else {
                    0.5 * dead
                };
                Leg::Bus((high + dead_high) / (b - a))
            } else {
                match self.diodes[k] {
                    Diode::Open => Leg::Open,
                    Diode::High => Leg::Bus(1.0),
                    Diode::Low => Leg::Bus(0.0),
                }
            };
        }
        if let Some(p) = self.faults.disconnected_phase {
            out[p.index()] = Leg::Open;
        }
        out
    }

    /// One RK4 sub-step.
    fn substep(&mut self, u0: Real, u1: Real, dt: Real) -> SubstepOut {
        let i_abc = self.phase_currents_a();
        if !self.enabled {
            self.update_diodes(i_abc);
        }
        let drives = self.drives(u0, u1, i_abc);
        let open = drives.iter().filter(|d| matches!(d, Leg::Open)).count();

        let x0 = [self.id, self.iq, self.omega_m, self.theta_m, self.v_cap];
        let f = |x: [Real; 5]| self.deriv(x, &drives, open);
        let k1 = f(x0);
        let k2 = f(add(x0, &k1, 0.5 * dt));
        let k3 = f(add(x0, &k2, 0.5 * dt));
        let k4 = f(add(x0, &k3, dt));
        let w = |a: Real, b: Real, c: Real, d: Real| (a + 2.0 * b + 2.0 * c + d) * dt / 6.0;
        let mut id = self.id + w(k1.id, k2.id, k3.id, k4.id);
        let mut iq = self.iq + w(k1.iq, k2.iq, k3.iq, k4.iq);
        let mut omega = self.omega_m + w(k1.omega, k2.omega, k3.omega, k4.omega);
        let theta = self.theta_m + w(k1.theta, k2.theta, k3.theta, k4.theta);
        let v_cap = self.v_cap + w(k1.v_cap, k2.v_cap, k3.v_cap, k4.v_cap);
        self.energy.supply_j += w(k1.p_supply, k2.p_supply, k3.p_supply, k4.p_supply);
        self.energy.copper_j += w(k1.p_copper, k2.p_copper, k3.p_copper, k4.p_copper);
        self.energy.shaft_j += w(k1.p_shaft, k2.p_shaft, k3.p_shaft, k4.p_shaft);
        self.energy.friction_j += w(k1.p_friction, k2.p_friction, k3.p_friction, k4.p_friction);
        self.energy.load_j += w(k1.p_load, k2.p_load, k3.p_load, k4.p_load);
        self.energy.short_j += w(k1.p_short, k2.p_short, k3.p_short, k4.p_short);
        let e_in = w(k1.p_supply, k2.p_supply, k3.p_supply, k4.p_supply);
        let q_dc = w(k1.i_dc, k2.i_dc, k3.i_dc, k4.i_dc);
        let copper_j = w(k1.p_copper, k2.p_copper, k3.p_copper, k4.p_copper);
        let (mut q_source, mut q_brake) = (0.0, 0.0);
        if self.dc_link.is_some() {
            let out = |p: Real| if p > 0.0 { p } else { 0.0 };
            let e = &mut self.energy;
            e.source_out_j += w(
                out(k1.p_source),
                out(k2.p_source),
                out(k3.p_source),
                out(k4.p_source),
            );
            e.source_in_j += w(
                out(-k1.p_source),
                out(-k2.p_source),
                out(-k3.p_source),
                out(-k4.p_source),
            );
            e.source_loss_j += w(
                k1.p_source_loss,
                k2.p_source_loss,
                k3.p_source_loss,
                k4.p_source_loss,
            );
            e.capacitor_j += w(k1.p_cap, k2.p_cap, k3.p_cap, k4.p_cap);
            e.esr_j += w(k1.p_esr, k2.p_esr, k3.p_esr, k4.p_esr);
            e.brake_j += w(k1.p_brake, k2.p_brake, k3.p_brake, k4.p_brake);
            q_source = w(k1.i_source, k2.i_source, k3.i_source, k4.i_source);
            q_brake = w(k1.i_brake, k2.i_brake, k3.i_brake, k4.i_brake);
            self.v_cap = v_cap;
        }

        // Coulomb friction and stiction: the speed does not cross zero under friction.
        if matches!(self.mechanics, Mechanics::Free)
            && self.motor.coulomb_friction_nm > 0.0
            && ((self.omega_m > 0.0 && omega < 0.0) || (self.omega_m < 0.0 && omega > 0.0))
        {
            let te = self.motor.torque_nm(id, iq);
            if (te - self.load_nm).abs() <= self.motor.coulomb_friction_nm {
                omega = 0.0;
            }
        }
        let (th, turns) = real::wrap_tau(theta);
        self.theta_m = th;
        self.turns += turns;
        self.omega_m = omega;

        // Constraints: open phases carry no current; a diode stops at zero current.
        let th_e = self.theta_e_rad();
        if open >= 2 {
            id = 0.0;
            iq = 0.0;
        } else {
            let mut n_crossed = 0;
            for k in 0..3 {
                let (c, s) = (
                    real::cos(th_e - PHASE_AXIS[k]),
                    real::sin(th_e - PHASE_AXIS[k]),
                );
                let ik = id * c - iq * s;
                let crossed = match (drives[k], self.enabled, self.diodes[k]) {
                    (Leg::Open, _, _) => true,
                    (_, false, Diode::High) => ik > 0.0,
                    (_, false, Diode::Low) => ik < 0.0,
                    _ => false,
                };
                if crossed {
                    // Remove the phase-k component: a_k = (c, -s) in dq, |a_k| = 1.
                    id -= ik * c;
                    iq += ik * s;
                    n_crossed += 1;
                }
            }
            if n_crossed >= 2 {
                id = 0.0;
                iq = 0.0;
            }
        }
        self.id = id;
        self.iq = iq;

        // Bus and terminal voltages at the end of the sub-step (for outputs).
        let v_bus = self.bus(self.v_cap, &drives, self.phase_currents_a()).v_bus;
        self.v_bus = v_bus;
        let mut vt = [0.0; 3];
        for k in 0..3 {
            vt[k] = match drives[k] {
                Leg::Bus(h) => h * v_bus,
                Leg::Open => self.open_terminal_voltage(k, &drives, v_bus),
            };
        }
        SubstepOut {
            e_in,
            q_dc,
            vt,
            copper_j,
            q_source,
            q_brake,
        }
    }

    /// Source voltage after the injected sag.
    fn source_v(&self) -> Real {
        match &self.dc_link {
            Some(d) => d.v_source_v - self.faults.bus_sag_v,
            None => self.cfg.bus_voltage_v - self.faults.bus_sag_v,
        }
    }

    /// Bus voltage with no load current: the source's, or the capacitor's.
    fn open_circuit_bus_v(&self) -> Real {
        match self.dc_link {
            Some(_) => self.v_cap,
            None => self.source_v(),
        }
    }

    /// The bus at capacitor voltage `v_cap` (ignored without a DC link),
    /// given drives and phase currents.
    fn bus(&self, v_cap: Real, drives: &[Leg; 3], i_abc: [Real; 3]) -> BusSolution {
        match &self.dc_link {
            None => BusSolution {
                v_bus: self.bus_voltage(drives, i_abc),
                ..BusSolution::default()
            },
            Some(dc) => {
                let mut i_dc = 0.0;
                for k in 0..3 {
                    if let Leg::Bus(h) = drives[k] {
                        i_dc += h * i_abc[k];
                    }
                }
                let g_brake = match dc.brake_resistor_ohm {
                    Some(r) if self.brake_on && r > 0.0 => 1.0 / r,
                    _ => 0.0,
                };
                power::solve_bus(
                    dc,
                    v_cap,
                    self.source_v(),
                    i_dc,
                    self.short_conductance(drives),
                    g_brake,
                )
            }
        }
    }

    /// Conductance a phase short adds between the bus rails, `(h_a - h_b)^2 / r`.
    fn short_conductance(&self, drives: &[Leg; 3]) -> Real {
        match self.faults.phase_short {
            Some(s) if s.r_ohm > 0.0 => match (drives[s.a.index()], drives[s.b.index()]) {
                (Leg::Bus(ha), Leg::Bus(hb)) => (ha - hb) * (ha - hb) / s.r_ohm,
                _ => 0.0,
            },
            _ => 0.0,
        }
    }

    /// Bus voltage with source resistance, given drives and phase currents.
    fn bus_voltage(&self, drives: &[Leg; 3], i_abc: [Real; 3]) -> Real {
        let mut i_dc = 0.0;
        for k in 0..3 {
            if let Leg::Bus(h) = drives[k] {
                i_dc += h * i_abc[k];
            }
        }
        let rs = self.cfg.source_resistance_ohm;
        // A short adds (h_a - h_b)^2 V_bus / r: solve the linear equation for V_bus.
        let g_short = self.short_conductance(drives);
        (self.source_v() - rs * i_dc) / (1.0 + rs * g_short)
    }

    /// Extra DC current drawn by a phase short.
    fn short_dc_current(&self, drives: &[Leg; 3], v_bus: Real) -> Real {
        match self.faults.phase_short {
            Some(s) if s.r_ohm > 0.0 => match (drives[s.a.index()], drives[s.b.index()]) {
                (Leg::Bus(ha), Leg::Bus(hb)) => (ha - hb) * (ha - hb) * v_bus / s.r_ohm,
                _ => 0.0,
            },
            _ => 0.0,
        }
    }

    /// Current in the short from leg `a` to leg `b` [A] (0 without a short).
    fn short_current(&self, drives: &[Leg; 3], v_bus: Real) -> Real {
        match self.faults.phase_short {
            Some(s) if s.r_ohm > 0.0 => match (drives[s.a.index()], drives[s.b.index()]) {
                (Leg::Bus(ha), Leg::Bus(hb)) => (ha - hb) * v_bus / s.r_ohm,
                _ => 0.0,
            },
            _ => 0.0,
        }
    }

    /// Terminal voltages seen by the motor (a short ties its two terminals).
    fn motor_terminal_v(&self, drives: &[Leg; 3], v_bus: Real) -> [Real; 3] {
        let mut v = [0.0; 3];
        for k in 0..3 {
            if let Leg::Bus(h) = drives[k] {
                v[k] = h * v_bus;
            }
        }
        if let Some(s) = self.faults.phase_short {
            let (a, b) = (s.a.index(), s.b.index());
            if let (Leg::Bus(_), Leg::Bus(_)) = (drives[a], drives[b]) {
                let m = 0.5 * (v[a] + v[b]);
                v[a] = m;
                v[b] = m;
            }
        }
        v
    }

    /// State derivative. `x = [id, iq, omega_m, theta_m, v_cap]`.
    fn deriv(&self, x: [Real; 5], drives: &[Leg; 3], open: usize) -> Deriv {
        let m = &self.motor;
        let r_ohm = self.winding_resistance_ohm();
        let [id0, iq0, omega, theta, v_cap] = x;
        let p = m.pole_pairs as Real;
        let th_e = p * theta;
        let we = p * omega;
        let (id, iq) = if open >= 2 { (0.0, 0.0) } else { (id0, iq0) };
        let mut cs = [(0.0, 0.0); 3];
        let mut i_abc = [0.0; 3];
        for k in 0..3 {
            let c = real::cos(th_e - PHASE_AXIS[k]);
            let s = real::sin(th_e - PHASE_AXIS[k]);
            cs[k] = (c, s);
            i_abc[k] = id * c - iq * s;
        }
        let bus = self.bus(v_cap, drives, i_abc);
        let v_bus = bus.v_bus;
        let v = self.motor_terminal_v(drives, v_bus);
        let (mut vd, mut vq) = (0.0, 0.0);
        for k in 0..3 {
            if let Leg::Bus(_) = drives[k] {
                vd += (2.0 / 3.0) * v[k] * cs[k].0;
                vq -= (2.0 / 3.0) * v[k] * cs[k].1;
            }
        }
        let mut did = (vd - r_ohm * id + we * m.lq_h * iq) / m.ld_h;
        let mut diq = (vq - r_ohm * iq - we * m.ld_h * id - we * m.flux_linkage_wb) / m.lq_h;
        if open >= 2 {
            did = 0.0;
            diq = 0.0;
        } else if open == 1 {
            // Solve the open phase's terminal voltage so that its current stays 0.
            if let Some(z) = drives.iter().position(|d| matches!(d, Leg::Open)) {
                let (c, s) = cs[z];
                let (ad, aq) = (c, -s);
                let (gd, gq) = (ad / m.ld_h, aq / m.lq_h);
                let (add, adq) = (-we * s, -we * c);
                let den = ad * gd + aq * gq;
                let mu = -(ad * did + aq * diq + add * id + adq * iq) / den;
                did += mu * gd;
                diq += mu * gq;
            }
        }
        let te = if open >= 2 { 0.0 } else { m.torque_nm(id, iq) };
        let domega = match self.mechanics {
            Mechanics::Free => {
                let tc = if omega > 0.0 {
                    m.coulomb_friction_nm
                } else if omega < 0.0 {
                    -m.coulomb_friction_nm
                } else {
                    // Stiction: friction cancels the net torque up to its limit.
                    let net = te - self.load_nm;
                    net.clamp(-m.coulomb_friction_nm, m.coulomb_friction_nm)
                };
                (te - m.viscous_friction_nm_s_per_rad * omega - tc - self.load_nm) / m.inertia_kg_m2
            }
            Mechanics::Locked | Mechanics::ConstantSpeed(_) => 0.0,
        };
        let mut i_dc = 0.0;
        for k in 0..3 {
            if let Leg::Bus(h) = drives[k] {
                i_dc += h * i_abc[k];
            }
        }
        let i_short = self.short_current(drives, v_bus);
        let p_short = match self.faults.phase_short {
            Some(s) => i_short * i_short * s.r_ohm,
            None => 0.0,
        };
        let copper = r_ohm * (i_abc[0] * i_abc[0] + i_abc[1] * i_abc[1] + i_abc[2] * i_abc[2]);
        let friction = if matches!(self.mechanics, Mechanics::Free) {
            m.viscous_friction_nm_s_per_rad * omega * omega + m.coulomb_friction_nm * omega.abs()
        } else {
            0.0
        };
        // DC link: capacitor, source, ESR and brake terms (zero without).
        let link = match &self.dc_link {
            Some(dc) => Deriv {
                v_cap: bus.i_cap / dc.c_f,
                p_source: v_bus * bus.i_source,
                p_source_loss: (self.source_v() - v_bus) * bus.i_source,
                p_cap: v_cap * bus.i_cap,
                p_esr: dc.esr_ohm * bus.i_cap * bus.i_cap,
                p_brake: v_bus * bus.i_brake,
                i_source: bus.i_source,
                i_brake: bus.i_brake,
                ..Deriv::default()
            },
            None => Deriv::default(),
        };
        Deriv {
            id: did,
            iq: diq,
            omega: domega,
            theta: omega,
            // Supply power: motor legs plus the short (both fed from the bus).
            p_supply: v_bus * (i_dc + self.short_dc_current(drives, v_bus)),
            p_copper: copper,
            p_shaft: te * omega,
            p_friction: friction,
            p_load: self.load_nm * omega,
            p_short,
            i_dc: i_dc + self.short_dc_current(drives, v_bus),
            ..link
        }
    }

    /// Terminal voltage of open phase `z`, from the constraint `di_z/dt = 0`
    /// (one open phase) or the star point (all open: back-EMF about the mean).
    fn open_terminal_voltage(&self, z: usize, drives: &[Leg; 3], v_bus: Real) -> Real {
        let m = &self.motor;
        let th_e = self.theta_e_rad();
        let we = self.omega_e_rad_s();
        let e = PHASE_AXIS.map(|phi| -we * m.flux_linkage_wb * real::sin(th_e - phi));
        let open = drives.iter().filter(|d| matches!(d, Leg::Open)).count();
        if open >= 2 {
            // No current: terminals float at star point + EMF; the star point is
            // set by the conducting phase (if any), else by the bus midpoint.
            let v = self.motor_terminal_v(drives, v_bus);
            let star = match drives.iter().position(|d| matches!(d, Leg::Bus(_))) {
                Some(k) => v[k] - e[k],
                None => 0.5 * v_bus,
            };
            return star + e[z];
        }
        // One open phase: recompute the multiplier of `deriv` at the present state.
        let d = self.deriv(
            [self.id, self.iq, self.omega_m, self.theta_m, self.v_cap],
            drives,
            0,
        );
        let (c, s) = (
            real::cos(th_e - PHASE_AXIS[z]),
            real::sin(th_e - PHASE_AXIS[z]),
        );
        let (ad, aq) = (c, -s);
        let (gd, gq) = (ad / m.ld_h, aq / m.lq_h);
        let (add, adq) = (-we * s, -we * c);
        let den = ad * gd + aq * gq;
        let mu = -(ad * d.id + aq * d.iq + add * self.id + adq * self.iq) / den;
        // `d` was computed with the open terminal at 0 V; the open terminal adds
        // (2/3) v_z a_z to v_dq, i.e. mu = (2/3) v_z. Zero sequence cancels, so
        // v_z is referred to the same rail as the driven terminals.
        let _ = v_bus;
        1.5 * mu
    }

    /// Diode state machine for the disabled bridge.
    fn update_diodes(&mut self, i_abc: [Real; 3]) {
        for k in 0..3 {
            self.diodes[k] = if i_abc[k] > I_ZERO_A {
                Diode::Low
            } else if i_abc[k] < -I_ZERO_A {
                Diode::High
            } else {
                Diode::Open
            };
        }
        if let Some(p) = self.faults.disconnected_phase {
            self.diodes[p.index()] = Diode::Open;
        }
        let open = self.diodes.iter().filter(|d| **d == Diode::Open).count();
        let v_bus = self.open_circuit_bus_v();
        let drives = self.drives(0.0, 1.0, i_abc);
        if open == 3 {
            // All open: conduction starts when the line-to-line EMF exceeds the bus.
            let th_e = self.theta_e_rad();
            let we = self.omega_e_rad_s();
            let e = PHASE_AXIS.map(|phi| -we * self.motor.flux_linkage_wb * real::sin(th_e - phi));
            let (mut hi, mut lo) = (0, 0);
            for k in 0..3 {
                if e[k] > e[hi] {
                    hi = k;
                }
                if e[k] < e[lo] {
                    lo = k;
                }
            }
            let disconnected = self.faults.disconnected_phase.map(Phase::index);
            if e[hi] - e[lo] > v_bus && Some(hi) != disconnected && Some(lo) != disconnected {
                self.diodes[hi] = Diode::High;
                self.diodes[lo] = Diode::Low;
            }
        } else if open == 1 {
            if let Some(z) = self.diodes.iter().position(|d| *d == Diode::Open) {
                if Some(z) != self.faults.disconnected_phase.map(Phase::index) {
                    let vz = self.open_terminal_voltage(z, &drives, v_bus);
                    if vz > v_bus {
                        self.diodes[z] = Diode::High;
                    } else if vz < 0.0 {
                        self.diodes[z] = Diode::Low;
                    }
                }
            }
        }
    }

    /// What the ADCs and the encoder read now.
    fn sample(&mut self) -> Measurements {
        let s = self.cfg.sensors;
        let i_abc = self.phase_currents_a();
        let drives = self.drives(0.0, 1.0, i_abc);
        let i_short = self.short_current(&drives, self.v_bus);
        let mut legs = i_abc;
        if let Some(sh) = self.faults.phase_short {
            legs[sh.a.index()] += i_short;
            legs[sh.b.index()] -= i_short;
        }
        let levels = (1u64 << s.adc_bits.min(31)) as Real;
        let lsb_i = 2.0 * s.current_full_scale_a / levels;
        let mut read = [0.0f32; 3];
        for k in 0..3 {
            let raw = legs[k] + s.current_offset_a[k] + self.faults.current_offset_error_a[k];
            let sign = if self.faults.current_reversed.map(Phase::index) == Some(k) {
                -1.0
            } else {
                1.0
            };
            let noise = s.current_noise_lsb_rms * self.rng.gaussian() as Real;
            let counts = real::floor(sign * raw / lsb_i + levels / 2.0 + noise + 0.5)
                .clamp(0.0, levels - 1.0);
            read[k] = ((counts - levels / 2.0) * lsb_i) as f32;
        }
        if let Some(p) = self.faults.nan_current {
            read[p.index()] = f32::NAN;
        }
        let currents = match s.shunts {
            Shunts::Two => PhaseCurrents::TwoPhase {
                a_a: read[0],
                b_a: read[1],
            },
            Shunts::Three => PhaseCurrents::ThreePhase(Abc::new(read[0], read[1], read[2])),
        };

        // Encoder.
        let cpr = s.encoder_counts_per_rev.max(1);
        let dir = if self.faults.encoder_reversed {
            -1.0
        } else {
            1.0
        };
        let turns = (dir * (self.theta_m - self.sensor_zero_m_rad) - s.encoder_offset_rad) / TAU;
        let frac = turns - real::floor(turns);
        let mut counts = (real::floor(frac * cpr as Real) as i64).rem_euclid(cpr as i64);
        match self.faults.encoder {
            EncoderFault::None => {}
            EncoderFault::Stuck => counts = self.last_encoder_counts as i64,
            EncoderFault::Jump(j) => counts = (counts + j as i64).rem_euclid(cpr as i64),
        }
        self.last_encoder_counts = counts as u32;
        let bits = ((counts as u128) << 32) / cpr as u128;
        let angle = MechanicalAngle::from_bits(bits as u32);

        // Bus voltage.
        let lsb_v = s.bus_full_scale_v / levels;
        let noise = s.bus_noise_lsb_rms * self.rng.gaussian() as Real;
        let vc = real::floor(self.v_bus / lsb_v + noise + 0.5).clamp(0.0, levels - 1.0);

        Measurements {
            currents,
            angle,
            v_bus_v: (vc * lsb_v) as f32,
            stage_temperature_c: self.stage_thermal.map(|_| self.t_stage_c as f32),
            time_s: self.time_s,
            period: self.period,
        }
    }
}

fn add(x: [Real; 5], d: &Deriv, h: Real) -> [Real; 5] {
    [
        x[0] + h * d.id,
        x[1] + h * d.iq,
        x[2] + h * d.omega,
        x[3] + h * d.theta,
        x[4] + h * d.v_cap,
    ]
}

/// Fractions of the window `[u0, u1]` (fractions of the period) during which
/// a phase with duty `d` and dead time `delta` (fraction of the period) has
/// its high side on and its low side on; the rest is dead time.
///
/// Centre-aligned: the ideal high pulse is `[0.5 - d/2, 0.5 + d/2]`; each
/// rising edge (high side at the pulse start, low side at its end) is delayed
/// by `delta`.
pub fn phase_fractions(d: Real, delta: Real, u0: Real, u1: Real) -> (Real, Real) {
    let overlap = |a: Real, b: Real| -> Real {
        let lo = if a > u0 { a } else { u0 };
        let hi = if b < u1 { b } else { u1 };
        if hi > lo {
            hi - lo
        } else {
            0.0
        }
    };
    if d >= 1.0 {
        return (u1 - u0, 0.0);
    }
    if d <= 0.0 {
        return (0.0, u1 - u0);
    }
    let on = 0.5 - 0.5 * d;
    let off = 0.5 + 0.5 * d;
    let high = overlap(on + delta, off);
    let low = overlap(0.0, on) + overlap(off + delta, 1.0);
    (high, low)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fractions_sum_and_dead_time() {
        // Rounding of the scalar (f64, or f32 with `plant-f32`).
        let tol: Real = 64.0 * Real::EPSILON;
        let (h, l) = phase_fractions(0.3, 0.0, 0.0, 1.0);
        assert!((h - 0.3).abs() < tol && (l - 0.7).abs() < tol);
        let (h, l) = phase_fractions(0.3, 0.01, 0.0, 1.0);
        assert!((h - 0.29).abs() < tol && (l - 0.69).abs() < tol);
        // Windows add up to the whole period.
        let mut hs = 0.0;
        for j in 0..16 {
            hs += phase_fractions(0.37, 0.01, j as Real / 16.0, (j + 1) as Real / 16.0).0;
        }
        assert!((hs - 0.36).abs() < tol);
    }

    /// One period with the bridge off and the rotor at rest: what the
    /// sensor reads [rad], and one encoder count [rad].
    fn first_reading(plant: &mut Plant) -> (f32, f32) {
        let m = plant.step_period([0.5; 3], false, 0.0);
        let count = TAU as f32 / plant.config().sensors.encoder_counts_per_rev as f32;
        (m.angle.to_radians(), count)
    }

    /// Distance between two angles on the circle [rad].
    fn circle_distance(a: f32, b: f32) -> f32 {
        let d = (a - b).rem_euclid(TAU as f32);
        d.min(TAU as f32 - d)
    }

    #[test]
    fn default_sensor_reads_as_before() {
        let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
        assert_eq!(plant.angle_sensor(), AngleSensorKind::Incremental);
        let (a, _) = first_reading(&mut plant);
        assert_eq!(a, 0.0);
    }

    #[test]
    fn incremental_reads_zero_at_start_and_counts() {
        let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
        plant.start_rotor_at(1.3);
        let (a, count) = first_reading(&mut plant);
        assert!(circle_distance(a, 0.0) <= count, "{a}");
        assert!((plant.theta_m_rad() - 1.3).abs() < 1e-6);
        // It counts the motion from there.
        plant.set_rotor_angle(1.3 + 0.5);
        let (a, count) = first_reading(&mut plant);
        assert!(circle_distance(a, 0.5) <= count, "{a}");
        // Chosen after the start: reads 0 where the rotor is.
        plant.set_angle_sensor(AngleSensorKind::Incremental);
        let (a, count) = first_reading(&mut plant);
        assert!(circle_distance(a, 0.0) <= count, "{a}");
    }

    #[test]
    fn absolute_reads_true_angle_minus_mounting_offset() {
        for start in [1.3, 0.2, 0.0, 6.0] {
            // Either order of the two calls.
            for sensor_first in [true, false] {
                let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
                let abs = AngleSensorKind::Absolute {
                    mounting_offset_rad: 0.9,
                };
                if sensor_first {
                    plant.set_angle_sensor(abs);
                    plant.start_rotor_at(start);
                } else {
                    plant.start_rotor_at(start);
                    plant.set_angle_sensor(abs);
                }
                let (a, count) = first_reading(&mut plant);
                let expected = real::wrap_tau(start - 0.9).0 as f32;
                assert!(
                    circle_distance(a, expected) <= count,
                    "start {start}: {a} vs {expected}"
                );
            }
        }
    }

    #[test]
    fn validate_rejects_negative_resistance() {
        let mut m = MotorParams::example();
        assert!(m.validate().is_ok());
        m.r_ohm = -1.0;
        assert_eq!(m.validate(), Err(ParamError::NotPositive("r_ohm")));
    }
}
