//! [`Service`]: the configuration in force, its label, the tables kept
//! with it, and what an identification left for the loops;
//! [`Service::boot`] takes the stored record at power-on.
//!
//! # The tables
//!
//! The anticogging map and the angle sensor's correction (design §32,
//! §33; [`Tables`], 1.5 KB) never travel in a `ConfigChange`, which
//! crosses the current loop's mailbox every period. The service keeps the
//! ones in force; its owner moves them between it and the current stage
//! outside the period, with the bridge off:
//!
//! - into the stage: at start-up before the interrupt runs (the stored
//!   record's, [`Service::tables`]), and when a link's outbox says so
//!   ([`crate::Outbox::tables`]: a record applied, a switch written),
//!   with [`Service::install_tables`] on the stage the drive lends while
//!   disabled (`Drive::stage_while_disabled`);
//! - back from the stage: after a calibration measured one
//!   (`Event::CoggingMeasured`, `Event::EncoderLinearised`), with
//!   [`Service::take_measured_tables`] before the next link, so that the
//!   next save stores it.

use crate::board::Board;
use crate::link::Link;
use crate::mailbox::ConfigMailbox;
use crate::records::{admit, admit_tables, link_setting, live_record, RecordStore};
use crate::snapshot::{Identified, Snapshot};
use foc_core::control::field::FieldConfig;
use foc_core::control::stage::CurrentStage;
use foc_core::control::Mechanics;
use foc_core::drive::ConfigChange;
use foc_protocol::scope::ScopePort;
use foc_protocol::WatchdogConfig;
use foc_store::settings::Tables;
use foc_store::{DriveRecord, Invalid, Label, Settings, StoreError};

/// What the boot found in the store.
#[derive(Clone, Debug, PartialEq)]
pub enum BootOutcome {
    /// No store (none configured, or its region unusable).
    NoStore,
    /// The store is empty: build-time settings.
    Empty,
    /// A record was loaded (`calibrated`: with an angle calibration that
    /// applies on this board).
    Loaded {
        /// The settings carry a calibration.
        calibrated: bool,
    },
    /// The record does not fit this board: build-time settings.
    Refused(Invalid),
    /// The store could not be read: build-time settings.
    Unreadable(StoreError),
}

/// The link's state of one drive (see the crate docs).
#[derive(Clone, Debug)]
pub struct Service {
    board: Board,
    settings: Settings,
    label: Label,
    /// The link-watchdog setting of the record loaded at boot.
    boot_link: Option<WatchdogConfig>,
    /// The identification last folded into `settings`.
    seen_identification: u32,
    /// Speed and position configurations re-derived from an
    /// identification's mechanics, for the next outbox.
    pending: ConfigMailbox,
    /// The tables in force (see the module docs).
    tables: Tables,
    /// The count of measured tables last taken from the stage.
    tables_seen: u32,
}

impl Service {
    /// The service of `board` with its build-time settings.
    pub fn new(board: Board) -> Self {
        Self {
            settings: board.base,
            board,
            label: Label::new(),
            boot_link: None,
            seen_identification: 0,
            pending: ConfigMailbox::EMPTY,
            tables: Tables::NONE,
            tables_seen: 0,
        }
    }

    /// Power-on: the stored record if there is one and the board takes it
    /// ([`admit`], its tables [`admit_tables`]: the owner installs them
    /// before the drive's interrupt runs), else the build-time settings.
    /// Never fails: what went wrong is in the outcome.
    pub fn boot<S: RecordStore>(board: Board, store: Option<&mut S>) -> (Self, BootOutcome) {
        let mut s = Self::new(board);
        let Some(store) = store else {
            return (s, BootOutcome::NoStore);
        };
        let outcome = match store.load() {
            Ok(None) => BootOutcome::Empty,
            Ok(Some(rec)) => match admit(&s.board, &rec) {
                Ok(settings) => {
                    s.settings = settings;
                    s.tables = admit_tables(&s.board, &rec);
                    s.boot_link = Some(link_setting(&rec));
                    s.label = rec.label;
                    BootOutcome::Loaded {
                        calibrated: settings.calibrated,
                    }
                }
                Err(e) => BootOutcome::Refused(e),
            },
            Err(e) => BootOutcome::Unreadable(e),
        };
        (s, outcome)
    }

    /// The board's facts.
    pub fn board(&self) -> &Board {
        &self.board
    }

    /// The configuration in force.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The drive's label (saved with the configuration).
    pub fn label(&self) -> &Label {
        &self.label
    }

    /// Replace the label (saved with the next save).
    pub fn set_label(&mut self, label: Label) {
        self.label = label;
    }

    /// The link-watchdog setting of the record loaded at boot.
    pub fn boot_link_setting(&self) -> Option<WatchdogConfig> {
        self.boot_link
    }

    /// The cascade configuration the drive starts with: the board's with
    /// the settings in force applied.
    pub fn cascade(&self) -> foc_core::drive::cascade::CascadeConfig {
        self.board.cascade_of(&self.settings)
    }

    /// The record of the configuration in force (with its tables) and
    /// the link watchdog `link`.
    pub fn live_record(&self, link: WatchdogConfig) -> DriveRecord {
        live_record(&self.board, &self.label, &self.settings, &self.tables, link)
    }

    /// The tables in force (see the module docs).
    pub fn tables(&self) -> &Tables {
        &self.tables
    }

    /// The tables in force, mutable (the link's switches).
    pub(crate) fn tables_mut(&mut self) -> &mut Tables {
        &mut self.tables
    }

    /// Install the tables in force in `stage` (the owner's part of an
    /// outbox's [`crate::Outbox::tables`], with the stage the drive lends
    /// while disabled), whole or not at all ([`Tables::install`]). If the
    /// stage refuses them, the stage's become the ones in force again
    /// (what a save stores is what the drive runs), logged.
    pub fn install_tables(&mut self, stage: &mut CurrentStage) -> Result<(), Invalid> {
        self.tables.install(stage).inspect_err(|e| {
            crate::log_warn!("tables: not installed: {}", e);
            self.tables = Tables::of_stage(stage);
        })
    }

    /// The drive could not lend its stage (not disabled, a calibration
    /// running): the stage's tables stay, and become the ones in force
    /// again, logged.
    pub fn tables_not_installed(&mut self, stage: &CurrentStage) {
        crate::log_warn!("tables: not installed: the drive is not disabled");
        self.tables = Tables::of_stage(stage);
    }

    /// How many measured tables have been taken from the stage
    /// ([`Self::take_measured_tables`]).
    pub fn tables_seen(&self) -> u32 {
        self.tables_seen
    }

    /// After a calibration measured a table (`Event::CoggingMeasured`,
    /// `Event::EncoderLinearised`; `count` the owner's count of them): the
    /// stage's tables become the ones in force, so a save stores them.
    /// Nothing when `count` was taken already. Call it before the next
    /// link (on a board, from the low priority under the drive's lock).
    pub fn take_measured_tables(&mut self, count: u32, stage: &CurrentStage) {
        if count == self.tables_seen {
            return;
        }
        self.tables_seen = count;
        self.tables = Tables::of_stage(stage);
    }

    /// The drive's change that makes the settings in force its own:
    /// limits, current loop, dividers, power, mechanics, the joint's
    /// travel range, the angle source, the d-current reference, and the
    /// calibration where the sensor's zero survives a reset (or where it
    /// was made without the sensor).
    pub fn full_change(&self) -> ConfigMailbox {
        let s = &self.settings;
        // A calibration made without the sensor has no zero to lose.
        let permit = s
            .permit()
            .filter(|p| self.board.zero_survives_reset || p.angle().sensorless_only);
        ConfigMailbox {
            current: Some(ConfigChange {
                limits: Some(s.limits),
                current: Some(s.current),
                dividers: Some(s.dividers),
                power: Some(s.power),
                permit,
                mechanics: s.mechanics,
                joint: Some(
                    s.joint
                        .rotor_change((s.limits.min_position_rad, s.limits.max_position_rad)),
                ),
                sensorless: Some(self.cascade().current.sensorless),
                beside: Some(self.cascade().current.fallback),
                field: Some(s.field),
                ..ConfigChange::default()
            }),
            speed: Some(s.speed),
            position: Some(s.position),
        }
    }

    /// Make `s` and `t` (a whole, admitted record's settings and tables)
    /// the configuration in force; the change every loop must take (the
    /// tables are installed by the owner: [`crate::Outbox::tables`]).
    pub(crate) fn adopt(&mut self, s: Settings, t: Tables, label: Label) -> ConfigMailbox {
        self.settings = s;
        self.tables = t;
        self.label = label;
        self.full_change()
    }

    /// The settings, mutable (the link's setters).
    pub(crate) fn settings_mut(&mut self) -> &mut Settings {
        &mut self.settings
    }

    /// Take a new identification into the settings: from now on they
    /// carry its angle calibration, motor model and gains (and so a save
    /// stores them). Its measured mechanics re-derive the speed and
    /// position loops, and a sensorless start is derived again, sent with
    /// the next [`Self::take_pending`] (the current stage's observer took
    /// them already).
    pub fn fold_identification(&mut self, id: Option<Identified>) {
        let Some(id) = id else {
            return;
        };
        if id.count == self.seen_identification {
            return;
        }
        self.seen_identification = id.count;
        self.settings.angle = id.permit.angle();
        self.settings.current = id.permit.current_config();
        self.settings.calibrated = true;
        if let Some(m) = id.result.mechanics {
            let mut c = self.cascade();
            let m = Mechanics::from(m);
            if c.set_mechanics(&m) {
                self.settings.mechanics = Some(m);
                self.settings.speed = c.speed;
                self.settings.position = c.position;
                self.pending.speed = Some(c.speed);
                self.pending.position = Some(c.position);
            }
        }
        // The d-current reference follows the identified motor (design
        // §30): MTPA where it is salient, the short circuit where its
        // characteristic current is within the limit, the deepest
        // weakening no deeper than its default (a motor with a smaller
        // `psi / Ld` than the one configured would have its flux reversed);
        // field weakening stays as it was set.
        let c = self.cascade();
        let derived = FieldConfig::for_motor(
            &c.current.current.motor,
            c.current.limits.max_current_a,
            c.rates.pwm_frequency_hz,
        );
        let before = self.settings.field;
        let field = FieldConfig {
            mtpa: derived.mtpa,
            short_circuit: derived.short_circuit,
            max_id_a: before.max_id_a.min(derived.max_id_a),
            ..before
        };
        if field != before && field.check().is_ok() {
            self.settings.field = field;
            self.pending.change(ConfigChange {
                field: Some(field),
                ..ConfigChange::default()
            });
        }
        // A sensorless start is derived from the motor and the mechanics:
        // again from the identified ones.
        if self.settings.sensorless.is_some() {
            let c = self.cascade();
            self.pending.change(ConfigChange {
                sensorless: Some(c.current.sensorless),
                beside: Some(c.current.fallback),
                ..ConfigChange::default()
            });
        }
    }

    /// The configurations an identification left for the loops, once.
    pub fn take_pending(&mut self) -> ConfigMailbox {
        core::mem::replace(&mut self.pending, ConfigMailbox::EMPTY)
    }

    /// The link of one frame, CAN message or poll: `snap` is the shared
    /// state now (its identification is folded in first), `store` the
    /// configuration store (`None`: none), `scope` the drive's scope
    /// (`None` outside frames), `link_setting` the link watchdog in force
    /// (saved with the configuration). Commit its outbox after the call.
    pub fn link<'a, S: RecordStore>(
        &'a mut self,
        snap: Snapshot,
        store: Option<&'a mut S>,
        scope: Option<&'a mut dyn ScopePort>,
        link_setting: WatchdogConfig,
    ) -> Link<'a, S> {
        self.fold_identification(snap.identified);
        Link::new(self, snap, store, scope, link_setting)
    }
}
