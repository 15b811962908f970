//! SLCAN (Lawicel) ASCII framing of classic CAN frames: the wire of a
//! USB-CAN adapter (CANable, CANtact), of python-can's `slcan` interface,
//! of the host test bus (`foc-canbus`) and of the emulated firmware's UART.
//!
//! Lines end with `\r`. Frames:
//!
//! | line | meaning |
//! |---|---|
//! | `tIIILDD..` | data frame, 11-bit id `III` (hex), length `L` (0-8), `L` data bytes in hex |
//! | `rIIIL` | remote frame, 11-bit id, length `L` |
//! | `TIIIIIIIILDD..` / `RIIIIIIIIL` | 29-bit frame: [`Event::Extended`] (CANopen's pre-defined connection set does not use them: ignored) |
//!
//! Commands (one letter, optional argument) decode to [`Cmd`]: `O` open,
//! `L` open listen-only, `C` close, `S0`-`S8` bit rate, `sXXYY` BTR
//! registers, `V` / `v` versions, `N` serial number, `F` status flags,
//! `Z0`/`Z1` timestamps, `X0`/`X1` auto-poll, `P` / `A` poll, `Q0`-`Q2`
//! auto-start, `MXXXXXXXX` / `mXXXXXXXX` acceptance code / mask. An
//! adapter answers a command with `\r` (ok, [`OK`]) or `\x07` (error,
//! [`ERROR`]); the version and status queries with their line
//! ([`encode_reply`]). An empty line (`\r` alone) is no event.
//!
//! Anything else (an unknown letter, a bad hex digit, a wrong length, a
//! CAN FD line) is an [`Event::Error`] once the line ends: the decoder
//! resynchronises at every `\r`. A line longer than [`MAX_LINE`] bytes is
//! discarded (one [`Event::Error`] at its `\r`). `\n` is ignored (some
//! tools send `\r\n`).
//!
//! no_std, no alloc, never panics.
//!
//! ```
//! use foc_canopen::slcan::{encode, Decoder, Event};
//! use foc_canopen::CanFrame;
//! let f = CanFrame::new(0x601, &[0x40, 0x00, 0x10, 0x00]).unwrap();
//! let mut line = [0u8; 27];
//! let n = encode(&f, &mut line);
//! assert_eq!(&line[..n], b"t601440001000\r");
//! let mut d = Decoder::new();
//! let events: Vec<_> = line[..n].iter().filter_map(|&b| d.push(b)).collect();
//! assert_eq!(events, [Event::Frame(f)]);
//! ```

use crate::frame::CanFrame;

/// Longest line the decoder keeps, `\r` not counted (a 29-bit frame with
/// 8 bytes and a 4-digit timestamp: 1 + 8 + 1 + 16 + 4 = 30).
pub const MAX_LINE: usize = 30;

/// Longest encoded classic 11-bit frame: `t` + 3 + 1 + 16 + `\r` = 22
/// bytes (the buffer of [`encode`] leaves room for a timestamp).
pub const MAX_FRAME_LINE: usize = 22;

/// An adapter's "ok" answer to a command.
pub const OK: u8 = b'\r';
/// An adapter's "error" answer to a command (BEL).
pub const ERROR: u8 = 0x07;

/// A decoded command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Cmd {
    /// `O`: open the channel (normal mode).
    Open,
    /// `L`: open the channel listen-only.
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `Sn`: standard bit rate `n` (0: 10, 1: 20, 2: 50, 3: 100, 4: 125,
    /// 5: 250, 6: 500, 7: 800 (750 in python-can), 8: 1000 kbit/s).
    Bitrate(u8),
    /// `sXXYY`: the SJA1000's BTR0 / BTR1 registers.
    Btr(u16),
    /// `V`: hardware and software version (answer `VHHSS`).
    Version,
    /// `v`: firmware version (answer `vMMmm`).
    FirmwareVersion,
    /// `N`: serial number (answer `Nxxxx`).
    SerialNumber,
    /// `F`: status flags (answer `Fxx`).
    StatusFlags,
    /// `Zn`: timestamps off (0) / on (1).
    Timestamp(bool),
    /// `Xn`: auto-poll off (0) / on (1).
    AutoPoll(bool),
    /// `P`: poll one frame.
    Poll,
    /// `A`: poll all frames.
    PollAll,
    /// `Qn`: auto-start (0 off, 1 normal, 2 listen-only).
    AutoStart(u8),
    /// `Mxxxxxxxx`: acceptance code.
    AcceptanceCode(u32),
    /// `mxxxxxxxx`: acceptance mask.
    AcceptanceMask(u32),
}

impl Cmd {
    /// The standard bit rate of a `Sn` code [kbit/s] (`None` beyond 8).
    pub const fn bitrate_kbit(code: u8) -> Option<u16> {
        match code {
            0 => Some(10),
            1 => Some(20),
            2 => Some(50),
            3 => Some(100),
            4 => Some(125),
            5 => Some(250),
            6 => Some(500),
            7 => Some(800),
            8 => Some(1000),
            _ => None,
        }
    }
}

/// What one byte completed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// A classic frame with an 11-bit identifier.
    Frame(CanFrame),
    /// A well-formed 29-bit frame (ignored by CANopen).
    Extended,
    /// A command.
    Command(Cmd),
    /// A malformed, unsupported or overlong line (discarded).
    Error,
}

/// Upper-case hex digit of the low nibble of `n`.
const fn hex_digit(n: u8) -> u8 {
    let n = n & 0xF;
    if n < 10 {
        b'0' + n
    } else {
        b'A' + n - 10
    }
}

/// Value of a hex digit (either case).
const fn hex_value(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

/// The number in the hex digits `s` (at most 8 of them; `None` if empty,
/// longer, or not hex).
fn hex(s: &[u8]) -> Option<u32> {
    if s.is_empty() || s.len() > 8 {
        return None;
    }
    s.iter()
        .try_fold(0u32, |acc, &c| Some((acc << 4) | u32::from(hex_value(c)?)))
}

/// Encode `frame` as one SLCAN line (`t...\r` or `r...\r`) into `out`:
/// its length (at most [`MAX_FRAME_LINE`]). A frame with an identifier
/// beyond 11 bits or a length beyond 8 is clamped (id masked to 11 bits,
/// length to 8): [`CanFrame`]'s constructors never make one.
pub fn encode(frame: &CanFrame, out: &mut [u8; 27]) -> usize {
    let len = frame.len.min(8);
    let id = frame.id & 0x7FF;
    let mut n = 0;
    let mut put = |b: u8| {
        if let Some(slot) = out.get_mut(n) {
            *slot = b;
            n += 1;
        }
    };
    put(if frame.rtr { b'r' } else { b't' });
    put(hex_digit((id >> 8) as u8));
    put(hex_digit((id >> 4) as u8));
    put(hex_digit(id as u8));
    put(b'0' + len);
    if !frame.rtr {
        for &b in frame.data.iter().take(usize::from(len)) {
            put(hex_digit(b >> 4));
            put(hex_digit(b));
        }
    }
    put(b'\r');
    n
}

/// The line an adapter answers `cmd` with into `out` (its length, `\r`
/// included), given the version (`V`: hardware, software as two decimal
/// digits each) and the serial number (`N`: four characters). Commands
/// without a reply line answer [`OK`] alone.
pub fn encode_reply(
    cmd: Cmd,
    version: (u8, u8),
    serial: &[u8; 4],
    status_flags: u8,
    out: &mut [u8; 8],
) -> usize {
    let dec = |v: u8| [b'0' + (v / 10) % 10, b'0' + v % 10];
    let line: [u8; 6] = match cmd {
        Cmd::Version | Cmd::FirmwareVersion => {
            let [a, b] = dec(version.0);
            let [c, d] = dec(version.1);
            let l = if cmd == Cmd::Version { b'V' } else { b'v' };
            [l, a, b, c, d, b'\r']
        }
        Cmd::SerialNumber => [b'N', serial[0], serial[1], serial[2], serial[3], b'\r'],
        Cmd::StatusFlags => [
            b'F',
            hex_digit(status_flags >> 4),
            hex_digit(status_flags),
            b'\r',
            0,
            0,
        ],
        _ => [OK, 0, 0, 0, 0, 0],
    };
    let n = match cmd {
        Cmd::Version | Cmd::FirmwareVersion | Cmd::SerialNumber => 6,
        Cmd::StatusFlags => 4,
        _ => 1,
    };
    for (o, b) in out.iter_mut().zip(line.iter()).take(n) {
        *o = *b;
    }
    n
}

/// Decode one complete line (without its `\r`).
fn decode_line(line: &[u8]) -> Option<Event> {
    let (&first, rest) = line.split_first()?;
    let ev = match first {
        b't' | b'r' => decode_frame(rest, 3, first == b'r').map(Event::Frame),
        b'T' | b'R' => decode_frame(rest, 8, first == b'R').map(|_| Event::Extended),
        _ => decode_command(first, rest).map(Event::Command),
    };
    Some(ev.unwrap_or(Event::Error))
}

/// A frame body after its letter: `id_digits` hex digits, the length, the
/// data (none for a remote frame), optionally a 4-digit timestamp
/// (ignored). For 29-bit ids the frame carries id 0: only its
/// well-formedness counts.
fn decode_frame(rest: &[u8], id_digits: usize, rtr: bool) -> Option<CanFrame> {
    let id = hex(rest.get(..id_digits)?)?;
    if (id_digits == 3 && id > 0x7FF) || id > 0x1FFF_FFFF {
        return None;
    }
    let len_c = *rest.get(id_digits)?;
    if !len_c.is_ascii_digit() {
        return None;
    }
    let len = len_c - b'0';
    if len > 8 {
        return None;
    }
    let body = rest.get(id_digits + 1..)?;
    let data_chars = if rtr { 0 } else { 2 * usize::from(len) };
    // Exactly the data, or the data and a 4-digit timestamp.
    let tail = body.get(data_chars..)?;
    if !(tail.is_empty() || (tail.len() == 4 && hex(tail).is_some())) {
        return None;
    }
    let mut data = [0u8; 8];
    for (i, d) in data.iter_mut().enumerate().take(data_chars / 2) {
        let hi = hex_value(*body.get(2 * i)?)?;
        let lo = hex_value(*body.get(2 * i + 1)?)?;
        *d = (hi << 4) | lo;
    }
    let std_id = if id_digits == 3 { id as u16 } else { 0 };
    if rtr {
        CanFrame::remote(std_id, len)
    } else {
        CanFrame::new(std_id, data.get(..usize::from(len))?)
    }
}

/// A command line: its letter and argument.
fn decode_command(letter: u8, arg: &[u8]) -> Option<Cmd> {
    let flag = |arg: &[u8]| match arg {
        b"0" => Some(false),
        b"1" => Some(true),
        _ => None,
    };
    let none = |c: Cmd| arg.is_empty().then_some(c);
    match letter {
        b'O' => none(Cmd::Open),
        b'L' => none(Cmd::ListenOnly),
        b'C' => none(Cmd::Close),
        b'V' => none(Cmd::Version),
        b'v' => none(Cmd::FirmwareVersion),
        b'N' => none(Cmd::SerialNumber),
        b'F' => none(Cmd::StatusFlags),
        b'P' => none(Cmd::Poll),
        b'A' => none(Cmd::PollAll),
        b'S' => match arg {
            [d @ b'0'..=b'8'] => Some(Cmd::Bitrate(d - b'0')),
            _ => None,
        },
        b's' if arg.len() == 4 => hex(arg).map(|v| Cmd::Btr(v as u16)),
        b'Z' => flag(arg).map(Cmd::Timestamp),
        b'X' => flag(arg).map(Cmd::AutoPoll),
        b'Q' => match arg {
            [d @ b'0'..=b'2'] => Some(Cmd::AutoStart(d - b'0')),
            _ => None,
        },
        b'M' if arg.len() == 8 => hex(arg).map(Cmd::AcceptanceCode),
        b'm' if arg.len() == 8 => hex(arg).map(Cmd::AcceptanceMask),
        _ => None,
    }
}

/// Byte-at-a-time SLCAN line decoder (see the module docs).
#[derive(Clone, Debug)]
pub struct Decoder {
    line: [u8; MAX_LINE],
    len: usize,
    /// The current line ran past [`MAX_LINE`]: discarded at its `\r`.
    overlong: bool,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// A decoder at the start of a line.
    pub const fn new() -> Self {
        Self {
            line: [0; MAX_LINE],
            len: 0,
            overlong: false,
        }
    }

    /// Forget a partial line.
    pub fn reset(&mut self) {
        self.len = 0;
        self.overlong = false;
    }

    /// Feed one byte: the event of the line it ends, if any.
    pub fn push(&mut self, byte: u8) -> Option<Event> {
        match byte {
            b'\r' => {
                let ev = if self.overlong {
                    Some(Event::Error)
                } else {
                    decode_line(self.line.get(..self.len).unwrap_or(&[]))
                };
                self.reset();
                ev
            }
            b'\n' => None,
            _ => {
                match self.line.get_mut(self.len) {
                    Some(slot) if !self.overlong => {
                        *slot = byte;
                        self.len += 1;
                    }
                    _ => self.overlong = true,
                }
                None
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn decode_all(bytes: &[u8]) -> ([Option<Event>; 16], usize) {
        let mut d = Decoder::new();
        let mut out = [None; 16];
        let mut n = 0;
        for &b in bytes {
            if let Some(e) = d.push(b) {
                if n < out.len() {
                    out[n] = Some(e);
                }
                n += 1;
            }
        }
        (out, n)
    }

    fn one(bytes: &[u8]) -> Option<Event> {
        let (out, n) = decode_all(bytes);
        assert!(n <= 1, "{n} events");
        out[0]
    }

    #[test]
    fn frames_encode() {
        let mut b = [0u8; 27];
        let f = CanFrame::new(0x7FF, &[0xDE, 0xAD, 0xBE, 0xEF, 0, 1, 2, 0xFF]).unwrap();
        let n = encode(&f, &mut b);
        assert_eq!(&b[..n], b"t7FF8DEADBEEF000102FF\r");
        assert_eq!(n, MAX_FRAME_LINE);
        let n = encode(&CanFrame::new(0x80, &[]).unwrap(), &mut b);
        assert_eq!(&b[..n], b"t0800\r");
        let n = encode(&CanFrame::remote(0x701, 1).unwrap(), &mut b);
        assert_eq!(&b[..n], b"r7011\r");
    }

    #[test]
    fn frames_decode() {
        assert_eq!(
            one(b"t1232abcd\r"),
            Some(Event::Frame(CanFrame::new(0x123, &[0xAB, 0xCD]).unwrap()))
        );
        assert_eq!(
            one(b"r7010\r"),
            Some(Event::Frame(CanFrame::remote(0x701, 0).unwrap()))
        );
        // With a timestamp (ignored).
        assert_eq!(
            one(b"t0001111234\r"),
            Some(Event::Frame(CanFrame::new(0, &[0x11]).unwrap()))
        );
        assert_eq!(one(b"T1FFFFFFF0\r"), Some(Event::Extended));
        assert_eq!(one(b"R000001232\r"), Some(Event::Extended));
        assert_eq!(one(b"\r"), None);
        assert_eq!(one(b"\n"), None);
    }

    #[test]
    fn bad_lines_are_errors() {
        for l in [
            &b"t8000\r"[..], // id beyond 11 bits
            b"t1239\r",      // length 9
            b"t1232ab\r",    // short data
            b"t1231abc\r",   // odd digits
            b"t12G0\r",      // not hex
            b"t1231gg\r",    // not hex data
            b"T200000000\r", // 29-bit id beyond 29 bits
            b"d1230\r",      // CAN FD
            b"S9\r",         // bit rate code
            b"Ox\r",         // argument where none
            b"?\r",          // unknown
            b"Z2\r",         // bad flag
            b"t\r",          // truncated
        ] {
            assert_eq!(one(l), Some(Event::Error), "{:?}", core::str::from_utf8(l));
        }
    }

    #[test]
    fn resyncs_after_error_and_overlong() {
        let mut bytes = [b'x'; 100];
        bytes[99] = b'\r';
        let (out, n) = decode_all(&bytes);
        assert_eq!((n, out[0]), (1, Some(Event::Error)));
        let (out, n) = decode_all(b"garbage\rt0800\r");
        assert_eq!(n, 2);
        assert_eq!(out[0], Some(Event::Error));
        assert_eq!(
            out[1],
            Some(Event::Frame(CanFrame::new(0x80, &[]).unwrap()))
        );
        // The longest legal line fits.
        assert_eq!(
            one(b"T1FFFFFFF8001122334455667789AB\r"),
            Some(Event::Extended)
        );
    }

    #[test]
    fn commands() {
        use Cmd::*;
        for (l, c) in [
            (&b"O\r"[..], Open),
            (b"L\r", ListenOnly),
            (b"C\r", Close),
            (b"S8\r", Bitrate(8)),
            (b"S0\r", Bitrate(0)),
            (b"s031C\r", Btr(0x031C)),
            (b"V\r", Version),
            (b"v\r", FirmwareVersion),
            (b"N\r", SerialNumber),
            (b"F\r", StatusFlags),
            (b"Z1\r", Timestamp(true)),
            (b"X0\r", AutoPoll(false)),
            (b"P\r", Poll),
            (b"A\r", PollAll),
            (b"Q2\r", AutoStart(2)),
            (b"M00000000\r", AcceptanceCode(0)),
            (b"mFFFFFFFF\r", AcceptanceMask(0xFFFF_FFFF)),
        ] {
            assert_eq!(one(l), Some(Event::Command(c)));
        }
        assert_eq!(Cmd::bitrate_kbit(8), Some(1000));
        assert_eq!(Cmd::bitrate_kbit(9), None);
    }

    #[test]
    fn replies() {
        let mut b = [0u8; 8];
        let n = encode_reply(Cmd::Version, (1, 13), b"FOC1", 0, &mut b);
        assert_eq!(&b[..n], b"V0113\r");
        let n = encode_reply(Cmd::SerialNumber, (1, 13), b"FOC1", 0, &mut b);
        assert_eq!(&b[..n], b"NFOC1\r");
        let n = encode_reply(Cmd::StatusFlags, (1, 13), b"FOC1", 0xA5, &mut b);
        assert_eq!(&b[..n], b"FA5\r");
        let n = encode_reply(Cmd::Open, (1, 13), b"FOC1", 0, &mut b);
        assert_eq!(&b[..n], b"\r");
    }

    fn any_frame() -> impl Strategy<Value = CanFrame> {
        (
            0u16..=0x7FF,
            any::<bool>(),
            proptest::collection::vec(any::<u8>(), 0..=8),
        )
            .prop_map(|(id, rtr, data)| {
                if rtr {
                    CanFrame::remote(id, data.len() as u8).unwrap()
                } else {
                    CanFrame::new(id, &data).unwrap()
                }
            })
    }

    proptest! {
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            let mut d = Decoder::new();
            for b in bytes {
                let _ = d.push(b);
            }
            // And it resynchronises at the next line end.
            let _ = d.push(b'\r');
            prop_assert_eq!(d.push(b't'), None);
            for &b in b"0800" { prop_assert_eq!(d.push(b), None); }
            prop_assert_eq!(d.push(b'\r'), Some(Event::Frame(CanFrame::new(0x80, &[]).unwrap())));
        }

        #[test]
        fn frames_round_trip(frames in proptest::collection::vec(any_frame(), 1..10)) {
            let mut d = Decoder::new();
            let mut line = [0u8; 27];
            for f in frames {
                let n = encode(&f, &mut line);
                prop_assert!(n <= MAX_FRAME_LINE);
                let mut got = None;
                for &b in &line[..n] {
                    if let Some(e) = d.push(b) {
                        prop_assert!(got.is_none());
                        got = Some(e);
                    }
                }
                prop_assert_eq!(got, Some(Event::Frame(f)));
            }
        }
    }
}
