//! The power state machine's pure parts (CiA 402 §6.2): controlword
//! commands, the transition table and the statusword's state bits.
//!
//! ```
//! use foc_canopen::cia402::state::{decode, next, CwCommand};
//! use foc_canopen::cia402::State;
//! assert_eq!(decode(0x0006), Some(CwCommand::Shutdown));
//! assert_eq!(next(State::SwitchOnDisabled, CwCommand::Shutdown), Some(State::ReadyToSwitchOn));
//! assert_eq!(next(State::SwitchOnDisabled, CwCommand::EnableOperation), None);
//! ```

use super::State;

/// Controlword bit 7: fault reset (rising edge).
pub const CW_FAULT_RESET: u16 = 1 << 7;
/// Controlword bit 4 (pp): new set-point (rising edge).
pub const CW_NEW_SETPOINT: u16 = 1 << 4;
/// Controlword bit 5 (pp): change set immediately.
pub const CW_CHANGE_IMMEDIATELY: u16 = 1 << 5;
/// Controlword bit 6 (pp): relative target.
pub const CW_RELATIVE: u16 = 1 << 6;
/// Controlword bit 8: halt.
pub const CW_HALT: u16 = 1 << 8;

/// A device control command of the controlword (bits 0..3 and 7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CwCommand {
    /// `0xxx x110`: transitions 2, 6, 8.
    Shutdown,
    /// `0xxx 0111`: transition 3, and 5 (disable operation) from enabled.
    SwitchOn,
    /// `0xxx 1111`: transitions 4, 16 (and 3 + 4 from ready).
    EnableOperation,
    /// `0xxx xx0x`: transitions 7, 9, 10, 12.
    DisableVoltage,
    /// `0xxx x01x`: transitions 7, 10, 11.
    QuickStop,
}

/// The command in a controlword (`None` with bit 7 set: a fault reset
/// takes precedence and is handled on its edge).
pub const fn decode(cw: u16) -> Option<CwCommand> {
    if cw & CW_FAULT_RESET != 0 {
        return None;
    }
    Some(if cw & 0x02 == 0 {
        CwCommand::DisableVoltage
    } else if cw & 0x04 == 0 {
        CwCommand::QuickStop
    } else if cw & 0x01 == 0 {
        CwCommand::Shutdown
    } else if cw & 0x08 == 0 {
        CwCommand::SwitchOn
    } else {
        CwCommand::EnableOperation
    })
}

/// The state a command leads to from `s`, `None` when the table has no
/// such transition (the state stays). Quick stop active -> operation
/// enabled (16) is allowed here; the caller refuses it for the quick stop
/// options that end in switch on disabled.
pub const fn next(s: State, c: CwCommand) -> Option<State> {
    use CwCommand as C;
    use State as S;
    match (s, c) {
        (S::SwitchOnDisabled, C::Shutdown) => Some(S::ReadyToSwitchOn), // 2
        (S::ReadyToSwitchOn, C::SwitchOn) => Some(S::SwitchedOn),       // 3
        (S::ReadyToSwitchOn, C::EnableOperation) => Some(S::OperationEnabled), // 3 + 4
        (S::ReadyToSwitchOn, C::DisableVoltage | C::QuickStop) => Some(S::SwitchOnDisabled), // 7
        (S::SwitchedOn, C::EnableOperation) => Some(S::OperationEnabled), // 4
        (S::SwitchedOn, C::Shutdown) => Some(S::ReadyToSwitchOn),       // 6
        (S::SwitchedOn, C::DisableVoltage | C::QuickStop) => Some(S::SwitchOnDisabled), // 10
        (S::OperationEnabled, C::SwitchOn) => Some(S::SwitchedOn),      // 5
        (S::OperationEnabled, C::Shutdown) => Some(S::ReadyToSwitchOn), // 8
        (S::OperationEnabled, C::DisableVoltage) => Some(S::SwitchOnDisabled), // 9
        (S::OperationEnabled, C::QuickStop) => Some(S::QuickStopActive), // 11
        (S::QuickStopActive, C::DisableVoltage) => Some(S::SwitchOnDisabled), // 12
        (S::QuickStopActive, C::EnableOperation) => Some(S::OperationEnabled), // 16
        _ => None,
    }
}

/// The statusword's state bits (0, 1, 2, 3, 5, 6) of a state. Bit 5
/// (quick stop, active low) is 0 in not ready to switch on and switch on
/// disabled; in fault reaction active and fault it shows `quick_stop_bit`
/// (controlword bit 2: 1 = no quick stop asked).
pub const fn state_bits(s: State, quick_stop_bit: bool) -> u16 {
    let qs = if quick_stop_bit { 0x20 } else { 0 };
    match s {
        State::NotReadyToSwitchOn => 0,
        State::SwitchOnDisabled => 0x40,
        State::ReadyToSwitchOn => 0x21,
        State::SwitchedOn => 0x23,
        State::OperationEnabled => 0x27,
        State::QuickStopActive => 0x07,
        State::FaultReactionActive => 0x0F | qs,
        State::Fault => 0x08 | qs,
    }
}
