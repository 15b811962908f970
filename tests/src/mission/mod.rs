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
//! 7. **braking** (design §18): a DC link sized from the motor file
//!    ([`braking_dc_link`]: a capacitance that gives the bus a time
//!    constant of 10 PWM periods on the regen ramp at the maximum current
//!    and takes the winding's energy at the maximum current between the
//!    chopper's switch-on voltage and the over-voltage threshold, a brake
//!    resistor that takes the rated
//!    current at the chopper's switch-on voltage) on a battery, a spin-up
//!    to the ramp's speed, then the supply made non-sinking (a diode-fed
//!    bench supply) and a hard stop (0 rad/s at once) with the board's
//!    power limits ([`PowerLimitsConfig::for_board`]: regen ramp and d-axis
//!    braking): the peak bus voltage against the over-voltage threshold,
//!    the stopping time and where the kinetic energy went; then the same
//!    stop with the brake resistor switched by the drive's chopper. It
//!    fails on a bus at or above the over-voltage threshold or a fault; a
//!    stop that takes longer than the segment is reported, not failed. The
//!    power limits and the DC link are only in this segment (every earlier
//!    figure is unchanged).
//! 8. **field weakening** (design §30; the segment's module, `field_weakening.rs`): turned
//!    on with `CurrentStage::set_field`, from rest to 2.2 x the drive
//!    model's base speed (or 60 % of the way to the model's top speed),
//!    held, a load step there (half the rated torque or less), back to
//!    rest, turned off. It fails on a fault, a speed reached more than 2 %
//!    off the command, a phase current at or above 1.1 x the limit, or
//!    below 2 x base where 2.2 x was commanded. Skipped, the reason
//!    stated, on a coarse angle sensor (halls: refused) or a base speed
//!    whose 1.2 x is beyond 80 % of the bench's resolved speed.
//! 9. **low-speed smoothness** (design §32, §33; `smoothness.rs`), where
//!    the motor file's imperfections are given ([`run_mission_with`];
//!    `cargo xtask sim` gives them): on a separate simulation of the same
//!    setup with the file's cogging, sensor error and dead time, driven
//!    by the mission's calibration, the zero-torque shaft-torque ripple,
//!    the speed ripple at 1 % and 5 % of the no-load speed and the
//!    sensor's angle error with both corrections off; the encoder
//!    linearisation, the anticogging calibration and the linearisation
//!    again with the map on, through the drive's lifecycle; the same
//!    figures with both on. It fails on a calibration
//!    that does not finish, a zero-torque ripple down less than 3 times,
//!    an angle error neither smaller nor within two counts, or a fault.
//!    Skipped, the reason stated, on a coarse angle sensor (halls).
//!
//! ```no_run
//! use foc_bench::mission::{run_mission, Setup};
//! let setup = Setup::load("tests/motors/dji-m2006.toml").unwrap();
//! let r = run_mission(&setup, &mut |_| {});
//! println!("{}", r.summary.to_markdown());
//! assert!(r.summary.failures().is_empty());
//! ```

mod field_weakening;
mod figures;
mod markdown;
mod result;
mod run;
mod segments;
mod sensorless;
mod setup;
mod sim;
mod smoothness;
mod summary;

use field_weakening::*;
use figures::*;
pub use result::*;
pub use run::*;
pub use segments::{
    braking_dc_link, BRAKING_ESR_TIME_CONSTANT_S, BRAKING_LINK_RULE, BRAKING_RAMP_PERIODS,
};
pub use sensorless::*;
pub use setup::*;
pub use sim::*;
pub use smoothness::*;
pub use summary::*;

use crate::identify;
use crate::metrics;
use crate::motor_file::{Imperfections, MotorFile, MotorFileError};
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
