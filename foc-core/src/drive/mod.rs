//! # The drive: what happens each PWM period, from reset on
//!
//! One [`Drive`] per motor. Its owner (the firmware's current-loop
//! interrupt, an emulated board, a test) calls [`Drive::step`] once per
//! PWM period: it reads the sensors through the hardware traits, lets the
//! [`Lifecycle`] decide (offset calibration with the bridge off, the
//! angle-sensor check, identification on request or at start-up, the
//! calibration permit, configuration changes at the period boundary, then
//! run mode through the [`CurrentStage`]), writes the feedback in place,
//! drives the bridge and returns the [`Output`]: which slower loops to run
//! and what happened.
//!
//! | module | what |
//! |---|---|
//! | [`lifecycle`] | [`Lifecycle`], hardware-free: phases, events, dividers |
//! | [`identify`] | the identification sequencer driven through the stage |
//! | [`rules`] | the one check of each rule: [`Status`], [`Refusal`], [`ConfigChange`] |
//! | [`period`] | [`Drive::run_period`]: one period as the firmware's interrupt runs it |
//!
//! The bench's `Cascade` runs the same [`Lifecycle`] on simulated samples,
//! so the start-up path the firmware runs is the one the host tests run.
//!
//! ```
//! use foc_core::drive::{Drive, Inputs, LifecycleConfig, LifePhase};
//! use foc_core::calibration::offsets::OffsetLimits;
//! use foc_core::control::{CommandSlot, Feedback, MotorParams};
//! use foc_core::drive::cascade::CascadeConfig;
//! # use foc_core::{hal::*, angle::MechanicalAngle, frames::Abc};
//! # struct Pwm(bool); struct Cs; struct Enc; struct Bus;
//! # impl PwmDriver for Pwm { type Error = (); fn period_counts(&self) -> u16 { 4200 }
//! #   fn set_compare(&mut self, _: [u16; 3]) -> Result<(), ()> { Ok(()) }
//! #   fn enable(&mut self) -> Result<(), ()> { self.0 = true; Ok(()) } fn disable(&mut self) { self.0 = false }
//! #   fn is_enabled(&self) -> bool { self.0 } }
//! # impl CurrentSense for Cs { type Error = (); fn read_currents(&mut self) -> Result<PhaseCurrents, ()> { Ok(PhaseCurrents::TwoPhase { a_a: 0.01, b_a: -0.01 }) }
//! #   fn offsets_a(&self) -> Abc { Abc::default() } fn set_offsets_a(&mut self, _: Abc) {} }
//! # impl AngleSensor for Enc { type Error = (); fn read_angle(&mut self) -> Result<MechanicalAngle, ()> { Ok(MechanicalAngle::ZERO) } }
//! # impl BusVoltage for Bus { type Error = (); fn read_bus_voltage_v(&mut self) -> Result<f32, ()> { Ok(24.0) } }
//! let motor = MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 40e-6, lq_h: 40e-6, flux_linkage_wb: 0.004 };
//! let cascade = CascadeConfig::for_motor(motor, 20_000.0, 10.0);
//! let life = LifecycleConfig {
//!     offsets: Some(OffsetLimits { samples: 16, max_offset_a: 0.5, max_noise_a: 0.1 }),
//!     sensor_check_reads: 4,
//!     identification: None,
//!     identify_at_start_up: false,
//!     speed_divider: 10,
//!     position_divider: 20,
//!     angle_kind: foc_core::drive::AngleKind::Incremental,
//!     stored: None,
//! };
//! let mut drive = Drive::new(Pwm(false), Cs, Enc, Bus, cascade.current, life);
//! let inputs = Inputs::new(CommandSlot::INIT, 0.0);
//! let mut feedback = Feedback::INIT; // what the other tasks read
//! for _ in 0..16 + 4 {
//!     drive.step(&inputs, &mut feedback);
//!     assert!(!drive.pwm.is_enabled()); // bridge off during start-up
//! }
//! assert_eq!(drive.lifecycle().phase(), LifePhase::Run);
//! assert!(!drive.status().calibrated); // no permit yet: closed loop refused
//! // What is too large for a configuration change (the anticogging map,
//! // the angle correction) goes in outside the period, bridge off:
//! let stage = drive.stage_while_disabled().expect("disabled");
//! assert_eq!(stage.set_cogging(&foc_core::control::cogging::CoggingMap::EMPTY), Ok(()));
//! ```

pub mod cascade;
pub mod cogging;
pub mod encoder;
pub mod identify;
pub mod lifecycle;
pub mod period;
pub mod progress;
pub mod rules;

pub use lifecycle::{Event, Inputs, LifePhase, Lifecycle, LifecycleConfig, Output};
pub use period::Mail;
pub use progress::Progress;

/// What the angle sensor knows at power-up. It decides what a stored
/// calibration is worth at boot (design §17): the stored electrical zero
/// is a sensor reading, so it only applies where the sensor reads the same
/// angle for the same rotor position after every reset.
///
/// | kind | angle at boot | stored calibration at boot | motion before the first command |
/// |---|---|---|---|
/// | `Absolute` | known (e.g. AS5047P) | permit installed, no identification | none |
/// | `Hall` | known to a sector (60 electrical degrees) | permit installed, no identification; coarse-angle start until the first edge | none |
/// | `Incremental` | unknown (counts from 0 at reset) | motor model and gains only; the electrical zero needs an identification (or an index search) | that routine's |
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AngleKind {
    /// The sensor reads the absolute rotor angle from the first sample.
    Absolute,
    /// Hall sensors: the sector is known from the first sample.
    Hall,
    /// A counting encoder that starts from zero at reset.
    Incremental,
}

impl AngleKind {
    /// True when a stored electrical zero is still right after a reset.
    pub const fn zero_survives_reset(self) -> bool {
        matches!(self, AngleKind::Absolute | AngleKind::Hall)
    }
}
pub use rules::{check_field, ConfigChange, JointChange, Refusal, Status, Sweep};

use crate::control::io::{apply, read_sample};
use crate::control::stage::{CurrentStage, CurrentStageConfig};
use crate::control::{Fault, Feedback};
use crate::frames::Abc;
use crate::hal::{AngleSensor, BrakeOutput, BusVoltage, CurrentSense, NoBrake, PwmDriver};

/// The drive: the board's hardware, the current stage and the lifecycle.
/// The hardware fields are public for the owner's other duties (e.g. an
/// emergency stop); the decisions go through [`Drive::step`].
///
/// `K` is the brake resistor's switch (design §18): [`NoBrake`] unless
/// [`Drive::with_brake`] gives one.
pub struct Drive<P, C, A, B, K = NoBrake> {
    /// PWM / bridge.
    pub pwm: P,
    /// Phase-current sensor.
    pub currents: C,
    /// Angle sensor.
    pub angle: A,
    /// Bus-voltage (and temperature) sensor.
    pub bus: B,
    /// Brake-resistor switch (set every period from the power limits'
    /// chopper, off without them).
    pub brake: K,
    stage: CurrentStage,
    life: Lifecycle,
}

impl<P, C, A, B> Drive<P, C, A, B, NoBrake>
where
    P: PwmDriver,
    C: CurrentSense,
    A: AngleSensor,
    B: BusVoltage,
{
    /// From reset: bridge off, current-sensor offsets zeroed, offset
    /// calibration next.
    pub fn new(
        mut pwm: P,
        mut currents: C,
        angle: A,
        bus: B,
        stage: CurrentStageConfig,
        life: LifecycleConfig,
    ) -> Self {
        pwm.disable();
        currents.set_offsets_a(Abc::default());
        Self {
            pwm,
            currents,
            angle,
            bus,
            brake: NoBrake,
            stage: CurrentStage::new(stage),
            life: Lifecycle::new(life),
        }
    }

    /// The same drive with a brake resistor's switch (switched off here;
    /// [`Drive::step`] drives it from then on).
    pub fn with_brake<K: BrakeOutput>(self, mut brake: K) -> Drive<P, C, A, B, K> {
        brake.set_brake(false);
        Drive {
            pwm: self.pwm,
            currents: self.currents,
            angle: self.angle,
            bus: self.bus,
            brake,
            stage: self.stage,
            life: self.life,
        }
    }
}

impl<P, C, A, B, K> Drive<P, C, A, B, K>
where
    P: PwmDriver,
    C: CurrentSense,
    A: AngleSensor,
    B: BusVoltage,
    K: BrakeOutput,
{
    /// One PWM period: read the sensors, decide, install offsets, release
    /// the PWM's hardware fault latch after an explicit clear (not while
    /// the power stage still reports a fault), drive the bridge (duties
    /// before enable; a PWM error is latched as [`Fault::PwmError`] with
    /// the bridge off), switch the brake resistor as the power limits'
    /// chopper decided (also with the bridge off: a coasting motor's
    /// back-EMF still charges the bus through the body diodes).
    ///
    /// The feedback is written in place into `feedback` (left unchanged
    /// during start-up): the firmware passes the copy its other tasks read,
    /// so publishing it costs no copy (design §20).
    pub fn step(&mut self, inputs: &Inputs, feedback: &mut Feedback) -> Output {
        let sample = read_sample(&mut self.currents, &mut self.angle, &mut self.bus);
        // The index the sensor latched (design §33), read only while the
        // lifecycle searches it (no copy of the inputs in the other
        // periods: `cargo xtask bench`).
        if self.life.phase() == LifePhase::IndexSearch {
            let index = self.angle.take_index();
            self.life.note_index(index);
        }
        let out = self.life.step(&mut self.stage, inputs, &sample, feedback);
        if let Some(o) = out.offsets_a {
            self.currents.set_offsets_a(o);
        }
        if out.faults_cleared && !inputs.gate_fault {
            self.pwm.release_fault_latch();
        }
        if let Err(f) = apply(&mut self.pwm, out.bridge) {
            self.stage.report_fault(f);
        }
        let brake_on = self.stage.brake_on();
        if brake_on != self.brake.is_brake_on() {
            self.brake.set_brake(brake_on);
        }
        out
    }

    /// Latch `fault` and turn the bridge off now (e.g. a loop overrun found
    /// after the step).
    pub fn trip(&mut self, fault: Fault) {
        self.stage.report_fault(fault);
        self.pwm.disable();
    }

    /// The current stage.
    pub fn stage(&self) -> &CurrentStage {
        &self.stage
    }

    /// The current stage, to install what is kept with the configuration
    /// but too large for a [`ConfigChange`] (the anticogging map, the
    /// angle sensor's correction: `CurrentStage::set_cogging`,
    /// `set_angle_correction`), outside the period: at start-up before
    /// the interrupt runs, or from a lower priority under the drive's
    /// lock. Only while the bridge is off by command (mode `Disabled`)
    /// and no routine owns the stage: during start-up's offset
    /// calibration and sensor check, or running ([`LifePhase::Run`]);
    /// not while a calibration turns the rotor (the sweeps install their
    /// own table, or put the old one back when stopped); `None`
    /// otherwise.
    pub fn stage_while_disabled(&mut self) -> Option<&mut CurrentStage> {
        let quiet = matches!(
            self.life.phase(),
            LifePhase::OffsetCalibration | LifePhase::SensorCheck(_) | LifePhase::Run
        ) && self.stage.active().mode() == crate::control::Mode::Disabled;
        quiet.then_some(&mut self.stage)
    }

    /// The lifecycle.
    pub fn lifecycle(&self) -> &Lifecycle {
        &self.life
    }

    /// The status the rules look at.
    pub fn status(&self) -> Status {
        self.life.status(&self.stage)
    }
}
