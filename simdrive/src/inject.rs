//! Faults to inject into the plant or its sensors (the CAN test bus's
//! control channel, `foc-ctl simulate`'s tests).

use crate::HostDrive;
use foc_bench::plant::{EncoderFault, Faults, Phase, PhaseShort};

/// A fault to inject into the plant or its sensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// `encoder`: the encoder reading freezes (a broken encoder): at 100
    /// rad/s the drive latches `AngleSensorStuck` within about 450 periods.
    EncoderStuck,
    /// `short` (or `overcurrent`): a phase-to-phase short A-B at the motor
    /// terminals through 10 mohm: `OverCurrentPhase` within 2 periods.
    PhaseShort,
    /// `open-phase`: phase C's lead disconnected (the drive has no
    /// open-phase detection in sensor modes: unloaded, nothing latches).
    OpenPhase,
    /// `nan-current`: the phase A current channel reads NaN: `NonFinite`
    /// at once.
    NanCurrent,
    /// `clear`: every injected fault removed (the drive's latched faults
    /// stay until cleared).
    Clear,
}

impl FaultKind {
    /// From its control-channel name.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "encoder" | "encoder-stuck" => Self::EncoderStuck,
            "short" | "overcurrent" | "over-current" => Self::PhaseShort,
            "open-phase" => Self::OpenPhase,
            "nan-current" => Self::NanCurrent,
            "clear" => Self::Clear,
            _ => return None,
        })
    }
}

impl HostDrive {
    /// Inject a fault into the plant or its sensors.
    pub fn inject(&mut self, kind: FaultKind) {
        let f = self.sim.plant.faults_mut();
        match kind {
            FaultKind::EncoderStuck => f.encoder = EncoderFault::Stuck,
            FaultKind::PhaseShort => {
                f.phase_short = Some(PhaseShort {
                    a: Phase::A,
                    b: Phase::B,
                    r_ohm: 0.01,
                })
            }
            FaultKind::OpenPhase => f.disconnected_phase = Some(Phase::C),
            FaultKind::NanCurrent => f.nan_current = Some(Phase::A),
            FaultKind::Clear => *f = Faults::default(),
        }
    }
}
