//! Motor identification run by the firmware: foc-core's `Identification`
//! sequencer (resistance, inductance, gains, sensor alignment with the
//! pole-pair check, flux linkage) stepped once per PWM period from the
//! current-loop task.
//!
//! Every period goes through the `CurrentStage` like normal control does:
//! open-loop voltage requests become `Command::OpenLoop` at the requested
//! angle, the flux step's velocity requests become `Command::Velocity`
//! (the speed task runs as usual), so the fault supervisor watches the
//! whole identification and the bridge goes to the safe state on any fault.
//! The stage stays uncalibrated (closed-loop commands refused) until the
//! sequencer's permit exists: after the alignment for the flux step, and
//! the final permit (measured gains and flux linkage) at the end.

use foc_core::angle::MechanicalAngle;
use foc_core::calibration::identification::{
    Identification, IdentificationConfig, IdentificationResult, Stage,
};
use foc_core::calibration::{CalError, CalInput, CalStep, ClosedLoopFeedback};
use foc_core::control::stage::{CurrentStage, Sample};
use foc_core::control::{BridgeCommand, Command, CommandSlot, Fault, Feedback, Limits, Mode};
use foc_core::frames::Abc;

/// What one identification period produced.
pub enum Outcome {
    /// Still running: apply the bridge command, publish the feedback.
    Running(BridgeCommand, Feedback),
    /// Finished: the stage now holds the measured calibration.
    Done(IdentificationResult, BridgeCommand, Feedback),
    /// Failed (fault latched, bridge safe): the reason and the stage.
    Failed(CalError, Stage, BridgeCommand, Feedback),
    /// Stopped by a supervisor fault (bridge safe, fault stays latched) or
    /// by an operator `Disable`: the fault if any, and the stage.
    Aborted(Option<Fault>, Stage, BridgeCommand, Feedback),
}

/// The sequencer plus the private command mailbox it drives the stage with.
pub struct Identifier {
    id: Identification,
    slot: CommandSlot,
    last_fb: Option<Feedback>,
    /// The stage's command limits before the identification (restored at
    /// the end); `None` until the first step.
    saved_limits: Option<Limits>,
    /// Current limit during the identification [A]: inside the routines'
    /// own over-current bound (twice the test current).
    current_limit_a: f32,
    /// This identification's alignment permit is installed (flux step).
    permit_installed: bool,
}

impl Identifier {
    /// A new identification driven through a private mailbox that starts as
    /// a copy of the shared one `shared`: the same fault-clear counter (so
    /// starting does not clear anything) and command numbers far from the
    /// shared ones (so every request is taken as new, and the shared
    /// mailbox's next command is new to the stage afterwards).
    pub fn new(config: IdentificationConfig, shared: &CommandSlot) -> Self {
        let mut slot = *shared;
        slot.seq = shared.seq.wrapping_add(0x4000_0000);
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
    pub fn stage(&self) -> Stage {
        self.id.stage()
    }

    fn post_if_new(&mut self, cmd: Command) {
        // Open-loop angles change every period during the sweeps: post each
        // change; repeat requests keep the running command.
        if self.slot.command != cmd {
            self.slot.post(cmd);
        }
    }

    fn restore_limits(&mut self, stage: &mut CurrentStage) {
        if let Some(l) = self.saved_limits.take() {
            stage.set_limits(l);
        }
    }

    /// One PWM period.
    pub fn step(&mut self, stage: &mut CurrentStage, iq_ref_a: f32, s: &Sample) -> Outcome {
        if self.saved_limits.is_none() {
            let l = stage.config().limits;
            self.saved_limits = Some(l);
            stage.set_limits(Limits {
                max_current_a: self.current_limit_a.min(l.max_current_a),
                ..l
            });
        }
        let nan = Abc::new(f32::NAN, f32::NAN, f32::NAN);
        // A failed read becomes a non-finite input: the routine fails cleanly.
        let i_abc = match (s.currents, s.angle) {
            (Some(c), Some(_)) => c.to_abc(),
            _ => nan,
        };
        let mut inp = CalInput::open_loop(
            i_abc,
            s.angle.unwrap_or(MechanicalAngle::ZERO),
            s.v_bus_v.unwrap_or(f32::NAN),
        );
        inp.closed_loop =
            self.last_fb
                .filter(|f| f.mode == Mode::Velocity)
                .map(|f| ClosedLoopFeedback {
                    v_dq_v: f.v_dq_v,
                    i_dq_a: f.i_dq_a,
                    velocity_rad_s: f.velocity_rad_s,
                });
        match self.id.step(&inp) {
            CalStep::Apply { v_dq, theta_e } => self.post_if_new(Command::OpenLoop {
                v_d_v: v_dq.d,
                v_q_v: v_dq.q,
                theta_e,
                omega_e_rad_s: 0.0,
            }),
            CalStep::Velocity { rad_s } => {
                // Always this identification's own alignment (a previous
                // calibration was revoked when it started).
                if !self.permit_installed {
                    if let Some(p) = self.id.permit() {
                        stage.set_calibration(&p);
                        self.permit_installed = true;
                    }
                }
                self.post_if_new(Command::Velocity { rad_s });
            }
            CalStep::Done(done) => {
                self.restore_limits(stage);
                done.permit.apply_to(stage);
                self.slot.post(Command::Disable);
                let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
                return Outcome::Done(done.result, b, fb);
            }
            CalStep::Failed(e) => {
                self.restore_limits(stage);
                stage.report_fault(Fault::CalibrationFailed);
                self.slot.post(Command::Disable);
                let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
                return Outcome::Failed(e, self.id.stage(), b, fb);
            }
        }
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        self.last_fb = Some(fb);
        // The supervisor latched a fault: stop here (the bridge is already
        // safe), rather than let the routine fail later for a reason that
        // is only a consequence.
        if let Some(f) = fb.first_fault {
            self.restore_limits(stage);
            return Outcome::Aborted(Some(f), self.id.stage(), b, fb);
        }
        Outcome::Running(b, fb)
    }

    /// Stop on operator request: bridge off, limits restored.
    pub fn abort(&mut self, stage: &mut CurrentStage, iq_ref_a: f32, s: &Sample) -> Outcome {
        self.restore_limits(stage);
        self.slot.post(Command::Disable);
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        Outcome::Aborted(None, self.id.stage(), b, fb)
    }
}

/// The last successful identification (read by the QEMU mission and the
/// command channel's parameters).
static LAST: cortex_m::interrupt::Mutex<core::cell::Cell<Option<IdentificationResult>>> =
    cortex_m::interrupt::Mutex::new(core::cell::Cell::new(None));

/// Record a successful identification.
pub fn publish(r: IdentificationResult) {
    cortex_m::interrupt::free(|cs| LAST.borrow(cs).set(Some(r)));
}

/// The last successful identification, if any (read by the command
/// channel's parameters and gain changes, and by the emulated mission).
pub fn last() -> Option<IdentificationResult> {
    cortex_m::interrupt::free(|cs| LAST.borrow(cs).get())
}
