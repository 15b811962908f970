//! The emulated board's instrument port: what a test bench does to the
//! simulated world and reads from it, as text lines on a UART (QEMU's first
//! `-serial`, USART1). It is the emulated *hardware*'s, not the firmware's:
//! the firmware never reads it, so a scenario driven from the host over the
//! command link can load the motor, break its sensor or read the true state
//! (the bench's oscilloscope) without any test code in the firmware.
//!
//! Requests, one per line (`\n`), answered with one line each:
//!
//! | request | does | reply |
//! |---|---|---|
//! | `load NM` | load torque opposing positive rotation [N m] | `ok` |
//! | `jump COUNTS` | the encoder jumps by COUNTS | `ok` |
//! | `stuck` | the encoder freezes | `ok` |
//! | `clear` | every injected fault removed | `ok` |
//! | `break` | the timer's break input raised (gate-driver fault) | `ok` |
//! | `panic` | a panic in the emulated hardware's interrupt (the firmware's panic handler runs) | none |
//! | `truth` | - | `truth T W P BRIDGE OUTPUTS BREAK AFTER PERIODS VBUS EBRAKE` |
//! | `watch W` | arm the stop watch with a speed bound W [rad/s] | `ok` |
//! | `watch?` | - | `watch PEAK_VBUS SETTLE_PERIODS ARMED_AT EBRAKE0 EKIN0` (or `watch none`) |
//!
//! `truth`: simulated time [s], true mechanical speed [rad/s] and unwrapped
//! position [rad], the bridge conducting last period (0/1), the outputs
//! commanded on (0/1), the break latch (0/1), periods conducted with the
//! break latched, periods simulated, true bus voltage [V], brake-resistor
//! energy [J]. An unknown or malformed request answers `error`.
//!
//! ```
//! use board_support::logic::instrument::{Request, LineBuf};
//! assert_eq!(Request::parse(b"load 0.1"), Some(Request::Load(0.1)));
//! assert_eq!(Request::parse(b"jump 1024"), Some(Request::Jump(1024)));
//! assert_eq!(Request::parse(b"watch?"), Some(Request::WatchRead));
//! assert_eq!(Request::parse(b"load x"), None);
//! let mut l = LineBuf::new();
//! assert_eq!(l.push(b't'), None);
//! for b in *b"ruth" { l.push(b); }
//! assert_eq!(l.push(b'\n'), Some(Request::Truth).map(|_| &b"truth"[..]));
//! ```

/// One request of the instrument port.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Request {
    /// `load NM`.
    Load(f32),
    /// `jump COUNTS`.
    Jump(i32),
    /// `stuck`.
    Stuck,
    /// `clear`.
    Clear,
    /// `break`.
    Break,
    /// `panic`.
    Panic,
    /// `truth`.
    Truth,
    /// `watch W`.
    Watch(f32),
    /// `watch?`.
    WatchRead,
}

impl Request {
    /// Parse one line (without its `\n`); `None` when it is not a request.
    pub fn parse(line: &[u8]) -> Option<Self> {
        let line = core::str::from_utf8(line).ok()?.trim();
        let (word, arg) = match line.split_once(' ') {
            Some((w, a)) => (w, Some(a.trim())),
            None => (line, None),
        };
        let num =
            |a: Option<&str>| -> Option<f32> { a?.parse::<f32>().ok().filter(|x| x.is_finite()) };
        Some(match (word, arg) {
            ("load", a) => Self::Load(num(a)?),
            ("jump", Some(a)) => Self::Jump(a.parse().ok()?),
            ("stuck", None) => Self::Stuck,
            ("clear", None) => Self::Clear,
            ("break", None) => Self::Break,
            ("panic", None) => Self::Panic,
            ("truth", None) => Self::Truth,
            ("watch?", None) => Self::WatchRead,
            ("watch", a) => Self::Watch(num(a)?),
            _ => return None,
        })
    }
}

/// Bytes of one request line (longer lines are dropped whole).
pub const LINE_CAPACITY: usize = 32;

/// Received bytes gathered into lines.
#[derive(Clone, Copy, Debug)]
pub struct LineBuf {
    buf: [u8; LINE_CAPACITY],
    len: usize,
    overflow: bool,
}

impl Default for LineBuf {
    fn default() -> Self {
        Self::new()
    }
}

impl LineBuf {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            buf: [0; LINE_CAPACITY],
            len: 0,
            overflow: false,
        }
    }

    /// Take one byte; at `\n` the complete line (without it), unless it
    /// was too long.
    pub fn push(&mut self, b: u8) -> Option<&[u8]> {
        if b == b'\n' {
            let (n, over) = (self.len, self.overflow);
            self.len = 0;
            self.overflow = false;
            return if over { None } else { self.buf.get(..n) };
        }
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = b;
                self.len += 1;
            }
            None => self.overflow = true,
        }
        None
    }
}

/// Bytes of one reply line.
pub const REPLY_CAPACITY: usize = 192;

/// A reply being formatted (`core::fmt::Write`; what does not fit is cut).
#[derive(Clone, Copy, Debug)]
pub struct Reply {
    buf: [u8; REPLY_CAPACITY],
    len: usize,
}

impl Default for Reply {
    fn default() -> Self {
        Self::new()
    }
}

impl Reply {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            buf: [0; REPLY_CAPACITY],
            len: 0,
        }
    }

    /// The text so far.
    pub fn as_bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }
}

impl core::fmt::Write for Reply {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for &b in s.as_bytes() {
            match self.buf.get_mut(self.len) {
                Some(slot) => {
                    *slot = b;
                    self.len += 1;
                }
                None => return Err(core::fmt::Error),
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::fmt::Write as _;

    #[test]
    fn requests_parse_and_bad_ones_do_not() {
        assert_eq!(Request::parse(b"load -0.25"), Some(Request::Load(-0.25)));
        assert_eq!(Request::parse(b"watch 2"), Some(Request::Watch(2.0)));
        assert_eq!(Request::parse(b"break"), Some(Request::Break));
        assert_eq!(Request::parse(b"truth\r"), Some(Request::Truth));
        for bad in [
            &b"load"[..],
            b"load nan",
            b"jump",
            b"jump 1.5",
            b"truth 1",
            b"",
            b"\xff",
        ] {
            assert_eq!(Request::parse(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn long_lines_are_dropped_whole() {
        let mut l = LineBuf::new();
        for _ in 0..(LINE_CAPACITY + 5) {
            assert_eq!(l.push(b'x'), None);
        }
        assert_eq!(l.push(b'\n'), None);
        for b in *b"clear" {
            l.push(b);
        }
        assert_eq!(l.push(b'\n'), Some(&b"clear"[..]));
    }

    #[test]
    fn replies_are_cut_not_overrun() {
        let mut r = Reply::new();
        for _ in 0..100 {
            let _ = write!(r, "0123456789");
        }
        assert_eq!(r.as_bytes().len(), REPLY_CAPACITY);
    }
}
