//! Sensor supervision from the motor model (design §24): the current
//! sensors judged by how well the motor's own equations explain what they
//! read, not by how well the loop tracks its reference.
//!
//! Every closed-loop period the check predicts this period's currents
//! from its estimate of last period's, the voltage the bridge really
//! applied over the period in between (rebuilt from the duties it was
//! given and the bus they were computed for, plus the dead time as far as
//! it is configured), the electrical speed and the identified `R`, `Ld`,
//! `Lq` and `psi`:
//!
//! ```text
//! x = estimate of i(k-1) in the dq frame of theta(k)   (this sample's frame)
//! Ld dx_d/dt = v_d - R x_d - w (Ld - Lq) x_q - e_d - dist_d
//! Lq dx_q/dt = v_q - R x_q - w (Ld - Lq) x_d - e_q - dist_q
//! e = w psi ((1 - cos X) / X, sin X / X), X = w Ts   (the back-EMF over the period)
//! x_pred = a x + b (v - cross - e - dist),  a = exp(-R Ts / L),  b = (1 - a) / R
//! r = i(k) - x_pred
//! ```
//!
//! per axis; the cross terms are what the frame's rotation leaves of a
//! salient rotor's inductances. It is an observer: the estimate moves
//! [`CURRENT_GAIN`] of the way to the measurement, and a voltage
//! disturbance `dist` (what the model's resistance, flux linkage and dead
//! time are off by) [`DISTURBANCE_GAIN`] of the way to what the residual
//! says. The speed is the angle's own change over a window
//! ([`SPEED_WINDOW_PERIODS`]); for a coarse sensor (halls) the caller's
//! estimate.
//!
//! The duties are those handed to the bridge, so with the current loop's
//! dead-time compensation on (design §31) they include it, and the
//! dead-time correction here (by the measured currents' signs, none
//! within the floor) still gives the voltage the bridge really applied.
//! The compensation does not change what this check gets wrong about the
//! dead time (its own sign near a current's zero), so its allowance
//! (twice `V_bus t_d / T` in the bounds and the envelope) is kept.
//!
//! Three checks here, none of which looks at the reference (a current
//! slewing at the voltage limit, a current limit, the power windows,
//! impedance mode all leave a healthy drive quiet, whatever its size),
//! and a fourth it hosts, the frozen-channel check
//! ([`super::frozen`], [`ModelCheck::frozen_channel`]), which reads the
//! reference only to excuse a reading that stands while the current
//! falls:
//!
//! - fast: `|r|` against a bound carried along with the estimate: what an
//!   inductance off by [`ModelTolerances::inductance`] does to this
//!   period's predicted change, what the disturbance estimate's error (its
//!   start at the full tolerances, then the changes of current and speed
//!   since, decaying at its gain) and the angle sensor's resolution can
//!   do, plus a floor for noise and quantisation.
//!   [`ModelTolerances::trip_periods`] periods over (a period more than four
//!   times over counts twice) trip. A dead channel shows at once;
//! - slow: the disturbance the readings need must stay inside what the
//!   tolerances allow at this current and speed ([`ENVELOPE_MARGIN`] times
//!   resistance, flux linkage, inductance terms, held while the estimate
//!   forgets); [`ENVELOPE_PERIODS`] periods outside trip. A frozen channel,
//!   a wrong gain or an offset drags the disturbance out of it while the
//!   loop pushes.
//!
//! - unbalance ([`super::unbalance`]): the voltage the model misses,
//!   turned by the angle and by twice it and averaged, must stay balanced
//!   (a wrong gain or an offset on one channel is not), at speed.
//!
//! Every verdict is [`Verdict::CurrentSense`]; the current stage names
//! it the angle's (`AngleSensorStuck`) when the angle reading has stood
//! still longer than its last speed allows, and it also latches that
//! when the back-EMF the check measures (independent of the angle) shows
//! the rotor turning under a still reading.
//!
//! ```
//! use foc_core::control::model::{ModelCheck, ModelTolerances, Period, Verdict, SPEED_WINDOW_PERIODS};
//! use foc_core::control::MotorParams;
//! use foc_core::frames::{AlphaBeta, Dq};
//! use foc_core::angle::ElectricalAngle;
//! let motor = MotorParams { pole_pairs: 7, r_ohm: 0.5, ld_h: 1e-4, lq_h: 1e-4, flux_linkage_wb: 0.005 };
//! let mut m = ModelCheck::new(motor, 50e-6, ModelTolerances::for_current_limit(10.0), false);
//! // Bridge on, rotor still, no current, zero volts: the model expects zero
//! // (judged once the speed window is full).
//! let p = Period { i_ab_a: AlphaBeta::new(0.0, 0.0), i_dq_a: Dq::ZERO, sin_cos: (0.0, 1.0),
//!     theta_e: ElectricalAngle::ZERO, omega_spread_rad_s: 0.0, omega_e_rad_s: 0.0,
//!     unchanged_periods: 0 };
//! for _ in 0..SPEED_WINDOW_PERIODS + 3 {
//!     assert_eq!(m.check(&p), Verdict::Quiet);
//!     m.record(&p, [0.5; 3], 24.0);
//! }
//! // A reading of 3 A out of nowhere is not the motor.
//! let bad = Period { i_ab_a: AlphaBeta::new(3.0, 0.0), i_dq_a: Dq::new(3.0, 0.0), ..p };
//! let mut v = Verdict::Quiet;
//! for _ in 0..3 {
//!     v = m.check(&bad);
//!     m.record(&bad, [0.5; 3], 24.0);
//! }
//! assert_eq!(v, Verdict::CurrentSense);
//! ```

use super::frozen::{FrozenChannels, Readings};
use super::unbalance::{Limits, Unbalance};
use super::MotorParams;
use crate::angle::ElectricalAngle;
use crate::frames::{Abc, AlphaBeta, Dq};
use crate::transforms;

/// How far the identified model may be from the motor, and the check's
/// floor and trip count.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ModelTolerances {
    /// Noise and quantisation floor of the current residual \[A\].
    pub floor_a: f32,
    /// Relative error of the resistance: identification and the winding's
    /// temperature (copper +39 % from 20 to 120 deg C) together.
    pub resistance: f32,
    /// Relative error of the inductances.
    pub inductance: f32,
    /// Relative error of the flux linkage (identification, magnet
    /// temperature).
    pub flux: f32,
    /// Angle error the sensor may have [rad, electrical] on top of its
    /// resolution (interpolation, timing).
    pub angle_e_rad: f32,
    /// The bridge's dead time \[s\] as far as it is known (0: none known);
    /// the applied voltage is corrected by `-sgn(i) V_bus t_d f_pwm` per
    /// phase and the bound widened by one phase's worth. The current stage
    /// puts the dead time its current loop compensates in place of a 0
    /// (the compensation is in the duties this check reads).
    pub dead_time_s: f32,
    /// Periods over the bound that trip; 0 disables the check.
    pub trip_periods: u8,
}

impl ModelTolerances {
    /// Defaults for a drive with the given current limit \[A\]: a floor of
    /// 2 % of it, resistance 60 %, inductance 30 %, flux linkage 25 %,
    /// 0.05 rad of angle, no dead time known, 3 periods. A steady error
    /// ends up in the disturbance estimate; its envelope
    /// ([`ENVELOPE_MARGIN`] times these) covers a resistance 30 % off on a
    /// winding 100 K hotter (+80 %), tested on every motor file.
    pub fn for_current_limit(max_current_a: f32) -> Self {
        let floor = 0.02 * max_current_a;
        Self {
            floor_a: if floor.is_finite() && floor > 0.0 {
                floor
            } else {
                0.1
            },
            resistance: 0.6,
            inductance: 0.3,
            flux: 0.25,
            angle_e_rad: 0.05,
            dead_time_s: 0.0,
            trip_periods: 3,
        }
    }
}

impl ModelTolerances {
    /// A tolerance that is NaN, infinite or negative becomes 0: the bound
    /// tightens and the check trips rather than goes blind (as the
    /// supervisor's own limits do).
    pub fn sanitized(self) -> Self {
        let t = |x: f32| if x.is_finite() && x > 0.0 { x } else { 0.0 };
        Self {
            floor_a: t(self.floor_a),
            resistance: t(self.resistance),
            inductance: t(self.inductance),
            flux: t(self.flux),
            angle_e_rad: t(self.angle_e_rad),
            dead_time_s: t(self.dead_time_s),
            trip_periods: self.trip_periods,
        }
    }
}

/// What the check concluded this period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Verdict {
    /// Nothing to report (or not enough history yet).
    Quiet,
    /// The currents read do not follow the voltage applied.
    CurrentSense,
}

/// One period's inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Period {
    /// Measured currents, stationary frame \[A\].
    pub i_ab_a: AlphaBeta,
    /// The same in the dq frame of this period's angle \[A\].
    pub i_dq_a: Dq,
    /// `(sin, cos)` of this period's electrical angle.
    pub sin_cos: (f32, f32),
    /// This period's electrical angle (the one `sin_cos` is of): the
    /// model's speed is its change over [`SPEED_WINDOW_PERIODS`].
    pub theta_e: ElectricalAngle,
    /// How uncertain that estimate is [rad/s, electrical] where it is the
    /// model's speed (a coarse angle): its back-EMF joins the bounds.
    pub omega_spread_rad_s: f32,
    /// An electrical speed estimate [rad/s]: where the angle is too coarse
    /// for its change to give a speed ([`ModelCheck::new`]'s `coarse`),
    /// the model's speed; otherwise unused (the window of angle
    /// increments gives it, see [`SPEED_WINDOW_PERIODS`]).
    pub omega_e_rad_s: f32,
    /// Periods since the angle reading last changed.
    pub unchanged_periods: u32,
}

/// The last evaluated period, for tests, the scope and the margin report.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Residual {
    /// Measured minus predicted current, dq frame of the sample \[A\].
    pub r_dq_a: Dq,
    /// The bound it was held against \[A\].
    pub bound_a: f32,
    /// The back-EMF the residual implies, same frame \[V\].
    pub emf_dq_v: Dq,
    /// The EMF below which the angle is not judged \[V\].
    pub min_emf_v: f32,
    /// The disturbance estimate \[V\] and its envelope \[V\].
    pub disturbance_dq_v: Dq,
    /// See `disturbance_dq_v`.
    pub envelope_v: f32,
    /// The model's electrical speed [rad/s].
    pub omega_e_rad_s: f32,
}

/// How far the current estimate moves to the measurement each period: the
/// estimate is mostly the model's, so a reading that drifts away from the
/// motor (a dead or frozen channel while the loop pushes) is seen growing
/// for many periods, not one period's worth of it.
pub const CURRENT_GAIN: f32 = 0.25;

/// How far the disturbance estimate moves each period (time constant 32
/// periods): slow against a sensor fault's first periods, fast against a
/// resistance that warms.
pub const DISTURBANCE_GAIN: f32 = 1.0 / 32.0;

/// The model's speed is the sensor's angle change over this many periods
/// (a moving window of exact angle increments): one count's quantisation
/// is spread over the window, and unlike a torque-fed estimate it does not
/// lag an acceleration the drive does not cause (a load) by more than half
/// the window. Its lag is bounded by the difference of the window's two
/// halves (the acceleration times half the window).
pub const SPEED_WINDOW_PERIODS: usize = 32;

const HALF_WINDOW: usize = SPEED_WINDOW_PERIODS / 2;

/// The disturbance envelope is this many times what the tolerances allow.
pub const ENVELOPE_MARGIN: f32 = 2.0;

/// Consecutive periods outside the envelope that trip.
pub const ENVELOPE_PERIODS: u8 = 4;

/// The voltage the tolerances allow the model to be off by \[V\]: resistance
/// at the current, flux linkage and the inductances' cross terms at the
/// speed.
#[inline(always)]
fn volts_tol(t: &ModelTolerances, k: &Derived, x_l1_a: f32, w_abs: f32) -> f32 {
    t.resistance * k.r_ohm * x_l1_a
        + w_abs * (t.flux * k.psi_wb + t.inductance * k.l_max_h * x_l1_a)
}

/// One period's prediction, residual and bound, as [`ModelCheck::check`]
/// hands them from step to step.
#[derive(Clone, Copy, Debug)]
struct Step {
    w: f32,
    w_lag: f32,
    wabs: f32,
    x0: Dq,
    x0n: f32,
    dead_v: f32,
    e_d: f32,
    e_model_q: f32,
    dist: Dq,
    pred_d: f32,
    pred_q: f32,
    r: Dq,
    step: f32,
    angle_v: f32,
    err_pred: f32,
    bound: f32,
}

/// Constants derived once from the motor and the period.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Derived {
    a_d: f32,
    a_q: f32,
    b_d: f32,
    b_q: f32,
    inv_b_d: f32,
    inv_b_q: f32,
    b_max: f32,
    ts_s: f32,
    inv_ts: f32,
    psi_wb: f32,
    ld_minus_lq_h: f32,
    l_max_h: f32,
    r_ohm: f32,
    /// `t_d f_pwm`.
    dead_fraction: f32,
    /// The unbalance check's noise at the start [V^2]: the floor's
    /// voltage, squared.
    unbalance_start_var_v2: f32,
    /// Whether the model is usable at all (finite, positive L, Ts and flux
    /// linkage).
    usable: bool,
    /// The angle is too coarse for its change to give the speed.
    coarse_angle: bool,
}

/// Run-time state.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ModelState {
    /// The model's current estimate after last period's correction,
    /// stationary frame \[A\], if the bridge was driven.
    prev_i_ab_a: Option<AlphaBeta>,
    /// The estimated voltage disturbance (what the model's R, psi and
    /// dead-time errors add), dq frame \[V\].
    dist_dq_v: Dq,
    /// Bound of the estimate's error after the correction \[A\].
    err_a: f32,
    /// Bound of the disturbance estimate's error \[V\].
    dist_err_v: f32,
    /// Last judged period's estimate and speed (the disturbance bound
    /// follows their changes).
    prev_x_dq_a: Dq,
    prev_omega_e_rad_s: f32,
    /// [`ModelCheck::check`] judged (and corrected) this period.
    judged: bool,
    /// Dead-time voltage error per volt of bus, from last period's current
    /// signs (stationary frame).
    prev_dead_ab: AlphaBeta,
    /// Voltage computed last period (acts over the next) \[V\], with the bus
    /// voltage it was computed for \[V\].
    v_newer: Option<(AlphaBeta, f32)>,
    /// Voltage computed two periods ago (acted over the last) \[V\], and its bus.
    v_older: Option<(AlphaBeta, f32)>,
    current_count: u8,
    /// Largest `(|r| / bound)^2` seen since the last [`ModelCheck::reset_peak`].
    peak_ratio_sq: f32,
    /// Largest `(|disturbance| / envelope)^2` seen, likewise.
    peak_dist_ratio_sq: f32,
    /// Consecutive periods with the disturbance outside its envelope.
    dist_count: u8,
    /// Last period's angle and the window's speed [rad/s, electrical].
    prev_theta_e: Option<ElectricalAngle>,
    speed: SpeedWindow,
    /// The envelope of the last judged period \[V\].
    envelope_v: f32,
    /// The unbalance check (a channel's gain or offset, at speed).
    unbalance: Unbalance,
    last: Residual,
}

/// The last [`SPEED_WINDOW_PERIODS`] angle increments (raw turn fractions,
/// so their sums are exact) and the sums of its newer and older halves.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct SpeedWindow {
    incs: [i32; SPEED_WINDOW_PERIODS],
    /// Slot of the oldest increment (the next to be replaced).
    next: usize,
    /// Increments held (up to the window's length): the speed is judged
    /// only from a full window.
    held: usize,
    sum_new: i64,
    sum_old: i64,
    /// The window's speed and the lag bound [rad/s, electrical].
    omega_rad_s: f32,
    lag_rad_s: f32,
}

impl SpeedWindow {
    /// Whether the window holds a full window of increments.
    fn full(&self) -> bool {
        self.held >= SPEED_WINDOW_PERIODS
    }

    /// One period's increment; updates the speed and its lag bound.
    #[inline(always)]
    fn push(&mut self, inc: i32, inv_ts: f32) {
        let mid = (self.next + HALF_WINDOW) % SPEED_WINDOW_PERIODS;
        // (Both indices are below the window's length: `get` only keeps
        // the no-panic guarantee visible.)
        let crossing = i64::from(self.incs.get(mid).copied().unwrap_or(0));
        let leaving = i64::from(self.incs.get(self.next).copied().unwrap_or(0));
        self.sum_new += i64::from(inc) - crossing;
        self.sum_old += crossing - leaving;
        if let Some(slot) = self.incs.get_mut(self.next) {
            *slot = inc;
        }
        self.next = (self.next + 1) % SPEED_WINDOW_PERIODS;
        if self.held < SPEED_WINDOW_PERIODS {
            self.held += 1;
        }
        // 2^32 per turn.
        let to_rad_s = core::f32::consts::TAU / 4_294_967_296.0 * inv_ts / HALF_WINDOW as f32;
        let w_new = self.sum_new as f32 * to_rad_s;
        let w_old = self.sum_old as f32 * to_rad_s;
        self.omega_rad_s = 0.5 * (w_new + w_old);
        self.lag_rad_s = (w_new - w_old).abs();
    }
}

/// The model-based sensor check (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelCheck {
    tol: ModelTolerances,
    k: Derived,
    state: ModelState,
    frozen: FrozenChannels,
}

/// `exp(-x)` for `x >= 0` at configuration time: the (2,2) Pade
/// approximant on `x / 4`, squared twice (within 1e-6 for `x <= 4`).
fn exp_neg(x: f32) -> f32 {
    let y = 0.25 * x;
    let n = 1.0 - 0.5 * y + y * y / 12.0;
    let d = 1.0 + 0.5 * y + y * y / 12.0;
    let e = n / d;
    let e2 = e * e;
    e2 * e2
}

/// `(a, b)` of one axis: `a = exp(-R Ts / L)`, `b = (1 - a) / R`
/// (`Ts / L` without resistance).
fn axis(r_ohm: f32, l_h: f32, ts_s: f32) -> (f32, f32) {
    let x = r_ohm * ts_s / l_h;
    if !x.is_finite() || x > 8.0 {
        // The current settles within a period: `a` is below 4e-4.
        return (0.0, if r_ohm > 0.0 { 1.0 / r_ohm } else { 0.0 });
    }
    if x < 1e-3 {
        // `(1 - a) / R` would lose its digits: its series, Ts / L (1 - x / 2).
        return (1.0 - x, ts_s / l_h * (1.0 - 0.5 * x));
    }
    let a = exp_neg(x);
    (a, (1.0 - a) / r_ohm)
}

impl Derived {
    fn new(m: MotorParams, ts_s: f32, tol: &ModelTolerances, coarse_angle: bool) -> Self {
        let usable = crate::all_finite([m.r_ohm, m.ld_h, m.lq_h, m.flux_linkage_wb, ts_s])
            && m.ld_h > 0.0
            && m.lq_h > 0.0
            // Flux linkage 0: not identified yet (the identification's
            // provisional permit while it measures it): the check waits.
            && m.flux_linkage_wb > 0.0
            && ts_s > 0.0
            && m.r_ohm >= 0.0;
        let (a_d, b_d) = axis(m.r_ohm, m.ld_h, ts_s);
        let (a_q, b_q) = axis(m.r_ohm, m.lq_h, ts_s);
        let usable = usable
            && crate::all_finite([b_d, b_q, 1.0 / b_d, 1.0 / b_q, tol.floor_a])
            && b_d > 0.0
            && b_q > 0.0;
        let dead = tol.dead_time_s / ts_s;
        Self {
            a_d,
            a_q,
            b_d,
            b_q,
            inv_b_d: 1.0 / b_d,
            inv_b_q: 1.0 / b_q,
            b_max: if b_d > b_q { b_d } else { b_q },
            ts_s,
            inv_ts: 1.0 / ts_s,
            psi_wb: m.flux_linkage_wb,
            ld_minus_lq_h: m.ld_h - m.lq_h,
            l_max_h: if m.ld_h > m.lq_h { m.ld_h } else { m.lq_h },
            r_ohm: m.r_ohm,
            dead_fraction: if dead.is_finite() && dead > 0.0 {
                dead
            } else {
                0.0
            },
            unbalance_start_var_v2: {
                let v = tol.floor_a / if b_d < b_q { b_d } else { b_q };
                v * v
            },
            usable,
            coarse_angle,
        }
    }
}

impl ModelCheck {
    /// The check for `motor` at the period `ts_s` \[s\]; `coarse_angle` when the angle moves in steps too coarse for its
    /// change to give a speed (halls: [`Period::omega_e_rad_s`] is used).
    pub fn new(motor: MotorParams, ts_s: f32, tol: ModelTolerances, coarse_angle: bool) -> Self {
        let tol = tol.sanitized();
        Self {
            tol,
            k: Derived::new(motor, ts_s, &tol, coarse_angle),
            state: ModelState {
                unbalance: Unbalance::new(ts_s),
                ..ModelState::default()
            },
            frozen: FrozenChannels::new(tol.floor_a),
        }
    }

    /// The tolerances in use.
    pub fn tolerances(&self) -> &ModelTolerances {
        &self.tol
    }

    /// Forget the history (bridge off, a new configuration): the next two
    /// driven periods rebuild it before anything is judged. The healthy
    /// margin ([`Self::peak_ratio`]) is kept.
    pub fn reset(&mut self) {
        if self.state.v_newer.is_none()
            && self.state.prev_i_ab_a.is_none()
            && self.state.prev_theta_e.is_none()
        {
            // Nothing recorded since the last reset (the bridge-off periods).
            return;
        }
        // (The frozen-channel check runs only in periods that record, or
        // trip after seven that did: it has nothing to forget either.)
        self.frozen.reset();
        let (peak, peak_dist) = (self.state.peak_ratio_sq, self.state.peak_dist_ratio_sq);
        let mut unbalance = self.state.unbalance;
        unbalance.reset();
        self.state = ModelState {
            peak_ratio_sq: peak,
            peak_dist_ratio_sq: peak_dist,
            unbalance,
            ..ModelState::default()
        };
    }

    /// A period the bridge is not driven by the closed loop (off, open
    /// loop) with a valid angle reading: [`Self::reset`], but the speed
    /// window keeps counting the angle's increments, so that a drive
    /// enabled on a turning rotor is judged from its first periods.
    pub fn idle(&mut self, theta_e: ElectricalAngle) {
        if self.state.v_newer.is_some() || self.state.prev_i_ab_a.is_some() {
            let (speed, prev) = (self.state.speed, self.state.prev_theta_e);
            self.reset();
            self.state.speed = speed;
            self.state.prev_theta_e = prev;
        }
        if !self.k.coarse_angle {
            self.push_angle(theta_e);
        }
    }

    /// The margins, squared (residual, disturbance, unbalance), to carry
    /// over to a check that replaces this one ([`Self::keep_peaks`]).
    pub fn peaks_sq(&self) -> [f32; 4] {
        let frozen = self.frozen.peak_ratio();
        [
            self.state.peak_ratio_sq,
            self.state.peak_dist_ratio_sq,
            self.state.unbalance.peak_sq(),
            frozen * frozen,
        ]
    }

    /// Carry the margins over from a check this one replaces.
    pub fn keep_peaks(&mut self, [residual_sq, disturbance_sq, unbalance_sq, frozen_sq]: [f32; 4]) {
        self.state.peak_ratio_sq = residual_sq;
        self.state.peak_dist_ratio_sq = disturbance_sq;
        self.state.unbalance.set_peak_sq(unbalance_sq);
        self.frozen.keep_peak(crate::sqrtf(frozen_sq));
    }

    /// Forget the largest ratio seen.
    pub fn reset_peak(&mut self) {
        self.state.peak_ratio_sq = 0.0;
        self.state.peak_dist_ratio_sq = 0.0;
        self.state.unbalance.set_peak_sq(0.0);
        self.frozen.reset_peak();
    }

    /// Largest `|residual| / bound` seen in a judged period (the margin:
    /// a healthy drive stays below 1).
    pub fn peak_ratio(&self) -> f32 {
        crate::sqrtf(self.state.peak_ratio_sq)
    }

    /// Largest `|unbalance average| / threshold` seen (the unbalance
    /// check's margin, [`super::unbalance`]).
    pub fn peak_unbalance_ratio(&self) -> f32 {
        self.state.unbalance.peak_ratio()
    }

    /// Largest `|disturbance| / envelope` seen (the slow check's margin).
    pub fn peak_disturbance_ratio(&self) -> f32 {
        crate::sqrtf(self.state.peak_dist_ratio_sq)
    }

    /// The last judged period.
    pub fn last(&self) -> &Residual {
        &self.state.last
    }

    /// The EMF \[V\] above which the angle is judged, at the last judged
    /// period's current (see [`Residual::min_emf_v`]).
    pub fn min_emf_v(&self) -> f32 {
        self.state.last.min_emf_v
    }

    /// Record what this period drove: the measured currents (their signs
    /// for the dead time too, `i_abc_a` is derived from `p.i_ab_a` with a
    /// zero sum) and the duties handed to the bridge with the bus voltage
    /// they were computed for. Call after [`Self::check`] in every period
    /// the bridge is driven; [`Self::idle`] in every other with a valid
    /// angle reading, [`Self::reset`] otherwise.
    #[inline(always)]
    pub fn record(&mut self, p: &Period, duties: [f32; 3], v_bus_v: f32) {
        let [da, db, dc] = duties;
        let v = transforms::clarke(Abc::new(da * v_bus_v, db * v_bus_v, dc * v_bus_v));
        self.state.v_older = self.state.v_newer;
        self.state.v_newer = Some((v, v_bus_v));
        if !self.state.judged {
            // Nothing judged this period (the first two driven ones): the
            // estimate starts at the reading, the bounds at the tolerances.
            self.state.prev_i_ab_a = Some(p.i_ab_a);
            let w = if self.k.coarse_angle || !self.state.speed.full() {
                p.omega_e_rad_s
            } else {
                self.state.speed.omega_rad_s
            };
            self.start_bound(p.i_dq_a, w);
        }
        self.state.judged = false;
        if self.k.dead_fraction > 0.0 {
            let i = transforms::inverse_clarke(p.i_ab_a);
            // A current within the floor has no sign to trust: no
            // correction there (the bounds allow twice the dead time).
            let f = self.tol.floor_a;
            let s = |x: f32| {
                if x > f {
                    -1.0
                } else if x < -f {
                    1.0
                } else {
                    0.0
                }
            };
            self.state.prev_dead_ab = transforms::clarke(Abc::new(s(i.a), s(i.b), s(i.c)));
        }
    }

    /// Judge this period (module docs). Without two periods of history, or
    /// with a model that is not usable, nothing is judged.
    #[inline(always)]
    pub fn check(&mut self, p: &Period) -> Verdict {
        // The speed window fills whatever else is missing: nothing is
        // judged (and the estimate restarts at the reading) until it is
        // full of this run's increments.
        let was_full = self.k.coarse_angle || self.state.speed.full();
        let w = self.average_speed(p);
        let (Some(x_ab), Some((v_ab, vbus))) = (self.state.prev_i_ab_a, self.state.v_older) else {
            return Verdict::Quiet;
        };
        if !self.k.usable || self.tol.trip_periods == 0 || !was_full {
            return Verdict::Quiet;
        }
        let s = self.predict(p, x_ab, v_ab, vbus, w);
        let env = self.publish(&s);
        let unbalanced = self.unbalance(p, &s, env);
        self.correct(p, Dq::new(s.pred_d, s.pred_q), s.r, s.err_pred, s.x0, w);
        self.judge(&s, env, unbalanced)
    }

    /// The frozen-channel check ([`super::frozen`]): its margin.
    pub fn frozen(&self) -> &FrozenChannels {
        &self.frozen
    }

    /// The frozen-channel check ([`super::frozen`]) on this period's
    /// readings: true when one is frozen. Call in every period the bridge
    /// is driven, with [`Self::check`].
    #[inline(always)]
    pub fn frozen_channel(&mut self, readings: &Readings) -> bool {
        // (Trip periods 0 disable the model's checks, this one too.)
        self.frozen.check(readings) && self.tol.trip_periods != 0
    }

    /// This period's prediction from the last one's current and voltage,
    /// its residual and the residual's bound.
    #[inline(always)]
    fn predict(&self, p: &Period, x_ab: AlphaBeta, v_ab: AlphaBeta, vbus: f32, w: f32) -> Step {
        let w_lag = self.state.speed.lag_rad_s;
        let k = &self.k;
        let t = &self.tol;
        let (sin, cos) = p.sin_cos;
        let dead_v = vbus * k.dead_fraction;
        let mut v_ab = v_ab;
        if k.dead_fraction > 0.0 {
            let d = self.state.prev_dead_ab;
            v_ab = AlphaBeta::new(v_ab.alpha + d.alpha * dead_v, v_ab.beta + d.beta * dead_v);
        }
        let x0 = transforms::park(x_ab, sin, cos);
        let v = transforms::park(v_ab, sin, cos);
        // The back-EMF averaged over the period, in this sample's frame:
        // w psi ((1 - cos X) / X, sin X / X), X = w Ts (two-term series,
        // within 0.3 % of it up to X = 1).
        let x = w * k.ts_s;
        let x2 = x * x;
        let emf = w * k.psi_wb * (1.0 - x2 * (1.0 / 6.0));
        let e_d = w * k.psi_wb * x * (0.5 - x2 * (1.0 / 24.0));
        let cross = w * k.ld_minus_lq_h;
        let e_model_q = emf + cross * x0.d;
        let dist = self.state.dist_dq_v;
        let pred_d = k.a_d * x0.d + k.b_d * (v.d - cross * x0.q - e_d - dist.d);
        let pred_q = k.a_q * x0.q + k.b_q * (v.q - e_model_q - dist.q);
        let r = Dq::new(p.i_dq_a.d - pred_d, p.i_dq_a.q - pred_q);

        // The bound: the estimate's own error carried over, what the
        // inductance tolerance and the disturbance estimate's error can do
        // this period, and the floor.
        let wabs = w.abs();
        let x0n = x0.d.abs() + x0.q.abs();
        let step = (pred_d - x0.d).abs() + (pred_q - x0.q).abs();
        let spread = if k.coarse_angle {
            p.omega_spread_rad_s.abs()
        } else {
            0.0
        };
        let angle_v = (wabs * t.angle_e_rad + w_lag + spread) * k.psi_wb;
        let err_pred = self.state.err_a
            + t.inductance * step
            + k.b_max * (self.state.dist_err_v + angle_v + 2.0 * dead_v);
        Step {
            w,
            w_lag,
            wabs,
            x0,
            x0n,
            dead_v,
            e_d,
            e_model_q,
            dist,
            pred_d,
            pred_q,
            r,
            step,
            angle_v,
            err_pred,
            bound: err_pred + t.floor_a,
        }
    }

    /// The residual as published ([`Residual`]: the back-EMF the
    /// measurement implies and its uncertainty), and the envelope the
    /// disturbance estimate may hold now; returns that envelope.
    #[inline(always)]
    fn publish(&mut self, s: &Step) -> f32 {
        let k = &self.k;
        let t = &self.tol;
        let (r, dist) = (s.r, s.dist);
        let emf_dq = Dq::new(
            s.e_d + dist.d - r.d * k.inv_b_d,
            s.e_model_q + dist.q - r.q * k.inv_b_q,
        );
        let inv_b_max = if k.inv_b_d < k.inv_b_q {
            k.inv_b_q
        } else {
            k.inv_b_d
        };
        let volts = t.resistance * k.r_ohm * s.x0n + s.wabs * t.inductance * k.l_max_h * s.x0n;
        // The back-EMF's size does not depend on the frame's direction:
        // of the angle's share only the speed's (lag, spread) counts.
        let speed_v = s.angle_v - s.wabs * t.angle_e_rad * k.psi_wb;
        let min_emf = 2.0
            * ((t.floor_a + t.inductance * s.step) * inv_b_max + volts + speed_v + 2.0 * s.dead_v);
        self.state.last = Residual {
            r_dq_a: r,
            bound_a: s.bound,
            emf_dq_v: emf_dq,
            min_emf_v: min_emf,
            disturbance_dq_v: self.state.dist_dq_v,
            envelope_v: 0.0,
            omega_e_rad_s: s.w,
        };
        // What the disturbance estimate may hold now: the tolerances at
        // this current and speed, the inductance's share of this period's
        // slew, and, since the estimate forgets only at its own rate,
        // what the envelope was lately, decaying at that rate.
        let env_now = ENVELOPE_MARGIN
            * (volts_tol(t, k, s.x0n, s.wabs) + t.inductance * s.step * inv_b_max + s.angle_v)
            + 0.25 * t.floor_a * inv_b_max
            + 2.0 * s.dead_v;
        let env_held = (1.0 - DISTURBANCE_GAIN) * self.state.envelope_v;
        let env = if env_now > env_held {
            env_now
        } else {
            env_held
        };
        self.state.envelope_v = env;
        self.state.last.envelope_v = env;
        env
    }

    /// The unbalance check on the voltage the model misses this period
    /// (the disturbance and what the residual adds to it); with a coarse
    /// angle (halls) too.
    #[inline(always)]
    fn unbalance(&mut self, p: &Period, s: &Step, env: f32) -> bool {
        let k = &self.k;
        let (r, dist, x0) = (s.r, s.dist, s.x0);
        let missed = Dq::new(dist.d - r.d * k.inv_b_d, dist.q - r.q * k.inv_b_q);
        let lim = Limits {
            envelope_v: env,
            scale_v: (k.r_ohm + s.wabs * k.l_max_h) * crate::sqrtf(x0.d * x0.d + x0.q * x0.q),
            innovation_v: Dq::new(-r.d * k.inv_b_d, -r.q * k.inv_b_q),
            start_var_v2: k.unbalance_start_var_v2,
        };
        let w_min = if s.wabs > s.w_lag {
            s.wabs - s.w_lag
        } else {
            0.0
        };
        self.state.unbalance.update(missed, p.sin_cos, w_min, &lim)
    }

    /// The verdict: the peaks for the margin report, the slow check (the
    /// disturbance the readings need must stay inside the envelope), the
    /// unbalance, then the residual against its bound.
    #[inline(always)]
    fn judge(&mut self, s: &Step, env: f32, unbalanced: bool) -> Verdict {
        let r = s.r;
        let r_sq = r.d * r.d + r.q * r.q;
        let b_sq = s.bound * s.bound;
        let ratio_sq = r_sq / b_sq;
        // (A NaN ratio is kept: the margin report shows it.)
        if ratio_sq > self.state.peak_ratio_sq || ratio_sq.is_nan() {
            self.state.peak_ratio_sq = ratio_sq;
        }
        let k_coarse = self.k.coarse_angle;
        let d = self.state.dist_dq_v;
        let d_sq = d.d * d.d + d.q * d.q;
        let env_sq = env * env;
        let d_ratio_sq = d_sq / env_sq;
        if (d_ratio_sq > self.state.peak_dist_ratio_sq || d_ratio_sq.is_nan()) && !k_coarse {
            self.state.peak_dist_ratio_sq = d_ratio_sq;
        }
        self.state.dist_count = if d_sq > env_sq {
            self.state.dist_count.saturating_add(1)
        } else {
            0
        };
        // Not with a coarse angle (halls): in the Q-85SX hub motor's
        // impedance segment its disturbance grew past any envelope on a
        // healthy drive (not yet understood; issue 32 stays open).
        if (self.state.dist_count >= ENVELOPE_PERIODS && !k_coarse) || unbalanced {
            return Verdict::CurrentSense;
        }
        self.count_current(r_sq > b_sq, r_sq > 16.0 * b_sq)
    }

    /// The observer's correction: the estimate moves [`CURRENT_GAIN`] of
    /// the way to the measurement, the disturbance [`DISTURBANCE_GAIN`] of
    /// the way to what the residual says; their error bounds follow
    /// (module docs).
    #[inline(always)]
    fn correct(&mut self, p: &Period, pred: Dq, r: Dq, err_pred: f32, x0: Dq, w: f32) {
        let k = &self.k;
        let t = &self.tol;
        let s = &mut self.state;
        let x = Dq::new(pred.d + CURRENT_GAIN * r.d, pred.q + CURRENT_GAIN * r.q);
        s.prev_i_ab_a = Some(transforms::inverse_park(x, p.sin_cos.0, p.sin_cos.1));
        s.dist_dq_v = Dq::new(
            s.dist_dq_v.d - DISTURBANCE_GAIN * r.d * k.inv_b_d,
            s.dist_dq_v.q - DISTURBANCE_GAIN * r.q * k.inv_b_q,
        );
        s.err_a = (1.0 - CURRENT_GAIN) * err_pred + CURRENT_GAIN * t.floor_a;
        // What the disturbance did since: R, psi and the cross terms
        // against the change of current and speed.
        let dx = (x0.d - s.prev_x_dq_a.d).abs() + (x0.q - s.prev_x_dq_a.q).abs();
        let dw = (w - s.prev_omega_e_rad_s).abs();
        let x0n = x0.d.abs() + x0.q.abs();
        let moved_v = t.resistance * k.r_ohm * dx
            + t.flux * k.psi_wb * dw
            + t.inductance * k.l_max_h * (dw * x0n + w.abs() * dx);
        let inv_b_max = if k.inv_b_d < k.inv_b_q {
            k.inv_b_q
        } else {
            k.inv_b_d
        };
        // Noise enters the disturbance estimate through the residual and
        // is averaged over its time constant: a quarter of the floor's
        // voltage is allowed for it (twice the standard deviation,
        // sqrt(g / (2 - g)) = 1/8, an average with gain g keeps of a
        // white noise as large as the floor).
        s.dist_err_v = (1.0 - DISTURBANCE_GAIN) * s.dist_err_v
            + DISTURBANCE_GAIN * 0.25 * t.floor_a * inv_b_max
            + moved_v;
        s.prev_x_dq_a = x0;
        s.prev_omega_e_rad_s = w;
        s.judged = true;
    }

    /// This period's speed [rad/s, electrical]: the angle's change over
    /// the window (see [`SPEED_WINDOW_PERIODS`]).
    #[inline(always)]
    fn average_speed(&mut self, p: &Period) -> f32 {
        let s = &mut self.state;
        if self.k.coarse_angle {
            s.speed.omega_rad_s = if p.omega_e_rad_s.is_finite() {
                p.omega_e_rad_s
            } else {
                0.0
            };
            return s.speed.omega_rad_s;
        }
        self.push_angle(p.theta_e);
        self.state.speed.omega_rad_s
    }

    /// The angle's increment since the last period into the speed window.
    #[inline(always)]
    fn push_angle(&mut self, theta_e: ElectricalAngle) {
        let s = &mut self.state;
        if let Some(prev) = s.prev_theta_e {
            let inc = theta_e.wrapping_sub(prev).to_bits() as i32;
            s.speed.push(inc, self.k.inv_ts);
        }
        s.prev_theta_e = Some(theta_e);
    }

    /// The disturbance bound when the check starts: everything the
    /// tolerances allow at this current and speed.
    #[inline(always)]
    fn start_bound(&mut self, x_dq: Dq, w: f32) {
        let k = &self.k;
        let t = &self.tol;
        let xn = x_dq.d.abs() + x_dq.q.abs();
        self.state.dist_err_v = t.resistance * k.r_ohm * xn
            + w.abs() * (t.flux * k.psi_wb + t.inductance * k.l_max_h * xn);
        self.state.err_a = t.floor_a;
        self.state.prev_x_dq_a = x_dq;
        self.state.prev_omega_e_rad_s = w;
    }

    #[inline(always)]
    fn count_current(&mut self, over: bool, gross: bool) -> Verdict {
        let s = &mut self.state;
        s.current_count = if gross {
            s.current_count.saturating_add(2)
        } else if over {
            s.current_count.saturating_add(1)
        } else {
            s.current_count.saturating_sub(1)
        };
        if s.current_count >= self.tol.trip_periods {
            Verdict::CurrentSense
        } else {
            Verdict::Quiet
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check() -> ModelCheck {
        let motor = MotorParams {
            pole_pairs: 7,
            r_ohm: 0.5,
            ld_h: 1e-4,
            lq_h: 1e-4,
            flux_linkage_wb: 0.005,
        };
        ModelCheck::new(
            motor,
            50e-6,
            ModelTolerances::for_current_limit(10.0),
            false,
        )
    }

    /// The rotor at 1000 rad/s electrical, period `k`.
    fn angle(k: u32) -> ElectricalAngle {
        ElectricalAngle::from_radians(1000.0 * 50e-6 * k as f32)
    }

    #[test]
    fn idle_periods_fill_the_speed_window() {
        let mut m = check();
        for k in 0..=SPEED_WINDOW_PERIODS as u32 {
            m.idle(angle(k));
        }
        assert!(m.state.speed.full());
        assert!((m.state.speed.omega_rad_s - 1000.0).abs() < 1.0);
        assert!(m.state.speed.lag_rad_s < 1.0);
    }

    /// A reset (a fault, a period without an angle) empties the window: a
    /// gap in the readings must not enter it as one period's increment.
    #[test]
    fn a_reset_empties_the_speed_window() {
        let mut m = check();
        for k in 0..=SPEED_WINDOW_PERIODS as u32 {
            m.idle(angle(k));
        }
        m.reset();
        m.reset();
        assert_eq!(m.state.speed.held, 0);
        assert_eq!(m.state.prev_theta_e, None);
        // Readings resume 100 periods later: the window starts again.
        for k in 0..=SPEED_WINDOW_PERIODS as u32 {
            assert!(!m.state.speed.full());
            m.idle(angle(100 + k));
        }
        assert!(m.state.speed.full());
        assert!((m.state.speed.omega_rad_s - 1000.0).abs() < 1.0);
    }
}
