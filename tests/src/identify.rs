//! Motor identification against the bench plant, driven through a [`Sim`]'s
//! real `Cascade`, as the firmware drives it through its current stage (so
//! the supervisor watches every period of it):
//!
//! 1. **current offsets**: bridge off, [`OFFSET_SAMPLES`] periods averaged by
//!    foc-core's `OffsetCalibrator`; the offsets are installed in the
//!    [`Sim`] ([`Sim::set_current_offsets`]) and subtracted from every later
//!    sample, as the firmware's `CurrentSense::set_offsets_a` does;
//! 2. **identification** (foc-core `calibration::identification`):
//!    resistance, inductance, current-loop gains, alignment (zero,
//!    direction, pole-pair check) and flux linkage (for hall-class sensors
//!    with a wider speed band, see [`config`]). Open-loop requests become `Command::OpenLoop`, velocity
//!    requests `Command::Velocity` after the provisional permit is
//!    installed. During it the cascade's current limit is 1.5 x the test
//!    current (the flux step runs closed loop);
//! 3. on success: bridge off, the configured limits back, the final permit
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
use foc_core::calibration::identification::{
    Identification, IdentificationConfig, Identified, Stage,
};
use foc_core::calibration::offsets::{OffsetCalibrator, OffsetError, OffsetLimits, OffsetStep};
use foc_core::calibration::{CalInput, CalStep, ClosedLoopFeedback};
use foc_core::control::{BridgeCommand, Command, CommandError, Fault, Mode};
use foc_core::frames::Abc;

/// PWM periods the current-offset calibration averages.
pub const OFFSET_SAMPLES: u32 = 1000;

/// Simulated-time limit of the identification [s].
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
/// the half-count bias of a counting sensor.
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
    c
}

/// How the identification ended (it ran to `Done` or to a named `Failed`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outcome {
    /// `Done(Identified)` or `Failed(reason)`.
    pub step: CalStep<Identified>,
    /// The stage it ended in (the failing one after `Failed`).
    pub stage: Stage,
    /// Current offsets found and installed [A].
    pub offsets: Abc,
    /// PWM periods of the offset calibration.
    pub offset_periods: usize,
    /// PWM periods of the identification proper (after the offsets).
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

/// Why the driving itself (not the identification) stopped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Error {
    /// The offset calibration rejected the readings.
    Offsets(OffsetError),
    /// The cascade refused a command the identification asked for.
    Refused {
        /// The command.
        command: Command,
        /// Why.
        error: CommandError,
        /// Identification stage.
        stage: Stage,
    },
    /// The supervisor latched a fault (bridge off).
    Fault {
        /// The fault.
        fault: Fault,
        /// Identification stage.
        stage: Stage,
    },
    /// Not finished within [`TIME_LIMIT_S`].
    Timeout(Stage),
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Error::Offsets(e) => write!(f, "current offsets rejected: {e:?}"),
            Error::Refused {
                command,
                error,
                stage,
            } => write!(
                f,
                "command {command:?} refused ({error:?}) during {stage:?}"
            ),
            Error::Fault { fault, stage } => write!(f, "fault {} during {stage:?}", fault.name()),
            Error::Timeout(stage) => write!(f, "not finished in {TIME_LIMIT_S} s ({stage:?})"),
        }
    }
}

impl std::error::Error for Error {}

/// Offset calibration with the bridge off, then the identification of
/// `cfg`, one PWM period at a time through `sim`'s cascade (which must be
/// disabled and is expected uncalibrated). `tick` is called after every
/// period. See the module docs for what is left installed.
///
/// `Ok` for both a finished and a named failed identification (see
/// [`Outcome::step`]); after a failure the bridge is off and the cascade
/// keeps whatever permit it had. `Err` when the drive itself stopped it.
pub fn run(
    sim: &mut Sim,
    setup: &Setup,
    cfg: IdentificationConfig,
    tick: &mut dyn FnMut(&Sim),
) -> Result<Outcome, Error> {
    // 1. Current offsets, bridge off.
    sim.cascade.command(Command::Disable).ok();
    let mut cal = OffsetCalibrator::new(OffsetLimits {
        samples: OFFSET_SAMPLES,
        max_offset_a: 0.1 * setup.max_current_a,
        max_noise_a: 0.05 * setup.max_current_a,
    });
    let mut offset_periods = 0;
    let offsets = loop {
        let raw = sim.last_sample().currents;
        sim.step();
        offset_periods += 1;
        tick(sim);
        match cal.step(raw.to_abc()) {
            OffsetStep::InProgress => {}
            OffsetStep::Done(o) => break o,
            OffsetStep::Failed(e) => return Err(Error::Offsets(e)),
        }
    };
    sim.set_current_offsets(offsets);

    // 2. Identification, current limit 1.5 x the test current.
    let limits = sim.cascade.current.config().limits;
    let speed = *sim.cascade.speed.speed_loop().config();
    let i_lim = 1.5 * cfg.alignment_current_a;
    sim.cascade.current.set_limits(foc_core::control::Limits {
        max_current_a: i_lim,
        ..limits
    });
    sim.cascade
        .speed
        .speed_loop()
        .set_config(foc_core::control::speed::SpeedLoopConfig {
            current_limit_a: i_lim,
            ..speed
        });
    let restore = |sim: &mut Sim| {
        sim.cascade.command(Command::Disable).ok();
        sim.cascade.current.set_limits(limits);
        sim.cascade.speed.speed_loop().set_config(speed);
    };
    let mut id = Identification::new(cfg);
    let mut provisional = false;
    let limit = (TIME_LIMIT_S * setup.pwm_hz()) as usize;
    for k in 0..limit {
        let sample = sim.sample();
        let fb = *sim.cascade.feedback();
        let currents = sample.currents.map_or(Abc::default(), |c| c.to_abc());
        let m = sim.last_sample();
        let mut inp = CalInput::open_loop(currents, m.angle, m.v_bus_v);
        if fb.mode == Mode::Velocity {
            inp.closed_loop = Some(ClosedLoopFeedback {
                v_dq_v: fb.v_dq_v,
                i_dq_a: fb.i_dq_a,
                velocity_rad_s: fb.velocity_rad_s,
            });
        }
        let step = id.step(&inp);
        let cmd = match step {
            CalStep::Apply { v_dq, theta_e } => Command::OpenLoop {
                v_d_v: v_dq.d,
                v_q_v: v_dq.q,
                theta_e,
                omega_e_rad_s: 0.0,
            },
            CalStep::Velocity { rad_s } => {
                // The first velocity request: install the provisional
                // permit (measured gains and zero, flux linkage 0).
                if !provisional {
                    if let Some(p) = id.permit() {
                        sim.cascade.set_calibration(&p);
                        provisional = true;
                    }
                }
                Command::Velocity { rad_s }
            }
            done_or_failed => {
                restore(sim);
                if let CalStep::Done(d) = &done_or_failed {
                    sim.cascade.set_calibration(&d.permit);
                }
                return Ok(Outcome {
                    step: done_or_failed,
                    stage: id.stage(),
                    offsets,
                    offset_periods,
                    periods: k,
                });
            }
        };
        if fb.active != cmd {
            if let Err(error) = sim.cascade.command(cmd) {
                restore(sim);
                return Err(Error::Refused {
                    command: cmd,
                    error,
                    stage: id.stage(),
                });
            }
        }
        if let BridgeCommand::SafeState = sim.step_with(&sample) {
            if let Some(fault) = sim.cascade.feedback().first_fault {
                restore(sim);
                return Err(Error::Fault {
                    fault,
                    stage: id.stage(),
                });
            }
        }
        tick(sim);
    }
    restore(sim);
    Err(Error::Timeout(id.stage()))
}
