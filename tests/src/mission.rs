//! Closed-loop simulation: the real `foc-core` [`Cascade`] against the
//! [`Plant`], at the real rates, through a scripted mission.
//!
//! Every PWM period [`Sim::step`] hands the controller the sample the plant
//! took at the end of the previous period, then advances the plant by one
//! period. The duties it returns go through the plant's shadow register
//! (`compute_delay_periods = 1`), so they act one period after the sample,
//! as in the firmware; a safe-state decision acts at once (the bridge is
//! disabled for the very next period). The speed and position stages run
//! every N and M periods inside [`Cascade::step`], exactly as the firmware
//! pends them.
//!
//! The mission ([`run_mission`]):
//!
//! 1. **identify** ([`crate::identify::run`]): current-offset calibration
//!    with the bridge off, then foc-core's `Identification` through the
//!    mission's cascade: R, Ld, Lq, current-loop gains, alignment (electrical
//!    zero, direction, pole-pair check) and the flux linkage (hall-class
//!    sensors included). The rest of the mission runs on its permit
//!    (measured gains and zero), not on supplied values; the bench does *not*
//!    copy the plant's parameters or encoder offset, it reports the errors
//!    against them.
//! 2. **current step** (torque mode, rotor locked): `iq` 0 -> `I_step`.
//! 3. **speed step** 0 -> `w1`, then a **ramp** `w1` -> `w2` (velocity mode).
//! 4. **load step** at `w2` (about 40 % of the rated torque).
//! 5. stop (load removed), then a **position move** of one turn.
//! 6. **impedance** (design §21): the rotor held by the impedance law
//!    (stiffness for 0.25 rad or 40 counts at 30 % of the torque limit,
//!    damping ratio 0.7 on the identified inertia), load steps of +-30 %
//!    of the torque limit and a sinusoidal load at a fifth of the spring's
//!    natural frequency: the stiffness and damping measured as the motor's
//!    torque against the true position and velocity. It fails beyond 5 %
//!    (stiffness) or 10 % (damping).
//! 7. **braking** (design §18): a DC link with the ODrive v3's bus capacitor
//!    on a battery, a spin-up to the ramp's speed, then the supply made
//!    non-sinking (a diode-fed bench supply) and a hard stop (0 rad/s at
//!    once) with the board's power limits
//!    ([`PowerLimitsConfig::for_board`]: regen ramp and d-axis braking):
//!    the peak bus voltage against the over-voltage threshold, the
//!    stopping time and where the kinetic energy went; then the same stop
//!    with the ODrive's 2 ohm brake resistor switched by the drive's
//!    chopper. It fails on a bus at or above the over-voltage threshold or
//!    a fault; a stop that takes longer than the segment is reported, not
//!    failed. The power limits and the DC link are only in this segment
//!    (every earlier figure is unchanged).
//!
//! ```no_run
//! use foc_bench::mission::{run_mission, Setup};
//! let setup = Setup::load("tests/motors/dji-m2006.toml").unwrap();
//! let r = run_mission(&setup, &mut |_| {});
//! println!("{}", r.summary.to_markdown());
//! assert!(r.summary.failures().is_empty());
//! ```

use crate::identify;
use crate::metrics;
use crate::motor_file::{MotorFile, MotorFileError};
use crate::plant::{self, BenchConfig, Measurements, Mechanics, Plant};
use crate::power::{DcLinkConfig, SourceKind};
use crate::report::{Panel, Trace};
use foc_core::angle::{ElectricalAngle, MechanicalAngle};
use foc_core::calibration::identification::IdentificationResult;
use foc_core::calibration::Calibrated;
use foc_core::control::power::{ActiveLimit, PowerLimitsConfig};
use foc_core::control::stage::{AngleCalibration, Sample};
use foc_core::control::{BridgeCommand, Command, Mode};
use foc_core::drive::cascade::{Cascade, CascadeConfig};
use foc_core::frames::Abc;
use foc_core::hal::PhaseCurrents;
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// The controller's motor parameters from the plant's (same values, `f32`).
pub fn control_motor(m: &plant::MotorParams) -> foc_core::control::MotorParams {
    foc_core::control::MotorParams {
        pole_pairs: m.pole_pairs,
        r_ohm: m.r_ohm as f32,
        ld_h: m.ld_h as f32,
        lq_h: m.lq_h as f32,
        flux_linkage_wb: m.flux_linkage_wb as f32,
    }
}

/// A motor on the bench: plant parameters, bench configuration, current ratings.
#[derive(Clone, Debug, PartialEq)]
pub struct Setup {
    /// Motor name.
    pub name: String,
    /// Plant motor parameters.
    pub motor: plant::MotorParams,
    /// Inverter, supply and sensors.
    pub bench: BenchConfig,
    /// Rated (continuous) current [A].
    pub rated_current_a: f32,
    /// Maximum current [A] (the controller's current limit).
    pub max_current_a: f32,
}

impl Setup {
    /// From a loaded motor file. The encoder's zero is put 1.234 rad away
    /// from the rotor d axis so that the alignment has something to find.
    pub fn from_file(f: &MotorFile) -> Self {
        let mut bench = f.bench_config();
        bench.sensors.encoder_offset_rad = 1.234;
        Self {
            name: f.name.clone(),
            motor: f.motor_params(),
            bench,
            rated_current_a: f.rated_current_a as f32,
            max_current_a: f.max_current_a as f32,
        }
    }

    /// Load a motor file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, MotorFileError> {
        MotorFile::load(path).map(|f| Self::from_file(&f))
    }

    /// PWM frequency [Hz].
    pub fn pwm_hz(&self) -> f32 {
        self.bench.pwm_frequency_hz as f32
    }

    /// Torque constant `1.5 p psi` [N m / A].
    pub fn kt(&self) -> f32 {
        control_motor(&self.motor).torque_constant_nm_per_a()
    }

    /// No-load speed at the nominal bus within the linear range [rad/s, mechanical].
    pub fn max_speed_rad_s(&self) -> f32 {
        let v_max = 0.95 * self.bench.bus_voltage_v as f32 / 3f32.sqrt();
        let k = self.motor.pole_pairs as f32 * self.motor.flux_linkage_wb as f32;
        if k > 0.0 {
            v_max / k
        } else {
            1.0e3
        }
    }

    /// Highest speed the mission and the dyno command [rad/s, mechanical]:
    /// one electrical turn per 10 PWM periods (0.63 rad electrical per
    /// period). foc-core compensates the 1.5-period delay of the voltage
    /// (`delay_compensation_periods`); this keeps the sampled electrical
    /// angle well resolved (it was one turn per 30 periods before the
    /// compensation, where the uncompensated lag was 18 deg).
    pub fn max_mission_speed_rad_s(&self) -> f32 {
        std::f32::consts::TAU * self.pwm_hz() / (10.0 * self.motor.pole_pairs as f32)
    }

    /// The controller configuration: [`CascadeConfig::for_motor_with_inertia`]
    /// (source tuning of the current loop) with the bench's inertia, the
    /// supervisor's bus limits at 60 % / 125 % of the nominal bus, and the
    /// position trajectory limited to 40 % of the no-load speed and to the
    /// acceleration 30 % of the maximum current gives.
    pub fn cascade_config(&self) -> CascadeConfig {
        let j = self.motor.inertia_kg_m2 as f32;
        let mut c = CascadeConfig::for_motor_with_inertia(
            control_motor(&self.motor),
            self.pwm_hz(),
            self.max_current_a,
            j,
        );
        let vbus = self.bench.bus_voltage_v as f32;
        c.current.supervisor.bus_over_voltage_v = 1.25 * vbus;
        c.current.supervisor.bus_under_voltage_v = 0.6 * vbus;
        c.current.limits.max_open_loop_voltage_v = vbus;
        c.position.max_velocity_rad_s = 0.4 * self.max_speed_rad_s();
        c.position.max_acceleration_rad_s2 = 0.3 * self.kt() * self.max_current_a / j;
        // The sensor's resolution is known before any calibration (the
        // supervisor's angle-step limit never goes below a few counts).
        c.current.angle.sensor_counts_per_rev = self.bench.sensors.encoder_counts_per_rev;
        // The bridge's dead time is the board's, known as the firmware
        // knows it (`board::DEAD_TIME_NS`, design §24): the model check
        // corrects for it.
        c.current.supervisor.model.dead_time_s = self.bench.dead_time_s as f32;
        // The plant's mechanics, as a user who knows them would give them
        // (the mission installs the identified ones instead).
        c.set_mechanics(&self.mechanics());
        c
    }

    /// [`Self::cascade_config`] as a drive starts before its first
    /// identification: the rotor's mechanics not known (the speed
    /// observer without a model, no speed feed-forward). The
    /// identification measures them and the drive installs them.
    pub fn unidentified_config(&self) -> CascadeConfig {
        let mut c = self.cascade_config();
        c.clear_mechanics();
        c
    }

    /// The plant's mechanics (rotor frame).
    pub fn mechanics(&self) -> foc_core::control::Mechanics {
        foc_core::control::Mechanics {
            inertia_kg_m2: self.motor.inertia_kg_m2 as f32,
            viscous_friction_nm_s_per_rad: self.motor.viscous_friction_nm_s_per_rad as f32,
            coulomb_friction_nm: self.motor.coulomb_friction_nm as f32,
        }
    }
}

impl Setup {
    /// The angle calibration that is exact for this bench: the plant's
    /// encoder offset is known here (the mission itself *finds* it with
    /// [`crate::identify::run`] instead).
    pub fn true_angle_calibration(&self) -> AngleCalibration {
        let pp = self.motor.pole_pairs;
        AngleCalibration {
            pole_pairs: pp,
            zero_offset: MechanicalAngle::from_radians(
                -(self.bench.sensors.encoder_offset_rad as f32),
            )
            .to_electrical(pp),
            reversed: false,
            // The bench's encoder reads floor counts: let the stage add
            // the half count (see `AngleCalibration::sensor_counts_per_rev`).
            sensor_counts_per_rev: self.bench.sensors.encoder_counts_per_rev,
        }
    }

    /// A calibration permit supplied from the bench's knowledge: the exact
    /// angle calibration and `config`'s current-loop configuration.
    pub fn supplied_calibration(&self, config: &CascadeConfig) -> Calibrated {
        Calibrated::supplied(self.true_angle_calibration(), config.current.current)
            .expect("plausible motor file")
    }
}

/// The controller's view of one plant sample.
pub fn sample_of(m: &Measurements) -> Sample {
    Sample {
        currents: Some(m.currents),
        angle: Some(m.angle),
        v_bus_v: Some(m.v_bus_v),
        // The power stage's temperature, where the plant models it.
        temperature_c: m.stage_temperature_c,
    }
}

/// `c` with the offsets `o` [A] removed.
pub fn remove_offsets(c: PhaseCurrents, o: Abc) -> PhaseCurrents {
    match c {
        PhaseCurrents::TwoPhase { a_a, b_a } => PhaseCurrents::TwoPhase {
            a_a: a_a - o.a,
            b_a: b_a - o.b,
        },
        PhaseCurrents::ThreePhase(i) => {
            PhaseCurrents::ThreePhase(Abc::new(i.a - o.a, i.b - o.b, i.c - o.c))
        }
    }
}

/// Names of the trace columns written by [`Sim`].
pub const TRACE_COLUMNS: [&str; 23] = [
    "id_a",
    "iq_a",
    "id_ref_a",
    "iq_ref_a",
    "vd_v",
    "vq_v",
    "speed_rad_s",
    "speed_est_rad_s",
    "speed_ref_rad_s",
    "position_rad",
    "position_est_rad",
    "position_ref_rad",
    "duty_a",
    "duty_b",
    "duty_c",
    "v_bus_v",
    "mode",
    "fault",
    "load_nm",
    "iq_true_a",
    "id_true_a",
    "bridge_on",
    "disturbance_rad_s2",
];

/// Plant + controller, stepped one PWM period at a time.
#[derive(Clone, Debug)]
pub struct Sim {
    /// The plant.
    pub plant: Plant,
    /// The controller.
    pub cascade: Cascade,
    /// Load torque applied from the next period [N m] (opposes positive rotation).
    pub load_nm: f32,
    last: Measurements,
    last_bridge: BridgeCommand,
    trace: Option<Trace>,
    /// Encoder-frame position of the plant's true position 0 [rad]: `est = true - offset`.
    encoder_offset_rad: f64,
    /// Current-sense offsets removed from every sample [A] (once calibrated).
    current_offsets: Option<Abc>,
    /// The position stage has run since position mode was entered: its
    /// reference is this move's (before that it is the last move's, or 0).
    position_planned: bool,
}

impl Sim {
    /// New simulation with the controller calibrated from the bench's
    /// knowledge ([`Setup::supplied_calibration`]), ready for closed loop.
    pub fn new_calibrated(setup: &Setup, config: CascadeConfig, record: bool) -> Self {
        let mut sim = Self::new(setup, config, record);
        sim.cascade
            .set_calibration(&setup.supplied_calibration(&config));
        sim
    }

    /// New simulation (bridge off, first sample taken), optionally recording
    /// a trace. The controller is uncalibrated (open loop only) until
    /// [`align`] or `cascade.set_calibration`.
    pub fn new(setup: &Setup, config: CascadeConfig, record: bool) -> Self {
        Self::with_plant(setup, Plant::new(setup.motor, setup.bench), config, record)
    }

    /// As [`Sim::new`] on a plant the caller prepared (e.g. with injected
    /// faults); `setup` gives the encoder offset of the true-position column.
    pub fn with_plant(
        setup: &Setup,
        mut plant: Plant,
        config: CascadeConfig,
        record: bool,
    ) -> Self {
        let last = plant.step_period([0.5; 3], false, 0.0);
        Self {
            plant,
            cascade: Cascade::new(config),
            load_nm: 0.0,
            last,
            last_bridge: BridgeCommand::SafeState,
            trace: record.then(|| Trace::new(&TRACE_COLUMNS)),
            encoder_offset_rad: setup.bench.sensors.encoder_offset_rad as f64,
            current_offsets: None,
            position_planned: false,
        }
    }

    /// Put the rotor at `theta_m` [rad] before the controller starts, and
    /// take a fresh sample there (one period with the bridge off).
    pub fn set_rotor_angle(&mut self, theta_m_rad: f64) {
        self.plant.set_rotor_angle(theta_m_rad as _);
        self.last = self.plant.step_period([0.5; 3], false, 0.0);
    }

    /// The plant's latest measurements (raw: current offsets not removed).
    pub fn last_sample(&self) -> &Measurements {
        &self.last
    }

    /// The sample the controller sees next: [`Sim::last_sample`] with the
    /// current offsets removed once [`Sim::set_current_offsets`] was called.
    pub fn sample(&self) -> Sample {
        let mut s = sample_of(&self.last);
        if let (Some(o), Some(c)) = (self.current_offsets, s.currents) {
            s.currents = Some(remove_offsets(c, o));
        }
        s
    }

    /// Remove these current-sense offsets [A] from every later sample (what
    /// the firmware's `CurrentSense::set_offsets_a` does after the offset
    /// calibration).
    pub fn set_current_offsets(&mut self, offsets: Abc) {
        self.current_offsets = Some(offsets);
    }

    /// The installed current-sense offsets [A].
    pub fn current_offsets(&self) -> Option<Abc> {
        self.current_offsets
    }

    /// The bridge command of the last step.
    pub fn last_bridge(&self) -> BridgeCommand {
        self.last_bridge
    }

    /// The recorded trace (if recording).
    pub fn trace(&self) -> Option<&Trace> {
        self.trace.as_ref()
    }

    /// Take the recorded trace.
    pub fn take_trace(&mut self) -> Option<Trace> {
        self.trace.take()
    }

    /// Rows recorded so far.
    pub fn rows(&self) -> usize {
        self.trace.as_ref().map_or(0, Trace::len)
    }

    /// One PWM period: the controller on the latest sample, then the plant.
    pub fn step(&mut self) -> BridgeCommand {
        let sample = self.sample();
        self.step_with(&sample)
    }

    /// As [`Sim::step`] with a sample the caller may have altered.
    pub fn step_with(&mut self, sample: &Sample) -> BridgeCommand {
        let bridge = self.cascade.step(sample);
        let (duties, on) = match bridge {
            BridgeCommand::SafeState => ([0.5; 3], false),
            BridgeCommand::Duties(d) => (d, true),
        };
        if self.trace.is_some() {
            self.record(on);
        }
        self.last_bridge = bridge;
        // The brake chopper the drive asks for (a no-op without a DC link).
        self.plant.set_brake(self.cascade.feedback().power.brake_on);
        // What the firmware's `CurrentSense::set_offsets_a` does when the
        // drive hands over calibrated offsets.
        if let Some(o) = self.cascade.take_offsets() {
            self.set_current_offsets(o);
        }
        self.last = self.plant.step_period(duties, on, self.load_nm);
        bridge
    }

    /// Run `n` periods.
    pub fn run(&mut self, n: usize) {
        for _ in 0..n {
            self.step();
        }
    }

    /// True position in the encoder's frame (unwrapped) [rad].
    pub fn true_position_rad(&self) -> f64 {
        self.plant.position_rad() as f64 - self.encoder_offset_rad
    }

    fn record(&mut self, on: bool) {
        let fb = *self.cascade.feedback();
        let nan = f64::NAN;
        let speed_ref = match fb.active {
            Command::Velocity { rad_s } => rad_s as f64,
            Command::Position { .. } => self.cascade.velocity_ref().rad_s as f64,
            _ => nan,
        };
        // The position stage runs every few periods: in the first periods
        // of a move its reference is still the previous move's (or 0).
        let position_mode = matches!(fb.active, Command::Position { .. });
        self.position_planned = position_mode
            && (self.position_planned
                || self.cascade.last_output().is_some_and(|o| o.run_position));
        let pos_ref = if self.position_planned {
            self.cascade.position.position_loop().reference().position as f64
        } else {
            nan
        };
        let row = [
            fb.i_dq_a.d as f64,
            fb.i_dq_a.q as f64,
            fb.i_dq_ref_a.d as f64,
            fb.i_dq_ref_a.q as f64,
            fb.v_dq_v.d as f64,
            fb.v_dq_v.q as f64,
            self.plant.omega_m_rad_s() as f64,
            fb.velocity_rad_s as f64,
            speed_ref,
            self.true_position_rad(),
            fb.position_rad as f64,
            pos_ref,
            fb.duties[0] as f64,
            fb.duties[1] as f64,
            fb.duties[2] as f64,
            fb.v_bus_v as f64,
            fb.mode as u8 as f64,
            fb.first_fault.map_or(0.0, |f| f.code() as f64),
            self.load_nm as f64,
            self.plant.iq_a() as f64,
            self.plant.id_a() as f64,
            if on { 1.0 } else { 0.0 },
            fb.disturbance_rad_s2 as f64,
        ];
        let t = self.last.time_s;
        if let Some(tr) = self.trace.as_mut() {
            tr.push(t, &row);
        }
    }
}

/// A named stretch of the mission (trace rows `start..end`).
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// Name.
    pub name: &'static str,
    /// First row.
    pub start: usize,
    /// One past the last row.
    pub end: usize,
}

/// What the identification segment measured, against the plant's truth.
#[derive(Clone, Debug, PartialEq)]
pub struct IdentificationSummary {
    /// Phase resistance [ohm] and its error [%].
    pub r_ohm: (f64, f64),
    /// d-axis inductance [H] and its error [%].
    pub ld_h: (f64, f64),
    /// q-axis inductance [H] and its error [%].
    pub lq_h: (f64, f64),
    /// Flux linkage [Wb] and its error [%] (None: not measured).
    pub flux_linkage_wb: Option<(f64, f64)>,
    /// Mechanics (design §19): inertia [kg m^2] and its error [%], and the
    /// friction torque `Fc + B |w|` at the identification's low and high
    /// test speeds [N m] with its error [%] (None: not measured).
    pub mechanics: Option<MechanicsFigures>,
    /// Pole pairs found and the plant's.
    pub pole_pairs: (u8, u8),
    /// Sensor reversed: found and the plant's.
    pub reversed: (bool, bool),
    /// Current-sense offsets found [A] (phases a, b, c).
    pub offsets_a: [f64; 3],
    /// Offset calibration time [s, simulated].
    pub offset_time_s: f64,
    /// Identification time after the offsets [s, simulated].
    pub time_s: f64,
    /// Wall time of the segment [s].
    pub wall_time_s: f64,
}

/// The identified mechanics against the plant's (design §19).
#[derive(Clone, Debug, PartialEq)]
pub struct MechanicsFigures {
    /// Inertia [kg m^2] and its error [%].
    pub inertia_kg_m2: (f64, f64),
    /// Viscous [N m s/rad] and Coulomb [N m] friction identified.
    pub friction: (f64, f64),
    /// The plant's viscous and Coulomb friction.
    pub plant_friction: (f64, f64),
    /// Friction torque at the low and the high test speed [rad/s]:
    /// (speed, identified [N m], error [%]).
    pub torque_at: [(f64, f64, f64); 2],
}

/// The impedance segment's figures (design §21), rotor frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ImpedanceFigures {
    /// Stiffness commanded [N m/rad].
    pub kp_nm_per_rad: f64,
    /// Damping commanded [N m s/rad].
    pub kd_nm_s_per_rad: f64,
    /// Stiffness from the two load steps [N m/rad].
    pub kp_steps: f64,
    /// Stiffness from the sinusoidal load [N m/rad].
    pub kp_sine: f64,
    /// Damping from the sinusoidal load [N m s/rad].
    pub kd_sine: f64,
    /// The sinusoidal load's frequency [Hz].
    pub sine_hz: f64,
}

impl ImpedanceFigures {
    fn err(m: f64, set: f64) -> f64 {
        100.0 * (m / set - 1.0)
    }

    /// What fails: stiffness beyond 5 %, damping beyond 10 %.
    pub fn failures(&self) -> Vec<String> {
        let mut f = Vec::new();
        for (what, m, set, tol) in [
            ("stiffness (steps)", self.kp_steps, self.kp_nm_per_rad, 5.0),
            ("stiffness (sine)", self.kp_sine, self.kp_nm_per_rad, 5.0),
            ("damping (sine)", self.kd_sine, self.kd_nm_s_per_rad, 10.0),
        ] {
            let e = Self::err(m, set);
            if !below(e.abs(), tol) {
                f.push(format!("impedance {what} off by {e:+.1} %"));
            }
        }
        f
    }

    /// One line for the report.
    pub fn describe(&self) -> String {
        format!(
            "kp {:.4} N m/rad: load steps {:.4} ({:+.1} %), sine {:.4} ({:+.1} %); kd {:.3e} N m s/rad: sine at {:.1} Hz {:.3e} ({:+.1} %)",
            self.kp_nm_per_rad,
            self.kp_steps,
            Self::err(self.kp_steps, self.kp_nm_per_rad),
            self.kp_sine,
            Self::err(self.kp_sine, self.kp_nm_per_rad),
            self.kd_nm_s_per_rad,
            self.sine_hz,
            self.kd_sine,
            Self::err(self.kd_sine, self.kd_nm_s_per_rad),
        )
    }
}

/// One stop of the braking segment.
#[derive(Clone, Debug, PartialEq)]
pub struct StopFigures {
    /// The speed command's ramp to 0 [s] (0: a hard stop, 0 rad/s at once).
    pub ramp_s: f64,
    /// Highest bus voltage [V] (the plant's, at the capacitor's terminals).
    pub peak_bus_v: f64,
    /// Speed at the stop command [rad/s].
    pub from_rad_s: f64,
    /// Time from the stop command to |speed| < 2 % of the commanded speed [s]
    /// (None: not within the segment).
    pub stop_s: Option<f64>,
    /// Speed at the end of the segment [rad/s].
    pub end_rad_s: f64,
    /// Kinetic energy removed [J].
    pub kinetic_j: f64,
    /// Into the bus capacitor (change of `C v^2 / 2`) [J].
    pub capacitor_j: f64,
    /// Into the brake resistor [J].
    pub resistor_j: f64,
    /// Copper loss of the winding [J].
    pub copper_j: f64,
    /// Friction [J].
    pub friction_j: f64,
    /// Delivered by the supply [J].
    pub source_j: f64,
    /// PWM periods with the regen limit active.
    pub regen_limited_periods: usize,
    /// PWM periods with the brake chopper on.
    pub brake_periods: usize,
    /// Faults latched during the stop (names).
    pub faults: Vec<String>,
}

/// The braking segment's figures (design §18).
#[derive(Clone, Debug, PartialEq)]
pub struct BrakingSummary {
    /// The DC link: its name and capacitance [F].
    pub link: &'static str,
    /// Bus capacitance [F].
    pub c_f: f64,
    /// Supply voltage [V].
    pub v_source_v: f64,
    /// The supervisor's over-voltage threshold [V].
    pub over_voltage_v: f64,
    /// The regen ramp [V] (start, end).
    pub regen_v: (f64, f64),
    /// Speed commanded before the stops [rad/s].
    pub from_rad_s: f64,
    /// The stop into the capacitor alone (regen limit on), along the
    /// mission's deceleration ramp.
    pub capacitor: StopFigures,
    /// A hard stop with the brake resistor (chopper on at the regen ramp's
    /// start).
    pub resistor: StopFigures,
    /// Its resistance [ohm].
    pub resistor_ohm: f64,
}

/// The speed loop's figures beyond the first step (design §19): the
/// speed estimate during the steps' acceleration, the load release and a
/// step large enough to put the q current on its limit.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SpeedFigures {
    /// Largest |estimate - true speed| while the first step accelerates
    /// [rad/s], and as a percentage of the step.
    pub estimate_error: (f64, f64),
    /// Largest rise above the speed after the load is released [rad/s].
    pub release_rise_rad_s: f64,
    /// Recovery into +-2 % after the load release [ms].
    pub release_recovery_ms: Option<f64>,
    /// The current-limited step: its target from rest [rad/s].
    pub sat_step_rad_s: f64,
    /// Its current limit [A].
    pub sat_limit_a: f64,
    /// Its overshoot [%].
    pub sat_overshoot_percent: f64,
    /// Its 2 % settling time [ms].
    pub sat_settling_ms: Option<f64>,
    /// How long the q-current reference was on the current limit [ms].
    pub sat_limited_ms: f64,
    /// Largest |estimate - true speed| while it accelerates [rad/s] and as
    /// a percentage of the step.
    pub sat_estimate_error: (f64, f64),
    /// Largest acceleration of the true speed during that step [rad/s^2].
    pub sat_peak_acceleration_rad_s2: f64,
    /// Largest acceleration of the true speed during the first step
    /// [rad/s^2].
    pub step_peak_acceleration_rad_s2: f64,
}

impl SpeedFigures {
    /// The speed-estimate error [% of the step] of the step with the
    /// mission's fastest acceleration, and that acceleration [rad/s^2].
    pub fn fastest_estimate_error(&self) -> (f64, f64) {
        if self.sat_peak_acceleration_rad_s2 >= self.step_peak_acceleration_rad_s2 {
            (self.sat_estimate_error.1, self.sat_peak_acceleration_rad_s2)
        } else {
            (self.estimate_error.1, self.step_peak_acceleration_rad_s2)
        }
    }
}

/// The figures measured on one mission.
#[derive(Clone, Debug, PartialEq)]
pub struct MissionSummary {
    /// Motor name.
    pub motor: String,
    /// PWM frequency [Hz].
    pub pwm_hz: f32,
    /// Speed and position loop dividers.
    pub dividers: (u16, u16),
    /// The identification's figures (None: it failed, see
    /// `identification_failure`, or the calibration was restored).
    pub identification: Option<IdentificationSummary>,
    /// The calibration came from a stored configuration (no identification).
    pub restored: bool,
    /// Why the identification failed (the mission then runs on the
    /// supplied calibration and fails).
    pub identification_failure: Option<String>,
    /// Alignment: electrical zero found [deg].
    pub align_found_deg: f64,
    /// Alignment error against the plant's true encoder offset [deg, electrical].
    pub align_error_deg: f64,
    /// Current-step size [A].
    pub current_step_a: f64,
    /// The current-step figures are of the true current's magnitude (hall-class
    /// sensor), not of its q component.
    pub current_step_magnitude: bool,
    /// q-current overshoot [%] (true current at the sample instants).
    pub current_overshoot_percent: f64,
    /// q-current 2 % settling time [PWM periods] (None: did not settle).
    pub current_settling_periods: Option<usize>,
    /// d-current peak during the q step [A].
    pub current_id_peak_a: f64,
    /// Speed step target [rad/s].
    pub speed_step_rad_s: f64,
    /// Speed-step overshoot [%].
    pub speed_overshoot_percent: f64,
    /// Speed-step 2 % settling time [ms].
    pub speed_settling_ms: Option<f64>,
    /// Speed after the ramp [rad/s].
    pub speed_high_rad_s: f64,
    /// Load step [N m].
    pub load_step_nm: f64,
    /// Largest speed dip after the load step [rad/s].
    pub load_dip_rad_s: f64,
    /// Steady speed error at the end of the load segment [rad/s] (ref - mean).
    pub load_steady_error_rad_s: f64,
    /// Recovery into +-2 % of the speed after the load step [ms].
    pub load_recovery_ms: Option<f64>,
    /// The speed loop's further figures (design §19).
    pub speed: SpeedFigures,
    /// Position move [rad].
    pub move_rad: f64,
    /// Position 2 % settling time from the move command [ms].
    pub position_settling_ms: Option<f64>,
    /// Final position error [rad] (true displacement vs commanded).
    pub position_final_error_rad: f64,
    /// One encoder count [rad].
    pub encoder_count_rad: f64,
    /// The braking segment (None: not run).
    pub braking: Option<BrakingSummary>,
    /// The impedance segment (None: not run).
    pub impedance: Option<ImpedanceFigures>,
    /// Faults latched during the mission (names).
    pub faults: Vec<String>,
    /// The model check's largest healthy residual over its bound (design
    /// §24): the false-alarm margin, below 1 on a healthy drive.
    pub model_margin: f64,
    /// The same for the model check's disturbance against its envelope.
    pub model_disturbance_margin: f64,
    /// PWM periods simulated.
    pub periods: usize,
    /// Simulated time [s].
    pub sim_time_s: f64,
    /// Wall-clock time [s].
    pub wall_time_s: f64,
}

impl MissionSummary {
    /// What failed the mission's pass criteria (empty: passed). The criteria
    /// are sanity bounds for any motor; the closed-loop tests hold tighter ones.
    pub fn failures(&self) -> Vec<String> {
        let mut f = Vec::new();
        if !self.faults.is_empty() {
            f.push(format!("faults latched: {}", self.faults.join(", ")));
        }
        let worst = self.model_margin.max(self.model_disturbance_margin);
        if worst.is_nan() || worst >= 1.0 {
            f.push(format!(
                "model check margin {:.2}: a healthy residual reached its bound",
                worst
            ));
        }
        if let Some(e) = &self.identification_failure {
            f.push(format!("identification failed: {e}"));
        }
        if let Some(id) = &self.identification {
            // Issue 9's requirements: R and L within 5 %, flux linkage
            // within 10 %, pole pairs and direction exact (the rotor starts
            // at 0.7 rad here; R no longer depends on the start angle).
            for (name, (_, err)) in [("R", id.r_ohm), ("Ld", id.ld_h), ("Lq", id.lq_h)] {
                if !below(err.abs(), 5.0) {
                    f.push(format!("identified {name} off by {err:+.1} %"));
                }
            }
            if let Some((_, err)) = id.flux_linkage_wb {
                if !below(err.abs(), 10.0) {
                    f.push(format!("identified flux linkage off by {err:+.1} %"));
                }
            }
            // Issue 18: inertia within 10 %, friction within 20 %.
            match &id.mechanics {
                Some(mf) => {
                    if !below(mf.inertia_kg_m2.1.abs(), 10.0) {
                        f.push(format!(
                            "identified inertia off by {:+.1} %",
                            mf.inertia_kg_m2.1
                        ));
                    }
                    for (w, _, e) in mf.torque_at {
                        if !below(e.abs(), 20.0) {
                            f.push(format!(
                                "identified friction at {w:.1} rad/s off by {e:+.1} %"
                            ));
                        }
                    }
                }
                None => f.push("mechanics not identified".into()),
            }
            if id.pole_pairs.0 != id.pole_pairs.1 {
                f.push(format!(
                    "pole pairs {} found, {} true",
                    id.pole_pairs.0, id.pole_pairs.1
                ));
            }
            if id.reversed.0 != id.reversed.1 {
                f.push("sensor direction wrong".into());
            }
        }
        if self.align_error_deg.abs() > 15.0 + self.encoder_count_rad.to_degrees() * 21.0 {
            f.push(format!("alignment error {:.1} deg", self.align_error_deg));
        }
        if !below(self.current_overshoot_percent, 15.0) {
            f.push(format!(
                "current overshoot {:.1} %",
                self.current_overshoot_percent
            ));
        }
        match self.current_settling_periods {
            Some(n) if n <= 30 => {}
            other => f.push(format!("current settling {other:?} periods")),
        }
        if self.speed_settling_ms.is_none() {
            f.push("speed step did not settle".into());
        }
        if !below(
            self.load_steady_error_rad_s.abs(),
            0.02 * self.speed_high_rad_s.abs() + 0.5,
        ) {
            f.push(format!(
                "speed error after load step {:.3} rad/s",
                self.load_steady_error_rad_s
            ));
        }
        let tol = (3.0 * self.encoder_count_rad).max(0.01 * self.move_rad.abs());
        if !below(self.position_final_error_rad.abs(), tol) {
            f.push(format!(
                "position error {:.4} rad (tolerance {tol:.4})",
                self.position_final_error_rad
            ));
        }
        if self.position_settling_ms.is_none() {
            f.push("position did not settle".into());
        }
        if let Some(z) = &self.impedance {
            f.extend(z.failures());
        }
        if let Some(b) = &self.braking {
            for (name, stop) in [("capacitor", &b.capacitor), ("resistor", &b.resistor)] {
                if !below(stop.peak_bus_v, b.over_voltage_v) {
                    f.push(format!(
                        "braking ({name}): bus {:.2} V, over-voltage threshold {:.2} V",
                        stop.peak_bus_v, b.over_voltage_v
                    ));
                }
                if !stop.faults.is_empty() {
                    f.push(format!(
                        "braking ({name}): faults latched: {}",
                        stop.faults.join(", ")
                    ));
                }
            }
        }
        f
    }

    /// The summary as Markdown.
    pub fn to_markdown(&self) -> String {
        let opt_ms =
            |x: Option<f64>| x.map_or("did not settle".to_string(), |v| format!("{v:.1} ms"));
        let mut s = String::new();
        let _ = writeln!(s, "# Simulation: {}\n", self.motor);
        let _ = writeln!(
            s,
            "PWM {:.0} Hz; speed loop every {} periods, position loop every {}; {} periods ({:.3} s simulated) in {:.2} s wall time.\n",
            self.pwm_hz, self.dividers.0, self.dividers.1, self.periods, self.sim_time_s, self.wall_time_s
        );
        s.push_str("| figure | value |\n|---|---:|\n");
        let mut row = |k: &str, v: String| {
            let _ = writeln!(s, "| {k} | {v} |");
        };
        if self.restored {
            row(
                "calibration",
                "restored from the stored configuration (no identification)".into(),
            );
        }
        match &self.identification {
            Some(id) => {
                row(
                    "identification time (offsets + identification)",
                    format!(
                        "{:.3} s + {:.2} s simulated ({:.2} s wall)",
                        id.offset_time_s, id.time_s, id.wall_time_s
                    ),
                );
                row(
                    "identified R / error",
                    format!("{:.4} ohm / {:+.2} %", id.r_ohm.0, id.r_ohm.1),
                );
                row(
                    "identified Ld / error",
                    format!("{:.2} uH / {:+.2} %", id.ld_h.0 * 1e6, id.ld_h.1),
                );
                row(
                    "identified Lq / error",
                    format!("{:.2} uH / {:+.2} %", id.lq_h.0 * 1e6, id.lq_h.1),
                );
                row(
                    "identified flux linkage / error",
                    id.flux_linkage_wb.map_or("not measured".into(), |(v, e)| {
                        format!("{:.3} mWb / {e:+.2} %", v * 1e3)
                    }),
                );
                if let Some(mf) = &id.mechanics {
                    row(
                        "identified inertia / error",
                        format!(
                            "{:.4e} kg m^2 / {:+.2} %",
                            mf.inertia_kg_m2.0, mf.inertia_kg_m2.1
                        ),
                    );
                    row(
                        "identified friction (plant)",
                        format!(
                            "B {:.3e} N m s/rad, Fc {:.4} N m ({:.3e}, {:.4}); at {:.1} rad/s {:+.2} %, at {:.1} rad/s {:+.2} %",
                            mf.friction.0,
                            mf.friction.1,
                            mf.plant_friction.0,
                            mf.plant_friction.1,
                            mf.torque_at[0].0,
                            mf.torque_at[0].2,
                            mf.torque_at[1].0,
                            mf.torque_at[1].2
                        ),
                    );
                }
                row(
                    "pole pairs found (plant)",
                    format!("{} ({})", id.pole_pairs.0, id.pole_pairs.1),
                );
                let dir = |r: bool| if r { "reversed" } else { "forward" };
                row(
                    "sensor direction found (plant)",
                    format!("{} ({})", dir(id.reversed.0), dir(id.reversed.1)),
                );
            }
            None if self.restored => {}
            None => row(
                "identification",
                format!(
                    "FAILED: {} (mission run on the supplied calibration)",
                    self.identification_failure.as_deref().unwrap_or("?")
                ),
            ),
        }
        row(
            if self.restored {
                "stored electrical zero / error"
            } else {
                "identified electrical zero / error"
            },
            format!(
                "{:.2} deg / {:+.2} deg",
                self.align_found_deg, self.align_error_deg
            ),
        );
        row(
            "q-current step",
            format!(
                "{:.2} A{}",
                self.current_step_a,
                if self.current_step_magnitude {
                    " (figures of the true current's magnitude: hall-class sensor)"
                } else {
                    ""
                }
            ),
        );
        row(
            "q-current overshoot",
            format!("{:.2} %", self.current_overshoot_percent),
        );
        row(
            "q-current 2 % settling",
            self.current_settling_periods
                .map_or("did not settle".into(), |n| format!("{n} PWM periods")),
        );
        row(
            "d-current peak during the q step",
            format!("{:.3} A", self.current_id_peak_a),
        );
        row("speed step", format!("{:.1} rad/s", self.speed_step_rad_s));
        row(
            "speed overshoot",
            format!("{:.2} %", self.speed_overshoot_percent),
        );
        row("speed 2 % settling", opt_ms(self.speed_settling_ms));
        row(
            "speed after ramp",
            format!("{:.1} rad/s", self.speed_high_rad_s),
        );
        row("load step", format!("{:.4} N m", self.load_step_nm));
        row(
            "speed dip after load step",
            format!("{:.3} rad/s", self.load_dip_rad_s),
        );
        row(
            "steady speed error with load",
            format!("{:+.4} rad/s", self.load_steady_error_rad_s),
        );
        row("recovery into +-2 %", opt_ms(self.load_recovery_ms));
        let sp = &self.speed;
        row(
            "speed rise after load release",
            format!("{:.3} rad/s", sp.release_rise_rad_s),
        );
        row(
            "recovery into +-2 % after release",
            opt_ms(sp.release_recovery_ms),
        );
        row(
            "speed-estimate error while the step accelerates",
            format!(
                "{:.3} rad/s ({:.2} % of the step; peak acceleration {:.0} rad/s^2)",
                sp.estimate_error.0, sp.estimate_error.1, sp.step_peak_acceleration_rad_s2
            ),
        );
        row(
            "current-limited speed step",
            format!(
                "{:.1} rad/s, current limit {:.2} A (q current on it for {:.1} ms, peak acceleration {:.0} rad/s^2)",
                sp.sat_step_rad_s, sp.sat_limit_a, sp.sat_limited_ms, sp.sat_peak_acceleration_rad_s2
            ),
        );
        row(
            "current-limited step overshoot",
            format!("{:.2} %", sp.sat_overshoot_percent),
        );
        row(
            "current-limited step 2 % settling",
            opt_ms(sp.sat_settling_ms),
        );
        row(
            "speed-estimate error while it accelerates",
            format!(
                "{:.3} rad/s ({:.2} % of the step)",
                sp.sat_estimate_error.0, sp.sat_estimate_error.1
            ),
        );
        let (e, a) = sp.fastest_estimate_error();
        row(
            "speed-estimate error at the mission's fastest acceleration",
            format!("{e:.2} % of its step ({a:.0} rad/s^2)"),
        );
        row("position move", format!("{:.4} rad", self.move_rad));
        row("position 2 % settling", opt_ms(self.position_settling_ms));
        row(
            "position final error",
            format!(
                "{:+.5} rad ({:.2} encoder counts)",
                self.position_final_error_rad,
                self.position_final_error_rad / self.encoder_count_rad
            ),
        );
        if let Some(z) = &self.impedance {
            row("impedance (design §21)", z.describe());
        }
        if let Some(b) = &self.braking {
            row(
                "braking: DC link",
                format!(
                    "{} ({:.0} uF), {:.1} V supply that cannot sink current; over-voltage threshold {:.2} V, regen ramp {:.2} -> {:.2} V",
                    b.link,
                    b.c_f * 1e6,
                    b.v_source_v,
                    b.over_voltage_v,
                    b.regen_v.0,
                    b.regen_v.1
                ),
            );
            let how = |st: &StopFigures| {
                if st.ramp_s > 0.0 {
                    format!("ramp to 0 in {:.0} ms", st.ramp_s * 1e3)
                } else {
                    "hard stop".to_string()
                }
            };
            for (name, stop) in [
                (
                    format!("braking into the capacitor ({})", how(&b.capacitor)),
                    &b.capacitor,
                ),
                (
                    format!(
                        "braking with a {:.1} ohm brake resistor ({})",
                        b.resistor_ohm,
                        how(&b.resistor)
                    ),
                    &b.resistor,
                ),
            ] {
                row(
                    &name,
                    format!(
                        "from {:.1} rad/s: peak bus {:.2} V, stop {}; kinetic {:.3} J -> capacitor {:.3} J, resistor {:.3} J, copper {:.3} J, friction {:.3} J (supply {:+.3} J); regen limit active {:.1} ms, chopper on {:.1} ms",
                        stop.from_rad_s,
                        stop.peak_bus_v,
                        stop.stop_s.map_or(
                            format!(
                                "{:.1} rad/s after {:.0} ms (not stopped)",
                                stop.end_rad_s,
                                BRAKE_STOP_S * 1e3
                            ),
                            |t| format!("{:.1} ms", t * 1e3)
                        ),
                        stop.kinetic_j,
                        stop.capacitor_j,
                        stop.resistor_j,
                        stop.copper_j,
                        stop.friction_j,
                        stop.source_j,
                        stop.regen_limited_periods as f64 / self.pwm_hz as f64 * 1e3,
                        stop.brake_periods as f64 / self.pwm_hz as f64 * 1e3,
                    ),
                );
            }
        }
        row(
            "model check: largest healthy residual / bound, disturbance / envelope",
            format!(
                "{:.2}, {:.2}",
                self.model_margin, self.model_disturbance_margin
            ),
        );
        row(
            "faults",
            if self.faults.is_empty() {
                "none".into()
            } else {
                self.faults.join(", ")
            },
        );
        let fails = self.failures();
        let _ = writeln!(
            s,
            "\nResult: {}",
            if fails.is_empty() {
                "PASS".to_string()
            } else {
                format!("FAIL ({})", fails.join("; "))
            }
        );
        s
    }
}

/// `x < limit`, false for NaN.
fn below(x: f64, limit: f64) -> bool {
    x < limit
}

/// A finished mission.
#[derive(Clone, Debug)]
pub struct MissionResult {
    /// The full-rate trace (one row per PWM period).
    pub trace: Trace,
    /// Its segments.
    pub segments: Vec<Segment>,
    /// The measured figures.
    pub summary: MissionSummary,
    /// The configuration the mission ended with (identified or restored),
    /// as the drive would save it.
    pub record: foc_store::DriveRecord,
}

impl MissionResult {
    /// The segment called `name`.
    pub fn segment(&self, name: &str) -> Option<&Segment> {
        self.segments.iter().find(|s| s.name == name)
    }

    /// Rows `seg` of the trace as a new trace (time from the segment start).
    pub fn slice(&self, seg: &Segment) -> Trace {
        let names: Vec<&str> = self.trace.names().iter().map(String::as_str).collect();
        let mut t = Trace::new(&names);
        let cols: Vec<&[f64]> = names.iter().filter_map(|n| self.trace.column(n)).collect();
        let t0 = self.trace.time_s().get(seg.start).copied().unwrap_or(0.0);
        for r in seg.start..seg.end.min(self.trace.len()) {
            let row: Vec<f64> = cols.iter().map(|c| c[r]).collect();
            t.push(self.trace.time_s()[r] - t0, &row);
        }
        t
    }

    /// Every `k`-th row, at most `max_rows` rows (for plots of long runs).
    pub fn decimated(&self, max_rows: usize) -> Trace {
        decimate(&self.trace, max_rows)
    }

    /// Rows `start..end` of the trace, times unchanged (simulation time).
    pub fn rows(&self, start: usize, end: usize) -> Trace {
        let names: Vec<&str> = self.trace.names().iter().map(String::as_str).collect();
        let mut t = Trace::new(&names);
        let cols: Vec<&[f64]> = names.iter().filter_map(|n| self.trace.column(n)).collect();
        for r in start..end.min(self.trace.len()) {
            let row: Vec<f64> = cols.iter().map(|c| c[r]).collect();
            t.push(self.trace.time_s()[r], &row);
        }
        t
    }

    /// Write into `dir`: `identification.csv` and `identification.svg`
    /// (the identify segment, decimated to at most 20 000 and 4000 rows:
    /// it is most of the simulated time), `mission.csv` (every PWM period
    /// from the end of the identification on, simulation time),
    /// `mission.svg` (the same, decimated), `current_step.csv`,
    /// `current_step.svg`, `speed.svg`, `position.svg`, `braking.svg` and
    /// `summary.md`.
    /// Returns the paths.
    pub fn write(&self, dir: &Path) -> std::io::Result<Vec<std::path::PathBuf>> {
        std::fs::create_dir_all(dir)?;
        let mut out = Vec::new();
        let id_end = self.segment("identify").map_or(0, |s| s.end);
        if let Some(seg) = self.segment("identify") {
            let t = self.rows(seg.start, seg.end);
            let p = dir.join("identification.csv");
            decimate(&t, 20_000).write_csv(&p)?;
            out.push(p);
            let k = t.len().div_ceil(4000).max(1);
            let p = dir.join("identification.svg");
            crate::report::plot_svg(
                &p,
                &format!(
                    "Identification: {} (offsets, R, L, alignment sweeps, flux; every {k}-th period)",
                    self.summary.motor
                ),
                &decimate(&t, 4000),
                &[
                    Panel::new("d current", "A", &["id_ref_a", "id_a"]),
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
                    Panel::new("dq voltages", "V", &["vd_v", "vq_v"]),
                    Panel::new(
                        "speed",
                        "rad/s",
                        &["speed_ref_rad_s", "speed_rad_s", "speed_est_rad_s"],
                    ),
                    Panel::new(
                        "position (rotor, mechanical, true, bench's encoder frame)",
                        "rad",
                        &["position_rad"],
                    ),
                    mode_panel(),
                    Panel::new("bridge on (0 off, 1 on)", "flag", &["bridge_on"]),
                ],
            )?;
            out.push(p);
        }
        let closed = self.rows(id_end, self.trace.len());
        let p = dir.join("mission.csv");
        closed.write_csv(&p)?;
        out.push(p);
        let (closed_plot, true_in_drive) =
            with_true_position_in_drive_frame(decimate(&closed, 4000));
        let mission_panels = [
            Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
            Panel::new("d current", "A", &["id_ref_a", "id_a"]),
            Panel::new("dq voltages", "V", &["vd_v", "vq_v"]),
            Panel::new(
                "speed",
                "rad/s",
                &["speed_ref_rad_s", "speed_rad_s", "speed_est_rad_s"],
            ),
            Panel::new(POSITION_PANEL, "rad", &["position_ref_rad", &true_in_drive]),
            Panel::new("PWM duty", "1", &["duty_a", "duty_b", "duty_c"]),
            Panel::new("bus voltage", "V", &["v_bus_v"]),
            Panel::new("load torque", "N m", &["load_nm"]),
            mode_panel(),
        ];
        let p = dir.join("mission.svg");
        crate::report::plot_svg(
            &p,
            &format!(
                "Mission after the identification: {} (every {}-th period)",
                self.summary.motor,
                closed.len().div_ceil(4000).max(1)
            ),
            &closed_plot,
            &mission_panels,
        )?;
        out.push(p);
        if let Some(seg) = self.segment("current step") {
            let zoom = Segment {
                name: "zoom",
                start: seg.start.saturating_sub(5),
                end: (seg.start + 80).min(seg.end),
            };
            let t = self.slice(&zoom);
            let p = dir.join("current_step.csv");
            t.write_csv(&p)?;
            out.push(p);
            let p = dir.join("current_step.svg");
            // The first row with the new reference.
            let step_at = t.time_s().get(seg.start - zoom.start).copied();
            crate::report::plot_svg_marked(
                &p,
                &format!(
                    "q-current step, rotor locked: {} ({:.2} % overshoot)",
                    self.summary.motor, self.summary.current_overshoot_percent
                ),
                &t,
                &[
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a", "iq_true_a"]),
                    Panel::new("d current", "A", &["id_ref_a", "id_a"]),
                    Panel::new("dq voltages", "V", &["vd_v", "vq_v"]),
                ],
                "time [s]",
                step_at.map(|t| (t, "step")),
            )?;
            out.push(p);
        }
        for (name, file, panels) in [
            (
                "speed step",
                "speed",
                vec![
                    Panel::new(
                        "speed",
                        "rad/s",
                        &["speed_ref_rad_s", "speed_rad_s", "speed_est_rad_s"],
                    ),
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
                    Panel::new("load torque", "N m", &["load_nm"]),
                ],
            ),
            (
                "position move",
                "position",
                vec![
                    Panel::new(
                        POSITION_PANEL,
                        "rad",
                        &["position_ref_rad", "position_est_rad", TRUE_IN_DRIVE],
                    ),
                    Panel::new("speed", "rad/s", &["speed_ref_rad_s", "speed_rad_s"]),
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
                ],
            ),
        ] {
            if let Some(seg) = self.segment(name) {
                // The speed plot covers step, ramp and load step.
                let end = if name == "speed step" {
                    self.segment("load step").map_or(seg.end, |s| s.end)
                } else {
                    seg.end
                };
                let whole = Segment {
                    name,
                    start: seg.start,
                    end,
                };
                let (dec, true_in_drive) =
                    with_true_position_in_drive_frame(decimate(&self.slice(&whole), 4000));
                let panels: Vec<Panel> = panels
                    .into_iter()
                    .map(|mut p| {
                        for s in &mut p.signals {
                            if s == TRUE_IN_DRIVE {
                                s.clone_from(&true_in_drive);
                            }
                        }
                        p
                    })
                    .collect();
                let p = dir.join(format!("{file}.svg"));
                crate::report::plot_svg(
                    &p,
                    &format!("{name}: {}", self.summary.motor),
                    &dec,
                    &panels,
                )?;
                out.push(p);
            }
        }
        if let (Some(a), Some(b)) = (self.segment("braking"), self.segment("braking, resistor")) {
            let whole = Segment {
                name: "braking",
                start: a.start,
                end: b.end,
            };
            let p = dir.join("braking.svg");
            crate::report::plot_svg(
                &p,
                &format!(
                    "Braking into a supply that cannot sink current (capacitor alone, then a brake resistor): {}",
                    self.summary.motor
                ),
                &decimate(&self.slice(&whole), 4000),
                &[
                    Panel::new("speed", "rad/s", &["speed_ref_rad_s", "speed_rad_s"]),
                    Panel::new("bus voltage", "V", &["v_bus_v"]),
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
                ],
            )?;
            out.push(p);
        }
        let p = dir.join("summary.md");
        std::fs::write(&p, self.summary.to_markdown())?;
        out.push(p);
        Ok(out)
    }
}

/// Title of the position panels: the reference, the drive's estimate and
/// the plant's true position, all in the drive's frame.
const POSITION_PANEL: &str = "position (rotor, mechanical, drive's frame)";

/// Stands for the true position's column in the drive's frame in a panel
/// list (replaced by [`with_true_position_in_drive_frame`]'s name).
const TRUE_IN_DRIVE: &str = "<true position in the drive's frame>";

/// The drive's mode code as its own panel, the codes spelled out.
fn mode_panel() -> Panel {
    let codes: Vec<String> = [
        (Mode::Disabled, "disabled"),
        (Mode::Torque, "torque"),
        (Mode::Velocity, "velocity"),
        (Mode::Position, "position"),
        (Mode::OpenLoop, "open loop"),
        (Mode::Impedance, "impedance"),
    ]
    .iter()
    .map(|(m, name)| format!("{} {name}", *m as u8))
    .collect();
    Panel::new(
        &format!("drive mode ({})", codes.join(", ")),
        "code",
        &["mode"],
    )
}

/// Whole turns `k` with `position_est_rad = position_rad + k 2 pi` over most
/// rows of `trace` (0 without rows that have both).
///
/// The two columns are in different frames: `position_rad` is the plant's
/// true position in the encoder's frame, unwrapped since the simulation
/// started ([`Sim::true_position_rad`]); the drive's position (its
/// estimate `position_est_rad`, its reference `position_ref_rad`) counts
/// turns from the encoder's single-turn reading (0..2 pi) where its angle
/// tracker last restarted (reset, start-up, calibration). So they differ
/// by whole turns, fixed between restarts: after the default mission's
/// identification by -1 turn (6.28 rad).
pub fn drive_frame_turns(trace: &Trace) -> i64 {
    let mut counts: Vec<(i64, usize)> = Vec::new();
    for (t, e) in col(trace, "position_rad")
        .iter()
        .zip(col(trace, "position_est_rad"))
    {
        let k = ((e - t) / std::f64::consts::TAU).round();
        if !k.is_finite() {
            continue;
        }
        let k = k as i64;
        match counts.iter_mut().find(|(kk, _)| *kk == k) {
            Some((_, n)) => *n += 1,
            None => counts.push((k, 1)),
        }
    }
    counts.iter().max_by_key(|(_, n)| *n).map_or(0, |(k, _)| *k)
}

/// `trace` with the true position shifted by [`drive_frame_turns`] whole
/// turns into the drive's frame, and the name of that column
/// (`position_rad` itself when no shift is needed, else e.g.
/// `position_rad - 1 turn`), so that a plot shows the reference, the
/// estimate and the true position in one frame.
pub fn with_true_position_in_drive_frame(trace: Trace) -> (Trace, String) {
    let k = drive_frame_turns(&trace);
    if k == 0 {
        return (trace, "position_rad".into());
    }
    let shift = k as f64 * std::f64::consts::TAU;
    let values: Vec<f64> = col(&trace, "position_rad")
        .iter()
        .map(|p| p + shift)
        .collect();
    let name = format!(
        "position_rad {} {} turn{}",
        if k < 0 { '-' } else { '+' },
        k.unsigned_abs(),
        if k.unsigned_abs() == 1 { "" } else { "s" }
    );
    (trace.with_column(&name, values), name)
}

/// Every `k`-th row of `trace`, at most `max_rows` rows.
pub fn decimate(trace: &Trace, max_rows: usize) -> Trace {
    let k = trace.len().div_ceil(max_rows.max(1)).max(1);
    let names: Vec<&str> = trace.names().iter().map(String::as_str).collect();
    let cols: Vec<&[f64]> = names.iter().filter_map(|n| trace.column(n)).collect();
    let mut t = Trace::new(&names);
    for r in (0..trace.len()).step_by(k) {
        let row: Vec<f64> = cols.iter().map(|c| c[r]).collect();
        t.push(trace.time_s()[r], &row);
    }
    t
}

fn secs(setup: &Setup, s: f64) -> usize {
    (s * setup.bench.pwm_frequency_hz as f64).round().max(1.0) as usize
}

fn col<'a>(t: &'a Trace, name: &str) -> &'a [f64] {
    t.column(name).unwrap_or(&[])
}

fn mean(x: &[f64]) -> f64 {
    if x.is_empty() {
        f64::NAN
    } else {
        x.iter().sum::<f64>() / x.len() as f64
    }
}

/// The crude alignment (the dyno still uses it; the mission identifies the
/// motor with [`crate::identify::run`] instead). Find the electrical zero: open-loop d-axis voltage (30 % of the rated
/// current through R) at `theta_e = 90 deg`, then at `0 deg`, each until the
/// encoder reading has been still for 0.1 s (at most 0.6 s). The reading
/// there, scaled by the pole pairs, is the calibration's `zero_offset`; it is
/// installed in the controller as a [`Calibrated`] permit (with the
/// configured current loop), which is then disabled. Returns the offset
/// found and its error against the plant's true encoder offset [deg, electrical].
pub fn align(sim: &mut Sim, setup: &Setup) -> (ElectricalAngle, f64) {
    let pp = setup.motor.pole_pairs;
    let i_align = (0.3 * setup.rated_current_a).min(0.5 * setup.max_current_a);
    let v_align = (setup.motor.r_ohm as f32 * i_align).max(0.05);
    for theta_deg in [90.0f32, 0.0] {
        // A new open-loop command with a different `theta_e` moves the
        // field there at once (no detour through the safe state).
        sim.cascade
            .command(Command::OpenLoop {
                v_d_v: v_align,
                v_q_v: 0.0,
                theta_e: ElectricalAngle::from_degrees(theta_deg),
                omega_e_rad_s: 0.0,
            })
            .ok();
        let mut last = sim.last_sample().angle;
        let mut still = 0usize;
        let (min_n, max_n, still_n) = (secs(setup, 0.05), secs(setup, 0.6), secs(setup, 0.1));
        for n in 0..max_n {
            sim.step();
            let a = sim.last_sample().angle;
            still = if a == last && n > min_n { still + 1 } else { 0 };
            last = a;
            if still >= still_n {
                break;
            }
        }
    }
    let found = sim.last_sample().angle.to_electrical(pp);
    let truth = setup.true_angle_calibration().zero_offset;
    let error_deg = found.diff_radians(truth).to_degrees() as f64;
    let angle = AngleCalibration {
        pole_pairs: pp,
        zero_offset: found,
        reversed: false,
        sensor_counts_per_rev: 0,
    };
    // The alignment result plus the configured current loop: the permit
    // for the closed-loop segments.
    let permit = Calibrated::supplied(angle, sim.cascade.config().current.current)
        .expect("plausible calibration");
    sim.cascade.set_calibration(&permit);
    sim.cascade.command(Command::Disable).ok();
    sim.run(secs(setup, 0.02));
    (found, error_deg)
}

fn identification_summary(
    setup: &Setup,
    sim: &Sim,
    o: &identify::Outcome,
    r: &IdentificationResult,
    wall_time_s: f64,
) -> IdentificationSummary {
    let m = &setup.motor;
    let with_err = |x: f32, truth: f64| (x as f64, 100.0 * (x as f64 / truth - 1.0));
    let ts = 1.0 / setup.bench.pwm_frequency_hz as f64;
    IdentificationSummary {
        r_ohm: with_err(r.r_ohm, m.r_ohm as f64),
        ld_h: with_err(r.ld_h, m.ld_h as f64),
        lq_h: with_err(r.lq_h, m.lq_h as f64),
        flux_linkage_wb: identify::config(setup, m.pole_pairs)
            .measure_flux
            .then(|| with_err(r.flux_linkage_wb, m.flux_linkage_wb as f64)),
        mechanics: r.mechanics.map(|x| {
            let (b, fc) = (
                x.viscous_friction_nm_s_per_rad as f64,
                x.coulomb_friction_nm as f64,
            );
            let (bp, fcp) = (m.viscous_friction_nm_s_per_rad, m.coulomb_friction_nm);
            let at = |w: f32| {
                let w = w.abs() as f64;
                let id = fc + b * w;
                (w, id, 100.0 * (id / (fcp + bp * w) - 1.0))
            };
            MechanicsFigures {
                inertia_kg_m2: with_err(x.inertia_kg_m2, m.inertia_kg_m2),
                friction: (b, fc),
                plant_friction: (bp, fcp),
                torque_at: [at(x.speeds_rad_s[0]), at(x.speeds_rad_s[1])],
            }
        }),
        pole_pairs: (r.pole_pairs, m.pole_pairs),
        reversed: (r.angle.reversed, sim.plant.faults().encoder_reversed),
        offsets_a: [o.offsets.a as f64, o.offsets.b as f64, o.offsets.c as f64],
        offset_time_s: o.offset_periods as f64 * ts,
        time_s: o.periods as f64 * ts,
        wall_time_s,
    }
}

/// Run the mission on `setup`. `progress` is called with the fraction done (0..=1).
pub fn run_mission(setup: &Setup, progress: &mut dyn FnMut(f64)) -> MissionResult {
    match run_mission_from(setup, None, progress) {
        Ok(r) => r,
        // Without a record there is nothing to refuse.
        Err(e) => unreachable!("{e}"),
    }
}

/// [`run_mission`], starting from a stored configuration when `stored` is
/// given (design §17): its settings on top of the setup's, and its
/// calibration installed by the drive's start-up (the bench's encoder
/// reads the same angle for the same rotor position after every start, as
/// an absolute sensor does) instead of an identification. The rest of the
/// mission is the same; its alignment figure then measures the stored
/// electrical zero against the plant's truth. `Err` when the record does
/// not apply to this setup (another PWM frequency, a value out of range,
/// no calibration) or the start-up does not install it.
pub fn run_mission_from(
    setup: &Setup,
    stored: Option<&foc_store::DriveRecord>,
    progress: &mut dyn FnMut(f64),
) -> Result<MissionResult, String> {
    let wall = Instant::now();
    // Without a stored record the drive knows nothing of the rotor's
    // mechanics until its identification has measured them.
    let base = match stored {
        Some(_) => setup.cascade_config(),
        None => setup.unidentified_config(),
    };
    let settings = match stored {
        Some(r) => Some(
            r.apply(&foc_store::Settings::from_cascade(&base), pwm_hz_u32(setup))
                .map_err(|e| e.to_string())?,
        ),
        None => None,
    };
    let config = settings.map_or(base, |s| s.apply_to(&base));
    let sim = Sim::new(setup, config, true);
    let plan = MissionPlan::new(setup, &config);
    let total = secs(setup, plan.expected_s).max(1);
    let mut m = Mission {
        setup,
        config,
        plan,
        sim,
        segments: Vec::new(),
        progress: Progress {
            report: progress,
            total,
        },
    };

    // The rotor starts somewhere arbitrary.
    m.sim.set_rotor_angle(0.7);

    let identified = match &settings {
        None => m.identify(),
        Some(s) => m.restore(s)?,
    };
    let i_step = m.current_step(&identified.config);
    m.speed_step();
    m.ramp();
    let load = m.load_step();
    m.load_release();
    m.stop();
    m.saturated_step();
    let p0_true = m.position_move();
    let impedance = m.impedance();
    let braking = m.braking();
    (m.progress.report)(1.0);

    let trace = m.sim.take_trace().unwrap_or_default();
    let record = m.record(settings.map_or(auto_link(setup), |s| s.watchdog));
    let mut summary = m.summary(&trace, identified, i_step, load, p0_true, wall);
    summary.restored = stored.is_some();
    summary.braking = Some(braking);
    summary.impedance = Some(impedance);
    Ok(MissionResult {
        trace,
        segments: m.segments,
        summary,
        record,
    })
}

/// The link-watchdog setting a record made by the bench carries: the
/// firmware's automatic one (1 s, stop).
fn auto_link(setup: &Setup) -> foc_store::record::WatchdogRecord {
    foc_store::record::WatchdogRecord {
        timeout_periods: pwm_hz_u32(setup),
        reaction: foc_store::record::WatchdogReaction::Stop,
    }
}

/// The setup's PWM frequency as a record states it [Hz].
fn pwm_hz_u32(setup: &Setup) -> u32 {
    setup.pwm_hz().round() as u32
}

/// The mission's speeds and durations, derived from the setup before it
/// starts.
struct MissionPlan {
    /// Torque constant [N m / A].
    kt: f32,
    /// Speed step target [rad/s].
    w1: f32,
    /// Speed at the end of the ramp [rad/s].
    w2: f32,
    /// Duration of the ramp (and of the stop) [s].
    t_ramp: f64,
    /// Duration of the current-limited step [s].
    t_sat: f64,
    /// Its current limit [A].
    i_sat: f32,
    /// Position move [rad].
    move_rad: f32,
    /// Duration of the position move [s].
    t_move: f64,
    /// Speed-loop divider of the initial configuration.
    speed_div: usize,
    /// The identification's configuration.
    id_cfg: foc_core::calibration::identification::IdentificationConfig,
    /// Expected duration of the whole mission, for the progress bar [s].
    expected_s: f64,
}

impl MissionPlan {
    fn new(setup: &Setup, config: &CascadeConfig) -> Self {
        let kt = setup.kt();
        let j = setup.motor.inertia_kg_m2 as f32;
        let w_max = setup.max_speed_rad_s();
        let i_max = setup.max_current_a;
        let speed_div = config.rates.speed_divider.max(1) as usize;
        // Speeds: within the voltage and current limits, and at most one
        // electrical turn per 10 PWM periods (`Setup::max_mission_speed_rad_s`).
        let w_cap = (0.6 * w_max).min(setup.max_mission_speed_rad_s());
        let w1 = (0.4 * w_cap).min(0.4 * i_max * kt / (j * 2.0 * std::f32::consts::PI * 20.0));
        let w2 = w_cap.max(w1);
        let a_ramp = 0.3 * kt * i_max / j;
        let t_ramp = ((w2 - w1) / a_ramp).max(0.1) as f64;
        // The current-limited step: at most the limit's acceleration, then
        // time to settle.
        let i_sat = i_max.min(0.5 * config.speed.kp_a_per_rad_s * w2);
        let t_sat = (w2 * j / (kt * i_sat)) as f64 * 1.5 + 0.4;
        let move_rad = std::f32::consts::TAU;
        let v_traj = config.position.max_velocity_rad_s;
        let a_traj = config.position.max_acceleration_rad_s2;
        let t_move = (move_rad / v_traj + v_traj / a_traj) as f64 + 0.6;
        let id_cfg = identify::config(setup, setup.motor.pole_pairs);
        // The alignment's calibration carries the sensor's resolution, so the
        // current stage adds the half count of a counting sensor to every
        // reading: the zero found is the physical one and the angle the
        // controller uses is unbiased (this matters on the hall-class hub
        // motor: half a count is 30 deg(e) there).
        // Identification: offsets, R and L (about 1 s), both alignment sweeps
        // with their holds, the flux step (about 2 s).
        let a = &id_cfg.alignment;
        let t_align = 2.0
            * (f32::from(a.lead_in_turns_e + a.turns_e) * std::f32::consts::TAU / a.speed_e_rad_s
                + a.hold_s);
        let t_id = 0.1 + 1.0 + t_align as f64 + if id_cfg.measure_flux { 2.0 } else { 0.0 };
        let expected_s = t_id
            + 0.03
            + 0.5
            + t_ramp
            + 0.3
            + 0.6
            + t_ramp
            + 0.4
            + 0.4
            + t_sat
            + t_ramp
            + 0.3
            + t_move
            + 2.0 * (BRAKE_SPIN_S + BRAKE_STOP_S);
        Self {
            kt,
            w1,
            w2,
            t_ramp,
            t_sat,
            i_sat,
            move_rad,
            t_move,
            speed_div,
            id_cfg,
            expected_s,
        }
    }
}

/// The braking segment's longest spin-up before each stop [s].
const BRAKE_SPIN_S: f64 = 1.0;
/// The braking segment's time after each stop command [s].
const BRAKE_STOP_S: f64 = 0.4;

/// The progress callback and the expected number of periods.
struct Progress<'a> {
    report: &'a mut dyn FnMut(f64),
    total: usize,
}

impl Progress<'_> {
    /// Report the fraction done every 2048 rows.
    fn tick(&mut self, sim: &Sim) {
        if sim.rows().is_multiple_of(2048) {
            (self.report)((sim.rows() as f64 / self.total as f64).min(1.0));
        }
    }
}

/// What the identification segment left for the rest of the mission.
struct Identified {
    /// Its figures (None: it failed).
    summary: Option<IdentificationSummary>,
    /// Why it failed.
    failure: Option<String>,
    /// The electrical zero in use after it.
    found: ElectricalAngle,
    /// Error of `found` against the plant's truth [deg, electrical].
    align_error_deg: f64,
    /// The measured configuration, used from here on.
    config: CascadeConfig,
}

/// A mission in progress: the simulation and the segments run so far.
struct Mission<'a> {
    setup: &'a Setup,
    /// The configuration before identification.
    config: CascadeConfig,
    plan: MissionPlan,
    sim: Sim,
    segments: Vec<Segment>,
    progress: Progress<'a>,
}

impl Mission<'_> {
    /// Run `n` periods, reporting progress.
    fn run_ticking(&mut self, n: usize) {
        for _ in 0..n {
            self.sim.step();
            self.progress.tick(&self.sim);
        }
    }

    /// Record the segment `name` from row `start` to now.
    fn end_segment(&mut self, name: &'static str, start: usize) {
        self.segments.push(Segment {
            name,
            start,
            end: self.sim.rows(),
        });
    }

    /// Segment 1, identify: current offsets, R, L, gains, alignment, flux
    /// linkage. On failure the rest runs on the supplied calibration.
    fn identify(&mut self) -> Identified {
        let setup = self.setup;
        let start = self.sim.rows();
        let id_wall = Instant::now();
        let progress = &mut self.progress;
        let outcome = identify::run(&mut self.sim, setup, self.plan.id_cfg, &mut |s| {
            progress.tick(s)
        });
        let id_wall_s = id_wall.elapsed().as_secs_f64();
        let (summary, failure) = match &outcome {
            Ok(o) => match o.identified() {
                Some(d) => (
                    Some(identification_summary(
                        setup, &self.sim, o, &d.result, id_wall_s,
                    )),
                    None,
                ),
                None => (None, Some(format!("{:?} in {:?}", o.step, o.stage))),
            },
            Err(e) => (None, Some(e.to_string())),
        };
        if summary.is_none() {
            // Run the rest on the bench's knowledge so that the report is
            // complete; `failures()` reports the identification failure.
            self.sim.cascade.command(Command::Disable).ok();
            self.sim.cascade.clear_faults();
            self.sim
                .cascade
                .set_calibration(&setup.supplied_calibration(&self.config));
        }
        self.sim.run(secs(setup, 0.02));
        self.end_segment("identify", start);
        let found = self.sim.cascade.current.config().angle.zero_offset;
        let align_error_deg = found
            .diff_radians(setup.true_angle_calibration().zero_offset)
            .to_degrees() as f64;
        Identified {
            summary,
            failure,
            found,
            align_error_deg,
            config: *self.sim.cascade.config(),
        }
    }

    /// Segment 1 from a stored configuration: the drive's start-up (offsets,
    /// sensor check) installs the stored permit, no identification.
    fn restore(&mut self, s: &foc_store::Settings) -> Result<Identified, String> {
        let setup = self.setup;
        let permit = s.permit().ok_or(
            "the configuration has no calibration (save one with `cargo xtask sim --save-config FILE`)",
        )?;
        let start = self.sim.rows();
        let mut life = identify::lifecycle_config(&self.sim, setup, self.plan.id_cfg);
        life.identify_at_start_up = false;
        life.angle_kind = foc_core::drive::AngleKind::Absolute;
        life.stored = Some(permit);
        self.sim.cascade = Cascade::from_reset(self.config, life);
        let limit = secs(setup, 1.0);
        let mut restored = false;
        for _ in 0..limit {
            self.sim.step();
            match self.sim.cascade.last_output().and_then(|o| o.event) {
                Some(foc_core::drive::Event::CalibrationRestored) => {
                    restored = true;
                    break;
                }
                Some(e @ foc_core::drive::Event::StartUpDone)
                | Some(e @ foc_core::drive::Event::OffsetsFailed(_))
                | Some(e @ foc_core::drive::Event::CurrentSenseFailed)
                | Some(e @ foc_core::drive::Event::SensorCheckFailed) => {
                    return Err(format!("start-up did not restore the calibration: {e:?}"))
                }
                _ => {}
            }
        }
        if !restored {
            return Err("start-up did not end within 1 s simulated".into());
        }
        self.sim.run(secs(setup, 0.02));
        self.end_segment("identify", start);
        let found = self.sim.cascade.current.config().angle.zero_offset;
        let align_error_deg = found
            .diff_radians(setup.true_angle_calibration().zero_offset)
            .to_degrees() as f64;
        Ok(Identified {
            summary: None,
            failure: None,
            found,
            align_error_deg,
            config: *self.sim.cascade.config(),
        })
    }

    /// The configuration in force as a record (calibrated when the stage is).
    fn record(&self, link: foc_store::record::WatchdogRecord) -> foc_store::DriveRecord {
        let c = self.sim.cascade.config();
        let mut s = foc_store::Settings::from_cascade(c);
        s.calibrated = self.sim.cascade.is_calibrated();
        s.watchdog = link;
        let mut label = foc_store::Label::new();
        for ch in self.setup.name.chars().filter(|c| (' '..='~').contains(c)) {
            if label.push(ch).is_err() {
                break;
            }
        }
        foc_store::DriveRecord::from_settings(&label, pwm_hz_u32(self.setup), &s)
    }

    /// Segment 2, q-current step with the rotor locked. Returns the step [A].
    fn current_step(&mut self, config: &CascadeConfig) -> f32 {
        let setup = self.setup;
        let sim = &mut self.sim;
        sim.plant.set_mechanics(Mechanics::Locked);
        let v_lin = 0.95 * setup.bench.bus_voltage_v as f32 / 3f32.sqrt();
        let kp = config.current.current.q_gains.kp_v_per_a;
        // As large as the voltage allows (the first step's voltage is about
        // Kp * I_step), so that the ADC's quantisation is small against the 2 % band.
        let i_step = (0.5 * setup.rated_current_a)
            .min(0.8 * v_lin / kp)
            .min(0.5 * setup.max_current_a);
        sim.cascade.command(Command::Torque { iq_a: 0.0 }).ok();
        sim.run(20);
        let start = sim.rows();
        sim.cascade.command(Command::Torque { iq_a: i_step }).ok();
        sim.run(secs(setup, 0.02).max(150));
        self.end_segment("current step", start);
        let sim = &mut self.sim;
        sim.cascade.command(Command::Torque { iq_a: 0.0 }).ok();
        sim.run(secs(setup, 0.005).max(50));
        sim.plant.set_mechanics(Mechanics::Free);
        // At rest before the speed step: the speed observer's disturbance
        // estimate unlearns the locked rotor (design §19).
        sim.run(secs(setup, 0.05));
        i_step
    }

    /// Segment 3a, speed step 0 -> `w1`.
    fn speed_step(&mut self) {
        let start = self.sim.rows();
        let w1 = self.plan.w1;
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: w1 })
            .ok();
        self.run_ticking(secs(self.setup, 0.5));
        self.end_segment("speed step", start);
    }

    /// Segment 3b, ramp `w1` -> `w2`, then a hold at `w2`.
    fn ramp(&mut self) {
        let start = self.sim.rows();
        self.velocity_ramp(self.plan.w1, self.plan.w2);
        self.run_ticking(secs(self.setup, 0.3));
        self.end_segment("ramp", start);
    }

    /// A linear velocity ramp `from` -> `to` [rad/s] over the plan's ramp
    /// time (a new command every speed-loop period), then `to` held.
    fn velocity_ramp(&mut self, from: f32, to: f32) {
        let speed_div = self.plan.speed_div;
        let n = secs(self.setup, self.plan.t_ramp);
        for k in 0..n {
            if k % speed_div == 0 {
                let w = from + (to - from) * (k as f32 / n as f32);
                self.sim
                    .cascade
                    .command(Command::Velocity { rad_s: w })
                    .ok();
            }
            self.sim.step();
            self.progress.tick(&self.sim);
        }
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: to })
            .ok();
    }

    /// Segment 4, load step at `w2`. Returns the load [N m].
    fn load_step(&mut self) -> f32 {
        let load = 0.4 * self.plan.kt * self.setup.rated_current_a;
        let start = self.sim.rows();
        self.sim.load_nm = load;
        self.run_ticking(secs(self.setup, 0.6));
        self.end_segment("load step", start);
        load
    }

    /// Segment 4b, load release at `w2`.
    fn load_release(&mut self) {
        let start = self.sim.rows();
        self.sim.load_nm = 0.0;
        self.run_ticking(secs(self.setup, 0.4));
        self.end_segment("load release", start);
    }

    /// Segment 5a, stop: ramp down to rest.
    fn stop(&mut self) {
        self.sim.load_nm = 0.0;
        let start = self.sim.rows();
        self.velocity_ramp(self.plan.w2, 0.0);
        self.run_ticking(secs(self.setup, 0.4));
        self.end_segment("stop", start);
    }

    /// Segment 5b, a speed step from rest to `w2` with the current limit
    /// lowered to `i_sat` (half what the proportional gain asks for at
    /// the step), so that the q current meets its limit, then a ramp back
    /// to rest with the limit restored.
    fn saturated_step(&mut self) {
        let start = self.sim.rows();
        let w = self.plan.w2;
        let limits = self.sim.cascade.current.config().limits;
        self.sim
            .cascade
            .current
            .set_limits(foc_core::control::Limits {
                max_current_a: self.plan.i_sat,
                ..limits
            });
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: w })
            .ok();
        self.run_ticking(secs(self.setup, self.plan.t_sat));
        self.sim.cascade.current.set_limits(limits);
        self.end_segment("current-limited step", start);
        let start = self.sim.rows();
        self.velocity_ramp(w, 0.0);
        self.run_ticking(secs(self.setup, 0.3));
        self.end_segment("stop 2", start);
    }

    /// Segment 5c, position move of one turn. Returns the true position at
    /// its start [rad].
    fn position_move(&mut self) -> f64 {
        let start = self.sim.rows();
        let p0_est = self.sim.cascade.feedback().position_rad;
        let p0_true = self.sim.true_position_rad();
        let target = p0_est + self.plan.move_rad;
        self.sim
            .cascade
            .command(Command::Position { rad: target })
            .ok();
        self.run_ticking(secs(self.setup, self.plan.t_move));
        self.end_segment("position move", start);
        p0_true
    }

    /// Segment 6, impedance (design §21): see the module docs.
    fn impedance(&mut self) -> ImpedanceFigures {
        let setup = self.setup;
        let t_max = setup.kt() * setup.max_current_a;
        let count = std::f32::consts::TAU / setup.bench.sensors.encoder_counts_per_rev as f32;
        let kp = 0.3 * t_max / (0.25f32).max(40.0 * count);
        let j = self
            .sim
            .cascade
            .config()
            .mechanics
            .map_or(setup.motor.inertia_kg_m2 as f32, |m| m.inertia_kg_m2);
        let kd = 1.4 * (kp * j).sqrt();
        let start = self.sim.rows();
        let p = self.sim.cascade.feedback().position_rad;
        let cmd = Command::Impedance(foc_core::control::joint::Impedance {
            position_rad: p,
            velocity_rad_s: 0.0,
            kp_nm_per_rad: kp,
            kd_nm_s_per_rad: kd,
            torque_ff_nm: 0.0,
            torque_limit_nm: f32::INFINITY,
        });
        self.sim.cascade.command(cmd).ok();
        self.run_ticking(secs(setup, 0.2));
        let load = 0.3 * t_max;
        let hold = |m: &mut Self, l: f32| {
            m.sim.load_nm = l;
            m.run_ticking(secs(setup, 0.5));
            let n = secs(setup, 0.1);
            let (mut t, mut x) = (0.0, 0.0);
            for _ in 0..n {
                m.run_ticking(1);
                t += m.sim.plant.torque_nm() as f64;
                x += m.sim.true_position_rad();
            }
            (t / n as f64, x / n as f64)
        };
        let (t1, x1) = hold(self, load);
        let (t2, x2) = hold(self, -load);
        let wn = (kp as f64 / j as f64).sqrt() / 5.0;
        let cycle = secs(setup, std::f64::consts::TAU / wn);
        let ts = 1.0 / setup.bench.pwm_frequency_hz as f64;
        let (mut xs, mut vs, mut tq) = (vec![], vec![], vec![]);
        for k in 0..8 * cycle {
            self.sim.load_nm = load * (wn * k as f64 * ts).sin() as f32;
            self.run_ticking(1);
            if k >= 4 * cycle {
                xs.push(self.sim.true_position_rad());
                vs.push(self.sim.plant.omega_m_rad_s() as f64);
                tq.push(self.sim.plant.torque_nm() as f64);
            }
        }
        self.sim.load_nm = 0.0;
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .ok();
        self.run_ticking(secs(setup, 0.1));
        self.end_segment("impedance", start);
        let (b, c) = crate::metrics::fit_two(&xs, &vs, &tq);
        ImpedanceFigures {
            kp_nm_per_rad: kp as f64,
            kd_nm_s_per_rad: kd as f64,
            kp_steps: (t1 - t2) / (x2 - x1),
            kp_sine: -b,
            kd_sine: -c,
            sine_hz: wn / std::f64::consts::TAU,
        }
    }

    /// Segment 7, braking (design §18): two stops from the ramp's speed
    /// into a supply that cannot sink current with the ODrive v3's bus
    /// capacitor, the board's regen limit on; the first into the capacitor
    /// alone, the second with the ODrive's brake resistor. Each: the DC link
    /// on a battery (it sinks the spin-up's overshoot), a spin-up, then the
    /// supply made non-sinking, the limits installed and 0 rad/s
    /// commanded. Afterwards the power limits are off again and the plant
    /// is back on its plain source.
    fn braking(&mut self) -> BrakingSummary {
        let setup = self.setup;
        let v_src = setup.bench.bus_voltage_v;
        let base = DcLinkConfig::odrive_v3();
        let resistor_ohm = base.brake_resistor_ohm.unwrap_or(2.0);
        let supervisor = self.sim.cascade.current.config().supervisor;
        let limits = PowerLimitsConfig::for_board(
            &supervisor,
            self.sim.cascade.current.config().current.motor,
            false,
        );
        let w0 = self.plan.w2;
        let mut stops = Vec::new();
        // Both hard stops (0 rad/s at once).
        for (name, brake, ramp_s) in [("braking", false, 0.0), ("braking, resistor", true, 0.0)] {
            let start = self.sim.rows();
            let mut link = base.battery(v_src, 0.02);
            link.brake_resistor_ohm = brake.then_some(resistor_ohm);
            self.sim.plant.set_dc_link(Some(link));
            self.sim
                .cascade
                .command(Command::Velocity { rad_s: w0 })
                .ok();
            // Until settled within 2 % of the speed for 50 ms (at most
            // BRAKE_SPIN_S).
            let mut settled = 0;
            for _ in 0..secs(setup, BRAKE_SPIN_S) {
                self.sim.step();
                self.progress.tick(&self.sim);
                let w = self.sim.plant.omega_m_rad_s() as f32;
                settled = if (w - w0).abs() < 0.02 * w0.abs() {
                    settled + 1
                } else {
                    0
                };
                if settled >= secs(setup, 0.05) {
                    break;
                }
            }
            if let Some(l) = self.sim.plant.dc_link_mut() {
                l.source = SourceKind::NonSinking;
            }
            let cfg = if brake {
                limits.with_brake_resistor()
            } else {
                limits
            };
            self.sim.cascade.current.set_power_limits(Some(cfg));
            self.sim.plant.reset_energy();
            let ke0 = self.sim.plant.kinetic_energy_j() as f64;
            let faults0: Vec<_> = self.sim.cascade.feedback().faults.iter().collect();
            let n_ramp = (ramp_s * setup.bench.pwm_frequency_hz as f64).round() as usize;
            let n = secs(setup, BRAKE_STOP_S);
            let ts = 1.0 / setup.bench.pwm_frequency_hz as f64;
            let mut stop = StopFigures {
                ramp_s,
                from_rad_s: self.sim.plant.omega_m_rad_s() as f64,
                peak_bus_v: 0.0,
                stop_s: None,
                end_rad_s: 0.0,
                kinetic_j: 0.0,
                capacitor_j: 0.0,
                resistor_j: 0.0,
                copper_j: 0.0,
                friction_j: 0.0,
                source_j: 0.0,
                regen_limited_periods: 0,
                brake_periods: 0,
                faults: Vec::new(),
            };
            for k in 0..n {
                if k <= n_ramp && k % self.plan.speed_div == 0 {
                    let w = if n_ramp == 0 {
                        0.0
                    } else {
                        w0 * (1.0 - k as f32 / n_ramp as f32)
                    };
                    self.sim
                        .cascade
                        .command(Command::Velocity { rad_s: w })
                        .ok();
                }
                self.sim.step();
                self.progress.tick(&self.sim);
                stop.peak_bus_v = stop.peak_bus_v.max(self.sim.plant.v_bus_v() as f64);
                let fb = self.sim.cascade.feedback();
                stop.regen_limited_periods += usize::from(fb.power.active == ActiveLimit::Regen);
                stop.brake_periods += usize::from(fb.power.brake_on);
                if stop.stop_s.is_none()
                    && (self.sim.plant.omega_m_rad_s() as f64).abs() < 0.02 * w0 as f64
                {
                    stop.stop_s = Some((k + 1) as f64 * ts);
                }
            }
            let e = *self.sim.plant.energy();
            stop.end_rad_s = self.sim.plant.omega_m_rad_s() as f64;
            stop.kinetic_j = ke0 - self.sim.plant.kinetic_energy_j() as f64;
            stop.capacitor_j = e.capacitor_j as f64;
            stop.resistor_j = e.brake_j as f64;
            stop.copper_j = e.copper_j as f64;
            stop.friction_j = e.friction_j as f64;
            stop.source_j = (e.source_out_j - e.source_in_j) as f64;
            stop.faults = self
                .sim
                .cascade
                .feedback()
                .faults
                .iter()
                .filter(|f| !faults0.contains(f))
                .map(|f| f.name().to_string())
                .collect();
            self.sim.cascade.current.set_power_limits(None);
            self.sim.plant.set_brake(false);
            self.sim.plant.set_dc_link(None);
            self.end_segment(name, start);
            stops.push(stop);
        }
        let resistor = stops.pop().expect("two stops");
        let capacitor = stops.pop().expect("two stops");
        BrakingSummary {
            link: "ODrive v3 bus (DcLinkConfig::odrive_v3)",
            c_f: base.c_f as f64,
            v_source_v: v_src as f64,
            over_voltage_v: supervisor.bus_over_voltage_v as f64,
            regen_v: (limits.regen_start_v as f64, limits.regen_end_v as f64),
            from_rad_s: w0 as f64,
            capacitor,
            resistor,
            resistor_ohm: resistor_ohm as f64,
        }
    }

    /// The segment `name` (every segment is recorded once).
    fn segment(&self, name: &str) -> Segment {
        self.segments
            .iter()
            .find(|s| s.name == name)
            .cloned()
            .unwrap()
    }

    /// The mission's figures from its `trace`.
    fn summary(
        &self,
        trace: &Trace,
        identified: Identified,
        i_step: f32,
        load: f32,
        p0_true: f64,
        wall: Instant,
    ) -> MissionSummary {
        let setup = self.setup;
        let periods = trace.len();
        let ts = 1.0 / setup.bench.pwm_frequency_hz as f64;
        let cpr = setup.bench.sensors.encoder_counts_per_rev.max(1);
        let i_step = i_step as f64;
        let current = current_step_figures(setup, trace, &self.segment("current step"), i_step);
        let w1 = self.plan.w1 as f64;
        let speed = speed_step_figures(trace, &self.segment("speed step"), w1, ts);
        let w2d = self.plan.w2 as f64;
        let load_figures = load_step_figures(setup, trace, &self.segment("load step"), w2d, ts);
        let move_d = self.plan.move_rad as f64;
        let ps = self.segment("position move");
        let position = position_figures(setup, trace, &ps, p0_true, move_d, ts);
        let config = identified.config;
        MissionSummary {
            motor: setup.name.clone(),
            pwm_hz: setup.pwm_hz(),
            dividers: (config.rates.speed_divider, config.rates.position_divider),
            identification: identified.summary,
            restored: false,
            identification_failure: identified.failure,
            align_found_deg: identified.found.to_degrees() as f64,
            align_error_deg: identified.align_error_deg,
            current_step_a: i_step,
            current_step_magnitude: current.0,
            current_overshoot_percent: current.1,
            current_settling_periods: current.2,
            current_id_peak_a: current.3,
            speed_step_rad_s: w1,
            speed_overshoot_percent: speed.0,
            speed_settling_ms: speed.1,
            speed_high_rad_s: w2d,
            load_step_nm: load as f64,
            load_dip_rad_s: load_figures.0,
            load_steady_error_rad_s: load_figures.1,
            load_recovery_ms: load_figures.2,
            speed: self.speed_figures(trace, w1, w2d, ts),
            move_rad: move_d,
            position_settling_ms: position.0,
            position_final_error_rad: position.1,
            encoder_count_rad: std::f64::consts::TAU / cpr as f64,
            braking: None,
            impedance: None,
            faults: mission_faults(trace),
            model_margin: self.sim.cascade.current.model_check().peak_ratio() as f64,
            model_disturbance_margin: self
                .sim
                .cascade
                .current
                .model_check()
                .peak_disturbance_ratio() as f64,
            periods,
            sim_time_s: periods as f64 * ts,
            wall_time_s: wall.elapsed().as_secs_f64(),
        }
    }
}

impl Mission<'_> {
    /// The speed loop's further figures from `trace`.
    fn speed_figures(&self, trace: &Trace, w1: f64, w2: f64, ts: f64) -> SpeedFigures {
        let est_err = |seg: &Segment, step: f64| {
            let e = estimate_error_accelerating(trace, seg, step);
            (e, 100.0 * e / step.abs().max(1e-9))
        };
        let rel = self.segment("load release");
        let w = &col(trace, "speed_rad_s")[rel.start..rel.end];
        let release_rise_rad_s = w.iter().fold(0.0f64, |m, v| m.max(v - w2));
        let tol = 0.02 * w2.abs();
        let release_recovery_ms = match w.iter().rposition(|v| (v - w2).abs() > tol) {
            None => Some(0.0),
            Some(i) if i + 1 < w.len() => Some(ms(i + 1, ts)),
            Some(_) => None,
        };
        let sat = self.segment("current-limited step");
        let (sat_overshoot_percent, sat_settling_ms) = speed_step_figures(trace, &sat, w2, ts);
        let iq_ref = &col(trace, "iq_ref_a")[sat.start..sat.end];
        let lim = self.plan.i_sat as f64;
        let on_limit = iq_ref.iter().filter(|i| i.abs() >= 0.98 * lim).count();
        let peak_acc = |seg: &Segment| {
            let ws = &col(trace, "speed_rad_s")[seg.start..seg.end];
            // Over 1 ms (the speed's quantisation is smoothed out).
            let n = ((1e-3 / ts).round() as usize).max(1);
            ws.windows(n + 1)
                .map(|p| ((p[n] - p[0]) / (n as f64 * ts)).abs())
                .fold(0.0f64, f64::max)
        };
        let step = self.segment("speed step");
        SpeedFigures {
            estimate_error: est_err(&step, w1),
            release_rise_rad_s,
            release_recovery_ms,
            sat_step_rad_s: w2,
            sat_limit_a: lim,
            sat_overshoot_percent,
            sat_settling_ms,
            sat_limited_ms: ms(on_limit, ts),
            sat_estimate_error: est_err(&sat, w2),
            sat_peak_acceleration_rad_s2: peak_acc(&sat),
            step_peak_acceleration_rad_s2: peak_acc(&step),
        }
    }
}

/// Largest |speed estimate - true speed| [rad/s] in step `seg` to `step`
/// [rad/s] from rest, while the true speed is below 90 % of the step (the
/// acceleration).
fn estimate_error_accelerating(trace: &Trace, seg: &Segment, step: f64) -> f64 {
    let w = &col(trace, "speed_rad_s")[seg.start..seg.end];
    let est = &col(trace, "speed_est_rad_s")[seg.start..seg.end];
    let end = w
        .iter()
        .position(|v| v.abs() >= 0.9 * step.abs())
        .unwrap_or(w.len());
    w[..end]
        .iter()
        .zip(&est[..end])
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
}

/// `n` PWM periods of `ts` seconds [ms].
fn ms(n: usize, ts: f64) -> f64 {
    n as f64 * ts * 1e3
}

/// Current step `cs` of `i_step` [A]: (figures of the magnitude?, overshoot
/// [%], 2 % settling [periods], d-current peak [A]).
fn current_step_figures(
    setup: &Setup,
    trace: &Trace,
    cs: &Segment,
    i_step: f64,
) -> (bool, f64, Option<usize>, f64) {
    // The true current (a current probe on the bench), at the sample instants.
    // With a hall-class sensor the controller's angle is only known to
    // +-half a count (+-30 deg(e) on the hub motor) at the locked position,
    // so the true current's q share says more about the sensor than about
    // the loop: there the true current's magnitude is measured.
    let current_step_magnitude = identify::hall_class(setup);
    let iq_mag: Vec<f64>;
    let iq = if current_step_magnitude {
        let (q, d) = (col(trace, "iq_true_a"), col(trace, "id_true_a"));
        iq_mag = (cs.start..cs.end).map(|k| q[k].hypot(d[k])).collect();
        &iq_mag[..]
    } else {
        &col(trace, "iq_true_a")[cs.start..cs.end]
    };
    let id = &col(trace, "id_a")[cs.start..cs.end];
    (
        current_step_magnitude,
        metrics::overshoot_percent(iq, 0.0, i_step),
        metrics::settling_index(iq, 0.0, i_step, 0.02),
        id.iter().fold(0.0f64, |m, v| m.max(v.abs())),
    )
}

/// Speed step `ss` to `w1` [rad/s]: (overshoot [%], 2 % settling [ms]).
fn speed_step_figures(trace: &Trace, ss: &Segment, w1: f64, ts: f64) -> (f64, Option<f64>) {
    let w = &col(trace, "speed_rad_s")[ss.start..ss.end];
    (
        metrics::overshoot_percent(w, 0.0, w1),
        metrics::settling_index(w, 0.0, w1, 0.02).map(|n| ms(n, ts)),
    )
}

/// Load step `ls` at `w2d` [rad/s]: (largest dip [rad/s], steady error
/// [rad/s], recovery into +-2 % [ms]).
fn load_step_figures(
    setup: &Setup,
    trace: &Trace,
    ls: &Segment,
    w2d: f64,
    ts: f64,
) -> (f64, f64, Option<f64>) {
    let w = &col(trace, "speed_rad_s")[ls.start..ls.end];
    let load_dip_rad_s = w.iter().fold(0.0f64, |m, v| m.max(w2d - v));
    let tail = secs(setup, 0.1).min(w.len());
    let load_steady_error_rad_s = w2d - mean(&w[w.len() - tail..]);
    let load_recovery_ms = {
        let tol = 0.02 * w2d.abs();
        let last_out = w.iter().rposition(|v| (v - w2d).abs() > tol);
        match last_out {
            None => Some(0.0),
            Some(i) if i + 1 < w.len() => Some(ms(i + 1, ts)),
            Some(_) => None,
        }
    };
    (load_dip_rad_s, load_steady_error_rad_s, load_recovery_ms)
}

/// Position move `ps` of `move_d` [rad] from the true position `p0_true`:
/// (2 % settling [ms], final error [rad]).
fn position_figures(
    setup: &Setup,
    trace: &Trace,
    ps: &Segment,
    p0_true: f64,
    move_d: f64,
    ts: f64,
) -> (Option<f64>, f64) {
    let pos = &col(trace, "position_rad")[ps.start..ps.end];
    let disp: Vec<f64> = pos.iter().map(|p| p - p0_true).collect();
    let position_settling_ms = metrics::settling_index(&disp, 0.0, move_d, 0.02).map(|n| ms(n, ts));
    let tail = secs(setup, 0.05).min(disp.len());
    let position_final_error_rad = move_d - mean(&disp[disp.len() - tail..]);
    (position_settling_ms, position_final_error_rad)
}

/// The faults latched during the mission (names, first occurrence order),
/// plus a note when position mode was never active.
fn mission_faults(trace: &Trace) -> Vec<String> {
    let mut faults: Vec<String> = Vec::new();
    for &c in col(trace, "fault") {
        if c > 0.0 {
            if let Some(f) = foc_core::control::Fault::from_code(c as u8) {
                let n = f.name().to_string();
                if !faults.contains(&n) {
                    faults.push(n);
                }
            }
        }
    }
    let modes_ok = col(trace, "mode").contains(&(Mode::Position as u8 as f64));
    if !modes_ok {
        faults.push("position mode never active".into());
    }
    faults
}

/// Simulation speed: controller steps per second alone (on a fixed sample)
/// and plant + controller periods per second, each measured for about
/// `seconds` of wall time.
pub fn bench_speed(setup: &Setup, seconds: f64) -> (f64, f64) {
    let config = setup.cascade_config();
    // Controller alone, torque mode, on a real sample.
    let mut sim = Sim::new_calibrated(setup, config, false);
    sim.cascade
        .command(Command::Torque {
            iq_a: 0.1 * setup.rated_current_a,
        })
        .ok();
    sim.run(10);
    let sample = sample_of(sim.last_sample());
    let mut c = sim.cascade;
    let t = Instant::now();
    let mut n = 0u64;
    let mut acc = 0.0f32;
    while t.elapsed().as_secs_f64() < seconds {
        for _ in 0..10_000 {
            if let BridgeCommand::Duties(d) = c.step(std::hint::black_box(&sample)) {
                acc += d[0];
            }
        }
        n += 10_000;
    }
    std::hint::black_box(acc);
    let ctrl = n as f64 / t.elapsed().as_secs_f64();
    // Plant + controller, velocity mode.
    let mut sim = Sim::new_calibrated(setup, config, false);
    sim.cascade
        .command(Command::Velocity {
            rad_s: 0.2 * setup.max_speed_rad_s(),
        })
        .ok();
    let t = Instant::now();
    let mut n = 0u64;
    while t.elapsed().as_secs_f64() < seconds {
        sim.run(1000);
        n += 1000;
    }
    let both = n as f64 / t.elapsed().as_secs_f64();
    (ctrl, both)
}
