//! [`View`]: what the link reads (mode, faults, limits, parameters,
//! telemetry) from a snapshot and the configuration in force.

use crate::service::Service;
use crate::snapshot::Snapshot;
use foc_core::control::joint::JointSetup;
use foc_core::control::{Fault, FaultSet, Feedback, Limits, Mode};
use foc_core::drive::Status;
use foc_protocol::message::{ParamId, Telemetry};

/// A read-only view of one drive (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct View<'a> {
    /// The shared state when the frame arrived.
    pub snap: &'a Snapshot,
    /// The service (configuration in force, board).
    pub service: &'a Service,
}

impl View<'_> {
    /// The drive's mode.
    pub fn mode(&self) -> Mode {
        self.snap.status.mode
    }
    /// Latched faults and the first of them.
    pub fn faults(&self) -> (FaultSet, Option<Fault>) {
        (self.snap.feedback.faults, self.snap.feedback.first_fault)
    }
    /// The motor's limits in force.
    pub fn limits(&self) -> Limits {
        self.service.settings().limits
    }
    /// The joint in force.
    pub fn joint(&self) -> JointSetup {
        self.service.settings().joint
    }
    /// The motor model's torque constant [N m / A].
    pub fn torque_constant_nm_per_a(&self) -> f32 {
        self.service
            .settings()
            .current
            .motor
            .torque_constant_nm_per_a()
    }
    /// The latest feedback.
    pub fn feedback(&self) -> Feedback {
        self.snap.feedback
    }
    /// The drive holds a calibration.
    pub fn is_calibrated(&self) -> bool {
        self.snap.status.calibrated
    }
    /// The drive's status.
    pub fn status(&self) -> Status {
        self.snap.status
    }
    /// A parameter's value (`None`: answered by the protocol itself).
    pub fn param(&self, id: ParamId) -> Option<f32> {
        let s = self.service.settings();
        let board = self.service.board();
        let m = s.current.motor;
        Some(match id {
            ParamId::PolePairs => f32::from(m.pole_pairs),
            ParamId::ResistanceOhm => m.r_ohm,
            ParamId::LdH => m.ld_h,
            ParamId::LqH => m.lq_h,
            ParamId::FluxLinkageWb => m.flux_linkage_wb,
            ParamId::PwmFrequencyHz => board.pwm_hz as f32,
            ParamId::SpeedDivider => f32::from(s.dividers.0),
            ParamId::PositionDivider => f32::from(s.dividers.1),
            ParamId::FirmwareVersion => {
                let [a, b, c] = board.firmware_version;
                f32::from(a) * 10_000.0 + f32::from(b) * 100.0 + f32::from(c)
            }
            ParamId::BusVoltageV => self.snap.feedback.v_bus_v,
            ParamId::Calibrated => f32::from(u8::from(self.snap.status.calibrated)),
            ParamId::MaxLoopCycles => self.snap.max_loop_cycles as f32,
            ParamId::CurrentKp => s.current.q_gains.kp_v_per_a,
            ParamId::CurrentKi => s.current.q_gains.ki_v_per_a_s,
            ParamId::SpeedKp => s.speed.kp_a_per_rad_s,
            ParamId::SpeedKi => s.speed.ki_a_per_rad,
            ParamId::PositionKp => s.position.kp_per_s,
            ParamId::ScopeCapacity => board.scope_values as f32,
            ParamId::AngleSource => f32::from(self.angle_source()),
            ParamId::BoardMaxCurrentA => board.max_current_a,
            ParamId::MaxCurrentA
            | ParamId::MaxVelocityRadS
            | ParamId::MinPositionRad
            | ParamId::MaxPositionRad
            | ParamId::MaxOpenLoopVoltageV
            | ParamId::MaxOpenLoopOmegaERadS
            | ParamId::MaxImpedanceKp
            | ParamId::MaxImpedanceKd => self.limit_in_force(id),
            ParamId::CalibrationStep => {
                f32::from(foc_protocol::message::progress_codes(self.snap.status.calibration).0)
            }
            ParamId::CalibrationResult => {
                f32::from(foc_protocol::message::progress_codes(self.snap.status.calibration).1)
            }
            ParamId::FieldWeakening => f32::from(u8::from(s.field.field_weakening)),
            ParamId::Mtpa => f32::from(u8::from(s.field.mtpa)),
            ParamId::MaxIdA => s.field.max_id_a,
            ParamId::ShortCircuit => f32::from(u8::from(s.field.short_circuit)),
            ParamId::Anticogging => f32::from(u8::from(self.service.tables().cogging.enabled)),
            ParamId::EncoderLinearisation => {
                f32::from(u8::from(self.service.tables().angle_correction.enabled))
            }
            ParamId::AnticoggingPeakA => self.service.tables().cogging.peak_a(),
            ParamId::EncoderCorrectionPeakRad => self.service.tables().angle_correction.peak_rad(),
            // Answered by the protocol layer itself.
            ParamId::ProtocolVersion | ParamId::TelemetryDivider | ParamId::WatchdogTimeout => {
                return None
            }
        })
    }
    /// One of the limits in force (commands are checked against them).
    fn limit_in_force(&self, id: ParamId) -> f32 {
        let s = self.service.settings();
        let l = foc_protocol::joint::limits_in_force(&s.limits, &s.joint);
        match id {
            ParamId::MaxCurrentA => l.max_current_a,
            ParamId::MaxVelocityRadS => l.max_velocity_rad_s,
            ParamId::MinPositionRad => l.min_position_rad,
            ParamId::MaxPositionRad => l.max_position_rad,
            ParamId::MaxOpenLoopVoltageV => l.max_open_loop_voltage_v,
            ParamId::MaxOpenLoopOmegaERadS => l.max_open_loop_omega_e_rad_s,
            ParamId::MaxImpedanceKp => l.max_kp_nm_per_rad,
            _ => l.max_kd_nm_s_per_rad,
        }
    }
    /// [`ParamId::AngleSource`]: the feedback's angle in use, consistent
    /// with the status (without the sensor: sensorless or limp-home).
    fn angle_source(&self) -> u8 {
        use foc_core::control::AngleInUse;
        let a = self.snap.feedback.angle_in_use;
        match (self.snap.status.sensorless, a) {
            (true, AngleInUse::LimpHome) => AngleInUse::LimpHome.code(),
            (true, _) => AngleInUse::Sensorless.code(),
            (false, AngleInUse::Observer) => AngleInUse::Observer.code(),
            (false, _) => AngleInUse::Sensor.code(),
        }
    }

    /// One telemetry sample.
    pub fn telemetry(&self) -> Telemetry {
        Telemetry::from_feedback(&self.snap.feedback, self.snap.max_loop_cycles)
    }
    /// The firmware's version.
    pub fn firmware_version(&self) -> [u8; 3] {
        self.service.board().firmware_version
    }
    /// Highest telemetry rate the link carries \[Hz\].
    pub fn max_stream_hz(&self) -> Option<f32> {
        self.service.board().max_stream_hz
    }
}
