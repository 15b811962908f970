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
//! `shared/reference/foc-notes.md`) writes its beta axis reversed; the
//! mapping is documented and tested in [`transforms`].
//!
//! Module map (source section in brackets):
//! - [`frames`]: `Abc`, `AlphaBeta`, `Dq` value types.
//! - [`angle`]: wrapping electrical / mechanical angles (section 3).
//! - [`trig`]: fast sin/cos for the current loop.
//! - [`transforms`]: Clarke, Park and inverses (sections 4, 5, 7).
//! - [`svpwm`]: seven-segment space-vector PWM (section 8).
//! - [`pi`]: PI controller with anti-windup (section 6).
//! - [`tuning`]: current-loop gains from motor parameters (section 11).
//! - [`hal`]: hardware traits implemented by boards.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable,
        clippy::todo
    )
)]

pub mod angle;
pub mod frames;
pub mod hal;
pub mod pi;
pub mod svpwm;
pub mod transforms;
pub mod trig;
pub mod tuning;

/// `sqrt(3)`.
pub const SQRT_3: f32 = 1.732_050_8;
/// `1 / sqrt(3)`.
pub const FRAC_1_SQRT_3: f32 = 0.577_350_26;
/// `2 / sqrt(3)`.
pub const FRAC_2_SQRT_3: f32 = 1.154_700_5;
/// `sqrt(3) / 2`.
pub const SQRT_3_2: f32 = 0.866_025_4;

/// Square root usable in `no_std` (single precision; `vsqrt.f32` on the M4F
/// where the compiler maps it, software otherwise).
#[inline]
pub fn sqrtf(x: f32) -> f32 {
    libm::sqrtf(x)
}

/// Clamp `x` to `[lo, hi]` with plain comparisons (no `fminf`/`fmaxf` calls,
/// which cost a library call each on the Cortex-M4F). A NaN `x` fails both
/// comparisons and is returned unchanged: callers that may see NaN check
/// `is_finite` first.
#[inline(always)]
pub fn clamp(x: f32, lo: f32, hi: f32) -> f32 {
    if x < lo {
        lo
    } else if x > hi {
        hi
    } else {
        x
    }
}
