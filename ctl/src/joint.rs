//! Robot joints over the link (design §21): the joint's settings, homing,
//! and how `foc-ctl` shows them.
//!
//! Frames ([`foc_protocol::joint`]): positions, velocities, torques and
//! stiffnesses of commands and telemetry are the **output**'s (after the
//! gearbox); the motor's limits and the joint's rotor-side settings are the
//! **rotor**'s. Every text here says which.

use crate::{describe_error, Client, ClientError};
use foc_protocol::message::{
    ErrorCode, HomingStart, HomingState, JointSettings, Request, Response, Telemetry,
};
use std::time::{Duration, Instant};

/// How often [`Client::home`] asks how homing stands.
pub const HOMING_POLL: Duration = Duration::from_millis(50);

impl Client {
    /// Set the joint up (frame, travel range, soft stop, impedance entry
    /// and timeout).
    pub fn set_joint(&mut self, j: JointSettings) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetJoint(j))
    }

    /// The joint in force.
    pub fn joint(&mut self) -> Result<JointSettings, ClientError> {
        match self.request(&Request::ReadJoint)? {
            Response::Joint(j) => Ok(j),
            r => Err(ClientError::Unexpected(r)),
        }
    }

    /// Start homing (Ack: started; the present position: done).
    pub fn start_homing(&mut self, h: HomingStart) -> Result<(), ClientError> {
        self.expect_ack(&Request::StartHoming(h))
    }

    /// Where homing stands.
    pub fn homing_state(&mut self) -> Result<HomingState, ClientError> {
        match self.request(&Request::ReadHoming)? {
            Response::Homing(s) => Ok(s),
            r => Err(ClientError::Unexpected(r)),
        }
    }

    /// Start homing and wait (at most `timeout`) until it is no longer
    /// running, calling `progress` with a telemetry sample (output frame)
    /// every [`HOMING_POLL`] while it runs. Returns how it ended
    /// ([`HomingState::Running`] on a timeout).
    pub fn home(
        &mut self,
        h: HomingStart,
        timeout: Duration,
        mut progress: impl FnMut(&Telemetry),
    ) -> Result<HomingState, ClientError> {
        self.start_homing(h)?;
        let end = Instant::now() + timeout;
        loop {
            let state = self.homing_state()?;
            if state != HomingState::Running || Instant::now() >= end {
                return Ok(state);
            }
            progress(&self.read_telemetry()?);
            std::thread::sleep(HOMING_POLL);
        }
    }
}

/// Changes to a joint's settings (`None`: keep the value in force).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct JointEdit {
    /// Rotor turns per output turn (signed).
    pub gear_ratio: Option<f32>,
    /// Rotor position at output 0 [rad, rotor].
    pub rotor_at_zero_rad: Option<f32>,
    /// Travel range [rad, output]: `Some(None)` removes it.
    pub travel_out_rad: Option<Option<(f32, f32)>>,
    /// Fault margin [rad, rotor].
    pub fault_margin_rad: Option<f32>,
    /// Soft stop's deceleration [rad/s^2, rotor].
    pub brake_accel_rad_s2: Option<f32>,
    /// Soft stop's gain [A/(rad/s), rotor].
    pub kv_a_per_rad_s: Option<f32>,
    /// Impedance entry blend [current-loop periods].
    pub entry_blend_periods: Option<u32>,
    /// Least damping after an impedance timeout [N m s/rad, rotor].
    pub timeout_kd_nm_s_per_rad: Option<f32>,
}

impl JointEdit {
    /// True when nothing is changed.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// `j` with these changes.
    pub fn apply(&self, j: JointSettings) -> JointSettings {
        JointSettings {
            gear_ratio: self.gear_ratio.unwrap_or(j.gear_ratio),
            rotor_at_zero_rad: self.rotor_at_zero_rad.unwrap_or(j.rotor_at_zero_rad),
            travel_out_rad: self.travel_out_rad.unwrap_or(j.travel_out_rad),
            fault_margin_rad: self.fault_margin_rad.unwrap_or(j.fault_margin_rad),
            brake_accel_rad_s2: self.brake_accel_rad_s2.unwrap_or(j.brake_accel_rad_s2),
            kv_a_per_rad_s: self.kv_a_per_rad_s.unwrap_or(j.kv_a_per_rad_s),
            entry_blend_periods: self.entry_blend_periods.unwrap_or(j.entry_blend_periods),
            timeout_kd_nm_s_per_rad: self
                .timeout_kd_nm_s_per_rad
                .unwrap_or(j.timeout_kd_nm_s_per_rad),
        }
    }
}

/// A joint's settings, one per line, each with its unit and frame.
pub fn joint_text(j: &JointSettings) -> String {
    let direction = if j.gear_ratio < 0.0 {
        "reversed"
    } else {
        "same direction"
    };
    let travel = match j.travel_out_rad {
        Some((lo, hi)) => format!("{lo} .. {hi} rad (output)"),
        None => "none (the motor's position range, rotor)".into(),
    };
    [
        format!(
            "gear ratio     {} (rotor turns per output turn, {direction})",
            j.gear_ratio
        ),
        format!(
            "home offset    {} rad (rotor position at output 0)",
            j.rotor_at_zero_rad
        ),
        format!("travel         {travel}"),
        format!("fault margin   {} rad (rotor)", j.fault_margin_rad),
        format!("brake accel    {} rad/s^2 (rotor)", j.brake_accel_rad_s2),
        format!("soft-stop kv   {} A/(rad/s) (rotor)", j.kv_a_per_rad_s),
        format!(
            "entry blend    {} current-loop periods",
            j.entry_blend_periods
        ),
        format!(
            "timeout kd     {} N m s/rad (rotor)",
            j.timeout_kd_nm_s_per_rad
        ),
    ]
    .join("\n")
}

/// How homing stands, in words.
pub fn homing_text(s: HomingState) -> String {
    match s {
        HomingState::Idle => "not homed since the drive started".into(),
        HomingState::Running => "running".into(),
        HomingState::Done => "done (the output frame is set)".into(),
        HomingState::Failed(f) => format!("failed: {}", f.text()),
    }
}

/// A Nack of `req` in words, naming the field an out-of-range one points at.
pub fn nack_text(req: &Request, e: ErrorCode) -> String {
    if let ErrorCode::OutOfRange { field } = e {
        if let Some(name) = req.field_name(field) {
            return format!("field {field} (`{name}`) invalid or out of range; nothing changed");
        }
    }
    format!("{}; nothing changed", describe_error(e))
}

/// An error of `req` in words ([`nack_text`] for a Nack).
pub fn error_text(req: &Request, e: &ClientError) -> String {
    match e {
        ClientError::Nack(code) => format!("refused by the device: {}", nack_text(req, *code)),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use foc_core::control::joint::Impedance;
    use foc_core::control::Command;

    #[test]
    fn an_edit_changes_only_what_it_names() {
        let j = JointSettings::from_setup(&foc_protocol::joint::NO_JOINT);
        let e = JointEdit {
            gear_ratio: Some(-20.0),
            travel_out_rad: Some(Some((-1.0, 1.0))),
            ..JointEdit::default()
        };
        let k = e.apply(j);
        assert_eq!(k.gear_ratio, -20.0);
        assert_eq!(k.travel_out_rad, Some((-1.0, 1.0)));
        assert_eq!(k.rotor_at_zero_rad, j.rotor_at_zero_rad);
        assert!(JointEdit::default().is_empty() && !e.is_empty());
        assert!(joint_text(&k).contains("-1 .. 1 rad (output)"));
        assert!(joint_text(&k).contains("reversed"));
    }

    #[test]
    fn nacks_name_the_field() {
        let r = Request::SetCommand(Command::Impedance(Impedance::default()));
        assert!(nack_text(&r, ErrorCode::OutOfRange { field: 3 }).contains("`kp_nm_per_rad`"));
        assert!(nack_text(&r, ErrorCode::NotCalibrated).contains("not calibrated"));
    }
}
