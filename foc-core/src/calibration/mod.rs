//! Calibration routines: non-blocking state machines stepped from the
//! current loop (one call per PWM period, no busy waits), each with limits
//! and a clear failure reason.
//!
//! - [`offsets`]: current-sensor offsets, averaged with the bridge off.

pub mod offsets;
