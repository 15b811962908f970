//! A calibration's progress on the wire: the drive's
//! [`Progress`] as two parameter values, [`ParamId::CalibrationStep`] and
//! [`ParamId::CalibrationResult`] (see [`progress_codes`]), and the names a
//! host shows for them.
//!
//! ```
//! use foc_protocol::message::{progress_codes, step_name, failure_reason};
//! use foc_core::drive::Progress;
//! use foc_core::calibration::identification::Step;
//! use foc_core::calibration::CalError;
//! assert_eq!(progress_codes(Progress::Running(Step::Alignment)), (5, 1));
//! let (step, result) = progress_codes(Progress::Failed(CalError::RotorStuck, Step::Flux));
//! assert_eq!((step_name(step), failure_reason(result)), ("flux linkage", Some("RotorStuck")));
//! ```
//!
//! [`ParamId::CalibrationStep`]: super::ParamId::CalibrationStep
//! [`ParamId::CalibrationResult`]: super::ParamId::CalibrationResult

use foc_core::calibration::identification::Step;
use foc_core::calibration::{CalError, Phase};
use foc_core::drive::Progress;

/// Result code of a failure: this plus the reason's number.
pub const FAILED_BASE: u8 = 32;

/// Step names by `calibration-step` code.
pub const STEP_NAMES: [&str; 13] = [
    "none",
    "current offsets",
    "resistance",
    "inductance",
    "current-loop gains",
    "sensor alignment",
    "flux linkage",
    "mechanics",
    "finished",
    "sensor check",
    "anticogging",
    "encoder linearisation",
    "index search",
];

/// The words for the `calibration-result` codes below [`FAILED_BASE`].
pub const RESULT_NAMES: [&str; 6] = [
    "none since reset",
    "running",
    "done",
    "aborted (a fault, or a Disable)",
    "offsets rejected (or the current sensor did not answer)",
    "the angle sensor did not answer its check",
];

/// Failure reasons by number (`CalError`'s variants, in order): a
/// failure's result code is [`FAILED_BASE`] plus the number.
pub const FAILURE_REASONS: [&str; 22] = [
    "InvalidInput",
    "InvalidConfig",
    "OverCurrent",
    "Timeout",
    "OpenPhase(A)",
    "OpenPhase(B)",
    "OpenPhase(C)",
    "VoltageLimitReached",
    "PhaseImbalance",
    "CurrentSenseMismatch",
    "NoCurrentResponse",
    "PolePairMismatch",
    "SensorReversed",
    "RotorStuck",
    "SensorNoMotion",
    "SpeedNotReached",
    "ImplausibleResult",
    "NoAcceleration",
    "InertiaOutOfRange",
    "FrictionOutOfRange",
    "MechanicsIllConditioned",
    "IndexNotFound",
];

const fn step_code(s: Step) -> u8 {
    match s {
        Step::Resistance => 2,
        Step::Inductance => 3,
        Step::Gains => 4,
        Step::Alignment => 5,
        Step::Flux => 6,
        Step::Mechanics => 7,
        Step::Done => 8,
        Step::Cogging => 10,
        Step::Encoder => 11,
        Step::IndexSearch => 12,
    }
}

/// A failure's reason number (the index into the names).
pub const fn failure_code(e: CalError) -> u8 {
    match e {
        CalError::InvalidInput => 0,
        CalError::InvalidConfig => 1,
        CalError::OverCurrent => 2,
        CalError::Timeout => 3,
        CalError::OpenPhase(Phase::A) => 4,
        CalError::OpenPhase(Phase::B) => 5,
        CalError::OpenPhase(Phase::C) => 6,
        CalError::VoltageLimitReached => 7,
        CalError::PhaseImbalance => 8,
        CalError::CurrentSenseMismatch => 9,
        CalError::NoCurrentResponse => 10,
        CalError::PolePairMismatch { .. } => 11,
        CalError::SensorReversed => 12,
        CalError::RotorStuck => 13,
        CalError::SensorNoMotion => 14,
        CalError::SpeedNotReached => 15,
        CalError::ImplausibleResult => 16,
        CalError::NoAcceleration => 17,
        CalError::InertiaOutOfRange => 18,
        CalError::FrictionOutOfRange => 19,
        CalError::MechanicsIllConditioned => 20,
        CalError::IndexNotFound => 21,
    }
}

/// The two parameter values `(step, result)` of a progress.
pub const fn progress_codes(p: Progress) -> (u8, u8) {
    match p {
        Progress::Idle => (0, 0),
        Progress::Offsets => (1, 1),
        Progress::OffsetsFailed => (1, 4),
        Progress::SensorCheck => (9, 1),
        Progress::SensorCheckFailed => (9, 5),
        Progress::Running(s) => (step_code(s), 1),
        Progress::Done => (8, 2),
        Progress::Failed(e, s) => (step_code(s), FAILED_BASE.wrapping_add(failure_code(e))),
        Progress::Aborted(_, s) => (step_code(s), 3),
    }
}

/// The name of step code `code` (`"unknown"` past the table).
pub fn step_name(code: u8) -> &'static str {
    STEP_NAMES
        .get(usize::from(code))
        .copied()
        .unwrap_or("unknown")
}

/// The reason's name of a failure's result code (`CalError`'s variant).
pub fn failure_reason(code: u8) -> Option<&'static str> {
    code.checked_sub(FAILED_BASE)
        .and_then(|n| FAILURE_REASONS.get(usize::from(n)))
        .copied()
}
