//! The drive's life from reset on, one PWM period at a time, without
//! hardware: [`Lifecycle::step`] takes this period's [`Sample`] and
//! [`Inputs`], writes the feedback in place and returns what the bridge must do and what
//! the caller must do to the sensors (install offsets) or the slower loops
//! (run them). [`super::Drive`] wraps it with the hardware traits; the
//! bench's `Cascade` and the SIL process call it directly.
//!
//! ```text
//!  reset --> OffsetCalibration --ok--> SensorCheck --ok--> Run <------------+
//!               | failed / no read       | no read          | identify     |
//!               +--(fault latched)-------+-----------> Run  +--> Identify --+
//!                                                              (done, failed,
//!                                                     fault, operator Disable)
//! ```
//!
//! Rules kept here, once: the bridge is off (safe state) outside `Identify`
//! and `Run`; a fault latched by anyone makes the current stage return the
//! safe state in the same period; closed-loop modes need offsets and a
//! calibration permit; an identification starts only disabled and
//! unfaulted, revokes the old permit, is aborted by an operator `Disable`
//! and never resumes the operator's earlier command when it ends; a
//! configuration change is applied whole at the start of a period, or
//! refused whole (see [`super::rules`]).

use super::cogging::{CoggingOutcome, CoggingRun};
use super::encoder::{EncoderOutcome, EncoderRun};
use super::identify::{Identifier, Outcome};
use super::rules::{ConfigChange, Refusal, Status};
use super::{AngleKind, Progress};
use crate::angle::MechanicalAngle;
use crate::calibration::identification::{IdentificationConfig, IdentificationResult, Step};
use crate::calibration::index::{IndexSearch, IndexSearchConfig};
use crate::calibration::offsets::{OffsetCalibrator, OffsetError, OffsetLimits, OffsetStep};
use crate::calibration::{CalError, CalInput, CalStep};
use crate::control::permit::Calibrated;
use crate::control::stage::{CurrentStage, Sample};
use crate::control::{BridgeCommand, Command, CommandSlot, Fault, Feedback, Mechanics};
use crate::frames::Abc;

/// Where the drive is in its life.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LifePhase {
    /// Averaging the current-sensor offsets with the bridge off.
    OffsetCalibration,
    /// Checking that the angle sensor answers (consecutive good reads).
    SensorCheck(u32),
    /// Motor identification (R, L, gains, alignment, flux linkage), and
    /// the anticogging and encoder calibrations.
    Identify,
    /// Turning slowly until the encoder's index pulses (design §33).
    IndexSearch,
    /// Control running (the current stage decides; disabled until told).
    Run,
}

/// What the drive does from reset on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LifecycleConfig {
    /// Current-offset calibration (bridge off); `None`: the measurements
    /// need none (start-up begins with the sensor check, a re-run request
    /// is refused as unsupported).
    pub offsets: Option<OffsetLimits>,
    /// Consecutive good angle readings the start-up sensor check needs.
    pub sensor_check_reads: u32,
    /// Identification settings; `None`: identification unsupported.
    pub identification: Option<IdentificationConfig>,
    /// Identify the motor right after the sensor check.
    pub identify_at_start_up: bool,
    /// Speed loop every N periods (0 is taken as 1).
    pub speed_divider: u16,
    /// Position loop every M periods (0 is taken as 1).
    pub position_divider: u16,
    /// What the angle sensor knows at power-up.
    pub angle_kind: AngleKind,
    /// A calibration permit from the drive's store (design §17). Installed
    /// at the end of start-up, in place of a start-up identification, when
    /// [`AngleKind::zero_survives_reset`]; otherwise unused (an incremental
    /// encoder's zero is wherever the rotor was at reset).
    pub stored: Option<Calibrated>,
}

/// What the owner hands the drive each period (small: a configuration
/// change is lent, not copied).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Inputs<'a> {
    /// The operator's command mailbox.
    pub command: CommandSlot,
    /// q-current reference from the speed stage \[A\].
    pub iq_ref_a: f32,
    /// A configuration change to apply at this period's start.
    pub change: Option<&'a ConfigChange>,
    /// The power stage reported a fault (timer break, gate driver).
    pub gate_fault: bool,
    /// The angle sensor's reading latched at its index pulse this period
    /// (`AngleSensor::take_index`; design §33).
    pub index: Option<MechanicalAngle>,
}

impl Inputs<'_> {
    /// A mailbox and a q-current reference, nothing else.
    pub const fn new(command: CommandSlot, iq_ref_a: f32) -> Self {
        Self {
            command,
            iq_ref_a,
            change: None,
            gate_fault: false,
            index: None,
        }
    }
}

/// Something that happened this period (for the log and the tests).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// Offsets measured and installed \[A\].
    OffsetsDone(Abc),
    /// The offset calibration rejected the readings (fault latched).
    OffsetsFailed(OffsetError),
    /// The current sensor did not answer during the offset calibration.
    CurrentSenseFailed,
    /// The angle sensor did not answer during the sensor check.
    SensorCheckFailed,
    /// Start-up finished: disabled, waiting for a command.
    StartUpDone,
    /// An identification started (start-up or request).
    IdentificationStarted,
    /// The identification finished; its permit is installed.
    Identified(IdentificationResult),
    /// Start-up finished with the stored calibration's permit installed
    /// (no identification, no motion): disabled, waiting for a command.
    CalibrationRestored,
    /// A routine failed (fault `CalibrationFailed` latched).
    IdentificationFailed(CalError, Step),
    /// Stopped by a fault, or by an operator `Disable` (`None`).
    IdentificationAborted(Option<Fault>, Step),
    /// The encoder's index was found (design §33); its reading is the
    /// zero of every reading from now on.
    IndexFound {
        /// How far the rotor turned to find it \[rad\] (mechanical, signed).
        travel_rad: f32,
    },
    /// The anticogging map is measured and installed (design §32).
    CoggingMeasured {
        /// Its largest feed-forward \[A\].
        peak_a: f32,
        /// Periods the calibration took.
        periods: u32,
    },
    /// The angle sensor's correction is learnt and installed (design §33).
    EncoderLinearised {
        /// Its largest correction \[rad\] (mechanical).
        peak_rad: f32,
        /// Periods the calibration took.
        periods: u32,
    },
}

/// The drive's decision for one period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Output {
    /// What the bridge must do.
    pub bridge: BridgeCommand,
    /// Install these current-sense offsets \[A\] now.
    pub offsets_a: Option<Abc>,
    /// Run the speed stage after this period.
    pub run_speed: bool,
    /// Run the position stage after this period.
    pub run_position: bool,
    /// What happened, if anything.
    pub event: Option<Event>,
    /// The verdict on [`Inputs::change`], when one was given.
    pub change: Option<Result<(), Refusal>>,
    /// The operator's fault clear was performed this period (before any
    /// fault found this period was latched): hardware fault latches may be
    /// released (`PwmDriver::release_fault_latch`).
    pub faults_cleared: bool,
}

/// The drive's life (see the module docs). Hardware-free: the caller owns
/// the [`CurrentStage`] and passes it to every step.
///
/// `repr(C)`: the fields every period reads first, the calibrations'
/// state (kilobytes: the anticogging run's accumulators, the encoder fit's
/// normal equations) last. Left to the compiler, the encoder fit's `f64`
/// alignment put it first and pushed every hot field kilobytes away: +150
/// to +190 instructions a period (`cargo xtask bench`).
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub struct Lifecycle {
    phase: LifePhase,
    /// Periods stepped so far.
    tick: u32,
    /// When the speed and the position stages run.
    speed: Countdown,
    position: Countdown,
    /// The current sensor's offsets are calibrated.
    offsets_ok: bool,
    /// The first offset sample after a restart was read with the old
    /// offsets: skip it.
    skip_offset_sample: bool,
    /// The index's reading, once found: taken off every reading.
    index_offset: Option<MechanicalAngle>,
    /// The operator's command number when the identification started.
    identify_seq: u32,
    /// How the last calibration ended (the status reports a running one
    /// from the phase).
    report: Progress,
    config: LifecycleConfig,
    offsets: Option<OffsetCalibrator>,
    /// The index search's settings (design §33; `None`: no index).
    index_search: Option<IndexSearchConfig>,
    identified: Option<IdentificationResult>,
    /// The index search, while it runs, and its private mailbox.
    index_run: Option<(IndexSearch, CommandSlot)>,
    /// The index reading the drive took from its sensor this period
    /// ([`Self::note_index`]).
    pending_index: Option<MechanicalAngle>,
    identifier: Option<Identifier>,
    /// The encoder linearisation, while it runs (design §33).
    encoder: Option<EncoderRun>,
    /// The anticogging calibration, while it runs (design §32).
    cogging: Option<CoggingRun>,
}

/// When a slower loop runs: every `divider` periods, counted down (no
/// division in the period): the periods where `tick % divider == 0`, with
/// `tick` the periods stepped so far.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Countdown {
    divider: u32,
    /// Periods to the next run, `divider - tick % divider`.
    left: u32,
}

impl Countdown {
    /// At `tick` 0: the next run after `divider` periods.
    const fn new(divider: u32) -> Self {
        Self {
            divider,
            left: divider,
        }
    }

    /// A new divider (at least 1) after `tick` periods: the next run at the
    /// next multiple of it.
    fn set(&mut self, divider: u32, tick: u32) {
        self.divider = divider;
        self.left = divider - tick % divider;
    }

    /// One period; true when the loop runs after it.
    #[inline]
    fn step(&mut self) -> bool {
        self.left -= 1;
        if self.left == 0 {
            self.left = self.divider;
            true
        } else {
            false
        }
    }
}

fn divider(n: u16) -> u32 {
    u32::from(n.max(1))
}

impl Lifecycle {
    /// From reset: offset calibration first (the caller zeroes the current
    /// sensor's offsets before the first sample), or the sensor check when
    /// no offset calibration is configured.
    pub fn new(config: LifecycleConfig) -> Self {
        let offsets = config.offsets.map(OffsetCalibrator::new);
        Self {
            config,
            phase: match offsets {
                Some(_) => LifePhase::OffsetCalibration,
                None => LifePhase::SensorCheck(0),
            },
            offsets,
            offsets_ok: offsets.is_none(),
            skip_offset_sample: false,
            identifier: None,
            cogging: None,
            encoder: None,
            index_search: None,
            index_run: None,
            pending_index: None,
            index_offset: None,
            identify_seq: 0,
            identified: None,
            report: Progress::Idle,
            speed: Countdown::new(divider(config.speed_divider)),
            position: Countdown::new(divider(config.position_divider)),
            tick: 0,
        }
    }

    /// Already started: phase `Run` with the caller vouching for the
    /// current sensor's offsets (simulations, tests, a process that was
    /// handed calibrated measurements).
    pub fn started(config: LifecycleConfig) -> Self {
        Self {
            phase: LifePhase::Run,
            offsets_ok: true,
            ..Self::new(config)
        }
    }

    /// The configuration.
    pub fn config(&self) -> &LifecycleConfig {
        &self.config
    }

    /// The phase.
    pub fn phase(&self) -> LifePhase {
        self.phase
    }

    /// The speed and position dividers in force \[periods\].
    pub fn dividers(&self) -> (u32, u32) {
        (self.speed.divider, self.position.divider)
    }

    /// The last successful identification, if any.
    pub fn identified(&self) -> Option<IdentificationResult> {
        self.identified
    }

    /// The stage of the identification running or last run.
    pub fn identification_step(&self) -> Option<Step> {
        if self.cogging.is_some() {
            return Some(Step::Cogging);
        }
        if self.encoder.is_some() {
            return Some(Step::Encoder);
        }
        if self.index_run.is_some() {
            return Some(Step::IndexSearch);
        }
        self.identifier.map(|i| i.current_step())
    }

    /// The status the rules look at.
    pub fn status(&self, stage: &CurrentStage) -> Status {
        let running = self.phase == LifePhase::Run;
        Status {
            running,
            mode: stage.active().mode(),
            faulted: stage.supervisor().is_faulted(),
            calibrated: running && self.offsets_ok && stage.is_calibrated(),
            sensorless: stage.sensorless().is_some(),
            injection: stage
                .sensorless()
                .is_some_and(|s| s.holds_torque_at_standstill()),
            calibration: self.progress(),
        }
    }

    /// The calibration running (from the phase), or how the last one
    /// ended.
    pub fn progress(&self) -> Progress {
        match self.phase {
            LifePhase::OffsetCalibration => Progress::Offsets,
            LifePhase::Identify => {
                Progress::Running(self.identification_step().unwrap_or(Step::Resistance))
            }
            LifePhase::SensorCheck(_) => Progress::SensorCheck,
            LifePhase::IndexSearch => Progress::Running(Step::IndexSearch),
            LifePhase::Run => self.report,
        }
    }

    /// One PWM period. `stage` is the drive's current stage (the same one
    /// every period); `fb` is the feedback published, written in place when
    /// the stage runs (left as it was during start-up).
    #[inline]
    pub fn step(
        &mut self,
        stage: &mut CurrentStage,
        inp: &Inputs,
        s: &Sample,
        fb: &mut Feedback,
    ) -> Output {
        let mut out = Output {
            bridge: BridgeCommand::SafeState,
            offsets_a: None,
            run_speed: false,
            run_position: false,
            event: None,
            change: None,
            faults_cleared: false,
        };
        self.step_out(stage, inp, s, fb, &mut out);
        out
    }

    /// [`Self::step`] writing into the caller's `out` (initialised by
    /// it): the output is built where the caller keeps it, not copied on
    /// return (design §20). Never inlined: whether the optimiser inlined
    /// it into the caller changed with unrelated edits and moved every
    /// period's instruction count by about 20.
    #[inline(never)]
    fn step_out(
        &mut self,
        stage: &mut CurrentStage,
        inp: &Inputs,
        s: &Sample,
        fb: &mut Feedback,
        out: &mut Output,
    ) {
        // The operator's clear first: a fault found this period (power
        // stage, link watchdog) is latched after it and stays latched.
        if self.phase == LifePhase::Run {
            out.faults_cleared = stage.take_clear(&inp.command);
        }
        if inp.gate_fault {
            stage.report_fault(Fault::GateDriverFault);
        }
        if let Some(ch) = inp.change {
            out.change = Some(self.apply_change(stage, ch, inp, out));
        }
        // The speed stage's output is interpolated over its period.
        stage.set_speed_periods(self.speed.divider);
        // The brake chopper every period: the phases without a stage step
        // (bridge off) step it alone (a coasting motor still charges the
        // bus through the body diodes).
        if matches!(
            self.phase,
            LifePhase::OffsetCalibration | LifePhase::SensorCheck(_)
        ) {
            stage.step_brake(s.v_bus_v);
        }
        match self.phase {
            LifePhase::OffsetCalibration => self.step_offsets(stage, s, out),
            LifePhase::SensorCheck(n) => self.step_sensor_check(stage, inp, s, n, out),
            LifePhase::Identify => self.step_identify(stage, inp, s, out, fb),
            LifePhase::IndexSearch => self.step_index_search(stage, inp, s, out, fb),
            LifePhase::Run => {
                out.bridge = stage.step_into(&inp.command, inp.iq_ref_a, s, fb);
            }
        }
        self.tick = self.tick.wrapping_add(1);
        out.run_speed = self.speed.step();
        out.run_position = self.position.step();
    }

    /// A configuration change: its settings whole or not at all, its
    /// calibration request on its own; the verdict is the first refusal.
    fn apply_change(
        &mut self,
        stage: &mut CurrentStage,
        ch: &ConfigChange,
        inp: &Inputs,
        out: &mut Output,
    ) -> Result<(), Refusal> {
        // Judged on the status before anything in the change is applied.
        let settings = self.check_settings(stage, ch);
        let calibration = self.check_calibration_request(stage, ch);
        if let Some(f) = ch.fault {
            stage.report_fault(f);
        }
        if settings.is_ok() {
            self.apply_settings(stage, ch);
        }
        let joint = match ch.joint {
            Some(j) if self.phase == LifePhase::Run => stage.set_joint(&j),
            Some(_) => Err(Refusal::Busy),
            None => Ok(()),
        };
        if calibration.is_ok() {
            if ch.calibrate_offsets {
                self.restart_offsets(out);
            }
            if ch.identify {
                self.start_identification(stage, &inp.command, out);
            }
            if ch.calibrate_cogging {
                self.start_cogging(stage, &inp.command, out);
            } else if ch.calibrate_encoder {
                self.start_encoder(stage, &inp.command, out);
            }
        }
        settings.and(calibration).and(joint)
    }

    fn check_settings(&self, stage: &CurrentStage, ch: &ConfigChange) -> Result<(), Refusal> {
        if !ch.has_settings() {
            return Ok(());
        }
        self.status(stage).check_config()?;
        if ch.limits.is_some_and(|l| l.validate().is_err()) {
            return Err(Refusal::Unsupported);
        }
        // The d-current reference: on the angle calibration in force after
        // the change (the stage would refuse it when it is applied, after
        // the rest of the settings).
        if ch.field_refusal(&stage.config().angle).is_some() {
            return Err(Refusal::Unsupported);
        }
        Ok(())
    }

    fn check_calibration_request(
        &self,
        stage: &CurrentStage,
        ch: &ConfigChange,
    ) -> Result<(), Refusal> {
        if !ch.identify && !ch.calibrate_offsets && !ch.calibrate_cogging && !ch.calibrate_encoder {
            return Ok(());
        }
        let status = self.status(stage);
        status.check_calibration()?;
        if ch.calibrate_encoder {
            // Turns in velocity and torque mode on the angle sensor.
            if ch.identify || ch.calibrate_offsets || ch.calibrate_cogging {
                return Err(Refusal::Busy);
            }
            if !status.calibrated {
                return Err(Refusal::NotCalibrated);
            }
            // Sensorless, the sensor is not read (nothing to linearise);
            // a coarse one (halls) is interpolated, not read, between its
            // edges.
            let coarse = stage.config().angle.interpolation_half_count().is_some();
            if stage.sensorless().is_some() || coarse {
                return Err(Refusal::Unsupported);
            }
            return Ok(());
        }
        if ch.calibrate_cogging {
            // A sweep at low speed in velocity mode: calibrated, and the
            // angle known at standstill; one calibration at a time.
            if ch.identify || ch.calibrate_offsets {
                return Err(Refusal::Busy);
            }
            if !status.calibrated {
                return Err(Refusal::NotCalibrated);
            }
            // Without the angle at low speed (sensorless without
            // injection), or with a coarse one (halls: the interpolated
            // angle is off by up to half a count, 30 deg(e), as wide as a
            // cogging cycle), the map cannot be measured.
            let coarse = stage.config().angle.interpolation_half_count().is_some()
                && stage.sensorless().is_none();
            if status.angle_only_in_motion() || coarse {
                return Err(Refusal::Unsupported);
            }
            return Ok(());
        }
        if (ch.identify && self.config.identification.is_none())
            || (ch.calibrate_offsets && self.config.offsets.is_none())
        {
            return Err(Refusal::Unsupported);
        }
        if ch.identify && ch.calibrate_offsets {
            // One calibration at a time: ask again when this one is done.
            return Err(Refusal::Busy);
        }
        Ok(())
    }

    fn apply_settings(&mut self, stage: &mut CurrentStage, ch: &ConfigChange) {
        if let Some(l) = ch.limits {
            stage.set_limits(l);
        }
        if let Some(cur) = ch.current {
            // Keep the closed-loop permit: the same angle calibration with
            // the new gains, if they pass the permit's check.
            match Calibrated::supplied(stage.config().angle, cur) {
                Ok(p) if stage.holds_permit() => stage.set_calibration(&p),
                _ => stage.set_current_config(cur),
            }
        }
        if let Some((n, m)) = ch.dividers {
            self.speed.set(divider(n), self.tick);
            self.position.set(divider(m), self.tick);
        }
        if let Some(p) = ch.permit {
            stage.set_calibration(&p);
        }
        // After the current loop's motor: the power model follows it.
        if let Some(p) = ch.power {
            stage.set_power_limits(p);
        }
        if let Some(m) = ch.mechanics {
            stage.set_mechanics(&m);
        }
        if let Some(s) = ch.sensorless {
            stage.set_sensorless(s);
        }
        if let Some(b) = ch.beside {
            stage.set_beside(b);
        }
        // After the limits, the current loop and the permit (its angle
        // calibration); `check_settings` judged it with the same rule, so
        // the stage takes it.
        if let Some(f) = ch.field {
            let _taken = stage.set_field(f);
        }
    }

    fn restart_offsets(&mut self, out: &mut Output) {
        let Some(limits) = self.config.offsets else {
            return;
        };
        self.offsets = Some(OffsetCalibrator::new(limits));
        self.offsets_ok = false;
        self.skip_offset_sample = true;
        self.phase = LifePhase::OffsetCalibration;
        out.offsets_a = Some(Abc::default());
    }

    fn start_identification(
        &mut self,
        stage: &mut CurrentStage,
        operator: &CommandSlot,
        out: &mut Output,
    ) {
        let Some(cfg) = self.config.identification else {
            return;
        };
        // A new identification never runs on the old calibration; on a
        // drive that runs sensorless it does without the angle sensor.
        stage.revoke_calibration();
        let mut cfg = IdentificationConfig {
            angle_sensor: stage.sensorless().is_none(),
            ..cfg
        };
        // The turning field's voltage clips at the stage's modulation.
        let m = stage.config().current.max_modulation;
        if m < cfg.field_flux.max_modulation {
            cfg.field_flux.max_modulation = m;
        }
        self.identifier = Some(Identifier::new(cfg, operator));
        self.identify_seq = operator.seq;
        self.phase = LifePhase::Identify;
        out.event = Some(Event::IdentificationStarted);
    }

    #[inline(never)]
    #[cold]
    fn start_cogging(
        &mut self,
        stage: &mut CurrentStage,
        operator: &CommandSlot,
        out: &mut Output,
    ) {
        // In place: the run is kilobytes (see `CoggingRun::start_in`).
        CoggingRun::start_in(&mut self.cogging, stage, operator);
        self.identifier = None;
        self.identify_seq = operator.seq;
        self.phase = LifePhase::Identify;
        out.event = Some(Event::IdentificationStarted);
    }

    /// Search the encoder's index at every start-up, after the sensor
    /// check and before a stored calibration is taken (design §33); `None`:
    /// no index. A stored electrical zero of an incremental encoder then
    /// applies (it is referred to the index).
    pub fn set_index_search(&mut self, c: Option<IndexSearchConfig>) {
        self.index_search = c;
    }

    /// The reading the angle sensor latched at its index this period, for
    /// the index search (what [`Inputs::index`] gives, from the drive's
    /// own sensor).
    pub fn note_index(&mut self, index: Option<MechanicalAngle>) {
        self.pending_index = index;
    }

    /// The index's reading, once found (the zero of every reading since).
    pub fn index_offset(&self) -> Option<MechanicalAngle> {
        self.index_offset
    }

    #[inline(never)]
    #[cold]
    fn start_index_search(&mut self, c: IndexSearchConfig, operator: &CommandSlot) {
        let mut slot = *operator;
        slot.seq = operator.seq.wrapping_add(0x4000_0000);
        slot.command = Command::Disable;
        self.index_run = Some((IndexSearch::new(c), slot));
        self.phase = LifePhase::IndexSearch;
    }

    /// The index search's period: the field through the stage's open loop
    /// (a private mailbox); once the index pulses, its reading becomes the
    /// readings' zero and start-up goes on (next period) where the sensor
    /// check left it, with the stored calibration now valid.
    #[inline(never)]
    #[cold]
    fn step_index_search(
        &mut self,
        stage: &mut CurrentStage,
        inp: &Inputs,
        s: &Sample,
        out: &mut Output,
        fb: &mut Feedback,
    ) {
        let Some((search, slot)) = self.index_run.as_mut() else {
            return;
        };
        let step = match (s.currents, s.angle, s.v_bus_v) {
            (Some(c), Some(a), Some(v)) => {
                let index = inp.index.or(self.pending_index.take());
                Some(search.step(&CalInput::open_loop(c.to_abc(), a, v), index))
            }
            // A failed read: the stage trips on it below.
            _ => None,
        };
        let ended = match step {
            Some(CalStep::Apply { v_dq, theta_e }) => {
                slot.post(Command::OpenLoop {
                    v_d_v: v_dq.d,
                    v_q_v: v_dq.q,
                    theta_e,
                    omega_e_rad_s: 0.0,
                });
                None
            }
            Some(CalStep::Done(zero)) => Some(Ok((zero, search.travel_rad()))),
            Some(CalStep::Failed(e)) => Some(Err(e)),
            _ => None,
        };
        if ended.is_some() {
            slot.post(Command::Disable);
        }
        let (b, f) = stage.step(slot, inp.iq_ref_a, s);
        out.bridge = b;
        *fb = f;
        match ended {
            None => {
                if let Some(fault) = f.first_fault {
                    self.index_run = None;
                    self.report = Progress::Aborted(Some(fault), Step::IndexSearch);
                    out.event = Some(Event::IdentificationAborted(Some(fault), Step::IndexSearch));
                    self.enter_run(stage);
                    stage.report_fault(fault);
                }
            }
            Some(Ok((zero, travel_rad))) => {
                self.index_run = None;
                self.index_offset = Some(zero);
                // Every reading from now on referred to the index: the
                // stage's, the routines' (through `CurrentStage::reading`).
                stage.set_reading_zero(zero);
                out.event = Some(Event::IndexFound { travel_rad });
                // Start-up goes on from the end of the sensor check.
                self.phase = LifePhase::SensorCheck(self.config.sensor_check_reads);
            }
            Some(Err(e)) => {
                self.index_run = None;
                // Into `Run` first: entering it resets the stage.
                self.enter_run(stage);
                stage.report_fault(Fault::CalibrationFailed);
                self.report = Progress::Failed(e, Step::IndexSearch);
                out.event = Some(Event::IdentificationFailed(e, Step::IndexSearch));
            }
        }
    }

    #[inline(never)]
    #[cold]
    fn start_encoder(
        &mut self,
        stage: &mut CurrentStage,
        operator: &CommandSlot,
        out: &mut Output,
    ) {
        self.encoder = Some(EncoderRun::for_stage(stage, operator));
        self.identifier = None;
        self.identify_seq = operator.seq;
        self.phase = LifePhase::Identify;
        out.event = Some(Event::IdentificationStarted);
    }

    fn step_offsets(&mut self, stage: &mut CurrentStage, s: &Sample, out: &mut Output) {
        if core::mem::take(&mut self.skip_offset_sample) {
            return;
        }
        let Some(reading) = s.currents.map(|c| c.to_abc()) else {
            stage.report_fault(Fault::CurrentSenseError);
            self.enter_run(stage);
            self.report = Progress::OffsetsFailed;
            out.event = Some(Event::CurrentSenseFailed);
            return;
        };
        let Some(cal) = self.offsets.as_mut() else {
            self.phase = LifePhase::SensorCheck(0);
            return;
        };
        match cal.step(reading) {
            OffsetStep::InProgress => {}
            OffsetStep::Done(o) => {
                out.offsets_a = Some(o);
                self.offsets_ok = true;
                self.phase = LifePhase::SensorCheck(0);
                out.event = Some(Event::OffsetsDone(o));
            }
            OffsetStep::Failed(e) => {
                stage.report_fault(Fault::CalibrationFailed);
                self.enter_run(stage);
                self.report = Progress::OffsetsFailed;
                out.event = Some(Event::OffsetsFailed(e));
            }
        }
    }

    fn step_sensor_check(
        &mut self,
        stage: &mut CurrentStage,
        inp: &Inputs,
        s: &Sample,
        n: u32,
        out: &mut Output,
    ) {
        // (A drive that runs sensorless does not read its angle sensor.)
        if s.angle.is_none() && stage.sensorless().is_none() {
            stage.report_fault(Fault::AngleSensorError);
            self.enter_run(stage);
            self.report = Progress::SensorCheckFailed;
            out.event = Some(Event::SensorCheckFailed);
        } else if n.saturating_add(1) < self.config.sensor_check_reads {
            self.phase = LifePhase::SensorCheck(n + 1);
        } else if let (Some(c), None) = (self.index_search, self.index_offset) {
            self.start_index_search(c, &inp.command);
        } else if let Some(p) = self.stored_permit() {
            stage.set_calibration(&p);
            self.enter_run(stage);
            self.report = Progress::Done;
            out.event = Some(Event::CalibrationRestored);
        } else if self.config.identify_at_start_up && self.config.identification.is_some() {
            self.start_identification(stage, &inp.command, out);
        } else {
            self.enter_run(stage);
            self.report = Progress::Done;
            out.event = Some(Event::StartUpDone);
        }
    }

    /// The stored permit, where the sensor's angle at boot makes it valid;
    /// one made without a sensor always (it has no zero to lose; it
    /// unlocks the closed loop only while the drive runs sensorless).
    fn stored_permit(&self) -> Option<Calibrated> {
        self.config.stored.filter(|p| {
            self.config.angle_kind.zero_survives_reset()
                || self.index_offset.is_some()
                || p.angle().sensorless_only
        })
    }

    /// From the start-up phases (bridge off, stage not stepped) to `Run`:
    /// the stage restarts its loops and angle tracker from the next sample
    /// (the rotor may have moved meanwhile).
    fn enter_run(&mut self, stage: &mut CurrentStage) {
        stage.reset();
        self.phase = LifePhase::Run;
    }

    /// Inlined into [`Self::step`] with the identification routines (about
    /// 21 KiB, which `cargo xtask size` therefore counts as control): kept
    /// out of line it made every period 57 instructions longer, in `Run`
    /// too (`cargo xtask bench`).
    fn step_identify(
        &mut self,
        stage: &mut CurrentStage,
        inp: &Inputs,
        s: &Sample,
        out: &mut Output,
        fb_out: &mut Feedback,
    ) {
        if self.cogging.is_some() {
            return self.step_cogging(stage, inp, s, out, fb_out);
        }
        if self.encoder.is_some() {
            return self.step_encoder(stage, inp, s, out, fb_out);
        }
        let Some(id) = self.identifier.as_mut() else {
            self.phase = LifePhase::Run;
            return;
        };
        // An operator `Disable` posted after the start aborts.
        let cmd = &inp.command;
        let abort = cmd.seq != self.identify_seq && cmd.command == Command::Disable;
        let (outcome, b, fb) = if abort {
            id.abort(stage, inp.iq_ref_a, s)
        } else {
            id.step(stage, inp.iq_ref_a, s)
        };
        out.bridge = b;
        *fb_out = fb;
        out.event = match outcome {
            Outcome::Running => return,
            Outcome::Done(r) => {
                self.report = Progress::Done;
                self.identified = Some(r);
                // The measured inertia feeds the speed observer's torque
                // model from now on (design §19).
                if let Some(m) = r.mechanics {
                    stage.set_mechanics(&Mechanics::from(m));
                }
                Some(Event::Identified(r))
            }
            Outcome::Failed(e, st) => {
                self.report = Progress::Failed(e, st);
                Some(Event::IdentificationFailed(e, st))
            }
            Outcome::Aborted(f, st) => {
                self.report = Progress::Aborted(f, st);
                Some(Event::IdentificationAborted(f, st))
            }
        };
        // Back to the operator's mailbox, with its last command taken as
        // seen: nothing sent before or during the identification starts
        // the motor now.
        stage.sync_mailbox(cmd);
        self.phase = LifePhase::Run;
    }

    /// The encoder linearisation's period (design §33).
    #[inline(never)]
    #[cold]
    fn step_encoder(
        &mut self,
        stage: &mut CurrentStage,
        inp: &Inputs,
        s: &Sample,
        out: &mut Output,
        fb_out: &mut Feedback,
    ) {
        let Some(run) = self.encoder.as_mut() else {
            return;
        };
        let cmd = &inp.command;
        let abort = cmd.seq != self.identify_seq && cmd.command == Command::Disable;
        let (outcome, b, fb) = if abort {
            run.abort(stage, inp.iq_ref_a, s)
        } else {
            run.step(stage, inp.iq_ref_a, s)
        };
        out.bridge = b;
        *fb_out = fb;
        out.event = match outcome {
            EncoderOutcome::Running => return,
            EncoderOutcome::Done { peak_rad, periods } => {
                self.report = Progress::Done;
                Some(Event::EncoderLinearised { peak_rad, periods })
            }
            EncoderOutcome::Failed(e) => {
                self.report = Progress::Failed(e, Step::Encoder);
                Some(Event::IdentificationFailed(e, Step::Encoder))
            }
            EncoderOutcome::Aborted(f) => {
                self.report = Progress::Aborted(f, Step::Encoder);
                Some(Event::IdentificationAborted(f, Step::Encoder))
            }
        };
        self.encoder = None;
        stage.sync_mailbox(cmd);
        self.phase = LifePhase::Run;
    }

    /// The anticogging calibration's period (design §32).
    #[inline(never)]
    #[cold]
    fn step_cogging(
        &mut self,
        stage: &mut CurrentStage,
        inp: &Inputs,
        s: &Sample,
        out: &mut Output,
        fb_out: &mut Feedback,
    ) {
        let Some(run) = self.cogging.as_mut() else {
            return;
        };
        let cmd = &inp.command;
        let abort = cmd.seq != self.identify_seq && cmd.command == Command::Disable;
        let (outcome, b, fb) = if abort {
            run.abort(stage, inp.iq_ref_a, s)
        } else {
            run.step(stage, inp.iq_ref_a, s)
        };
        out.bridge = b;
        *fb_out = fb;
        out.event = match outcome {
            CoggingOutcome::Running => return,
            CoggingOutcome::Done { peak_a, periods } => {
                self.report = Progress::Done;
                Some(Event::CoggingMeasured { peak_a, periods })
            }
            CoggingOutcome::Failed(e) => {
                self.report = Progress::Failed(e, Step::Cogging);
                Some(Event::IdentificationFailed(e, Step::Cogging))
            }
            CoggingOutcome::Aborted(f) => {
                self.report = Progress::Aborted(f, Step::Cogging);
                Some(Event::IdentificationAborted(f, Step::Cogging))
            }
        };
        self.cogging = None;
        stage.sync_mailbox(cmd);
        self.phase = LifePhase::Run;
    }
}

#[cfg(test)]
mod tests {
    use super::Countdown;

    /// The countdown runs in exactly the periods where `tick % divider ==
    /// 0` (the rule it replaces), also across divider changes.
    #[test]
    fn countdown_runs_where_the_tick_is_a_multiple_of_the_divider() {
        let changes = [
            (0u32, 10u32),
            (37, 3),
            (38, 1),
            (50, 7),
            (51, 20),
            (200, 20),
            (333, 4),
        ];
        let mut c = Countdown::new(changes[0].1);
        let mut d = changes[0].1;
        let mut tick = 0u32;
        for _ in 0..1000 {
            if let Some(&(_, n)) = changes[1..].iter().find(|(at, _)| *at == tick) {
                c.set(n, tick);
                d = n;
            }
            tick += 1;
            assert_eq!(c.step(), tick.is_multiple_of(d), "tick {tick}, divider {d}");
        }
    }
}
