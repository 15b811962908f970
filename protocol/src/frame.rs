//! Framing: COBS-stuffed payloads delimited by 0x00, with a CRC-32.
//!
//! ```text
//! wire    := COBS(payload) 0x00
//! payload := tag:u8 | seq:u16 LE | body (per tag, fixed layout) | crc:u32 LE
//! crc     := CRC-32/ISO-HDLC over tag | seq | body
//! ```
//!
//! COBS (consistent overhead byte stuffing) removes every 0x00 from the
//! payload at a cost of one byte per 254, so a receiver that starts in the
//! middle of a frame, or after line noise, is back in step at the next 0x00.
//! An empty frame (two delimiters in a row, or a frame whose payload is
//! empty once un-stuffed, such as `01 00`) is ignored: a sender may start
//! with a 0x00 to flush whatever the receiver had half-collected.
//!
//! The [`FrameDecoder`] un-stuffs on the fly into a fixed buffer of
//! [`MAX_PAYLOAD`] bytes: no allocation, any input accepted, every problem
//! reported as a [`FrameError`] when its frame's delimiter arrives.
//!
//! ```
//! use foc_protocol::frame::{FrameDecoder, FrameError, FrameErrorKind};
//! use foc_protocol::message::Response;
//! let mut dec = FrameDecoder::new();
//! // Garbage, then a delimiter: reported once, then the decoder is in step.
//! let mut errors = 0;
//! for &b in &[0x13u8, 0x37, 0x42, 0x00] {
//!     if let Some(Err(e)) = dec.feed::<Response>(b) {
//!         assert_eq!(e.kind, FrameErrorKind::Cobs);
//!         errors += 1;
//!     }
//! }
//! assert_eq!(errors, 1);
//! ```

use crate::message::Message;
use crate::wire::DecodeError;
pub use crate::wire::{Reader, Writer};
use crc::{Crc, CRC_32_ISO_HDLC};

/// The frame CRC: CRC-32/ISO-HDLC (poly 0x04C11DB7 reflected, init and
/// xor-out 0xFFFFFFFF; check value of `"123456789"` is 0xCBF43926).
pub const CRC: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// Largest un-stuffed payload (tag + seq + body + CRC) \[bytes\].
pub const MAX_PAYLOAD: usize = 64;

/// Bytes of a payload that are not body: tag (1) + seq (2) + CRC (4).
pub const OVERHEAD: usize = 7;

/// Largest body of a message \[bytes\].
pub const MAX_BODY: usize = MAX_PAYLOAD - OVERHEAD;

/// Worst-case COBS size of `n` payload bytes (without the delimiter).
pub const fn cobs_max_len(n: usize) -> usize {
    n.saturating_add(n / 254).saturating_add(1)
}

/// Largest frame on the wire, delimiter included \[bytes\]: a transmit
/// buffer of this size always suffices.
pub const MAX_FRAME: usize = cobs_max_len(MAX_PAYLOAD) + 1;

/// A decoded, CRC-checked frame.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Packet<M> {
    /// Sequence number (echoed in the reply to a request; a wrapping stream
    /// counter in unsolicited telemetry).
    pub seq: u16,
    /// The message.
    pub msg: M,
    /// The frame's CRC (identifies a retransmission of the same request).
    pub crc: u32,
}

/// What went wrong with a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameErrorKind {
    /// More than [`MAX_PAYLOAD`] bytes before the delimiter.
    TooLong,
    /// Invalid COBS (the delimiter came inside a stuffed block).
    Cobs,
    /// Payload shorter than tag + seq + CRC.
    Truncated,
    /// CRC mismatch.
    BadCrc,
    /// CRC correct, but the tag is not a known message.
    UnknownTag(u8),
    /// CRC correct, but the body is shorter than its message needs.
    ShortBody,
    /// CRC correct, but the body is longer than its message.
    LongBody,
    /// CRC correct, but field `n` (0-based, in body order) has an invalid
    /// value (an enum code, a non-finite angle...).
    BadField(u8),
}

/// A frame that could not be decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameError {
    /// What went wrong.
    pub kind: FrameErrorKind,
    /// The sequence number, when the CRC was good (so it can be trusted and
    /// echoed in a Nack); `None` otherwise.
    pub seq: Option<u16>,
}

/// Why [`encode`] failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// The output buffer is too small (use [`MAX_FRAME`] bytes).
    BufferTooSmall,
}

/// COBS-encode `src` into `dst` (no delimiter). Returns the encoded length,
/// or `None` when `dst` is too small.
pub fn cobs_encode(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    let mut code_at = 0usize;
    let mut out = 1usize;
    let mut code = 1u8;
    // Reserve the first code byte.
    *dst.get_mut(0)? = 0;
    for &b in src {
        if b == 0 {
            *dst.get_mut(code_at)? = code;
            code_at = out;
            *dst.get_mut(code_at)? = 0;
            out = out.checked_add(1)?;
            code = 1;
        } else {
            *dst.get_mut(out)? = b;
            out = out.checked_add(1)?;
            code = code.checked_add(1)?;
            if code == 0xFF {
                *dst.get_mut(code_at)? = code;
                code_at = out;
                *dst.get_mut(code_at)? = 0;
                out = out.checked_add(1)?;
                code = 1;
            }
        }
    }
    *dst.get_mut(code_at)? = code;
    Some(out)
}

/// Encode `msg` with sequence number `seq` as a complete wire frame
/// (COBS + delimiter) into `out`. Returns the number of bytes to send.
pub fn encode<M: Message>(seq: u16, msg: &M, out: &mut [u8]) -> Result<usize, EncodeError> {
    let mut payload = [0u8; MAX_PAYLOAD];
    let mut w = Writer::new(&mut payload);
    w.u8(msg.tag());
    w.u16(seq);
    msg.encode_body(&mut w);
    let crc = CRC.checksum(w.written());
    w.u32(crc);
    if w.overflowed() {
        return Err(EncodeError::BufferTooSmall);
    }
    let n = w.len();
    let src = payload.get(..n).ok_or(EncodeError::BufferTooSmall)?;
    let len = cobs_encode(src, out).ok_or(EncodeError::BufferTooSmall)?;
    *out.get_mut(len).ok_or(EncodeError::BufferTooSmall)? = 0;
    len.checked_add(1).ok_or(EncodeError::BufferTooSmall)
}

/// Decode one un-stuffed payload (without delimiter): CRC, tag, body.
pub fn decode_payload<M: Message>(payload: &[u8]) -> Result<Packet<M>, FrameError> {
    let err = |kind, seq| FrameError { kind, seq };
    let body_end = payload
        .len()
        .checked_sub(4)
        .filter(|&n| n >= 3)
        .ok_or(err(FrameErrorKind::Truncated, None))?;
    let (data, crc_bytes) = payload
        .split_at_checked(body_end)
        .ok_or(err(FrameErrorKind::Truncated, None))?;
    let crc = Reader::new(crc_bytes)
        .u32()
        .map_err(|_| err(FrameErrorKind::Truncated, None))?;
    if CRC.checksum(data) != crc {
        return Err(err(FrameErrorKind::BadCrc, None));
    }
    let mut r = Reader::new(data);
    let tag = r.u8().map_err(|_| err(FrameErrorKind::Truncated, None))?;
    let seq = r.u16().map_err(|_| err(FrameErrorKind::Truncated, None))?;
    let msg = M::decode_body(tag, &mut r).and_then(|m| r.finish().map(|()| m));
    match msg {
        Ok(msg) => Ok(Packet { seq, msg, crc }),
        Err(e) => Err(err(
            match e {
                DecodeError::UnknownTag => FrameErrorKind::UnknownTag(tag),
                DecodeError::Short => FrameErrorKind::ShortBody,
                DecodeError::Long => FrameErrorKind::LongBody,
                DecodeError::BadField(n) => FrameErrorKind::BadField(n),
            },
            Some(seq),
        )),
    }
}

/// Streaming decoder: feed it every received byte; at each delimiter it
/// yields the frame (or why it was rejected). Fixed buffer, never panics,
/// resynchronises at every 0x00.
#[derive(Clone, Debug)]
pub struct FrameDecoder {
    buf: [u8; MAX_PAYLOAD],
    len: usize,
    /// Bytes left in the current COBS block (0: the next byte is a code).
    remaining: u8,
    /// Code of the block just finished (0: no block yet in this frame).
    prev_code: u8,
    overflow: bool,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    /// Empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_PAYLOAD],
            len: 0,
            remaining: 0,
            prev_code: 0,
            overflow: false,
        }
    }

    /// Forget a partly received frame.
    pub fn reset(&mut self) {
        self.len = 0;
        self.remaining = 0;
        self.prev_code = 0;
        self.overflow = false;
    }

    fn push(&mut self, b: u8) {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = b;
                self.len = self.len.saturating_add(1);
            }
            None => self.overflow = true,
        }
    }

    /// Feed one byte: the un-stuffed payload when it completes a frame.
    /// `Some(Ok(&[]))` is never returned: empty frames (nothing between two
    /// delimiters, or a valid COBS frame whose payload is empty, `01 00`)
    /// are skipped like an idle line.
    pub fn feed_raw(&mut self, byte: u8) -> Option<Result<&[u8], FrameErrorKind>> {
        if byte == 0 {
            let result = if self.prev_code == 0 {
                // Nothing since the last delimiter: idle line, skip.
                None
            } else if self.overflow {
                Some(Err(FrameErrorKind::TooLong))
            } else if self.remaining != 0 {
                Some(Err(FrameErrorKind::Cobs))
            } else if self.len == 0 {
                // A complete frame with an empty payload (a lone `01` code
                // byte): nothing to deliver, skip it like an idle line.
                None
            } else {
                Some(Ok(()))
            };
            let len = self.len;
            self.len = 0;
            self.remaining = 0;
            self.prev_code = 0;
            self.overflow = false;
            return match result {
                None => None,
                Some(Err(e)) => Some(Err(e)),
                Some(Ok(())) => Some(Ok(self.buf.get(..len).unwrap_or(&[]))),
            };
        }
        if self.remaining == 0 {
            // A code byte: the previous block (if any, and if shorter than
            // the maximum) stood for a zero.
            if self.prev_code != 0 && self.prev_code != 0xFF {
                self.push(0);
            }
            self.prev_code = byte;
            self.remaining = byte.saturating_sub(1);
        } else {
            self.push(byte);
            self.remaining = self.remaining.saturating_sub(1);
        }
        None
    }

    /// Feed one byte: a decoded message when it completes a frame.
    pub fn feed<M: Message>(&mut self, byte: u8) -> Option<Result<Packet<M>, FrameError>> {
        match self.feed_raw(byte)? {
            Ok(payload) => Some(decode_payload(payload)),
            Err(kind) => Some(Err(FrameError { kind, seq: None })),
        }
    }

    /// Feed a slice, calling `on_frame` for every frame it completes.
    pub fn feed_slice<M: Message>(
        &mut self,
        bytes: &[u8],
        mut on_frame: impl FnMut(Result<Packet<M>, FrameError>),
    ) {
        for &b in bytes {
            if let Some(r) = self.feed::<M>(b) {
                on_frame(r);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(enc: &[u8]) -> Vec<u8> {
        let mut d = FrameDecoder::new();
        let mut out = None;
        for &b in enc {
            if let Some(r) = d.feed_raw(b) {
                out = Some(r.unwrap().to_vec());
            }
        }
        out.unwrap()
    }

    extern crate std;
    use std::vec::Vec;

    #[test]
    fn crc_check_value() {
        assert_eq!(CRC.checksum(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn cobs_known_vectors() {
        // Vectors from the COBS paper / Wikipedia.
        let cases: &[(&[u8], &[u8])] = &[
            (&[0x00], &[0x01, 0x01]),
            (&[0x00, 0x00], &[0x01, 0x01, 0x01]),
            (&[0x11, 0x22, 0x00, 0x33], &[0x03, 0x11, 0x22, 0x02, 0x33]),
            (&[0x11, 0x22, 0x33, 0x44], &[0x05, 0x11, 0x22, 0x33, 0x44]),
            (&[0x11, 0x00, 0x00, 0x00], &[0x02, 0x11, 0x01, 0x01, 0x01]),
        ];
        for (raw, enc) in cases {
            let mut buf = [0u8; 16];
            let n = cobs_encode(raw, &mut buf).unwrap();
            assert_eq!(&buf[..n], *enc);
            let mut framed = enc.to_vec();
            framed.push(0);
            assert_eq!(decode_all(&framed), *raw);
        }
    }

    #[test]
    fn cobs_254_run() {
        // A run of 254 non-zero bytes needs the 0xFF code (no implied zero).
        let raw: Vec<u8> = (1..=254u8).collect();
        let mut buf = [0u8; 300];
        let n = cobs_encode(&raw, &mut buf).unwrap();
        assert_eq!(buf[0], 0xFF);
        assert_eq!(n, cobs_max_len(raw.len()));
        assert!(buf[..n].iter().all(|&b| b != 0));
    }

    #[test]
    fn encode_rejects_small_buffer() {
        let mut out = [0u8; 4];
        assert_eq!(
            encode(1, &crate::message::Request::Ping, &mut out),
            Err(EncodeError::BufferTooSmall)
        );
    }

    #[test]
    fn empty_frames_are_skipped_and_cobs_errors_reported() {
        let mut d = FrameDecoder::new();
        assert!(d.feed_raw(0).is_none());
        assert!(d.feed_raw(0).is_none());
        // Code byte says 5 bytes follow, only 2 arrive.
        assert!(d.feed_raw(5).is_none());
        assert!(d.feed_raw(1).is_none());
        assert!(d.feed_raw(2).is_none());
        assert_eq!(d.feed_raw(0), Some(Err(FrameErrorKind::Cobs)));
    }

    /// Regression: `fd 00 01 00 00` used to yield `Some(Ok(&[]))` at the
    /// second delimiter (`01` is the COBS encoding of an empty payload),
    /// against `feed_raw`'s contract. Now: the COBS error of the
    /// truncated first frame, then nothing; the decoder stays in step.
    #[test]
    fn empty_payload_after_unstuffing_is_skipped() {
        let mut d = FrameDecoder::new();
        let out: Vec<_> = [0xfd, 0x00, 0x01, 0x00, 0x00]
            .iter()
            .filter_map(|&b| d.feed_raw(b).map(|r| r.map(|p| p.to_vec())))
            .collect();
        assert_eq!(out, [Err(FrameErrorKind::Cobs)]);
        // Any number of empty COBS frames, alone or between real ones.
        let mut d = FrameDecoder::new();
        for &b in &[0x01, 0x00, 0x01, 0x00, 0x00, 0x01] {
            assert_eq!(d.feed_raw(b), None);
        }
        assert_eq!(d.feed_raw(0x00), None);
        // The message-level decode: no frame (in particular no Truncated
        // error) for the empty payload, then a real frame decodes.
        let mut d = FrameDecoder::new();
        let mut frames = Vec::new();
        d.feed_slice::<crate::message::Request>(&[0xfd, 0x00, 0x01, 0x00, 0x00], |r| {
            frames.push(r)
        });
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].unwrap_err().kind, FrameErrorKind::Cobs);
        let mut buf = [0u8; MAX_FRAME];
        let n = encode(9, &crate::message::Request::Ping, &mut buf).unwrap();
        let mut wire = std::vec![0x01, 0x00];
        wire.extend_from_slice(&buf[..n]);
        let mut frames = Vec::new();
        d.feed_slice::<crate::message::Request>(&wire, |r| frames.push(r));
        assert_eq!(frames.len(), 1);
        let p = frames[0].unwrap();
        assert_eq!((p.seq, p.msg), (9, crate::message::Request::Ping));
    }

    #[test]
    fn too_long_is_reported_once_then_in_step() {
        let mut d = FrameDecoder::new();
        let mut errs = Vec::new();
        for _ in 0..1000 {
            if let Some(r) = d.feed_raw(0x01) {
                errs.push(r.map(|p| p.len()));
            }
        }
        assert!(errs.is_empty());
        assert_eq!(d.feed_raw(0), Some(Err(FrameErrorKind::TooLong)));
        let mut buf = [0u8; MAX_FRAME];
        let n = encode(3, &crate::message::Request::Ping, &mut buf).unwrap();
        let mut ok = 0;
        for &b in &buf[..n] {
            if let Some(r) = d.feed::<crate::message::Request>(b) {
                assert_eq!(r.unwrap().seq, 3);
                ok += 1;
            }
        }
        assert_eq!(ok, 1);
    }
}
