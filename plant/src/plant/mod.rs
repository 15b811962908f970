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
//! - Mechanical: `J dw/dt = Te + T_cog - B w - Tc sgn(w) - T_load`, with
//!   stiction (the rotor stays stopped while `|Te + T_cog - T_load| <= Tc`).
//!   Or [`Mechanics`] `Locked` / `ConstantSpeed` for tests. The cogging
//!   torque `T_cog` is optional ([`Plant::set_cogging`], see [`Cogging`]).
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
//! - Sensors: see [`SensorConfig`] and [`Faults`]; the angle sensor's
//!   error over a turn is optional ([`Plant::set_angle_sensor_error`], see
//!   [`SensorError`]).
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
//!
//! Files: this one the plant's state and accessors; `motor` its
//! parameters; `config` the bench (PWM, shunts, sensors); `faults` what
//! can be broken on purpose; `inverter` the legs, diodes and bus;
//! `dynamics` the motor's equations over a period; `sensors` the readings;
//! `imperfections` cogging and the angle sensor's error.

// Loops over the three phases index several parallel arrays.
#![allow(clippy::needless_range_loop)]

mod config;
mod dynamics;
mod faults;
mod imperfections;
mod inverter;
mod motor;
mod sensors;

pub use config::*;
pub use faults::*;
pub use imperfections::*;
pub use inverter::*;
pub use motor::*;

use crate::power::{self, BusSolution, DcLinkConfig, StageThermal, WindingThermal};
use crate::real::{self, Real, TAU, TWO_PI_3};
use crate::rng::Rng;
use foc_core::angle::{ElectricalAngle, MechanicalAngle};
use foc_core::frames::Abc;
use foc_core::hal::PhaseCurrents;

/// Axis angles of phases A, B, C.
const PHASE_AXIS: [Real; 3] = [0.0, TWO_PI_3, -TWO_PI_3];

/// A current below this is zero for the diode model \[A\].
const I_ZERO_A: Real = 1e-9;

/// What the controller samples at the period boundary (centre of the zero
/// vector 000).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measurements {
    /// Phase currents \[A\] as the ADC reads them (quantised, noisy, with the
    /// hardware offsets: offset calibration is the controller's job).
    pub currents: PhaseCurrents,
    /// Encoder reading.
    pub angle: MechanicalAngle,
    /// The encoder's reading latched at its index pulse, when the rotor
    /// passed the index mark during the period that just ended
    /// ([`Plant::set_encoder_index`]; `None` without a mark).
    pub index: Option<MechanicalAngle>,
    /// Bus voltage \[V\] as the ADC reads it.
    pub v_bus_v: f32,
    /// Power-stage temperature [deg C] as the board's sensor reads it: `Some`
    /// only with the stage thermal model ([`Plant::set_stage_thermal`]).
    /// The bench feeds it to the drive as `Sample::temperature_c` (the bench
    /// adapter's `BusVoltage::read_temperature_c` returns it).
    pub stage_temperature_c: Option<f32>,
    /// Time of the sample \[s\].
    pub time_s: f64,
    /// Index of the period that just ended (0 for the first).
    pub period: u64,
}

/// Energy integrals since construction (or [`Plant::reset_energy`]) \[J\].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct EnergyAccount {
    /// Delivered by the DC bus to the inverter (`V_bus i_dc`).
    pub supply_j: Real,
    /// Dissipated in the winding resistance.
    pub copper_j: Real,
    /// Converted to mechanical (`Te w`).
    pub shaft_j: Real,
    /// Work of the cogging torque on the rotor (`T_cog w`; zero without
    /// [`Plant::set_cogging`]): minus the change of
    /// [`Plant::cogging_energy_j`]. On a free rotor `shaft_j + cogging_j =
    /// friction_j + load_j +` the change of kinetic energy.
    pub cogging_j: Real,
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
    /// `encoder_offset_rad`) \[rad\]: the power-on angle of an incremental
    /// encoder, the mounting offset of an absolute sensor.
    sensor_zero_m_rad: Real,
    /// The angle sensor's error over a turn (off by default).
    sensor_error: Option<SensorError>,
    /// The encoder's index mark: the rotor's mechanical angle at which it
    /// pulses \[rad\] (`None`: no index).
    encoder_index_m_rad: Option<Real>,
    /// The unwrapped position at the last sample (the index's crossing).
    index_last_pos_rad: Real,
    /// Cogging torque (off by default).
    cogging: Option<Cogging>,
    time_s: f64,
    period: u64,
    energy: EnergyAccount,
    // Power stage (all optional, off by default).
    dc_link: Option<DcLinkConfig>,
    /// Capacitor voltage \[V\] (the state; the bus when there is no DC link
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
            sensor_error: None,
            encoder_index_m_rad: None,
            index_last_pos_rad: 0.0,
            cogging: None,
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
    /// Start the rotor at mechanical angle `theta_m_rad` \[rad\] as at
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
    /// Put the rotor at mechanical angle `theta_m` \[rad\] (a jump: an
    /// incremental encoder counts it, see [`Plant::start_rotor_at`]).
    pub fn set_rotor_angle(&mut self, theta_m_rad: Real) {
        let (r, _) = real::wrap_tau(theta_m_rad);
        self.theta_m = r;
    }
    /// Put the rotor at the unwrapped mechanical position `position_rad`
    /// \[rad\] (see [`Plant::position_rad`]; a jump the angle sensor sees,
    /// e.g. a rotor held back by a mechanical end stop).
    pub fn set_position(&mut self, position_rad: Real) {
        let (r, turns) = real::wrap_tau(position_rad);
        self.theta_m = r;
        self.turns = turns;
    }
    /// Set the rotor speed [rad/s] (free mechanics keeps evolving from it).
    pub fn set_speed(&mut self, omega_m_rad_s: Real) {
        self.omega_m = omega_m_rad_s;
    }
    /// Set the dq currents directly \[A\] (initial conditions for tests).
    pub fn set_currents_dq(&mut self, id_a: Real, iq_a: Real) {
        self.id = id_a;
        self.iq = iq_a;
    }

    // ----- true state -----

    /// True d-axis current \[A\].
    pub fn id_a(&self) -> Real {
        self.id
    }
    /// True q-axis current \[A\].
    pub fn iq_a(&self) -> Real {
        self.iq
    }
    /// True phase currents \[A\] (into the motor).
    pub fn phase_currents_a(&self) -> [Real; 3] {
        let th = self.theta_e_rad();
        let (id, iq) = (self.id, self.iq);
        PHASE_AXIS.map(|phi| id * real::cos(th - phi) - iq * real::sin(th - phi))
    }
    /// True electrical angle \[rad\] in `[0, 2 pi)`.
    pub fn theta_e_rad(&self) -> Real {
        real::wrap_tau(self.theta_m * self.motor.pole_pairs as Real).0
    }
    /// True electrical angle.
    pub fn theta_e(&self) -> ElectricalAngle {
        ElectricalAngle::from_radians(self.theta_e_rad() as f32)
    }
    /// True mechanical angle \[rad\] in `[0, 2 pi)`.
    pub fn theta_m_rad(&self) -> Real {
        self.theta_m
    }
    /// True mechanical position over many turns \[rad\].
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
    /// Bus voltage at the end of the last sub-step \[V\].
    pub fn v_bus_v(&self) -> Real {
        self.v_bus
    }
    /// Bus voltage averaged over the sub-steps of the last period \[V\].
    ///
    /// Without a DC link ([`Plant::set_dc_link`]) there is no capacitor: with
    /// a source resistance and carrier-compared PWM the instantaneous bus
    /// voltage (and so the sampled one) moves with the switching state.
    pub fn v_bus_avg_v(&self) -> Real {
        self.v_bus_avg
    }
    /// Supply (DC) current averaged over the last period \[A\]: the
    /// inverter's DC input (legs and an injected short), see
    /// [`Plant::inverter_current_a`].
    pub fn supply_current_a(&self) -> Real {
        self.i_dc_avg
    }
    /// Inverter DC input current averaged over the last period \[A\]
    /// (`sum_k h_k i_k` plus an injected short's; negative while
    /// regenerating). The same as [`Plant::supply_current_a`].
    pub fn inverter_current_a(&self) -> Real {
        self.i_dc_avg
    }
    /// Source current into the bus averaged over the last period \[A\]. With
    /// a DC link it differs from the inverter's by the capacitor and brake
    /// currents; without, it is the inverter's.
    pub fn source_current_a(&self) -> Real {
        match self.dc_link {
            Some(_) => self.i_source_avg,
            None => self.i_dc_avg,
        }
    }
    /// Brake-resistor current averaged over the last period \[A\].
    pub fn brake_current_a(&self) -> Real {
        self.i_brake_avg
    }
    /// Input power `V_bus i_dc` averaged over the last period \[W\].
    pub fn input_power_w(&self) -> Real {
        self.p_in_avg
    }
    /// Mechanical output power at the shaft `Te w` \[W\] (before friction).
    pub fn shaft_power_w(&self) -> Real {
        self.torque_nm() * self.omega_m
    }
    /// Terminal voltages (to the bus minus rail) averaged over the last period \[V\].
    pub fn terminal_voltages_avg_v(&self) -> [Real; 3] {
        self.v_terminal_avg
    }
    /// Magnetic energy stored in the windings, `0.75 (Ld id^2 + Lq iq^2)` \[J\]
    /// (the d part saturated as [`MotorParams::d_energy_j`]).
    pub fn magnetic_energy_j(&self) -> Real {
        let m = &self.motor;
        if m.d_saturation.fraction == 0.0 {
            return 0.75 * (m.ld_h * self.id * self.id + m.lq_h * self.iq * self.iq);
        }
        m.d_energy_j(self.id) + 0.75 * m.lq_h * self.iq * self.iq
    }
    /// Kinetic energy `J w^2 / 2` \[J\].
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
    /// Simulated time \[s\].
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
    /// Set the capacitor voltage \[V\] (an initial condition; DC link only).
    pub fn set_capacitor_voltage(&mut self, v: Real) {
        if self.dc_link.is_some() {
            self.v_cap = v;
        }
    }
    /// Capacitor voltage \[V\] (DC link only; without, the source voltage).
    pub fn capacitor_voltage_v(&self) -> Real {
        match self.dc_link {
            Some(_) => self.v_cap,
            None => self.source_v(),
        }
    }
    /// Energy stored in the capacitor `C v_C^2 / 2` \[J\] (0 without a DC link).
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
    /// Energy dissipated in the brake resistor \[J\] (also in [`Plant::energy`]).
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
    /// Phase resistance in use \[ohm\]: [`MotorParams::r_ohm`], or its value
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
    /// sensor reads \[rad\], and one encoder count \[rad\].
    fn first_reading(plant: &mut Plant) -> (f32, f32) {
        let m = plant.step_period([0.5; 3], false, 0.0);
        let count = TAU as f32 / plant.config().sensors.encoder_counts_per_rev as f32;
        (m.angle.to_radians(), count)
    }

    /// Distance between two angles on the circle \[rad\].
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
