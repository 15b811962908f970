//! Where the drive's calibration stands ([`Progress`]), in the status the
//! host reads: a host that started a calibration follows its steps and
//! learns its result, a failure with its reason.

use crate::calibration::common::CalError;
use crate::calibration::identification::Step;
use crate::control::Fault;

/// The calibration running, or how the last one ended.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Progress {
    /// None since reset.
    #[default]
    Idle,
    /// The current sensor's offsets are being measured (bridge off).
    Offsets,
    /// The offset calibration rejected the readings, or the current sensor
    /// did not answer (fault latched).
    OffsetsFailed,
    /// The angle sensor is being checked (after the offsets).
    SensorCheck,
    /// The angle sensor did not answer during its check (fault latched).
    SensorCheckFailed,
    /// The identification runs this step.
    Running(Step),
    /// The last calibration finished (the offsets and the sensor check, or
    /// an identification whose permit is now installed).
    Done,
    /// The identification failed at this step for this reason (fault
    /// `CalibrationFailed` latched).
    Failed(CalError, Step),
    /// The identification was stopped at this step by a fault, or by an
    /// operator `Disable` (`None`).
    Aborted(Option<Fault>, Step),
}

impl Progress {
    /// True while a calibration runs.
    pub const fn is_running(self) -> bool {
        matches!(
            self,
            Progress::Offsets | Progress::SensorCheck | Progress::Running(_)
        )
    }
}
