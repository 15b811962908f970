//! SDO abort codes (CiA 301 §7.2.4.3.17, table 22).

/// Why an SDO transfer (or an object write) was refused. The discriminant
/// is the 32-bit abort code sent on the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u32)]
pub enum Abort {
    /// Toggle bit not alternated.
    ToggleBit = 0x0503_0000,
    /// SDO protocol timed out.
    Timeout = 0x0504_0000,
    /// Client/server command specifier not valid or unknown.
    InvalidCommand = 0x0504_0001,
    /// Out of memory.
    OutOfMemory = 0x0504_0005,
    /// Unsupported access to an object.
    UnsupportedAccess = 0x0601_0000,
    /// Attempt to read a write-only object.
    WriteOnly = 0x0601_0001,
    /// Attempt to write a read-only object.
    ReadOnly = 0x0601_0002,
    /// Object does not exist in the object dictionary.
    NoObject = 0x0602_0000,
    /// Object cannot be mapped to the PDO.
    NotMappable = 0x0604_0041,
    /// The number and length of the objects to be mapped would exceed the PDO length.
    PdoTooLong = 0x0604_0042,
    /// General parameter incompatibility.
    ParamIncompatible = 0x0604_0043,
    /// General internal incompatibility in the device.
    DeviceIncompatible = 0x0604_0047,
    /// Access failed due to a hardware error (e.g. the store failed).
    Hardware = 0x0606_0000,
    /// Data type does not match, length of service parameter does not match.
    LengthMismatch = 0x0607_0010,
    /// Data type does not match, length of service parameter too high.
    TooLong = 0x0607_0012,
    /// Data type does not match, length of service parameter too low.
    TooShort = 0x0607_0013,
    /// Sub-index does not exist.
    NoSubIndex = 0x0609_0011,
    /// Invalid value for parameter (download only).
    InvalidValue = 0x0609_0030,
    /// Value of parameter written too high.
    ValueTooHigh = 0x0609_0031,
    /// Value of parameter written too low.
    ValueTooLow = 0x0609_0032,
    /// General error.
    General = 0x0800_0000,
    /// Data cannot be transferred or stored to the application.
    CannotStore = 0x0800_0020,
    /// ... because of local control.
    LocalControl = 0x0800_0021,
    /// ... because of the present device state.
    DeviceState = 0x0800_0022,
    /// No data available (the device does not have this value).
    NoData = 0x0800_0024,
}

impl Abort {
    /// The 32-bit code sent on the bus.
    pub const fn code(self) -> u32 {
        self as u32
    }
}
