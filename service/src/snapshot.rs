//! What the drive looked like when a frame arrived: the service decides
//! on this copy, never on live state (the loops keep running meanwhile).

use foc_core::calibration::identification::IdentificationResult;
use foc_core::calibration::Calibrated;
use foc_core::control::{Command, Feedback};
use foc_core::drive::Status;

/// A successful identification, as the current loop publishes it.
#[derive(Clone, Copy, Debug)]
pub struct Identified {
    /// What was measured.
    pub result: IdentificationResult,
    /// The permit the stage holds since: angle calibration, motor model
    /// and current-loop gains.
    pub permit: Calibrated,
    /// Identifications so far (tells the service a new one happened).
    pub count: u32,
}

/// Requests committed to the drive's mailboxes that the current loop may
/// not have taken yet (the status in a [`Snapshot`] is the last period's).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pending {
    /// The operator's command in the mailbox (taken or not).
    pub command: Command,
    /// A calibration (offsets, identification) requested and not taken.
    pub calibration: bool,
}

/// The shared state at one instant (taken together, under one lock on a
/// board).
#[derive(Clone, Copy, Debug)]
pub struct Snapshot {
    /// Latest feedback of the current loop.
    pub feedback: Feedback,
    /// Longest current-loop run \[cycles\] (0 where not measured).
    pub max_loop_cycles: u32,
    /// The drive's status (started, mode, faulted, calibrated).
    pub status: Status,
    /// The last successful identification.
    pub identified: Option<Identified>,
    /// What the drive has been asked but has not taken yet.
    pub pending: Pending,
}
