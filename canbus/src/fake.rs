//! [`FakeNode`]: a stand-in [`BusNode`] for the bus's own tests (no drive,
//! no object dictionary). It speaks just enough CANopen to be seen:
//!
//! | event | it sends |
//! |---|---|
//! | boot | boot-up `0x700+id [0x00]` |
//! | every `heartbeat_ms` of bus time | heartbeat `0x700+id [state]` |
//! | NMT `0x000 [cs, id or 0]` | nothing; state 0x05 (start `0x01`), 0x04 (stop `0x02`), 0x7F (pre-op `0x80`); `0x81`/`0x82` reboot (boot-up again) |
//! | a frame to `0x600+id` | echo of its data on `0x580+id` |
//! | SYNC `0x080` | `0x180+id`: bus time \[us\] (u32 LE), PWM periods run (u32 LE) |
//! | bus state change | `0x080+id [0x00, 0x81, state]` (EMCY-like, on recovery only: nothing gets out while bus-off) |
//! | a fault injected | `0x080+id [0x10, 0x00, 0x01]` at the next tick |

use crate::bus::{BusNode, BusState};
use foc_canopen::CanFrame;

/// PWM frequency the fake drive "runs" at \[Hz\] (counted in its TPDO).
pub const FAKE_PWM_HZ: u64 = 20_000;

/// PWM periods between bus times `from_us` and `to_us` at `pwm_hz`:
/// counted on the absolute grid, so any split of a span gives the same
/// total.
pub fn periods_between(from_us: u64, to_us: u64, pwm_hz: u64) -> u64 {
    let at = |t: u64| (u128::from(t) * u128::from(pwm_hz) / 1_000_000) as u64;
    at(to_us).saturating_sub(at(from_us))
}

/// The stand-in node (see the module docs).
#[derive(Clone, Debug)]
pub struct FakeNode {
    id: u8,
    /// Heartbeat period \[ms\] (0: none).
    pub heartbeat_ms: u64,
    state: u8,
    periods: u64,
    fault_pending: bool,
    /// Power cycles so far.
    pub boots: u32,
}

impl FakeNode {
    /// Node `id` with a 100 ms heartbeat.
    pub fn new(id: u8) -> Self {
        Self {
            id,
            heartbeat_ms: 100,
            state: 0x7F,
            periods: 0,
            fault_pending: false,
            boots: 0,
        }
    }

    fn frame(&self, base: u16, data: &[u8]) -> Option<CanFrame> {
        CanFrame::new(base + u16::from(self.id), data)
    }

    fn boot_up(&mut self, out: &mut dyn FnMut(CanFrame)) {
        self.state = 0x7F;
        self.boots = self.boots.saturating_add(1);
        if let Some(f) = self.frame(0x700, &[0]) {
            out(f);
        }
    }
}

impl BusNode for FakeNode {
    fn node_id(&self) -> u8 {
        self.id
    }
    fn boot(&mut self, _now_us: u64, out: &mut dyn FnMut(CanFrame)) {
        self.boot_up(out);
    }
    fn on_frame(&mut self, f: &CanFrame, now_us: u64, out: &mut dyn FnMut(CanFrame)) {
        let id = u16::from(self.id);
        match f.id {
            0x000 => {
                let d = f.data();
                let (Some(&cs), Some(&target)) = (d.first(), d.get(1)) else {
                    return;
                };
                if target != 0 && target != self.id {
                    return;
                }
                match cs {
                    0x01 => self.state = 0x05,
                    0x02 => self.state = 0x04,
                    0x80 => self.state = 0x7F,
                    0x81 | 0x82 => self.boot_up(out),
                    _ => {}
                }
            }
            0x080 => {
                let mut d = [0u8; 8];
                d[..4].copy_from_slice(&(now_us as u32).to_le_bytes());
                d[4..].copy_from_slice(&(self.periods as u32).to_le_bytes());
                if let Some(r) = self.frame(0x180, &d) {
                    out(r);
                }
            }
            x if x == 0x600 + id => {
                if let Some(r) = self.frame(0x580, f.data()) {
                    out(r);
                }
            }
            _ => {}
        }
    }
    fn tick(&mut self, now_us: u64, out: &mut dyn FnMut(CanFrame)) {
        if self.fault_pending {
            self.fault_pending = false;
            if let Some(f) = self.frame(0x080, &[0x10, 0x00, 0x01]) {
                out(f);
            }
        }
        let period_us = self.heartbeat_ms.saturating_mul(1000);
        if period_us > 0 && now_us.is_multiple_of(period_us) {
            if let Some(f) = self.frame(0x700, &[self.state]) {
                out(f);
            }
        }
    }
    fn advance(&mut self, from_us: u64, to_us: u64) {
        self.periods += periods_between(from_us, to_us, FAKE_PWM_HZ);
    }
    fn on_bus_state(&mut self, state: BusState, _now_us: u64, out: &mut dyn FnMut(CanFrame)) {
        let code = match state {
            BusState::ErrorActive => 0,
            BusState::ErrorPassive => 1,
            BusState::BusOff => 2,
        };
        if let Some(f) = self.frame(0x080, &[0x00, 0x81, code]) {
            out(f);
        }
    }
    fn power_cycle(&mut self) {
        self.periods = 0;
        self.fault_pending = false;
    }
    fn inject_fault(&mut self, kind: &str) -> Result<String, String> {
        self.fault_pending = true;
        Ok(format!("node {} fake fault {kind}", self.id))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn periods_do_not_depend_on_the_split() {
        assert_eq!(periods_between(0, 1000, 20_000), 20);
        let split: u64 = (0..10)
            .map(|k| periods_between(k * 333, (k + 1) * 333, 30_000))
            .sum();
        assert_eq!(split, periods_between(0, 3330, 30_000));
    }
}
