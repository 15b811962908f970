//! The object dictionary's metadata: one const table ([`OBJECTS`]) holding
//! every object and sub-object the node has (index, sub-index, names, data
//! type, access, PDO mapping, limits, default, object kind), and the
//! helpers that turn bytes into values and back.
//!
//! The values themselves live where they are used: the communication
//! parameters in the node, the profile's in [`crate::cia402::Cia402`]'s
//! fields, the drive's in the [`foc_protocol::device::DeviceContext`].
//! The same table drives the SDO server's checks, the PDO mapping checks
//! and the EDS writer ([`crate::eds`]).
//!
//! ```
//! use foc_canopen::od::{find, DataType};
//! let def = find(0x6040, 0).unwrap();
//! assert_eq!(def.data_type, DataType::Unsigned16);
//! assert!(def.pdo_mappable);
//! ```

mod table;

pub use table::OBJECTS;
pub(crate) use table::{RPDO_DEFAULT, TPDO_DEFAULT};

use crate::Abort;

/// CANopen basic data types (CiA 301 table 44), with their DataType index.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DataType {
    /// BOOLEAN (0x0001), one byte 0 or 1.
    Boolean,
    /// INTEGER8 (0x0002).
    Integer8,
    /// INTEGER16 (0x0003).
    Integer16,
    /// INTEGER32 (0x0004).
    Integer32,
    /// UNSIGNED8 (0x0005).
    Unsigned8,
    /// UNSIGNED16 (0x0006).
    Unsigned16,
    /// UNSIGNED32 (0x0007).
    Unsigned32,
    /// REAL32 (0x0008), IEEE 754 single.
    Real32,
    /// VISIBLE_STRING (0x0009).
    VisibleString,
}

impl DataType {
    /// The DataType object index (EDS `DataType=`).
    pub const fn code(self) -> u16 {
        match self {
            Self::Boolean => 0x0001,
            Self::Integer8 => 0x0002,
            Self::Integer16 => 0x0003,
            Self::Integer32 => 0x0004,
            Self::Unsigned8 => 0x0005,
            Self::Unsigned16 => 0x0006,
            Self::Unsigned32 => 0x0007,
            Self::Real32 => 0x0008,
            Self::VisibleString => 0x0009,
        }
    }

    /// Size in bytes of a numeric type (0 for a string: variable).
    pub const fn size(self) -> usize {
        match self {
            Self::Boolean | Self::Integer8 | Self::Unsigned8 => 1,
            Self::Integer16 | Self::Unsigned16 => 2,
            Self::Integer32 | Self::Unsigned32 | Self::Real32 => 4,
            Self::VisibleString => 0,
        }
    }

    /// The full range of an integer type (`None` for REAL32 and strings).
    pub const fn int_range(self) -> Option<(i64, i64)> {
        match self {
            Self::Boolean => Some((0, 1)),
            Self::Integer8 => Some((i8::MIN as i64, i8::MAX as i64)),
            Self::Integer16 => Some((i16::MIN as i64, i16::MAX as i64)),
            Self::Integer32 => Some((i32::MIN as i64, i32::MAX as i64)),
            Self::Unsigned8 => Some((0, u8::MAX as i64)),
            Self::Unsigned16 => Some((0, u16::MAX as i64)),
            Self::Unsigned32 => Some((0, u32::MAX as i64)),
            Self::Real32 | Self::VisibleString => None,
        }
    }
}

/// Access rights (EDS `AccessType=`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Access {
    /// Read only (may change: actual values).
    Ro,
    /// Write only.
    Wo,
    /// Read and write.
    Rw,
    /// Read only, never changes.
    Const,
}

impl Access {
    /// True if an SDO upload may read it.
    pub const fn readable(self) -> bool {
        !matches!(self, Self::Wo)
    }
    /// True if an SDO download may write it.
    pub const fn writable(self) -> bool {
        matches!(self, Self::Wo | Self::Rw)
    }
    /// The EDS spelling.
    pub const fn eds(self) -> &'static str {
        match self {
            Self::Ro => "ro",
            Self::Wo => "wo",
            Self::Rw => "rw",
            Self::Const => "const",
        }
    }
}

/// Object code (EDS `ObjectType=`); compound objects carry their highest
/// sub-index (the value of sub 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Kind {
    /// A single value (0x7), sub-index 0.
    Var,
    /// An array (0x8): sub 0 = highest sub-index, subs of one type.
    Array(u8),
    /// A record (0x9): sub 0 = highest sub-index, subs of any type.
    Record(u8),
}

impl Kind {
    /// The EDS object code.
    pub const fn code(self) -> u8 {
        match self {
            Self::Var => 0x7,
            Self::Array(_) => 0x8,
            Self::Record(_) => 0x9,
        }
    }
}

/// Default value of an object, as the EDS states it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Default {
    /// A number.
    Int(i64),
    /// A REAL32 number.
    Real(f32),
    /// A COB-ID relative to the node id: `$NODEID+base`.
    NodeId(u32),
    /// A string.
    Str(&'static str),
    /// Given by the device at run time (identity, calibration, actual
    /// values): no fixed default.
    Device,
}

/// One object or sub-object of the dictionary.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObjectDef {
    /// Index.
    pub index: u16,
    /// Sub-index (0 for a VAR).
    pub sub: u8,
    /// The object's name (for a compound, the parent's name).
    pub object: &'static str,
    /// The sub-object's name (the object's own for a VAR).
    pub name: &'static str,
    /// Object kind (the same on every sub of a compound).
    pub kind: Kind,
    /// Data type.
    pub data_type: DataType,
    /// Access.
    pub access: Access,
    /// May be mapped into a PDO (RPDO when writable, TPDO when readable).
    pub pdo_mappable: bool,
    /// Inclusive limits of an integer value (`None`: the type's range).
    pub limits: Option<(i64, i64)>,
    /// Default value.
    pub default: Default,
}

impl ObjectDef {
    /// The limits in force: the table's, else the type's full range.
    pub const fn range(&self) -> Option<(i64, i64)> {
        match self.limits {
            Some(l) => Some(l),
            None => self.data_type.int_range(),
        }
    }
    /// The PDO mapping entry of this object: `index << 16 | sub << 8 | bits`.
    pub const fn mapping(&self) -> u32 {
        ((self.index as u32) << 16) | ((self.sub as u32) << 8) | (self.data_type.size() as u32 * 8)
    }
}

/// The definition of `index`/`sub`: `Err(NoObject)` when the index is
/// missing, `Err(NoSubIndex)` when only the sub-index is.
pub fn lookup(index: u16, sub: u8) -> Result<&'static ObjectDef, Abort> {
    let mut any = false;
    for d in OBJECTS {
        if d.index == index {
            any = true;
            if d.sub == sub {
                return Ok(d);
            }
        }
    }
    Err(if any {
        Abort::NoSubIndex
    } else {
        Abort::NoObject
    })
}

/// The definition of `index`/`sub`, if any.
pub fn find(index: u16, sub: u8) -> Option<&'static ObjectDef> {
    lookup(index, sub).ok()
}

/// A decoded value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    /// Any integer type (and BOOLEAN as 0 / 1).
    Int(i64),
    /// REAL32.
    Real(f32),
}

impl Value {
    /// The integer, or 0 for a real.
    pub const fn int(self) -> i64 {
        match self {
            Self::Int(v) => v,
            Self::Real(_) => 0,
        }
    }
}

/// Bytes of an object's value (up to [`Data::CAPACITY`]: the longest
/// string of the dictionary).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Data {
    buf: [u8; Data::CAPACITY],
    len: u8,
}

impl Data {
    /// The largest value in bytes.
    pub const CAPACITY: usize = 32;

    /// Empty.
    pub const fn empty() -> Self {
        Self {
            buf: [0; Self::CAPACITY],
            len: 0,
        }
    }

    /// From bytes (truncated to [`Self::CAPACITY`]).
    pub fn from_bytes(b: &[u8]) -> Self {
        let mut d = Self::empty();
        for (dst, src) in d.buf.iter_mut().zip(b) {
            *dst = *src;
        }
        d.len = b.len().min(Self::CAPACITY) as u8;
        d
    }

    /// Append a byte; false when full.
    pub fn push(&mut self, b: u8) -> bool {
        match self.buf.get_mut(usize::from(self.len)) {
            Some(slot) => {
                *slot = b;
                self.len += 1;
                true
            }
            None => false,
        }
    }

    /// The bytes.
    pub fn bytes(&self) -> &[u8] {
        self.buf.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

impl core::fmt::Write for Data {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for b in s.bytes() {
            if !self.push(b) {
                return Err(core::fmt::Error);
            }
        }
        Ok(())
    }
}

/// Decode `bytes` as a value of type `ty`: the length must be the type's
/// ([`Abort::TooLong`] / [`Abort::TooShort`]); strings are not decoded
/// ([`Abort::UnsupportedAccess`]: none is writable).
pub fn decode(ty: DataType, bytes: &[u8]) -> Result<Value, Abort> {
    let n = ty.size();
    if n == 0 {
        return Err(Abort::UnsupportedAccess);
    }
    if bytes.len() > n {
        return Err(Abort::TooLong);
    }
    if bytes.len() < n {
        return Err(Abort::TooShort);
    }
    let mut b = [0u8; 4];
    for (dst, src) in b.iter_mut().zip(bytes) {
        *dst = *src;
    }
    let [b0, b1, ..] = b;
    Ok(match ty {
        DataType::Boolean | DataType::Unsigned8 => Value::Int(i64::from(b0)),
        DataType::Integer8 => Value::Int(i64::from(b0 as i8)),
        DataType::Integer16 => Value::Int(i64::from(i16::from_le_bytes([b0, b1]))),
        DataType::Unsigned16 => Value::Int(i64::from(u16::from_le_bytes([b0, b1]))),
        DataType::Integer32 => Value::Int(i64::from(i32::from_le_bytes(b))),
        DataType::Unsigned32 => Value::Int(i64::from(u32::from_le_bytes(b))),
        DataType::Real32 => Value::Real(f32::from_le_bytes(b)),
        DataType::VisibleString => return Err(Abort::UnsupportedAccess),
    })
}

/// Encode a value as type `ty` (little endian; integers truncated to the
/// type's width).
pub fn encode(ty: DataType, v: Value) -> Data {
    let raw: [u8; 4] = match v {
        Value::Int(i) => (i as u32).to_le_bytes(),
        Value::Real(r) => r.to_le_bytes(),
    };
    Data::from_bytes(raw.get(..ty.size()).unwrap_or(&[]))
}

/// Check a decoded value against the object's limits:
/// [`Abort::ValueTooHigh`] / [`Abort::ValueTooLow`]; a REAL32 must be
/// finite ([`Abort::InvalidValue`]).
pub fn check_range(def: &ObjectDef, v: Value) -> Result<(), Abort> {
    match v {
        Value::Int(i) => match def.range() {
            Some((lo, _)) if i < lo => Err(Abort::ValueTooLow),
            Some((_, hi)) if i > hi => Err(Abort::ValueTooHigh),
            _ => Ok(()),
        },
        Value::Real(r) if !r.is_finite() => Err(Abort::InvalidValue),
        Value::Real(_) => Ok(()),
    }
}

/// Decode and range-check a download for `def` (the access is checked by
/// the caller).
pub fn parse(def: &ObjectDef, bytes: &[u8]) -> Result<Value, Abort> {
    let v = decode(def.data_type, bytes)?;
    check_range(def, v)?;
    Ok(v)
}
