//! Calibration routines: non-blocking state machines stepped from the
//! current loop (one call per PWM period, no busy waits), each with limits
//! and a clear failure reason.
//!
//! - [`offsets`]: current-sensor offsets, averaged with the bridge off.
//! - [`common`]: the shared step shape ([`CalInput`] in, [`CalStep`] out,
//!   [`CalError`] on failure).
//! - [`resistance`]: phase resistance from DC steps at 0/120/240 degrees.
//! - [`inductance`]: Ld and Lq from a square wave on a DC holding current.
//! - [`alignment`]: sensor direction, electrical zero and pole-pair check.
//! - [`flux`]: flux linkage from two closed-loop speeds.
//! - [`field_flux`]: flux linkage from two speeds of a turning field,
//!   without an angle sensor.
//! - [`mechanics`]: inertia, viscous and Coulomb friction from torque pulses.
//! - [`cogging`]: the anticogging map from a slow sweep in both directions.
//! - [`index`]: the incremental encoder's index, found at start-up.
//! - [`encoder`]: the angle sensor's error from turns at a steady speed.
//! - [`gains`]: current-loop gains from the measured values (technical optimum).
//! - [`permit`]: [`Calibrated`], the proof that closed-loop modes may start.
//! - [`identification`]: the sequencer running all of them in order.
//!
//! Every routine is stepped the same way: build a [`CalInput`] from this
//! period's measurements, call `step`, and do what the returned [`CalStep`]
//! says (apply an open-loop voltage, run velocity or torque mode, or stop).
//!
//! ```
//! use foc_core::calibration::{CalInput, CalStep};
//! use foc_core::calibration::identification::{Identification, IdentificationConfig};
//! use foc_core::{angle::MechanicalAngle, frames::Abc};
//! let mut id = Identification::new(IdentificationConfig::new(7, 20_000.0, 2.0, 6.0));
//! // In the PWM interrupt, every period:
//! let inp = CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0);
//! match id.step(&inp) {
//!     CalStep::Apply { v_dq, theta_e } => { /* open-loop voltage v_dq at theta_e */ let _ = (v_dq, theta_e); }
//!     CalStep::Velocity { rad_s } => { /* permit.apply_to(stage); velocity mode */ let _ = rad_s; }
//!     CalStep::Torque { iq_a } => { /* permit.apply_to(stage); torque mode */ let _ = iq_a; }
//!     CalStep::Done(identified) => { /* identified.permit.apply_to(...) */ let _ = identified; }
//!     CalStep::Failed(reason) => { /* bridge off, report `reason` */ let _ = reason; }
//! }
//! ```

pub mod alignment;
pub mod cogging;
pub mod common;
pub mod encoder;
pub mod field_flux;
pub mod flux;
pub mod gains;
pub mod identification;
pub mod index;
pub mod inductance;
pub mod mechanics;
pub mod offsets;
pub mod permit;
pub mod resistance;

pub use common::{CalError, CalInput, CalStep, ClosedLoopFeedback, Phase};
pub use permit::Calibrated;
