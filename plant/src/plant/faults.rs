//! What can be broken on purpose: phases, shorts, the encoder, a current
//! channel.

use super::*;

/// One of the three phases.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Phase A.
    A,
    /// Phase B.
    B,
    /// Phase C.
    C,
}

impl Phase {
    /// Index 0, 1, 2.
    pub const fn index(self) -> usize {
        match self {
            Phase::A => 0,
            Phase::B => 1,
            Phase::C => 2,
        }
    }
}

/// A short between two motor terminals (through `r_ohm`, switches included).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseShort {
    /// First phase.
    pub a: Phase,
    /// Second phase.
    pub b: Phase,
    /// Resistance of the short \[ohm\].
    pub r_ohm: Real,
}

/// Encoder fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum EncoderFault {
    /// Healthy.
    #[default]
    None,
    /// The reading freezes at its last value.
    Stuck,
    /// The reading is offset by this many counts (set it once: a jump).
    Jump(i32),
}

/// Fault injection hooks (all off by default). Change them any time through
/// [`Plant::faults_mut`]; they act from the next sub-step / sample.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Faults {
    /// Phase-to-phase short at the motor terminals. The two terminals see the
    /// mean of their two bridge voltages; the legs carry the extra current
    /// `(v_a - v_b) / r_ohm` (measured by the shunts, drawn from the bus).
    pub phase_short: Option<PhaseShort>,
    /// A phase lead disconnected (its current is zero; the others carry all).
    pub disconnected_phase: Option<Phase>,
    /// Drop of the source voltage \[V\].
    pub bus_sag_v: Real,
    /// Encoder fault.
    pub encoder: EncoderFault,
    /// Encoder counts the wrong way.
    pub encoder_reversed: bool,
    /// This current channel reads NaN.
    pub nan_current: Option<Phase>,
    /// This current channel is wired with the wrong sign.
    pub current_reversed: Option<Phase>,
    /// Extra offset on each current channel, e.g. after calibration \[A\].
    pub current_offset_error_a: [Real; 3],
}
