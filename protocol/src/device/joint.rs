//! The joint's requests (`SetJoint`, `StartHoming`) and the homing runner
//! of [`DeviceState`] (design §21).
//!
//! Homing runs here, on the link's side of the drive: the
//! [`Homing`] sequencer is stepped at every [`DeviceState::poll`] (any
//! rate: it counts time from the feedback's period counter) on
//! [`DeviceContext::feedback`]; its commands go through
//! [`DeviceContext::post`] after the drive's own check; when it is done the
//! joint's frame is moved so the home point reads the requested output
//! position ([`foc_core::control::joint::OutputFrame::homed_at`]) and set
//! with [`DeviceContext::set_joint`]; when it fails the bridge is disabled.
//! While it runs it feeds the link watchdog (it is the command source; its
//! search ends by itself within its longest travel); a command from the
//! host aborts it. An end-stop search runs without the travel limits
//! (they are in the frame it is about to move, and the stop is usually
//! beyond them): the joint without its travel range is set at the start,
//! the joint as it was (or, when done, in its new frame) at the end.

use super::{out_of_range, DeviceContext, DeviceState};
use crate::joint::{end_stop_field, taken, HomingFailure, HomingStart, HomingState, JointSettings};
use crate::message::{ErrorCode, ParamId, Response};
use foc_core::control::homing::{Homing, HomingError, HomingMethod, HomingStep};
use foc_core::control::joint::JointSetup;
use foc_core::control::{Command, CommandError, Feedback, Limits, Mode};

/// Seconds a posted homing command may take to show in the feedback.
const TAKE_GRACE_S: f32 = 0.1;

/// A homing running.
#[derive(Clone, Copy, Debug)]
pub(super) struct HomingRun {
    homing: Homing,
    /// The output position of the home point [rad, output].
    home_output_rad: f32,
    /// Feedback period of the last post, until the drive shows it taken.
    posted_at: Option<u32>,
    /// Periods a post may take to show (then the sequencer judges).
    grace_periods: u32,
    /// The joint before the homing (travel range included).
    saved: JointSetup,
}

impl HomingRun {
    /// True while the last post has not shown in the feedback yet (and
    /// the grace has not run out); forgets the post once it shows.
    fn waiting(&mut self, fb: &Feedback) -> bool {
        let Some(t) = self.posted_at else {
            return false;
        };
        if taken(fb, Mode::Impedance) || fb.period.wrapping_sub(t) >= self.grace_periods {
            self.posted_at = None;
            return false;
        }
        true
    }
}

impl DeviceState {
    /// Where homing stands.
    pub const fn homing_state(&self) -> HomingState {
        self.homing_state
    }

    /// Another front end on the same drive homed it (or is homing it):
    /// report its state from now on. A homing this state runs itself
    /// keeps its own. For a host simulation that serves several clients,
    /// each with its own protocol state, on one drive.
    pub fn share_homing_state(&mut self, state: HomingState) {
        if self.homing.is_none() {
            self.homing_state = state;
        }
    }

    /// `SetJoint`: every value checked (field-exact), then the context
    /// takes it (the drive started; not while homing).
    pub(super) fn set_joint<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        j: &JointSettings,
    ) -> Result<Response, Response> {
        let setup = j.to_setup().map_err(out_of_range)?;
        if self.homing.is_some() || !ctx.status().running {
            return Err(Response::Nack(ErrorCode::Busy));
        }
        ctx.set_joint(setup).map_err(|r| Response::Nack(r.into()))?;
        Ok(Response::Ack)
    }

    /// `StartHoming`: checked whole (output frame, then the sequencer's
    /// own check in the rotor frame against the limits in force), then
    /// stepped once: the present position homes at once; an end-stop
    /// search posts its first command (checked by the drive's rules
    /// first) and runs on in [`Self::poll`].
    pub(super) fn start_homing<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        h: &HomingStart,
    ) -> Result<Response, Response> {
        h.check_finite().map_err(out_of_range)?;
        if self.homing.is_some() || !ctx.status().running {
            return Err(Response::Nack(ErrorCode::Busy));
        }
        let pwm_hz = ctx
            .param(ParamId::PwmFrequencyHz)
            .filter(|f| f.is_finite() && *f > 0.0)
            .ok_or(Response::Nack(ErrorCode::Unsupported))?;
        let saved = ctx.joint();
        let method = h.method_in_rotor(&saved.frame);
        // The search runs without travel limits: the motor's range.
        let limits = match method {
            HomingMethod::EndStop(_) => ctx.limits(),
            HomingMethod::Present => self.limits_in_force(ctx),
        };
        let kt = ctx.torque_constant_nm_per_a();
        let mut homing = Homing::new(method, &limits, kt, 1.0 / pwm_hz)
            .map_err(|e| Response::Nack(homing_refusal(h, e)))?;
        let fb = ctx.feedback();
        match homing.step(&fb, &limits) {
            HomingStep::Post(cmd) => {
                let refuse = |e| Response::Nack(command_refusal(h, e));
                ctx.status().check_command(&cmd, &limits).map_err(refuse)?;
                let free = JointSetup {
                    travel_out_rad: None,
                    ..saved
                };
                ctx.set_joint(free).map_err(|r| Response::Nack(r.into()))?;
                if let Err(e) = ctx.post(cmd) {
                    let _ = ctx.set_joint(saved);
                    return Err(refuse(e));
                }
                self.posted(cmd);
                self.homing = Some(HomingRun {
                    homing,
                    home_output_rad: h.home_output_rad,
                    posted_at: Some(fb.period),
                    grace_periods: (TAKE_GRACE_S * pwm_hz) as u32,
                    saved,
                });
                self.homing_state = HomingState::Running;
            }
            HomingStep::Done { home_rotor_rad } => {
                self.set_home(ctx, &saved, home_rotor_rad, h.home_output_rad)
                    .map_err(Response::Nack)?;
                self.homing_state = HomingState::Done;
            }
            // A fresh sequencer posts or finishes at its first step.
            HomingStep::Running | HomingStep::Failed(_) => {
                return Err(Response::Nack(ErrorCode::Busy))
            }
        }
        Ok(Response::Ack)
    }

    /// The joint `joint` (its travel range back) with its frame moved so
    /// that the rotor position `home_rotor_rad` reads `home_output_rad`,
    /// checked whole and handed to the context.
    fn set_home<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        joint: &JointSetup,
        home_rotor_rad: f32,
        home_output_rad: f32,
    ) -> Result<(), ErrorCode> {
        let home = ErrorCode::OutOfRange { field: 1 };
        let joint = *joint;
        let frame = joint
            .frame
            .homed_at(home_rotor_rad, home_output_rad)
            .ok_or(home)?;
        let setup = JointSettings::from_setup(&JointSetup { frame, ..joint })
            .to_setup()
            .map_err(|_| home)?;
        ctx.set_joint(setup).map_err(ErrorCode::from)
    }

    /// A host command took over: the homing ends (its last command is
    /// replaced by the host's), the joint as it was before it.
    pub(super) fn abort_homing<C: DeviceContext>(&mut self, ctx: &mut C) {
        if let Some(run) = self.homing.take() {
            self.homing_state = HomingState::Failed(HomingFailure::Aborted);
            let _ = ctx.set_joint(run.saved);
        }
    }

    /// The joint the host's commands are judged in: the one before a
    /// homing while it runs (its search has the travel range off).
    pub(super) fn host_joint<C: DeviceContext>(&self, ctx: &C) -> JointSetup {
        self.homing.map_or_else(|| ctx.joint(), |r| r.saved)
    }

    /// One step of a running homing (from [`Self::poll`]).
    pub(super) fn step_homing<C: DeviceContext>(&mut self, ctx: &mut C) {
        let Some(mut run) = self.homing else {
            return;
        };
        // The homing is the command source while it runs.
        self.watchdog.feed();
        let fb = ctx.feedback();
        if run.waiting(&fb) {
            self.homing = Some(run);
            return;
        }
        let limits = self.limits_in_force(ctx);
        let end = match run.homing.step(&fb, &limits) {
            HomingStep::Post(cmd) => {
                if self.post_checked(ctx, cmd, &limits) {
                    run.posted_at = Some(fb.period);
                    None
                } else {
                    Some(HomingState::Failed(HomingFailure::Refused))
                }
            }
            HomingStep::Running => None,
            HomingStep::Done { home_rotor_rad } => Some(
                match self.set_home(ctx, &run.saved, home_rotor_rad, run.home_output_rad) {
                    Ok(()) => HomingState::Done,
                    Err(_) => HomingState::Failed(HomingFailure::Refused),
                },
            ),
            HomingStep::Failed(e) => Some(HomingState::Failed(e.into())),
        };
        match end {
            None => self.homing = Some(run),
            Some(state) => self.end_homing(ctx, state, &run.saved),
        }
    }

    /// Post a homing command the drive's rules take; false when refused.
    fn post_checked<C: DeviceContext>(&mut self, ctx: &mut C, cmd: Command, l: &Limits) -> bool {
        let ok = ctx.status().check_command(&cmd, l).is_ok() && ctx.post(cmd).is_ok();
        if ok {
            self.posted(cmd);
        }
        ok
    }

    /// The homing ended: a failure disables the bridge and puts the joint
    /// (`saved`) back as it was.
    fn end_homing<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        state: HomingState,
        saved: &JointSetup,
    ) {
        self.homing = None;
        self.homing_state = state;
        if matches!(state, HomingState::Failed(_)) {
            // Disable is always taken.
            let _ = ctx.post(Command::Disable);
            let _ = ctx.set_joint(*saved);
        }
    }
}

/// A sequencer's refusal of a request as a Nack.
fn homing_refusal(h: &HomingStart, e: HomingError) -> ErrorCode {
    match e {
        HomingError::Invalid(c) => command_refusal(h, c),
        HomingError::NoStop | HomingError::Interrupted => ErrorCode::Busy,
    }
}

/// A command error of the search (its check or its first command) as a
/// Nack: the drive's state codes, else the end stop's field.
fn command_refusal(h: &HomingStart, e: CommandError) -> ErrorCode {
    match (e, h.method) {
        (CommandError::Faulted, _) => ErrorCode::Faulted,
        (CommandError::Busy, _) => ErrorCode::Busy,
        (CommandError::NotCalibrated, _) => ErrorCode::NotCalibrated,
        (CommandError::NeedsAngleSensor, _) => ErrorCode::NeedsAngleSensor,
        (e, HomingMethod::EndStop(stop)) => ErrorCode::OutOfRange {
            field: end_stop_field(&stop, e),
        },
        (_, HomingMethod::Present) => ErrorCode::OutOfRange { field: 1 },
    }
}
