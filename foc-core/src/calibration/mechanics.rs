//! Rotor + load inertia `J`, viscous friction `B` and Coulomb friction `Fc`
//! from torque pulses in closed-loop current (torque) mode.
//!
//! The rigid body with friction is
//!
//! ```text
//! kt iq = J dw/dt + B w + Fc sgn(w),        kt = 1.5 p psi
//! ```
//!
//! integrated over time, so that no acceleration is ever differentiated:
//!
//! ```text
//! kt * int(iq dt) = J * (w_end - w_start) + B * int(w dt) + Fc * int(sgn(w) dt)
//! ```
//!
//! The q current and the speed first go through the same low-pass (two
//! first-order stages of `filter_s`): a linear filter applied to every
//! signal keeps the equation exact, and it smooths the quantisation
//! ripple of the speed estimate of a coarse sensor (48 counts per turn).
//!
//! The integrals run over *runs*: stretches of one constant-current phase,
//! starting `settle_s` after the phase began (the speed is the current
//! stage's estimate, which lags by about `2 a / wn` while accelerating:
//! that lag is the same at both ends of a stretch of constant current and
//! cancels in `w_end - w_start`, but not across a current step), with the
//! filtered speed at one sign above `min_speed_fraction` of the target
//! throughout and for the filter's memory before (the sign of the Coulomb
//! term is then certain). Every `window_s` of a run adds one row, the run
//! from its start so far, to a least-squares fit of `(J, B, Fc)`; only the
//! 3 x 3 normal equations are accumulated (no sample buffer). Rows that
//! grow with the run make the speed noise at their two ends (the estimate
//! of a coarse sensor ripples by several rad/s) small against
//! `w_end - w_start`; rows of a few milliseconds would let it bias `J`
//! low (the noise of a regressor attenuates its coefficient).
//!
//! **Experiment** (`w_t` = `speed_target_rad_s`, `I` = `current_a`):
//!
//! | phase | q current | until |
//! |---|---|---|
//! | probe | ramp from 0 to `+I` in `accel_time_s`, then `+I` | `w >= +w_t` |
//! | pulse 1 | `-I1` | `w <= -w_t` (brakes through zero) |
//! | pulse 2 | `+I2` | `w >= +w_t` (brakes through zero) |
//! | pulse 3 | `-I2` | `w <= min_speed_fraction * w_t` |
//! | stop | velocity request 0 | rotor (nearly) still, at most `stop_timeout_s` |
//!
//! The probe sizes the current `I1 <= I` of the pulses so that the
//! acceleration from standstill to `w_t` takes about `accel_time_s` (a
//! light rotor would reach the target within milliseconds at `I`, too
//! few rows after the settling). On the ramp `i = I t / t_a`
//! (`t_a` = `accel_time_s`) the rotor starts when the torque overcomes the
//! friction, at `t0 = t_a I_F / I`, and then `J w = kt I (t - t0)^2 /
//! (2 t_a)` (Coulomb friction); the times `t_h` and `t_r` at which the
//! speed passes `w_t / 2` and `w_t` give `t0 = (sqrt(2) t_h - t_r) /
//! (sqrt(2) - 1)` (a delay of the speed estimate moves all three alike,
//! and only makes `I_F` larger) and
//!
//! ```text
//! I1 = I_F + J w_t / (kt t_a) = I (t0 / t_a + (t_r - t0)^2 / (2 t_a^2))
//! ```
//!
//! (`I` when the ramp ended before the target). A delay of the speed
//! estimate makes this `I1` too large by up to `I delay / t_a` (pulses too
//! short); pulse 1 corrects it for pulses 2 and 3: its deceleration `b`
//! (braking half: torque plus friction) and acceleration `a` (accelerating
//! half: torque minus friction), each timed between 70 % and 30 % of `w_t`
//! in one half (a constant lag cancels), give `I_F = I1 (b - a) / (a + b)`
//! and `J / kt = 2 I1 / (a + b)`, so `I2 = I1 (b - a + 2 w_t / t_a) / (a + b)`.
//!
//! Only the pulses go into the fit: each speed is crossed both accelerating and braking at one
//! current, so that `J` comes from the difference of the two and the
//! friction from their sum, and both directions are run, so that an
//! offset in the current or the speed does not look like friction. A
//! zero-current coast would add little: there the dead time's distortion
//! of the phase currents around their zero crossings biases the measured
//! `iq` by a few milliamperes with the sign of the speed (on the bench),
//! which on a low-friction motor is a sizeable part of its friction.
//!
//! The fit is solved after pulse 3 (Cramer's rule on the normal equations
//! scaled to unit diagonal, with a determinant check); a negative `B` or
//! `Fc` (noise around a small true value) is refitted with that term at 0.
//! The routine asks for [`CalStep::Torque`] requests (and a final
//! [`CalStep::Velocity`] of 0) and needs [`CalInput::closed_loop`] every
//! period (measured `iq`, tracked mechanical speed).
//!
//! Failures: [`CalError::NoAcceleration`] (the probe never reached
//! `min_speed_fraction` of the target: locked rotor, or friction above the
//! test torque), [`CalError::SpeedNotReached`] (a pulse moved the rotor
//! but ran out of time), [`CalError::MechanicsIllConditioned`] (too few
//! rows, or rows that do not separate the three terms),
//! [`CalError::InertiaOutOfRange`], [`CalError::FrictionOutOfRange`]
//! (outside the configured bounds, or friction at the target speed above
//! the torque that reached it), [`CalError::InvalidInput`],
//! [`CalError::OverCurrent`], [`CalError::InvalidConfig`].
//!
//! ```
//! use foc_core::calibration::mechanics::{MechanicalId, MechanicsConfig};
//! use foc_core::calibration::{CalInput, CalStep};
//! use foc_core::{angle::MechanicalAngle, frames::Abc};
//! // kt 0.05 N m/A, 2 A, target 100 rad/s.
//! let mut m = MechanicalId::new(MechanicsConfig::new(20_000.0, 0.05, 2.0, 4.0, Some(100.0)));
//! // The probe's current ramp starts at 0 A.
//! let s = m.step(&CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0));
//! assert_eq!(s, CalStep::Torque { iq_a: 0.0 });
//! ```

use super::common::{check_input, latch, periods, CalError, CalInput, CalStep};

/// Fewest rows (one per `window_s` of a run) for a fit.
pub const MIN_ROWS: u32 = 12;

/// Smallest determinant of the normal equations scaled to unit diagonal
/// (1 for independent terms, 0 when one term is a combination of the
/// others).
pub const MIN_DETERMINANT: f32 = 1.0e-4;

/// Configuration of the mechanical identification.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MechanicsConfig {
    /// PWM (step) period \[s\].
    pub ts_s: f32,
    /// Torque constant `1.5 p psi` [N m / A] (the sequencer replaces it
    /// with the measured flux linkage's).
    pub torque_constant_nm_per_a: f32,
    /// q current of the probe pulse \[A\], the largest the routine asks for
    /// (keep it within the drive's current limit).
    pub current_a: f32,
    /// Smallest q current of the pulses after the probe, as a fraction of
    /// `current_a` (their current is sized for `accel_time_s`).
    pub min_current_fraction: f32,
    /// Current vector that aborts the routine \[A\].
    pub max_current_a: f32,
    /// Speed the pulses accelerate to [rad/s, mechanical]. `None`: the
    /// sequencer uses the flux step's second speed (back-EMF at its
    /// `emf_fraction` of the voltage limit); the routine alone refuses to
    /// start without one ([`CalError::InvalidConfig`]).
    pub speed_target_rad_s: Option<f32>,
    /// Wanted time from standstill to the target speed \[s\] (sets the
    /// current of the pulses after the probe), also the probe's ramp time.
    pub accel_time_s: f32,
    /// Time after each current change before a run starts \[s\]: the speed
    /// estimate's lag settles to the new acceleration (many time constants
    /// of the speed estimate, plus the filter's delay).
    pub settle_s: f32,
    /// A run adds one row every `window_s` \[s\].
    pub window_s: f32,
    /// Time constant of each of the two first-order low-passes the q
    /// current and the speed go through \[s\]: smooths the quantisation
    /// ripple of the speed estimate of a coarse sensor; a run starts only
    /// after about six of them at speed (0: no filter).
    pub filter_s: f32,
    /// Runs only above this fraction of the target speed; pulse 3 ends
    /// there.
    pub min_speed_fraction: f32,
    /// Time limit of pulse 3 and of the probe after its ramp \[s\] (pulses
    /// 1 and 2, through zero speed, get twice that).
    pub pulse_timeout_s: f32,
    /// Time limit of the final stop \[s\] (then `Done` anyway).
    pub stop_timeout_s: f32,
    /// Plausible inertia [kg m^2]: `(min, max)`.
    pub inertia_range_kg_m2: (f32, f32),
    /// Largest plausible viscous friction [N m s / rad].
    pub max_viscous_nm_s_per_rad: f32,
    /// Largest plausible Coulomb friction [N m].
    pub max_coulomb_nm: f32,
}

impl MechanicsConfig {
    /// Defaults for a PWM frequency \[Hz\], a torque constant [N m / A], a
    /// probe current and an abort current \[A\] and a target speed [rad/s]:
    /// 120 ms to the target speed, 25 ms settling (about 12
    /// time constants of an 80 Hz speed estimate), a 2 ms filter, a row
    /// every 4 ms above 20 % of the target speed, 0.6 s per pulse, 0.5 s to
    /// stop; inertia from 1e-8 to 10 kg m^2, friction up to 10 N m s/rad
    /// and 100 N m.
    pub fn new(
        pwm_frequency_hz: f32,
        torque_constant_nm_per_a: f32,
        current_a: f32,
        max_current_a: f32,
        speed_target_rad_s: Option<f32>,
    ) -> Self {
        Self {
            ts_s: 1.0 / pwm_frequency_hz,
            torque_constant_nm_per_a,
            current_a,
            min_current_fraction: 0.02,
            max_current_a,
            speed_target_rad_s,
            accel_time_s: 0.12,
            settle_s: 0.025,
            window_s: 0.004,
            filter_s: 0.002,
            min_speed_fraction: 0.2,
            pulse_timeout_s: 0.6,
            stop_timeout_s: 0.5,
            inertia_range_kg_m2: (1.0e-8, 10.0),
            max_viscous_nm_s_per_rad: 10.0,
            max_coulomb_nm: 100.0,
        }
    }

    fn is_valid(&self) -> bool {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let (j_lo, j_hi) = self.inertia_range_kg_m2;
        pos(self.ts_s)
            && pos(self.torque_constant_nm_per_a)
            && pos(self.current_a)
            && pos(self.max_current_a)
            && self.current_a < self.max_current_a
            && pos(self.min_current_fraction)
            && self.min_current_fraction <= 1.0
            && self.speed_target_rad_s.is_some_and(pos)
            && pos(self.accel_time_s)
            && self.settle_s.is_finite()
            && self.settle_s >= 0.0
            && pos(self.window_s)
            && self.filter_s.is_finite()
            && self.filter_s >= 0.0
            && pos(self.min_speed_fraction)
            && self.min_speed_fraction < 0.9
            && pos(self.pulse_timeout_s)
            && pos(self.stop_timeout_s)
            && pos(j_lo)
            && pos(j_hi)
            && j_lo < j_hi
            && pos(self.max_viscous_nm_s_per_rad)
            && pos(self.max_coulomb_nm)
    }
}

/// Result of the mechanical identification.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MechanicsResult {
    /// Rotor + load inertia [kg m^2].
    pub inertia_kg_m2: f32,
    /// Viscous friction [N m s / rad].
    pub viscous_friction_nm_s_per_rad: f32,
    /// Coulomb friction [N m].
    pub coulomb_friction_nm: f32,
    /// The speed range the fit covers [rad/s, mechanical]: the lowest
    /// speed of a run and the target speed.
    pub speeds_rad_s: [f32; 2],
    /// Rows in the fit.
    pub rows: u32,
}

impl MechanicsResult {
    /// Friction torque at `w_rad_s` [N m]: `B |w| + Fc` (magnitude).
    pub fn friction_nm(&self, w_rad_s: f32) -> f32 {
        self.viscous_friction_nm_s_per_rad * w_rad_s.abs() + self.coulomb_friction_nm
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum State {
    /// Torque pulse `k` (0: probe, +; 1: -; 2: +; 3: -, down to the low
    /// speed).
    Pulse { k: u8 },
    /// Velocity 0 until still; `slow` periods below the still band so far.
    Stop { slow: u32 },
}

/// One run's sums (of the filtered signals).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Run {
    n: u32,
    w0: f32,
    sum_iq: f32,
    sum_w: f32,
}

impl Run {
    /// A run starting at speed `w0`.
    fn start(w0: f32) -> Self {
        Self {
            n: 0,
            w0,
            sum_iq: 0.0,
            sum_w: 0.0,
        }
    }
}

/// Two first-order low-passes in series.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Lpf2 {
    s1: f32,
    s2: f32,
}

impl Lpf2 {
    fn update(&mut self, x: f32, alpha: f32) -> f32 {
        self.s1 += alpha * (x - self.s1);
        self.s2 += alpha * (self.s1 - self.s2);
        self.s2
    }
}

/// The filters of q current and speed.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Filters {
    iq: Lpf2,
    w: Lpf2,
}

impl Filters {
    /// Started at these values.
    fn new(iq: f32, w: f32) -> Self {
        let at = |x| Lpf2 { s1: x, s2: x };
        Self {
            iq: at(iq),
            w: at(w),
        }
    }

    fn update(&mut self, iq: f32, w: f32, alpha: f32) -> (f32, f32) {
        (self.iq.update(iq, alpha), self.w.update(w, alpha))
    }
}

/// Normal equations `M theta = v` of the scaled rows (symmetric `M`).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Normal {
    m11: f32,
    m12: f32,
    m13: f32,
    m22: f32,
    m23: f32,
    m33: f32,
    v1: f32,
    v2: f32,
    v3: f32,
    count: u32,
}

impl Normal {
    const ZERO: Self = Self {
        m11: 0.0,
        m12: 0.0,
        m13: 0.0,
        m22: 0.0,
        m23: 0.0,
        m33: 0.0,
        v1: 0.0,
        v2: 0.0,
        v3: 0.0,
        count: 0,
    };

    fn add(&mut self, x: [f32; 3], y: f32) {
        let [x1, x2, x3] = x;
        self.m11 += x1 * x1;
        self.m12 += x1 * x2;
        self.m13 += x1 * x3;
        self.m22 += x2 * x2;
        self.m23 += x2 * x3;
        self.m33 += x3 * x3;
        self.v1 += x1 * y;
        self.v2 += x2 * y;
        self.v3 += x3 * y;
        self.count = self.count.saturating_add(1);
    }

    /// Least-squares solution with the terms of `use_term` (the others
    /// held at 0), or `None` when the scaled determinant is below
    /// [`MIN_DETERMINANT`].
    fn solve(&self, use_term: [bool; 3]) -> Option<[f32; 3]> {
        let [u1, u2, u3] = use_term;
        // Scale to unit diagonal: c_ij = m_ij / (s_i s_j), s_i = sqrt(m_ii).
        let scale = |on: bool, m: f32| {
            if !on {
                Some(0.0)
            } else if m > 0.0 && m.is_finite() {
                Some(1.0 / crate::sqrtf(m))
            } else {
                None
            }
        };
        let (s1, s2, s3) = (
            scale(u1, self.m11)?,
            scale(u2, self.m22)?,
            scale(u3, self.m33)?,
        );
        // Excluded terms (scale 0): a unit row and column, right-hand side 0.
        let (c11, c22, c33) = (1.0, 1.0, 1.0);
        let c12 = self.m12 * s1 * s2;
        let c13 = self.m13 * s1 * s3;
        let c23 = self.m23 * s2 * s3;
        let (b1, b2, b3) = (self.v1 * s1, self.v2 * s2, self.v3 * s3);
        let det3 = |a: [f32; 9]| {
            let [a11, a12, a13, a21, a22, a23, a31, a32, a33] = a;
            a11 * (a22 * a33 - a23 * a32) - a12 * (a21 * a33 - a23 * a31)
                + a13 * (a21 * a32 - a22 * a31)
        };
        let det = det3([c11, c12, c13, c12, c22, c23, c13, c23, c33]);
        if !(det.is_finite() && det >= MIN_DETERMINANT) {
            return None;
        }
        let t1 = det3([b1, c12, c13, b2, c22, c23, b3, c23, c33]) / det;
        let t2 = det3([c11, b1, c13, c12, b2, c23, c13, b3, c33]) / det;
        let t3 = det3([c11, c12, b1, c12, c22, b2, c13, c23, b3]) / det;
        let th = [t1 * s1, t2 * s2, t3 * s3];
        th.iter().all(|x| x.is_finite()).then_some(th)
    }
}

#[inline]
fn sign(w: f32) -> f32 {
    if w > 0.0 {
        1.0
    } else if w < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// The mechanical identification state machine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MechanicalId {
    cfg: MechanicsConfig,
    state: State,
    /// Periods in the current state.
    n: u32,
    /// A closed-loop feedback has been seen.
    started: bool,
    /// q current of the pulse running (1 to 3) \[A\].
    i1_a: f32,
    /// Probe: period the speed first passed half the target.
    half_at: Option<u32>,
    /// Probe: highest speed magnitude seen [rad/s].
    peak_rad_s: f32,
    /// Pulse 1: periods at which `-w` first passed `CROSSINGS` times the
    /// target (braking, then accelerating).
    crossed: [Option<u32>; 4],
    /// The run being summed (`None` outside one).
    run: Option<Run>,
    /// Signal filters (from the first feedback on).
    filters: Option<Filters>,
    /// Periods in a row above the low speed at one sign, and that sign.
    steady: u32,
    steady_sign: f32,
    normal: Normal,
    result: Option<MechanicsResult>,
    finished: Option<CalStep<MechanicsResult>>,
}

impl MechanicalId {
    /// New measurement (first request: the probe pulse).
    pub fn new(config: MechanicsConfig) -> Self {
        Self {
            cfg: config,
            state: State::Pulse { k: 0 },
            n: 0,
            started: false,
            i1_a: config.current_a,
            half_at: None,
            peak_rad_s: 0.0,
            crossed: [None; 4],
            run: None,
            filters: None,
            steady: 0,
            steady_sign: 0.0,
            normal: Normal::ZERO,
            result: None,
            finished: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &MechanicsConfig {
        &self.cfg
    }

    /// One PWM period. See the module docs.
    pub fn step(&mut self, inp: &CalInput) -> CalStep<MechanicsResult> {
        if let Some(f) = self.finished {
            return f;
        }
        let r = self.run(inp);
        latch(&mut self.finished, r)
    }

    fn target(&self) -> f32 {
        self.cfg.speed_target_rad_s.unwrap_or(0.0)
    }

    /// This state's request.
    fn command(&self) -> CalStep<MechanicsResult> {
        let c = &self.cfg;
        match self.state {
            State::Pulse { k: 0 } => {
                // The probe's ramp: I / t_a per second, then I.
                let ramp = self.n as f32 * c.ts_s / c.accel_time_s;
                let ramp = if ramp < 1.0 { ramp } else { 1.0 };
                CalStep::Torque {
                    iq_a: ramp * c.current_a,
                }
            }
            State::Pulse { k } => CalStep::Torque {
                iq_a: pulse_sign(k) * self.i1_a,
            },
            State::Stop { .. } => CalStep::Velocity { rad_s: 0.0 },
        }
    }

    fn enter(&mut self, s: State) {
        self.state = s;
        self.n = 0;
        self.run = None;
    }

    /// Run bookkeeping for one period of a constant-current phase (`fit`:
    /// a pulse, whose runs go into the fit; else only the filters and the
    /// speed bookkeeping run).
    fn measure(&mut self, w: f32, iq: f32, fit: bool) {
        let c = &self.cfg;
        let w_t = self.target();
        let w_min = c.min_speed_fraction * w_t;
        // The same filter on every signal: the filtered ones obey the same
        // equation, with the speed's quantisation ripple smoothed.
        let alpha = c.ts_s / (c.filter_s + c.ts_s);
        let f = self.filters.get_or_insert(Filters::new(iq, w));
        let (iq_f, w_f) = f.update(iq, w, alpha);
        // Periods at one sign above the low speed, so far (of the filtered
        // speed: the raw estimate of a coarse sensor ripples across the
        // bound, and runs picked by its ripple would be biased).
        self.steady = if w_f.abs() >= w_min && sign(w_f) == self.steady_sign {
            self.steady.saturating_add(1)
        } else {
            self.steady_sign = sign(w_f);
            0
        };
        // The filter's memory: about 6 time constants of the two stages.
        let memory = if c.filter_s > 0.0 {
            periods(6.0 * c.filter_s, c.ts_s)
        } else {
            0
        };
        // A run: after the settling, at one sign above the low speed for
        // at least the filter's memory.
        if !fit || self.n < periods(c.settle_s, c.ts_s) || self.steady < memory {
            self.run = None;
            return;
        }
        let Some(run) = self.run.as_mut() else {
            self.run = Some(Run::start(w_f));
            return;
        };
        run.n += 1;
        run.sum_iq += iq_f;
        run.sum_w += w_f;
        let n_win = periods(c.window_s, c.ts_s);
        if !run.n.is_multiple_of(n_win) {
            return;
        }
        let r = *run;
        // Row: the run so far (from its start to here) in the integral
        // form, in units of one window (the speed's noise at the two ends
        // weighs less the longer the run):
        // y = int(iq) / (I T_w), x1 = dw t_a / (w_t T_w),
        // x2 = int(w) / (w_t T_w), x3 = sgn(w) T / T_w.
        let k = n_win as f32;
        let x = [
            (w_f - r.w0) * c.accel_time_s / (w_t * k * c.ts_s),
            r.sum_w / (k * w_t),
            self.steady_sign * r.n as f32 / k,
        ];
        let y = r.sum_iq / (k * c.current_a);
        if x.iter().all(|v| v.is_finite()) && y.is_finite() {
            self.normal.add(x, y);
        }
    }

    /// The fit and its checks.
    fn solve(&self) -> Result<MechanicsResult, CalError> {
        let c = &self.cfg;
        if self.normal.count < MIN_ROWS {
            return Err(CalError::MechanicsIllConditioned);
        }
        let mut th = self
            .normal
            .solve([true; 3])
            .ok_or(CalError::MechanicsIllConditioned)?;
        // A negative friction term is noise around a small true value:
        // refit without it (then with the inertia alone).
        let [_, b, f] = th;
        if b < 0.0 || f < 0.0 {
            th = self
                .normal
                .solve([true, b >= 0.0, f >= 0.0])
                .ok_or(CalError::MechanicsIllConditioned)?;
            let [_, b, f] = th;
            if b < 0.0 || f < 0.0 {
                th = self
                    .normal
                    .solve([true, false, false])
                    .ok_or(CalError::MechanicsIllConditioned)?;
            }
        }
        let [t1, t2, t3] = th;
        let w_t = self.target();
        let ki = c.torque_constant_nm_per_a * c.current_a; // [N m]
        let j = t1 * ki * c.accel_time_s / w_t;
        let b = t2 * ki / w_t;
        let fc = t3 * ki;
        let (j_lo, j_hi) = c.inertia_range_kg_m2;
        if !(j.is_finite() && j >= j_lo && j <= j_hi) {
            return Err(CalError::InertiaOutOfRange);
        }
        // The pulses reached the target against this friction with
        // `kt * I1`: more friction than that is not what was measured.
        let reached = c.torque_constant_nm_per_a * self.i1_a;
        let ok = |x: f32, max: f32| x.is_finite() && (0.0..=max).contains(&x);
        if !(ok(b, c.max_viscous_nm_s_per_rad)
            && ok(fc, c.max_coulomb_nm)
            && b * w_t + fc < reached)
        {
            return Err(CalError::FrictionOutOfRange);
        }
        Ok(MechanicsResult {
            inertia_kg_m2: j,
            viscous_friction_nm_s_per_rad: b,
            coulomb_friction_nm: fc,
            speeds_rad_s: [c.min_speed_fraction * w_t, w_t],
            rows: self.normal.count,
        })
    }

    fn run(&mut self, inp: &CalInput) -> Result<CalStep<MechanicsResult>, CalError> {
        let c = self.cfg;
        if !c.is_valid() {
            return Err(CalError::InvalidConfig);
        }
        check_input(inp, c.max_current_a)?;
        let Some(fb) = inp.closed_loop else {
            // The first period comes before any torque request was answered.
            if self.started {
                return Err(CalError::InvalidInput);
            }
            return Ok(self.command());
        };
        self.started = true;
        let (w, iq) = (fb.velocity_rad_s, fb.i_dq_a.q);
        self.n = self.n.saturating_add(1);
        match self.state {
            State::Pulse { k } => self.on_pulse(k, w, iq)?,
            State::Stop { slow } => {
                let w_min = c.min_speed_fraction * self.target();
                let slow = if w.abs() < 0.5 * w_min { slow + 1 } else { 0 };
                let still = slow >= periods(0.05, c.ts_s);
                if still || self.n > periods(c.stop_timeout_s, c.ts_s) {
                    if let Some(r) = self.result {
                        return Ok(CalStep::Done(r));
                    }
                    return Err(CalError::InvalidConfig);
                }
                self.state = State::Stop { slow };
            }
        }
        Ok(self.command())
    }

    /// One period of pulse `k`: the fit's rows, the probe's times, and the
    /// next pulse once this one reaches its speed.
    fn on_pulse(&mut self, k: u8, w: f32, iq: f32) -> Result<(), CalError> {
        let c = self.cfg;
        let w_t = self.target();
        let w_min = c.min_speed_fraction * w_t;
        // The probe's ramp does not go into the fit (the speed
        // estimate's lag changes with the acceleration).
        self.measure(w, iq, k > 0);
        let sw = pulse_sign(k) * w;
        self.time_probe(k, w, sw, w_t);
        let end = if k < 3 { sw >= w_t } else { sw >= -w_min };
        let limit = periods(c.pulse_timeout_s, c.ts_s);
        let limit = match k {
            0 => limit.saturating_add(periods(c.accel_time_s, c.ts_s)),
            1 | 2 => limit.saturating_mul(2),
            _ => limit,
        };
        if end {
            match k {
                0 => {
                    self.i1_a = self.pulse_current();
                    self.enter(State::Pulse { k: 1 });
                }
                1 => {
                    self.i1_a = self.refined_current();
                    self.enter(State::Pulse { k: 2 });
                }
                2 => self.enter(State::Pulse { k: 3 }),
                _ => {
                    self.result = Some(self.solve()?);
                    self.enter(State::Stop { slow: 0 });
                }
            }
        } else if self.n > limit {
            return Err(if k == 0 && self.peak_rad_s < w_min {
                CalError::NoAcceleration
            } else {
                CalError::SpeedNotReached
            });
        }
        Ok(())
    }

    /// The times the probe (pulse 0) and pulse 1 take to cross their speed
    /// levels, `sw` the speed signed in the pulse's direction.
    fn time_probe(&mut self, k: u8, w: f32, sw: f32, w_t: f32) {
        if k == 1 {
            for (at, level) in self.crossed.iter_mut().zip(CROSSINGS) {
                if at.is_none() && sw >= level * w_t {
                    *at = Some(self.n);
                }
            }
        }
        if k == 0 {
            if w.abs() > self.peak_rad_s {
                self.peak_rad_s = w.abs();
            }
            if self.half_at.is_none() && sw >= 0.5 * w_t {
                self.half_at = Some(self.n);
            }
        }
    }

    /// Current of pulse 1 (and of 2 and 3 without a refinement) from the
    /// probe's times (see the module docs), the probe ending now.
    fn pulse_current(&self) -> f32 {
        let c = &self.cfg;
        let i0 = c.current_a;
        let t_a = c.accel_time_s;
        let t_r = self.n as f32 * c.ts_s;
        if t_r >= t_a {
            // The ramp ended before the target: the full current.
            return i0;
        }
        let t_h = self.half_at.unwrap_or(0) as f32 * c.ts_s;
        let t0 = (core::f32::consts::SQRT_2 * t_h - t_r) / (core::f32::consts::SQRT_2 - 1.0);
        let t0 = crate::clamp(t0, 0.0, t_h);
        let dt = t_r - t0;
        let i = i0 * (t0 / t_a + dt * dt / (2.0 * t_a * t_a));
        if i.is_finite() {
            crate::clamp(i, c.min_current_fraction * i0, i0)
        } else {
            i0
        }
    }

    /// Current of pulses 2 and 3 from pulse 1's deceleration `b` (torque
    /// plus friction) and acceleration `a` (torque minus friction), each
    /// timed between two speeds of one half (a constant lag of the speed
    /// estimate cancels): `I_F = I1 (b - a) / (a + b)` and
    /// `J / kt = 2 I1 / (a + b)`, so `I2 = I1 (b - a + 2 w_t / t_a) / (a + b)`.
    /// The probe's `I1` when a crossing was missed.
    fn refined_current(&self) -> f32 {
        let c = &self.cfg;
        let [Some(b0), Some(b1), Some(a0), Some(a1)] = self.crossed else {
            return self.i1_a;
        };
        let w_t = self.target();
        let rate = |from: u32, to: u32| {
            let dn = to.saturating_sub(from).max(1);
            0.4 * w_t / (dn as f32 * c.ts_s)
        };
        let (b, a) = (rate(b0, b1), rate(a0, a1));
        let friction = if b > a { b - a } else { 0.0 };
        let i = self.i1_a * (friction + 2.0 * w_t / c.accel_time_s) / (a + b);
        if i.is_finite() {
            crate::clamp(i, c.min_current_fraction * c.current_a, c.current_a)
        } else {
            self.i1_a
        }
    }
}

/// Speeds (fractions of the target, in the direction of pulse 1) whose
/// crossing times give pulse 1's deceleration and acceleration.
const CROSSINGS: [f32; 4] = [-0.7, -0.3, 0.3, 0.7];

/// Direction of pulse `k` (+, -, +, -).
#[inline]
fn pulse_sign(k: u8) -> f32 {
    if k.is_multiple_of(2) {
        1.0
    } else {
        -1.0
    }
}

impl From<MechanicsResult> for crate::control::Mechanics {
    fn from(r: MechanicsResult) -> Self {
        Self {
            inertia_kg_m2: r.inertia_kg_m2,
            viscous_friction_nm_s_per_rad: r.viscous_friction_nm_s_per_rad,
            coulomb_friction_nm: r.coulomb_friction_nm,
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::angle::MechanicalAngle;
    use crate::calibration::ClosedLoopFeedback;
    use crate::control::estimator::{AngleTracker, AngleTrackerConfig};
    use crate::frames::{Abc, Dq};

    /// Rigid body with viscous and Coulomb friction (stiction at zero),
    /// a first-order current loop (0.2 ms) and one period of delay between
    /// a request and the feedback that shows it.
    #[derive(Clone, Copy, Debug)]
    struct Body {
        j: f64,
        b: f64,
        fc: f64,
        kt: f64,
        ts: f64,
        w: f64,
        theta: f64,
        iq: f64,
        locked: bool,
    }

    impl Body {
        fn new(j: f64, b: f64, fc: f64, kt: f64, pwm_hz: f64) -> Self {
            Self {
                j,
                b,
                fc,
                kt,
                ts: 1.0 / pwm_hz,
                w: 0.0,
                theta: 0.0,
                iq: 0.0,
                locked: false,
            }
        }

        /// One period at the q-current reference `iq_ref`.
        fn advance(&mut self, iq_ref: f64) {
            const SUB: usize = 10;
            let dt = self.ts / SUB as f64;
            for _ in 0..SUB {
                self.iq += (iq_ref - self.iq) * (dt / 2e-4);
                if self.locked {
                    continue;
                }
                let drive = self.kt * self.iq - self.b * self.w;
                if self.w == 0.0 && drive.abs() <= self.fc {
                    continue; // stiction
                }
                let dir = if self.w != 0.0 {
                    self.w.signum()
                } else {
                    drive.signum()
                };
                let w = self.w + dt * (drive - dir * self.fc) / self.j;
                self.w = if w * dir < 0.0 { 0.0 } else { w };
                self.theta += dt * self.w;
            }
        }
    }

    struct Run {
        out: CalStep<MechanicsResult>,
        periods: usize,
    }

    /// Drive the routine against `body`. `lagged`: the speed comes from an
    /// 80 Hz angle tracker on a 4096-count encoder (else the true speed);
    /// `nan_at`: a NaN speed from that period on.
    fn run(body: Body, cfg: MechanicsConfig, lagged: bool, nan_at: Option<usize>) -> Run {
        run_with(body, cfg, lagged.then_some(4096.0), nan_at)
    }

    /// As [`run`], the tracker on a `counts`-count encoder when given.
    fn run_with(
        mut body: Body,
        cfg: MechanicsConfig,
        counts: Option<f64>,
        nan_at: Option<usize>,
    ) -> Run {
        let mut m = MechanicalId::new(cfg);
        let mut tracker = AngleTracker::new(AngleTrackerConfig::with_bandwidth(
            2.0 * core::f32::consts::PI * 80.0,
            body.ts as f32,
        ));
        let mut fb: Option<ClosedLoopFeedback> = None;
        let mut noise = 0x2545_f491_u32;
        for k in 0..200_000 {
            let iq = body.iq as f32;
            let mut inp = CalInput::open_loop(
                Abc::new(iq, -0.5 * iq, -0.5 * iq),
                MechanicalAngle::ZERO,
                24.0,
            );
            inp.closed_loop = fb;
            let out = m.step(&inp);
            let iq_ref = match out {
                CalStep::Torque { iq_a } => iq_a as f64,
                CalStep::Velocity { rad_s } => {
                    let w = fb.map_or(0.0, |f| f.velocity_rad_s) as f64;
                    let lim = cfg.current_a as f64;
                    (body.j / body.kt * 200.0 * (rad_s as f64 - w)).clamp(-lim, lim)
                }
                CalStep::Apply { .. } => panic!("mechanics asks for closed loop only"),
                CalStep::Done(_) | CalStep::Failed(_) => return Run { out, periods: k },
            };
            body.advance(iq_ref);
            let w = if let Some(counts) = counts {
                let turns = body.theta / core::f64::consts::TAU;
                let q = libm::floor(turns * counts) / counts;
                tracker.update(MechanicalAngle::from_turns(q as f32));
                tracker.velocity_rad_s()
            } else {
                body.w as f32
            };
            // Current-sense noise, about 1 % of the test current.
            noise ^= noise << 13;
            noise ^= noise >> 17;
            noise ^= noise << 5;
            let n = (noise as f32 / u32::MAX as f32 - 0.5) * 0.03 * cfg.current_a;
            let w = if nan_at.is_some_and(|a| k >= a) {
                f32::NAN
            } else {
                w
            };
            fb = Some(ClosedLoopFeedback {
                v_dq_v: Dq::ZERO,
                i_dq_a: Dq::new(0.0, body.iq as f32 + n),
                velocity_rad_s: w,
                theta_e: crate::angle::ElectricalAngle::ZERO,
            });
        }
        panic!("routine did not finish");
    }

    /// (body, probe current \[A\], target speed [rad/s]): a light fast
    /// rotor, a heavy one with large friction, and a light one that the
    /// test current accelerates in a few milliseconds.
    fn motors() -> [(Body, f32, f32); 3] {
        [
            (Body::new(3e-6, 1e-7, 5e-4, 0.00697, 20e3), 2.5, 850.0),
            (Body::new(5e-3, 2e-3, 0.3, 0.744, 15e3), 15.0, 8.6),
            (Body::new(6e-5, 1e-5, 5e-3, 0.0756, 40e3), 10.0, 78.0),
        ]
    }

    fn config(body: &Body, i: f32, w_t: f32) -> MechanicsConfig {
        MechanicsConfig::new(
            (1.0 / body.ts) as f32,
            body.kt as f32,
            i,
            2.0 * i,
            Some(w_t),
        )
    }

    fn check(body: &Body, r: &MechanicsResult, tol_j: f64, tol_f: f64) {
        let ej = r.inertia_kg_m2 as f64 / body.j - 1.0;
        let f = |w: f64| body.fc + body.b * w;
        let [lo, hi] = r.speeds_rad_s;
        let e_lo = r.friction_nm(lo) as f64 / f(lo as f64) - 1.0;
        let e_hi = r.friction_nm(hi) as f64 / f(hi as f64) - 1.0;
        std::println!(
            "J {:.3e} ({:+.2} %), B {:.3e} (true {:.1e}), Fc {:.3e} (true {:.1e}), friction {:+.2} % at {lo:.1}, {:+.2} % at {hi:.1} rad/s, {} rows",
            r.inertia_kg_m2,
            100.0 * ej,
            r.viscous_friction_nm_s_per_rad,
            body.b,
            r.coulomb_friction_nm,
            body.fc,
            100.0 * e_lo,
            100.0 * e_hi,
            r.rows
        );
        assert!(ej.abs() < tol_j, "{r:?}");
        assert!(e_lo.abs() < tol_f && e_hi.abs() < tol_f, "{r:?}");
    }

    #[test]
    fn identifies_rigid_body_with_ideal_speed() {
        for (body, i, w_t) in motors() {
            let r = run(body, config(&body, i, w_t), false, None);
            let CalStep::Done(res) = r.out else {
                panic!("{body:?}: {:?}", r.out)
            };
            std::println!("{:.2} s", r.periods as f64 * body.ts);
            check(&body, &res, 0.02, 0.05);
            assert!(r.periods as f64 * body.ts < 2.0);
        }
    }

    #[test]
    fn identifies_rigid_body_with_tracked_speed() {
        for (body, i, w_t) in motors() {
            let r = run(body, config(&body, i, w_t), true, None);
            let CalStep::Done(res) = r.out else {
                panic!("{body:?}: {:?}", r.out)
            };
            std::println!("{:.2} s", r.periods as f64 * body.ts);
            check(&body, &res, 0.05, 0.10);
        }
    }

    #[test]
    fn identifies_rigid_body_with_a_coarse_encoder() {
        // A hub motor on a 48-count sensor: the tracked speed ripples by
        // several rad/s at the edge rate.
        let body = Body::new(1.5e-4, 2e-5, 0.065, 0.1079, 16e3);
        let r = run_with(body, config(&body, 5.0, 104.7), Some(48.0), None);
        let CalStep::Done(res) = r.out else {
            panic!("{body:?}: {:?}", r.out)
        };
        check(&body, &res, 0.05, 0.10);
    }

    #[test]
    fn locked_rotor_and_too_much_friction_do_not_accelerate() {
        let (mut body, i, w_t) = motors()[0];
        body.locked = true;
        let r = run(body, config(&body, i, w_t), true, None);
        assert_eq!(r.out, CalStep::Failed(CalError::NoAcceleration));
        // Friction above the test torque: stiction holds the rotor.
        let (mut body, i, w_t) = motors()[1];
        body.fc = 1.2 * body.kt * i as f64;
        let r = run(body, config(&body, i, w_t), false, None);
        assert_eq!(r.out, CalStep::Failed(CalError::NoAcceleration));
    }

    #[test]
    fn target_out_of_reach_is_named() {
        // Viscous friction holds the speed at half the target.
        let (mut body, i, w_t) = motors()[2];
        body.b = body.kt * i as f64 / (0.5 * w_t as f64);
        let r = run(body, config(&body, i, w_t), false, None);
        assert_eq!(r.out, CalStep::Failed(CalError::SpeedNotReached));
    }

    #[test]
    fn non_finite_input_and_bad_config_are_named() {
        let (body, i, w_t) = motors()[0];
        let r = run(body, config(&body, i, w_t), false, Some(500));
        assert_eq!(r.out, CalStep::Failed(CalError::InvalidInput));
        let mut cfg = config(&body, i, w_t);
        cfg.speed_target_rad_s = None;
        assert_eq!(
            run(body, cfg, false, None).out,
            CalStep::Failed(CalError::InvalidConfig)
        );
        let mut cfg = config(&body, i, w_t);
        cfg.torque_constant_nm_per_a = f32::NAN;
        assert_eq!(
            run(body, cfg, false, None).out,
            CalStep::Failed(CalError::InvalidConfig)
        );
        // Feedback missing after the first period.
        let mut m = MechanicalId::new(config(&body, i, w_t));
        let inp = CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0);
        assert!(matches!(m.step(&inp), CalStep::Torque { .. }));
        let mut with = inp;
        with.closed_loop = Some(ClosedLoopFeedback::default());
        assert!(matches!(m.step(&with), CalStep::Torque { .. }));
        assert_eq!(m.step(&inp), CalStep::Failed(CalError::InvalidInput));
        // Latched.
        assert_eq!(m.step(&with), CalStep::Failed(CalError::InvalidInput));
    }

    #[test]
    fn results_outside_the_bounds_are_named() {
        let (body, i, w_t) = motors()[2];
        let mut cfg = config(&body, i, w_t);
        cfg.inertia_range_kg_m2 = (1e-8, 0.5 * body.j as f32);
        assert_eq!(
            run(body, cfg, false, None).out,
            CalStep::Failed(CalError::InertiaOutOfRange)
        );
        let mut cfg = config(&body, i, w_t);
        cfg.max_coulomb_nm = 0.5 * body.fc as f32;
        assert_eq!(
            run(body, cfg, false, None).out,
            CalStep::Failed(CalError::FrictionOutOfRange)
        );
    }

    #[test]
    fn normal_equations_refuse_dependent_terms() {
        let mut n = Normal::ZERO;
        // x3 = x2 in every row: not separable.
        for k in 0..20 {
            let x = k as f32 * 0.1;
            n.add([1.0 - x, 0.5, 0.5], x);
        }
        assert_eq!(n.solve([true; 3]), None);
        // Without the third term it solves.
        let th = n.solve([true, true, false]).unwrap();
        assert!(th.iter().all(|t| t.is_finite()));
        assert_eq!(th[2], 0.0);
    }
}
