//! One PWM period as the firmware's current-loop interrupt runs it:
//! [`Drive::run_period`] refreshes the inputs from the other tasks'
//! mailboxes, steps the drive with the feedback written in place and
//! publishes the status. The firmware calls it with its RTIC resources
//! (whose locks cost nothing at the interrupt's top priority) and the
//! instruction bench (`cargo xtask bench`) with the same kinds of values,
//! so the counts are those of the code the interrupt runs.
//!
//! Nothing large is copied (design §20): the [`Inputs`] live across
//! periods (only the command mailbox, the q-current reference and the
//! gate flag are refreshed), a configuration change is taken from its
//! mailbox only when one is there (and handed to the drive once), and the
//! feedback is written into the copy the other tasks read.

use super::{ConfigChange, Drive, Inputs, Output, Status};
use crate::control::{CommandSlot, Feedback};
use crate::hal::{AngleSensor, BrakeOutput, BusVoltage, CurrentSense, PwmDriver};

/// What one period reads from the other tasks.
pub struct Mail<'a> {
    /// The operator's command mailbox.
    pub command: CommandSlot,
    /// q-current reference from the speed stage [A].
    pub iq_ref_a: f32,
    /// The current stage's part of the configuration mailbox: taken (left
    /// `None`) when it holds a change.
    pub change: &'a mut Option<ConfigChange>,
    /// The power stage reported a fault (break input, gate driver).
    pub gate_fault: bool,
}

impl<P, C, A, B, K> Drive<P, C, A, B, K>
where
    P: PwmDriver,
    C: CurrentSense,
    A: AngleSensor,
    B: BusVoltage,
    K: BrakeOutput,
{
    /// One period: refresh `inputs` (kept by the caller across periods)
    /// from `mail`, [`Drive::step`] with the feedback written into
    /// `feedback`, the status into `status`. A change taken from the
    /// mailbox is applied (or refused) this period; its verdict is in
    /// [`Output::change`].
    #[inline(always)]
    pub fn run_period(
        &mut self,
        inputs: &mut Inputs,
        mail: Mail<'_>,
        feedback: &mut Feedback,
        status: &mut Status,
    ) -> Output {
        inputs.command = mail.command;
        inputs.iq_ref_a = mail.iq_ref_a;
        inputs.gate_fault = mail.gate_fault;
        if mail.change.is_some() {
            inputs.change = mail.change.take();
        }
        let out = self.step(inputs, feedback);
        if inputs.change.is_some() {
            inputs.change = None;
        }
        *status = self.status();
        out
    }
}
