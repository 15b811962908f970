//! The shape shared by every identification routine: per-period inputs
//! ([`CalInput`]), the per-period answer ([`CalStep`]) and the failure
//! reasons ([`CalError`]).
//!
//! A routine is a state machine stepped once per PWM period from the current
//! loop. Each call takes this period's measurements and returns either a
//! command for this period ([`CalStep::Apply`]: an open-loop dq voltage at an
//! electrical angle, [`CalStep::Velocity`]: a closed-loop velocity request,
//! or [`CalStep::Torque`]: a closed-loop q-current request), the result ([`CalStep::Done`]) or the reason it stopped
//! ([`CalStep::Failed`]). After `Done` or `Failed` every further call
//! returns the same value: the caller must then command something else
//! (usually zero voltage or the safe state).
//!
//! ```
//! use foc_core::calibration::{CalInput, CalStep};
//! use foc_core::{angle::MechanicalAngle, frames::{Abc, Dq}};
//! let inp = CalInput::open_loop(Abc::new(0.0, 0.0, 0.0), MechanicalAngle::ZERO, 24.0);
//! assert!(inp.closed_loop.is_none());
//! let s: CalStep<f32> = CalStep::Done(1.5);
//! assert!(s.is_finished());
//! assert_eq!(s.voltage(), None);
//! ```

use crate::angle::ElectricalAngle;
use crate::angle::MechanicalAngle;
use crate::frames::{Abc, Dq};
use crate::{transforms, trig, FRAC_1_SQRT_3};

/// Fraction of the linear modulation range `Udc / sqrt(3)` the routines
/// may use (the same margin as the current loop's default).
pub const MAX_MODULATION: f32 = 0.95;

/// What a routine asks for this period, or how it ended.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalStep<T> {
    /// Apply this open-loop voltage \[V\] in the dq frame of `theta_e` (e.g.
    /// through `CurrentLoop::step_voltage` or `Command::OpenLoop` with
    /// `omega_e_rad_s = 0`). Already limited to the routine's voltage limit
    /// and to the voltage circle of the measured bus.
    Apply {
        /// dq voltage \[V\].
        v_dq: Dq,
        /// Electrical angle of the d axis of `v_dq`.
        theta_e: ElectricalAngle,
    },
    /// Run the closed-loop velocity mode at this *mechanical* speed [rad/s]
    /// (as `Command::Velocity`) and pass back
    /// [`CalInput::closed_loop`] every period.
    Velocity {
        /// Mechanical velocity reference [rad/s].
        rad_s: f32,
    },
    /// Run the closed-loop current (torque) mode at this q current \[A\]
    /// with `id = 0` (as `Command::Torque`) and pass back
    /// [`CalInput::closed_loop`] every period.
    Torque {
        /// q-axis current reference \[A\].
        iq_a: f32,
    },
    /// Finished with this result.
    Done(T),
    /// Stopped; the reason.
    Failed(CalError),
}

impl<T> CalStep<T> {
    /// True for `Done` and `Failed`.
    pub const fn is_finished(&self) -> bool {
        matches!(self, CalStep::Done(_) | CalStep::Failed(_))
    }

    /// The open-loop voltage of an `Apply` step.
    pub fn voltage(&self) -> Option<(Dq, ElectricalAngle)> {
        match self {
            CalStep::Apply { v_dq, theta_e } => Some((*v_dq, *theta_e)),
            _ => None,
        }
    }

    /// Convert the result type (commands and failures pass unchanged).
    pub fn map<U>(self, f: impl FnOnce(T) -> U) -> CalStep<U> {
        match self {
            CalStep::Apply { v_dq, theta_e } => CalStep::Apply { v_dq, theta_e },
            CalStep::Velocity { rad_s } => CalStep::Velocity { rad_s },
            CalStep::Torque { iq_a } => CalStep::Torque { iq_a },
            CalStep::Done(t) => CalStep::Done(f(t)),
            CalStep::Failed(e) => CalStep::Failed(e),
        }
    }
}

/// A motor phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Phase {
    /// Phase A (electrical axis at 0 degrees).
    A,
    /// Phase B (120 degrees).
    B,
    /// Phase C (240 degrees).
    C,
}

/// Why an identification routine stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalError {
    /// A measurement was NaN or infinite, or the bus voltage was not positive.
    InvalidInput,
    /// The configuration is unusable (non-positive time, current, limit...).
    InvalidConfig,
    /// The current vector exceeded the routine's current limit.
    OverCurrent,
    /// A step did not finish within its time limit.
    Timeout,
    /// No current flows at this phase's angle at the voltage limit: the
    /// phase (or its wire / switch) is disconnected.
    OpenPhase(Phase),
    /// Substantial current flows but the target is not reached at the
    /// voltage limit (resistance too high for the test current, or bus too
    /// low): lower the test current or raise the voltage limit.
    VoltageLimitReached,
    /// The resistances measured at 0, 120 and 240 degrees disagree by more
    /// than the tolerance.
    PhaseImbalance,
    /// The measured current vector points away from the commanded voltage
    /// vector (by more than the configured angle): current-sense phase
    /// order, gain sign or motor wiring do not match.
    CurrentSenseMismatch,
    /// The current ripple of the inductance measurement stayed too small
    /// to measure at the voltage limit.
    NoCurrentResponse,
    /// Electrical turns commanded per mechanical turn measured differ from
    /// the configured pole-pair count. Never absorbed: fix the configuration.
    PolePairMismatch {
        /// Configured pole pairs.
        configured: u8,
        /// Measured pole pairs times 100 (saturating).
        measured_x100: u16,
    },
    /// The sensor counts opposite to the direction the configuration states.
    SensorReversed,
    /// The sensor showed motion, but the rotor did not follow the rotating
    /// field throughout (blocked part way, or much less travel one way than
    /// the other).
    RotorStuck,
    /// The sensor reading did not change while the field turned (dead or
    /// frozen sensor, missing magnet; also a fully blocked rotor).
    SensorNoMotion,
    /// The closed-loop speed did not settle at the requested value in time
    /// (flux step), or a torque pulse moved the rotor but did not reach the
    /// target speed in time (mechanical step: friction or load too high for
    /// the test current, or the target too high).
    SpeedNotReached,
    /// The measurement finished but the value is not physical (non-positive,
    /// non-finite, or scattered beyond use).
    ImplausibleResult,
    /// The rotor did not accelerate under the mechanical step's test
    /// torque (locked rotor, or friction above the test torque).
    NoAcceleration,
    /// The identified inertia is outside the configured plausible range
    /// (or not positive).
    InertiaOutOfRange,
    /// The identified viscous or Coulomb friction is outside the configured
    /// bounds, or above the torque that accelerated the rotor.
    FrictionOutOfRange,
    /// Too few usable windows for the mechanical fit, or windows that do
    /// not separate inertia, viscous and Coulomb friction.
    MechanicsIllConditioned,
    /// The encoder's index did not pulse within the index search's travel
    /// (design §33): no index, a broken index line, or the wrong sensor.
    IndexNotFound,
}

/// Closed-loop measurements for [`CalStep::Velocity`] and [`CalStep::Torque`]
/// requests (from the current stage's `Feedback`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClosedLoopFeedback {
    /// Commanded dq voltage of the current loop \[V\] (`Feedback::v_dq_v`).
    pub v_dq_v: Dq,
    /// Measured dq current \[A\] (`Feedback::i_dq_a`).
    pub i_dq_a: Dq,
    /// Measured mechanical velocity [rad/s] (`Feedback::velocity_rad_s`).
    pub velocity_rad_s: f32,
    /// Electrical angle the current loop used (`Feedback::theta_e`).
    pub theta_e: ElectricalAngle,
}

/// One period's measurements for a routine.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CalInput {
    /// Measured phase currents \[A\] (offsets removed).
    pub i_abc_a: Abc,
    /// Raw angle-sensor reading (no direction, pole-pair or offset applied).
    pub angle: MechanicalAngle,
    /// Measured bus voltage \[V\].
    pub v_bus_v: f32,
    /// Closed-loop feedback while answering a [`CalStep::Velocity`] or
    /// [`CalStep::Torque`] request; `None` otherwise.
    pub closed_loop: Option<ClosedLoopFeedback>,
}

impl CalInput {
    /// Input for the open-loop routines (no closed-loop feedback).
    pub const fn open_loop(i_abc_a: Abc, angle: MechanicalAngle, v_bus_v: f32) -> Self {
        Self {
            i_abc_a,
            angle,
            v_bus_v,
            closed_loop: None,
        }
    }
}

/// A routine's step with its outcome latched: the first `Done` or `Failed`
/// (an `Err` from the routine becomes `Failed`) is stored in `finished`,
/// which the routine returns from then on.
pub(crate) fn latch<T: Copy>(
    finished: &mut Option<CalStep<T>>,
    r: Result<CalStep<T>, CalError>,
) -> CalStep<T> {
    let out = r.unwrap_or_else(CalStep::Failed);
    if out.is_finished() {
        *finished = Some(out);
    }
    out
}

/// Usable open-loop voltage magnitude \[V\]: the configured limit or the
/// voltage circle of the bus, whichever is smaller.
#[inline]
pub(crate) fn voltage_limit_v(max_voltage_v: f32, v_bus_v: f32) -> f32 {
    let bus = MAX_MODULATION * v_bus_v * FRAC_1_SQRT_3;
    if bus < max_voltage_v {
        bus
    } else {
        max_voltage_v
    }
}

/// Check one period's input: finite currents and bus, bus above zero,
/// current vector within `max_current_a`.
pub(crate) fn check_input(inp: &CalInput, max_current_a: f32) -> Result<(), CalError> {
    if !inp.i_abc_a.is_finite() || !inp.v_bus_v.is_finite() || inp.v_bus_v <= 0.0 {
        return Err(CalError::InvalidInput);
    }
    if let Some(f) = inp.closed_loop {
        if !f.v_dq_v.is_finite() || !f.i_dq_a.is_finite() || !f.velocity_rad_s.is_finite() {
            return Err(CalError::InvalidInput);
        }
    }
    if transforms::clarke(inp.i_abc_a).magnitude() > max_current_a {
        return Err(CalError::OverCurrent);
    }
    Ok(())
}

/// Measured currents in the dq frame of `theta_e` \[A\].
#[inline]
pub(crate) fn current_dq(i_abc_a: Abc, theta_e: ElectricalAngle) -> Dq {
    let (s, c) = trig::sin_cos(theta_e);
    transforms::park(transforms::clarke(i_abc_a), s, c)
}

/// Periods in `s` seconds at period `ts_s` (at least 1, saturating).
#[inline]
pub(crate) fn periods(s: f32, ts_s: f32) -> u32 {
    let n = s / ts_s + 0.5;
    if n.is_finite() && n >= 1.0 {
        if n < 4.0e9 {
            n as u32
        } else {
            u32::MAX
        }
    } else {
        1
    }
}

/// One step of the voltage integrator that drives a DC current to
/// `target_a`: `dv/dt = wc (v / i) (target - i)` once current flows (a
/// first-order approach at `wc` whatever the resistance, since `v / i` is
/// the resistance seen), at most `ramp_v_per_s` in either direction, and a
/// plain ramp at `ramp_v_per_s` while `i` is below 5 % of the target.
/// Returns the new voltage in `[0, v_lim]`.
#[inline]
pub(crate) fn approach_v(
    v: f32,
    i_a: f32,
    target_a: f32,
    wc_rad_s: f32,
    ramp_v_per_s: f32,
    ts_s: f32,
    v_lim: f32,
) -> f32 {
    let max_dv = ramp_v_per_s * ts_s;
    let dv = if i_a > 0.05 * target_a && v > 0.0 {
        let gain = wc_rad_s * v / i_a; // [V/(A s)]
        crate::clamp(gain * (target_a - i_a) * ts_s, -max_dv, max_dv)
    } else {
        max_dv
    };
    crate::clamp(v + dv, 0.0, v_lim)
}

/// Rotor-motion detector from the raw sensor: "moving" as soon as the
/// reading is more than 1/1024 turn from a snapshot, "still" again after
/// 64 periods within that distance. The DC routines hold their voltage
/// while the rotor swings into a new field position (the back-EMF of a
/// heavy, low-resistance rotor would otherwise let the integrator wind
/// up and over-shoot once the rotor stops).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Motion {
    snap: Option<MechanicalAngle>,
    n: u8,
    moving: bool,
}

impl Motion {
    pub(crate) const NEW: Self = Self {
        snap: None,
        n: 0,
        moving: false,
    };
    /// Feed this period's reading; true while the rotor moves.
    pub(crate) fn update(&mut self, a: MechanicalAngle) -> bool {
        match self.snap {
            None => self.snap = Some(a),
            Some(s) => {
                let d = a.wrapping_sub(s).to_bits() as i32;
                if d.unsigned_abs() > (1u32 << 22) {
                    self.moving = true;
                    self.snap = Some(a);
                    self.n = 0;
                } else {
                    self.n = self.n.saturating_add(1);
                    if self.n >= 64 {
                        self.moving = false;
                        self.snap = Some(a);
                        self.n = 0;
                    }
                }
            }
        }
        self.moving
    }
}

/// Running mean of a scalar.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Mean {
    sum: f32,
    n: u32,
}

impl Mean {
    pub(crate) const ZERO: Self = Self { sum: 0.0, n: 0 };
    #[inline]
    pub(crate) fn add(&mut self, x: f32) {
        self.sum += x;
        self.n = self.n.saturating_add(1);
    }
    #[inline]
    pub(crate) fn count(&self) -> u32 {
        self.n
    }
    #[inline]
    pub(crate) fn mean(&self) -> f32 {
        if self.n == 0 {
            0.0
        } else {
            self.sum / self.n as f32
        }
    }
}

/// Circular mean of angles (sum of unit vectors).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct CircularMean {
    sin: f32,
    cos: f32,
    n: u32,
}

impl CircularMean {
    #[inline]
    pub(crate) fn add(&mut self, a: ElectricalAngle) {
        let (s, c) = trig::sin_cos(a);
        self.sin += s;
        self.cos += c;
        self.n = self.n.saturating_add(1);
    }
    /// Add another accumulator's points.
    #[inline]
    pub(crate) fn merge(&mut self, o: &Self) {
        self.sin += o.sin;
        self.cos += o.cos;
        self.n = self.n.saturating_add(o.n);
    }
    /// The mean angle and the mean resultant length (1 = all equal,
    /// 0 = spread evenly); `None` with no points.
    pub(crate) fn mean(&self) -> Option<(ElectricalAngle, f32)> {
        if self.n == 0 {
            return None;
        }
        let n = self.n as f32;
        let (s, c) = (self.sin / n, self.cos / n);
        let len = crate::sqrtf(s * s + c * c);
        Some((ElectricalAngle::from_radians(libm::atan2f(s, c)), len))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn circular_mean_across_wrap() {
        let mut m = CircularMean::default();
        m.add(ElectricalAngle::from_degrees(350.0));
        m.add(ElectricalAngle::from_degrees(10.0));
        let (a, len) = m.mean().unwrap();
        assert!(a.diff_radians(ElectricalAngle::ZERO).abs() < 1e-5);
        assert!(len > 0.98);
        assert_eq!(CircularMean::default().mean(), None);
    }

    #[test]
    fn limits_and_checks() {
        assert!((voltage_limit_v(100.0, 24.0) - 0.95 * 24.0 / 3f32.sqrt()).abs() < 1e-4);
        assert_eq!(voltage_limit_v(2.0, 24.0), 2.0);
        let ok = CalInput::open_loop(Abc::new(1.0, -0.5, -0.5), MechanicalAngle::ZERO, 24.0);
        assert_eq!(check_input(&ok, 2.0), Ok(()));
        assert_eq!(check_input(&ok, 0.5), Err(CalError::OverCurrent));
        let mut bad = ok;
        bad.i_abc_a.b = f32::NAN;
        assert_eq!(check_input(&bad, 2.0), Err(CalError::InvalidInput));
        let mut bad = ok;
        bad.v_bus_v = f32::NAN;
        assert_eq!(check_input(&bad, 2.0), Err(CalError::InvalidInput));
        assert_eq!(periods(0.01, 1e-4), 100);
        assert_eq!(periods(f32::NAN, 1e-4), 1);
    }
}
