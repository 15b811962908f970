//! Stored records and the board: which record a board takes ([`admit`]),
//! which of its tables ([`admit_tables`]), the record of the settings in
//! force ([`live_record`]), and the store as the service uses it
//! ([`RecordStore`]).

use crate::board::Board;
use foc_protocol::message::ErrorCode;
use foc_protocol::WatchdogConfig;
use foc_store::record::WatchdogRecord;
use foc_store::settings::{reaction_record, timeout_reaction, Tables};
use foc_store::{CanRecord, DriveRecord, Invalid, Label, Settings, Store, StoreError};

/// `rec` applied onto the board's build-time settings: whole, or refused.
/// On top of the record's own checks, the board's: its current limit, its
/// over-voltage threshold (the regen limit's end and the brake's
/// switch-on voltage below it: else the fault lets the motor coast and its
/// back-EMF charges the bus through the body diodes), its motor's pole
/// pairs (the identification and a hall decoder are built for them) and
/// its sensor's counts per turn (a calibration from another sensor is
/// meaningless here). The record's d-current reference (`[field]`, design
/// §30; none: the motor's defaults) is checked by
/// [`DriveRecord::apply`] with the drive's own rule on the board's angle
/// sensor: field weakening on halls is `field.field_weakening`.
///
/// Where the sensor's zero does not survive a reset (an incremental
/// encoder), the record's motor model and gains apply but not its
/// calibration: the settings come back uncalibrated, with the board's
/// angle configuration, until an identification. A calibration made
/// without the sensor (`sensorless_only`, design §29) applies on every
/// board: it has no zero to lose.
pub fn admit(board: &Board, rec: &DriveRecord) -> Result<Settings, Invalid> {
    let base = &board.base;
    let invalid = |field| Err(Invalid { field });
    if rec.motor.pole_pairs != base.current.motor.pole_pairs {
        return invalid("motor.pole_pairs");
    }
    if rec
        .calibration
        .as_ref()
        .is_some_and(|c| c.sensor_counts_per_rev != base.angle.sensor_counts_per_rev)
    {
        return invalid("calibration.sensor_counts_per_rev");
    }
    let mut s = rec.apply(base, board.pwm_hz)?;
    if s.limits.max_current_a > board.max_current_a {
        return invalid("limits.max_current_a");
    }
    if let Some(p) = &rec.power {
        let over_voltage_v = board.bus_over_voltage_v();
        if p.regen_end_v >= over_voltage_v {
            return invalid("power.regen_end_v");
        }
        if p.brake_on_v < f32::INFINITY && p.brake_on_v >= over_voltage_v {
            return invalid("power.brake_on_v");
        }
    }
    // A sensorless setting this board's build cannot derive a start from
    // (it would run on its sensor while the record says sensorless).
    let derived = board.cascade_of(&s).current;
    if s.sensorless.is_some() && derived.sensorless.is_none() && derived.fallback.is_none() {
        return invalid("sensorless");
    }
    if s.sensorless
        .is_some_and(|sl| sl.bus_voltage_v >= board.bus_over_voltage_v())
    {
        return invalid("sensorless.bus_voltage_v");
    }
    // (A calibration made without the sensor has no zero to lose.)
    if s.calibrated && !board.zero_survives_reset && !s.angle.sensorless_only {
        crate::log_warn!("store: the stored electrical zero does not apply to an incremental encoder (its zero is where the rotor was at reset): motor model and gains kept, identification needed");
        s.calibrated = false;
        s.angle = base.angle;
    }
    Ok(s)
}

/// The tables of `rec` (admitted whole by [`admit`], which checked them
/// with the record) this board takes. The anticogging map is referred to
/// the electrical angle, which every calibration refers to the magnets.
/// The angle sensor's correction is referred to the sensor's reading:
/// where its zero does not survive a reset (an incremental encoder) the
/// stored correction belongs to another zero and is dropped, with a log
/// line saying so (learn it again once the drive is calibrated). The map
/// stored with a correction goes with it: it was measured on the
/// corrected angle, and on the uncorrected one a sensor's eccentricity
/// moves it by `p e(theta)` from one pole pair to the next (on the GL80,
/// 0.3 deg of eccentricity made the zero-torque ripple 1.8 times worse
/// than without a map, design §32).
pub fn admit_tables(board: &Board, rec: &DriveRecord) -> Tables {
    let mut t = Tables::of_record(rec);
    if t.has_angle_correction() && !board.zero_survives_reset {
        crate::log_warn!("store: the stored angle correction does not apply to an incremental encoder (its reading's zero is where the rotor was at reset): dropped with the anticogging map measured on it, learn both again");
        t = Tables::NONE;
    }
    t
}

/// The record of the settings `s` and the tables `t` in force, labelled
/// `label`, with the link watchdog `link` in force.
pub fn live_record(
    board: &Board,
    label: &Label,
    s: &Settings,
    t: &Tables,
    link: WatchdogConfig,
) -> DriveRecord {
    let mut s = *s;
    s.watchdog = WatchdogRecord {
        timeout_periods: link.timeout_periods,
        reaction: reaction_record(link.reaction),
    };
    DriveRecord::from_settings(label, board.pwm_hz, &s).with_tables(t)
}

/// The link-watchdog setting a record carries.
pub fn link_setting(rec: &DriveRecord) -> WatchdogConfig {
    WatchdogConfig {
        timeout_periods: rec.watchdog.timeout_periods,
        reaction: timeout_reaction(rec.watchdog.reaction),
    }
}

/// A store failure as the link reports it: a record that is not one
/// (damaged, another version, out of range, none valid) is `BadRecord`,
/// anything else (flash, layout, full, an inconsistent region)
/// `StoreFailed`.
pub fn store_error(e: StoreError) -> ErrorCode {
    crate::log_warn!("store: {}", e);
    match e {
        StoreError::Record(_) | StoreError::Invalid(_) | StoreError::NoValidRecord => {
            ErrorCode::BadRecord
        }
        StoreError::Layout | StoreError::Flash(_) | StoreError::Corrupt | StoreError::Full => {
            ErrorCode::StoreFailed
        }
    }
}

/// The configuration store as the service uses it. [`Store`] is one; a
/// board wraps it to stretch its watchdog over a flash stall.
pub trait RecordStore {
    /// The newest drive record, if any.
    fn load(&mut self) -> Result<Option<DriveRecord>, StoreError>;
    /// Append a drive record.
    fn save(&mut self, rec: &DriveRecord) -> Result<(), StoreError>;
    /// Forget every record (the next boot starts from the build-time
    /// settings).
    fn erase(&mut self) -> Result<(), StoreError>;
    /// The CAN node's stored communication settings, if any.
    fn load_can(&mut self) -> Result<Option<CanRecord>, StoreError>;
    /// Keep the CAN node's communication settings.
    fn save_can(&mut self, rec: &CanRecord) -> Result<(), StoreError>;
}

impl<F: embedded_storage::nor_flash::NorFlash> RecordStore for Store<F> {
    fn load(&mut self) -> Result<Option<DriveRecord>, StoreError> {
        Store::load(self)
    }
    fn save(&mut self, rec: &DriveRecord) -> Result<(), StoreError> {
        Store::save(self, rec)
    }
    fn erase(&mut self) -> Result<(), StoreError> {
        Store::erase(self)
    }
    fn load_can(&mut self) -> Result<Option<CanRecord>, StoreError> {
        Store::load_can(self)
    }
    fn save_can(&mut self, rec: &CanRecord) -> Result<(), StoreError> {
        Store::save_can(self, rec)
    }
}

/// No store at all (a board whose region is unusable, a simulation
/// without flash): every operation answers `Unsupported`.
pub enum NoStore {}

impl RecordStore for NoStore {
    fn load(&mut self) -> Result<Option<DriveRecord>, StoreError> {
        match *self {}
    }
    fn save(&mut self, _: &DriveRecord) -> Result<(), StoreError> {
        match *self {}
    }
    fn erase(&mut self) -> Result<(), StoreError> {
        match *self {}
    }
    fn load_can(&mut self) -> Result<Option<CanRecord>, StoreError> {
        match *self {}
    }
    fn save_can(&mut self, _: &CanRecord) -> Result<(), StoreError> {
        match *self {}
    }
}
