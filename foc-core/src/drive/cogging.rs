//! The anticogging calibration driven through the current stage (design
//! §32): [`CoggingCalibration`] stepped once per PWM period by the
//! [`Lifecycle`](super::Lifecycle), its velocity requests posted through a
//! private [`CommandSlot`] as `Command::Velocity`, so the speed loop, the
//! fault supervisor and the safe state work as in normal control.
//!
//! Each finished pass's map is installed in the stage at once (the next
//! pass runs with it); a failed or aborted calibration puts the map the
//! stage had before back.

use crate::calibration::cogging::{CoggingCalConfig, CoggingCalibration};
use crate::calibration::{CalError, CalInput, CalStep, ClosedLoopFeedback};
use crate::control::cogging::CoggingMap;
use crate::control::stage::{CurrentStage, Sample};
use crate::control::{BridgeCommand, Command, CommandSlot, Fault, Feedback, Mode};

/// How an anticogging period ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CoggingOutcome {
    /// Still running.
    Running,
    /// Finished: the stage holds the new map (its peak \[A\]).
    Done {
        /// The map's largest feed-forward \[A\].
        peak_a: f32,
        /// Periods the calibration took.
        periods: u32,
    },
    /// The routine failed (fault `CalibrationFailed` latched, old map back).
    Failed(CalError),
    /// Stopped by a supervisor fault or an operator `Disable` (`None`).
    Aborted(Option<Fault>),
}

/// The routine plus the private mailbox it drives the stage with.
#[derive(Clone, Copy, Debug)]
pub struct CoggingRun {
    cal: CoggingCalibration,
    slot: CommandSlot,
    last_fb: Option<Feedback>,
    /// The stage's map before the calibration (put back on failure).
    before: CoggingMap,
    installed_passes: u8,
}

impl CoggingRun {
    /// A calibration on `stage` with the defaults for its motor, pole
    /// pairs and current limit ([`CoggingCalConfig::new`]).
    pub fn for_stage(stage: &CurrentStage, operator: &CommandSlot) -> Self {
        let c = stage.config();
        let config = CoggingCalConfig::new(
            c.angle.pole_pairs,
            1.0 / c.current.ts_s,
            c.limits.max_current_a,
        );
        Self::new(config, stage, operator)
    }

    /// A calibration with `config`, through a private mailbox that starts
    /// as a copy of `operator` (as the identification's does).
    pub fn new(config: CoggingCalConfig, stage: &CurrentStage, operator: &CommandSlot) -> Self {
        let mut slot = *operator;
        slot.seq = operator.seq.wrapping_add(0x4000_0000);
        slot.command = Command::Disable;
        Self {
            cal: CoggingCalibration::new(config),
            slot,
            last_fb: None,
            before: *stage.cogging(),
            installed_passes: 0,
        }
    }

    /// The routine (its progress, its last map).
    pub fn calibration(&self) -> &CoggingCalibration {
        &self.cal
    }

    fn input(&self, s: &Sample) -> Option<CalInput> {
        let i_abc = s.currents?.to_abc();
        let mut inp = CalInput::open_loop(i_abc, s.angle?, s.v_bus_v?);
        inp.closed_loop =
            self.last_fb
                .filter(|f| f.mode == Mode::Velocity)
                .map(|f| ClosedLoopFeedback {
                    v_dq_v: f.v_dq_v,
                    i_dq_a: f.i_dq_a,
                    velocity_rad_s: f.velocity_rad_s,
                    theta_e: f.theta_e,
                });
        Some(inp)
    }

    /// One PWM period through `stage`.
    pub fn step(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
    ) -> (CoggingOutcome, BridgeCommand, Feedback) {
        // A failed read is the stage's fault (it trips below), not the
        // routine's.
        match self.input(s).map(|inp| self.cal.step(&inp)) {
            None => {}
            Some(CalStep::Velocity { rad_s }) => {
                self.install_new_map(stage);
                if self.slot.command != (Command::Velocity { rad_s }) {
                    self.slot.post(Command::Velocity { rad_s });
                }
            }
            Some(CalStep::Done(())) => {
                self.install_new_map(stage);
                let out = CoggingOutcome::Done {
                    peak_a: stage.cogging().peak_a(),
                    periods: self.cal.elapsed_periods(),
                };
                return self.finish(stage, iq_ref_a, s, out);
            }
            Some(CalStep::Failed(e)) => {
                self.put_back(stage);
                stage.report_fault(Fault::CalibrationFailed);
                return self.finish(stage, iq_ref_a, s, CoggingOutcome::Failed(e));
            }
            // The routine asks for nothing else.
            Some(_) => {}
        }
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        self.last_fb = Some(fb);
        if let Some(f) = fb.first_fault {
            self.put_back(stage);
            return (CoggingOutcome::Aborted(Some(f)), b, fb);
        }
        (CoggingOutcome::Running, b, fb)
    }

    /// A pass finished: its map goes into the stage (the next pass runs
    /// with it).
    fn install_new_map(&mut self, stage: &mut CurrentStage) {
        if self.cal.passes_done() > self.installed_passes {
            self.installed_passes = self.cal.passes_done();
            // Checked by the routine against its share of the limit.
            let _taken = stage.set_cogging(self.cal.map());
        }
    }

    fn put_back(&mut self, stage: &mut CurrentStage) {
        let _taken = stage.set_cogging(&self.before);
    }

    /// Stop on operator request: bridge off, the old map back.
    pub fn abort(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
    ) -> (CoggingOutcome, BridgeCommand, Feedback) {
        self.put_back(stage);
        self.finish(stage, iq_ref_a, s, CoggingOutcome::Aborted(None))
    }

    /// The last period: `Disable` through the private mailbox.
    fn finish(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
        out: CoggingOutcome,
    ) -> (CoggingOutcome, BridgeCommand, Feedback) {
        self.slot.post(Command::Disable);
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        (out, b, fb)
    }
}
