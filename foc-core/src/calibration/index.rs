//! The index search of an incremental encoder at start-up (design §33):
//! turn the rotor slowly in a configured direction until the encoder's
//! index pulses, so that the readings can be referred to the index and a
//! stored electrical zero (and angle correction) apply after every reset.
//!
//! **The motion.** The rotor is not calibrated yet, so it is turned by a
//! field, as the alignment does (§15): a d-axis voltage `R I` (the search
//! current `I`) at an angle that first stays put for `align_s` while the
//! rotor settles onto it (it may jump by up to half an electrical turn),
//! then turns at `speed_e_rad_s` in `direction`. The rotor follows the
//! field at no more than `I`'s torque. It moves at most `max_turns`
//! mechanical turns (default 1.25: the index is within one turn) plus the
//! settling jump.
//!
//! Named failures: no index within `max_turns` ([`CalError::IndexNotFound`]),
//! a reading that does not move while the field turns two electrical
//! turns ([`CalError::SensorNoMotion`]), the current vector above
//! `1.5 I` ([`CalError::OverCurrent`]), the whole search within
//! `timeout_s` ([`CalError::Timeout`]).

use super::common::{check_input, latch, voltage_limit_v, CalError, CalInput, CalStep};
use crate::angle::{ElectricalAngle, MechanicalAngle};
use crate::frames::Dq;
use core::f32::consts::TAU;

/// Settings of the index search.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IndexSearchConfig {
    /// +1: the motor's positive direction (A -> B -> C); -1: the other.
    pub direction: i8,
    /// Search current \[A\] (> 0).
    pub current_a: f32,
    /// Phase resistance \[ohm\] (the voltage is `R I`).
    pub r_ohm: f32,
    /// Pole pairs.
    pub pole_pairs: u8,
    /// Speed of the field, electrical [rad/s] (> 0).
    pub speed_e_rad_s: f32,
    /// Time the field stays put first \[s\].
    pub align_s: f32,
    /// Largest travel before giving up [mechanical turns].
    pub max_turns: f32,
    /// Control period \[s\].
    pub ts_s: f32,
    /// Bound on the search \[s\].
    pub timeout_s: f32,
}

impl IndexSearchConfig {
    /// Defaults: the positive direction, the field at one electrical turn
    /// per second after 0.3 s in place, at most 1.25 turns, a timeout of
    /// 1.5 times the longest search.
    pub fn new(current_a: f32, r_ohm: f32, pole_pairs: u8, pwm_frequency_hz: f32) -> Self {
        let mut c = Self {
            direction: 1,
            current_a,
            r_ohm,
            pole_pairs,
            speed_e_rad_s: TAU,
            align_s: 0.3,
            max_turns: 1.25,
            ts_s: 1.0 / pwm_frequency_hz,
            timeout_s: 0.0,
        };
        c.timeout_s = 1.5 * c.longest_s();
        c
    }

    /// The longest search: the settling, and `max_turns` at the field's
    /// speed \[s\].
    pub fn longest_s(&self) -> f32 {
        self.align_s + self.max_turns * TAU * self.pole_pairs as f32 / self.speed_e_rad_s
    }

    fn check(&self) -> Result<(), CalError> {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let ok = (self.direction == 1 || self.direction == -1)
            && pos(self.current_a)
            && pos(self.r_ohm)
            && self.pole_pairs > 0
            && pos(self.speed_e_rad_s)
            && self.align_s.is_finite()
            && self.align_s >= 0.0
            && pos(self.max_turns)
            && pos(self.ts_s)
            && pos(self.timeout_s);
        if ok {
            Ok(())
        } else {
            Err(CalError::InvalidConfig)
        }
    }
}

/// The index search routine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexSearch {
    config: IndexSearchConfig,
    period: u32,
    field: ElectricalAngle,
    /// The field's travel since it started turning \[rad\] (electrical).
    field_rad: f32,
    last: Option<MechanicalAngle>,
    /// The reading's travel \[rad\] (mechanical, signed).
    travel_rad: f32,
    found: Option<MechanicalAngle>,
    finished: Option<CalStep<MechanicalAngle>>,
}

impl IndexSearch {
    /// A new search (the config is checked at the first step).
    pub fn new(config: IndexSearchConfig) -> Self {
        Self {
            config,
            period: 0,
            field: ElectricalAngle::ZERO,
            field_rad: 0.0,
            last: None,
            travel_rad: 0.0,
            found: None,
            finished: None,
        }
    }

    /// How far the reading moved \[rad\] (mechanical, signed).
    pub fn travel_rad(&self) -> f32 {
        self.travel_rad
    }

    /// One period: `inp.angle` the reading, `index` the reading latched at
    /// the index pulse this period (if it pulsed). Done with the index's
    /// reading.
    pub fn step(
        &mut self,
        inp: &CalInput,
        index: Option<MechanicalAngle>,
    ) -> CalStep<MechanicalAngle> {
        if let Some(f) = self.finished {
            return f;
        }
        let r = self.step_inner(inp, index);
        latch(&mut self.finished, r)
    }

    fn step_inner(
        &mut self,
        inp: &CalInput,
        index: Option<MechanicalAngle>,
    ) -> Result<CalStep<MechanicalAngle>, CalError> {
        let c = self.config;
        c.check()?;
        check_input(inp, 1.5 * c.current_a)?;
        self.period = self.period.saturating_add(1);
        if self.period as f32 * c.ts_s > c.timeout_s {
            return Err(CalError::Timeout);
        }
        if let Some(l) = self.last {
            self.travel_rad += inp.angle.diff_radians(l);
        }
        self.last = Some(inp.angle);
        // The index only counts once the field turns (a pulse while the
        // rotor jumps onto the field is as good, but is not expected).
        if let Some(i) = index {
            return Ok(CalStep::Done(i));
        }
        if self.travel_rad.abs() > c.max_turns * TAU {
            return Err(CalError::IndexNotFound);
        }
        if self.period as f32 * c.ts_s > c.align_s {
            let step = c.direction as f32 * c.speed_e_rad_s * c.ts_s;
            self.field = self.field.add_radians(step);
            self.field_rad += step.abs();
            let expected = self.field_rad / c.pole_pairs as f32;
            if self.field_rad > 2.0 * TAU && self.travel_rad.abs() < 0.1 * expected {
                return Err(CalError::SensorNoMotion);
            }
        }
        let v = (c.r_ohm * c.current_a).min(voltage_limit_v(f32::INFINITY, inp.v_bus_v));
        Ok(CalStep::Apply {
            v_dq: Dq::new(v, 0.0),
            theta_e: self.field,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::Abc;

    const HZ: f32 = 10_000.0;

    /// A rotor that follows the field (a pole pair behind nothing), an
    /// index at `mark` turns from the start; `None`: no index.
    fn run(
        search: &mut IndexSearch,
        mark: Option<f32>,
        stuck: bool,
    ) -> (CalStep<MechanicalAngle>, f32) {
        let pp = 4.0f32;
        for _ in 0..1_000_000 {
            let pos = if stuck {
                0.0
            } else {
                search.field_rad * search.config.direction as f32 / pp
            };
            let reading = MechanicalAngle::from_radians(0.2 + pos);
            let inp = CalInput::open_loop(Abc::default(), reading, 24.0);
            let index = mark
                .filter(|m| (pos / TAU - m).abs() < 2e-4)
                .map(|_| reading);
            match search.step(&inp, index) {
                CalStep::Apply { .. } => {}
                other => return (other, pos),
            }
        }
        panic!("did not finish");
    }

    #[test]
    fn finds_the_index_within_a_turn_either_way() {
        for dir in [1i8, -1] {
            let c = IndexSearchConfig {
                direction: dir,
                ..IndexSearchConfig::new(2.0, 0.5, 4, HZ)
            };
            let mut s = IndexSearch::new(c);
            let (end, pos) = run(&mut s, Some(0.6 * dir as f32), false);
            assert!(matches!(end, CalStep::Done(_)), "{end:?}");
            assert!((pos / TAU - 0.6 * dir as f32).abs() < 1e-3, "{pos}");
        }
    }

    #[test]
    fn named_failures() {
        let c = IndexSearchConfig::new(2.0, 0.5, 4, HZ);
        assert_eq!(
            run(&mut IndexSearch::new(c), None, false).0,
            CalStep::Failed(CalError::IndexNotFound)
        );
        assert_eq!(
            run(&mut IndexSearch::new(c), Some(0.5), true).0,
            CalStep::Failed(CalError::SensorNoMotion)
        );
        let bad = IndexSearchConfig { direction: 0, ..c };
        assert_eq!(
            run(&mut IndexSearch::new(bad), Some(0.5), false).0,
            CalStep::Failed(CalError::InvalidConfig)
        );
        let mut s = IndexSearch::new(c);
        let hot = CalInput::open_loop(Abc::new(4.0, -2.0, -2.0), MechanicalAngle::ZERO, 24.0);
        assert_eq!(s.step(&hot, None), CalStep::Failed(CalError::OverCurrent));
    }
}
