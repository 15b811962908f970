//! Permanent-magnet flux linkage from two steady speeds in closed-loop
//! velocity mode.
//!
//! In steady state with `id = 0` the q voltage is
//! `v_q = R i_q + w_e psi (+ w_e Ld i_d)`, so
//!
//! ```text
//! psi = delta(v_q - R i_q) / delta(w_e),     w_e = p * w_m
//! ```
//!
//! between two speeds. The slope cancels every constant voltage error (the
//! dead-time error of a current vector held on q, an error in `R i_q` from a
//! load torque that does not change with speed, ...); the `Ld i_d` term is
//! subtracted when `ld_h` is known.
//!
//! The routine asks for [`CalStep::Velocity`] requests (mechanical rad/s):
//! first `first_speed_rad_s`; once settled (speed within `speed_tolerance`
//! for `settle_s`) it averages over `average_s`, estimates `psi` roughly
//! from that one point and picks the second speed so that the back-EMF
//! reaches `emf_fraction` of the voltage limit (at least twice the first
//! speed, at most `max_speed_rad_s`). After the second point it asks for
//! speed zero until the rotor is (nearly) stopped, then returns `Done`.
//! The caller passes back [`CalInput::closed_loop`] every period.
//!
//! ```
//! use foc_core::calibration::flux::{FluxConfig, FluxLinkage};
//! use foc_core::calibration::{CalInput, CalStep};
//! use foc_core::{angle::MechanicalAngle, frames::Abc};
//! let mut f = FluxLinkage::new(FluxConfig::new(7, 20_000.0, 0.2, 5.0));
//! let s = f.step(&CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0));
//! assert!(matches!(s, CalStep::Velocity { rad_s } if rad_s > 0.0));
//! ```

use super::common::{
    check_input, latch, periods, CalError, CalInput, CalStep, ClosedLoopFeedback, Mean,
};
use core::f32::consts::TAU;

/// Configuration of the flux-linkage measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FluxConfig {
    /// PWM (step) period \[s\].
    pub ts_s: f32,
    /// Pole pairs.
    pub pole_pairs: u8,
    /// Phase resistance \[ohm\].
    pub r_ohm: f32,
    /// d inductance \[H\] (for the `w_e Ld i_d` term; 0 to ignore).
    pub ld_h: f32,
    /// First speed [rad/s, mechanical].
    pub first_speed_rad_s: f32,
    /// Highest speed the routine may ask for [rad/s, mechanical].
    pub max_speed_rad_s: f32,
    /// Back-EMF at the second speed as a fraction of the voltage limit.
    pub emf_fraction: f32,
    /// Bus fraction usable as voltage limit: `Udc / sqrt(3)` times this.
    pub max_modulation: f32,
    /// Speed band around the request, relative.
    pub speed_tolerance: f32,
    /// Time inside the band before averaging \[s\].
    pub settle_s: f32,
    /// Averaging time \[s\].
    pub average_s: f32,
    /// Time limit to settle at each speed \[s\].
    pub speed_timeout_s: f32,
    /// Current vector that aborts the routine \[A\].
    pub max_current_a: f32,
}

impl FluxConfig {
    /// Defaults: first speed 5 electrical Hz, second speed at 30 % of the
    /// voltage limit but at most 200 electrical Hz, 5 % speed band, 0.2 s
    /// settle, 0.2 s averaging, 3 s per speed.
    pub fn new(pole_pairs: u8, pwm_frequency_hz: f32, r_ohm: f32, max_current_a: f32) -> Self {
        let p = f32::from(pole_pairs.max(1));
        Self {
            ts_s: 1.0 / pwm_frequency_hz,
            pole_pairs,
            r_ohm,
            ld_h: 0.0,
            first_speed_rad_s: 5.0 * TAU / p,
            max_speed_rad_s: 200.0 * TAU / p,
            emf_fraction: 0.3,
            max_modulation: 0.95,
            speed_tolerance: 0.05,
            settle_s: 0.2,
            average_s: 0.2,
            speed_timeout_s: 3.0,
            max_current_a,
        }
    }

    fn is_valid(&self) -> bool {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        self.pole_pairs > 0
            && pos(self.ts_s)
            && pos(self.r_ohm)
            && self.ld_h.is_finite()
            && self.ld_h >= 0.0
            && pos(self.first_speed_rad_s)
            && pos(self.max_speed_rad_s)
            && self.max_speed_rad_s >= 2.0 * self.first_speed_rad_s
            && pos(self.emf_fraction)
            && pos(self.max_modulation)
            && pos(self.speed_tolerance)
            && pos(self.settle_s)
            && pos(self.average_s)
            && pos(self.speed_timeout_s)
            && pos(self.max_current_a)
    }
}

/// Result of the flux-linkage measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FluxResult {
    /// Flux linkage \[Wb\] (peak, per phase).
    pub flux_linkage_wb: f32,
    /// The two speeds measured at [rad/s, mechanical].
    pub speeds_rad_s: [f32; 2],
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum State {
    /// Settling at speed `k` (0 or 1); `n` periods in the band so far.
    Settle {
        k: u8,
        n: u32,
    },
    Average {
        k: u8,
    },
    Stop {
        n: u32,
    },
}

/// The flux-linkage state machine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FluxLinkage {
    cfg: FluxConfig,
    state: State,
    speeds: [f32; 2],
    periods_at_speed: u32,
    avg_y: Mean,
    avg_w: Mean,
    points: [(f32, f32); 2],
    psi: f32,
    finished: Option<CalStep<FluxResult>>,
}

impl FluxLinkage {
    /// New measurement (first request: the first speed).
    pub fn new(config: FluxConfig) -> Self {
        Self {
            cfg: config,
            state: State::Settle { k: 0, n: 0 },
            speeds: [config.first_speed_rad_s, 0.0],
            periods_at_speed: 0,
            avg_y: Mean::ZERO,
            avg_w: Mean::ZERO,
            points: [(0.0, 0.0); 2],
            psi: 0.0,
            finished: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &FluxConfig {
        &self.cfg
    }

    /// One PWM period. See the module docs.
    pub fn step(&mut self, inp: &CalInput) -> CalStep<FluxResult> {
        if let Some(f) = self.finished {
            return f;
        }
        let r = self.run(inp);
        latch(&mut self.finished, r)
    }

    fn speed(&self, k: u8) -> f32 {
        if k == 0 {
            self.speeds[0]
        } else {
            self.speeds[1]
        }
    }

    /// `v_q - R i_q - w_e Ld i_d` \[V\] and `w_e` [rad/s] of one sample.
    fn point(&self, f: &ClosedLoopFeedback) -> (f32, f32) {
        let w_e = f32::from(self.cfg.pole_pairs) * f.velocity_rad_s;
        (
            f.v_dq_v.q - self.cfg.r_ohm * f.i_dq_a.q - w_e * self.cfg.ld_h * f.i_dq_a.d,
            w_e,
        )
    }

    /// The second speed [rad/s]: the back-EMF at `emf_fraction` of the
    /// voltage limit, from the first point's rough flux linkage.
    fn second_speed(&self, first: (f32, f32), v_bus_v: f32) -> f32 {
        let c = &self.cfg;
        let v_lim = c.max_modulation * v_bus_v * crate::FRAC_1_SQRT_3;
        let psi_rough = if first.1 > 0.0 {
            first.0 / first.1
        } else {
            0.0
        };
        let p = f32::from(c.pole_pairs);
        let w2 = if psi_rough > 0.0 && psi_rough.is_finite() {
            c.emf_fraction * v_lim / (psi_rough * p)
        } else {
            4.0 * c.first_speed_rad_s
        };
        crate::clamp(w2, 2.0 * c.first_speed_rad_s, c.max_speed_rad_s)
    }

    fn run(&mut self, inp: &CalInput) -> Result<CalStep<FluxResult>, CalError> {
        let c = self.cfg;
        if !c.is_valid() {
            return Err(CalError::InvalidConfig);
        }
        check_input(inp, c.max_current_a)?;
        self.periods_at_speed = self.periods_at_speed.saturating_add(1);
        let timeout = periods(c.speed_timeout_s, c.ts_s);
        match self.state {
            State::Settle { k, n } => {
                let w_ref = self.speed(k);
                if self.periods_at_speed > timeout {
                    return Err(CalError::SpeedNotReached);
                }
                let in_band = inp
                    .closed_loop
                    .is_some_and(|f| (f.velocity_rad_s - w_ref).abs() < c.speed_tolerance * w_ref);
                self.state = if !in_band {
                    State::Settle { k, n: 0 }
                } else if n + 1 >= periods(c.settle_s, c.ts_s) {
                    self.avg_y = Mean::ZERO;
                    self.avg_w = Mean::ZERO;
                    State::Average { k }
                } else {
                    State::Settle { k, n: n + 1 }
                };
                Ok(CalStep::Velocity { rad_s: w_ref })
            }
            State::Average { k } => {
                let w_ref = self.speed(k);
                let Some(f) = inp.closed_loop else {
                    return Err(CalError::InvalidInput);
                };
                let (y, w_e) = self.point(&f);
                self.avg_y.add(y);
                self.avg_w.add(w_e);
                if self.avg_y.count() < periods(c.average_s, c.ts_s) {
                    return Ok(CalStep::Velocity { rad_s: w_ref });
                }
                let pt = (self.avg_y.mean(), self.avg_w.mean());
                self.periods_at_speed = 0;
                if k == 0 {
                    self.points[0] = pt;
                    let w2 = self.second_speed(pt, inp.v_bus_v);
                    self.speeds[1] = w2;
                    self.state = State::Settle { k: 1, n: 0 };
                    return Ok(CalStep::Velocity { rad_s: w2 });
                }
                self.points[1] = pt;
                let [(y1, w1), (y2, w2)] = self.points;
                let psi = (y2 - y1) / (w2 - w1);
                if !(psi.is_finite() && psi > 0.0) {
                    return Err(CalError::ImplausibleResult);
                }
                self.psi = psi;
                self.state = State::Stop { n: 0 };
                Ok(CalStep::Velocity { rad_s: 0.0 })
            }
            State::Stop { n } => {
                let slow = inp.closed_loop.is_some_and(|f| {
                    f.velocity_rad_s.abs() < c.speed_tolerance * c.first_speed_rad_s
                });
                let n = if slow { n + 1 } else { 0 };
                if n >= periods(0.05, c.ts_s) || self.periods_at_speed > timeout {
                    return Ok(CalStep::Done(FluxResult {
                        flux_linkage_wb: self.psi,
                        speeds_rad_s: self.speeds,
                    }));
                }
                self.state = State::Stop { n };
                Ok(CalStep::Velocity { rad_s: 0.0 })
            }
        }
    }
}
