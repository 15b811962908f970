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
        d.get_mut(..data.len())?.copy_from_slice(data);
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
            self.data.get(..usize::from(self.len.min(8))).unwrap_or(&[])
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

/// [`CanFrame`] is itself an [`embedded_can::Frame`] (standard
/// identifiers only), so a port that carries CANopen frames as they are
/// (the emulated board's SLCAN UART) needs no conversion. Never panics:
/// an out-of-range field written directly is clamped (id to 11 bits,
/// length to 8).
impl Frame for CanFrame {
    /// A data frame; `None` for an extended identifier or more than 8 bytes.
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        match id.into() {
            Id::Standard(s) => CanFrame::new(s.as_raw(), data),
            Id::Extended(_) => None,
        }
    }

    /// A remote frame; `None` for an extended identifier or `dlc > 8`.
    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        match id.into() {
            Id::Standard(s) => CanFrame::remote(s.as_raw(), u8::try_from(dlc).ok()?),
            Id::Extended(_) => None,
        }
    }

    fn is_extended(&self) -> bool {
        false
    }

    fn is_remote_frame(&self) -> bool {
        self.rtr
    }

    fn id(&self) -> Id {
        // Masked to 11 bits, `StandardId::new` cannot refuse it.
        Id::Standard(StandardId::new(self.id & 0x7FF).unwrap_or(StandardId::ZERO))
    }

    fn dlc(&self) -> usize {
        usize::from(self.len.min(8))
    }

    fn data(&self) -> &[u8] {
        CanFrame::data(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_can_frame_round_trips() {
        let id = StandardId::new(0x601).unwrap();
        let f = <CanFrame as Frame>::new(id, &[1, 2, 3]).unwrap();
        assert_eq!(f, CanFrame::new(0x601, &[1, 2, 3]).unwrap());
        assert_eq!(Frame::id(&f), Id::Standard(id));
        assert_eq!(Frame::dlc(&f), 3);
        assert_eq!(Frame::data(&f), &[1, 2, 3]);
        assert!(!f.is_extended() && !f.is_remote_frame());
        let r = <CanFrame as Frame>::new_remote(id, 8).unwrap();
        assert!(r.is_remote_frame());
        assert_eq!(Frame::dlc(&r), 8);
        assert_eq!(Frame::data(&r), &[] as &[u8]);
        assert_eq!(CanFrame::from_frame(&r), Some(r));
        assert_eq!(r.to_frame::<CanFrame>(), Some(r));
    }

    #[test]
    fn refused_and_clamped() {
        let ext = embedded_can::ExtendedId::new(0x1234_5678).unwrap();
        assert_eq!(<CanFrame as Frame>::new(ext, &[]), None);
        assert_eq!(<CanFrame as Frame>::new_remote(ext, 1), None);
        let id = StandardId::new(0x80).unwrap();
        assert_eq!(<CanFrame as Frame>::new(id, &[0; 9]), None);
        assert_eq!(<CanFrame as Frame>::new_remote(id, 9), None);
        assert_eq!(<CanFrame as Frame>::new_remote(id, 300), None);
        // Fields written out of range directly: clamped, no panic.
        let wild = CanFrame {
            id: 0xFFFF,
            rtr: false,
            len: 200,
            data: [7; 8],
        };
        assert_eq!(Frame::id(&wild), Id::Standard(StandardId::MAX));
        assert_eq!(Frame::dlc(&wild), 8);
        assert_eq!(Frame::data(&wild).len(), 8);
    }
}
