//! The current-loop task's work in one PWM period, once: the firmware's
//! `current_loop` calls it with its RTIC resources (whose locks cost
//! nothing at the task's top priority) and the bench (`cargo xtask bench`)
//! calls it with the same kinds of values, so the instruction counts are
//! those of the code the interrupt runs.
//!
//! Nothing large is copied (design §20): the inputs live across periods
//! (only the command mailbox, the q-current reference and the gate flag
//! are refreshed), a configuration change is taken from its mailbox only
//! when one is there, and the drive writes the feedback in place into the
//! copy the other tasks read.

use foc_core::control::{CommandSlot, Feedback};
use foc_core::drive::{ConfigChange, Drive, Inputs, Output, Status};
use foc_core::hal::{AngleSensor, BrakeOutput, BusVoltage, CurrentSense, PwmDriver};

/// What the period reads from the other tasks.
pub struct Mail<'a> {
    /// The operator's command mailbox.
    pub command: CommandSlot,
    /// q-current reference from the speed loop [A].
    pub iq_ref_a: f32,
    /// The current stage's part of the configuration mailbox (taken).
    pub change: &'a mut Option<ConfigChange>,
    /// The power stage reported a fault (break input, gate driver).
    pub gate_fault: bool,
}

/// One period: refresh `inputs` from `mail`, step the drive with the
/// feedback written into `feedback`, publish the status.
#[inline(always)]
pub fn run<P, C, A, B, K>(
    drive: &mut Drive<P, C, A, B, K>,
    inputs: &mut Inputs,
    mail: Mail<'_>,
    feedback: &mut Feedback,
    status: &mut Status,
) -> Output
where
    P: PwmDriver,
    C: CurrentSense,
    A: AngleSensor,
    B: BusVoltage,
    K: BrakeOutput,
{
    inputs.command = mail.command;
    inputs.iq_ref_a = mail.iq_ref_a;
    inputs.gate_fault = mail.gate_fault;
    if mail.change.is_some() {
        inputs.change = mail.change.take();
    }
    let out = drive.step(inputs, feedback);
    if inputs.change.is_some() {
        inputs.change = None;
    }
    *status = drive.status();
    out
}
