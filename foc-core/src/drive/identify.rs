//! The identification driven through the current stage: foc-core's
//! [`Identification`] sequencer (resistance, inductance, gains, sensor
//! alignment with the pole-pair check, flux linkage, inertia and friction)
//! stepped once per PWM period by the [`Lifecycle`](super::Lifecycle).
//!
//! Every period goes through the [`CurrentStage`] like normal control does:
//! open-loop voltage requests become `Command::OpenLoop` at the requested
//! angle, the flux step's velocity requests become `Command::Velocity` (the
//! speed stage runs as usual, held within the identification's current
//! limit through [`Feedback::current_limit_a`]), the mechanical step's
//! torque requests `Command::Torque`, so the fault supervisor watches the
//! whole identification and the bridge goes to the safe state on any
//! fault. The stage stays uncalibrated (closed-loop commands refused) until
//! the sequencer's permit exists: the provisional one (after the alignment)
//! for the flux and mechanical steps, the final one (measured gains and
//! flux linkage) at the end.
//!
//! The sequencer drives the stage through a private [`CommandSlot`], so the
//! operator's mailbox is never written; the lifecycle marks the operator's
//! last command as seen when the identification ends, so it never resumes.

use crate::angle::MechanicalAngle;
use crate::calibration::identification::{
    Identification, IdentificationConfig, IdentificationResult, Step,
};
use crate::calibration::{CalError, CalInput, CalStep, ClosedLoopFeedback};
use crate::control::stage::{CurrentStage, Sample};
use crate::control::{BridgeCommand, Command, CommandSlot, Fault, Feedback, Limits, Mode};
use crate::frames::Abc;

/// How an identification period ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// Still running.
    Running,
    /// Finished: the stage holds the measured calibration.
    Done(IdentificationResult),
    /// A routine failed (fault `CalibrationFailed` latched, bridge safe).
    Failed(CalError, Step),
    /// Stopped by a supervisor fault (bridge safe, the fault stays latched)
    /// or by an operator `Disable` (`None`).
    Aborted(Option<Fault>, Step),
}

/// The sequencer plus the private command mailbox it drives the stage with.
#[derive(Clone, Copy, Debug)]
pub struct Identifier {
    id: Identification,
    slot: CommandSlot,
    last_fb: Option<Feedback>,
    /// The stage's command limits before the identification (restored at
    /// the end); `None` until the first step.
    saved_limits: Option<Limits>,
    /// Current limit during the identification \[A\]: inside the routines'
    /// own over-current bound (twice the test current).
    current_limit_a: f32,
    /// This identification's provisional permit is installed (flux and
    /// mechanical steps).
    permit_installed: bool,
}

impl Identifier {
    /// A new identification driven through a private mailbox that starts
    /// as a copy of `operator`: the same fault-clear number (starting
    /// clears nothing) and command numbers far from the operator's (every
    /// request is taken as new).
    pub fn new(config: IdentificationConfig, operator: &CommandSlot) -> Self {
        let mut slot = *operator;
        slot.seq = operator.seq.wrapping_add(0x4000_0000);
        slot.command = Command::Disable;
        Self {
            id: Identification::new(config),
            slot,
            last_fb: None,
            saved_limits: None,
            current_limit_a: 1.5 * config.alignment_current_a,
            permit_installed: false,
        }
    }

    /// The stage the sequencer is in.
    pub fn current_step(&self) -> Step {
        self.id.current_step()
    }

    fn post_if_new(&mut self, cmd: Command) {
        // Open-loop angles change every period during the sweeps: post each
        // change; repeat requests keep the running command.
        if self.slot.command != cmd {
            self.slot.post(cmd);
        }
    }

    fn limit_current(&mut self, stage: &mut CurrentStage) {
        if self.saved_limits.is_none() {
            let l = stage.config().limits;
            self.saved_limits = Some(l);
            let lim = if self.current_limit_a < l.max_current_a {
                self.current_limit_a
            } else {
                l.max_current_a
            };
            stage.set_limits(Limits {
                max_current_a: lim,
                ..l
            });
        }
    }

    fn restore_limits(&mut self, stage: &mut CurrentStage) {
        if let Some(l) = self.saved_limits.take() {
            stage.set_limits(l);
        }
    }

    /// Ended without a result: limits back, and the provisional permit
    /// (flux and mechanical steps) taken away, so no closed loop runs on a
    /// calibration the sequencer did not finish.
    fn give_up(&mut self, stage: &mut CurrentStage) {
        self.restore_limits(stage);
        if self.permit_installed {
            stage.revoke_calibration();
        }
    }

    /// Before the first closed-loop request: the sequencer's provisional
    /// permit, always this identification's own alignment (the previous
    /// calibration was revoked when it started).
    fn install_permit(&mut self, stage: &mut CurrentStage) {
        if !self.permit_installed {
            if let Some(p) = self.id.permit() {
                stage.set_calibration(&p);
                self.permit_installed = true;
            }
        }
    }

    /// The sequencer's input from this period's sample and the last
    /// closed-loop feedback (a failed read would be a non-finite input; the
    /// caller does not step the routine on one).
    fn input(&self, stage: &CurrentStage, s: &Sample) -> CalInput {
        let nan = Abc::new(f32::NAN, f32::NAN, f32::NAN);
        let angle_ok = s.angle.is_some() || !self.id.config().angle_sensor;
        let i_abc = match s.currents {
            Some(c) if angle_ok => c.to_abc(),
            _ => nan,
        };
        // Without a sensor nothing reads it, even where a (broken) one
        // still answers: the routines see a rotor that does not move.
        // The reading as the stage uses it (referred to the index, the
        // sensor's error taken off, design §33): the alignment's zero is
        // then the stage's.
        let angle = s
            .angle
            .filter(|_| self.id.config().angle_sensor)
            .map(|a| stage.angle_correction().correct(stage.reading(a)))
            .unwrap_or(MechanicalAngle::ZERO);
        let mut inp = CalInput::open_loop(i_abc, angle, s.v_bus_v.unwrap_or(f32::NAN));
        inp.closed_loop = self
            .last_fb
            .filter(|f| matches!(f.mode, Mode::Velocity | Mode::Torque))
            .map(|f| ClosedLoopFeedback {
                v_dq_v: f.v_dq_v,
                i_dq_a: f.i_dq_a,
                velocity_rad_s: f.velocity_rad_s,
                theta_e: f.theta_e,
            });
        inp
    }

    /// One PWM period through `stage`.
    pub fn step(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
    ) -> (Outcome, BridgeCommand, Feedback) {
        self.limit_current(stage);
        // A failed read is the stage's fault (it trips on it below), not
        // the routine's: the routine is not stepped on it.
        let angle_ok = s.angle.is_some() || !self.id.config().angle_sensor;
        let reads_ok = s.currents.is_some() && angle_ok && s.v_bus_v.is_some();
        let step = if reads_ok {
            Some(self.id.step(&self.input(stage, s)))
        } else {
            None
        };
        match step {
            None => {}
            Some(CalStep::Apply { v_dq, theta_e }) => self.post_if_new(Command::OpenLoop {
                v_d_v: v_dq.d,
                v_q_v: v_dq.q,
                theta_e,
                omega_e_rad_s: 0.0,
            }),
            Some(CalStep::Velocity { rad_s }) => {
                self.install_permit(stage);
                self.post_if_new(Command::Velocity { rad_s });
            }
            Some(CalStep::Torque { iq_a }) => {
                self.install_permit(stage);
                self.post_if_new(Command::Torque { iq_a });
            }
            Some(CalStep::Done(done)) => {
                self.restore_limits(stage);
                stage.set_calibration(&done.permit);
                return self.finish(stage, iq_ref_a, s, Outcome::Done(done.result));
            }
            Some(CalStep::Failed(e)) => {
                self.give_up(stage);
                stage.report_fault(Fault::CalibrationFailed);
                let out = Outcome::Failed(e, self.id.current_step());
                return self.finish(stage, iq_ref_a, s, out);
            }
        }
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        self.last_fb = Some(fb);
        // The supervisor latched a fault: stop here (the bridge is already
        // safe), rather than let the routine fail later for a reason that
        // is only a consequence.
        if let Some(f) = fb.first_fault {
            self.give_up(stage);
            return (Outcome::Aborted(Some(f), self.id.current_step()), b, fb);
        }
        (Outcome::Running, b, fb)
    }

    /// Stop on operator request: bridge off, limits restored.
    pub fn abort(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
    ) -> (Outcome, BridgeCommand, Feedback) {
        self.give_up(stage);
        let out = Outcome::Aborted(None, self.id.current_step());
        self.finish(stage, iq_ref_a, s, out)
    }

    /// The last period: `Disable` through the private mailbox.
    fn finish(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
        out: Outcome,
    ) -> (Outcome, BridgeCommand, Feedback) {
        self.slot.post(Command::Disable);
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        (out, b, fb)
    }
}
