//! # foc-core: portable field-oriented control
//!
//! Everything a three-phase PMSM/BLDC drive computes, with no hardware, no
//! allocation, no `unsafe` and no panics in the hot path. Boards reach the
//! control code only through the traits in [`hal`].
//!
//! Frame convention (see [`transforms`]): amplitude-invariant Clarke with the
//! beta axis 90 electrical degrees *ahead* of phase A (positive rotation
//! A -> B -> C), and Park with `d` along the rotor flux (`theta_e`) and `q`
//! 90 degrees ahead. The source design (`MC_FOC_DRIVE.c`, see
//! `docs/src/design/`) writes its beta axis reversed; the
//! mapping is documented and tested in [`transforms`].
//!
//! Module map (design section in brackets):
//! - [`frames`]: `Abc`, `AlphaBeta`, `Dq` value types.
//! - [`angle`]: wrapping electrical / mechanical angles (design §3).
//! - [`trig`]: fast sin/cos for the current loop.
//! - [`transforms`]: Clarke, Park and inverses (design §4, §5, §7).
//! - [`svpwm`]: seven-segment space-vector PWM (design §8).
//! - [`pi`]: PI controller with anti-windup (design §6).
//! - [`tuning`]: current-loop gains from motor parameters (design §11).
//! - [`control`]: the loops and stages, the fault supervisor.
//! - [`calibration`]: offsets and the motor identification routines.
//! - [`drive`]: the drive's life each PWM period, from reset on, and the
//!   cascade ([`drive::cascade`]) that assembles the loops.
//! - [`response`]: step-response figures (design §22).
//! - [`scope`]: scope capture of the feedback (design §22).
//! - [`hal`]: hardware traits implemented by boards.
//! - [`math`]: square root, clamps and constants without library calls.
//!
//! ## Layers
//!
//! Bottom to top; a module may use its own layer and those below, never
//! one above (`tests/layers.rs` reads the source and fails otherwise):
//!
//! 1. math: [`math`], [`frames`], [`angle`], [`trig`], [`transforms`],
//!    [`svpwm`], [`pi`], [`tuning`];
//! 2. [`hal`]: the hardware traits;
//! 3. [`control`]: the loops, stages, estimators and checks of one
//!    period, and the permit type that unlocks them;
//! 4. [`calibration`]: the routines that measure what `control` needs and
//!    hand out permits;
//! 5. [`drive`] (the lifecycle, the rules of the link, the cascade that
//!    assembles the loops), [`scope`], [`response`].
//!
//! # Where to start reading
//!
//! The math first: [`transforms`] (Clarke, Park) and [`svpwm`], then one
//! current-loop period in [`control::stage::CurrentStage`], the loops it
//! feeds in [`drive::cascade::Cascade`], and the whole drive's period, with
//! its faults and identification, in [`drive::lifecycle::Lifecycle`]. The
//! book's design chapters (`docs/src/design/`) explain each, cited here as
//! "design §N".
#![no_std]
#![forbid(unsafe_code)]
// The no-panic lints and `missing_docs`: `[workspace.lints]` (Cargo.toml).

pub mod angle;
pub mod calibration;
pub mod control;
pub mod drive;
pub mod frames;
pub mod hal;
pub mod math;
pub mod pi;
pub mod response;
pub mod scope;
pub mod svpwm;
pub mod transforms;
pub mod trig;
pub mod tuning;

pub(crate) use math::{all_finite, clamp_ordered};
pub use math::{clamp, sqrtf, FRAC_1_SQRT_3, FRAC_2_SQRT_3, SQRT_3, SQRT_3_2};
