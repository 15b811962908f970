//! The identification sequencer: resistance, inductance, current-loop
//! gains, sensor alignment, flux linkage and the mechanical parameters
//! (inertia, viscous and Coulomb friction), in that order, stepped once per
//! PWM period, ending in an [`IdentificationResult`] and a [`Calibrated`]
//! permit.
//!
//! | stage | routine | asks for | uses |
//! |---|---|---|---|
//! | [`Step::Resistance`] | [`PhaseResistance`] | open-loop voltage | - |
//! | [`Step::Inductance`] | [`Inductance`] | open-loop voltage | R, to correct the exponential current response |
//! | (gains) | [`current_loop_config`] | nothing (same period) | R, Ld, Lq |
//! | [`Step::Alignment`] | [`Alignment`] | open-loop voltage | R and the dead-time drop, to size the voltage |
//! | [`Step::Flux`] | [`FluxLinkage`] | closed-loop velocity | the permit of R, L, gains and alignment |
//! | [`Step::Mechanics`] | [`MechanicalId`] | closed-loop torque, then velocity 0 | the same permit; `kt = 1.5 p psi` from the flux; the flux step's second speed as target |
//!
//! The flux step runs when [`IdentificationConfig::measure_flux`] is set
//! (the rotor may spin), the mechanical step when
//! [`IdentificationConfig::measure_mechanics`] is set as well (it needs the
//! measured torque constant); otherwise their results are 0 / `None`.
//!
//! A stage that finishes hands over in the same period, so every call
//! returns a command until `Done` or `Failed`. [`Identification::current_step`]
//! tells where a failure happened.
//!
//! **Driving it.** Every PWM period build a [`CalInput`] from the
//! measurements and call [`Identification::step`]:
//! - `Apply { v_dq, theta_e }`: apply the open-loop voltage (e.g.
//!   `CurrentLoop::step_voltage`);
//! - `Velocity { rad_s }` or `Torque { iq_a }`: on the first such request
//!   take [`Identification::permit`] and install it (`Calibrated::apply_to`
//!   or `CalibratedCascade::new`), then run velocity mode at `rad_s`
//!   (mechanical) or torque mode at `iq_a` and fill
//!   [`CalInput::closed_loop`] from its feedback;
//! - `Done(Identified { result, permit })`: store `result`, build the
//!   closed-loop drive from `permit`;
//! - `Failed(reason)`: bridge off, report `reason` and [`Identification::current_step`].
//!
//! ```
//! use foc_core::calibration::identification::{Identification, IdentificationConfig, Step};
//! use foc_core::calibration::{CalInput, CalStep};
//! use foc_core::{angle::MechanicalAngle, frames::Abc};
//! let mut id = Identification::new(IdentificationConfig::new(7, 20_000.0, 2.0, 6.0));
//! let bad = CalInput::open_loop(Abc::new(f32::NAN, 0.0, 0.0), MechanicalAngle::ZERO, 24.0);
//! assert!(matches!(id.step(&bad), CalStep::Failed(_)));
//! assert_eq!(id.current_step(), Step::Resistance);
//! assert!(id.permit().is_none());
//! ```

use super::alignment::{Alignment, AlignmentConfig};
use super::common::{CalError, CalInput, CalStep};
use super::field_flux::{FieldFlux, FieldFluxConfig};
use super::flux::{FluxConfig, FluxLinkage};
use super::gains::current_loop_config;
use super::inductance::{Inductance, InductanceConfig};
use super::mechanics::{MechanicalId, MechanicsConfig, MechanicsResult};
use super::permit::Calibrated;
use super::resistance::{PhaseResistance, ResistanceConfig, ResistanceResult};
use crate::control::current::CurrentLoopConfig;
use crate::control::stage::AngleCalibration;
use crate::control::MotorParams;

/// Configuration of the whole identification.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IdentificationConfig {
    /// PWM (step) frequency \[Hz\].
    pub pwm_frequency_hz: f32,
    /// Configured pole pairs (checked by the alignment, never changed).
    pub pole_pairs: u8,
    /// Resistance step.
    pub resistance: ResistanceConfig,
    /// Inductance step; its `r_ohm` is replaced by the measured resistance.
    pub inductance: InductanceConfig,
    /// Alignment step; its `voltage_v` is replaced by
    /// `R * alignment_current_a + dead-time drop` (bounded by its
    /// `max_voltage_v`).
    pub alignment: AlignmentConfig,
    /// d current the alignment voltage is sized for \[A\].
    pub alignment_current_a: f32,
    /// Flux step; its `r_ohm` and `ld_h` are replaced by the measured values.
    pub flux: FluxConfig,
    /// Run the flux step (false: flux linkage 0 in the result, for a rotor
    /// that may not spin freely).
    pub measure_flux: bool,
    /// Mechanical step; its `torque_constant_nm_per_a` is replaced by
    /// `1.5 p psi` of the measured flux linkage, and a `speed_target_rad_s`
    /// of `None` by the flux step's second speed.
    pub mechanics: MechanicsConfig,
    /// Run the mechanical step after the flux step (only when the flux is
    /// measured; false: `mechanics` `None` in the result).
    pub measure_mechanics: bool,
    /// The drive reads an angle sensor (true; the drive's lifecycle sets
    /// it from whether the drive runs sensorless). Without one (design
    /// §29) there is no alignment (the permit's angle calibration is
    /// [`AngleCalibration::sensorless`]), the flux linkage is measured on
    /// a turning field ([`Self::field_flux`]) and the mechanical step does
    /// not run (its torque pulses brake through zero speed, where nothing
    /// tells the rotor's angle): the inertia is the configuration's.
    /// [`Self::measure_flux`] must then be set (the observer runs on the
    /// flux linkage): without it the sequencer fails with
    /// [`CalError::InvalidConfig`] after the gains.
    pub angle_sensor: bool,
    /// The flux step without an angle sensor ([`Self::new`]: the test
    /// current and the open-loop voltage limit; the drive's lifecycle
    /// lowers its modulation to the current stage's).
    pub field_flux: FieldFluxConfig,
}

impl IdentificationConfig {
    /// Defaults of every step for `pole_pairs`, a PWM frequency \[Hz\], a test
    /// current \[A\] (resistance, inductance bias and alignment) and an
    /// open-loop voltage limit \[V\]. The direction of the sensor is detected;
    /// set `alignment.expected_reversed` to enforce one.
    pub fn new(
        pole_pairs: u8,
        pwm_frequency_hz: f32,
        test_current_a: f32,
        max_voltage_v: f32,
    ) -> Self {
        let mut alignment =
            AlignmentConfig::new(pole_pairs, pwm_frequency_hz, 0.0, 1.5 * test_current_a);
        alignment.max_voltage_v = max_voltage_v;
        Self {
            pwm_frequency_hz,
            pole_pairs,
            resistance: ResistanceConfig::new(pwm_frequency_hz, test_current_a, max_voltage_v),
            inductance: InductanceConfig::new(pwm_frequency_hz, test_current_a, max_voltage_v),
            alignment,
            alignment_current_a: test_current_a,
            flux: FluxConfig::new(pole_pairs, pwm_frequency_hz, 0.0, 2.0 * test_current_a),
            measure_flux: true,
            // Probe current: the test current (the drive limits the
            // current to 1.5 times it during the identification).
            mechanics: MechanicsConfig::new(
                pwm_frequency_hz,
                0.0,
                test_current_a,
                2.0 * test_current_a,
                None,
            ),
            measure_mechanics: true,
            angle_sensor: true,
            field_flux: FieldFluxConfig::new(test_current_a, max_voltage_v),
        }
    }
}

/// Everything the identification measured.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IdentificationResult {
    /// Phase resistance \[ohm\].
    pub r_ohm: f32,
    /// d-axis inductance \[H\].
    pub ld_h: f32,
    /// q-axis inductance \[H\].
    pub lq_h: f32,
    /// Flux linkage \[Wb\] (0 when not measured).
    pub flux_linkage_wb: f32,
    /// Inertia and friction (`None` when not measured).
    pub mechanics: Option<MechanicsResult>,
    /// Sensor to electrical angle.
    pub angle: AngleCalibration,
    /// Pole pairs (configured and confirmed).
    pub pole_pairs: u8,
}

impl IdentificationResult {
    /// As [`MotorParams`].
    pub fn motor_params(&self) -> MotorParams {
        MotorParams {
            pole_pairs: self.pole_pairs,
            r_ohm: self.r_ohm,
            ld_h: self.ld_h,
            lq_h: self.lq_h,
            flux_linkage_wb: self.flux_linkage_wb,
        }
    }
}

/// The final value of a successful identification.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Identified {
    /// The measured values.
    pub result: IdentificationResult,
    /// The permit for closed-loop modes (gains from the measured values,
    /// flux linkage included for the decoupling feed-forward).
    pub permit: Calibrated,
}

/// Where the sequencer is (or stopped).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Step {
    /// Phase resistance.
    Resistance,
    /// Ld and Lq.
    Inductance,
    /// Current-loop gains (instantaneous).
    Gains,
    /// Sensor alignment.
    Alignment,
    /// Flux linkage (closed loop).
    Flux,
    /// Inertia and friction (closed-loop torque pulses).
    Mechanics,
    /// The anticogging map (design §32): its own request
    /// (`ConfigChange::calibrate_cogging`), never part of the sequence.
    Cogging,
    /// The angle sensor's correction (design §33): its own request
    /// (`ConfigChange::calibrate_encoder`), never part of the sequence.
    Encoder,
    /// The incremental encoder's index search at start-up (design §33).
    IndexSearch,
    /// Finished successfully.
    Done,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Running {
    Resistance(PhaseResistance),
    Inductance(Inductance),
    Alignment(Alignment),
    Flux(FluxLinkage),
    FieldFlux(FieldFlux),
    Mechanics(MechanicalId),
    Finished,
}

/// The identification sequencer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Identification {
    cfg: IdentificationConfig,
    running: Running,
    stage: Step,
    r: Option<ResistanceResult>,
    current: Option<CurrentLoopConfig>,
    angle: Option<AngleCalibration>,
    permit: Option<Calibrated>,
    /// Measured flux linkage \[Wb\] (0 until measured).
    flux_linkage_wb: f32,
    finished: Option<CalStep<Identified>>,
}

impl Identification {
    /// New sequencer, starting with the resistance.
    pub fn new(config: IdentificationConfig) -> Self {
        Self {
            cfg: config,
            running: Running::Resistance(PhaseResistance::new(config.resistance)),
            stage: Step::Resistance,
            r: None,
            current: None,
            angle: None,
            permit: None,
            flux_linkage_wb: 0.0,
            finished: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &IdentificationConfig {
        &self.cfg
    }

    /// The current stage (the failing one after `Failed`).
    pub fn current_step(&self) -> Step {
        self.stage
    }

    /// The permit once the alignment is done (its motor parameters have
    /// flux linkage 0 during the flux and mechanical steps); the final one
    /// after `Done`.
    pub fn permit(&self) -> Option<Calibrated> {
        self.permit
    }

    /// The resistance result, once measured.
    pub fn resistance(&self) -> Option<ResistanceResult> {
        self.r
    }

    /// One PWM period. See the module docs.
    pub fn step(&mut self, inp: &CalInput) -> CalStep<Identified> {
        if let Some(f) = self.finished {
            return f;
        }
        let out = self.run(inp);
        if out.is_finished() {
            self.finished = Some(out);
        }
        out
    }

    fn run(&mut self, inp: &CalInput) -> CalStep<Identified> {
        // At most one hand-over per stage in one period.
        for _ in 0..6 {
            let next = match &mut self.running {
                Running::Resistance(r) => match r.step(inp) {
                    CalStep::Done(res) => self.after_resistance(res),
                    other => return pass(other),
                },
                Running::Inductance(l) => match l.step(inp) {
                    CalStep::Done(res) => self.after_inductance(res.ld_h, res.lq_h),
                    other => return pass(other),
                },
                Running::Alignment(a) => match a.step(inp) {
                    CalStep::Done(res) => self.after_alignment(res.calibration),
                    other => return pass(other),
                },
                Running::Flux(f) => match f.step(inp) {
                    CalStep::Done(res) => self.after_flux(res.flux_linkage_wb, res.speeds_rad_s[1]),
                    other => return pass(other),
                },
                Running::FieldFlux(f) => match f.step(inp) {
                    CalStep::Done(res) => {
                        self.flux_linkage_wb = res.flux_linkage_wb;
                        self.finish(None)
                    }
                    other => return pass(other),
                },
                Running::Mechanics(m) => match m.step(inp) {
                    CalStep::Done(res) => self.finish(Some(res)),
                    other => return pass(other),
                },
                Running::Finished => Err(CalError::InvalidConfig),
            };
            match next {
                Ok(Some(done)) => {
                    self.stage = Step::Done;
                    self.running = Running::Finished;
                    return CalStep::Done(done);
                }
                Ok(None) => {}
                Err(e) => return CalStep::Failed(e),
            }
        }
        CalStep::Failed(CalError::InvalidConfig)
    }

    fn after_resistance(&mut self, res: ResistanceResult) -> Result<Option<Identified>, CalError> {
        self.r = Some(res);
        self.stage = Step::Inductance;
        // The measured resistance corrects the exponential current response.
        let mut l = self.cfg.inductance;
        l.r_ohm = res.r_ohm;
        l.swing_from_current |= !self.cfg.angle_sensor;
        self.running = Running::Inductance(Inductance::new(l));
        Ok(None)
    }

    fn after_inductance(&mut self, ld_h: f32, lq_h: f32) -> Result<Option<Identified>, CalError> {
        self.stage = Step::Gains;
        let r = self.r.ok_or(CalError::InvalidConfig)?;
        let motor = MotorParams {
            pole_pairs: self.cfg.pole_pairs,
            r_ohm: r.r_ohm,
            ld_h,
            lq_h,
            flux_linkage_wb: 0.0,
        };
        let current = current_loop_config(motor, 1.0 / self.cfg.pwm_frequency_hz)?;
        self.current = Some(current);
        if !self.cfg.angle_sensor {
            return self.without_alignment(current);
        }
        self.stage = Step::Alignment;
        let mut a = self.cfg.alignment;
        let offset = if r.v_offset_v > 0.0 {
            r.v_offset_v
        } else {
            0.0
        };
        let v = r.r_ohm * self.cfg.alignment_current_a + offset;
        a.voltage_v = if v < a.max_voltage_v {
            v
        } else {
            a.max_voltage_v
        };
        self.running = Running::Alignment(Alignment::new(a));
        Ok(None)
    }

    /// Without an angle sensor: no alignment; the flux on a turning field.
    fn without_alignment(
        &mut self,
        current: CurrentLoopConfig,
    ) -> Result<Option<Identified>, CalError> {
        // Without a flux linkage the observer has nothing to run on: a
        // drive without a sensor must measure it.
        if !self.cfg.measure_flux {
            return Err(CalError::InvalidConfig);
        }
        let counts = self.cfg.alignment.sensor_counts_per_rev;
        let angle = AngleCalibration::sensorless(self.cfg.pole_pairs, counts);
        self.angle = Some(angle);
        self.permit = Some(super::permit::identified(angle, current)?);
        self.stage = Step::Flux;
        self.running = Running::FieldFlux(FieldFlux::new(self.cfg.field_flux, current));
        Ok(None)
    }

    fn after_alignment(&mut self, angle: AngleCalibration) -> Result<Option<Identified>, CalError> {
        let current = self.current.ok_or(CalError::InvalidConfig)?;
        self.angle = Some(angle);
        self.permit = Some(super::permit::identified(angle, current)?);
        if !self.cfg.measure_flux {
            return self.finish(None);
        }
        self.stage = Step::Flux;
        let mut f = self.cfg.flux;
        f.r_ohm = current.motor.r_ohm;
        f.ld_h = current.motor.ld_h;
        f.pole_pairs = self.cfg.pole_pairs;
        self.running = Running::Flux(FluxLinkage::new(f));
        Ok(None)
    }

    fn after_flux(
        &mut self,
        flux_linkage_wb: f32,
        speed_rad_s: f32,
    ) -> Result<Option<Identified>, CalError> {
        self.flux_linkage_wb = flux_linkage_wb;
        if !self.cfg.measure_mechanics {
            return self.finish(None);
        }
        self.stage = Step::Mechanics;
        let mut m = self.cfg.mechanics;
        m.torque_constant_nm_per_a = 1.5 * f32::from(self.cfg.pole_pairs) * flux_linkage_wb;
        m.speed_target_rad_s = m.speed_target_rad_s.or(Some(speed_rad_s));
        self.running = Running::Mechanics(MechanicalId::new(m));
        Ok(None)
    }

    fn finish(
        &mut self,
        mechanics: Option<MechanicsResult>,
    ) -> Result<Option<Identified>, CalError> {
        let (Some(mut current), Some(angle)) = (self.current, self.angle) else {
            return Err(CalError::InvalidConfig);
        };
        let flux_linkage_wb = self.flux_linkage_wb;
        current.motor.flux_linkage_wb = flux_linkage_wb;
        let permit = super::permit::identified(angle, current)?;
        self.permit = Some(permit);
        let m = current.motor;
        Ok(Some(Identified {
            result: IdentificationResult {
                r_ohm: m.r_ohm,
                ld_h: m.ld_h,
                lq_h: m.lq_h,
                flux_linkage_wb,
                mechanics,
                angle,
                pole_pairs: m.pole_pairs,
            },
            permit,
        }))
    }
}

/// A command or failure of a routine as a step of the sequencer. `Done`
/// is matched by the caller before; it maps to a failure rather than a panic.
fn pass<T>(s: CalStep<T>) -> CalStep<Identified> {
    match s {
        CalStep::Apply { v_dq, theta_e } => CalStep::Apply { v_dq, theta_e },
        CalStep::Velocity { rad_s } => CalStep::Velocity { rad_s },
        CalStep::Torque { iq_a } => CalStep::Torque { iq_a },
        CalStep::Failed(e) => CalStep::Failed(e),
        CalStep::Done(_) => CalStep::Failed(CalError::InvalidConfig),
    }
}
