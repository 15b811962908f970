//! One PWM period as the firmware's current-loop interrupt runs it:
//! [`Drive::run_period`] makes the inputs from the other tasks' mailboxes,
//! steps the drive with the feedback written in place and publishes the
//! status. The firmware calls it with its RTIC resources (inside their
//! locks, which the bench does not count) and the instruction bench
//! (`cargo xtask bench`) with the same kinds of values, so the counts are
//! those of the code the interrupt runs.
//!
//! Nothing large is copied (design §20): a configuration change waiting in
//! its mailbox is lent to the drive (then the mailbox is emptied: applied
//! or refused once), and the feedback is written into the copy the other
//! tasks read.

use super::{ConfigChange, Drive, Inputs, Output, Status};
use crate::control::{CommandSlot, Feedback};
use crate::hal::{AngleSensor, BrakeOutput, BusVoltage, CurrentSense, PwmDriver};

/// What one period reads from the other tasks.
pub struct Mail<'a> {
    /// The operator's command mailbox.
    pub command: CommandSlot,
    /// q-current reference from the speed stage \[A\].
    pub iq_ref_a: f32,
    /// The current stage's part of the configuration mailbox: emptied when
    /// it held a change (applied or refused this period).
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
    /// One period: the inputs from `mail`, [`Drive::step`] with the
    /// feedback written into `feedback`, the status into `status`. A change
    /// in the mailbox is applied (or refused) this period, its verdict in
    /// [`Output::change`], and the mailbox emptied.
    #[inline(always)]
    pub fn run_period(
        &mut self,
        mail: Mail<'_>,
        feedback: &mut Feedback,
        status: &mut Status,
    ) -> Output {
        let inputs = Inputs {
            command: mail.command,
            iq_ref_a: mail.iq_ref_a,
            change: mail.change.as_ref(),
            gate_fault: mail.gate_fault,
            index: None,
        };
        let out = self.step(&inputs, feedback);
        if mail.change.is_some() {
            *mail.change = None;
        }
        *status = self.status();
        out
    }
}
