//! d- and q-axis inductance from a square-wave voltage on top of a DC
//! holding current.
//!
//! The rotor is held at `theta_e = 0` by a DC d current `bias_current_a`
//! (voltage found by the same integrator as in [`super::resistance`]). Then
//! a square wave `+-V`, its sign flipping every PWM period, is added to the
//! d voltage, later to the q voltage. Each period the current changes by
//!
//! ```text
//! delta_i = (Ts / L) * (+-V + V_bias - R i - e)  ~=  +-V Ts / L
//! ```
//!
//! because the DC terms balance (the bias integrator keeps `V_bias = R i + e`
//! on average, `e` being the constant dead-time error). So
//!
//! ```text
//! L = V Ts / i_pp,     i_pp = | mean( s_k * (i_k - i_(k-1)) ) |
//! ```
//!
//! where `s_k = +-1` is the sign commanded in period `k` (synchronous
//! detection: equal to the mean `|delta i|` for a clean triangle, but sensor
//! noise averages out instead of adding a bias, and the result does not
//! depend on whether the loop delay is one or two periods).
//!
//! Assumptions:
//! - `R Ts / L << 1`: within one period the current is a straight line. For
//!   the exact exponential response the estimate is `L (1 + a^2 / 12)` with
//!   `a = R Ts / L` (0.1 % at `a = 0.1`), so even this is mild.
//! - No phase current crosses zero: the ripple target (`ripple_fraction` of
//!   the bias, peak to peak) keeps the dead-time error constant. With the
//!   default 0.3 the q ripple peak is 0.15 of the bias, far below the
//!   `bias / sqrt(3)` at which phases B and C would cross zero.
//! - The rotor stays aligned (Ld along d); the q wave averages to zero
//!   torque (the first and last half-steps centre the triangle).
//! - Inductance at the bias current (saturation is not separated).
//!
//! The amplitude `V` is found by probing: start at `start_voltage_v`, measure
//! the ripple over `probe_periods`, rescale `V` by `target / ripple` (at most
//! 8x per probe) until the ripple lies within a factor of 2 of the target,
//! then measure over `measure_periods`. Amplitude changes use a half step
//! (`(V_old + V_new) / 2`) so that the triangle stays centred.
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
    CalStep, Mean, Motion,
};
use crate::angle::ElectricalAngle;
use crate::frames::Dq;

/// Configuration of the inductance measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InductanceConfig {
    /// PWM (step) period [s].
    pub ts_s: f32,
    /// DC d current holding the rotor [A].
    pub bias_current_a: f32,
    /// Target ripple (peak to peak) as a fraction of the bias (e.g. 0.3).
    pub ripple_fraction: f32,
    /// Largest open-loop voltage [V] (also limited by the bus).
    pub max_voltage_v: f32,
    /// Current vector that aborts the routine [A].
    pub max_current_a: f32,
    /// Approach rate of the bias current [rad/s].
    pub loop_bandwidth_rad_s: f32,
    /// Fastest change of the bias voltage [V/s].
    pub ramp_v_per_s: f32,
    /// Time the bias must stay within 3 % before injecting [s].
    pub settle_s: f32,
    /// Time limit for the bias to settle [s].
    pub bias_timeout_s: f32,
    /// First square-wave amplitude [V].
    pub start_voltage_v: f32,
    /// Periods ignored after every amplitude change.
    pub skip_periods: u32,
    /// Periods per probe.
    pub probe_periods: u32,
    /// Periods of the final measurement per axis.
    pub measure_periods: u32,
    /// Probes per axis before giving up ([`CalError::Timeout`]).
    pub max_probes: u8,
}

impl InductanceConfig {
    /// Defaults for a PWM frequency, a bias current [A] and a voltage limit
    /// [V]: 30 % ripple, 50 ms settle, start at 2 % of the voltage limit,
    /// 32 periods skipped, 64-period probes, 4000-period measurement.
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
    }
}

/// Result of the inductance measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InductanceResult {
    /// d-axis inductance [H].
    pub ld_h: f32,
    /// q-axis inductance [H].
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

/// The inductance measurement state machine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Inductance {
    cfg: InductanceConfig,
    state: State,
    v_bias: f32,
    amp: f32,
    last_amp: f32,
    sign: f32,
    since_change: u32,
    prev_i: Dq,
    demod: Mean,
    bias_periods: u32,
    i_d_filt: f32,
    motion: Motion,
    ld_h: f32,
    ld_restart: f32,
    finished: Option<CalStep<InductanceResult>>,
}

impl Inductance {
    /// New measurement (starts by ramping the bias current).
    pub fn new(config: InductanceConfig) -> Self {
        Self {
            cfg: config,
            state: State::Bias(0),
            v_bias: 0.0,
            amp: 0.0,
            last_amp: 0.0,
            sign: 1.0,
            since_change: 0,
            prev_i: Dq::ZERO,
            demod: Mean::ZERO,
            bias_periods: 0,
            i_d_filt: 0.0,
            motion: Motion::NEW,
            ld_h: 0.0,
            ld_restart: 0.0,
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

    fn set_amp(&mut self, amp: f32) {
        self.amp = amp;
        self.since_change = 0;
        self.demod = Mean::ZERO;
    }

    fn run(&mut self, inp: &CalInput) -> Result<CalStep<InductanceResult>, CalError> {
        if !self.cfg.is_valid() {
            return Err(CalError::InvalidConfig);
        }
        check_input(inp, self.cfg.max_current_a)?;
        let c = self.cfg;
        let i = current_dq(inp.i_abc_a, ElectricalAngle::ZERO);
        let v_lim = voltage_limit_v(c.max_voltage_v, inp.v_bus_v);
        let target = c.bias_current_a;
        // The d current without the injected ripple (two-sample mean).
        let i_d_dc = if matches!(
            self.state,
            State::Probe { axis: Axis::D, .. } | State::Measure(Axis::D)
        ) {
            0.5 * (i.d + self.prev_i.d)
        } else {
            i.d
        };
        let moving = self.motion.update(inp.angle);
        let v_new = approach_v(
            self.v_bias,
            i_d_dc,
            target,
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
        let delta = Dq::new(i.d - self.prev_i.d, i.q - self.prev_i.q);
        self.prev_i = i;
        self.since_change = self.since_change.saturating_add(1);

        match self.state {
            State::Bias(n) => {
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
                    self.set_amp(c.start_voltage_v);
                    State::Probe {
                        axis: Axis::D,
                        n: 0,
                    }
                } else {
                    State::Bias(n + 1)
                };
            }
            State::Probe { axis, n } => {
                self.accumulate(axis, delta);
                if self.since_change > c.skip_periods + c.probe_periods {
                    let ripple = self.demod.mean().abs();
                    let want = c.ripple_fraction * target;
                    let headroom = v_lim - self.v_bias;
                    if ripple > 0.5 * want && ripple < 2.0 * want {
                        self.state = State::Measure(axis);
                        self.since_change = 0;
                        self.demod = Mean::ZERO;
                    } else if self.amp >= 0.999 * headroom && ripple < want {
                        if ripple > 0.1 * want {
                            self.state = State::Measure(axis);
                            self.since_change = 0;
                            self.demod = Mean::ZERO;
                        } else {
                            return Err(CalError::NoCurrentResponse);
                        }
                    } else if n >= c.max_probes {
                        return Err(CalError::Timeout);
                    } else {
                        let k = if ripple > 0.0 { want / ripple } else { 8.0 };
                        let k = crate::clamp(k, 0.125, 8.0);
                        let new_amp = crate::clamp(self.amp * k, 0.0, headroom);
                        let usable = new_amp > 0.0;
                        if !usable {
                            return Err(CalError::VoltageLimitReached);
                        }
                        self.set_amp(new_amp);
                        self.state = State::Probe { axis, n: n + 1 };
                    }
                }
            }
            State::Measure(axis) => {
                self.accumulate(axis, delta);
                if self.since_change > c.skip_periods + c.measure_periods {
                    let ripple = self.demod.mean().abs();
                    let l = self.amp * c.ts_s / ripple;
                    if !(l.is_finite() && l > 0.0) {
                        return Err(CalError::ImplausibleResult);
                    }
                    match axis {
                        Axis::D => {
                            self.ld_h = l;
                            // Start the q probes with the d amplitude.
                            self.ld_restart = self.amp;
                            self.set_amp(0.0);
                            self.state = State::Gap(0);
                        }
                        Axis::Q => {
                            return Ok(CalStep::Done(InductanceResult {
                                ld_h: self.ld_h,
                                lq_h: l,
                            }));
                        }
                    }
                }
            }
            State::Gap(n) => {
                if n >= c.skip_periods {
                    self.set_amp(self.ld_restart);
                    self.state = State::Probe {
                        axis: Axis::Q,
                        n: 0,
                    };
                } else {
                    self.state = State::Gap(n + 1);
                }
            }
        }

        // Output: bias on d plus the square wave on the active axis.
        let wave = self.sign * 0.5 * (self.amp + self.last_amp);
        self.last_amp = self.amp;
        let v_dq = match self.state {
            State::Probe { axis: Axis::Q, .. } | State::Measure(Axis::Q) => {
                Dq::new(self.v_bias, wave)
            }
            State::Probe { axis: Axis::D, .. } | State::Measure(Axis::D) | State::Gap(_) => {
                Dq::new(self.v_bias + wave, 0.0)
            }
            State::Bias(_) => Dq::new(self.v_bias, 0.0),
        };
        self.sign = -self.sign;
        Ok(CalStep::Apply {
            v_dq,
            theta_e: ElectricalAngle::ZERO,
        })
    }

    fn accumulate(&mut self, axis: Axis, delta: Dq) {
        if self.since_change > self.cfg.skip_periods {
            let d = match axis {
                Axis::D => delta.d,
                Axis::Q => delta.q,
            };
            self.demod.add(self.sign * d);
        }
    }
}
