//! The checks behind the fuzz targets of `foc-protocol`, as plain functions.
//!
//! Each `fuzz_targets/<name>.rs` hands libFuzzer's input to the function of
//! the same name here; `cargo xtask fuzz --replay` (`cargo test
//! --no-default-features` in this crate, on stable, without libFuzzer) runs
//! the seed corpus (`seeds/<name>/`, committed) and the local corpus
//! (`corpus/<name>/`, written by libFuzzer, not committed) through the very
//! same functions. A check fails by panicking.
//!
//! - [`frame_decoder`]: bytes fed one by one to [`FrameDecoder`]; the
//!   documented contract of [`FrameDecoder::feed_raw`] (never
//!   `Some(Ok(&[]))`, a payload is at most [`MAX_PAYLOAD`] bytes), the same
//!   answers as a straightforward reference COBS decoder, `feed` consistent
//!   with `feed_raw`, and resynchronisation at the next delimiter.
//! - [`message_decode`]: the input as a received payload, and as
//!   `tag | seq | body` completed with its correct CRC, decoded as
//!   [`Request`] and as [`Response`]: no panic; a decoded message
//!   re-encodes ([`encode`]) and decodes equal.
//! - [`device_commands`]: the input (after a 3-byte set-up header) through
//!   [`DeviceState::on_byte`] with a [`RecordingContext`], with interleaved
//!   [`DeviceState::poll`] calls: no panic; every frame gets exactly one
//!   reply, every reply (and every streamed sample) is one whole frame that
//!   decodes, with the request's sequence number; a Nack changed nothing in
//!   the context.
//!
//! A crash input worth keeping goes into `seeds/<name>/` (it is then
//! replayed on stable by `cargo xtask fuzz --replay`).

use std::fmt::Debug;

use foc_core::control::stage::TimeoutReaction;
use foc_core::control::Fault;
use foc_protocol::device::tests_support::RecordingContext;
use foc_protocol::device::{DeviceState, Refusal, WatchdogConfig};
use foc_protocol::frame::{
    decode_payload, encode, FrameDecoder, FrameError, FrameErrorKind, Packet, CRC, MAX_FRAME,
    MAX_PAYLOAD,
};
use foc_protocol::message::{Message, Request, Response};

/// A check: panics when the input breaks a property.
pub type Check = fn(&[u8]);

/// The fuzz targets: name (= `fuzz_targets/<name>.rs`, `seeds/<name>/`)
/// and check.
pub const TARGETS: &[(&str, Check)] = &[
    ("frame_decoder", frame_decoder),
    ("message_decode", message_decode),
    ("device_commands", device_commands),
];

// ---------------------------------------------------------------------------
// frame_decoder

/// Arbitrary bytes fed to a [`FrameDecoder`] byte by byte.
pub fn frame_decoder(data: &[u8]) {
    let mut raw = FrameDecoder::new();
    let mut typed = FrameDecoder::new();
    let mut reference = ReferenceDecoder::default();
    for &b in data {
        let got = raw.feed_raw(b).map(|r| r.map(<[u8]>::to_vec));
        if let Some(Ok(payload)) = &got {
            assert!(!payload.is_empty(), "feed_raw returned Some(Ok(&[]))");
            assert!(
                payload.len() <= MAX_PAYLOAD,
                "payload of {} bytes > MAX_PAYLOAD",
                payload.len()
            );
        }
        assert_eq!(
            got,
            reference.feed(b),
            "FrameDecoder and the reference COBS decoder disagree"
        );
        let msg = typed.feed::<Request>(b);
        match (&got, &msg) {
            (None, None) => {}
            (Some(Ok(payload)), Some(m)) => assert_eq!(
                format!("{m:?}"),
                format!("{:?}", decode_payload::<Request>(payload)),
                "feed is not decode_payload of feed_raw's payload"
            ),
            (Some(Err(kind)), Some(Err(e))) => {
                assert_eq!(
                    *e,
                    FrameError {
                        kind: *kind,
                        seq: None
                    }
                );
            }
            _ => panic!("feed_raw gave {got:?} but feed gave {msg:?}"),
        }
    }
    // Whatever came before: one delimiter, then a valid frame decodes.
    let _ = typed.feed::<Request>(0);
    let mut wire = [0u8; MAX_FRAME];
    let n = encode(0x1234, &Request::Ping, &mut wire).expect("Ping fits MAX_FRAME");
    let mut frames = Vec::new();
    typed.feed_slice::<Request>(wire.get(..n).unwrap_or(&[]), |r| frames.push(r));
    assert_eq!(frames.len(), 1, "not back in step after a delimiter");
    let p = frames[0].expect("not back in step after a delimiter");
    assert_eq!((p.seq, p.msg), (0x1234, Request::Ping));
}

/// A reference COBS frame decoder, written for clarity: collect the bytes
/// up to the delimiter, then un-stuff them in one go. Same rules as the
/// documentation of [`foc_protocol::frame`]: empty frames are skipped, more
/// than [`MAX_PAYLOAD`] bytes is `TooLong` (checked first), a delimiter
/// inside a block is `Cobs`.
#[derive(Default)]
struct ReferenceDecoder {
    pending: Vec<u8>,
}

impl ReferenceDecoder {
    fn feed(&mut self, b: u8) -> Option<Result<Vec<u8>, FrameErrorKind>> {
        if b != 0 {
            self.pending.push(b);
            return None;
        }
        let stuffed = std::mem::take(&mut self.pending);
        if stuffed.is_empty() {
            return None;
        }
        let mut out = Vec::new();
        let mut complete = true;
        let mut i = 0;
        let mut prev_code = None;
        while i < stuffed.len() {
            let code = stuffed[i];
            // A block shorter than the maximum stands for a zero after it.
            if prev_code.is_some_and(|c| c != 0xFF) {
                out.push(0);
            }
            prev_code = Some(code);
            let end = i + usize::from(code);
            if end > stuffed.len() {
                out.extend_from_slice(&stuffed[i + 1..]);
                complete = false;
                break;
            }
            out.extend_from_slice(&stuffed[i + 1..end]);
            i = end;
        }
        Some(if out.len() > MAX_PAYLOAD {
            Err(FrameErrorKind::TooLong)
        } else if !complete {
            Err(FrameErrorKind::Cobs)
        } else if out.is_empty() {
            return None;
        } else {
            Ok(out)
        })
    }
}

// ---------------------------------------------------------------------------
// message_decode

/// Arbitrary bytes decoded as [`Request`] and [`Response`]: once as a
/// received payload (`tag | seq | body | crc`, so mostly CRC errors), once
/// as `tag | seq | body` completed with its correct CRC (so the fuzzer
/// reaches the body decoders).
pub fn message_decode(data: &[u8]) {
    round_trip::<Request>(data, |_| true);
    round_trip::<Response>(data, canonical_response);
    let mut payload = data.to_vec();
    payload.extend_from_slice(&CRC.checksum(data).to_le_bytes());
    round_trip::<Request>(&payload, |_| true);
    round_trip::<Response>(&payload, canonical_response);
}

/// A Nack's field byte only survives for `OutOfRange` (`ErrorCode::to_wire`
/// writes 0 otherwise), so a Nack need not re-encode to the very bytes it
/// was decoded from; every other layout is one-to-one.
fn canonical_response(r: &Response) -> bool {
    !matches!(r, Response::Nack(_))
}

/// Decode `payload`; when it is a message, encode it again as a wire frame,
/// decode that through the streaming decoder and compare.
fn round_trip<M>(payload: &[u8], canonical: fn(&M) -> bool)
where
    M: Message + PartialEq + Debug + Copy,
{
    let Ok(p) = decode_payload::<M>(payload) else {
        return;
    };
    let (wire, again, unstuffed) = re_encode(&p);
    assert_eq!(again.seq, p.seq);
    // `a != a` only when a float in it is NaN (compared bitwise below).
    #[allow(clippy::eq_op)]
    let nan = p.msg != p.msg;
    assert!(
        again.msg == p.msg || nan,
        "{:?} re-decoded as {:?}",
        p.msg,
        again.msg
    );
    let (wire2, _, _) = re_encode(&again);
    assert_eq!(wire, wire2, "encode(decode(encode(m))) != encode(m)");
    if canonical(&p.msg) {
        assert_eq!(unstuffed, payload, "{:?} re-encodes differently", p.msg);
        assert_eq!(again.crc, p.crc);
    }
}

/// `encode`, then the streaming decoder: (wire bytes, decoded packet,
/// un-stuffed payload). Panics unless exactly one frame decodes.
fn re_encode<M: Message + Debug + Copy>(p: &Packet<M>) -> (Vec<u8>, Packet<M>, Vec<u8>) {
    let mut buf = [0u8; MAX_FRAME];
    let n = encode(p.seq, &p.msg, &mut buf).expect("a decoded message fits MAX_FRAME");
    let wire = buf[..n].to_vec();
    assert_eq!(
        wire.last(),
        Some(&0),
        "frame does not end with the delimiter"
    );
    assert!(!wire[..n - 1].contains(&0), "0x00 inside the stuffed frame");
    let mut dec = FrameDecoder::new();
    let mut payloads = Vec::new();
    for &b in &wire {
        if let Some(r) = dec.feed_raw(b) {
            payloads.push(r.map(<[u8]>::to_vec));
        }
    }
    assert_eq!(payloads.len(), 1, "{wire:02x?}: not exactly one frame");
    let unstuffed = payloads.remove(0).expect("re-encoded frame rejected");
    let again = decode_payload::<M>(&unstuffed).expect("re-encoded message does not decode");
    (wire, again, unstuffed)
}

// ---------------------------------------------------------------------------
// device_commands

/// Length of the set-up header of a `device_commands` input.
pub const DEVICE_HEADER: usize = 3;

/// Arbitrary bytes through [`DeviceState::on_byte`], with `poll` calls in
/// between. The first [`DEVICE_HEADER`] bytes set the scene:
///
/// - byte 0, bits 0-3: `poll` after every N wire bytes (0: never); bit 4:
///   the context is not calibrated; bit 5: the context refuses its setters
///   (`Busy`); bit 6: `DeviceState::with_auto_watchdog` (1000 periods,
///   stop); bit 7: a fault is latched at the start;
/// - bytes 1-2: periods (u16 LE) the period counter advances per `poll`.
///
/// The rest is the byte stream from the host.
pub fn device_commands(data: &[u8]) {
    let (header, stream) = data.split_at(data.len().min(DEVICE_HEADER));
    let flags = header.first().copied().unwrap_or(0);
    let step = u32::from(u16::from_le_bytes([
        header.get(1).copied().unwrap_or(0),
        header.get(2).copied().unwrap_or(0),
    ]));
    let poll_every = usize::from(flags & 0x0F);
    let mut ctx = RecordingContext {
        calibrated: flags & 0x10 == 0,
        refuse: (flags & 0x20 != 0).then_some(Refusal::Busy),
        ..RecordingContext::default()
    };
    if flags & 0x80 != 0 {
        ctx.faults.insert(Fault::OverCurrentPhase);
        ctx.first_fault = Some(Fault::OverCurrentPhase);
    }
    let mut dev = if flags & 0x40 != 0 {
        DeviceState::with_auto_watchdog(WatchdogConfig {
            timeout_periods: 1000,
            reaction: TimeoutReaction::Stop,
        })
    } else {
        DeviceState::new()
    };

    let mut decoder = FrameDecoder::new();
    // What the device's decoder sees, decoded alongside (the expected seq).
    let mut shadow = FrameDecoder::new();
    let mut tx = [0u8; MAX_FRAME];
    let mut now = 0u32;
    for (i, &b) in stream.iter().enumerate() {
        let before = ctx;
        let frame = shadow.feed::<Request>(b);
        let sent = dev.on_byte(&mut ctx, &mut decoder, b, &mut tx);
        match (frame, sent) {
            (None, None) => {}
            (Some(frame), Some(n)) => {
                assert!(n <= MAX_FRAME);
                let (seq, reply) = decode_reply(tx.get(..n).unwrap_or(&[]));
                let want = match frame {
                    Ok(p) => p.seq,
                    Err(e) => e.seq.unwrap_or(0),
                };
                assert_eq!(seq, want, "reply to {frame:?} with the wrong seq");
                if frame.is_err() {
                    assert!(
                        matches!(reply, Response::Nack(_)),
                        "{frame:?} answered with {reply:?}"
                    );
                }
                if let Response::Nack(_) = reply {
                    assert_unchanged(&before, &ctx, &frame);
                }
            }
            (frame, sent) => panic!("frame {frame:?} but reply {sent:?}"),
        }
        if poll_every != 0 && (i + 1) % poll_every == 0 {
            now = now.wrapping_add(step);
            if let Some((seq, sample)) = dev.poll(&mut ctx, now) {
                assert!(matches!(sample, Response::Stream(_)), "{sample:?}");
                let n = encode(seq, &sample, &mut tx).expect("a sample fits MAX_FRAME");
                let (seq2, sample2) = decode_reply(tx.get(..n).unwrap_or(&[]));
                assert_eq!(seq2, seq);
                assert_eq!(format!("{sample2:?}"), format!("{sample:?}"));
            }
        }
    }
}

/// A reply must be exactly one whole frame that decodes as a [`Response`].
fn decode_reply(wire: &[u8]) -> (u16, Response) {
    assert_eq!(
        wire.last(),
        Some(&0),
        "reply does not end with the delimiter"
    );
    let mut dec = FrameDecoder::new();
    let mut frames = Vec::new();
    dec.feed_slice::<Response>(wire, |r| frames.push(r));
    assert_eq!(frames.len(), 1, "{wire:02x?}: not exactly one frame");
    let p = frames[0].expect("reply does not decode");
    (p.seq, p.msg)
}

/// A Nack means nothing changed in the context (its mutating-call counter
/// aside: a refusing setter is called, and counted, but changes nothing).
fn assert_unchanged(
    before: &RecordingContext,
    after: &RecordingContext,
    frame: &Result<Packet<Request>, FrameError>,
) {
    let after = RecordingContext {
        calls: before.calls,
        ..*after
    };
    assert!(
        *before == after || format!("{before:?}") == format!("{after:?}"),
        "Nack'd {frame:?} changed the context:\n{before:?}\n{after:?}"
    );
}

#[cfg(test)]
mod seeds;

#[cfg(test)]
mod replay {
    //! The corpus through the checks, without libFuzzer (stable).

    use std::panic::{catch_unwind, AssertUnwindSafe};
    use std::path::{Path, PathBuf};

    /// `seeds/<target>` (committed) and `corpus/<target>` (libFuzzer's).
    fn inputs(target: &str) -> (usize, Vec<PathBuf>) {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut seeds = 0;
        let mut files = Vec::new();
        for dir in ["seeds", "corpus"] {
            let Ok(entries) = std::fs::read_dir(root.join(dir).join(target)) else {
                continue;
            };
            let mut found: Vec<PathBuf> = entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_file())
                .collect();
            found.sort();
            if dir == "seeds" {
                seeds = found.len();
            }
            files.extend(found);
        }
        (seeds, files)
    }

    fn replay(target: &str) {
        let check = super::TARGETS
            .iter()
            .find(|(name, _)| *name == target)
            .map(|&(_, check)| check)
            .expect("known target");
        let (seeds, files) = inputs(target);
        assert!(seeds > 0, "no seed files in seeds/{target}");
        let mut failed = Vec::new();
        for file in &files {
            let data = std::fs::read(file).expect("readable corpus file");
            if catch_unwind(AssertUnwindSafe(|| check(&data))).is_err() {
                failed.push(file.display().to_string());
            }
        }
        println!(
            "{target}: {} inputs replayed ({seeds} seeds, {} from corpus/)",
            files.len(),
            files.len() - seeds
        );
        assert!(failed.is_empty(), "{target}: failing inputs: {failed:#?}");
    }

    #[test]
    fn frame_decoder() {
        replay("frame_decoder");
    }

    #[test]
    fn message_decode() {
        replay("message_decode");
    }

    #[test]
    fn device_commands() {
        replay("device_commands");
    }
}
