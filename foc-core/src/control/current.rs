//! The current loop (design §4-8, §10): measured phase currents and
//! the electrical angle in, three PWM duties out, every PWM period.
//!
//! ```text
//! i_abc --Clarke--> i_ab --Park(theta_e)--> i_dq
//! e_d = id_ref - id,  e_q = iq_ref - iq                 (design §6)
//! v_d = PI_d(e_d) + ff_d,  ff_d = -w_e Lq iq            (decoupling, optional)
//! v_q = PI_q(e_q) + ff_q,  ff_q =  w_e (Ld id + psi)
//! |v_dq| <= m_max * Udc / sqrt(3)   circle, d axis first, PI limits follow it
//! v_dq --inverse Park(theta_e + k w_e Ts)--> v_ab
//! v_ab += clarke(s(i_abc_ref)) Udc t_d / T              (dead time, optional)
//! v_ab --SVPWM(Udc)--> duties
//! ```
//!
//! The inverse Park (design §7, §8) is taken at the angle the rotor
//! will have when the voltage acts, `k` periods after the sample (`k` =
//! [`CurrentLoopConfig::delay_compensation_periods`], 1.5 by default: one
//! period of computation plus half a period of PWM hold). Without it the
//! applied vector lags by `1.5 w_e Ts` (13.5 deg electrical at one electrical
//! turn per 60 periods), which couples d and q at speed.
//!
//! The bridge's dead time is compensated on top of the limited voltage
//! ([`CurrentLoopConfig::dead_time`], off by default; design §31, module
//! [`super::dead_time`]): per phase `s(i_k) t_d / T` of duty, `s` a sign
//! smoothed over a band, `i_k` the reference's phase current at the angle
//! the voltage applies at. The PIs, the circle and the anti-windup do not
//! see it; [`CurrentLoopOutput::v_ab_v`] and the duties include it.
//!
//! The voltage limit is a circle (not a square) of the *measured* bus
//! voltage, so loop gains do not change with the bus. The d axis gets the
//! voltage it needs first (flux control), the q axis the rest. Each PI's
//! integrator is bounded by the same per-sample limit, which is the
//! anti-windup informed by the voltage circle.
//!
//! # Anti-windup: matched back-calculation ([`DEFAULT_ANTI_WINDUP`])
//!
//! The PIs cancel the winding's pole with their zero (`kp / ki = L / R`,
//! [`tuning::technical_optimum`]). Such a PI's integrator, unsaturated, is
//! the first-order lag `I = u / (1 + s L/R)` of its own output `u` (from
//! `u = kp e + I`, `dI/dt = ki e`), and so is `R i` for the winding
//! (`L di/dt + R i = u`, the feed-forward removing the rest): the integrator
//! holds `R i`, the voltage that keeps the present current. Each axis keeps
//! that relation through a saturation with back-calculation whose tracking
//! gain matches the zero, `kb = ki / (kp + ki Ts)` per axis
//! ([`AntiWindup::MatchedBackCalculation`]; `R / L` up to the discrete
//! correction, which matters where `R Ts / L` is not small, 0.36 to 0.48 on
//! the DJI M2006): in every sample `I += g (u - I)`, `g = ki Ts / (kp + ki
//! Ts)`, `u` the PI output actually applied (within the circle, less the
//! feed-forward). So when the loop leaves the limit the integrator already
//! holds about `R i` and the step settles as an unsaturated one does. On
//! the bench (`tests/tests/current_saturation.rs`: every motor file, rotor
//! locked, a q step whose first PI output is 1.6 or 2 times the circle)
//! that is 2 % within 7 to 10 periods after 3 to 6 saturated ones (1 %
//! within 10 to 14), against 8 to 11 for a step within the circle.
//!
//! - Conditional integration ([`AntiWindup::Clamp`], the default before)
//!   freezes the integrator while the step is on the limit: it leaves the
//!   limit near 0 instead of `R i`, the current comes to rest short of the
//!   reference by about `R / (kp + R)` of the step (2 % on the M153 at
//!   15 kHz, 17 % on the GL80 at 20 kHz) and creeps in with `L / R`:
//!   17 to 40 periods to the 2 % band on the bench; on the M153 the
//!   shortfall stays just inside 2 % (7 to 8 periods) but needs 39 to 83
//!   periods into 1 %.
//! - Back-calculation with the usual `kb = ki / kp` is the same to first
//!   order, but its per-sample step `ki Ts / kp = R Ts / L` exceeds the
//!   matched one by about `(R Ts / L)^2`, and through `u - u_raw` it also
//!   subtracts `g ki Ts e`: on a short time constant with a large error it
//!   drags the integrator down (DJI M2006: 13 periods instead of 8).
//!
//! The delay compensation does not change this (it rotates the applied
//! vector, not its d and q values); at speed the decoupling feed-forward is
//! outside the PIs, whose outputs and limits are both taken net of it. The
//! d axis, served first, is only limited when it alone asks for more than
//! the circle; the q axis tracks whatever the d axis leaves it. Per step
//! the matched form costs what the clamp did: only on a saturated sample, a
//! subtraction, a multiply-add and a clamp (the clamp's four comparisons
//! before), with `g` computed once per configuration, not per step.
//!
//! ```
//! use foc_core::control::current::{CurrentLoop, CurrentLoopConfig, CurrentLoopInput};
//! use foc_core::control::MotorParams;
//! use foc_core::{angle::ElectricalAngle, frames::{Abc, Dq}};
//! let motor = MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 50e-6, lq_h: 50e-6, flux_linkage_wb: 0.005 };
//! let mut cl = CurrentLoop::new(CurrentLoopConfig::technical_optimum(motor, 20_000.0));
//! let out = cl.step(&CurrentLoopInput {
//!     i_abc_a: Abc::new(0.0, 0.0, 0.0),
//!     theta_e: ElectricalAngle::ZERO,
//!     omega_e_rad_s: 0.0,
//!     v_bus_v: 24.0,
//!     i_dq_ref_a: Dq::new(0.0, 1.0),
//! });
//! assert!(out.v_dq_v.q > 0.0); // positive q error -> positive q voltage
//! assert!(out.duties.iter().all(|d| (0.0..=1.0).contains(d)));
//! ```

use super::dead_time::{DeadTimeCompensation, DeadTimeGains};
use super::MotorParams;
use crate::angle::ElectricalAngle;
use crate::frames::{Abc, AlphaBeta, Dq};
use crate::pi::{AntiWindup, Pi, PiConfig};
use crate::svpwm::{self, SvpwmOutput};
use crate::tuning::{self, CurrentPiGains};
use crate::{sqrtf, transforms, trig, FRAC_1_SQRT_3};

/// Current-loop configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CurrentLoopConfig {
    /// Loop period = PWM period \[s\].
    pub ts_s: f32,
    /// d-axis PI gains.
    pub d_gains: CurrentPiGains,
    /// q-axis PI gains.
    pub q_gains: CurrentPiGains,
    /// Motor parameters (for decoupling feed-forward).
    pub motor: MotorParams,
    /// Add the decoupling / back-EMF feed-forward terms.
    pub decoupling: bool,
    /// Fraction of the linear range `Udc/sqrt(3)` the dq voltage may use (0..=1).
    pub max_modulation: f32,
    /// Anti-windup of both PIs ([`DEFAULT_ANTI_WINDUP`] from the
    /// constructors: module docs, "Anti-windup").
    pub anti_windup: AntiWindup,
    /// Computation-delay compensation [PWM periods]: the voltage computed
    /// from the sample at `theta_e` acts from one period later and, averaged
    /// over that period, at `theta_e + 1.5 w_e Ts`. The inverse Park uses
    /// `theta_e + k w_e Ts` (the Park of the measured currents keeps the
    /// sampled angle). 1.5 for the usual one-period update; 0 disables.
    pub delay_compensation_periods: f32,
    /// Dead-time compensation ([`super::dead_time`], design §31):
    /// [`DeadTimeCompensation::OFF`] from the constructors; a drive sets
    /// it from its board's dead time
    /// ([`DeadTimeCompensation::for_current_limit`]).
    pub dead_time: DeadTimeCompensation,
}

/// The current loop's anti-windup, for both PIs: back-calculation with the
/// tracking gain matched to each PI's zero (`kb = ki / (kp + ki Ts)`, per
/// axis, from its gains): the integrator keeps holding about `R i` through
/// a saturation, so a voltage-limited step settles as fast as an
/// unsaturated one (module docs, "Anti-windup").
pub const DEFAULT_ANTI_WINDUP: AntiWindup = AntiWindup::MatchedBackCalculation;

/// Default [`CurrentLoopConfig::delay_compensation_periods`]: one period of
/// computation (duties latched at the next period start) plus half a period
/// of zero-order hold.
pub const DEFAULT_DELAY_COMPENSATION_PERIODS: f32 = 1.5;

impl CurrentLoopConfig {
    /// The source's tuning (design §11): technical optimum for both axes at
    /// the given PWM frequency, decoupling on, 95 % of the linear range,
    /// 1.5 periods of delay compensation, the matched back-calculation
    /// ([`DEFAULT_ANTI_WINDUP`]), no dead-time compensation (the board's
    /// dead time is not the motor's: see [`Self::dead_time`]).
    pub fn technical_optimum(motor: MotorParams, pwm_frequency_hz: f32) -> Self {
        let ts_s = 1.0 / pwm_frequency_hz;
        Self {
            ts_s,
            d_gains: tuning::technical_optimum(motor.ld_h, motor.r_ohm, ts_s),
            q_gains: tuning::technical_optimum(motor.lq_h, motor.r_ohm, ts_s),
            motor,
            decoupling: true,
            max_modulation: 0.95,
            anti_windup: DEFAULT_ANTI_WINDUP,
            delay_compensation_periods: DEFAULT_DELAY_COMPENSATION_PERIODS,
            dead_time: DeadTimeCompensation::OFF,
        }
    }
}

/// Inputs of one current-loop step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentLoopInput {
    /// Phase currents \[A\].
    pub i_abc_a: Abc,
    /// Electrical angle of the rotor d axis.
    pub theta_e: ElectricalAngle,
    /// Electrical angular velocity [rad/s] (for decoupling).
    pub omega_e_rad_s: f32,
    /// Measured bus voltage \[V\].
    pub v_bus_v: f32,
    /// Current reference \[A\].
    pub i_dq_ref_a: Dq,
}

/// Outputs of one current-loop step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentLoopOutput {
    /// Duties for phases A, B, C in `[0, 1]`.
    pub duties: [f32; 3],
    /// Measured currents in the dq frame \[A\].
    pub i_dq_a: Dq,
    /// Commanded dq voltage \[V\] (after the circle limit): the PIs' and
    /// the feed-forward's, without the dead-time compensation (the voltage
    /// the winding gets once the bridge's error is cancelled).
    pub v_dq_v: Dq,
    /// The alpha/beta voltage handed to the modulator \[V\]: `v_dq_v` at
    /// the angle it applies at, plus the dead-time compensation when on
    /// (module docs).
    pub v_ab_v: AlphaBeta,
    /// Modulator report (sector, times, saturation, validity).
    pub svpwm: SvpwmOutput,
    /// True when the voltage circle limited the output.
    pub voltage_limited: bool,
    /// True when an input was unusable: duties are centred, state untouched.
    pub invalid: bool,
    /// `(sin, cos)` of the angle the measured currents were turned by
    /// (the sample's `theta_e`).
    pub sin_cos: (f32, f32),
}

/// The current loop: two PIs plus the frame transforms and modulator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentLoop {
    config: CurrentLoopConfig,
    pi_d: Pi,
    pi_q: Pi,
    /// `delay_compensation_periods * ts_s` \[s\] (0 when that is not finite):
    /// the voltage angle's advance per rad/s of `w_e`.
    advance_s: f32,
    /// `ki * ts` of the d and q PIs (see [`Pi::ki_ts`]).
    ki_ts: Dq,
    /// The d and q PIs' [`PiConfig::matched_tracking_gain`] (used with
    /// [`AntiWindup::MatchedBackCalculation`] only).
    track_g: Dq,
    /// Every PI gain (`kp`, `ki * ts`, both axes) is finite: the step takes
    /// [`Pi::step_error_lean`], otherwise the general step, out of line.
    gains_finite: bool,
    /// `gains_finite` and the q PI's `kp` and `ki * ts` are `>= 0`: the
    /// step may take [`Self::pi_q_inside_circle`].
    q_fast: bool,
    /// The dead-time compensation's per-step values (off: not applied).
    dead: DeadTimeGains,
}

/// The loop's `advance_s`: `k Ts`, or 0 for k = 0 or an unusable product.
fn advance_s(c: &CurrentLoopConfig) -> f32 {
    let a = c.delay_compensation_periods * c.ts_s;
    if a.is_finite() {
        a
    } else {
        0.0
    }
}

fn pi_config(g: CurrentPiGains, c: &CurrentLoopConfig) -> PiConfig {
    PiConfig {
        kp: g.kp_v_per_a,
        ki_per_s: g.ki_v_per_a_s,
        ts_s: c.ts_s,
        out_min: -1.0e9,
        out_max: 1.0e9,
        anti_windup: c.anti_windup,
    }
}

impl CurrentLoop {
    /// New loop with zero integrators.
    pub fn new(config: CurrentLoopConfig) -> Self {
        let mut cl = Self {
            pi_d: Pi::new(pi_config(config.d_gains, &config)),
            pi_q: Pi::new(pi_config(config.q_gains, &config)),
            advance_s: 0.0,
            ki_ts: Dq::ZERO,
            track_g: Dq::ZERO,
            gains_finite: false,
            q_fast: false,
            dead: DeadTimeGains::OFF,
            config,
        };
        cl.derive();
        cl
    }

    /// The values derived from the configuration once, not every step.
    fn derive(&mut self) {
        self.advance_s = advance_s(&self.config);
        self.ki_ts = Dq::new(self.pi_d.ki_ts(), self.pi_q.ki_ts());
        self.track_g = Dq::new(
            self.pi_d.config.matched_tracking_gain(),
            self.pi_q.config.matched_tracking_gain(),
        );
        self.gains_finite = crate::all_finite([
            self.pi_d.config.kp,
            self.pi_q.config.kp,
            self.ki_ts.d,
            self.ki_ts.q,
        ]);
        self.q_fast = self.gains_finite && self.pi_q.config.kp >= 0.0 && self.ki_ts.q >= 0.0;
        self.dead = self.config.dead_time.gains(self.config.ts_s);
    }

    /// The configuration.
    pub fn config(&self) -> &CurrentLoopConfig {
        &self.config
    }

    /// Replace the configuration (gains), keeping the integrators.
    pub fn set_config(&mut self, config: CurrentLoopConfig) {
        self.pi_d.config = pi_config(config.d_gains, &config);
        self.pi_q.config = pi_config(config.q_gains, &config);
        self.config = config;
        self.derive();
    }

    /// Zero both integrators.
    pub fn reset(&mut self) {
        self.pi_d.reset();
        self.pi_q.reset();
    }

    /// Bumpless entry from an open-loop voltage: preload the integrators so
    /// that zero current error reproduces `v_dq_v` (less the feed-forward the
    /// next step adds at `omega_e_rad_s` and currents `i_dq_a`).
    pub fn preload(&mut self, v_dq_v: Dq, i_dq_a: Dq, omega_e_rad_s: f32) {
        let ff = self.feed_forward(i_dq_a, omega_e_rad_s);
        self.pi_d.preload(v_dq_v.d - ff.d);
        self.pi_q.preload(v_dq_v.q - ff.q);
    }

    /// Integrator values \[V\] (d, q).
    pub fn integrators(&self) -> Dq {
        Dq::new(self.pi_d.state.integral, self.pi_q.state.integral)
    }

    #[inline]
    fn feed_forward(&self, i: Dq, omega_e: f32) -> Dq {
        if self.config.decoupling {
            let m = &self.config.motor;
            Dq::new(
                -omega_e * m.lq_h * i.q,
                omega_e * (m.ld_h * i.d + m.flux_linkage_wb),
            )
        } else {
            Dq::ZERO
        }
    }

    /// The d-axis PI on this sample's limits (same results as
    /// [`Pi::step_error`]).
    #[inline(always)]
    fn step_pi_d(&mut self, error: f32, lo: f32, hi: f32) -> f32 {
        if self.gains_finite {
            let kp = self.pi_d.config.kp;
            self.pi_d
                .step_error_lean(error, lo, hi, kp, self.ki_ts.d, self.track_g.d)
        } else {
            self.pi_d.step_error_cold(error, lo, hi)
        }
    }

    /// The q-axis PI, as [`Self::step_pi_d`].
    #[inline(always)]
    fn step_pi_q(&mut self, error: f32, lo: f32, hi: f32) -> f32 {
        if self.gains_finite {
            let kp = self.pi_q.config.kp;
            self.pi_q
                .step_error_lean(error, lo, hi, kp, self.ki_ts.q, self.track_g.q)
        } else {
            self.pi_q.step_error_cold(error, lo, hi)
        }
    }

    /// The q-axis PI step when the voltage circle cannot act on it, without
    /// the circle's square root: `None` when that is not certain (then the
    /// caller takes [`Self::step_pi_q`] on the limits `+-sqrt(rem) - ff_q`).
    ///
    /// [`Pi::step_error_lean`] clamps three values to `[lo, hi]`: the stored
    /// integrator `i_prev`, the new integrator `i = i_prev + ki_ts e` and
    /// `u = kp e + i`. With `kp, ki_ts >= 0` (`q_fast`) `i` lies between
    /// `i_prev` and `u` (f32 rounding is monotonic), so when both ends are
    /// inside the limits no clamp acts, the output is `u`, unsaturated, and
    /// the result is bit for bit that of the general step, whatever the
    /// exact value of the limits. Inside is tested on the squares:
    /// `(x + ff_q)^2 <= r = rem (1 - 2^-16) - 2^-20 ff_q^2`. The margins
    /// cover the square root's relative error (below 1e-6) and the
    /// roundings of `lo = -s - ff_q`, `hi = s - ff_q`, `x + ff_q` and the
    /// squares (a few 1e-7 relative, plus `2^-24 |ff_q|` absolute, which
    /// the `ff_q^2` term covers: `2 s 2^-24 |f| <= 6.8e-6 s^2 + 5.2e-10
    /// f^2`); `rem >= 1e-30` keeps everything clear of subnormals. NaN or
    /// infinite values fail the comparisons. About 15 instructions instead
    /// of the square root (about 30) and three clamps.
    #[inline(always)]
    fn pi_q_inside_circle(&mut self, error: f32, rem: f32, ff_q: f32) -> Option<f32> {
        if !self.q_fast {
            return None;
        }
        let i_prev = self.pi_q.state.integral;
        let i = i_prev + self.ki_ts.q * error;
        let u = self.pi_q.config.kp * error + i;
        let r = rem * (1.0 - 1.0 / 65_536.0) - (1.0 / 1_048_576.0) * (ff_q * ff_q);
        let a = i_prev + ff_q;
        let b = u + ff_q;
        if (1e-30..=f32::MAX).contains(&rem) && a * a <= r && b * b <= r {
            self.pi_q.state = crate::pi::PiState {
                integral: i,
                output: u,
                saturated: false,
            };
            Some(u)
        } else {
            None
        }
    }

    /// One step. Non-finite inputs or a bus at or below zero give centred
    /// duties with `invalid = true` and leave the integrators untouched.
    #[inline]
    pub fn step(&mut self, inp: &CurrentLoopInput) -> CurrentLoopOutput {
        self.step_inline(inp)
    }

    /// [`Self::step`], always inlined: the current stage's copy, so that the
    /// output fields it does not use (the modulator's times and modulation
    /// index, with its square root) are never computed there, and the
    /// output is not copied through memory.
    #[inline(always)]
    pub(crate) fn step_inline(&mut self, inp: &CurrentLoopInput) -> CurrentLoopOutput {
        self.step_inline_ab(inp, transforms::clarke(inp.i_abc_a))
    }

    /// [`Self::step_inline`] with `i_ab = clarke(inp.i_abc_a)` already
    /// computed by the caller (the current stage needs it for the
    /// supervisor's current-vector check too).
    #[inline(always)]
    pub(crate) fn step_inline_ab(
        &mut self,
        inp: &CurrentLoopInput,
        i_ab: AlphaBeta,
    ) -> CurrentLoopOutput {
        if !inputs_usable(inp) {
            return CurrentLoopOutput::INVALID;
        }
        let (sin, cos) = trig::sin_cos(inp.theta_e);
        let i_dq = transforms::park(i_ab, sin, cos);
        let ff = self.feed_forward(i_dq, inp.omega_e_rad_s);
        let v_max = self.config.max_modulation * inp.v_bus_v * FRAC_1_SQRT_3;

        // d axis first: total v_d = u_d + ff_d within [-v_max, v_max].
        let u_d = self.step_pi_d(inp.i_dq_ref_a.d - i_dq.d, -v_max - ff.d, v_max - ff.d);
        let v_d = u_d + ff.d;
        // q axis: what is left of the circle.
        let rem = v_max * v_max - v_d * v_d;
        let e_q = inp.i_dq_ref_a.q - i_dq.q;
        let u_q = match self.pi_q_inside_circle(e_q, rem, ff.q) {
            Some(u) => u,
            None => {
                let v_q_max = if rem > 0.0 { sqrtf(rem) } else { 0.0 };
                self.step_pi_q(e_q, -v_q_max - ff.q, v_q_max - ff.q)
            }
        };
        let v_dq = Dq::new(v_d, u_q + ff.q);
        // The voltage acts about `k` periods after the sample: apply it in
        // the dq frame of the rotor as it will be then, `k w_e Ts` ahead.
        // Up to `SMALL_ROTATION_MAX_RAD` (w_e up to 3,333 rad/s at 20 kHz
        // and k = 1.5) the sampled angle's (sin, cos) is rotated by a short
        // Taylor series (`trig::rotate_small`, within 4e-7 of the exact
        // rotation); beyond, a second `sin_cos` of the advanced angle.
        // k = 0 (or unusable) makes `advance` 0, which rotates by nothing.
        let advance = self.advance_s * inp.omega_e_rad_s;
        let (sin_v, cos_v) = if advance.abs() <= trig::SMALL_ROTATION_MAX_RAD {
            trig::rotate_small((sin, cos), advance)
        } else {
            trig::sin_cos(inp.theta_e.add_radians(advance))
        };
        let v_ab = transforms::inverse_park(v_dq, sin_v, cos_v);
        // The dead time's error cancelled on top of the limited voltage,
        // from the reference's phase currents at the same angle (design
        // §31; the PIs and the circle above never see it).
        let v_ab = if self.dead.is_on() {
            let c = self
                .dead
                .voltage_ab(inp.i_dq_ref_a, sin_v, cos_v, inp.v_bus_v);
            AlphaBeta::new(v_ab.alpha + c.alpha, v_ab.beta + c.beta)
        } else {
            v_ab
        };
        let sv = svpwm::svpwm_inline(v_ab, inp.v_bus_v);
        CurrentLoopOutput {
            duties: sv.duties,
            i_dq_a: i_dq,
            v_dq_v: v_dq,
            v_ab_v: v_ab,
            svpwm: sv,
            voltage_limited: self.pi_d.state.saturated || self.pi_q.state.saturated,
            invalid: sv.invalid,
            sin_cos: (sin, cos),
        }
    }
}

impl CurrentLoop {
    /// Open-loop voltage step (alignment, bring-up): applies `v_dq_v` at
    /// `theta_e`, limited to the same voltage circle, and reports the
    /// measured dq currents. The PIs are not stepped. No dead-time
    /// compensation here (no current reference to take its sign from, and
    /// the identification measures the bridge's drop with open-loop
    /// voltages: design §31).
    pub fn step_voltage(
        &mut self,
        i_abc_a: Abc,
        theta_e: ElectricalAngle,
        v_dq_v: Dq,
        v_bus_v: f32,
    ) -> CurrentLoopOutput {
        let inp = CurrentLoopInput {
            i_abc_a,
            theta_e,
            omega_e_rad_s: 0.0,
            v_bus_v,
            i_dq_ref_a: Dq::ZERO,
        };
        if !crate::all_finite([v_dq_v.d, v_dq_v.q]) || !inputs_usable(&inp) {
            return CurrentLoopOutput::INVALID;
        }
        let (sin, cos) = trig::sin_cos(theta_e);
        let v_max = self.config.max_modulation * v_bus_v * FRAC_1_SQRT_3;
        let mag = v_dq_v.magnitude();
        let (v_dq, limited) = if mag > v_max {
            let k = v_max / mag;
            (Dq::new(v_dq_v.d * k, v_dq_v.q * k), true)
        } else {
            (v_dq_v, false)
        };
        let v_ab = transforms::inverse_park(v_dq, sin, cos);
        let sv = svpwm::svpwm(v_ab, v_bus_v);
        CurrentLoopOutput {
            duties: sv.duties,
            i_dq_a: transforms::park(transforms::clarke(i_abc_a), sin, cos),
            v_dq_v: v_dq,
            v_ab_v: v_ab,
            svpwm: sv,
            voltage_limited: limited,
            invalid: sv.invalid,
            sin_cos: (sin, cos),
        }
    }
}

/// True when every input of `inp` is finite and the bus is above zero: one
/// combined finiteness check (see [`crate::all_finite`]) instead of seven.
#[inline(always)]
fn inputs_usable(inp: &CurrentLoopInput) -> bool {
    let i = &inp.i_abc_a;
    crate::all_finite([
        i.a,
        i.b,
        i.c,
        inp.i_dq_ref_a.d,
        inp.i_dq_ref_a.q,
        inp.omega_e_rad_s,
        inp.v_bus_v,
    ]) && inp.v_bus_v > 0.0
}

impl CurrentLoopOutput {
    /// The output for an unusable input: centred duties, zero vectors, the
    /// modulator's neutral report, `invalid` set.
    const INVALID: Self = Self {
        duties: [0.5; 3],
        i_dq_a: Dq::ZERO,
        v_dq_v: Dq::ZERO,
        v_ab_v: AlphaBeta::new(0.0, 0.0),
        svpwm: SvpwmOutput::NEUTRAL_INVALID,
        voltage_limited: false,
        invalid: true,
        sin_cos: (0.0, 1.0),
    };
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;

    fn motor() -> MotorParams {
        MotorParams {
            pole_pairs: 7,
            r_ohm: 0.2,
            ld_h: 100e-6,
            lq_h: 120e-6,
            flux_linkage_wb: 0.01,
        }
    }

    fn input(iq_ref: f32) -> CurrentLoopInput {
        CurrentLoopInput {
            i_abc_a: Abc::default(),
            theta_e: ElectricalAngle::from_degrees(33.0),
            omega_e_rad_s: 0.0,
            v_bus_v: 24.0,
            i_dq_ref_a: Dq::new(0.0, iq_ref),
        }
    }

    #[test]
    fn voltage_stays_inside_circle_and_d_has_priority() {
        let mut cl = CurrentLoop::new(CurrentLoopConfig::technical_optimum(motor(), 20e3));
        let mut inp = input(1000.0); // absurd reference: saturate
        inp.i_dq_ref_a.d = -1000.0;
        let v_max = 0.95 * 24.0 * FRAC_1_SQRT_3;
        for _ in 0..100 {
            let o = cl.step(&inp);
            assert!(o.v_dq_v.magnitude() <= v_max * 1.0001);
            assert!(o.voltage_limited);
            assert!(!o.svpwm.saturated, "circle is inside the hexagon");
        }
        // d demanded the full circle: it gets it, q gets nothing.
        let o = cl.step(&inp);
        assert!((o.v_dq_v.d + v_max).abs() < 1e-3);
        assert!(o.v_dq_v.q.abs() < 1e-2);
        // Integrators bounded by the circle (no windup).
        assert!(cl.integrators().d.abs() <= v_max * 1.0001);
    }

    /// A locked rotor's winding (no back-EMF, no coupling) at a fixed
    /// angle, with the loop's period of computation delay: the voltage
    /// computed from the sample of period k acts over period k + 1 (held,
    /// `L di/dt = v - R i` solved exactly over the period per axis).
    struct Winding {
        m: MotorParams,
        ts_s: f32,
        theta_e: ElectricalAngle,
        i: Dq,
        next_v: Dq,
    }

    impl Winding {
        fn new(m: MotorParams, ts_s: f32) -> Self {
            Self {
                m,
                ts_s,
                theta_e: ElectricalAngle::from_degrees(33.0),
                i: Dq::ZERO,
                next_v: Dq::ZERO,
            }
        }

        /// The loop's input for this period's sample.
        fn input(&self, i_ref: Dq, v_bus_v: f32) -> CurrentLoopInput {
            let (s, c) = trig::sin_cos(self.theta_e);
            CurrentLoopInput {
                i_abc_a: transforms::inverse_clarke(transforms::inverse_park(self.i, s, c)),
                theta_e: self.theta_e,
                omega_e_rad_s: 0.0,
                v_bus_v,
                i_dq_ref_a: i_ref,
            }
        }

        /// One period: the voltage computed last period acts, `v` waits.
        fn period(&mut self, v: Dq) {
            let v_now = core::mem::replace(&mut self.next_v, v);
            let axis = |i: f32, v: f32, l: f32| {
                let a = std::primitive::f32::exp(-self.m.r_ohm * self.ts_s / l);
                a * i + (1.0 - a) * v / self.m.r_ohm
            };
            self.i = Dq::new(
                axis(self.i.d, v_now.d, self.m.ld_h),
                axis(self.i.q, v_now.q, self.m.lq_h),
            );
        }
    }

    /// First period from which `x` stays within 2 % of the step `target`
    /// (from 0) to the end.
    fn settling_2pct(x: &[f32], target: f32) -> usize {
        x.iter()
            .rposition(|v| (v - target).abs() > 0.02 * target.abs())
            .map_or(0, |k| k + 1)
    }

    struct StepFigures {
        /// Periods on the voltage limit from the step on.
        saturated: usize,
        /// 2 % settling of the stepped axis \[periods\].
        settling: usize,
        /// Overshoot of the stepped axis [% of the step].
        overshoot_pct: f32,
        /// Largest current on the other axis \[A\].
        other_max_a: f32,
    }

    /// A current step `i_ref` (on one axis) on the [`Winding`] from rest at
    /// bus `v_bus_v`, with the technical optimum and `anti_windup`.
    fn step_on_winding(anti_windup: AntiWindup, i_ref: Dq, v_bus_v: f32) -> StepFigures {
        let ts = 1.0 / 20e3;
        let mut cl = CurrentLoop::new(CurrentLoopConfig {
            anti_windup,
            ..CurrentLoopConfig::technical_optimum(motor(), 20e3)
        });
        let mut w = Winding::new(motor(), ts);
        let (mut x, mut other) = (std::vec::Vec::new(), 0.0f32);
        let mut saturated = 0;
        let q = i_ref.q != 0.0;
        let target = if q { i_ref.q } else { i_ref.d };
        for k in 0..400 {
            let (now, off) = if q { (w.i.q, w.i.d) } else { (w.i.d, w.i.q) };
            x.push(now);
            other = other.max(off.abs());
            let o = cl.step(&w.input(i_ref, v_bus_v));
            assert!(!o.invalid);
            if o.voltage_limited && saturated == k {
                saturated += 1;
            }
            w.period(o.v_dq_v);
        }
        let peak = x.iter().map(|v| v / target).fold(0.0f32, f32::max);
        StepFigures {
            saturated,
            settling: settling_2pct(&x, target),
            overshoot_pct: 100.0 * (peak - 1.0).max(0.0),
            other_max_a: other,
        }
    }

    /// Issue 18: a current step whose first periods are on the voltage limit
    /// (`(kp + ki Ts) I` is 1.6 times the circle at a 10 V bus; the final
    /// `R I` = 2 V is well inside it) settles into 2 % within 12 periods on
    /// both axes, as an unsaturated step does, with the default (matched
    /// back-calculation). Conditional integration (the old default) leaves
    /// the limit with the integrator near 0 and creeps in with `L / R`
    /// (31 and 26 periods here): it fails the same criterion.
    #[test]
    fn saturated_current_step_settles_within_12_periods() {
        let cfg = CurrentLoopConfig::technical_optimum(motor(), 20e3);
        assert_eq!(cfg.anti_windup, DEFAULT_ANTI_WINDUP);
        for i_ref in [Dq::new(0.0, 10.0), Dq::new(-10.0, 0.0)] {
            let new = step_on_winding(cfg.anti_windup, i_ref, 10.0);
            let old = step_on_winding(AntiWindup::Clamp, i_ref, 10.0);
            std::println!(
                "{i_ref:?}: default: {} periods saturated, {:.2} % overshoot, settles in {}; \
                 clamp: {} saturated, {:.2} %, settles in {}",
                new.saturated,
                new.overshoot_pct,
                new.settling,
                old.saturated,
                old.overshoot_pct,
                old.settling
            );
            assert!(new.saturated >= 2, "{i_ref:?}: {} periods", new.saturated);
            assert!(new.settling <= 12, "{i_ref:?}: {} periods", new.settling);
            assert!(
                new.overshoot_pct < 5.0,
                "{i_ref:?}: {} %",
                new.overshoot_pct
            );
            assert!(
                new.other_max_a < 0.02 * 10.0,
                "{i_ref:?}: {}",
                new.other_max_a
            );
            assert!(
                old.saturated >= 2 && old.settling > 12,
                "{i_ref:?}: {}",
                old.settling
            );
        }
        // The same step within the circle (24 V bus): not saturated, and
        // the same figures with either anti-windup (it never acts).
        for i_ref in [Dq::new(0.0, 10.0), Dq::new(-10.0, 0.0)] {
            let a = step_on_winding(cfg.anti_windup, i_ref, 24.0);
            let b = step_on_winding(AntiWindup::Clamp, i_ref, 24.0);
            assert_eq!(a.saturated, 0);
            assert!(a.settling <= 12, "{i_ref:?}: {}", a.settling);
            assert_eq!((a.settling, a.overshoot_pct), (b.settling, b.overshoot_pct));
        }
    }

    /// After a long saturation (a reference the bus cannot reach) the
    /// integrators hold no more than the circle, and a reversed reference
    /// turns the voltage round at once and settles in a few periods: no
    /// windup. (The matched back-calculation's integrator then holds the
    /// voltage the winding needs for the current it carries, not a frozen
    /// value.)
    #[test]
    fn recovers_quickly_after_saturation() {
        let ts = 1.0 / 20e3;
        for aw in [DEFAULT_ANTI_WINDUP, AntiWindup::Clamp] {
            let mut cl = CurrentLoop::new(CurrentLoopConfig {
                anti_windup: aw,
                ..CurrentLoopConfig::technical_optimum(motor(), 20e3)
            });
            let v_max = 0.95 * 24.0 * FRAC_1_SQRT_3;
            let mut w = Winding::new(motor(), ts);
            for _ in 0..10_000 {
                let o = cl.step(&w.input(Dq::new(0.0, 1000.0), 24.0));
                assert!(o.voltage_limited);
                w.period(o.v_dq_v);
            }
            // The winding carries v_max / R = 66 A.
            assert!((w.i.q - v_max / 0.2).abs() < 0.1, "{aw:?}: {}", w.i.q);
            assert!(cl.integrators().q.abs() <= v_max * 1.0001);
            let o = cl.step(&w.input(Dq::new(0.0, -1.0), 24.0));
            assert!(
                o.v_dq_v.q < -0.99 * v_max,
                "{aw:?}: wound up: {}",
                o.v_dq_v.q
            );
            w.period(o.v_dq_v);
            for _ in 0..60 {
                let o = cl.step(&w.input(Dq::new(0.0, -1.0), 24.0));
                w.period(o.v_dq_v);
            }
            assert!((w.i.q + 1.0).abs() < 0.1, "{aw:?}: {}", w.i.q);
        }
    }

    #[test]
    fn nan_input_gives_centred_duties_and_keeps_state() {
        let mut cl = CurrentLoop::new(CurrentLoopConfig::technical_optimum(motor(), 20e3));
        cl.step(&input(1.0));
        let before = cl.integrators();
        for bad in [
            {
                let mut i = input(1.0);
                i.i_abc_a.a = f32::NAN;
                i
            },
            {
                let mut i = input(1.0);
                i.v_bus_v = 0.0;
                i
            },
            {
                let mut i = input(f32::INFINITY);
                i.omega_e_rad_s = 1.0;
                i
            },
        ] {
            let o = cl.step(&bad);
            assert!(o.invalid);
            assert_eq!(o.duties, [0.5; 3]);
            assert_eq!(cl.integrators(), before);
        }
    }

    #[test]
    fn decoupling_feed_forward_at_speed() {
        // At speed with zero current and zero error, v_q equals w psi.
        let m = motor();
        let mut cl = CurrentLoop::new(CurrentLoopConfig::technical_optimum(m, 20e3));
        let mut inp = input(0.0);
        inp.omega_e_rad_s = 500.0;
        let o = cl.step(&inp);
        assert!((o.v_dq_v.q - 500.0 * m.flux_linkage_wb).abs() < 1e-4);
        assert!(o.v_dq_v.d.abs() < 1e-6);
    }

    /// The dq voltage lands at the advanced angle `theta_e + 1.5 w_e Ts`
    /// (Park of v_ab there gives back v_dq), the measured currents are
    /// still taken at the sampled angle, and k = 0 applies it at the
    /// sampled angle.
    #[test]
    fn delay_compensation_advances_the_voltage_angle() {
        let m = motor();
        let cfg = CurrentLoopConfig::technical_optimum(m, 20e3);
        assert_eq!(cfg.delay_compensation_periods, 1.5);
        let mut inp = input(2.0);
        inp.omega_e_rad_s = 2000.0; // 0.15 rad advance at 20 kHz
        let th = ElectricalAngle::from_degrees(33.0);
        // A pure d current of 1 A at the sampled angle.
        let (s, c) = trig::sin_cos(th);
        let ab = transforms::inverse_park(Dq::new(1.0, 0.0), s, c);
        inp.i_abc_a = Abc::new(ab.alpha, -0.5 * ab.alpha + 0.866_025_4 * ab.beta, 0.0);
        inp.i_abc_a.c = -inp.i_abc_a.a - inp.i_abc_a.b;
        for (k, advance) in [(1.5f32, 1.5 * 2000.0 / 20e3), (0.0, 0.0)] {
            let mut cl = CurrentLoop::new(CurrentLoopConfig {
                delay_compensation_periods: k,
                ..cfg
            });
            let o = cl.step(&inp);
            assert!((o.i_dq_a.d - 1.0).abs() < 1e-4 && o.i_dq_a.q.abs() < 1e-4);
            let (sv, cv) = trig::sin_cos(th.add_radians(advance));
            let back = transforms::park(o.v_ab_v, sv, cv);
            assert!(
                (back.d - o.v_dq_v.d).abs() < 1e-3 && (back.q - o.v_dq_v.q).abs() < 1e-3,
                "k = {k}: {back:?} vs {:?}",
                o.v_dq_v
            );
            // ... and not at the other angle (0.15 rad apart).
            let other = if k == 0.0 { 1.5 * 2000.0 / 20e3 } else { 0.0 };
            let (so, co) = trig::sin_cos(th.add_radians(other));
            let wrong = transforms::park(o.v_ab_v, so, co);
            assert!((wrong.d - o.v_dq_v.d).abs() > 0.1 * o.v_dq_v.magnitude());
        }
    }

    #[test]
    fn bumpless_preload_reproduces_voltage() {
        let mut cl = CurrentLoop::new(CurrentLoopConfig::technical_optimum(motor(), 20e3));
        let v = Dq::new(1.5, -0.5);
        cl.preload(v, Dq::ZERO, 0.0);
        let mut inp = input(0.0);
        inp.i_dq_ref_a = Dq::ZERO;
        let o = cl.step(&inp);
        assert!((o.v_dq_v.d - v.d).abs() < 1e-5 && (o.v_dq_v.q - v.q).abs() < 1e-5);
    }

    /// Both ways of advancing the voltage angle (the small-angle rotation
    /// up to `SMALL_ROTATION_MAX_RAD`, a second `sin_cos` beyond) put the
    /// voltage at `theta_e + k w_e Ts` while Park keeps the sampled angle,
    /// on both sides of the switch-over and in both directions.
    #[test]
    fn delay_compensation_small_and_large_advances() {
        let cfg = CurrentLoopConfig::technical_optimum(motor(), 20e3);
        for w in [
            -6000.0f32, -3333.0, -3334.0, -100.0, 100.0, 3333.0, 3334.0, 6000.0,
        ] {
            for deg in [0.0f32, 33.0, 89.9, 181.0, 300.0] {
                let th = ElectricalAngle::from_degrees(deg);
                let mut inp = input(2.0);
                inp.theta_e = th;
                inp.omega_e_rad_s = w;
                let mut cl = CurrentLoop::new(cfg);
                let o = cl.step(&inp);
                let (s, c) = trig::sin_cos(th);
                let ab = transforms::inverse_park(o.i_dq_a, s, c);
                assert!(ab.alpha.abs() < 1e-6 && ab.beta.abs() < 1e-6); // zero currents
                let adv = 1.5 * w / 20e3;
                let (sv, cv) = trig::sin_cos(th.add_radians(adv));
                let back = transforms::park(o.v_ab_v, sv, cv);
                let tol = 1e-5 * (1.0 + o.v_dq_v.magnitude());
                assert!(
                    (back.d - o.v_dq_v.d).abs() < tol && (back.q - o.v_dq_v.q).abs() < tol,
                    "w {w}, {deg} deg: {back:?} vs {:?}",
                    o.v_dq_v
                );
            }
        }
    }

    /// The q PI's shortcut inside the voltage circle changes nothing: the
    /// same outputs and states, bit for bit, as the step that always takes
    /// the square root, from deep inside the circle to saturation, at
    /// speed (large feed-forward) and with values placed right at the
    /// circle's edge.
    #[test]
    fn q_shortcut_matches_the_square_root_path() {
        let bits = |o: &CurrentLoopOutput| {
            let d = o.duties.map(f32::to_bits);
            (
                d,
                o.v_dq_v.d.to_bits(),
                o.v_dq_v.q.to_bits(),
                o.voltage_limited,
            )
        };
        let mut seed = 0x1234_5678u32;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed as f32 / u32::MAX as f32
        };
        let mut hits = 0u32;
        let mut misses = 0u32;
        for (k, mm) in [0.95f32, 0.5, 1.0].into_iter().enumerate() {
            let cfg = CurrentLoopConfig {
                max_modulation: mm,
                anti_windup: if k == 1 {
                    AntiWindup::BackCalculation { kb_per_s: 2000.0 }
                } else {
                    AntiWindup::Clamp
                },
                ..CurrentLoopConfig::technical_optimum(motor(), 20e3)
            };
            let mut fast = CurrentLoop::new(cfg);
            assert!(fast.q_fast);
            let mut slow = fast;
            slow.q_fast = false;
            for n in 0..200_000u32 {
                let scale = [0.1f32, 5.0, 60.0, 1000.0][(n / 1000 % 4) as usize];
                let mut inp = input((rnd() - 0.5) * scale);
                inp.i_dq_ref_a.d = (rnd() - 0.5) * scale * 0.3;
                inp.omega_e_rad_s =
                    (rnd() - 0.5) * [0.0f32, 2000.0, 20000.0][(n / 300 % 3) as usize];
                inp.v_bus_v = 24.0 * (0.5 + rnd());
                inp.theta_e = ElectricalAngle::from_bits((rnd() * 4.0e9) as u32);
                inp.i_abc_a = Abc::new((rnd() - 0.5) * 4.0, (rnd() - 0.5) * 4.0, 0.0);
                inp.i_abc_a.c = -inp.i_abc_a.a - inp.i_abc_a.b;
                if n % 7 == 0 {
                    // Put the stored q integrator right on (or one ulp
                    // around) the last limit.
                    let lim = slow.pi_q.state.output;
                    let v = f32::from_bits(lim.to_bits().wrapping_add(n % 3).wrapping_sub(1));
                    fast.pi_q.state.integral = v;
                    slow.pi_q.state.integral = v;
                }
                let before = fast.pi_q.state;
                let (a, b) = (fast.step(&inp), slow.step(&inp));
                assert_eq!(bits(&a), bits(&b), "{n}: {inp:?} {before:?}");
                assert_eq!(
                    fast.pi_q.state.integral.to_bits(),
                    slow.pi_q.state.integral.to_bits()
                );
                assert_eq!(
                    fast.pi_q.state.output.to_bits(),
                    slow.pi_q.state.output.to_bits()
                );
                assert_eq!(fast.pi_q.state.saturated, slow.pi_q.state.saturated);
                assert_eq!(fast.pi_d.state, slow.pi_d.state);
                if a.voltage_limited {
                    misses += 1;
                } else {
                    hits += 1;
                }
            }
        }
        assert!(hits > 10_000 && misses > 10_000, "{hits} {misses}");
    }

    /// 500 ns at 20 kHz (1 % of the period), band 0.5 A.
    fn with_dead_time(cfg: CurrentLoopConfig) -> CurrentLoopConfig {
        CurrentLoopConfig {
            dead_time: DeadTimeCompensation {
                dead_time_s: 500e-9,
                band_a: 0.5,
            },
            ..cfg
        }
    }

    /// A random input generator (xorshift) over references, currents,
    /// speeds, buses and angles, from deep inside the circle to far
    /// beyond it.
    fn random_inputs(seed: u32) -> impl FnMut(u32) -> CurrentLoopInput {
        let mut seed = seed;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed as f32 / u32::MAX as f32
        };
        move |n| {
            let scale = [0.1f32, 2.0, 20.0, 1000.0][(n / 500 % 4) as usize];
            let mut inp = input((rnd() - 0.5) * scale);
            inp.i_dq_ref_a.d = (rnd() - 0.5) * scale * 0.3;
            inp.omega_e_rad_s = (rnd() - 0.5) * [0.0f32, 2000.0, 8000.0][(n / 300 % 3) as usize];
            inp.v_bus_v = 24.0 * (0.5 + rnd());
            inp.theta_e = ElectricalAngle::from_bits((rnd() * 4.0e9) as u32);
            inp.i_abc_a = Abc::new((rnd() - 0.5) * 4.0, (rnd() - 0.5) * 4.0, 0.0);
            inp.i_abc_a.c = -inp.i_abc_a.a - inp.i_abc_a.b;
            inp
        }
    }

    fn output_bits(o: &CurrentLoopOutput) -> ([u32; 3], [u32; 4], bool, bool) {
        (
            o.duties.map(f32::to_bits),
            [
                o.v_dq_v.d.to_bits(),
                o.v_dq_v.q.to_bits(),
                o.v_ab_v.alpha.to_bits(),
                o.v_ab_v.beta.to_bits(),
            ],
            o.voltage_limited,
            o.invalid,
        )
    }

    /// Off (the constructors' default, a dead time of 0, or values that
    /// are not usable) the loop's outputs and states are bit for bit
    /// those of the loop without the compensation, closed loop and open
    /// loop.
    #[test]
    fn dead_time_off_is_bit_identical() {
        let base = CurrentLoopConfig::technical_optimum(motor(), 20e3);
        assert_eq!(base.dead_time, DeadTimeCompensation::OFF);
        for dt in [
            DeadTimeCompensation {
                dead_time_s: 0.0,
                band_a: 0.5,
            },
            DeadTimeCompensation {
                dead_time_s: f32::NAN,
                band_a: 0.5,
            },
            DeadTimeCompensation {
                dead_time_s: 500e-9,
                band_a: 0.0,
            },
            DeadTimeCompensation {
                dead_time_s: 500e-9,
                band_a: f32::NAN,
            },
            DeadTimeCompensation {
                dead_time_s: 20e-6,
                band_a: 0.5,
            },
        ] {
            let mut off = CurrentLoop::new(base);
            let mut other = CurrentLoop::new(CurrentLoopConfig {
                dead_time: dt,
                ..base
            });
            assert!(!other.dead.is_on(), "{dt:?}");
            let mut gen = random_inputs(0x9e37_79b9);
            for n in 0..4000 {
                let inp = gen(n);
                let (a, b) = (off.step(&inp), other.step(&inp));
                assert_eq!(output_bits(&a), output_bits(&b), "{dt:?} {n}");
                assert_eq!(off.pi_d.state, other.pi_d.state);
                assert_eq!(off.pi_q.state, other.pi_q.state);
            }
        }
    }

    /// On, the PIs, the circle and the anti-windup see exactly what they
    /// see off (the same `v_dq_v`, integrators, limit flags, bit for bit);
    /// `v_ab_v` differs by the compensation of the reference's phase
    /// currents at the angle the voltage applies at; the duties stay in
    /// `[0, 1]`.
    #[test]
    fn dead_time_sits_on_top_of_the_limited_voltage() {
        for mm in [0.95f32, 1.0] {
            let base = CurrentLoopConfig {
                max_modulation: mm,
                ..CurrentLoopConfig::technical_optimum(motor(), 20e3)
            };
            let on_cfg = with_dead_time(base);
            let gains = on_cfg.dead_time.gains(on_cfg.ts_s);
            let mut off = CurrentLoop::new(base);
            let mut on = CurrentLoop::new(on_cfg);
            assert!(on.dead.is_on());
            let mut gen = random_inputs(0x1234_5678);
            let mut limited = 0;
            for n in 0..20_000 {
                let inp = gen(n);
                let (a, b) = (off.step(&inp), on.step(&inp));
                assert_eq!(a.v_dq_v.d.to_bits(), b.v_dq_v.d.to_bits(), "{n}");
                assert_eq!(a.v_dq_v.q.to_bits(), b.v_dq_v.q.to_bits(), "{n}");
                assert_eq!(a.voltage_limited, b.voltage_limited);
                assert_eq!(off.pi_d.state, on.pi_d.state);
                assert_eq!(off.pi_q.state, on.pi_q.state);
                assert!(b.duties.iter().all(|d| (0.0..=1.0).contains(d)), "{b:?}");
                assert!(!b.invalid);
                let adv = 1.5 * inp.omega_e_rad_s / 20e3;
                let (s, c) = trig::sin_cos(inp.theta_e.add_radians(adv));
                let want = gains.voltage_ab(inp.i_dq_ref_a, s, c, inp.v_bus_v);
                let got = AlphaBeta::new(
                    b.v_ab_v.alpha - a.v_ab_v.alpha,
                    b.v_ab_v.beta - a.v_ab_v.beta,
                );
                let tol = 1e-5 * (1.0 + a.v_dq_v.magnitude());
                assert!(
                    (got.alpha - want.alpha).abs() < tol && (got.beta - want.beta).abs() < tol,
                    "{n}: {got:?} {want:?}"
                );
                limited += usize::from(a.voltage_limited);
            }
            assert!(limited > 1000, "{limited}");
        }
    }

    /// Inside the modulator's range the compensation is the duty
    /// `s(i_k) t_d / T` on each phase (up to the common mode the
    /// modulator adds): 1 % of the period on each line where both phase
    /// references are beyond the band, a share inside it; it follows the
    /// reference, not the measured current.
    #[test]
    fn dead_time_adds_the_phase_duties() {
        let base = CurrentLoopConfig::technical_optimum(motor(), 20e3);
        let mut off = CurrentLoop::new(base);
        let mut on = CurrentLoop::new(with_dead_time(base));
        // Reference 4 A along phase a's axis (rotor at 0, at rest): phase
        // a +4 A, b and c -2 A: all beyond the 0.5 A band.
        let mut inp = input(0.0);
        inp.theta_e = ElectricalAngle::ZERO;
        inp.i_dq_ref_a = Dq::new(4.0, 0.0);
        // The measured currents are small and of the other sign: ignored.
        inp.i_abc_a = Abc::new(-0.1, 0.05, 0.05);
        let (a, b) = (off.step(&inp), on.step(&inp));
        let line = |d: [f32; 3]| [d[0] - d[1], d[1] - d[2], d[2] - d[0]];
        let (la, lb) = (line(a.duties), line(b.duties));
        let want = [0.02f32, 0.0, -0.02]; // 0.01 (1 - (-1)), 0, -0.02
        for k in 0..3 {
            assert!((lb[k] - la[k] - want[k]).abs() < 1e-5, "{la:?} {lb:?}");
        }
        // Reference 0.6 A along a: phase a beyond the band (+1), b and c
        // -0.3 A, inside it (-0.6 each).
        inp.i_dq_ref_a = Dq::new(0.6, 0.0);
        let (a, b) = (off.step(&inp), on.step(&inp));
        let (la, lb) = (line(a.duties), line(b.duties));
        let want = [0.01 * 1.6f32, 0.0, -0.01 * 1.6];
        for k in 0..3 {
            assert!((lb[k] - la[k] - want[k]).abs() < 1e-5, "{la:?} {lb:?}");
        }
        // No reference: nothing added.
        inp.i_dq_ref_a = Dq::ZERO;
        let (a, b) = (off.step(&inp), on.step(&inp));
        for k in 0..3 {
            assert!((a.duties[k] - b.duties[k]).abs() < 1e-6);
        }
    }

    /// At speed the sign is the reference's at the angle the voltage
    /// applies at (`theta_e + 1.5 w_e Ts`), not at the sampled angle:
    /// just before the reference's phase-a current crosses zero, the
    /// compensation already has the sign it has after the crossing.
    #[test]
    fn dead_time_sign_at_the_applied_angle() {
        let base = CurrentLoopConfig::technical_optimum(motor(), 20e3);
        let mut off = CurrentLoop::new(base);
        let mut on = CurrentLoop::new(with_dead_time(base));
        // q reference 10 A: phase a's current is -10 sin(theta); at
        // theta = -3 deg it is +0.52 A (beyond the band), the voltage
        // applies 0.15 rad (8.6 deg) later where it is -0.98 A.
        let mut inp = input(10.0);
        inp.theta_e = ElectricalAngle::from_degrees(-3.0);
        inp.omega_e_rad_s = 2000.0;
        let (a, b) = (off.step(&inp), on.step(&inp));
        let d = AlphaBeta::new(
            b.v_ab_v.alpha - a.v_ab_v.alpha,
            b.v_ab_v.beta - a.v_ab_v.beta,
        );
        let s = transforms::inverse_clarke(d);
        // Phase a's share of the compensation is negative: clarke(-1, b, c)
        // with b, c of opposite signs gives a = 2/3 (-1) - 1/3 (b + c) < 0.
        assert!(s.a < -0.5 * 0.01 * 24.0, "{s:?}");
    }

    /// The open-loop voltage step is never compensated (the identification
    /// measures the bridge's drop with it): bit for bit the same.
    #[test]
    fn step_voltage_is_not_compensated() {
        let base = CurrentLoopConfig::technical_optimum(motor(), 20e3);
        let mut off = CurrentLoop::new(base);
        let mut on = CurrentLoop::new(with_dead_time(base));
        for deg in [0.0f32, 45.0, 200.0] {
            let th = ElectricalAngle::from_degrees(deg);
            let i = Abc::new(2.0, -1.0, -1.0);
            let v = Dq::new(1.5, 0.5);
            let (a, b) = (
                off.step_voltage(i, th, v, 24.0),
                on.step_voltage(i, th, v, 24.0),
            );
            assert_eq!(output_bits(&a), output_bits(&b));
        }
    }

    /// With the compensation on, an unusable input still gives centred
    /// duties and leaves the integrators as they were.
    #[test]
    fn dead_time_on_nan_input_gives_centred_duties() {
        let mut cl = CurrentLoop::new(with_dead_time(CurrentLoopConfig::technical_optimum(
            motor(),
            20e3,
        )));
        cl.step(&input(1.0));
        let before = cl.integrators();
        let mut bad = input(1.0);
        bad.i_dq_ref_a.d = f32::NAN;
        let o = cl.step(&bad);
        assert!(o.invalid);
        assert_eq!(o.duties, [0.5; 3]);
        assert_eq!(cl.integrators(), before);
    }
}
