//! The encoder linearisation driven through the current stage (design
//! §33): [`EncoderCalibration`] stepped once per PWM period by the
//! [`Lifecycle`](super::Lifecycle), its velocity and torque requests
//! posted through a private [`CommandSlot`], so the fault supervisor and
//! the safe state work as in normal control. The routine fits the raw
//! readings (the stage's correction, if any, steers the loop meanwhile);
//! the new correction is installed only when it finishes.

use crate::calibration::encoder::{EncoderCalConfig, EncoderCalibration};
use crate::calibration::{CalError, CalInput, CalStep, ClosedLoopFeedback};
use crate::control::stage::{CurrentStage, Sample};
use crate::control::{BridgeCommand, Command, CommandSlot, Fault, Feedback, Mode};

/// How an encoder-linearisation period ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EncoderOutcome {
    /// Still running.
    Running,
    /// Finished: the stage holds the new correction.
    Done {
        /// Its largest correction \[rad\] (mechanical).
        peak_rad: f32,
        /// Periods the run took.
        periods: u32,
    },
    /// The routine failed (fault `CalibrationFailed` latched).
    Failed(CalError),
    /// Stopped by a supervisor fault or an operator `Disable` (`None`).
    Aborted(Option<Fault>),
}

/// The routine plus the private mailbox it drives the stage with.
#[derive(Clone, Copy, Debug)]
pub struct EncoderRun {
    cal: EncoderCalibration,
    slot: CommandSlot,
    last_fb: Option<Feedback>,
}

impl EncoderRun {
    /// A run on `stage` with the defaults for its current limit
    /// ([`EncoderCalConfig::new`]) and its motor's no-load speed.
    pub fn for_stage(stage: &CurrentStage, operator: &CommandSlot) -> Self {
        let c = stage.config();
        let m = c.current.motor;
        let k = crate::SQRT_3 * m.pole_pairs as f32 * m.flux_linkage_wb;
        let config = EncoderCalConfig {
            no_load_rad_s_per_v: if k > 0.0 { 1.0 / k } else { 0.0 },
            accel_per_a_rad_s2: c.observer.accel_per_a_rad_s2,
            ..EncoderCalConfig::new(1.0 / c.current.ts_s, c.limits.max_current_a)
        };
        Self::new(config, operator)
    }

    /// A run with `config`, through a private mailbox that starts as a
    /// copy of `operator` (as the identification's does).
    pub fn new(config: EncoderCalConfig, operator: &CommandSlot) -> Self {
        let mut slot = *operator;
        slot.seq = operator.seq.wrapping_add(0x4000_0000);
        slot.command = Command::Disable;
        Self {
            cal: EncoderCalibration::new(config),
            slot,
            last_fb: None,
        }
    }

    /// The routine.
    pub fn calibration(&self) -> &EncoderCalibration {
        &self.cal
    }

    /// The routine's input: the reading referred to the index (design
    /// §33), the sensor's error not taken off (it is what is fitted).
    fn input(&self, stage: &CurrentStage, s: &Sample) -> Option<CalInput> {
        let i_abc = s.currents?.to_abc();
        let mut inp = CalInput::open_loop(i_abc, stage.reading(s.angle?), s.v_bus_v?);
        inp.closed_loop = self
            .last_fb
            .filter(|f| matches!(f.mode, Mode::Velocity | Mode::Torque))
            .map(|f| ClosedLoopFeedback {
                v_dq_v: f.v_dq_v,
                i_dq_a: f.i_dq_a,
                velocity_rad_s: f.velocity_rad_s,
                theta_e: f.theta_e,
            });
        Some(inp)
    }

    fn post(&mut self, cmd: Command) {
        if self.slot.command != cmd {
            self.slot.post(cmd);
        }
    }

    /// One PWM period through `stage`.
    pub fn step(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
    ) -> (EncoderOutcome, BridgeCommand, Feedback) {
        match self.input(stage, s).map(|inp| self.cal.step(&inp)) {
            None => {}
            Some(CalStep::Velocity { rad_s }) => self.post(Command::Velocity { rad_s }),
            Some(CalStep::Torque { iq_a }) => self.post(Command::Torque { iq_a }),
            Some(CalStep::Done(())) => {
                // Installed straight from the routine (no copy on the
                // stack), its peak from its scale (no scan: this period
                // also runs the stage).
                let c = self.cal.correction();
                let out = match stage.set_angle_correction(c) {
                    Ok(()) => EncoderOutcome::Done {
                        peak_rad: c.full_scale_rad(),
                        periods: self.cal.elapsed_periods(),
                    },
                    Err(_) => {
                        stage.report_fault(Fault::CalibrationFailed);
                        EncoderOutcome::Failed(CalError::ImplausibleResult)
                    }
                };
                return self.finish(stage, iq_ref_a, s, out);
            }
            Some(CalStep::Failed(e)) => {
                stage.report_fault(Fault::CalibrationFailed);
                return self.finish(stage, iq_ref_a, s, EncoderOutcome::Failed(e));
            }
            // The routine asks for nothing else.
            Some(CalStep::Apply { .. }) => {}
        }
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        self.last_fb = Some(fb);
        if let Some(f) = fb.first_fault {
            return (EncoderOutcome::Aborted(Some(f)), b, fb);
        }
        (EncoderOutcome::Running, b, fb)
    }

    /// Stop on operator request: bridge off.
    pub fn abort(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
    ) -> (EncoderOutcome, BridgeCommand, Feedback) {
        self.finish(stage, iq_ref_a, s, EncoderOutcome::Aborted(None))
    }

    /// The last period: `Disable` through the private mailbox.
    fn finish(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
        out: EncoderOutcome,
    ) -> (EncoderOutcome, BridgeCommand, Feedback) {
        self.slot.post(Command::Disable);
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        (out, b, fb)
    }
}
