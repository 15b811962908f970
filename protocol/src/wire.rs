//! Little-endian field encoding shared by the message and frame layers: a
//! bounds-checked [`Writer`] and [`Reader`] over fixed buffers, and the
//! [`DecodeError`] a read reports.
//!
//! Dependencies run one way: `wire` <- `message` <- `frame`. The items are
//! re-exported where they were always reached: [`crate::frame::Reader`],
//! [`crate::frame::Writer`] and [`crate::message::DecodeError`].

/// Why a body could not be decoded (mapped to a
/// [`crate::frame::FrameErrorKind`] by the frame layer).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// Unknown tag.
    UnknownTag,
    /// Body too short.
    Short,
    /// Bytes left over after the body.
    Long,
    /// Field `n` holds an invalid code.
    BadField(u8),
}

/// A bounds-checked little-endian writer over a fixed buffer.
#[derive(Debug)]
pub struct Writer<'a> {
    buf: &'a mut [u8],
    len: usize,
    overflow: bool,
}

impl<'a> Writer<'a> {
    /// Writer at the start of `buf`.
    pub fn new(buf: &'a mut [u8]) -> Self {
        Self {
            buf,
            len: 0,
            overflow: false,
        }
    }
    /// Append one byte (sets the overflow flag when full).
    pub fn u8(&mut self, v: u8) {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = v;
                self.len = self.len.saturating_add(1);
            }
            None => self.overflow = true,
        }
    }
    /// Append bytes.
    pub fn bytes(&mut self, v: &[u8]) {
        for &b in v {
            self.u8(b);
        }
    }
    /// Append a `u16` LE.
    pub fn u16(&mut self, v: u16) {
        self.bytes(&v.to_le_bytes());
    }
    /// Append a `u32` LE.
    pub fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }
    /// Append an `f32` LE (IEEE 754 bits).
    pub fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }
    /// Bytes written.
    pub fn len(&self) -> usize {
        self.len
    }
    /// True when nothing was written.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// True when a write did not fit.
    pub fn overflowed(&self) -> bool {
        self.overflow
    }
    /// The bytes written so far.
    pub fn written(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }
}

/// A bounds-checked little-endian reader; every read past the end is a
/// [`DecodeError::Short`].
#[derive(Clone, Copy, Debug)]
pub struct Reader<'a> {
    buf: &'a [u8],
}

impl<'a> Reader<'a> {
    /// Reader over `buf`.
    pub fn new(buf: &'a [u8]) -> Self {
        Self { buf }
    }
    fn take<const N: usize>(&mut self) -> Result<[u8; N], DecodeError> {
        let (head, rest) = self.buf.split_at_checked(N).ok_or(DecodeError::Short)?;
        let mut out = [0u8; N];
        out.copy_from_slice(head);
        self.buf = rest;
        Ok(out)
    }
    /// Read `n` bytes.
    pub fn slice(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        let (head, rest) = self.buf.split_at_checked(n).ok_or(DecodeError::Short)?;
        self.buf = rest;
        Ok(head)
    }
    /// Read a byte.
    pub fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(u8::from_le_bytes(self.take::<1>()?))
    }
    /// Read a `u16` LE.
    pub fn u16(&mut self) -> Result<u16, DecodeError> {
        Ok(u16::from_le_bytes(self.take::<2>()?))
    }
    /// Read a `u32` LE.
    pub fn u32(&mut self) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.take::<4>()?))
    }
    /// Read an `f32` LE.
    pub fn f32(&mut self) -> Result<f32, DecodeError> {
        Ok(f32::from_bits(self.u32()?))
    }
    /// Fails with [`DecodeError::Long`] unless everything was read.
    pub fn finish(self) -> Result<(), DecodeError> {
        if self.buf.is_empty() {
            Ok(())
        } else {
            Err(DecodeError::Long)
        }
    }
}
