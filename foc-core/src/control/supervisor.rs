//! Fault supervision: one place decides, boards only act.
//!
//! The [`Supervisor`] checks every current-loop sample against its
//! [`SupervisorConfig`] limits. A fault *latches*: from the step it is
//! detected in, the current stage commands the bridge's safe state, and it
//! stays there until [`Supervisor::clear`] is called explicitly. If the
//! condition persists, the next sample trips again.
//!
//! ```
//! use foc_core::control::supervisor::{Fault, Supervisor, SupervisorConfig};
//! let mut sup = Supervisor::new(SupervisorConfig::default());
//! sup.trip(Fault::LoopOverrun);
//! assert!(sup.is_faulted());
//! assert_eq!(sup.first_fault(), Some(Fault::LoopOverrun));
//! assert_eq!(Fault::LoopOverrun.name(), "current-loop overrun");
//! sup.clear();
//! assert!(!sup.is_faulted());
//! ```

use super::model::ModelTolerances;
use crate::frames::Abc;

/// A fault the supervisor can latch. Each has a stable numeric code.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Fault {
    /// A phase current exceeded the per-phase limit.
    OverCurrentPhase = 1,
    /// The current vector magnitude exceeded its limit.
    OverCurrentVector = 2,
    /// Bus voltage above the limit.
    BusOverVoltage = 3,
    /// Bus voltage below the limit.
    BusUnderVoltage = 4,
    /// `|ia + ib + ic|` too large with three shunts (design §2).
    CurrentSumMismatch = 5,
    /// The angle sensor reported an error.
    AngleSensorError = 6,
    /// The angle reading jumped away from the tracked angle.
    AngleSensorImplausible = 7,
    /// A non-finite number in a measurement or in the control path.
    NonFinite = 8,
    /// The current loop did not finish within its budget (reported by the caller).
    LoopOverrun = 9,
    /// No command arrived within the timeout in a mode that needs them.
    CommandTimeout = 10,
    /// The current measurement failed (ADC error, no sample).
    CurrentSenseError = 11,
    /// The bus-voltage measurement failed.
    BusSenseError = 12,
    /// Power-stage temperature above the limit.
    OverTemperature = 13,
    /// The gate driver or the timer break input signalled a fault.
    GateDriverFault = 14,
    /// Writing the PWM failed.
    PwmError = 15,
    /// A calibration routine failed.
    CalibrationFailed = 16,
    /// The watchdog or an unexpected reset (reported by the firmware).
    Watchdog = 17,
    /// The angle reading did not change for the configured time while the
    /// drive demanded a large current to move (velocity or position mode):
    /// the sensor is stuck (frozen reading) or the rotor is stalled.
    AngleSensorStuck = 18,
    /// The tracked speed exceeded the over-speed limit.
    OverSpeed = 19,
    /// Velocity mode: the speed error stayed above its band, with the
    /// current saturated, and did not shrink over a whole window (a
    /// runaway, e.g. a slipped sensor, or a speed the drive cannot reach).
    SpeedRunaway = 20,
    /// The position went beyond the travel limits by more than their
    /// margin (design §21) while the bridge was on.
    TravelLimit = 21,
    /// Sensorless (design §27): the flux observer did not follow the field
    /// of a start in time, or lost the rotor: a locked or stalled rotor, a
    /// load beyond the start current, or a speed it cannot see.
    ObserverLostLock = 22,
}

impl Fault {
    /// Every fault, in code order.
    pub const ALL: [Fault; 22] = [
        Fault::OverCurrentPhase,
        Fault::OverCurrentVector,
        Fault::BusOverVoltage,
        Fault::BusUnderVoltage,
        Fault::CurrentSumMismatch,
        Fault::AngleSensorError,
        Fault::AngleSensorImplausible,
        Fault::NonFinite,
        Fault::LoopOverrun,
        Fault::CommandTimeout,
        Fault::CurrentSenseError,
        Fault::BusSenseError,
        Fault::OverTemperature,
        Fault::GateDriverFault,
        Fault::PwmError,
        Fault::CalibrationFailed,
        Fault::Watchdog,
        Fault::AngleSensorStuck,
        Fault::OverSpeed,
        Fault::SpeedRunaway,
        Fault::TravelLimit,
        Fault::ObserverLostLock,
    ];

    /// Stable numeric code (1..).
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The fault with this code, if any.
    pub fn from_code(code: u8) -> Option<Fault> {
        Fault::ALL.iter().copied().find(|f| f.code() == code)
    }

    /// Human-readable name.
    pub const fn name(self) -> &'static str {
        match self {
            Fault::OverCurrentPhase => "phase over-current",
            Fault::OverCurrentVector => "current-vector over-current",
            Fault::BusOverVoltage => "bus over-voltage",
            Fault::BusUnderVoltage => "bus under-voltage",
            Fault::CurrentSumMismatch => "phase-current sum mismatch",
            Fault::AngleSensorError => "angle-sensor error",
            Fault::AngleSensorImplausible => "angle-sensor implausible jump",
            Fault::NonFinite => "non-finite value",
            Fault::LoopOverrun => "current-loop overrun",
            Fault::CommandTimeout => "command timeout",
            Fault::CurrentSenseError => "current-sense error",
            Fault::BusSenseError => "bus-voltage sense error",
            Fault::OverTemperature => "over-temperature",
            Fault::GateDriverFault => "gate-driver / break fault",
            Fault::PwmError => "PWM write error",
            Fault::CalibrationFailed => "calibration failed",
            Fault::Watchdog => "watchdog",
            Fault::AngleSensorStuck => "angle sensor stuck or rotor stalled",
            Fault::OverSpeed => "over-speed",
            Fault::SpeedRunaway => "speed runaway / persistent speed error",
            Fault::TravelLimit => "travel limit exceeded",
            Fault::ObserverLostLock => "sensorless observer lost the rotor",
        }
    }

    pub(crate) const fn bit(self) -> u32 {
        1u32 << (self as u8)
    }
}

/// A set of latched faults (bit `code` set for each).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FaultSet(pub u32);

impl FaultSet {
    /// No fault.
    pub const EMPTY: Self = Self(0);
    /// True when `f` is in the set.
    pub const fn contains(self, f: Fault) -> bool {
        self.0 & f.bit() != 0
    }
    /// True when no fault is set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// Add a fault.
    pub fn insert(&mut self, f: Fault) {
        self.0 |= f.bit();
    }
    /// Iterate over the faults in the set.
    pub fn iter(self) -> impl Iterator<Item = Fault> {
        Fault::ALL.into_iter().filter(move |f| self.contains(*f))
    }
}

/// Supervisor limits. Each limit is checked with a strict `>` (or `<`), so a
/// value exactly at the limit is still normal.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SupervisorConfig {
    /// Per-phase current limit \[A\].
    pub max_phase_current_a: f32,
    /// Current-vector magnitude limit (`|i_alpha_beta|`) \[A\].
    pub max_vector_current_a: f32,
    /// Bus over-voltage threshold \[V\].
    pub bus_over_voltage_v: f32,
    /// Bus under-voltage threshold \[V\].
    pub bus_under_voltage_v: f32,
    /// Largest tolerated `|ia + ib + ic|` with three shunts \[A\].
    pub max_current_sum_a: f32,
    /// Largest tolerated difference between the angle reading and the
    /// tracked (predicted) mechanical angle \[rad\].
    pub max_angle_innovation_rad: f32,
    /// Largest tolerated change of that difference from one period to the
    /// next, in *electrical* radians: a slipping or jumping sensor moves it
    /// at once, the tracker's lag in acceleration only gradually. What
    /// matters is how far the field would be misplaced, so the mechanical
    /// limit shrinks with the pole pairs
    /// ([`Supervisor::set_angle_resolution`]); it never goes below 1.5
    /// counts of a counting sensor of known resolution (2.5: the reading
    /// and the prediction each move by up to a count).
    pub max_angle_step_e_rad: f32,
    /// Smallest angle-step limit [rad, mechanical] whatever the pole pairs:
    /// for sensors whose readings move in steps the resolution does not
    /// describe (halls: a whole sector when the decoder resynchronises).
    pub angle_step_floor_rad: f32,
    /// Over-speed limit [rad/s, mechanical] on the tracked speed
    /// ([`Fault::OverSpeed`]).
    pub max_speed_rad_s: f32,
    /// Runaway window \[periods\] ([`Fault::SpeedRunaway`]); 0 disables.
    pub runaway_periods: u32,
    /// Runaway band [rad/s]: speed errors below it never count.
    pub runaway_band_rad_s: f32,
    /// Current-sense plausibility from the motor model
    /// ([`Fault::CurrentSenseError`], see [`super::model`]): how far the
    /// identified model may be from the motor, and the trip count.
    pub model: ModelTolerances,
    /// The slower back-up ([`Fault::CurrentSenseError`]): the current
    /// loop's tracking error `|i_dq_ref - i_dq|` \[A\] above which a period
    /// counts. Periods on the voltage limit never count: there the loop
    /// cannot follow its reference (the back-EMF, or the `L di/dt` a large
    /// inductance needs while it slews, takes the voltage).
    pub tracking_band_a: f32,
    /// Consecutive periods above the band that trip; 0 disables.
    pub tracking_periods: u32,
    /// Over-temperature threshold [deg C].
    pub max_temperature_c: f32,
    /// Stuck-sensor / stall check ([`Fault::AngleSensorStuck`]): the angle
    /// reading has not changed for more than this many periods while the
    /// q-current demand is at least [`Self::stuck_current_a`] and motion is
    /// commanded. 0 disables the check. Choose it longer than the time the
    /// rotor needs to move one sensor count from standstill at that current
    /// (`sqrt(2 count J / (kt I))`), and than one count at
    /// [`Self::stuck_min_speed_rad_s`] for coarse sensors (halls).
    pub stuck_periods: u32,
    /// q-current demand \[A\] (magnitude) above which a still reading counts.
    pub stuck_current_a: f32,
    /// Velocity mode: smallest commanded speed [rad/s, mechanical] that
    /// counts as commanded motion.
    pub stuck_min_speed_rad_s: f32,
    /// Position mode: smallest distance from the target [rad, mechanical]
    /// that counts as commanded motion (holding a position never trips).
    pub stuck_min_distance_rad: f32,
}

impl Default for SupervisorConfig {
    /// Conservative limits for a small drive (10 A, 8..30 V).
    fn default() -> Self {
        Self {
            max_phase_current_a: 10.0,
            max_vector_current_a: 10.0,
            bus_over_voltage_v: 30.0,
            bus_under_voltage_v: 8.0,
            max_current_sum_a: 1.0,
            max_angle_innovation_rad: 0.5,
            max_angle_step_e_rad: 0.3,
            angle_step_floor_rad: 0.0,
            max_speed_rad_s: 1.0e4,
            runaway_periods: 2000, // 100 ms at 20 kHz
            runaway_band_rad_s: 5.0,
            model: ModelTolerances::for_current_limit(10.0),
            tracking_band_a: 2.5,
            tracking_periods: 40, // 2 ms at 20 kHz
            max_temperature_c: 90.0,
            stuck_periods: 400, // 20 ms at 20 kHz
            stuck_current_a: 5.0,
            stuck_min_speed_rad_s: 1.0,
            stuck_min_distance_rad: 0.1,
        }
    }
}

impl SupervisorConfig {
    /// NaN limits replaced by ones that trip at once (0 for the upper
    /// limits, `+inf` for the under-voltage limit); the current limits also
    /// when infinite (no drive has unlimited current). Other infinite
    /// limits stay (an explicit "no limit").
    pub fn sanitized(self) -> Self {
        let upper = |x: f32| if x.is_nan() { 0.0 } else { x };
        let current = |x: f32| if x.is_finite() { x } else { 0.0 };
        Self {
            max_phase_current_a: current(self.max_phase_current_a),
            max_vector_current_a: current(self.max_vector_current_a),
            bus_over_voltage_v: upper(self.bus_over_voltage_v),
            bus_under_voltage_v: if self.bus_under_voltage_v.is_nan() {
                f32::INFINITY
            } else {
                self.bus_under_voltage_v
            },
            max_current_sum_a: upper(self.max_current_sum_a),
            max_angle_innovation_rad: upper(self.max_angle_innovation_rad),
            max_angle_step_e_rad: upper(self.max_angle_step_e_rad),
            max_temperature_c: upper(self.max_temperature_c),
            max_speed_rad_s: upper(self.max_speed_rad_s),
            model: ModelTolerances {
                floor_a: upper(self.model.floor_a),
                ..self.model
            },
            tracking_band_a: upper(self.tracking_band_a),
            runaway_band_rad_s: upper(self.runaway_band_rad_s),
            stuck_current_a: upper(self.stuck_current_a),
            ..self
        }
    }
}

/// Measurements the supervisor checks in one current-loop period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Checks {
    /// Phase currents \[A\] (third derived with two shunts).
    pub i_abc_a: Abc,
    /// Measured `ia + ib + ic` with three shunts, `None` with two.
    pub measured_sum_a: Option<f32>,
    /// `|i_alpha_beta|` \[A\].
    pub vector_current_a: f32,
    /// Bus voltage \[V\].
    pub v_bus_v: f32,
    /// `|theta_measured - theta_predicted|` [rad, mechanical].
    pub angle_innovation_rad: f32,
    /// Change of the signed innovation since the last period, magnitude
    /// [rad, mechanical].
    pub angle_step_rad: f32,
    /// Tracked speed [rad/s, mechanical].
    pub speed_rad_s: f32,
    /// Temperature [deg C], if measured.
    pub temperature_c: Option<f32>,
}

/// The fault supervisor: limits plus latched state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Supervisor {
    /// Limits.
    pub config: SupervisorConfig,
    latched: FaultSet,
    first: Option<Fault>,
    still_periods: u32,
    /// The innovation-step limit in mechanical radians (see
    /// [`SupervisorConfig::max_angle_step_e_rad`]).
    angle_step_limit_rad: f32,
    /// Runaway window: periods so far and the error at its start [rad/s].
    runaway_count: u32,
    runaway_start_rad_s: f32,
    tracking_count: u32,
}

impl Supervisor {
    /// New supervisor with no fault latched. Limits that are not numbers
    /// (NaN) are replaced by values that trip at once (a NaN limit would
    /// never trip: over-current protection silently off).
    pub fn new(config: SupervisorConfig) -> Self {
        let config = config.sanitized();
        Self {
            config,
            latched: FaultSet::EMPTY,
            first: None,
            still_periods: 0,
            angle_step_limit_rad: config.max_angle_step_e_rad,
            runaway_count: 0,
            runaway_start_rad_s: 0.0,
            tracking_count: 0,
        }
    }

    /// The current-sense back-up check, once per closed-loop current
    /// period: `error_sq_a2` is `|i_dq_ref - i_dq|^2` [A^2], `excused` true
    /// on the voltage limit (or with the angle reading frozen). Latches
    /// [`Fault::CurrentSenseError`] after more than `tracking_periods`
    /// consecutive periods above the band.
    #[inline]
    pub fn check_tracking(&mut self, error_sq_a2: f32, excused: bool) -> Option<Fault> {
        let c = &self.config;
        let band = c.tracking_band_a;
        // NaN is not above the band (non-finite values trip elsewhere).
        let above = error_sq_a2 > band * band;
        let off = c.tracking_periods == 0 || excused || !above;
        if off {
            self.tracking_count = 0;
            return None;
        }
        self.tracking_count = self.tracking_count.saturating_add(1);
        if self.tracking_count > c.tracking_periods {
            self.trip(Fault::CurrentSenseError);
            return Some(Fault::CurrentSenseError);
        }
        None
    }

    /// The angle sensor's scale: the innovation-step limit becomes
    /// `max_angle_step_e_rad / pole_pairs` mechanical radians, but at
    /// least 2.5 counts when `counts_per_rev` is known (not 0).
    pub fn set_angle_resolution(&mut self, pole_pairs: u8, counts_per_rev: u32) {
        let pp = f32::from(pole_pairs.max(1));
        let electrical = self.config.max_angle_step_e_rad / pp;
        let counts = if counts_per_rev > 0 {
            2.5 * core::f32::consts::TAU / counts_per_rev as f32
        } else {
            0.0
        };
        let floor = self.config.angle_step_floor_rad;
        let lim = if counts > electrical {
            counts
        } else {
            electrical
        };
        self.angle_step_limit_rad = if floor > lim { floor } else { lim };
    }

    /// Restart the runaway window (a new speed setpoint: the error is
    /// judged against it from now on).
    pub fn restart_runaway(&mut self) {
        self.runaway_count = 0;
    }

    /// The innovation-step limit in force [rad, mechanical].
    pub fn angle_step_limit_rad(&self) -> f32 {
        self.angle_step_limit_rad
    }

    /// The runaway check, once per period: `speed_error_rad_s` (velocity
    /// mode's reference minus the tracked speed; `None` in other modes)
    /// and `saturated` (the q-current reference at its limit). Latches
    /// [`Fault::SpeedRunaway`] when, for a whole window of
    /// `runaway_periods` periods, the error stayed above the band with the
    /// current saturated and ended no smaller than it began: a loop that
    /// pushes as hard as it can and does not close.
    pub fn check_runaway(
        &mut self,
        speed_error_rad_s: Option<f32>,
        saturated: bool,
    ) -> Option<Fault> {
        let c = &self.config;
        let err = match speed_error_rad_s {
            Some(e) if saturated && c.runaway_periods > 0 && e.abs() > c.runaway_band_rad_s => {
                e.abs()
            }
            _ => {
                self.runaway_count = 0;
                return None;
            }
        };
        if self.runaway_count == 0 {
            self.runaway_start_rad_s = err;
        }
        self.runaway_count = self.runaway_count.saturating_add(1);
        if self.runaway_count < c.runaway_periods {
            return None;
        }
        self.runaway_count = 0;
        if err >= self.runaway_start_rad_s {
            self.trip(Fault::SpeedRunaway);
            return Some(Fault::SpeedRunaway);
        }
        None
    }

    /// Latch a fault (also used by callers for overrun, driver faults, ...).
    pub fn trip(&mut self, fault: Fault) {
        if self.first.is_none() {
            self.first = Some(fault);
        }
        self.latched.insert(fault);
    }

    /// Withdraw `fault` when it is the only fault latched since the set
    /// `before` was read this period (a sensor fault a fall-back handles,
    /// design §27): returns true when withdrawn. Any other new fault, or
    /// one latched before, stays.
    pub fn withdraw(&mut self, fault: Fault, before: FaultSet) -> bool {
        let mut only = before;
        only.insert(fault);
        if before.contains(fault) || self.latched != only {
            return false;
        }
        self.latched = before;
        if before.is_empty() {
            self.first = None;
        }
        true
    }

    /// True while any fault is latched.
    pub fn is_faulted(&self) -> bool {
        !self.latched.is_empty()
    }

    /// The first fault latched since the last clear.
    pub fn first_fault(&self) -> Option<Fault> {
        self.first
    }

    /// Every fault latched since the last clear.
    pub fn faults(&self) -> FaultSet {
        self.latched
    }

    /// Clear every latched fault (explicit operator action).
    pub fn clear(&mut self) {
        self.latched = FaultSet::EMPTY;
        self.first = None;
        self.still_periods = 0;
        self.runaway_count = 0;
        self.tracking_count = 0;
    }

    /// The stuck-sensor / stall check, once per period: `reading_changed`
    /// (the raw angle reading differs from the previous period's),
    /// `iq_demand_a` (this period's q-current reference) and
    /// `motion_commanded` (the mode asks the rotor to move). Latches and
    /// returns [`Fault::AngleSensorStuck`] once the reading has been still,
    /// with the demand at or above `stuck_current_a` and motion commanded,
    /// for more than `stuck_periods` consecutive periods.
    pub fn check_stuck(
        &mut self,
        reading_changed: bool,
        iq_demand_a: f32,
        motion_commanded: bool,
    ) -> Option<Fault> {
        let c = &self.config;
        let suspicious = c.stuck_periods > 0
            && !reading_changed
            && motion_commanded
            && iq_demand_a.abs() >= c.stuck_current_a;
        self.still_periods = if suspicious {
            self.still_periods.saturating_add(1)
        } else {
            0
        };
        if suspicious && self.still_periods > c.stuck_periods {
            self.trip(Fault::AngleSensorStuck);
            Some(Fault::AngleSensorStuck)
        } else {
            None
        }
    }

    /// Check one period's measurements; latches and returns the first new
    /// fault found. Non-finite values trip [`Fault::NonFinite`].
    pub fn check(&mut self, m: &Checks) -> Option<Fault> {
        let limit = self.config.max_vector_current_a;
        self.check_impl(m, m.vector_current_a, limit)
    }

    /// [`Self::check`] with the current vector given as its *square*
    /// `|i_alpha_beta|^2` [A^2] (`m.vector_current_a` is ignored): the
    /// current stage's entry point, which saves the square root.
    ///
    /// `|i| > limit` is decided as `|i|^2 > limit^2`. Both sides are
    /// non-negative and squaring is monotonic, so the decision is the same
    /// as [`Self::check`]'s except within an f32 rounding of the limit
    /// (a relative `1e-7`, far below any measurement's resolution). A square
    /// that overflows to infinity trips [`Fault::NonFinite`], exactly as the
    /// overflowing magnitude did.
    #[inline]
    pub fn check_vector_sq(&mut self, m: &Checks, vector_current_sq_a2: f32) -> Option<Fault> {
        let l = self.config.max_vector_current_a;
        // A negative limit always tripped (`|i| >= 0 > l`) and a NaN one
        // never did: keep both so (NaN squared is NaN).
        let limit_sq = if l < 0.0 { -1.0 } else { l * l };
        self.check_impl(m, vector_current_sq_a2, limit_sq)
    }

    /// The checks, with the current vector as `vector` (magnitude or square)
    /// against `vector_limit` (in the same form).
    #[inline(always)]
    fn check_impl(&mut self, m: &Checks, vector: f32, vector_limit: f32) -> Option<Fault> {
        let c = &self.config;
        // One combined finiteness check (an absent value counts as finite).
        let fault = if !crate::all_finite([
            m.i_abc_a.a,
            m.i_abc_a.b,
            m.i_abc_a.c,
            vector,
            m.v_bus_v,
            m.angle_innovation_rad,
            m.angle_step_rad,
            m.speed_rad_s,
            m.measured_sum_a.unwrap_or(0.0),
            m.temperature_c.unwrap_or(0.0),
        ]) {
            Some(Fault::NonFinite)
        } else if m.i_abc_a.a.abs() > c.max_phase_current_a
            || m.i_abc_a.b.abs() > c.max_phase_current_a
            || m.i_abc_a.c.abs() > c.max_phase_current_a
        {
            Some(Fault::OverCurrentPhase)
        } else if vector > vector_limit {
            Some(Fault::OverCurrentVector)
        } else if m
            .measured_sum_a
            .is_some_and(|s| s.abs() > c.max_current_sum_a)
        {
            Some(Fault::CurrentSumMismatch)
        } else if m.v_bus_v > c.bus_over_voltage_v {
            Some(Fault::BusOverVoltage)
        } else if m.v_bus_v < c.bus_under_voltage_v {
            Some(Fault::BusUnderVoltage)
        } else if m.angle_innovation_rad > c.max_angle_innovation_rad
            || m.angle_step_rad > self.angle_step_limit_rad
        {
            Some(Fault::AngleSensorImplausible)
        } else if m.speed_rad_s.abs() > c.max_speed_rad_s {
            Some(Fault::OverSpeed)
        } else if m.temperature_c.is_some_and(|t| t > c.max_temperature_c) {
            Some(Fault::OverTemperature)
        } else {
            None
        };
        if let Some(f) = fault {
            self.trip(f);
        }
        fault
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn normal() -> Checks {
        Checks {
            i_abc_a: Abc::new(1.0, -0.5, -0.5),
            measured_sum_a: Some(0.0),
            vector_current_a: 1.0,
            v_bus_v: 24.0,
            angle_innovation_rad: 0.01,
            angle_step_rad: 0.001,
            speed_rad_s: 10.0,
            temperature_c: Some(40.0),
        }
    }

    /// The angle-step limit: electrical over the pole pairs, never below
    /// 2.5 counts of a known resolution nor below the configured floor.
    #[test]
    fn angle_step_limit_scales_with_pole_pairs_and_floors() {
        let c = SupervisorConfig::default();
        let mut s = Supervisor::new(c);
        s.set_angle_resolution(7, 0);
        assert!((s.angle_step_limit_rad() - 0.3 / 7.0).abs() < 1e-6);
        s.set_angle_resolution(8, 48);
        let count = core::f32::consts::TAU / 48.0;
        assert!((s.angle_step_limit_rad() - 2.5 * count).abs() < 1e-6);
        let hall = 1.5 * core::f32::consts::TAU / 66.0;
        let mut s = Supervisor::new(SupervisorConfig {
            angle_step_floor_rad: hall,
            ..c
        });
        s.set_angle_resolution(11, 0);
        assert!((s.angle_step_limit_rad() - hall).abs() < 1e-6);
    }

    #[test]
    fn normal_sample_passes() {
        let mut s = Supervisor::new(SupervisorConfig::default());
        assert_eq!(s.check(&normal()), None);
        assert!(!s.is_faulted());
    }

    /// Each condition trips its own fault just past the limit and not at it.
    #[test]
    fn each_check_trips_past_its_limit_only() {
        let c = SupervisorConfig::default();
        type Case = (Fault, fn(&mut Checks, &SupervisorConfig, f32));
        let cases: [Case; 9] = [
            (Fault::OverCurrentPhase, |m, c, e| {
                m.i_abc_a = Abc::new(c.max_phase_current_a + e, 0.0, 0.0);
                m.vector_current_a = 0.0;
            }),
            (Fault::OverCurrentVector, |m, c, e| {
                m.vector_current_a = c.max_vector_current_a + e
            }),
            (Fault::CurrentSumMismatch, |m, c, e| {
                m.measured_sum_a = Some(-(c.max_current_sum_a + e))
            }),
            (Fault::BusOverVoltage, |m, c, e| {
                m.v_bus_v = c.bus_over_voltage_v + e
            }),
            (Fault::BusUnderVoltage, |m, c, e| {
                m.v_bus_v = c.bus_under_voltage_v - e
            }),
            (Fault::AngleSensorImplausible, |m, c, e| {
                m.angle_innovation_rad = c.max_angle_innovation_rad + e
            }),
            (Fault::AngleSensorImplausible, |m, c, e| {
                m.angle_step_rad = c.max_angle_step_e_rad + e
            }),
            (Fault::OverSpeed, |m, c, e| {
                m.speed_rad_s = -(c.max_speed_rad_s + e)
            }),
            (Fault::OverTemperature, |m, c, e| {
                m.temperature_c = Some(c.max_temperature_c + e)
            }),
        ];
        for (fault, set) in cases {
            let mut at = normal();
            set(&mut at, &c, 0.0);
            let mut s = Supervisor::new(c);
            assert_eq!(s.check(&at), None, "{fault:?} tripped at its limit");
            let mut past = normal();
            set(&mut past, &c, 0.01);
            assert_eq!(s.check(&past), Some(fault));
            assert!(s.faults().contains(fault));
        }
    }

    #[test]
    fn stuck_check_needs_all_conditions_for_longer_than_the_limit() {
        let c = SupervisorConfig {
            stuck_periods: 10,
            stuck_current_a: 5.0,
            ..SupervisorConfig::default()
        };
        let mut s = Supervisor::new(c);
        for _ in 0..10 {
            assert_eq!(s.check_stuck(false, -5.0, true), None);
        }
        assert_eq!(
            s.check_stuck(false, -5.0, true),
            Some(Fault::AngleSensorStuck)
        );
        assert!(s.faults().contains(Fault::AngleSensorStuck));
        // Any condition missing restarts the count.
        type Case = (bool, f32, bool);
        let breaks: [Case; 3] = [(true, 6.0, true), (false, 4.9, true), (false, 6.0, false)];
        for (changed, iq, motion) in breaks {
            let mut s = Supervisor::new(c);
            for k in 0..100 {
                let r = if k == 8 {
                    s.check_stuck(changed, iq, motion)
                } else {
                    s.check_stuck(false, 6.0, true)
                };
                if k < 19 {
                    assert_eq!(r, None, "k = {k}");
                }
            }
            assert!(s.is_faulted());
        }
        // 0 disables.
        let mut s = Supervisor::new(SupervisorConfig {
            stuck_periods: 0,
            ..c
        });
        for _ in 0..1000 {
            assert_eq!(s.check_stuck(false, 100.0, true), None);
        }
    }

    #[test]
    fn nan_trips_non_finite_and_latches_until_clear() {
        let mut s = Supervisor::new(SupervisorConfig::default());
        let mut m = normal();
        m.i_abc_a.b = f32::NAN;
        assert_eq!(s.check(&m), Some(Fault::NonFinite));
        assert_eq!(s.check(&normal()), None);
        assert!(s.is_faulted(), "a fault must stay latched");
        s.clear();
        assert!(!s.is_faulted());
    }

    #[test]
    fn codes_round_trip_and_names_are_distinct() {
        for (i, f) in Fault::ALL.iter().enumerate() {
            assert_eq!(Fault::from_code(f.code()), Some(*f));
            for g in &Fault::ALL[i + 1..] {
                assert_ne!(f.name(), g.name());
            }
        }
        assert_eq!(Fault::from_code(0), None);
    }

    /// The squared entry point decides as `check` does: same fault for
    /// vectors on both sides of the limit (away from the rounding boundary),
    /// for odd limits, and for an overflowing square.
    #[test]
    fn squared_vector_check_matches_magnitude_check() {
        for limit in [10.0f32, 0.0, -1.0, f32::NAN, f32::INFINITY, 3.3] {
            let cfg = SupervisorConfig {
                max_vector_current_a: limit,
                max_phase_current_a: 1e30,
                ..SupervisorConfig::default()
            };
            for v in [0.0f32, 1.0, 3.29, 3.31, 9.99, 10.01, 1e3] {
                let mut m = normal();
                m.vector_current_a = v;
                let mut a = Supervisor::new(cfg);
                let mut b = Supervisor::new(cfg);
                assert_eq!(
                    a.check(&m),
                    b.check_vector_sq(&m, v * v),
                    "limit {limit}, |i| {v}"
                );
            }
        }
        // |i|^2 overflows: non-finite, as the overflowing magnitude was.
        let cfg = SupervisorConfig {
            max_phase_current_a: f32::MAX,
            ..SupervisorConfig::default()
        };
        let mut m = normal();
        m.i_abc_a = Abc::new(1e20, -1e20, 0.0);
        let sq = 1e20f32 * 1e20;
        assert_eq!(
            Supervisor::new(cfg).check_vector_sq(&m, sq),
            Some(Fault::NonFinite)
        );
        m.vector_current_a = crate::transforms::clarke(m.i_abc_a).magnitude();
        assert_eq!(Supervisor::new(cfg).check(&m), Some(Fault::NonFinite));
    }
}
