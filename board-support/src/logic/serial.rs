//! Pure parts of the command UART driver (`crate::hw::serial`): the
//! baud-rate register encoding and the byte rings, tested on the host.
//!
//! ```
//! use board_support::logic::serial::{brr_value, Ring};
//! assert_eq!(brr_value(45_000_000, 115_200), 391);
//! let mut r: Ring<8> = Ring::new();
//! assert!(r.push(7));
//! assert_eq!(r.pop(), Some(7));
//! ```

/// `USARTDIV` as written to BRR with 16x oversampling: `fck / baud`,
/// rounded (mantissa in bits 15:4, fraction in 3:0; RM0090 30.6.3).
pub const fn brr_value(pclk_hz: u32, baud: u32) -> u16 {
    if baud == 0 {
        return 0xFFFF;
    }
    let v = (pclk_hz + baud / 2) / baud;
    if v < 16 {
        16
    } else if v > 0xFFFF {
        0xFFFF
    } else {
        v as u16
    }
}

/// A fixed-capacity byte ring (one slot kept free: `N - 1` usable bytes;
/// `N >= 2`).
pub struct Ring<const N: usize> {
    buf: [u8; N],
    head: usize,
    tail: usize,
}

impl<const N: usize> Ring<N> {
    /// Empty ring.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            head: 0,
            tail: 0,
        }
    }
    /// Bytes queued.
    pub fn len(&self) -> usize {
        (self.head + N - self.tail) % N
    }
    /// True when nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.head == self.tail
    }
    /// Free slots.
    pub fn free(&self) -> usize {
        N - 1 - self.len()
    }
    /// Append; false (nothing stored) when full.
    pub fn push(&mut self, b: u8) -> bool {
        let next = (self.head + 1) % N;
        if next == self.tail {
            return false;
        }
        if let Some(slot) = self.buf.get_mut(self.head) {
            *slot = b;
        }
        self.head = next;
        true
    }
    /// Oldest byte.
    pub fn pop(&mut self) -> Option<u8> {
        if self.head == self.tail {
            return None;
        }
        let b = self.buf.get(self.tail).copied();
        self.tail = (self.tail + 1) % N;
        b
    }
}

impl<const N: usize> Default for Ring<N> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn brr_for_the_boards() {
        // 45 MHz / 115200 = 390.6 -> 391 (0.1 % error).
        assert_eq!(brr_value(45_000_000, 115_200), 391);
        assert_eq!(brr_value(42_000_000, 115_200), 365);
        assert_eq!(brr_value(16_000_000, 115_200), 139);
        assert_eq!(brr_value(1, 0), 0xFFFF);
    }

    #[test]
    fn ring_keeps_order_and_refuses_when_full() {
        let mut r: Ring<4> = Ring::new();
        assert!(r.push(1) && r.push(2) && r.push(3));
        assert!(!r.push(4));
        assert_eq!(r.free(), 0);
        assert_eq!(r.pop(), Some(1));
        assert!(r.push(4));
        assert_eq!(
            (r.pop(), r.pop(), r.pop(), r.pop()),
            (Some(2), Some(3), Some(4), None)
        );
    }
}
