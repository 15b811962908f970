//! Motor identification against the bench plant, through the firmware's
//! own start-up path: the [`Sim`]'s controller is restarted from reset
//! ([`foc_core::drive::cascade::Cascade::from_reset`]), so foc-core's
//! drive `Lifecycle` runs exactly what the firmware's current-loop
//! interrupt runs, one PWM period at a time, with the supervisor watching
//! every period:
//!
//! 1. **current offsets**: bridge off, [`OFFSET_SAMPLES`] periods averaged;
//!    the lifecycle hands the offsets over and the [`Sim`] subtracts them
//!    from every later sample, as the firmware's
//!    `CurrentSense::set_offsets_a` does;
//! 2. **sensor check**: [`SENSOR_CHECK_READS`] good angle readings;
//! 3. **identification** (foc-core `calibration::identification`, driven
//!    by `drive::identify`): resistance, inductance, current-loop gains,
//!    alignment (zero, direction, pole-pair check), flux linkage (for
//!    hall-class sensors with a wider speed band, see [`config`]) and the
//!    mechanical parameters (inertia, viscous and Coulomb friction, from
//!    torque pulses up to [`mechanics_speed_rad_s`]), with the current
//!    limited to 1.5 x the test current;
//! 4. on success: bridge off, the configured limits back, the final permit
//!    (measured gains and electrical zero, flux linkage included) installed.
//!
//! Used by `cargo xtask sim`'s mission ([`crate::mission::run_mission`]) and
//! by `tests/tests/identification.rs` (one implementation of the driving).
//!
//! ```no_run
//! use foc_bench::{identify, mission::{Setup, Sim}};
//! let s = Setup::load("tests/motors/dji-m2006.toml").unwrap();
//! let mut sim = Sim::new(&s, s.cascade_config(), false);
//! let out = identify::run(&mut sim, &s, identify::config(&s, s.motor.pole_pairs), &mut |_| {}).unwrap();
//! assert!(out.identified().is_some() && sim.cascade.is_calibrated());
//! ```

use crate::mission::{Setup, Sim};
use foc_core::calibration::identification::{IdentificationConfig, Identified, Step};
use foc_core::calibration::offsets::{OffsetError, OffsetLimits};
use foc_core::calibration::{CalStep, Calibrated};
use foc_core::control::Fault;
use foc_core::drive::cascade::Cascade;
use foc_core::drive::{Event, LifecycleConfig};
use foc_core::frames::Abc;

/// PWM periods the current-offset calibration averages.
pub const OFFSET_SAMPLES: u32 = 1000;

/// Good angle readings the start-up sensor check needs.
pub const SENSOR_CHECK_READS: u32 = 64;

/// Simulated-time limit of the identification \[s\].
pub const TIME_LIMIT_S: f32 = 60.0;

/// Fewer than 64 encoder counts per electrical turn (e.g. the hub motor's
/// 48 counts on 8 pole pairs = 6 per electrical turn).
pub fn hall_class(s: &Setup) -> bool {
    s.bench.sensors.encoder_counts_per_rev / u32::from(s.motor.pole_pairs.max(1)) < 64
}

/// The flux step's speed band for hall-class sensors (relative; 5 % else).
pub const HALL_FLUX_SPEED_TOLERANCE: f32 = 0.25;

/// Identification settings for a bench motor: test current a quarter of
/// the maximum, open-loop voltage limit a quarter of the bus, and a slow
/// alignment sweep for motors with a large flux linkage (their back-EMF
/// would otherwise swamp the small alignment voltage).
///
/// With a hall-class sensor ([`hall_class`]) the current stage interpolates
/// the angle between the edges (foc-core `AngleCalibration::
/// interpolation_half_count`), but the tracked speed still ripples at the
/// edge rate: the flux step runs at a first speed of at least 400 edges per
/// second, with a [`HALL_FLUX_SPEED_TOLERANCE`] band and a longer average.
/// `alignment.sensor_counts_per_rev` is set so that the alignment removes
/// the half-count bias of a counting sensor. The mechanical step's target
/// speed is [`mechanics_speed_rad_s`] (its other settings are foc-core's
/// defaults, the hub motor's 48-count sensor included).
pub fn config(s: &Setup, pole_pairs: u8) -> IdentificationConfig {
    let mut c = IdentificationConfig::new(
        pole_pairs,
        s.pwm_hz(),
        0.25 * s.max_current_a,
        0.25 * s.bench.bus_voltage_v as f32,
    );
    if s.motor.flux_linkage_wb > 0.05 {
        c.alignment.speed_e_rad_s = 0.25 * core::f32::consts::TAU;
    }
    if hall_class(s) {
        // The tracked speed of a coarse sensor ripples at the edge rate
        // (its mean is right): a first speed of at least 400 edges per
        // second, a wider band and a longer average.
        let cpr = s.bench.sensors.encoder_counts_per_rev.max(1) as f32;
        let f = &mut c.flux;
        f.first_speed_rad_s = f
            .first_speed_rad_s
            .max(400.0 * core::f32::consts::TAU / cpr);
        f.speed_tolerance = HALL_FLUX_SPEED_TOLERANCE;
        f.average_s = 0.4;
    }
    c.alignment.sensor_counts_per_rev = s.bench.sensors.encoder_counts_per_rev;
    c.mechanics.speed_target_rad_s = Some(mechanics_speed_rad_s(s));
    c
}

/// The mechanical step's target speed [rad/s]: 30 % of the no-load speed,
/// at most [`Setup::max_mission_speed_rad_s`] (without it the flux step's
/// second speed is used, which its clamp to twice the first speed puts at
/// 55 % of the no-load speed on the high-flux M153).
pub fn mechanics_speed_rad_s(s: &Setup) -> f32 {
    (0.3 * s.max_speed_rad_s()).min(s.max_mission_speed_rad_s())
}

/// How the identification ended (it ran to `Done` or to a named `Failed`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outcome {
    /// `Done(Identified)` or `Failed(reason)`.
    pub step: CalStep<Identified>,
    /// The stage it ended in (the failing one after `Failed`).
    pub stage: Step,
    /// Current offsets found and installed \[A\].
    pub offsets: Abc,
    /// PWM periods of the offset calibration.
    pub offset_periods: usize,
    /// PWM periods of the sensor check and the identification proper
    /// (after the offsets).
    pub periods: usize,
}

impl Outcome {
    /// The result and permit, if the identification succeeded.
    pub fn identified(&self) -> Option<&Identified> {
        match &self.step {
            CalStep::Done(d) => Some(d),
            _ => None,
        }
    }
}

/// Why the drive stopped (not a named identification failure).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Error {
    /// The offset calibration rejected the readings.
    Offsets(OffsetError),
    /// A sensor did not answer during start-up (its fault is latched).
    StartUp(Fault),
    /// The supervisor latched a fault (bridge off).
    Fault {
        /// The fault.
        fault: Fault,
        /// Identification stage.
        stage: Step,
    },
    /// Not finished within [`TIME_LIMIT_S`].
    Timeout(Step),
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Error::Offsets(e) => write!(f, "current offsets rejected: {e:?}"),
            Error::StartUp(fault) => write!(f, "start-up failed: {}", fault.name()),
            Error::Fault { fault, stage } => write!(f, "fault {} during {stage:?}", fault.name()),
            Error::Timeout(stage) => write!(f, "not finished in {TIME_LIMIT_S} s ({stage:?})"),
        }
    }
}

impl std::error::Error for Error {}

/// The drive's lifecycle settings the bench starts from: the firmware's
/// sequence with the bench's offset limits and `cfg`.
pub fn lifecycle_config(sim: &Sim, setup: &Setup, cfg: IdentificationConfig) -> LifecycleConfig {
    let rates = sim.cascade.config().rates;
    LifecycleConfig {
        offsets: Some(OffsetLimits {
            samples: OFFSET_SAMPLES,
            max_offset_a: 0.1 * setup.max_current_a,
            max_noise_a: 0.05 * setup.max_current_a,
        }),
        sensor_check_reads: SENSOR_CHECK_READS,
        identification: Some(cfg),
        identify_at_start_up: true,
        speed_divider: rates.speed_divider,
        position_divider: rates.position_divider,
        angle_kind: foc_core::drive::AngleKind::Incremental,
        stored: None,
    }
}

/// Restart `sim`'s controller from reset (same configuration) and run the
/// drive's start-up: offsets with the bridge off, the sensor check, then
/// the identification of `cfg`, one PWM period at a time. `tick` is called
/// after every period. See the module docs for what is left installed.
///
/// `Ok` for both a finished and a named failed identification (see
/// [`Outcome::step`]); after a failure the bridge is off and the cascade is
/// uncalibrated. `Err` when the drive itself stopped it.
pub fn run(
    sim: &mut Sim,
    setup: &Setup,
    cfg: IdentificationConfig,
    tick: &mut dyn FnMut(&Sim),
) -> Result<Outcome, Error> {
    drive(sim, setup, cfg, false, tick)
}

/// [`run`] on a drive that runs sensorless (`sim`'s configuration has a
/// `sensorless` start), with the angle withheld from every sample (a
/// board without an angle input, design §29): the sensor check is skipped,
/// the identification measures the flux linkage on a turning field and
/// leaves a permit that holds only while the drive runs sensorless.
pub fn run_without_angle(
    sim: &mut Sim,
    setup: &Setup,
    cfg: IdentificationConfig,
    tick: &mut dyn FnMut(&Sim),
) -> Result<Outcome, Error> {
    drive(sim, setup, cfg, true, tick)
}

fn drive(
    sim: &mut Sim,
    setup: &Setup,
    cfg: IdentificationConfig,
    withhold_angle: bool,
    tick: &mut dyn FnMut(&Sim),
) -> Result<Outcome, Error> {
    let life = lifecycle_config(sim, setup, cfg);
    // From reset: the current sensing's offsets are zeroed first.
    sim.set_current_offsets(Abc::default());
    sim.cascade = Cascade::from_reset(*sim.cascade.config(), life);
    let limit = (TIME_LIMIT_S * setup.pwm_hz()) as usize;
    let mut offsets = None;
    for k in 0..limit {
        let mut sample = sim.sample();
        if withhold_angle {
            sample.angle = None;
        }
        sim.step_with(&sample);
        tick(sim);
        let Some(event) = sim.cascade.last_output().and_then(|o| o.event) else {
            continue;
        };
        let (offsets_a, offset_periods) = offsets.unwrap_or((Abc::default(), k + 1));
        let outcome = |step, stage| Outcome {
            step,
            stage,
            offsets: offsets_a,
            offset_periods,
            periods: k + 1 - offset_periods,
        };
        match event {
            Event::OffsetsDone(o) => offsets = Some((o, k + 1)),
            Event::OffsetsFailed(e) => return Err(Error::Offsets(e)),
            Event::CurrentSenseFailed => return Err(Error::StartUp(Fault::CurrentSenseError)),
            Event::SensorCheckFailed => return Err(Error::StartUp(Fault::AngleSensorError)),
            Event::StartUpDone
            | Event::IdentificationStarted
            | Event::CalibrationRestored
            | Event::CoggingMeasured { .. }
            | Event::EncoderLinearised { .. }
            | Event::IndexFound { .. } => {}
            Event::Identified(result) => {
                let c = sim.cascade.current.config();
                // The permit the stage holds now, as a value.
                let permit = Calibrated::supplied(c.angle, c.current)
                    .expect("the identification's permit passed this check");
                let done = CalStep::Done(Identified { result, permit });
                return Ok(outcome(done, Step::Done));
            }
            Event::IdentificationFailed(e, st) => return Ok(outcome(CalStep::Failed(e), st)),
            Event::IdentificationAborted(fault, st) => {
                let fault = fault.unwrap_or(Fault::CalibrationFailed);
                return Err(Error::Fault { fault, stage: st });
            }
        }
    }
    let stage = sim
        .cascade
        .lifecycle()
        .identification_step()
        .unwrap_or(Step::Resistance);
    Err(Error::Timeout(stage))
}
