//! Robot-joint features (design §21): the output frame after a gearbox, the
//! impedance law and the travel limits' soft stop.
//!
//! Everything inside the drive runs in the **rotor frame** (mechanical
//! radians of the motor shaft, N m at the motor shaft). A joint is commanded
//! in the **output frame** (the shaft after the gearbox, with the home
//! offset): [`OutputFrame`] converts at the interfaces, in one place.
//!
//! ```text
//! p_out = (p_rotor - rotor_at_zero) / g        g: rotor turns per output turn
//! v_out = v_rotor / g                          (signed: g < 0 reverses)
//! T_out = T_rotor * g                          (no gearbox losses modelled)
//! kp_out = kp_rotor * g^2,  kd_out = kd_rotor * g^2
//! ```
//!
//! ```
//! use foc_core::control::joint::OutputFrame;
//! let f = OutputFrame::new(-20.0, 3.0).unwrap(); // 20:1, reversed; rotor at 3 rad = output 0
//! assert!((f.position_to_output(3.0 - 20.0) - 1.0).abs() < 1e-6);
//! assert!((f.stiffness_to_rotor(400.0) - 1.0).abs() < 1e-6);
//! assert!(OutputFrame::new(0.0, 0.0).is_none());
//! ```

use super::{Command, CommandError, Limits};

/// The output frame: a gear ratio and where the output's zero is.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OutputFrame {
    /// Rotor turns per output turn; negative when the output turns the
    /// other way (|g| in [[`Self::MIN_RATIO`], [`Self::MAX_RATIO`]]).
    gear_ratio: f32,
    /// The rotor position where the output reads 0 [rad, rotor, mechanical]
    /// (set by homing).
    rotor_at_zero_rad: f32,
}

/// Why a joint setting was refused (nothing changed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum JointError {
    /// The gear ratio is not finite or its magnitude is outside
    /// [`OutputFrame::MIN_RATIO`]..=[`OutputFrame::MAX_RATIO`].
    GearRatio,
    /// The output offset is not finite.
    Offset,
    /// A travel or impedance setting is not finite, negative, or the
    /// travel limits are out of order.
    Travel,
}

impl Default for OutputFrame {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl OutputFrame {
    /// Smallest gear ratio magnitude accepted.
    pub const MIN_RATIO: f32 = 0.01;
    /// Largest gear ratio magnitude accepted.
    pub const MAX_RATIO: f32 = 10_000.0;
    /// No gearbox, output zero at rotor zero.
    pub const IDENTITY: Self = Self {
        gear_ratio: 1.0,
        rotor_at_zero_rad: 0.0,
    };

    /// A frame, `None` when a value is out of range ([`Self::check`]).
    pub fn new(gear_ratio: f32, rotor_at_zero_rad: f32) -> Option<Self> {
        Self::check(gear_ratio, rotor_at_zero_rad).ok()
    }

    /// Check the two values.
    pub fn check(gear_ratio: f32, rotor_at_zero_rad: f32) -> Result<Self, JointError> {
        let m = gear_ratio.abs();
        if !(gear_ratio.is_finite() && (Self::MIN_RATIO..=Self::MAX_RATIO).contains(&m)) {
            return Err(JointError::GearRatio);
        }
        if !rotor_at_zero_rad.is_finite() {
            return Err(JointError::Offset);
        }
        Ok(Self {
            gear_ratio,
            rotor_at_zero_rad,
        })
    }

    /// Rotor turns per output turn (signed).
    pub fn gear_ratio(&self) -> f32 {
        self.gear_ratio
    }

    /// The rotor position where the output reads 0 [rad, rotor].
    pub fn rotor_at_zero_rad(&self) -> f32 {
        self.rotor_at_zero_rad
    }

    /// The same gear with the output reading `output_rad` at the rotor
    /// position `rotor_rad` (homing).
    pub fn homed_at(&self, rotor_rad: f32, output_rad: f32) -> Option<Self> {
        Self::new(self.gear_ratio, rotor_rad - self.gear_ratio * output_rad)
    }

    /// Rotor position \[rad\] -> output position \[rad\].
    pub fn position_to_output(&self, rotor_rad: f32) -> f32 {
        (rotor_rad - self.rotor_at_zero_rad) / self.gear_ratio
    }
    /// Output position \[rad\] -> rotor position \[rad\].
    pub fn position_to_rotor(&self, output_rad: f32) -> f32 {
        self.rotor_at_zero_rad + self.gear_ratio * output_rad
    }
    /// Rotor velocity [rad/s] -> output velocity [rad/s].
    pub fn velocity_to_output(&self, rotor_rad_s: f32) -> f32 {
        rotor_rad_s / self.gear_ratio
    }
    /// Output velocity [rad/s] -> rotor velocity [rad/s].
    pub fn velocity_to_rotor(&self, output_rad_s: f32) -> f32 {
        output_rad_s * self.gear_ratio
    }
    /// Rotor torque [N m] -> output torque [N m].
    pub fn torque_to_output(&self, rotor_nm: f32) -> f32 {
        rotor_nm * self.gear_ratio
    }
    /// Output torque [N m] -> rotor torque [N m].
    pub fn torque_to_rotor(&self, output_nm: f32) -> f32 {
        output_nm / self.gear_ratio
    }
    /// Output stiffness [N m/rad] -> rotor stiffness [N m/rad] (`/ g^2`).
    pub fn stiffness_to_rotor(&self, output_nm_per_rad: f32) -> f32 {
        output_nm_per_rad / (self.gear_ratio * self.gear_ratio)
    }
    /// Rotor stiffness (or damping) -> output (`* g^2`).
    pub fn stiffness_to_output(&self, rotor_nm_per_rad: f32) -> f32 {
        rotor_nm_per_rad * self.gear_ratio * self.gear_ratio
    }
    /// An output range `[lo, hi]` \[rad\] as a rotor range, ordered.
    pub fn range_to_rotor(&self, lo_out: f32, hi_out: f32) -> (f32, f32) {
        let (a, b) = (
            self.position_to_rotor(lo_out),
            self.position_to_rotor(hi_out),
        );
        if a <= b {
            (a, b)
        } else {
            (b, a)
        }
    }
    /// A rotor range as an output range, ordered.
    pub fn range_to_output(&self, lo_rotor: f32, hi_rotor: f32) -> (f32, f32) {
        let (a, b) = (
            self.position_to_output(lo_rotor),
            self.position_to_output(hi_rotor),
        );
        if a <= b {
            (a, b)
        } else {
            (b, a)
        }
    }

    /// An impedance command given at the output, in the rotor frame.
    pub fn impedance_to_rotor(&self, c: &Impedance) -> Impedance {
        Impedance {
            position_rad: self.position_to_rotor(c.position_rad),
            velocity_rad_s: self.velocity_to_rotor(c.velocity_rad_s),
            kp_nm_per_rad: self.stiffness_to_rotor(c.kp_nm_per_rad),
            kd_nm_s_per_rad: self.stiffness_to_rotor(c.kd_nm_s_per_rad),
            torque_ff_nm: self.torque_to_rotor(c.torque_ff_nm),
            torque_limit_nm: self.torque_to_rotor(c.torque_limit_nm).abs(),
        }
    }
}

/// The impedance law's set-point (see [`Command::Impedance`]), in the frame
/// its use says: `T = kp (p_ref - p) + kd (v_ref - v) + T_ff`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Impedance {
    /// Position reference [rad, mechanical].
    pub position_rad: f32,
    /// Velocity reference [rad/s, mechanical]; the position reference
    /// advances with it between commands.
    pub velocity_rad_s: f32,
    /// Stiffness [N m/rad] (>= 0, at most the limit).
    pub kp_nm_per_rad: f32,
    /// Damping [N m s/rad] (>= 0, at most the limit).
    pub kd_nm_s_per_rad: f32,
    /// Feed-forward torque [N m].
    pub torque_ff_nm: f32,
    /// Largest torque the law may give [N m] (>= 0; `inf`: the current
    /// limit's).
    pub torque_limit_nm: f32,
}

impl Impedance {
    /// Check every field against `l` (rotor frame): finite, the position
    /// inside the position range, the velocity within its limit, `kp` and
    /// `kd` non-negative and within their maxima. The feed-forward torque
    /// is only checked finite: the law's sum is clamped to the current
    /// (torque) limit.
    pub fn validate(&self, l: &Limits) -> Result<(), CommandError> {
        let all = [
            self.position_rad,
            self.velocity_rad_s,
            self.kp_nm_per_rad,
            self.kd_nm_s_per_rad,
            self.torque_ff_nm,
        ];
        if !all.iter().all(|x| x.is_finite()) || self.torque_limit_nm.is_nan() {
            return Err(CommandError::NonFinite);
        }
        if self.torque_limit_nm < 0.0 {
            return Err(CommandError::CurrentOutOfRange);
        }
        if !(super::within(l.min_position_rad, self.position_rad)
            && super::within(self.position_rad, l.max_position_rad))
        {
            return Err(CommandError::PositionOutOfRange);
        }
        if !super::within(self.velocity_rad_s.abs(), l.max_velocity_rad_s) {
            return Err(CommandError::VelocityOutOfRange);
        }
        if self.kp_nm_per_rad < 0.0 || !super::within(self.kp_nm_per_rad, l.max_kp_nm_per_rad) {
            return Err(CommandError::StiffnessOutOfRange);
        }
        if self.kd_nm_s_per_rad < 0.0 || !super::within(self.kd_nm_s_per_rad, l.max_kd_nm_s_per_rad)
        {
            return Err(CommandError::DampingOutOfRange);
        }
        Ok(())
    }
}

impl From<Impedance> for Command {
    fn from(i: Impedance) -> Self {
        Command::Impedance(i)
    }
}

/// The impedance law in amperes, worked out once when a command is taken
/// (`1 / kt` folded in), stepped every current-loop period.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImpedanceLaw {
    /// Position reference [rad, rotor], advanced by `v_ref * ts` each period.
    pub p_ref_rad: f32,
    /// Its advance per period \[rad\].
    pub p_step_rad: f32,
    /// Velocity reference [rad/s, rotor].
    pub v_ref_rad_s: f32,
    /// `kp / kt` [A/rad].
    pub kp_a_per_rad: f32,
    /// `kd / kt` [A s/rad].
    pub kd_a_s_per_rad: f32,
    /// `T_ff / kt` \[A\].
    pub iq_ff_a: f32,
    /// `T_max / kt` \[A\].
    pub iq_max_a: f32,
    /// Position range the reference stays in [rad, rotor].
    pub p_min_rad: f32,
    /// Position range the reference stays in [rad, rotor].
    pub p_max_rad: f32,
    /// What the reference's last advances lost to rounding \[rad\]
    /// (carried into the next: far from 0 a slow reference's advance is
    /// below the `f32` step of its position, 3e-5 rad at 300 rad, and it
    /// stalled; the anticogging sweep found it, design §32).
    pub p_carry_rad: f32,
}

impl ImpedanceLaw {
    /// The law of a (validated, rotor-frame) command for a torque constant
    /// `kt` [N m/A] and a period `ts_s`; `kt <= 0` gives no torque at all.
    pub fn new(c: &Impedance, kt_nm_per_a: f32, ts_s: f32, l: &Limits) -> Self {
        let inv_kt = if kt_nm_per_a > 0.0 && kt_nm_per_a.is_finite() {
            1.0 / kt_nm_per_a
        } else {
            0.0
        };
        Self {
            p_ref_rad: c.position_rad,
            p_step_rad: c.velocity_rad_s * ts_s,
            v_ref_rad_s: c.velocity_rad_s,
            kp_a_per_rad: c.kp_nm_per_rad * inv_kt,
            kd_a_s_per_rad: c.kd_nm_s_per_rad * inv_kt,
            iq_ff_a: c.torque_ff_nm * inv_kt,
            iq_max_a: c.torque_limit_nm * inv_kt,
            p_min_rad: l.min_position_rad,
            p_max_rad: l.max_position_rad,
            p_carry_rad: 0.0,
        }
    }

    /// One period: the q current \[A\] for the measured position and velocity
    /// (within the law's torque limit), then the reference advanced (kept
    /// in the range).
    #[inline(always)]
    pub fn step(&mut self, p_rad: f32, v_rad_s: f32) -> f32 {
        let iq = self.kp_a_per_rad * (self.p_ref_rad - p_rad)
            + self.kd_a_s_per_rad * (self.v_ref_rad_s - v_rad_s)
            + self.iq_ff_a;
        let iq = crate::clamp(iq, -self.iq_max_a, self.iq_max_a);
        let step = self.p_step_rad + self.p_carry_rad;
        let next = self.p_ref_rad + step;
        self.p_carry_rad = step - (next - self.p_ref_rad);
        self.p_ref_rad = crate::clamp(next, self.p_min_rad, self.p_max_rad);
        iq
    }
}

/// Travel limits' soft stop and fault (rotor frame; the range is the
/// command [`Limits`]' position range).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TravelConfig {
    /// Beyond the range by more than this \[rad\]: [`Fault::TravelLimit`](super::Fault::TravelLimit).
    pub fault_margin_rad: f32,
    /// Deceleration the soft stop brakes with [rad/s^2] (> 0).
    pub brake_accel_rad_s2: f32,
    /// The soft stop's velocity gain [A/(rad/s)] (> 0).
    pub kv_a_per_rad_s: f32,
}

impl TravelConfig {
    /// Defaults: a fault 0.1 rad (rotor) beyond the range, braking with
    /// half the current limit `max_current_a` when the rotor's inertia is
    /// known (`mechanics`, with the torque constant `kt_nm_per_a`), else at
    /// the position loop's acceleration limit `max_accel_rad_s2`; the soft
    /// stop's gain `kv_a_per_rad_s` (the speed loop's proportional gain).
    /// `CascadeConfig::default_travel` fills these in from a cascade.
    pub fn defaults(
        kt_nm_per_a: f32,
        max_current_a: f32,
        mechanics: Option<super::Mechanics>,
        max_accel_rad_s2: f32,
        kv_a_per_rad_s: f32,
    ) -> Self {
        let brake = match mechanics {
            Some(m) if m.is_usable() && kt_nm_per_a > 0.0 => {
                0.5 * kt_nm_per_a * max_current_a / m.inertia_kg_m2
            }
            _ => max_accel_rad_s2,
        };
        Self {
            fault_margin_rad: 0.1,
            brake_accel_rad_s2: brake,
            kv_a_per_rad_s,
        }
    }

    /// True when every value is finite and in range.
    pub fn is_valid(&self) -> bool {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        self.fault_margin_rad.is_finite()
            && self.fault_margin_rad >= 0.0
            && pos(self.brake_accel_rad_s2)
            && pos(self.kv_a_per_rad_s)
    }

    /// The q-current window \[A\] that brakes the rotor to the range's ends:
    /// towards an end at distance `d` the velocity allowed is
    /// `sqrt(2 a d)` (negative beyond it: back inside), and the current
    /// may not push harder than `kv (v_allowed - v)` asks, less the
    /// current of the braking deceleration itself (`brake_a`, `J a / kt`;
    /// phased in as `10 kv v` up to it) while the rotor moves towards the
    /// end at or above the allowed velocity. Far from both ends the window is wider than any current
    /// limit.
    #[inline(always)]
    pub fn window_a(
        &self,
        p_rad: f32,
        v_rad_s: f32,
        (min_rad, max_rad): (f32, f32),
        brake_a: f32,
    ) -> (f32, f32) {
        let allowed = |d: f32| {
            let s = crate::sqrtf(2.0 * self.brake_accel_rad_s2 * d.abs());
            if d >= 0.0 {
                s
            } else {
                -s
            }
        };
        let kv = self.kv_a_per_rad_s;
        // The braking current phases in with the speed (`10 kv v`, fully
        // from a tenth of the speed whose error alone would ask for it):
        // no step at rest, where the speed is only the sensor's noise.
        let ff = |speed: f32| {
            let x = 10.0 * speed * kv;
            if x < brake_a {
                x
            } else {
                brake_a
            }
        };
        let (up, down) = (allowed(max_rad - p_rad), allowed(p_rad - min_rad));
        let mut hi = kv * (up - v_rad_s);
        if v_rad_s > 0.0 && v_rad_s >= up {
            hi -= ff(v_rad_s);
        }
        let mut lo = -kv * (down + v_rad_s);
        if v_rad_s < 0.0 && -v_rad_s >= down {
            lo += ff(-v_rad_s);
        }
        (lo, hi)
    }

    /// True when `p_rad` is beyond the range by more than the margin.
    #[inline(always)]
    pub fn exceeded(&self, p_rad: f32, min_rad: f32, max_rad: f32) -> bool {
        p_rad > max_rad + self.fault_margin_rad || p_rad < min_rad - self.fault_margin_rad
    }
}

/// Robot-joint settings of the current stage (rotor frame).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JointConfig {
    /// Travel limits (soft stop and fault) on the limits' position range;
    /// `None`: the range only checks commands.
    pub travel: Option<TravelConfig>,
    /// Periods over which the current moves from the one in force to the
    /// impedance law's when impedance mode is entered (bumpless entry).
    pub entry_blend_periods: u32,
    /// Damping used after a command timeout in impedance mode when the
    /// command's own is smaller [N m s/rad, rotor].
    pub timeout_kd_nm_s_per_rad: f32,
}

impl JointConfig {
    /// No travel limits, a 10 ms entry blend at `pwm_hz`, no extra damping.
    pub fn for_pwm(pwm_hz: f32) -> Self {
        Self {
            travel: None,
            entry_blend_periods: (0.01 * pwm_hz) as u32,
            timeout_kd_nm_s_per_rad: 0.0,
        }
    }

    /// Longest entry blend \[periods\] (about a minute at 20 kHz): beyond
    /// 2^24 the f32 weight's step would round to nothing and the blend
    /// would never end.
    pub const MAX_ENTRY_BLEND_PERIODS: u32 = 1 << 20;

    /// True when every value is valid.
    pub fn is_valid(&self) -> bool {
        self.entry_blend_periods <= Self::MAX_ENTRY_BLEND_PERIODS
            && self.travel.is_none_or(|t| t.is_valid())
            && self.timeout_kd_nm_s_per_rad.is_finite()
            && self.timeout_kd_nm_s_per_rad >= 0.0
    }
}

/// A joint as its user sets it up: the output frame and the travel range
/// at the output, with the rotor-frame settings of the stage.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JointSetup {
    /// Gear ratio and home offset.
    pub frame: OutputFrame,
    /// Travel range at the output [rad, output] (`min < max`); `None`: the
    /// drive's build-time position range, no travel limits.
    pub travel_out_rad: Option<(f32, f32)>,
    /// Soft stop and fault margin (rotor frame), used with a travel range.
    pub travel: TravelConfig,
    /// Impedance entry blend and timeout damping.
    pub joint: JointConfig,
}

impl JointSetup {
    /// The stage's change for this setup: the travel range in the rotor
    /// frame (it replaces the motor's position range, it does not narrow
    /// it), or `unbounded_rad`, the motor's own range, without one.
    pub fn rotor_change(&self, unbounded_rad: (f32, f32)) -> JointChange {
        let (range, travel) = match self.travel_out_rad {
            Some((lo, hi)) => (self.frame.range_to_rotor(lo, hi), Some(self.travel)),
            None => (unbounded_rad, None),
        };
        JointChange {
            min_position_rad: range.0,
            max_position_rad: range.1,
            joint: JointConfig {
                travel,
                ..self.joint
            },
        }
    }

    /// Check every value.
    pub fn validate(&self) -> Result<(), JointError> {
        OutputFrame::check(self.frame.gear_ratio, self.frame.rotor_at_zero_rad)?;
        if let Some((lo, hi)) = self.travel_out_rad {
            if !(lo.is_finite() && hi.is_finite() && lo < hi && self.travel.is_valid()) {
                return Err(JointError::Travel);
            }
        }
        if !self.joint.is_valid() {
            return Err(JointError::Travel);
        }
        Ok(())
    }
}

/// The travel range (the limits' position range) and the joint settings,
/// rotor frame. Taken in any mode once started; refused
/// ([`super::Refusal::Unsupported`]) when a value is invalid, and
/// ([`super::Refusal::NotDisabled`]) when the active command's position target
/// lies outside the new range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointChange {
    /// Lower end of the range [rad, rotor].
    pub min_position_rad: f32,
    /// Upper end of the range [rad, rotor].
    pub max_position_rad: f32,
    /// Travel limits, impedance entry and timeout.
    pub joint: JointConfig,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A change to a valid value and the error it must give.
    type Case = (fn(&mut Impedance), CommandError);

    fn limits() -> Limits {
        Limits {
            max_current_a: 10.0,
            max_velocity_rad_s: 100.0,
            min_position_rad: -10.0,
            max_position_rad: 10.0,
            max_open_loop_voltage_v: 5.0,
            max_open_loop_omega_e_rad_s: 100.0,
            max_kp_nm_per_rad: 50.0,
            max_kd_nm_s_per_rad: 2.0,
        }
    }

    #[test]
    fn frame_round_trips_and_scales() {
        let f = OutputFrame::new(-20.0, 5.0).unwrap();
        for p in [-3.0f32, 0.0, 0.25, 7.0] {
            let r = f.position_to_rotor(p);
            assert!((f.position_to_output(r) - p).abs() < 1e-5);
        }
        assert_eq!(f.velocity_to_rotor(1.0), -20.0);
        assert_eq!(f.torque_to_rotor(20.0), -1.0);
        assert_eq!(f.stiffness_to_output(1.0), 400.0);
        assert_eq!(f.range_to_rotor(-1.0, 1.0), (-15.0, 25.0));
        assert_eq!(f.range_to_output(-15.0, 25.0), (-1.0, 1.0));
        let h = f.homed_at(100.0, 2.0).unwrap();
        assert!((h.position_to_output(100.0) - 2.0).abs() < 1e-6);
    }

    #[test]
    fn frame_refuses_bad_values() {
        for g in [0.0, 1e-3, f32::NAN, f32::INFINITY, -2e4] {
            assert_eq!(
                OutputFrame::check(g, 0.0),
                Err(JointError::GearRatio),
                "{g}"
            );
        }
        assert_eq!(OutputFrame::check(2.0, f32::NAN), Err(JointError::Offset));
    }

    #[test]
    fn impedance_validation_names_the_field() {
        let ok = Impedance {
            position_rad: 1.0,
            velocity_rad_s: 0.0,
            kp_nm_per_rad: 10.0,
            kd_nm_s_per_rad: 0.5,
            torque_ff_nm: 0.1,
            torque_limit_nm: f32::INFINITY,
        };
        let l = limits();
        assert_eq!(ok.validate(&l), Ok(()));
        let cases: [Case; 8] = [
            (|c| c.kp_nm_per_rad = f32::NAN, CommandError::NonFinite),
            (|c| c.torque_ff_nm = f32::INFINITY, CommandError::NonFinite),
            (
                |c| c.kp_nm_per_rad = -1.0,
                CommandError::StiffnessOutOfRange,
            ),
            (
                |c| c.kp_nm_per_rad = 51.0,
                CommandError::StiffnessOutOfRange,
            ),
            (
                |c| c.kd_nm_s_per_rad = -0.1,
                CommandError::DampingOutOfRange,
            ),
            (|c| c.position_rad = 11.0, CommandError::PositionOutOfRange),
            (
                |c| c.torque_limit_nm = -1.0,
                CommandError::CurrentOutOfRange,
            ),
            (|c| c.torque_limit_nm = f32::NAN, CommandError::NonFinite),
        ];
        for (f, e) in cases {
            let mut c = ok;
            f(&mut c);
            assert_eq!(c.validate(&l), Err(e), "{c:?}");
        }
    }

    #[test]
    fn law_is_the_spring_damper_and_advances_its_reference() {
        let c = Impedance {
            position_rad: 1.0,
            velocity_rad_s: 2.0,
            kp_nm_per_rad: 4.0,
            kd_nm_s_per_rad: 0.5,
            torque_ff_nm: 0.2,
            torque_limit_nm: 10.0,
        };
        let mut law = ImpedanceLaw::new(&c, 0.5, 1e-3, &limits());
        // (4 (1 - 0.5) + 0.5 (2 - 1) + 0.2) / 0.5 = 5.4 A
        assert!((law.step(0.5, 1.0) - 5.4).abs() < 1e-5);
        assert!((law.p_ref_rad - 1.002).abs() < 1e-6);
        // The torque limit: 10 N m = 20 A.
        assert_eq!(law.step(-100.0, 0.0), 20.0);
        // Kept in the range.
        for _ in 0..100_000 {
            law.step(0.0, 0.0);
        }
        assert_eq!(law.p_ref_rad, 10.0);
    }

    /// Far from 0 a slow reference still advances at its speed: the
    /// rounding of each step is carried into the next.
    #[test]
    fn a_slow_reference_far_from_zero_advances() {
        let mut law = ImpedanceLaw {
            p_ref_rad: 300.0,
            p_step_rad: 9e-6,
            p_min_rad: -1e6,
            p_max_rad: 1e6,
            ..ImpedanceLaw::default()
        };
        for _ in 0..100_000 {
            law.step(300.0, 0.0);
        }
        // 0.9 rad in 100 000 periods (without the carry: 0, the step is
        // below the f32 spacing at 300 rad).
        assert!((law.p_ref_rad - 300.9).abs() < 1e-3, "{}", law.p_ref_rad);
    }

    #[test]
    fn soft_stop_window_brakes_towards_the_ends_only() {
        let t = TravelConfig {
            fault_margin_rad: 0.5,
            brake_accel_rad_s2: 100.0,
            kv_a_per_rad_s: 1.0,
        };
        // Far inside, at rest: wide open.
        let (lo, hi) = t.window_a(0.0, 0.0, (-10.0, 10.0), 0.5);
        assert!(lo < -40.0 && hi > 40.0);
        // 0.5 rad before the upper end at 20 rad/s (allowed 10): must brake.
        let (_, hi) = t.window_a(9.5, 20.0, (-10.0, 10.0), 0.5);
        assert!((hi + 10.5).abs() < 1e-4, "{hi}");
        // At 0.02 rad/s the braking current is phased in to 0.2 A.
        let (_, hi) = t.window_a(10.0, 0.02, (-10.0, 10.0), 0.5);
        assert!((hi + 0.02 + 0.2).abs() < 1e-5, "{hi}");
        // At rest right at the end: nothing pushes it away.
        let (_, hi) = t.window_a(10.0, 0.0, (-10.0, 10.0), 0.5);
        assert_eq!(hi, 0.0);
        // Beyond the end at rest: pushed back inside.
        let (lo, hi) = t.window_a(10.02, 0.0, (-10.0, 10.0), 0.5);
        assert!(hi < 0.0 && lo < hi);
        let (lo, _) = t.window_a(-10.02, 0.0, (-10.0, 10.0), 0.5);
        assert!(lo > 0.0);
        assert!(!t.exceeded(10.4, -10.0, 10.0));
        assert!(t.exceeded(10.6, -10.0, 10.0) && t.exceeded(-10.6, -10.0, 10.0));
    }
}
