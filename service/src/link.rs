//! [`Link`]: the protocol's [`DeviceContext`] of one frame. It decides on
//! a [`Snapshot`] and the configuration in force, and writes what the
//! frame asks for into its [`Outbox`], committed by the owner after the
//! call (on a board into the loops' mailboxes, in a simulation into the
//! drive at once).
//!
//! The drive's own rules (only while started and disabled, identification
//! not while faulted, commands against the limits and the permit) are
//! `foc_core::drive::Status`'s, applied by the protocol to the snapshot's
//! status for the immediate Nack and by the drive again when it takes the
//! change. The link adds (nothing changes, the host gets a Nack):
//!
//! | request | refused when | reply |
//! |---|---|---|
//! | limits | `max_current_a` above the board's hardware limit | `Unsupported` |
//! | current gains | not positive (a calibration permit cannot vouch for them) | `Unsupported` |
//! | position gains | a move faster than a velocity command may be | `Unsupported` |
//! | calibration `alignment` alone | always: it is part of `identification` | `Unsupported` |
//! | calibration `identification` | the board cannot identify on command | `Unsupported` |
//! | joint | the pending position command's target outside the new travel range | `NotDisabled` |
//! | limits | `max_current_a` below the anticogging map's peak (the record would not be saved) | `Unsupported` |
//! | a d-current reference parameter | the reference it makes is one the drive refuses (`foc_core::drive::check_field`: field weakening on a coarse angle sensor such as halls, or with `max-id` 0 or no bandwidth) | `Unsupported` |
//! | `anticogging`, `encoder-linearisation` on | no such table (never measured, nor loaded) | `NotCalibrated` |
//! | a table's switch | a command posted and not yet taken | `NotDisabled` |
//! | calibration `anticogging`, `encoder linearisation` | a command posted and not yet taken | `NotDisabled` |
//! | calibration `anticogging`, `encoder linearisation` | the drive's rule (`foc_core::drive::Status::check_sweep` on the angle calibration in force): uncalibrated; halls, or sensorless (without injection, for the map) | `NotCalibrated` / `Unsupported` |
//! | store operations | not quiet (see [`Link::quiet`]) | `NotDisabled` / `Busy` |
//! | apply a record | the board does not take it ([`crate::records::admit`]) | `BadRecord` |

use crate::mailbox::Outbox;
use crate::records::{admit, admit_tables, link_setting, store_error, RecordStore};
use crate::service::Service;
use crate::snapshot::Snapshot;
use crate::view::View;
use foc_core::calibration::Calibrated;
use foc_core::control::field::FieldConfig;
use foc_core::control::joint::JointSetup;
use foc_core::control::{Command, CommandError, Fault, FaultSet, Feedback, Limits, Mode};
use foc_core::drive::{ConfigChange, Status};
use foc_protocol::config::{ConfigSource, StoreOp, MAX_RECORD};
use foc_protocol::message::{
    Calibration, CurrentGains, ErrorCode, ParamId, PositionGains, SpeedGains, Telemetry,
};
use foc_protocol::scope::ScopePort;
use foc_protocol::{DeviceContext, Refusal, WatchdogConfig};
use foc_store::DriveRecord;

/// The [`DeviceContext`] of one frame (see the module docs).
pub struct Link<'a, S: RecordStore> {
    /// The shared state when the frame arrived.
    pub snap: Snapshot,
    service: &'a mut Service,
    store: Option<&'a mut S>,
    scope: Option<&'a mut dyn ScopePort>,
    link_setting: WatchdogConfig,
    /// What to commit.
    pub out: Outbox,
}

impl<'a, S: RecordStore> Link<'a, S> {
    pub(crate) fn new(
        service: &'a mut Service,
        snap: Snapshot,
        store: Option<&'a mut S>,
        scope: Option<&'a mut dyn ScopePort>,
        link_setting: WatchdogConfig,
    ) -> Self {
        Self {
            snap,
            service,
            store,
            scope,
            link_setting,
            out: Outbox::default(),
        }
    }

    /// The read-only part.
    pub fn view(&self) -> View<'_> {
        View {
            snap: &self.snap,
            service: self.service,
        }
    }

    /// The link-watchdog setting in force (saved with the configuration).
    pub fn link_setting(&self) -> WatchdogConfig {
        self.link_setting
    }

    /// The store, or `Unsupported` without one.
    pub(crate) fn store_mut(&mut self) -> Result<&mut S, ErrorCode> {
        self.store.as_deref_mut().ok_or(ErrorCode::Unsupported)
    }

    fn change(&mut self, c: ConfigChange) {
        self.out.config.change(c);
    }

    /// A flash operation stalls the processor for up to seconds: only
    /// while the bridge is off and stays off. The protocol checked the
    /// last period's status (started, disabled); a command committed
    /// since (an earlier frame of the same burst) and not yet taken would
    /// turn the bridge on during the stall (`NotDisabled`), and so would a
    /// calibration requested and not yet taken (`Busy`: a calibration is
    /// never interrupted by a stall either). Nor with the brake resistor
    /// conducting, which would stay on for the whole stall (`Busy`).
    pub fn quiet(&self) -> Result<(), ErrorCode> {
        if self.snap.pending.command != Command::Disable {
            return Err(ErrorCode::NotDisabled);
        }
        if self.snap.pending.calibration || self.out.config.calibration_pending() {
            return Err(ErrorCode::Busy);
        }
        if self.snap.feedback.power.brake_on {
            return Err(ErrorCode::Busy);
        }
        Ok(())
    }

    /// Decode, check and adopt a record: whole, or nothing changes.
    fn apply_record(&mut self, rec: &DriveRecord) -> Result<WatchdogConfig, ErrorCode> {
        let s = admit(self.service.board(), rec).map_err(|e| {
            crate::log_warn!("store: record refused: {}", e);
            ErrorCode::BadRecord
        })?;
        let t = admit_tables(self.service.board(), rec);
        let change = self.service.adopt(s, t, rec.label.clone());
        self.out.config.merge(&change);
        self.out.tables = true;
        Ok(link_setting(rec))
    }

    fn load_stored(&mut self) -> Result<DriveRecord, ErrorCode> {
        self.quiet()?;
        match self.store_mut()?.load() {
            Ok(Some(r)) => Ok(r),
            Ok(None) => Err(ErrorCode::NothingStored),
            Err(e) => Err(store_error(e)),
        }
    }

    fn save(&mut self, rec: &DriveRecord) -> Result<(), ErrorCode> {
        self.quiet()?;
        self.store_mut()?.save(rec).map_err(store_error)?;
        crate::log_info!("store: saved \"{=str}\"", rec.label.as_str());
        Ok(())
    }

    /// A staged record, decoded and admitted before anything is written
    /// or applied.
    fn staged(&self, staged: &[u8]) -> Result<DriveRecord, ErrorCode> {
        let rec = DriveRecord::decode(staged).map_err(|e| {
            crate::log_warn!("store: staged record refused: {}", e);
            ErrorCode::BadRecord
        })?;
        admit(self.service.board(), &rec).map_err(|e| {
            crate::log_warn!("store: staged record refused: {}", e);
            ErrorCode::BadRecord
        })?;
        Ok(rec)
    }

    /// Make `f` the d-current reference (design §30), whole, or refuse it
    /// with the drive's own rule on the angle calibration in force
    /// (`foc_store::settings::field_refusal`, which names why: logged).
    fn set_field(&mut self, f: FieldConfig) -> Result<(), Refusal> {
        let s = self.service.settings();
        if let Some(e) = foc_store::settings::field_refusal(&f, &s.angle) {
            crate::log_warn!("field: refused: {}", e);
            return Err(Refusal::Unsupported);
        }
        self.service.settings_mut().field = f;
        self.change(ConfigChange {
            field: Some(f),
            ..ConfigChange::default()
        });
        Ok(())
    }

    /// Switch a table (design §32, §33) on or off: not on without one
    /// (`NotCalibrated`: calibrate first), not with a command waiting in
    /// the mailbox (`NotDisabled`: the owner installs the tables with the
    /// bridge off).
    fn set_table_switch(&mut self, id: ParamId, on: bool) -> Result<(), Refusal> {
        if self.snap.pending.command != Command::Disable {
            return Err(Refusal::NotDisabled);
        }
        let t = self.service.tables_mut();
        let (held, enabled) = match id {
            ParamId::Anticogging => (t.has_cogging(), &mut t.cogging.enabled),
            ParamId::EncoderLinearisation => {
                (t.has_angle_correction(), &mut t.angle_correction.enabled)
            }
            _ => return Err(Refusal::Unsupported),
        };
        if on && !held {
            return Err(Refusal::NotCalibrated);
        }
        *enabled = on;
        self.out.tables = true;
        Ok(())
    }

    /// The travel range of `joint` in the rotor frame on `limits`.
    fn joint_change(joint: &JointSetup, limits: &Limits) -> foc_core::drive::JointChange {
        joint.rotor_change((limits.min_position_rad, limits.max_position_rad))
    }
}

impl<S: RecordStore> DeviceContext for Link<'_, S> {
    fn post(&mut self, cmd: Command) -> Result<(), CommandError> {
        self.out.post = Some(cmd);
        Ok(())
    }
    fn keep_alive(&mut self) {
        // Nothing to post: see `Outbox::apply_command`.
    }
    fn mode(&self) -> Mode {
        self.view().mode()
    }
    fn faults(&self) -> (FaultSet, Option<Fault>) {
        self.view().faults()
    }
    fn clear_faults(&mut self) {
        self.out.clear = true;
    }
    fn report_fault(&mut self, fault: Fault) {
        self.change(ConfigChange {
            fault: Some(fault),
            ..ConfigChange::default()
        });
    }
    fn limits(&self) -> Limits {
        self.view().limits()
    }
    fn set_limits(&mut self, limits: Limits) -> Result<(), Refusal> {
        if limits.max_current_a > self.service.board().max_current_a {
            return Err(Refusal::Unsupported);
        }
        // A sensorless start current above the new limit would leave the
        // configuration unsaveable (the record checks it).
        if self
            .service
            .settings()
            .sensorless
            .is_some_and(|sl| sl.start_current_a > limits.max_current_a)
        {
            return Err(Refusal::Unsupported);
        }
        // Nor an anticogging map larger than the new limit (the record
        // checks it against the limit, as the stage does).
        if self.service.tables().cogging.peak_a() > limits.max_current_a {
            crate::log_warn!("limits: refused: below the anticogging map's peak");
            return Err(Refusal::Unsupported);
        }
        let s = self.service.settings_mut();
        s.limits = limits;
        s.speed.current_limit_a = limits.max_current_a;
        let (speed, joint) = (s.speed, Self::joint_change(&s.joint, &limits));
        // The joint after the limits: the travel range stays in force.
        self.change(ConfigChange {
            limits: Some(limits),
            joint: Some(joint),
            ..ConfigChange::default()
        });
        self.out.config.speed = Some(speed);
        Ok(())
    }
    fn joint(&self) -> JointSetup {
        self.view().joint()
    }
    fn set_joint(&mut self, setup: JointSetup) -> Result<(), Refusal> {
        let change = Self::joint_change(&setup, &self.service.settings().limits);
        // The drive refuses a range that leaves the active position
        // target outside. It applies a change before it takes a new
        // command: the command in its mailbox (taken or about to be) is
        // the one it checks, not one this request posts.
        if let Command::Position { rad } = self.snap.pending.command {
            if !(change.min_position_rad..=change.max_position_rad).contains(&rad) {
                return Err(Refusal::NotDisabled);
            }
        }
        self.service.settings_mut().joint = setup;
        self.change(ConfigChange {
            joint: Some(change),
            ..ConfigChange::default()
        });
        Ok(())
    }
    fn torque_constant_nm_per_a(&self) -> f32 {
        self.view().torque_constant_nm_per_a()
    }
    fn feedback(&self) -> Feedback {
        self.view().feedback()
    }
    fn set_current_gains(&mut self, gains: CurrentGains) -> Result<(), Refusal> {
        // After an identification the settings hold the measured motor
        // model (decoupling, back-EMF feed-forward): only the gains
        // change. The stage keeps its calibration only with values a
        // permit vouches for; the current loop re-checks.
        let s = self.service.settings_mut();
        let mut cur = s.current;
        gains.apply(&mut cur);
        if Calibrated::supplied(s.angle, cur).is_err() {
            return Err(Refusal::Unsupported);
        }
        s.current = cur;
        self.change(ConfigChange {
            current: Some(cur),
            ..ConfigChange::default()
        });
        Ok(())
    }
    fn set_speed_gains(&mut self, gains: SpeedGains) -> Result<(), Refusal> {
        let s = self.service.settings_mut();
        gains.apply(&mut s.speed);
        self.out.config.speed = Some(s.speed);
        Ok(())
    }
    fn set_position_gains(&mut self, gains: PositionGains) -> Result<(), Refusal> {
        let s = self.service.settings_mut();
        // A move may not be faster than a velocity command is allowed to be.
        if gains.max_velocity_rad_s > s.limits.max_velocity_rad_s {
            return Err(Refusal::Unsupported);
        }
        gains.apply(&mut s.position);
        self.out.config.position = Some(s.position);
        Ok(())
    }
    fn set_dividers(&mut self, speed: u16, position: u16) -> Result<(), Refusal> {
        let pwm = self.service.board().pwm_hz as f32;
        let s = self.service.settings_mut();
        s.dividers = (speed, position);
        // The slower loops' discrete-time gains follow their new periods.
        s.speed.ts_s = f32::from(speed) / pwm;
        s.position.ts_s = f32::from(position) / pwm;
        let (sp, po) = (s.speed, s.position);
        self.change(ConfigChange {
            dividers: Some((speed, position)),
            ..ConfigChange::default()
        });
        self.out.config.speed = Some(sp);
        self.out.config.position = Some(po);
        Ok(())
    }
    fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), Refusal> {
        let on = value == 1.0;
        if matches!(id, ParamId::Anticogging | ParamId::EncoderLinearisation) {
            return self.set_table_switch(id, on);
        }
        // One setting of the reference in force; the whole is judged.
        let mut f = self.service.settings().field;
        match id {
            ParamId::FieldWeakening => f.field_weakening = on,
            ParamId::Mtpa => f.mtpa = on,
            ParamId::MaxIdA => f.max_id_a = value,
            ParamId::ShortCircuit => f.short_circuit = on,
            _ => return Err(Refusal::Unsupported),
        }
        self.set_field(f)
    }
    fn start_calibration(&mut self, routine: Calibration) -> Result<(), Refusal> {
        let change = match routine {
            Calibration::Offsets => ConfigChange {
                calibrate_offsets: true,
                ..ConfigChange::default()
            },
            Calibration::Identification if self.service.board().identifies => ConfigChange {
                identify: true,
                ..ConfigChange::default()
            },
            // Alignment alone is part of the identification sequence.
            Calibration::Identification | Calibration::Alignment => {
                return Err(Refusal::Unsupported)
            }
            // The sweeps: the drive's own rule, on the angle calibration
            // in force, for the immediate answer (the drive judges the
            // request again when it takes it).
            Calibration::Anticogging | Calibration::EncoderLinearisation => {
                // A command waiting in the mailbox would be overtaken by
                // the sweep (which takes the stage at the same boundary).
                if self.snap.pending.command != Command::Disable {
                    return Err(Refusal::NotDisabled);
                }
                let angle = self.service.settings().angle;
                let sweep = routine.sweep().ok_or(Refusal::Unsupported)?;
                self.view().status().check_sweep(sweep, &angle)?;
                ConfigChange {
                    calibrate_cogging: routine == Calibration::Anticogging,
                    calibrate_encoder: routine == Calibration::EncoderLinearisation,
                    ..ConfigChange::default()
                }
            }
        };
        self.change(change);
        Ok(())
    }
    fn is_calibrated(&self) -> bool {
        self.view().is_calibrated()
    }
    fn status(&self) -> Status {
        self.view().status()
    }
    fn param(&self, id: ParamId) -> Option<f32> {
        self.view().param(id)
    }
    fn telemetry(&self) -> Telemetry {
        self.view().telemetry()
    }
    fn firmware_version(&self) -> [u8; 3] {
        self.view().firmware_version()
    }
    fn max_stream_hz(&self) -> Option<f32> {
        self.view().max_stream_hz()
    }
    fn scope(&mut self) -> Option<&mut dyn ScopePort> {
        match self.scope.as_mut() {
            Some(s) => Some(&mut **s),
            None => None,
        }
    }
    fn config_record(
        &mut self,
        source: ConfigSource,
        link: WatchdogConfig,
        out: &mut [u8; MAX_RECORD],
    ) -> Result<usize, ErrorCode> {
        let rec = match source {
            ConfigSource::Live => self.service.live_record(link),
            ConfigSource::Stored => self.load_stored()?,
        };
        rec.encode(out).map_err(|e| {
            crate::log_warn!("store: record does not encode: {}", e);
            ErrorCode::BadRecord
        })
    }
    fn store(
        &mut self,
        op: StoreOp,
        staged: &[u8],
        link: WatchdogConfig,
    ) -> Result<Option<WatchdogConfig>, ErrorCode> {
        // Applying is refused too while something is pending: the drive
        // would refuse the current loop's part and the slower loops would
        // still take theirs.
        self.quiet()?;
        match op {
            StoreOp::Save => {
                let rec = self.service.live_record(link);
                self.save(&rec).map(|()| None)
            }
            StoreOp::Erase => {
                self.store_mut()?.erase().map_err(store_error)?;
                crate::log_info!(
                    "store: erased (the next boot starts from the build-time settings)"
                );
                Ok(None)
            }
            StoreOp::Load => {
                let rec = self.load_stored()?;
                self.apply_record(&rec).map(Some)
            }
            StoreOp::Apply | StoreOp::ApplyAndSave => {
                let rec = self.staged(staged)?;
                if op == StoreOp::ApplyAndSave {
                    self.save(&rec)?;
                }
                self.apply_record(&rec).map(Some)
            }
        }
    }
}
