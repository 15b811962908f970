//! A classic CAN data frame with an 11-bit identifier (CANopen's pre-defined
//! connection set uses standard identifiers only), and the conversions to
//! and from any [`embedded_can::Frame`].

use embedded_can::{Frame, Id, StandardId};

/// A classic CAN frame: 11-bit identifier, up to 8 data bytes, or a remote
/// request of `len` bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CanFrame {
    /// 11-bit identifier (the CANopen COB-ID), `0..=0x7FF`.
    pub id: u16,
    /// Remote transmission request.
    pub rtr: bool,
    /// Data length code, `0..=8`.
    pub len: u8,
    /// Data (bytes beyond `len` are zero).
    pub data: [u8; 8],
}

impl CanFrame {
    /// A data frame; `None` if `id > 0x7FF` or `data` is longer than 8 bytes.
    pub fn new(id: u16, data: &[u8]) -> Option<Self> {
        if id > 0x7FF || data.len() > 8 {
            return None;
        }
        let mut d = [0u8; 8];
        d[..data.len()].copy_from_slice(data);
        Some(Self {
            id,
            rtr: false,
            len: data.len() as u8,
            data: d,
        })
    }

    /// A remote frame asking for `len` bytes; `None` if out of range.
    pub fn remote(id: u16, len: u8) -> Option<Self> {
        if id > 0x7FF || len > 8 {
            return None;
        }
        Some(Self {
            id,
            rtr: true,
            len,
            data: [0; 8],
        })
    }

    /// The data bytes (empty for a remote frame).
    pub fn data(&self) -> &[u8] {
        if self.rtr {
            &[]
        } else {
            &self.data[..usize::from(self.len.min(8))]
        }
    }

    /// From a driver's frame; `None` for an extended identifier (not used by
    /// CANopen's pre-defined connection set: ignored).
    pub fn from_frame<F: Frame>(f: &F) -> Option<Self> {
        let id = match f.id() {
            Id::Standard(s) => s.as_raw(),
            Id::Extended(_) => return None,
        };
        if f.is_remote_frame() {
            Self::remote(id, f.dlc() as u8)
        } else {
            Self::new(id, f.data())
        }
    }

    /// To a driver's frame.
    pub fn to_frame<F: Frame>(&self) -> Option<F> {
        let id = StandardId::new(self.id)?;
        if self.rtr {
            F::new_remote(id, usize::from(self.len))
        } else {
            F::new(id, self.data())
        }
    }
}
