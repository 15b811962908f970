//! Permanent-magnet flux linkage without an angle sensor (design §29): the
//! rotor is carried by a turning current vector of fixed size (I/f), and
//! the flux linkage comes from the back-EMF that vector's own frame sees.
//!
//! The routine runs its own current loop ([`CurrentLoop`], the gains the
//! identification just measured) in a frame it turns itself, with the
//! whole current on that frame's d axis. The rotor follows the frame at a
//! load angle `delta` (behind it; a quarter turn at most), so in the
//! frame, in steady state,
//!
//! ```text
//! e = v - R i - j w_f L i = j w_r psi e^(-j delta)
//! ```
//!
//! (`w_f` the frame's electrical speed, `w_r` the rotor's, equal on
//! average). The EMF vector's size is `w psi` whatever the load angle.
//! A voltage error of the inverter (the dead time's drop) is a vector of
//! constant size along the current, and here the current is fixed in the
//! frame: it is the same at both speeds, so
//!
//! ```text
//! psi = |mean(e_2) - mean(e_1)| / (w_2 - w_1)
//! ```
//!
//! from two speeds cancels it (the load angle is taken equal at both; a
//! rotor that swings about the field makes the means a little short,
//! about 1.5 % for a swing of 10 degrees). The second speed puts the
//! back-EMF at `emf_fraction` of the open-loop voltage limit, from the
//! first point's rough value.
//!
//! **Sequence:** the current rises along angle 0 and holds (the rotor
//! aligns), the frame accelerates to the first speed in `ramp_s`, settles,
//! averages; then to the second speed in `ramp_s`, settles, averages; then
//! back to zero in `ramp_s`, and the current falls. Every period returns
//! [`CalStep::Apply`] with the loop's voltage at the frame's angle
//! advanced by the current loop's delay compensation (the voltage acts
//! later than the sample it was computed from).
//!
//! **A rotor that does not follow** (blocked, too heavy for the ramp, too
//! much load) gives an EMF that does not grow with the frame's speed, and
//! one that turns through the frame: the one-point value at the second
//! speed, `|e_2| / w_2`, must be within [`AGREEMENT`] of the slope's, and
//! the mean EMF vector there at least [`COHERENCE`] of the mean EMF's size,
//! else [`CalError::RotorStuck`]. A locked salient rotor passes both: its
//! saliency makes a voltage that grows with the speed and has a steady
//! mean, `w I (Lq - Ld) / 2` along q (the rest turns at twice the slip);
//! a flux linkage below [`SALIENCY_MARGIN`] times `I |Lq - Ld| / 2` is
//! therefore refused as well (a real magnet is far above it: 35 times on
//! the bench's GL80 file, 16 on the interior-PM one, at their test
//! currents).
//!
//! ```
//! use foc_core::calibration::field_flux::{FieldFlux, FieldFluxConfig};
//! use foc_core::calibration::{CalInput, CalStep};
//! use foc_core::control::{current::CurrentLoopConfig, MotorParams};
//! use foc_core::{angle::MechanicalAngle, frames::Abc};
//! let motor = MotorParams { pole_pairs: 7, r_ohm: 0.2, ld_h: 60e-6, lq_h: 60e-6, flux_linkage_wb: 0.0 };
//! let cfg = FieldFluxConfig::new(2.0, 6.0);
//! let mut f = FieldFlux::new(cfg, CurrentLoopConfig::technical_optimum(motor, 20_000.0));
//! let s = f.step(&CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0));
//! assert!(matches!(s, CalStep::Apply { .. }));
//! ```

use super::common::{check_input, latch, periods, CalError, CalInput, CalStep};
use crate::angle::ElectricalAngle;
use crate::control::current::{CurrentLoop, CurrentLoopConfig, CurrentLoopInput};
use crate::frames::Dq;
use crate::FRAC_1_SQRT_3;
use core::f32::consts::TAU;

/// The one-point flux linkage at the second speed must be within this
/// share of the two-point value.
pub const AGREEMENT: f32 = 0.25;

/// A locked salient rotor looks, in the frame, like a flux linkage of
/// `I |Lq - Ld| / 2` (the saliency's flux, turned through the frame at
/// twice the slip, has that mean along q): a result below this many times
/// that is not told from it.
pub const SALIENCY_MARGIN: f32 = 4.0;

/// At the second speed the mean EMF vector must be at least this share of
/// the mean EMF's size: a rotor that follows the field holds the EMF still
/// in the frame (a swing of 25 degrees leaves 0.9), one that slips lets
/// it turn through the frame.
pub const COHERENCE: f32 = 0.8;

/// Configuration of the flux measurement on a turning field.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldFluxConfig {
    /// Size of the field's current \[A\].
    pub current_a: f32,
    /// Open-loop voltage limit \[V\] (the drive's `max_open_loop_voltage_v`
    /// or less).
    pub max_voltage_v: f32,
    /// Time of the current's rise \[s\] (and of its fall at the end).
    pub rise_s: f32,
    /// Time the current holds still before the field turns \[s\].
    pub hold_s: f32,
    /// Time of every speed change \[s\].
    pub ramp_s: f32,
    /// First speed [rad/s, electrical].
    pub first_speed_rad_s: f32,
    /// Highest speed [rad/s, electrical].
    pub max_speed_rad_s: f32,
    /// Back-EMF at the second speed as a share of the voltage limit.
    pub emf_fraction: f32,
    /// Time at each speed before averaging \[s\].
    pub settle_s: f32,
    /// Averaging time at each speed \[s\].
    pub average_s: f32,
    /// Current vector that aborts the routine \[A\].
    pub max_current_a: f32,
    /// Share of the bus's linear range `Udc / sqrt(3)` the voltage may
    /// use: at most the modulation of the stage that applies it (it clips
    /// there, and the EMF is computed from the voltage asked for). The
    /// drive's lifecycle sets it from the current stage.
    pub max_modulation: f32,
}

impl FieldFluxConfig {
    /// Defaults for a field current \[A\] and an open-loop
    /// voltage limit \[V\]: rise 10 ms, hold 0.5 s, every speed change in
    /// 1 s, first speed 2 electrical Hz (the back-EMF of a large motor
    /// stays well inside the limit there), at most 200 Hz, back-EMF at the
    /// second speed 40 % of the limit, 0.5 s settling and 0.3 s averaging
    /// at each speed, abort at twice the field's current.
    pub fn new(current_a: f32, max_voltage_v: f32) -> Self {
        Self {
            current_a,
            max_voltage_v,
            rise_s: 0.01,
            hold_s: 0.5,
            ramp_s: 1.0,
            first_speed_rad_s: 2.0 * TAU,
            max_speed_rad_s: 200.0 * TAU,
            emf_fraction: 0.4,
            settle_s: 0.5,
            average_s: 0.3,
            max_current_a: 2.0 * current_a,
            max_modulation: super::common::MAX_MODULATION,
        }
    }

    fn is_valid(&self, current: &CurrentLoopConfig) -> bool {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let m = &current.motor;
        pos(current.ts_s)
            && pos(m.r_ohm)
            && pos(m.ld_h)
            && pos(m.lq_h)
            && pos(self.current_a)
            && pos(self.max_voltage_v)
            && pos(self.rise_s)
            && pos(self.hold_s)
            && pos(self.ramp_s)
            && pos(self.first_speed_rad_s)
            && self.max_speed_rad_s.is_finite()
            && self.max_speed_rad_s >= 2.0 * self.first_speed_rad_s
            && pos(self.emf_fraction)
            && self.emf_fraction < 1.0
            && pos(self.settle_s)
            && pos(self.average_s)
            && self.max_current_a >= self.current_a
            && pos(self.max_modulation)
            && self.max_modulation <= 1.0
    }

    /// The voltage the routine may ask for \[V\] on the bus `v_bus_v`.
    fn voltage_limit_v(&self, v_bus_v: f32) -> f32 {
        let bus = self.max_modulation * v_bus_v * FRAC_1_SQRT_3;
        if bus < self.max_voltage_v {
            bus
        } else {
            self.max_voltage_v
        }
    }
}

/// Result of the measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FieldFluxResult {
    /// Flux linkage \[Wb\] (peak, per phase).
    pub flux_linkage_wb: f32,
    /// The two speeds measured at [rad/s, electrical].
    pub speeds_e_rad_s: [f32; 2],
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum State {
    /// The current rises, then holds (`n` periods so far).
    Align { n: u32 },
    /// The field goes to speed `k` (0, 1; 2 is zero at the end).
    Ramp { k: u8 },
    /// At speed `k`: `n` periods of settling.
    Settle { k: u8, n: u32 },
    /// At speed `k`: averaging.
    Average { k: u8 },
    /// The current falls (`n` periods so far).
    Fall { n: u32 },
}

/// The measurement's state machine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldFlux {
    cfg: FieldFluxConfig,
    /// The current loop's configuration (gains, period, motor).
    current: CurrentLoopConfig,
    state: State,
    loop_: CurrentLoop,
    /// The frame's angle and speed [rad/s, electrical].
    theta: ElectricalAngle,
    w_rad_s: f32,
    /// The speed change per period of the ramp in progress.
    dw: f32,
    /// Speeds 0 and 1.
    speeds: [f32; 2],
    /// The voltage applied last period, in the frame \[V\].
    last_v: Dq,
    /// Sums of the EMF vector and of its size at the current speed, and
    /// their count.
    sum: Dq,
    sum_abs: f32,
    n: u32,
    /// The mean EMF vectors at the two speeds \[V\].
    emf: [Dq; 2],
    psi: f32,
    finished: Option<CalStep<FieldFluxResult>>,
}

impl FieldFlux {
    /// A new measurement with the current loop of `current` (the gains
    /// and period; its motor's `r_ohm`, `ld_h` and `lq_h`, the flux
    /// linkage being the unknown). Its first period raises the current.
    pub fn new(config: FieldFluxConfig, current: CurrentLoopConfig) -> Self {
        Self {
            cfg: config,
            current,
            state: State::Align { n: 0 },
            loop_: CurrentLoop::new(current),
            theta: ElectricalAngle::ZERO,
            w_rad_s: 0.0,
            dw: 0.0,
            speeds: [config.first_speed_rad_s, 0.0],
            last_v: Dq::ZERO,
            sum: Dq::ZERO,
            sum_abs: 0.0,
            n: 0,
            emf: [Dq::ZERO; 2],
            psi: 0.0,
            finished: None,
        }
    }

    /// One PWM period. See the module docs.
    pub fn step(&mut self, inp: &CalInput) -> CalStep<FieldFluxResult> {
        if let Some(f) = self.finished {
            return f;
        }
        let r = self.run(inp);
        latch(&mut self.finished, r)
    }

    fn run(&mut self, inp: &CalInput) -> Result<CalStep<FieldFluxResult>, CalError> {
        let c = self.cfg;
        if !c.is_valid(&self.current) {
            return Err(CalError::InvalidConfig);
        }
        check_input(inp, c.max_current_a)?;
        let ts = self.current.ts_s;
        let mut id_ref = c.current_a;
        match self.state {
            State::Align { n } => {
                id_ref *= ramp_share(n, periods(c.rise_s, ts));
                self.state = if n + 1 >= periods(c.rise_s + c.hold_s, ts) {
                    self.start_ramp(0)
                } else {
                    State::Align { n: n + 1 }
                };
            }
            State::Ramp { k } => {
                let target = self.speed(k);
                self.w_rad_s += self.dw;
                if (self.dw >= 0.0 && self.w_rad_s >= target)
                    || (self.dw < 0.0 && self.w_rad_s <= target)
                {
                    self.w_rad_s = target;
                    self.state = if k == 2 {
                        State::Fall { n: 0 }
                    } else {
                        State::Settle { k, n: 0 }
                    };
                }
            }
            State::Settle { k, n } => {
                self.state = if n + 1 >= periods(c.settle_s, ts) {
                    self.sum = Dq::ZERO;
                    self.sum_abs = 0.0;
                    self.n = 0;
                    State::Average { k }
                } else {
                    State::Settle { k, n: n + 1 }
                };
            }
            State::Average { k } => self.average(k, inp)?,
            State::Fall { n } => {
                let rise = periods(c.rise_s, ts);
                if n >= rise {
                    return Ok(CalStep::Done(FieldFluxResult {
                        flux_linkage_wb: self.psi,
                        speeds_e_rad_s: [self.speeds[0], self.speeds[1]],
                    }));
                }
                id_ref *= 1.0 - ramp_share(n, rise);
                self.state = State::Fall { n: n + 1 };
            }
        }
        Ok(self.drive(inp, id_ref))
    }

    /// Speed `k` [rad/s, electrical] (0, 1; 2 and beyond: the final 0).
    fn speed(&self, k: u8) -> f32 {
        match k {
            0 => self.speeds[0],
            1 => self.speeds[1],
            _ => 0.0,
        }
    }

    /// The field's ramp to speed `k`, taking `ramp_s`.
    fn start_ramp(&mut self, k: u8) -> State {
        let ts = self.current.ts_s;
        let target = self.speed(k);
        self.dw = (target - self.w_rad_s) / periods(self.cfg.ramp_s, ts) as f32;
        State::Ramp { k }
    }

    /// One period's EMF into the mean; at the end of the average, the
    /// next speed (or the result and the ramp down).
    fn average(&mut self, k: u8, inp: &CalInput) -> Result<(), CalError> {
        let c = self.cfg;
        let m = self.current.motor;
        let i = super::common::current_dq(inp.i_abc_a, self.theta);
        let w = self.w_rad_s;
        let v = self.last_v;
        let e = Dq::new(
            v.d - m.r_ohm * i.d + w * m.lq_h * i.q,
            v.q - m.r_ohm * i.q - w * m.ld_h * i.d,
        );
        self.sum.d += e.d;
        self.sum.q += e.q;
        self.sum_abs += e.magnitude();
        self.n += 1;
        if self.n < periods(c.average_s, self.current.ts_s) {
            return Ok(());
        }
        let inv = 1.0 / self.n as f32;
        let e = Dq::new(self.sum.d * inv, self.sum.q * inv);
        if k == 0 {
            self.emf[0] = e;
            self.speeds[1] = self.second_speed(e, inp.v_bus_v);
            self.state = self.start_ramp(1);
            return Ok(());
        }
        self.emf[1] = e;
        let [w1, w2] = [self.speeds[0], self.speeds[1]];
        let de = Dq::new(e.d - self.emf[0].d, e.q - self.emf[0].q);
        let psi = de.magnitude() / (w2 - w1);
        let one_point = e.magnitude() / w2;
        if !(psi.is_finite() && psi > 0.0) {
            return Err(CalError::ImplausibleResult);
        }
        let coherent = e.magnitude() >= COHERENCE * self.sum_abs * inv;
        let saliency_wb = 0.5 * c.current_a * (m.lq_h - m.ld_h).abs();
        if (one_point - psi).abs() > AGREEMENT * psi
            || !coherent
            || psi < SALIENCY_MARGIN * saliency_wb
        {
            return Err(CalError::RotorStuck);
        }
        self.psi = psi;
        self.state = self.start_ramp(2);
        Ok(())
    }

    /// The second speed [rad/s, electrical]: the back-EMF at
    /// `emf_fraction` of the voltage limit, from the first point's rough
    /// flux linkage (its q part: the dead time's error lies along the
    /// current, on d, and at the first speed it can be larger than the
    /// back-EMF of a small motor); twice the first speed at least, the
    /// highest at most.
    fn second_speed(&self, e1: Dq, v_bus_v: f32) -> f32 {
        let c = &self.cfg;
        let w1 = c.first_speed_rad_s;
        let psi_rough = e1.q.abs() / w1;
        let v_lim = c.voltage_limit_v(v_bus_v);
        let w2 = if psi_rough.is_finite() && psi_rough > 0.0 {
            c.emf_fraction * v_lim / psi_rough
        } else {
            c.max_speed_rad_s
        };
        crate::clamp(w2, 2.0 * w1, c.max_speed_rad_s)
    }

    /// The current loop on the frame, the frame turned on, and the voltage
    /// to apply at its angle advanced by the loop's delay compensation.
    fn drive(&mut self, inp: &CalInput, id_ref: f32) -> CalStep<FieldFluxResult> {
        let c = &self.cfg;
        // The loop's voltage circle is the open-loop limit: it is given
        // the bus whose circle that is.
        let v_lim = c.voltage_limit_v(inp.v_bus_v);
        let bus = v_lim / (self.current.max_modulation * FRAC_1_SQRT_3);
        let out = self.loop_.step(&CurrentLoopInput {
            i_abc_a: inp.i_abc_a,
            theta_e: self.theta,
            omega_e_rad_s: self.w_rad_s,
            v_bus_v: bus,
            i_dq_ref_a: Dq::new(id_ref, 0.0),
        });
        let v = if out.invalid { Dq::ZERO } else { out.v_dq_v };
        let ts = self.current.ts_s;
        let advance = self.current.delay_compensation_periods * ts * self.w_rad_s;
        let theta_e = self.theta.add_radians(advance);
        self.last_v = v;
        self.theta = self.theta.add_radians(self.w_rad_s * ts);
        CalStep::Apply { v_dq: v, theta_e }
    }
}

/// `(n + 1) / total`, at most 1.
fn ramp_share(n: u32, total: u32) -> f32 {
    let s = (n + 1) as f32 / total.max(1) as f32;
    if s < 1.0 {
        s
    } else {
        1.0
    }
}
