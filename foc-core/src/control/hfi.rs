//! The angle of a salient rotor at standstill: high-frequency injection
//! (design §28).
//!
//! The flux observer (design §26) needs a back-EMF; at standstill there is
//! none. A salient rotor (`Lq > Ld`, interior PM) shows its angle in its
//! inductance instead: a voltage pulse along an axis drives more current
//! along `d` than along `q`. The drive adds to its own voltage a square
//! wave of amplitude `Vh` on the d axis it believes in, its sign flipping
//! every period (half the PWM rate, far above the current loop's
//! bandwidth). The current's change over one period, read in that frame,
//! is for an angle error `delta = theta - theta_est`:
//!
//! ```text
//! di_d = s Vh T (cos^2 delta / Ld + sin^2 delta / Lq)
//! di_q = s Vh T sin(2 delta) (1/Ld - 1/Lq) / 2
//! ```
//!
//! The difference of two periods' changes doubles this and removes what
//! the fundamental (the current loop, the back-EMF) adds, which moves
//! little in two periods. Their ratio, over the saliency `1 - Ld/Lq`, is
//! about `delta` for small errors:
//!
//! ```text
//! err = (dd_q / dd_d) / (1 - Ld / Lq)  ~ delta
//! ```
//!
//! The ratio needs neither `Vh`, nor `T`, nor whether the bridge applies a
//! duty in the period it is computed or the next (the sign of the d
//! response carries that), nor how much of `Vh` the dead time eats. A
//! second-order PLL follows it, critically damped, its bandwidth from the
//! rotor's acceleration and the PWM rate ([`HfiConfig::for_motor`]). The
//! current loop sees the mean of the last two samples, in which the
//! injection's triangle cancels.
//!
//! The ratio reads zero on the q axis too (`sin 2 delta = 0` at a quarter
//! turn), an unstable equilibrium any disturbance leaves, but a start placed
//! exactly there would stay: there the d response is that of `Lq`, smaller,
//! so at the end of the settling a response below the mean of the two
//! turns the estimate a quarter turn and settles again ([`Hfi::on_q_axis`];
//! once).
//!
//! **Magnet polarity**: the ratio sees the axis, not its direction (`sin
//! 2 delta`): the estimate may sit half a turn off. A d current along the
//! magnet adds to its flux and saturates the iron: less inductance, a
//! larger response `dd_d`. The polarity test ([`Polarity`]) drives `+I`
//! then `-I` along the estimated d axis, averages the response of each
//! and turns the estimate half a turn when `-I` gave the larger one.
//!
//! Limits: a motor whose saliency is below [`SALIENCY_MIN`] is refused
//! ([`HfiConfig::for_motor`] gives `None`); the injection's voltage is
//! [`INJECTION_RIPPLE_SHARE`] of the start current's worth of ripple, at
//! most [`INJECTION_BUS_SHARE`] of the bus. Above low speed the flux
//! observer takes over (design §27).

use super::MotorParams;
use crate::angle::ElectricalAngle;
use crate::frames::{AlphaBeta, Dq};
use crate::transforms;

/// The least saliency `1 - Ld / Lq` injection runs on.
pub const SALIENCY_MIN: f32 = 0.1;

/// The d current's ripple per period the injection aims for, as a share of
/// the start current.
pub const INJECTION_RIPPLE_SHARE: f32 = 0.05;

/// The injection's largest amplitude as a share of the bus.
pub const INJECTION_BUS_SHARE: f32 = 0.2;

/// The PLL's largest natural frequency times the period (critically
/// damped).
pub const PLL_PER_PERIOD: f32 = 0.03;

/// The PLL's smallest natural frequency times the period.
pub const PLL_MIN_PER_PERIOD: f32 = 0.005;

/// The angle the PLL may lag by while the rotor accelerates at the start
/// current's rate \[rad, electrical\]: `a / w_n^2` for a second-order PLL.
pub const PLL_ACCEL_LAG_RAD: f32 = 0.1;

/// Each of the polarity test's two pulses \[s\] (its second half is
/// measured). No torque acts meanwhile: a load turns the rotor freely
/// until the closed loop starts.
pub const POLARITY_PULSE_S: f32 = 0.008;

/// A d response below this share of the expected one is no response (a
/// bridge not yet switching, an open phase): the PLL holds.
pub const RESPONSE_FLOOR_SHARE: f32 = 0.2;

/// How the injection runs on one motor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HfiConfig {
    /// Control period \[s\].
    pub ts_s: f32,
    /// The injection's amplitude \[V\].
    pub v_inject_v: f32,
    /// `1 - Ld / Lq`.
    pub saliency: f32,
    /// The d response expected of a right estimate, `2 Vh T / Ld` \[A\].
    pub expected_response_a: f32,
    /// PLL gains: angle \[1/s\] and speed \[1/s^2\] per unit error.
    pub kp: f32,
    /// See `kp`.
    pub ki: f32,
    /// The polarity test's d current \[A\].
    pub polarity_current_a: f32,
    /// Periods the PLL settles before the polarity test.
    pub settle_periods: u32,
    /// Periods of each of the polarity test's two pulses (the second half
    /// of each is measured).
    pub pulse_periods: u32,
}

impl HfiConfig {
    /// Derived from the identified motor, the period \[s\], the start
    /// current \[A\] (the polarity test's), the acceleration that current
    /// gives the bare rotor [rad/s^2, electrical] and the bus \[V\]: the
    /// injection gives a d ripple of [`INJECTION_RIPPLE_SHARE`] of the
    /// start current per period (at most [`INJECTION_BUS_SHARE`] of the
    /// bus); the PLL is as slow as lets it lag that acceleration by
    /// [`PLL_ACCEL_LAG_RAD`] (a slower PLL passes less of the current
    /// readings' quantisation on to the speed loop), between
    /// [`PLL_MIN_PER_PERIOD`] and [`PLL_PER_PERIOD`] of the period rate;
    /// the PLL settles for ten of its time
    /// constants (at least 10 ms); each polarity pulse lasts
    /// [`POLARITY_PULSE_S`]. `None`
    /// when the motor's saliency is below [`SALIENCY_MIN`] or a value is
    /// not usable.
    pub fn for_motor(
        motor: &MotorParams,
        ts_s: f32,
        start_current_a: f32,
        accel_rad_s2: f32,
        v_bus_v: f32,
    ) -> Option<Self> {
        let usable = crate::all_finite([
            motor.ld_h,
            motor.lq_h,
            ts_s,
            start_current_a,
            accel_rad_s2,
            v_bus_v,
        ]) && motor.ld_h > 0.0
            && accel_rad_s2 > 0.0
            && motor.lq_h > 0.0
            && ts_s > 0.0
            && start_current_a > 0.0
            && v_bus_v > 0.0;
        if !usable {
            return None;
        }
        let saliency = 1.0 - motor.ld_h / motor.lq_h;
        if saliency < SALIENCY_MIN {
            return None;
        }
        let v = (INJECTION_RIPPLE_SHARE * start_current_a * motor.ld_h / ts_s)
            .min(INJECTION_BUS_SHARE * v_bus_v);
        let wn = crate::clamp(
            crate::sqrtf(accel_rad_s2 / PLL_ACCEL_LAG_RAD),
            PLL_MIN_PER_PERIOD / ts_s,
            PLL_PER_PERIOD / ts_s,
        );
        let periods = |s: f32| ((s / ts_s) as u32).max(1);
        Some(Self {
            ts_s,
            v_inject_v: v,
            saliency,
            expected_response_a: 2.0 * v * ts_s / motor.ld_h,
            kp: 2.0 * wn,
            ki: wn * wn,
            polarity_current_a: start_current_a,
            settle_periods: periods((10.0 / wn).max(0.01)),
            pulse_periods: periods(POLARITY_PULSE_S),
        })
    }
}

/// The injection's estimator: the angle and speed of a salient rotor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hfi {
    cfg: HfiConfig,
    angle: ElectricalAngle,
    speed_rad_s: f32,
    /// The injection's sign for the next period.
    sign: f32,
    /// The last sample and its change over the period before, read in the
    /// estimate's frame (`None` after a start).
    last_i_ab: Option<AlphaBeta>,
    last_change: Option<Dq>,
    /// The last d response `|dd_d| / 2` \[A\] (0 when none yet).
    response_a: f32,
    /// The last angle error the PLL took \[rad\].
    error_rad: f32,
    /// The mean of the last two samples \[A\].
    mean_i_ab: AlphaBeta,
    /// Periods in a row whose response was below the floor.
    silent: u32,
}

impl Hfi {
    /// At angle zero, at rest.
    pub fn new(cfg: HfiConfig) -> Self {
        Self {
            cfg,
            angle: ElectricalAngle::ZERO,
            speed_rad_s: 0.0,
            sign: 1.0,
            last_i_ab: None,
            last_change: None,
            response_a: 0.0,
            error_rad: 0.0,
            mean_i_ab: AlphaBeta::new(0.0, 0.0),
            silent: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &HfiConfig {
        &self.cfg
    }

    /// Start again from `angle` at `speed_rad_s` [rad/s, electrical] (a
    /// hand-back from the flux observer, a new start): the differences
    /// restart.
    pub fn place(&mut self, angle: ElectricalAngle, speed_rad_s: f32) {
        self.angle = angle;
        self.speed_rad_s = if speed_rad_s.is_finite() {
            speed_rad_s
        } else {
            0.0
        };
        self.last_i_ab = None;
        self.last_change = None;
        self.response_a = 0.0;
        self.error_rad = 0.0;
        self.silent = 0;
    }

    /// Turn the estimate half a turn (the polarity test found it on the
    /// magnet's south pole).
    pub fn flip(&mut self) {
        self.angle = self.angle.add_radians(core::f32::consts::PI);
        self.last_change = None;
    }

    /// The estimated angle.
    pub fn angle(&self) -> ElectricalAngle {
        self.angle
    }

    /// The estimated speed [rad/s, electrical].
    pub fn speed_rad_s(&self) -> f32 {
        self.speed_rad_s
    }

    /// The last d response `|dd_d| / 2` \[A\]: larger where the d axis
    /// saturates (the polarity test reads it).
    pub fn response_a(&self) -> f32 {
        self.response_a
    }

    /// True when the estimate sits on the rotor's q axis (the demodulation's
    /// other equilibrium, unstable, where the error reads zero): the d
    /// response is then that of `Lq`, below the mean of the `Ld` and `Lq`
    /// responses.
    pub fn on_q_axis(&self) -> bool {
        let ld_over_lq = 1.0 - self.cfg.saliency;
        2.0 * self.response_a < 0.5 * (1.0 + ld_over_lq) * self.cfg.expected_response_a
    }

    /// Turn the estimate a quarter turn (off the q axis; the PLL then
    /// settles on the d axis).
    pub fn turn_quarter(&mut self) {
        self.angle = self.angle.add_radians(core::f32::consts::FRAC_PI_2);
        self.last_change = None;
    }

    /// The last angle error the PLL took \[rad\] (about the true error for
    /// small errors).
    pub fn error_rad(&self) -> f32 {
        self.error_rad
    }

    /// The mean of the last two samples \[A\]: the current without the
    /// injection's ripple (what the current loop runs on); `i_ab` itself
    /// before the first sample since [`Self::place`] (a run's first
    /// period: the mean of an earlier run would be stale).
    pub fn mean_current(&self, i_ab: AlphaBeta) -> AlphaBeta {
        if self.last_i_ab.is_some() {
            self.mean_i_ab
        } else {
            i_ab
        }
    }

    /// Periods in a row whose d response stayed below
    /// [`RESPONSE_FLOOR_SHARE`] of the expected (no injection reaches the
    /// motor: an open phase, a bridge that does not switch).
    pub fn silent_periods(&self) -> u32 {
        self.silent
    }

    /// Period start: the measured current \[A\]. Demodulates, steps the PLL
    /// (with no correction, coasting at its speed, when the response is
    /// below [`RESPONSE_FLOOR_SHARE`] of the expected) and forms the mean
    /// current.
    pub fn update(&mut self, i_ab: AlphaBeta) {
        if !crate::all_finite([i_ab.alpha, i_ab.beta]) {
            return;
        }
        let Some(last) = self.last_i_ab.replace(i_ab) else {
            // The first sample: no change yet.
            self.mean_i_ab = i_ab;
            return;
        };
        self.mean_i_ab = AlphaBeta::new(
            0.5 * (i_ab.alpha + last.alpha),
            0.5 * (i_ab.beta + last.beta),
        );
        let (s, c) = crate::trig::sin_cos(self.angle);
        let change = transforms::park(
            AlphaBeta::new(i_ab.alpha - last.alpha, i_ab.beta - last.beta),
            s,
            c,
        );
        let mut err = 0.0;
        if let Some(prev) = self.last_change {
            let dd = Dq::new(change.d - prev.d, change.q - prev.q);
            self.response_a = 0.5 * libm::fabsf(dd.d);
            if libm::fabsf(dd.d) >= RESPONSE_FLOOR_SHARE * self.cfg.expected_response_a {
                let e = dd.q / dd.d / self.cfg.saliency;
                err = crate::clamp(e, -1.0, 1.0);
                self.silent = 0;
            } else {
                self.silent = self.silent.saturating_add(1);
            }
        }
        self.last_change = Some(change);
        self.error_rad = err;
        let ts = self.cfg.ts_s;
        self.speed_rad_s += self.cfg.ki * err * ts;
        self.angle = self
            .angle
            .add_radians((self.speed_rad_s + self.cfg.kp * err) * ts);
    }

    /// The injection's d voltage for the period ahead \[V\] (its sign flips
    /// at each call).
    pub fn inject_v(&mut self) -> f32 {
        self.sign = -self.sign;
        self.sign * self.cfg.v_inject_v
    }
}

/// The polarity test: the responses averaged over the second half of each
/// pulse, `+I` first.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Polarity {
    periods: u32,
    sum_pos_a: f32,
    sum_neg_a: f32,
    n_pos: u32,
    n_neg: u32,
}

/// What the polarity test decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PolarityResult {
    /// The estimate is on the magnet's north (d) axis.
    Right,
    /// The estimate is half a turn off: turn it.
    Flip,
    /// The two responses are closer than [`POLARITY_MARGIN`]: the
    /// direction is not known (a lost lock).
    Unknown,
}

/// The least relative difference of the polarity test's two responses
/// that decides.
pub const POLARITY_MARGIN: f32 = 0.03;

impl Polarity {
    /// The d current of this period \[A\] (`+I`, then `-I`, then 0 when
    /// done) given the pulse length and current.
    pub fn current_a(&self, cfg: &HfiConfig) -> f32 {
        let p = cfg.pulse_periods.clamp(2, u32::MAX / 4);
        if self.periods < p {
            cfg.polarity_current_a
        } else if self.periods < 2 * p {
            -cfg.polarity_current_a
        } else {
            0.0
        }
    }

    /// Count this period's response \[A\]; `Some` once both pulses are
    /// measured.
    pub fn step(&mut self, cfg: &HfiConfig, response_a: f32) -> Option<PolarityResult> {
        let p = cfg.pulse_periods.clamp(2, u32::MAX / 4);
        let k = self.periods;
        if (p / 2..p).contains(&k) {
            self.sum_pos_a += response_a;
            self.n_pos += 1;
        } else if (p + p / 2..2 * p).contains(&k) {
            self.sum_neg_a += response_a;
            self.n_neg += 1;
        }
        self.periods = self.periods.saturating_add(1);
        if self.periods < 2 * p {
            return None;
        }
        let pos = self.sum_pos_a / self.n_pos.max(1) as f32;
        let neg = self.sum_neg_a / self.n_neg.max(1) as f32;
        // Less than POLARITY_MARGIN apart: the motor does not saturate
        // enough to tell (or the response is noise).
        let mean = 0.5 * (neg + pos);
        let decided = mean > 0.0 && (neg - pos).abs() >= POLARITY_MARGIN * mean;
        Some(if !decided {
            PolarityResult::Unknown
        } else if neg > pos {
            PolarityResult::Flip
        } else {
            PolarityResult::Right
        })
    }

    /// The mean responses so far, `(+I, -I)` \[A\].
    pub fn responses_a(&self) -> (f32, f32) {
        (
            self.sum_pos_a / self.n_pos.max(1) as f32,
            self.sum_neg_a / self.n_neg.max(1) as f32,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An interior-PM motor (Ld 36 mH, Lq 51 mH) at 15 kHz.
    fn motor() -> MotorParams {
        MotorParams {
            pole_pairs: 3,
            r_ohm: 3.6,
            ld_h: 0.036,
            lq_h: 0.051,
            flux_linkage_wb: 0.545,
        }
    }

    const TS: f32 = 1.0 / 15_000.0;

    fn config() -> HfiConfig {
        HfiConfig::for_motor(&motor(), TS, 6.0, 3e4, 540.0).unwrap()
    }

    /// A locked salient rotor at `theta` whose d inductance falls by
    /// `sat` per ampere of d current (along the magnet), with the bridge
    /// applying each period's voltage one period later; the dq current
    /// integrates exactly (R neglected over a period).
    struct Rotor {
        theta: f32,
        i_dq: Dq,
        pending: AlphaBeta,
        sat: f32,
    }

    impl Rotor {
        fn current(&self) -> AlphaBeta {
            let (s, c) = libm::sincosf(self.theta);
            transforms::inverse_park(self.i_dq, s, c)
        }
        /// Apply the pending voltage for a period, queue `v_ab`.
        fn step(&mut self, v_ab: AlphaBeta) {
            let (s, c) = libm::sincosf(self.theta);
            let v = transforms::park(self.pending, s, c);
            let m = motor();
            let ld = m.ld_h * (1.0 - self.sat * self.i_dq.d);
            self.i_dq = Dq::new(self.i_dq.d + v.d * TS / ld, self.i_dq.q + v.q * TS / m.lq_h);
            self.pending = v_ab;
        }
    }

    /// One period: the estimator reads the rotor, a d-current PI-free
    /// drive adds `v_dq` (in the estimate's frame) to the injection.
    fn period(h: &mut Hfi, r: &mut Rotor, v_dq: Dq) {
        h.update(r.current());
        let v = Dq::new(v_dq.d + h.inject_v(), v_dq.q);
        let (s, c) = crate::trig::sin_cos(h.angle());
        r.step(transforms::inverse_park(v, s, c));
    }

    /// From errors up to 1.2 rad either way the estimate settles on the
    /// rotor's axis (modulo half a turn) within 0.01 rad, inside the
    /// settling time.
    #[test]
    fn the_estimate_settles_on_the_rotors_axis() {
        let c = config();
        for k in 0..24 {
            let theta = k as f32 * 0.26;
            for start in [-1.2f32, -0.5, 0.3, 1.2] {
                let mut h = Hfi::new(c);
                h.place(ElectricalAngle::from_radians(theta - start), 0.0);
                let mut r = Rotor {
                    theta,
                    i_dq: Dq::ZERO,
                    pending: AlphaBeta::new(0.0, 0.0),
                    sat: 0.0,
                };
                for _ in 0..c.settle_periods {
                    period(&mut h, &mut r, Dq::ZERO);
                }
                let e = ElectricalAngle::from_radians(2.0 * theta)
                    .diff_radians(ElectricalAngle::from_radians(2.0 * h.angle().to_radians()));
                assert!(
                    libm::fabsf(e) < 0.02,
                    "theta {theta} start {start}: 2x error {e}"
                );
                assert!(libm::fabsf(h.speed_rad_s()) < 1.0, "{}", h.speed_rad_s());
            }
        }
    }

    /// The polarity test finds the magnet's direction from either half;
    /// on a motor without saturation it cannot tell and says so.
    #[test]
    fn the_polarity_test_finds_the_magnet() {
        let c = config();
        for (off, sat, want) in [
            (0.0, 0.015, PolarityResult::Right),
            (core::f32::consts::PI, 0.015, PolarityResult::Flip),
            (0.1, 0.015, PolarityResult::Right),
            (core::f32::consts::PI - 0.1, 0.015, PolarityResult::Flip),
            (0.0, 0.0, PolarityResult::Unknown),
            (core::f32::consts::PI, 0.0, PolarityResult::Unknown),
        ] {
            let theta = 0.7;
            let mut h = Hfi::new(c);
            h.place(ElectricalAngle::from_radians(theta + off), 0.0);
            let mut r = Rotor {
                theta,
                i_dq: Dq::ZERO,
                pending: AlphaBeta::new(0.0, 0.0),
                sat,
            };
            let mut p = Polarity::default();
            let got = loop {
                // A crude d-current controller in the estimate's frame.
                let (s, co) = crate::trig::sin_cos(h.angle());
                let i = transforms::park(h.mean_current(r.current()), s, co);
                let v = Dq::new(200.0 * (p.current_a(&c) - i.d), 0.0);
                period(&mut h, &mut r, v);
                if let Some(res) = p.step(&c, h.response_a()) {
                    break res;
                }
            };
            let (pos, neg) = p.responses_a();
            assert_eq!(got, want, "offset {off}: +I {pos} -I {neg}");
        }
    }

    /// Too little saliency, or unusable values: no configuration.
    #[test]
    fn round_or_unusable_motors_are_refused() {
        let mut m = motor();
        m.lq_h = m.ld_h * 1.05;
        assert!(HfiConfig::for_motor(&m, TS, 6.0, 3e4, 540.0).is_none());
        assert!(HfiConfig::for_motor(&motor(), f32::NAN, 6.0, 3e4, 540.0).is_none());
        assert!(HfiConfig::for_motor(&motor(), TS, 0.0, 3e4, 540.0).is_none());
        let c = config();
        // 5 % of 6 A per period on 36 mH at 15 kHz: 162 V, held to 20 %
        // of 540 V.
        assert!((c.v_inject_v - 108.0).abs() < 1e-3);
        let low = HfiConfig::for_motor(&motor(), TS, 1.0, 3e4, 540.0).unwrap();
        assert!((low.v_inject_v - 0.05 * 0.036 * 15_000.0).abs() < 1e-3);
        assert!((c.saliency - (1.0 - 36.0 / 51.0)).abs() < 1e-6);
    }

    /// Placed exactly a quarter turn off (where the error reads zero) the
    /// d response tells; turned a quarter, the estimate settles on the
    /// axis.
    #[test]
    fn a_start_on_the_q_axis_is_seen_and_left() {
        let c = config();
        let theta = 0.4;
        let mut h = Hfi::new(c);
        h.place(
            ElectricalAngle::from_radians(theta + core::f32::consts::FRAC_PI_2),
            0.0,
        );
        let mut r = Rotor {
            theta,
            i_dq: Dq::ZERO,
            pending: AlphaBeta::new(0.0, 0.0),
            sat: 0.0,
        };
        // Four periods: a full second difference.
        for _ in 0..4 {
            period(&mut h, &mut r, Dq::ZERO);
        }
        assert!(h.on_q_axis(), "{}", h.response_a());
        // On the d axis it does not read as the q axis.
        let mut d = Hfi::new(c);
        d.place(ElectricalAngle::from_radians(theta), 0.0);
        let mut rd = Rotor {
            theta,
            i_dq: Dq::ZERO,
            pending: AlphaBeta::new(0.0, 0.0),
            sat: 0.0,
        };
        for _ in 0..4 {
            period(&mut d, &mut rd, Dq::ZERO);
        }
        assert!(!d.on_q_axis(), "{}", d.response_a());
        h.turn_quarter();
        for _ in 0..c.settle_periods {
            period(&mut h, &mut r, Dq::ZERO);
        }
        assert!(!h.on_q_axis());
        let e = ElectricalAngle::from_radians(2.0 * theta)
            .diff_radians(ElectricalAngle::from_radians(2.0 * h.angle().to_radians()));
        assert!(libm::fabsf(e) < 0.02, "{e}");
    }

    /// A non-finite sample moves nothing.
    #[test]
    fn a_non_finite_sample_is_ignored() {
        let mut h = Hfi::new(config());
        h.place(ElectricalAngle::from_radians(0.3), 0.0);
        let before = h;
        h.update(AlphaBeta::new(f32::NAN, 0.0));
        assert_eq!(h, before);
    }
}
