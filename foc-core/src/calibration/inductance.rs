//! d- and q-axis inductance from a square-wave voltage on top of a DC
//! holding current.
//!
//! The rotor is held at `theta_e = 0` by a DC d current `bias_current_a`
//! (voltage found by the same integrator as in [`super::resistance`]). Then
//! a square wave `+-V` is added to the d voltage, later to the q voltage,
//! its sign flipping every `N` PWM periods (a *half-wave* of `N >= 1`
//! periods). Each period the current changes by
//!
//! ```text
//! delta_i_k = (Ts / L) * (u_(k-d) + V_bias - R i - e)  ~=  (Ts / L) u_(k-d)
//! ```
//!
//! where `u_k` is the wave voltage commanded in period `k` and `d` the loop
//! delay (1 or 2 periods, up to 3 accepted), because the DC terms balance
//! (the bias integrator keeps `V_bias = R i + e` on average, `e` being the
//! constant dead-time error) and the resistive drop of a centred triangle
//! averages out against the square wave. So, by least squares,
//!
//! ```text
//! L = Ts / g,     g = sum( u_(k-d) delta_i_k ) / sum( u_(k-d)^2 )
//! ```
//!
//! evaluated for `d = 1, 2, 3` and taking the largest `|g|` (for `N = 1`
//! every lag gives the same magnitude; for `N > 1` a wrong lag mixes in
//! periods of the other sign and only lowers it). Sensor noise averages out
//! instead of adding a bias, and the result does not depend on the loop
//! delay.
//!
//! **Why half-waves of several periods.** The ripple (peak to peak) is
//! `V N Ts / L`. With `N = 1` a large inductance on a limited voltage gives
//! a ripple of only a few ADC steps (the 51 mH q axis of a 2.2 kW IPM motor
//! at 119 V and 15 kHz: 0.155 A, 8.7 steps of a 12-bit ADC over +-36 A).
//! Without sensor noise the sampled triangle then repeats exactly, so its
//! quantisation error does not average out: each corner of the triangle
//! reads up to half a step off, every cycle, which biased that Lq by
//! -5.5 % (and Ld by +3 %). So the probing below chooses `N` as well as
//! `V`, and reaches the ripple target (`ripple_fraction` of the bias, many
//! ADC steps) whatever the inductance.
//!
//! **Amplitude sweep.** During the measurement the amplitude sweeps
//! linearly from `V` down to `(1 - sweep_depth) V` and back, every
//! `sweep_half_waves` half-waves, over whole sweeps. The corners of the
//! triangle (the only samples that do not cancel in the sum, per
//! half-wave) then cover a range of many ADC steps instead of two fixed
//! values, so what is left of the quantisation error averages out too, with
//! or without noise. The least-squares `g` uses the voltage actually
//! commanded in each period, so the sweep needs no correction.
//!
//! Assumptions:
//! - Within a half-wave the current is nearly a straight line: `N` is
//!   limited so that `N Ts` stays within `max_half_wave_tau_fraction` (0.2)
//!   of `L / R`. The straight-line estimate of the exact exponential
//!   response is `L (a / 2) / tanh(a / 2) ~= L (1 + a^2 / 12)` with
//!   `a = R N Ts / L` (+1.1 % for the DJI M2006's `a = 0.36` at `N = 1`);
//!   with the resistance known (`r_ohm`, which the sequencer fills in from
//!   the resistance step) the result is corrected exactly, otherwise the
//!   limit keeps it within 0.33 % for `N > 1` (`R` then taken as
//!   `V_bias / i`, which the dead-time drop only raises).
//! - No phase current crosses zero: the ripple target (`ripple_fraction` of
//!   the bias, peak to peak) keeps the dead-time error constant. With the
//!   default 0.3 the q ripple peak is 0.15 of the bias, far below the
//!   `bias / sqrt(3)` at which phases B and C would cross zero.
//! - The rotor stays aligned (Ld along d); the q wave averages to zero
//!   torque: every change of the wave (start, probe, sweep, stop) uses a
//!   half-wave of the mean of the old and the new volt-periods, which keeps
//!   the triangle centred. Where the torque ripple overcomes the friction
//!   the rotor vibrates, and its back-EMF (a capacitance
//!   `J / (1.5 p^2 psi^2)` in series with Lq) reads Lq low by about
//!   `1.5 p^2 psi^2 / (J w^2 Lq)` at the wave's `w = pi / (N Ts)`: 0.02 %
//!   for the 2.2 kW IPM motor, 0.24 % for M153 (`N = 6`).
//! - Inductance at the bias current: the incremental inductance there
//!   (saturation is not separated; on a motor whose d axis saturates with
//!   its own current the result lies below the inductance at zero
//!   current, by 5 % on the bench's GL80 file).
//!
//! The wave is found by probing: start at `start_voltage_v` with `N = 1`,
//! fit `g` over a probe (`probe_periods`, at least two whole cycles), aim
//! the volt-periods `V N` at `target / g` (at most 8x up or down per probe)
//! with the smallest `N` for which `V` fits the voltage headroom (`N` at
//! most `max_half_wave_periods` and the time-constant limit above), until
//! the ripple lies within a factor of 2 of the target (or the wave is at
//! its limits with at least a tenth of it), then measure over
//! `measure_periods` (rounded up to whole sweeps). Changes take effect at
//! half-wave boundaries; `skip_periods` plus the transition half-wave are
//! ignored after each.
//!
//! ```
//! use foc_core::calibration::inductance::{Inductance, InductanceConfig};
//! use foc_core::calibration::{CalInput, CalStep};
//! use foc_core::{angle::MechanicalAngle, frames::Abc};
//! let mut l = Inductance::new(InductanceConfig::new(20_000.0, 2.0, 6.0));
//! let s = l.step(&CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0));
//! let (v, theta) = s.voltage().unwrap(); // ramping the DC bias on d at 0 deg
//! assert!(v.d > 0.0 && v.q == 0.0 && theta.to_bits() == 0);
//! ```

use super::common::{
    approach_v, check_input, current_dq, latch, periods, voltage_limit_v, CalError, CalInput,
    CalStep, Motion,
};
use crate::angle::ElectricalAngle;
use crate::frames::Dq;

/// Loop delays (periods between commanding a voltage and the first current
/// difference it causes) the fit considers: 1 ..= `MAX_DELAY_PERIODS`.
const MAX_DELAY_PERIODS: usize = 3;

/// Configuration of the inductance measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InductanceConfig {
    /// PWM (step) period \[s\].
    pub ts_s: f32,
    /// DC d current holding the rotor \[A\].
    pub bias_current_a: f32,
    /// Target ripple (peak to peak) as a fraction of the bias (e.g. 0.3).
    pub ripple_fraction: f32,
    /// Largest open-loop voltage \[V\] (also limited by the bus).
    pub max_voltage_v: f32,
    /// Current vector that aborts the routine \[A\].
    pub max_current_a: f32,
    /// Approach rate of the bias current [rad/s].
    pub loop_bandwidth_rad_s: f32,
    /// Fastest change of the bias voltage [V/s].
    pub ramp_v_per_s: f32,
    /// Time the bias must stay within 3 % before injecting \[s\].
    pub settle_s: f32,
    /// Time limit for the bias to settle \[s\].
    pub bias_timeout_s: f32,
    /// First square-wave amplitude \[V\].
    pub start_voltage_v: f32,
    /// Periods ignored after every change of the wave (on top of the
    /// transition half-wave).
    pub skip_periods: u32,
    /// Periods per probe (at least two whole wave cycles are used).
    pub probe_periods: u32,
    /// Periods of the final measurement per axis (rounded up to whole
    /// amplitude sweeps).
    pub measure_periods: u32,
    /// Probes per axis before giving up ([`CalError::Timeout`]).
    pub max_probes: u8,
    /// Longest half-wave [PWM periods] (at least 1).
    pub max_half_wave_periods: u32,
    /// Longest half-wave as a fraction of the winding time constant `L / R`
    /// (with `R = V_bias / i`) \[1\].
    pub max_half_wave_tau_fraction: f32,
    /// Depth of the amplitude sweep during the measurement, as a fraction
    /// of the amplitude (0: none, below 1).
    pub sweep_depth: f32,
    /// Half-waves from the top of the amplitude sweep to its bottom.
    pub sweep_half_waves: u32,
    /// Phase resistance \[ohm\] for the correction of the exponential current
    /// response and the half-wave limit (the sequencer sets the resistance
    /// step's result). 0: unknown, no correction (the half-wave limit then
    /// takes `V_bias / i`, which the dead-time drop only raises).
    pub r_ohm: f32,
    /// Tell the rotor's swing onto the bias from the current instead of
    /// the angle sensor (a drive without one, design §29): while no wave
    /// runs, a q current (low-passed over 16 periods) above
    /// [`SWING_IQ_SHARE`] of the bias is a rotor that still turns (its
    /// back-EMF drives it).
    pub swing_from_current: bool,
}

/// With [`InductanceConfig::swing_from_current`]: a q current above this
/// share of the bias current, while no wave runs, is a rotor that swings.
pub const SWING_IQ_SHARE: f32 = 0.05;

impl InductanceConfig {
    /// Defaults for a PWM frequency, a bias current \[A\] and a voltage limit
    /// \[V\]: 30 % ripple, 50 ms settle, start at 2 % of the voltage limit,
    /// 32 periods skipped, 64-period probes, 4000-period measurement,
    /// half-waves of at most 64 periods and 0.2 `L / R`, amplitude swept by
    /// 50 % over 32 half-waves, resistance unknown.
    pub fn new(pwm_frequency_hz: f32, bias_current_a: f32, max_voltage_v: f32) -> Self {
        Self {
            ts_s: 1.0 / pwm_frequency_hz,
            bias_current_a,
            ripple_fraction: 0.3,
            max_voltage_v,
            max_current_a: 1.5 * bias_current_a,
            loop_bandwidth_rad_s: 30.0,
            ramp_v_per_s: 10.0,
            settle_s: 0.05,
            bias_timeout_s: 2.0,
            start_voltage_v: 0.02 * max_voltage_v,
            skip_periods: 32,
            probe_periods: 64,
            measure_periods: 4000,
            max_probes: 16,
            max_half_wave_periods: 64,
            max_half_wave_tau_fraction: 0.2,
            sweep_depth: 0.5,
            sweep_half_waves: 32,
            r_ohm: 0.0,
            swing_from_current: false,
        }
    }

    fn is_valid(&self) -> bool {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        pos(self.ts_s)
            && pos(self.bias_current_a)
            && pos(self.ripple_fraction)
            && self.ripple_fraction <= 1.0
            && pos(self.max_voltage_v)
            && pos(self.max_current_a)
            && pos(self.loop_bandwidth_rad_s)
            && pos(self.ramp_v_per_s)
            && pos(self.settle_s)
            && pos(self.bias_timeout_s)
            && pos(self.start_voltage_v)
            && self.probe_periods > 0
            && self.measure_periods > 0
            && self.max_half_wave_periods > 0
            && pos(self.max_half_wave_tau_fraction)
            && self.sweep_depth.is_finite()
            && (0.0..1.0).contains(&self.sweep_depth)
            && self.sweep_half_waves > 0
            && self.r_ohm.is_finite()
            && self.r_ohm >= 0.0
    }
}

/// Result of the inductance measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InductanceResult {
    /// d-axis inductance \[H\].
    pub ld_h: f32,
    /// q-axis inductance \[H\].
    pub lq_h: f32,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Axis {
    D,
    Q,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum State {
    Bias(u32),
    Probe {
        axis: Axis,
        n: u8,
    },
    Measure(Axis),
    /// Back to no injection between the axes.
    Gap(u32),
}

/// The square-wave generator: half-waves of `len` periods at `volts`,
/// alternating in sign.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Wave {
    /// Sign of the running half-wave.
    sign: f32,
    /// Amplitude of the running half-wave \[V\].
    volts: f32,
    /// Periods left in the running half-wave (0: at a boundary).
    left: u32,
    /// Volt-periods the previous half-wave aimed at [V periods].
    last_v_periods: f32,
    /// Length the previous half-wave aimed at \[periods\].
    last_len: u32,
    /// Half-waves started (wrapping).
    count: u32,
}

impl Wave {
    const IDLE: Self = Self {
        sign: -1.0,
        volts: 0.0,
        left: 0,
        last_v_periods: 0.0,
        last_len: 1,
        count: 0,
    };

    /// No wave and none to come back from.
    fn idle(&self) -> bool {
        self.left == 0 && self.last_v_periods == 0.0
    }

    /// At a boundary: start the next half-wave aiming at `amp_v` for
    /// `len` periods. It applies the mean of the previous and the new
    /// volt-periods (the triangle stays centred through any change), over
    /// the longer of the two lengths (so the amplitude stays within the
    /// larger of the two). Returns the length of the started half-wave
    /// (0: none, the wave is idle).
    fn start(&mut self, amp_v: f32, len: u32) -> u32 {
        let target = amp_v * len as f32;
        if target == 0.0 && self.last_v_periods == 0.0 {
            self.volts = 0.0;
            self.last_len = len.max(1);
            return 0;
        }
        let n = len.max(self.last_len).max(1);
        self.sign = -self.sign;
        self.volts = 0.5 * (self.last_v_periods + target) / n as f32;
        self.left = n;
        self.last_v_periods = target;
        self.last_len = len.max(1);
        self.count = self.count.wrapping_add(1);
        n
    }
}

/// The inductance from the straight-line estimate `l_est_h` of a square
/// wave with half-waves of `half_s` on a winding of `r_ohm` (0: unknown,
/// no correction). The corners of the exact (exponential) steady-state
/// triangle are `+-(V / R) tanh(a / 2)` with `a = R half / L`, so
/// `l_est = (R half / 2) / tanh(a / 2)` and
/// `L = R half / (2 atanh(R half / (2 l_est)))` \[H\]. `None` for a
/// non-positive or non-finite estimate, or one below what `r_ohm` allows.
fn exponential_corrected_h(l_est_h: f32, r_ohm: f32, half_s: f32) -> Option<f32> {
    if !(l_est_h.is_finite() && l_est_h > 0.0) {
        return None;
    }
    if r_ohm.is_nan() || r_ohm <= 0.0 {
        return Some(l_est_h);
    }
    let y = r_ohm * half_s / (2.0 * l_est_h);
    if !(y > 0.0 && y < 1.0) {
        return None;
    }
    let l = r_ohm * half_s / (2.0 * libm::atanhf(y));
    (l.is_finite() && l > 0.0).then_some(l)
}

/// The inductance measurement state machine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Inductance {
    cfg: InductanceConfig,
    state: State,
    v_bias: f32,
    /// Aimed amplitude \[V\] and half-wave length \[periods\] of the wave.
    amp_v: f32,
    half_periods: u32,
    /// The target changed: restart the fit at the next half-wave.
    changed: bool,
    wave: Wave,
    /// Wave voltage commanded 1, 2, 3 periods ago \[V\].
    past_u_v: [f32; MAX_DELAY_PERIODS],
    /// Least-squares sums per loop delay: `sum(u delta_i)` [V A] and
    /// `sum(u^2)` [V^2].
    sum_u_di: [f32; MAX_DELAY_PERIODS],
    sum_u2: [f32; MAX_DELAY_PERIODS],
    /// Periods still ignored, and periods fitted, since the last change.
    skip_left: u32,
    fitted: u32,
    /// Half-waves started in the measurement (for the sweep).
    sweep_count: u32,
    prev_i: Dq,
    /// The d current without the injected ripple \[A\], and the running sum
    /// over the wave cycle (two half-waves) that gives it.
    i_d_dc_a: f32,
    cycle_sum_a: f32,
    cycle_n: u32,
    bias_periods: u32,
    i_d_filt: f32,
    /// The q current through the same low-pass (the swing seen without a
    /// sensor: [`InductanceConfig::swing_from_current`]).
    i_q_filt: f32,
    motion: Motion,
    ld_h: f32,
    ld_restart: (f32, u32),
    finished: Option<CalStep<InductanceResult>>,
}

impl Inductance {
    /// New measurement (starts by ramping the bias current).
    pub fn new(config: InductanceConfig) -> Self {
        Self {
            cfg: config,
            state: State::Bias(0),
            v_bias: 0.0,
            amp_v: 0.0,
            half_periods: 1,
            changed: false,
            wave: Wave::IDLE,
            past_u_v: [0.0; MAX_DELAY_PERIODS],
            sum_u_di: [0.0; MAX_DELAY_PERIODS],
            sum_u2: [0.0; MAX_DELAY_PERIODS],
            skip_left: 0,
            fitted: 0,
            sweep_count: 0,
            prev_i: Dq::ZERO,
            i_d_dc_a: 0.0,
            cycle_sum_a: 0.0,
            cycle_n: 0,
            bias_periods: 0,
            i_d_filt: 0.0,
            i_q_filt: 0.0,
            motion: Motion::NEW,
            ld_h: 0.0,
            ld_restart: (0.0, 1),
            finished: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &InductanceConfig {
        &self.cfg
    }

    /// One PWM period. See the module docs.
    pub fn step(&mut self, inp: &CalInput) -> CalStep<InductanceResult> {
        if let Some(f) = self.finished {
            return f;
        }
        let r = self.run(inp);
        latch(&mut self.finished, r)
    }

    /// Aim the wave at `amp_v` over half-waves of `half_periods` (from the
    /// next half-wave on); the fit restarts after the transition.
    fn set_wave(&mut self, amp_v: f32, half_periods: u32) {
        self.amp_v = amp_v;
        self.half_periods = half_periods.max(1);
        self.changed = true;
    }

    /// Restart the fit, ignoring `skip` periods first.
    fn restart_fit(&mut self, skip: u32) {
        self.sum_u_di = [0.0; MAX_DELAY_PERIODS];
        self.sum_u2 = [0.0; MAX_DELAY_PERIODS];
        self.skip_left = skip;
        self.fitted = 0;
    }

    /// The fitted current change per volt and period `|g|` [A/(V period)]
    /// of the best-matching loop delay (0 when nothing was fitted).
    fn slope(&self) -> f32 {
        let mut best = 0.0f32;
        for (s, q) in self.sum_u_di.iter().zip(self.sum_u2.iter()) {
            if *q > 0.0 {
                let g = (*s / *q).abs();
                if g.is_finite() && g > best {
                    best = g;
                }
            }
        }
        best
    }

    /// Longest half-wave for the fitted slope `g`: `max_half_wave_periods`,
    /// and `N Ts <= fraction * L / R` with `L = Ts / g`, `R` the configured
    /// resistance or else `V_bias / i`.
    fn max_half_periods(&self, g: f32) -> u32 {
        let c = &self.cfg;
        let mut n = c.max_half_wave_periods.max(1);
        let r_ohm = if c.r_ohm > 0.0 {
            c.r_ohm
        } else if self.i_d_dc_a > 0.05 * c.bias_current_a && self.v_bias > 0.0 {
            self.v_bias / self.i_d_dc_a
        } else {
            0.0
        };
        if r_ohm > 0.0 {
            let g_r = g * r_ohm;
            let lim = c.max_half_wave_tau_fraction / g_r;
            if g_r > 0.0 && lim.is_finite() && lim < n as f32 {
                // Saturating cast; at least one period.
                n = (lim as u32).max(1);
            }
        }
        n
    }

    fn run(&mut self, inp: &CalInput) -> Result<CalStep<InductanceResult>, CalError> {
        if !self.cfg.is_valid() {
            return Err(CalError::InvalidConfig);
        }
        check_input(inp, self.cfg.max_current_a)?;
        let i = current_dq(inp.i_abc_a, ElectricalAngle::ZERO);
        let v_lim = voltage_limit_v(self.cfg.max_voltage_v, inp.v_bus_v);
        let moving = self.track_bias(i, inp, v_lim);
        self.fit(i);
        let headroom = v_lim - self.v_bias;
        if let Some(result) = self.advance(moving, headroom)? {
            return Ok(CalStep::Done(result));
        }
        let u = self.wave_volts(headroom);
        Ok(CalStep::Apply {
            v_dq: self.applied_v(u),
            theta_e: ElectricalAngle::ZERO,
        })
    }

    /// The d current without the injected ripple and the bias voltage that
    /// holds it at the target; true while the rotor still moves.
    fn track_bias(&mut self, i: Dq, inp: &CalInput, v_lim: f32) -> bool {
        let c = self.cfg;
        // The d current without the injected ripple: the mean over the last
        // whole wave cycle while the wave is on d (updated as each cycle
        // ends), the sample otherwise.
        let wave_on_d = matches!(
            self.state,
            State::Probe { axis: Axis::D, .. } | State::Measure(Axis::D) | State::Gap(_)
        ) && !self.wave.idle();
        if wave_on_d {
            self.cycle_sum_a += i.d;
            self.cycle_n = self.cycle_n.saturating_add(1);
        } else {
            self.i_d_dc_a = i.d;
            self.cycle_sum_a = 0.0;
            self.cycle_n = 0;
        }
        let i_d_dc = self.i_d_dc_a;
        // Low-passed like the d current: one noisy sample is no swing.
        self.i_q_filt += (i.q - self.i_q_filt) * (1.0 / 16.0);
        let swinging = c.swing_from_current
            && self.wave.idle()
            && self.i_q_filt.abs() > SWING_IQ_SHARE * c.bias_current_a;
        let moving = self.motion.update(inp.angle) || swinging;
        let v_new = approach_v(
            self.v_bias,
            i_d_dc,
            c.bias_current_a,
            c.loop_bandwidth_rad_s,
            c.ramp_v_per_s,
            c.ts_s,
            v_lim,
        );
        // Hold (never raise) the bias while the rotor swings to 0 degrees.
        if !(moving && v_new > self.v_bias) {
            self.v_bias = v_new;
        }
        // Low-pass (16 periods) for the settling decision only.
        self.i_d_filt += (i_d_dc - self.i_d_filt) * (1.0 / 16.0);
        moving
    }

    /// The fit: this period's current change against the wave voltage
    /// commanded 1, 2, 3 periods ago.
    fn fit(&mut self, i: Dq) {
        let delta = Dq::new(i.d - self.prev_i.d, i.q - self.prev_i.q);
        self.prev_i = i;
        if let State::Probe { axis, .. } | State::Measure(axis) = self.state {
            if self.skip_left > 0 {
                self.skip_left -= 1;
            } else {
                let di = match axis {
                    Axis::D => delta.d,
                    Axis::Q => delta.q,
                };
                let sums = self.sum_u_di.iter_mut().zip(self.sum_u2.iter_mut());
                for ((s_u_di, s_u2), u) in sums.zip(self.past_u_v.iter()) {
                    *s_u_di += u * di;
                    *s_u2 += u * u;
                }
                self.fitted = self.fitted.saturating_add(1);
            }
        }
    }

    /// The sequence: bias, probes, measurement, gap, per axis; the result
    /// once the q measurement ends.
    fn advance(
        &mut self,
        moving: bool,
        headroom: f32,
    ) -> Result<Option<InductanceResult>, CalError> {
        match self.state {
            State::Bias(n) => self.on_bias(n, moving)?,
            State::Probe { axis, n } => self.on_probe(axis, n, headroom)?,
            State::Measure(axis) => return self.on_measure(axis),
            State::Gap(n) => self.on_gap(n),
        }
        Ok(None)
    }

    /// Settle the d current on its target, then start the d probes.
    fn on_bias(&mut self, n: u32, moving: bool) -> Result<(), CalError> {
        let c = self.cfg;
        let target = c.bias_current_a;
        self.bias_periods = self.bias_periods.saturating_add(1);
        if self.bias_periods > periods(c.bias_timeout_s, c.ts_s) {
            return Err(if self.i_d_filt < 0.25 * target {
                CalError::NoCurrentResponse
            } else {
                CalError::Timeout
            });
        }
        let in_band = !moving && (target - self.i_d_filt).abs() < 0.03 * target;
        self.state = if !in_band {
            State::Bias(0)
        } else if n + 1 >= periods(c.settle_s, c.ts_s) {
            self.set_wave(c.start_voltage_v, 1);
            State::Probe {
                axis: Axis::D,
                n: 0,
            }
        } else {
            State::Bias(n + 1)
        };
        Ok(())
    }

    /// At a half-wave boundary after a whole probe window: measure with
    /// this wave when its ripple is right, else resize it.
    fn on_probe(&mut self, axis: Axis, n: u8, headroom: f32) -> Result<(), CalError> {
        let c = self.cfg;
        let window = c.probe_periods.max(self.half_periods.saturating_mul(4));
        if self.wave.left != 0 || self.changed || self.fitted < window {
            return Ok(());
        }
        let g = self.slope();
        let ripple = g * self.amp_v * self.half_periods as f32;
        let want = c.ripple_fraction * c.bias_current_a;
        let n_max = self.max_half_periods(g);
        if ripple > 0.5 * want && ripple < 2.0 * want {
            self.start_measure(axis);
        } else if self.amp_v >= 0.999 * headroom && self.half_periods >= n_max && ripple < want {
            if ripple > 0.1 * want {
                self.start_measure(axis);
            } else {
                return Err(CalError::NoCurrentResponse);
            }
        } else if n >= c.max_probes {
            return Err(CalError::Timeout);
        } else {
            self.resize_wave(ripple, want, headroom, n_max)?;
            self.state = State::Probe { axis, n: n + 1 };
        }
        Ok(())
    }

    /// The next probe's wave: the volt-periods that give the wanted ripple,
    /// on the shortest half-wave that carries them within the headroom.
    fn resize_wave(
        &mut self,
        ripple: f32,
        want: f32,
        headroom: f32,
        n_max: u32,
    ) -> Result<(), CalError> {
        let k = if ripple > 0.0 { want / ripple } else { 8.0 };
        let k = crate::clamp(k, 0.125, 8.0);
        let v_periods = self.amp_v * self.half_periods as f32 * k;
        let len = libm::ceilf(v_periods / headroom);
        let len = if len.is_finite() && len >= 1.0 {
            (len as u32).min(n_max)
        } else {
            1
        };
        let new_amp = crate::clamp(v_periods / len as f32, 0.0, headroom);
        let usable = new_amp > 0.0;
        if !usable {
            return Err(CalError::VoltageLimitReached);
        }
        self.set_wave(new_amp, len);
        Ok(())
    }

    /// After whole sweeps at a boundary: the axis's inductance; after d the
    /// gap, after q the result.
    fn on_measure(&mut self, axis: Axis) -> Result<Option<InductanceResult>, CalError> {
        let c = self.cfg;
        let sweep = c.sweep_half_waves.saturating_mul(2);
        let whole_sweeps = self.sweep_count.is_multiple_of(sweep);
        let done = self.fitted >= c.measure_periods
            && (whole_sweeps || self.fitted >= c.measure_periods.saturating_mul(2));
        if self.wave.left != 0 || !done {
            return Ok(None);
        }
        let l = exponential_corrected_h(
            c.ts_s / self.slope(),
            c.r_ohm,
            self.half_periods as f32 * c.ts_s,
        )
        .ok_or(CalError::ImplausibleResult)?;
        match axis {
            Axis::D => {
                self.ld_h = l;
                // Start the q probes with the d wave.
                self.ld_restart = (self.amp_v, self.half_periods);
                self.set_wave(0.0, self.half_periods);
                self.state = State::Gap(0);
                Ok(None)
            }
            Axis::Q => Ok(Some(InductanceResult {
                ld_h: self.ld_h,
                lq_h: l,
            })),
        }
    }

    /// Back to the centre, a pause, then the q probes.
    fn on_gap(&mut self, n: u32) {
        if !self.wave.idle() {
            // Still coming back to the centre.
        } else if n >= self.cfg.skip_periods {
            let (amp, len) = self.ld_restart;
            self.set_wave(amp, len);
            self.state = State::Probe {
                axis: Axis::Q,
                n: 0,
            };
        } else {
            self.state = State::Gap(n + 1);
        }
    }

    /// The wave: a new half-wave at a boundary (swept in the measurement),
    /// then this period's share of it \[V\], remembered for the fit.
    fn wave_volts(&mut self, headroom: f32) -> f32 {
        let c = self.cfg;
        if self.wave.left == 0 {
            let amp = match self.state {
                State::Measure(_) => {
                    let m = c.sweep_half_waves;
                    let j = self.sweep_count % m.saturating_mul(2);
                    let down = if j <= m { j } else { m.saturating_mul(2) - j };
                    self.sweep_count = self.sweep_count.wrapping_add(1);
                    self.amp_v * (1.0 - c.sweep_depth * down as f32 / m as f32)
                }
                _ => self.amp_v,
            };
            let len = self.wave.start(amp, self.half_periods);
            if self.changed {
                self.changed = false;
                self.restart_fit(c.skip_periods.saturating_add(len));
            }
            // Every second half-wave ends a whole cycle of the d current.
            if !self.wave.count.is_multiple_of(2) && self.cycle_n > 0 {
                self.i_d_dc_a = self.cycle_sum_a / self.cycle_n as f32;
                self.cycle_sum_a = 0.0;
                self.cycle_n = 0;
            }
        }
        let u = if self.wave.left > 0 {
            self.wave.left -= 1;
            let h = if headroom > 0.0 { headroom } else { 0.0 };
            self.wave.sign * crate::clamp(self.wave.volts, 0.0, h)
        } else {
            0.0
        };
        self.past_u_v.rotate_right(1);
        self.past_u_v[0] = u;
        u
    }

    /// The voltage applied this period: the bias on d, the wave on its axis.
    fn applied_v(&self, u: f32) -> Dq {
        match self.state {
            State::Probe { axis: Axis::Q, .. } | State::Measure(Axis::Q) => Dq::new(self.v_bias, u),
            State::Probe { axis: Axis::D, .. } | State::Measure(Axis::D) | State::Gap(_) => {
                Dq::new(self.v_bias + u, 0.0)
            }
            State::Bias(_) => Dq::new(self.v_bias, 0.0),
        }
    }

    /// From the probes to the measurement with the same wave (the sweep
    /// starts at its top).
    fn start_measure(&mut self, axis: Axis) {
        self.state = State::Measure(axis);
        self.sweep_count = 0;
        self.restart_fit(0);
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::angle::MechanicalAngle;
    use crate::frames::Abc;
    use std::println;

    /// A motor on the test bench (values of `tests/motors/*.toml`).
    #[derive(Clone, Copy, Debug)]
    struct Motor {
        name: &'static str,
        p: u8,
        r_ohm: f64,
        ld_h: f64,
        lq_h: f64,
        psi_wb: f64,
        j_kg_m2: f64,
        coulomb_nm: f64,
        pwm_hz: f64,
        v_bus_v: f64,
        max_current_a: f64,
        cpr: u32,
    }

    /// The six motor files, as the bench's mission sets them up.
    const MOTORS: [Motor; 6] = [
        Motor {
            name: "cute-q85sx-hub",
            p: 8,
            r_ohm: 0.1535,
            ld_h: 150e-6,
            lq_h: 150e-6,
            psi_wb: 0.008992,
            j_kg_m2: 1.5e-4,
            coulomb_nm: 0.065,
            pwm_hz: 16_000.0,
            v_bus_v: 36.0,
            max_current_a: 20.0,
            cpr: 48,
        },
        Motor {
            name: "dji-m2006",
            p: 7,
            r_ohm: 0.461,
            ld_h: 64.22e-6,
            lq_h: 64.22e-6,
            psi_wb: 6.64e-4,
            j_kg_m2: 3e-6,
            coulomb_nm: 0.0005,
            pwm_hz: 20_000.0,
            v_bus_v: 24.0,
            max_current_a: 10.0,
            cpr: 8192,
        },
        Motor {
            name: "gl80-kv30",
            p: 21,
            r_ohm: 1.13,
            ld_h: 0.57e-3,
            lq_h: 0.82e-3,
            psi_wb: 8.75e-3,
            j_kg_m2: 4e-4,
            coulomb_nm: 0.01,
            pwm_hz: 20_000.0,
            v_bus_v: 24.0,
            max_current_a: 8.0,
            cpr: 16_384,
        },
        Motor {
            name: "hkc-cheetah",
            p: 21,
            r_ohm: 0.105,
            ld_h: 30e-6,
            lq_h: 30e-6,
            psi_wb: 0.0024,
            j_kg_m2: 6e-5,
            coulomb_nm: 0.005,
            pwm_hz: 40_000.0,
            v_bus_v: 24.0,
            max_current_a: 40.0,
            cpr: 16_384,
        },
        Motor {
            name: "ipm-2k2-540v",
            p: 3,
            r_ohm: 3.6,
            ld_h: 0.036,
            lq_h: 0.051,
            psi_wb: 0.545,
            j_kg_m2: 0.015,
            coulomb_nm: 0.1,
            pwm_hz: 15_000.0,
            v_bus_v: 540.0,
            max_current_a: 18.2,
            cpr: 10_000,
        },
        Motor {
            name: "m153-source",
            p: 4,
            r_ohm: 0.05,
            ld_h: 0.5e-3,
            lq_h: 0.5e-3,
            psi_wb: 0.124,
            j_kg_m2: 5e-3,
            coulomb_nm: 0.3,
            pwm_hz: 15_000.0,
            v_bus_v: 26.0,
            max_current_a: 60.0,
            cpr: 4096,
        },
    ];

    /// Sensors and timing of the test bench.
    #[derive(Clone, Copy, Debug)]
    struct Bench {
        /// Current ADC resolution \[bits\] over `+-2 max_current_a`.
        adc_bits: u8,
        /// Current ADC noise, RMS \[LSB\].
        noise_lsb: f64,
        /// Periods from the command to the first current difference it
        /// causes: 2 (the duties apply in the next period) or 1.
        delay_periods: u8,
    }

    const BENCH: Bench = Bench {
        adc_bits: 12,
        noise_lsb: 0.0,
        delay_periods: 2,
    };

    /// A PMSM in its rotor frame (RK4, 20 sub-steps per period), a rotor
    /// with inertia and Coulomb friction (stiction), rounding current ADCs,
    /// a counting angle sensor and the computation delay.
    struct TestPlant {
        m: Motor,
        b: Bench,
        id_a: f64,
        iq_a: f64,
        theta_e_rad: f64,
        omega_m_rad_s: f64,
        /// Voltage applied in the next period (alpha, beta) \[V\].
        pending_v: (f64, f64),
        rng: u64,
    }

    impl TestPlant {
        fn new(m: Motor, b: Bench) -> Self {
            Self {
                m,
                b,
                id_a: 0.0,
                iq_a: 0.0,
                theta_e_rad: 0.7,
                omega_m_rad_s: 0.0,
                pending_v: (0.0, 0.0),
                rng: 0x2545_f491_4f6c_dd1d,
            }
        }

        /// Roughly Gaussian, unit standard deviation.
        fn gauss(&mut self) -> f64 {
            let mut s = 0.0;
            for _ in 0..12 {
                self.rng = self
                    .rng
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                s += (self.rng >> 11) as f64 / (1u64 << 53) as f64;
            }
            s - 6.0
        }

        fn input(&mut self) -> CalInput {
            let (s, c) = libm::sincos(self.theta_e_rad);
            let alpha = self.id_a * c - self.iq_a * s;
            let beta = self.id_a * s + self.iq_a * c;
            let k = 0.5 * libm::sqrt(3.0);
            let lsb = 4.0 * self.m.max_current_a / libm::exp2(f64::from(self.b.adc_bits));
            let mut adc = |x: f64| {
                let n = self.b.noise_lsb * self.gauss();
                (libm::round(x / lsb + n) * lsb) as f32
            };
            let abc = Abc::new(
                adc(alpha),
                adc(-0.5 * alpha + k * beta),
                adc(-0.5 * alpha - k * beta),
            );
            let turns = self.theta_e_rad / f64::from(self.m.p) / core::f64::consts::TAU;
            let counts = libm::floor(turns * f64::from(self.m.cpr)) as i64;
            let counts = counts.rem_euclid(i64::from(self.m.cpr)) as u64;
            let bits = (counts << 32) / u64::from(self.m.cpr);
            CalInput::open_loop(
                abc,
                MechanicalAngle::from_bits(bits as u32),
                self.m.v_bus_v as f32,
            )
        }

        /// One period after the routine answered `step`.
        fn advance<T>(&mut self, step: &CalStep<T>) {
            let next = match step.voltage() {
                Some((v, th)) => {
                    let (s, c) = libm::sincos(f64::from(th.to_radians()));
                    let (d, q) = (f64::from(v.d), f64::from(v.q));
                    (d * c - q * s, d * s + q * c)
                }
                None => (0.0, 0.0),
            };
            let v = if self.b.delay_periods == 1 {
                next
            } else {
                core::mem::replace(&mut self.pending_v, next)
            };
            const SUB: u32 = 20;
            let m = self.m;
            let dt = 1.0 / m.pwm_hz / f64::from(SUB);
            let p = f64::from(m.p);
            for _ in 0..SUB {
                // Electrical: RK4 at this sub-step's angle and speed.
                let (s, c) = libm::sincos(self.theta_e_rad);
                let vd = v.0 * c + v.1 * s;
                let vq = -v.0 * s + v.1 * c;
                let we = p * self.omega_m_rad_s;
                let f = |id: f64, iq: f64| {
                    (
                        (vd - m.r_ohm * id + we * m.lq_h * iq) / m.ld_h,
                        (vq - m.r_ohm * iq - we * (m.ld_h * id + m.psi_wb)) / m.lq_h,
                    )
                };
                let (id, iq) = (self.id_a, self.iq_a);
                let k1 = f(id, iq);
                let k2 = f(id + 0.5 * dt * k1.0, iq + 0.5 * dt * k1.1);
                let k3 = f(id + 0.5 * dt * k2.0, iq + 0.5 * dt * k2.1);
                let k4 = f(id + dt * k3.0, iq + dt * k3.1);
                self.id_a += dt / 6.0 * (k1.0 + 2.0 * k2.0 + 2.0 * k3.0 + k4.0);
                self.iq_a += dt / 6.0 * (k1.1 + 2.0 * k2.1 + 2.0 * k3.1 + k4.1);
                // Mechanical: Euler, with stiction.
                let te = 1.5 * p * (m.psi_wb + (m.ld_h - m.lq_h) * id) * iq;
                if self.omega_m_rad_s == 0.0 && te.abs() <= m.coulomb_nm {
                    // Stuck.
                } else {
                    let dir = if self.omega_m_rad_s != 0.0 {
                        self.omega_m_rad_s.signum()
                    } else {
                        te.signum()
                    };
                    let w = self.omega_m_rad_s + dt * (te - dir * m.coulomb_nm) / m.j_kg_m2;
                    self.omega_m_rad_s = if w * dir < 0.0 { 0.0 } else { w };
                }
                self.theta_e_rad += dt * p * self.omega_m_rad_s;
            }
        }
    }

    /// The bench's identification settings: bias a quarter of the maximum
    /// current, voltage limit a quarter of the bus, the resistance known
    /// (as the sequencer passes it on).
    fn bench_config(m: &Motor) -> InductanceConfig {
        let mut c = InductanceConfig::new(
            m.pwm_hz as f32,
            (0.25 * m.max_current_a) as f32,
            (0.25 * m.v_bus_v) as f32,
        );
        c.r_ohm = m.r_ohm as f32;
        c
    }

    /// Run the measurement: the result, the routine at the end and the
    /// periods it took.
    fn measure(m: Motor, b: Bench, cfg: InductanceConfig) -> (CalStep<InductanceResult>, u32) {
        let mut plant = TestPlant::new(m, b);
        let mut l = Inductance::new(cfg);
        for n in 0..1_000_000u32 {
            let s = l.step(&plant.input());
            if s.is_finished() {
                return (s, n);
            }
            plant.advance(&s);
        }
        (CalStep::Failed(CalError::Timeout), 1_000_000)
    }

    /// Relative errors of Ld and Lq [%].
    fn errors_pct(m: &Motor, s: CalStep<InductanceResult>) -> (f64, f64) {
        let CalStep::Done(r) = s else {
            panic!("{}: {s:?}", m.name)
        };
        (
            100.0 * (f64::from(r.ld_h) / m.ld_h - 1.0),
            100.0 * (f64::from(r.lq_h) / m.lq_h - 1.0),
        )
    }

    #[test]
    fn every_motor_file_with_a_noiseless_12_bit_adc() {
        // Without noise a strictly periodic one-period square wave read the
        // IPM's Lq 5.5 % low (its ripple was 8.7 ADC steps).
        for delay_periods in [2, 1] {
            for m in MOTORS {
                let b = Bench {
                    delay_periods,
                    ..BENCH
                };
                let (s, n) = measure(m, b, bench_config(&m));
                let (ed, eq) = errors_pct(&m, s);
                println!(
                    "{} (delay {delay_periods}): Ld {ed:+.3} %, Lq {eq:+.3} %, {:.2} s",
                    m.name,
                    f64::from(n) / m.pwm_hz
                );
                assert!(
                    ed.abs() < 0.5 && eq.abs() < 0.5,
                    "{}: {ed} %, {eq} %",
                    m.name
                );
            }
        }
    }

    #[test]
    fn every_motor_file_with_a_noisy_adc() {
        for m in MOTORS {
            let b = Bench {
                noise_lsb: 1.5,
                ..BENCH
            };
            let (s, _) = measure(m, b, bench_config(&m));
            let (ed, eq) = errors_pct(&m, s);
            println!("{} (noise 1.5 LSB): Ld {ed:+.3} %, Lq {eq:+.3} %", m.name);
            assert!(
                ed.abs() < 0.5 && eq.abs() < 0.5,
                "{}: {ed} %, {eq} %",
                m.name
            );
        }
    }

    #[test]
    fn long_half_waves_only_where_the_voltage_needs_them() {
        // The IPM on its 135 V limit needs several periods per half-wave to
        // reach the ripple target, within a fifth of its L / R; the small
        // DJI motor keeps the one-period square wave.
        for (k, name, lo, hi) in [(4, "ipm", 4, 30), (1, "dji", 1, 1)] {
            let m = MOTORS[k];
            let cfg = bench_config(&m);
            let mut plant = TestPlant::new(m, BENCH);
            let mut l = Inductance::new(cfg);
            let mut longest = 0;
            for _ in 0..200_000 {
                let s = l.step(&plant.input());
                if let State::Measure(_) = l.state {
                    longest = longest.max(l.half_periods);
                }
                if s.is_finished() {
                    assert!(matches!(s, CalStep::Done(_)), "{name}: {s:?}");
                    break;
                }
                plant.advance(&s);
            }
            assert!((lo..=hi).contains(&longest), "{name}: {longest}");
            let tau_periods = m.lq_h.min(m.ld_h) / m.r_ohm * m.pwm_hz;
            assert!(f64::from(longest) <= 0.2 * tau_periods || longest == 1);
        }
    }

    #[test]
    fn without_the_resistance_only_the_exponential_bias_is_left() {
        // a = R Ts / L = 0.36 at N = 1: (a / 2) / tanh(a / 2) = +1.07 %.
        let m = MOTORS[1];
        let mut cfg = bench_config(&m);
        cfg.r_ohm = 0.0;
        let (s, _) = measure(m, BENCH, cfg);
        let (ed, eq) = errors_pct(&m, s);
        println!("{} without R: Ld {ed:+.3} %, Lq {eq:+.3} %", m.name);
        assert!((ed - 1.07).abs() < 0.4 && (eq - 1.07).abs() < 0.4);
    }

    #[test]
    fn exponential_correction() {
        let (r, half, l) = (0.5f32, 1e-4f32, 1e-4f32);
        let x = 0.5 * r * half / l;
        let l_est = l * x / libm::tanhf(x);
        let got = exponential_corrected_h(l_est, r, half).unwrap();
        assert!((got / l - 1.0).abs() < 1e-5, "{got}");
        assert_eq!(exponential_corrected_h(l_est, 0.0, half), Some(l_est));
        // Below what the resistance allows, non-finite or non-positive.
        assert_eq!(exponential_corrected_h(0.4 * r * half, r, half), None);
        assert_eq!(exponential_corrected_h(f32::INFINITY, r, half), None);
        assert_eq!(exponential_corrected_h(-1.0, 0.0, half), None);
    }

    #[test]
    fn wave_changes_keep_the_triangle_centred() {
        // Volt-periods: start at 2 x 1, grow to 6 x 3, shrink to 1 x 1, stop.
        let mut w = Wave::IDLE;
        let mut corner = 0.0f32;
        let mut corners = std::vec::Vec::new();
        for (amp, len, halves) in [(2.0, 1, 4), (6.0, 3, 4), (1.0, 1, 4), (0.0, 1, 2)] {
            for _ in 0..halves {
                let n = w.start(amp, len);
                for _ in 0..n {
                    corner += w.sign * w.volts;
                }
                w.left = 0;
                corners.push(corner);
            }
        }
        // Corners at +-(V N) / 2 of each setting, back to 0 when stopped.
        let want = [
            1.0, -1.0, 1.0, -1.0, 9.0, -9.0, 9.0, -9.0, 0.5, -0.5, 0.5, -0.5, 0.0,
        ];
        for (c, w) in corners.iter().zip(want.iter()) {
            assert!((c - w).abs() < 1e-5, "{corners:?}");
        }
        assert!(w.idle());
        assert_eq!(w.start(0.0, 1), 0);
    }
}
