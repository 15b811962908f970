//! The unbalance check (design §24): a current channel whose gain is wrong
//! or whose reading carries an offset, found from the voltage the motor
//! model cannot explain, at speed.
//!
//! A healthy drive's model errors (resistance, inductance, flux linkage)
//! are the same on every phase: in the rotor's dq frame the voltage they
//! leave unexplained is steady whenever the current and the speed are. A
//! single channel off is not the same on every phase:
//!
//! - an offset is a constant error in the stationary frame: it rotates at
//!   `-theta` in dq, and the voltage it leaves is `R` times it;
//! - a wrong gain (or a dead channel) reads the current vector through a
//!   matrix that is not a rotation: its unbalanced part (a current of the
//!   negative sequence) rotates at `-2 theta` in dq, and the voltage it
//!   leaves is `|R - j w L|` times it.
//!
//! So the unexplained voltage, turned by `theta` and by `2 theta` and
//! averaged over [`TIME_CONSTANT_S`], keeps those two and averages the
//! balanced part away once the rotor turns enough within the average. The
//! threshold is what a balanced error (at most the disturbance envelope)
//! leaks through the average at this speed, [`TOLERANCE`] of the voltage
//! an unbalanced current would need, and the noise the average keeps.
//!
//! ```
//! use foc_core::control::unbalance::{Unbalance, Limits};
//! use foc_core::frames::Dq;
//! let ts = 50e-6;
//! let mut u = Unbalance::new(ts);
//! let w = 2000.0f32; // rad/s electrical
//! let lim = Limits { envelope_v: 1.0, scale_v: 1.0, innovation_v: Dq::ZERO, start_var_v2: 1.0 };
//! let mut theta = 0.0f32;
//! let mut tripped = false;
//! // A balanced error (1 V, steady in dq): no trip.
//! for _ in 0..20_000 {
//!     theta += w * ts;
//!     let sc = (libm::sinf(theta), libm::cosf(theta));
//!     assert!(!u.update(Dq::new(0.0, 1.0), sc, w, &lim));
//! }
//! // A 2 V error fixed in the stationary frame (an offset's): trips.
//! for _ in 0..20_000 {
//!     theta += w * ts;
//!     let (s, c) = (libm::sinf(theta), libm::cosf(theta));
//!     // (2, 0) in alpha-beta, seen in dq.
//!     tripped |= u.update(Dq::new(2.0 * c, -2.0 * s), (s, c), w, &lim);
//! }
//! assert!(tripped);
//! ```

use crate::frames::Dq;

/// Time constant of the averages \[s\]: the detection takes a few of them.
pub const TIME_CONSTANT_S: f32 = 0.05;

/// Share of the voltage an unbalanced current needs (`(R + w L) |i|`)
/// a healthy motor's own unbalance may leave: its phases' resistances and
/// inductances 10 % apart. (A 0.6 gain on one channel of two reads a
/// negative-sequence current of about 0.23 of the vector.)
pub const TOLERANCE: f32 = 0.1;

/// Consecutive periods over the threshold that trip.
pub const TRIP_PERIODS: u16 = 16;

/// This period's bounds, all \[V\].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Largest balanced (steady in dq) voltage error a healthy drive has:
    /// the disturbance envelope.
    pub envelope_v: f32,
    /// `(R + w L) |i|`: the voltage scale of an unbalance at this
    /// current.
    pub scale_v: f32,
    /// This period's innovation: the part of the unexplained voltage the
    /// disturbance estimate did not already hold (its noise is measured
    /// from it).
    pub innovation_v: Dq,
    /// The innovation's mean square at the start [V^2] (the current
    /// floor's voltage, squared): the measured one starts there.
    pub start_var_v2: f32,
}

/// Run-time state: the two averages and the trip count.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Unbalance {
    gamma: f32,
    ts_s: f32,
    /// Average of the error turned by `theta` (the stationary frame) \[V\].
    z1: Dq,
    /// Average of the error turned by `2 theta` \[V\].
    z2: Dq,
    count: u16,
    /// Mean square of the innovation [V^2] (None: not started).
    var_v2: Option<f32>,
    /// The thresholds, held: each is this period's or the last one's
    /// decayed at the averages' own rate, whichever is larger (an average
    /// forgets a slow period's balanced error only at that rate) \[V\].
    th: (f32, f32),
    /// Largest `|z| / threshold` seen, squared.
    peak_sq: f32,
}

impl Unbalance {
    /// For a control period of `ts_s` \[s\].
    pub fn new(ts_s: f32) -> Self {
        let g = ts_s / TIME_CONSTANT_S;
        Self {
            gamma: if g.is_finite() && g > 0.0 && g < 1.0 {
                g
            } else {
                0.0
            },
            ts_s,
            ..Self::default()
        }
    }

    /// Forget the averages (the model's history was reset).
    pub fn reset(&mut self) {
        *self = Self {
            peak_sq: self.peak_sq,
            ..Self::new(self.ts_s)
        };
    }

    /// Largest `|average| / threshold` seen (the margin).
    pub fn peak_ratio(&self) -> f32 {
        crate::sqrtf(self.peak_sq)
    }

    /// Carry or forget the margin (see [`Self::peak_ratio`]).
    pub fn set_peak_sq(&mut self, peak_sq: f32) {
        self.peak_sq = peak_sq;
    }

    /// The margin, squared.
    pub fn peak_sq(&self) -> f32 {
        self.peak_sq
    }

    /// The averages after this period's unexplained voltage `m` (dq frame
    /// of the angle whose `(sin, cos)` is `sin_cos`) at the electrical
    /// speed `w_rad_s`; true when an average has stood over its threshold
    /// for [`TRIP_PERIODS`] periods.
    /// `w_rad_s` is the speed with its uncertainty taken off (the
    /// smallest it may be), as the leak grows when the rotor turns less.
    #[inline(always)]
    pub fn update(&mut self, m: Dq, sin_cos: (f32, f32), w_rad_s: f32, lim: &Limits) -> bool {
        if self.gamma <= 0.0 {
            return false;
        }
        let (s, c) = sin_cos;
        let g = self.gamma;
        let n = lim.innovation_v;
        let var = self.var_v2.unwrap_or(lim.start_var_v2);
        let var = var + g * (n.d * n.d + n.q * n.q - var);
        self.var_v2 = Some(if var.is_finite() {
            var
        } else {
            lim.start_var_v2
        });
        // Three standard deviations of what an average of white noise of
        // that mean square keeps (gamma / 2 of it).
        let noise_v = 3.0 * crate::sqrtf(0.5 * g * var);
        let m1 = Dq::new(m.d * c - m.q * s, m.d * s + m.q * c);
        let (c2, s2) = (c * c - s * s, 2.0 * s * c);
        let m2 = Dq::new(m.d * c2 - m.q * s2, m.d * s2 + m.q * c2);
        self.z1 = Dq::new(
            self.z1.d + g * (m1.d - self.z1.d),
            self.z1.q + g * (m1.q - self.z1.q),
        );
        self.z2 = Dq::new(
            self.z2.d + g * (m2.d - self.z2.d),
            self.z2.q + g * (m2.q - self.z2.q),
        );
        // What a balanced error leaks: an average with gain g of a phasor
        // turning x per period keeps g / |1 - (1 - g) e^(-jx)| of it, at
        // least g / (2 |sin(x / 2)|) ([`chords`]).
        let turn = w_rad_s.abs() * self.ts_s;
        let leak = |c: f32| {
            if c > g {
                lim.envelope_v * g / c
            } else {
                lim.envelope_v
            }
        };
        let (chord1, chord2) = chords(turn);
        let (leak1, leak2) = (leak(chord1), leak(chord2));
        let keep = 1.0 - g;
        let th1 = max(leak1 + TOLERANCE * lim.scale_v + noise_v, keep * self.th.0);
        let th2 = max(leak2 + TOLERANCE * lim.scale_v + noise_v, keep * self.th.1);
        self.th = (th1, th2);
        let r1 = (self.z1.d * self.z1.d + self.z1.q * self.z1.q) / (th1 * th1);
        let r2 = (self.z2.d * self.z2.d + self.z2.q * self.z2.q) / (th2 * th2);
        let r = if r1 > r2 { r1 } else { r2 };
        if r > self.peak_sq || r.is_nan() {
            self.peak_sq = r;
        }
        self.count = if r > 1.0 || r.is_nan() {
            self.count.saturating_add(1)
        } else {
            0
        };
        self.count >= TRIP_PERIODS
    }
}

/// `(2 |sin(x / 2)|, 2 |sin x|)` for `x >= 0`: the chords of a turn by
/// `x` and by `2 x` (one sine and cosine: `sin x = 2 sin(x/2) cos(x/2)`),
/// zero where the turn is a whole number of turns (a phasor that turns by
/// exactly a turn each period is not averaged away).
#[inline(always)]
fn chords(x: f32) -> (f32, f32) {
    let half = crate::angle::ElectricalAngle::from_radians(0.5 * x);
    let (s, c) = crate::trig::sin_cos(half);
    (2.0 * s.abs(), 4.0 * (s * c).abs())
}

#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}
