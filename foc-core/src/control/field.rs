//! The d-current reference (design §30): maximum torque per ampere (MTPA)
//! on a salient rotor, and field weakening above base speed as a closed
//! loop on the voltage margin.
//!
//! ```text
//! torque  T = 1.5 p iq (psi - dL id),   dL = Lq - Ld
//! asked   iq_t = T / kt (every mode's q current: the torque at id = 0)
//! MTPA    id = (psi - sqrt(psi^2 + 4 dL^2 iq^2)) / (2 dL)
//!            = -2 dL iq^2 / (psi + sqrt(psi^2 + 4 dL^2 iq^2))   (the form used: no cancellation)
//! voltage |v| ~ w_e sqrt((psi + Ld id)^2 + (Lq iq)^2)   (R neglected)
//! FW      id_ff = (sqrt((v_t / w_e)^2 - (Lq iq)^2) - psi) / Ld, at most 0
//!         id_fb += k (v_t - |v_dq|),  k = bw Ts / (Ld |w_e|)    (loop gain bw)
//!         id_fw = clamp(id_ff + id_fb, -max_id, 0)      (id_fb taken back to fit)
//! id      = max(min(id_mtpa, id_fw), -max_id)
//! iq      = iq_t / (1 - dL id / psi), within sqrt(I_max^2 - id^2)   (the d axis first)
//!         and, weakening, within the steady-state voltage ellipse at id = -max_id
//! ```
//!
//! - MTPA follows the torque-per-ampere ridge from the identified `Ld`,
//!   `Lq` and `psi` (the Lagrange condition of `T` on a current circle).
//!   It is on by default where `Lq` exceeds `Ld` by more than
//!   [`MTPA_SALIENCY_MARGIN`]; below it the gain is under a fraction of a
//!   per cent at the current limit and the square root not worth a period.
//!   The modes' limit is on the asked `iq_t`: at the limit MTPA gives the
//!   torque of `id = 0` at the current limit with less current (design
//!   §30).
//!   The q current is capped at the MTPA point on the current circle
//!   before `id` is taken from it, so the pair never leaves the circle.
//! - Field weakening holds the current loop's voltage (its last output,
//!   which already includes every resistive and inductive drop the model
//!   misses) at `v_t = (1 - voltage_margin) m_max V_bus / sqrt(3)`. The
//!   feed-forward is the steady-state ellipse; the integrator corrects the
//!   model (saturation, resistance) with a loop bandwidth `bw` independent
//!   of speed (the plant gain `d|v| / d id ~ w_e Ld` is divided out). Both
//!   are bounded by the configured `max_id_a` (demagnetisation) and the
//!   current circle; the integrator is taken back whenever the sum is
//!   clipped (no wind-up). Below base speed the feed-forward is 0 and the
//!   integrator rises back to it. The output is slew-limited: it rises
//!   (leaves field weakening) by at most `margin v_max Ts / Ld` per period,
//!   the d voltage the margin leaves, and deepens at most
//!   [`DEEPEN_RATE`] times as fast, so the d axis, served first, never
//!   takes from the q axis the voltage that holds the back-EMF.
//! - Switching field weakening off takes effect once its d current has
//!   returned to 0 (below base speed); until then it runs as before: at a
//!   speed that still needs it, removing it would lose current control to
//!   the back-EMF (the runaway braking peers report).
//!
//! ```
//! use foc_core::control::field::{Field, FieldConfig};
//! use foc_core::control::MotorParams;
//! use foc_core::frames::Dq;
//! // The 2.2 kW interior-PM motor: MTPA gives a negative d current.
//! let m = MotorParams { pole_pairs: 3, r_ohm: 3.6, ld_h: 0.036, lq_h: 0.051, flux_linkage_wb: 0.545 };
//! let mut f = Field::new(FieldConfig::for_motor(&m, 18.2, 15_000.0), &m, 18.2, 15_000.0, 0.95);
//! let i = f.reference(10.0, 0.0, 540.0, Dq::ZERO);
//! // The same torque with less q current: the reluctance torque helps.
//! assert!(i.d < -1.0 && i.q < 10.0);
//! ```

use super::MotorParams;
use crate::frames::Dq;
use crate::{clamp, sqrtf, FRAC_1_SQRT_3};

/// MTPA is on by default when `(Lq - Ld) / Ld` exceeds this (5 %).
pub const MTPA_SALIENCY_MARGIN: f32 = 0.05;

/// How many times faster than it may rise the weakening d current may
/// deepen (a bus that sags, an acceleration past base speed).
pub const DEEPEN_RATE: f32 = 4.0;

/// Per period on the voltage circle while weakening, the q range's share
/// shrinks by this (and grows back ten times slower).
pub const Q_SHARE_STEP: f32 = 0.01;

/// The q range shrinks only after this many periods in a row on the
/// circle (a weakening that catches up with an acceleration stands there
/// for a few; a q reference the voltage cannot hold, for good).
pub const Q_SHARE_AFTER_PERIODS: u16 = 30;

/// The least share of the q range.
pub const Q_SHARE_MIN: f32 = 0.2;

/// Default largest weakening `|id|` as a share of the characteristic
/// current `psi / Ld`: a motor whose inductance is 30 % above the model
/// (the tolerance the sensor supervision allows) has its characteristic
/// current at 0.77 of the model's; beyond it the flux reverses and the
/// loop loses the motor (interior-PM file, Ld +30 %: from 340 to 477 rad/s
/// uncommanded before `SpeedRunaway` tripped, with the whole `psi / Ld`).
pub const MAX_ID_SHARE: f32 = 0.75;

/// Field weakening deepens only above this share of the no-load base
/// speed (`w_e psi > share v_t`): below it a voltage shortfall is the
/// winding's resistance (GL80 with its winding at 120 deg C: the loop
/// took id to its limit at 0.7 x base and the drive faulted).
pub const FW_ENTRY_SHARE: f32 = 0.8;

/// The least voltage margin field weakening accepts (2 %): the margin's
/// d voltage is also the rate its d current may rise at.
pub const MIN_VOLTAGE_MARGIN: f32 = 0.02;

/// Default share of the voltage circle field weakening keeps free for
/// the current loop's dynamics (5 %).
pub const DEFAULT_VOLTAGE_MARGIN: f32 = 0.05;

/// Default field-weakening loop bandwidth, as a fraction of the PWM
/// frequency in rad/s (a thirtieth: about a tenth of the current loop's).
pub const DEFAULT_BANDWIDTH_PER_PWM_HZ: f32 = 1.0 / 30.0;

/// The d-current reference's configuration (stored with the drive's).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FieldConfig {
    /// Maximum torque per ampere from `Ld`, `Lq` and `psi` (salient rotors).
    pub mtpa: bool,
    /// Field weakening above base speed (closed loop on the voltage margin).
    pub field_weakening: bool,
    /// Largest `|id|` field weakening may use \[A\] (the magnets'
    /// demagnetisation limit; at most the current limit is used).
    pub max_id_a: f32,
    /// Share of the voltage circle field weakening keeps free (0..0.5).
    pub voltage_margin: f32,
    /// Field-weakening loop bandwidth \[rad/s\].
    pub bandwidth_rad_s: f32,
    /// Safe state chosen by speed (design §30): above the speed where the
    /// back-EMF's line-to-line peak exceeds the bus, the bridge's three
    /// low sides are switched on instead of freewheeling.
    pub short_circuit: bool,
}

impl FieldConfig {
    /// Everything off: `id = 0`, freewheeling safe state.
    pub const OFF: Self = Self {
        mtpa: false,
        field_weakening: false,
        max_id_a: 0.0,
        voltage_margin: DEFAULT_VOLTAGE_MARGIN,
        bandwidth_rad_s: 0.0,
        short_circuit: false,
    };

    /// Defaults for a motor: MTPA where [`is_salient`], field weakening
    /// off (the user turns it on), `max_id_a` the smaller of the current
    /// limit and [`MAX_ID_SHARE`] of the characteristic current `psi / Ld`
    /// (beyond which the magnet's flux is reversed), the short circuit where
    /// its steady current `psi / Ld` is within the current limit.
    pub fn for_motor(m: &MotorParams, max_current_a: f32, pwm_frequency_hz: f32) -> Self {
        let ch = characteristic_current_a(m);
        Self {
            mtpa: is_salient(m),
            field_weakening: false,
            max_id_a: if MAX_ID_SHARE * ch < max_current_a {
                MAX_ID_SHARE * ch
            } else {
                max_current_a
            },
            voltage_margin: DEFAULT_VOLTAGE_MARGIN,
            bandwidth_rad_s: DEFAULT_BANDWIDTH_PER_PWM_HZ * pwm_frequency_hz,
            short_circuit: ch.is_finite() && ch <= max_current_a,
        }
    }

    /// Why this configuration is unusable, if it is.
    pub fn check(&self) -> Result<(), &'static str> {
        if !(self.max_id_a >= 0.0 && self.max_id_a < 1.0e6) {
            return Err("max_id_a must be a finite current >= 0");
        }
        if !(0.0..=0.5).contains(&self.voltage_margin) {
            return Err("voltage_margin must be within 0 .. 0.5");
        }
        if !(self.bandwidth_rad_s >= 0.0 && self.bandwidth_rad_s < 1.0e6) {
            return Err("bandwidth_rad_s must be finite and >= 0");
        }
        if self.field_weakening && !(self.max_id_a > 0.0 && self.bandwidth_rad_s > 0.0) {
            return Err("field weakening needs max_id_a > 0 and bandwidth_rad_s > 0");
        }
        if self.field_weakening && self.voltage_margin < MIN_VOLTAGE_MARGIN {
            // The margin is also the d current's slew: 0 would hold it at 0.
            return Err("field weakening needs voltage_margin >= 0.02");
        }
        Ok(())
    }
}

/// `(Lq - Ld) / Ld` above [`MTPA_SALIENCY_MARGIN`].
pub fn is_salient(m: &MotorParams) -> bool {
    m.ld_h > 0.0 && m.lq_h - m.ld_h > MTPA_SALIENCY_MARGIN * m.ld_h
}

/// The characteristic current `psi / Ld` \[A\] (infinite without `Ld`): the
/// d current that cancels the magnet's flux, and the short circuit's
/// steady current at high speed.
pub fn characteristic_current_a(m: &MotorParams) -> f32 {
    if m.ld_h > 0.0 && m.flux_linkage_wb >= 0.0 {
        m.flux_linkage_wb / m.ld_h
    } else {
        f32::INFINITY
    }
}

/// The constants [`Field::new`] derives stay finite (an absurd motor, e.g.
/// `Lq = 3e38 H`, made MTPA's d current NaN).
fn derived_finite(c: &FieldConfig, m: &MotorParams, max_current_a: f32, pwm_hz: f32) -> bool {
    let dl = m.lq_h - m.ld_h;
    let mtpa = 8.0 * dl * dl * max_current_a * max_current_a + m.flux_linkage_wb;
    let gain = c.bandwidth_rad_s / (pwm_hz * m.ld_h);
    let rise = c.voltage_margin / (pwm_hz * m.ld_h);
    let reluctance = dl / m.flux_linkage_wb;
    let flux = m.lq_h * max_current_a + m.ld_h * max_current_a;
    [mtpa, gain, rise, reluctance, flux, m.r_ohm, pwm_hz]
        .iter()
        .all(|x| x.is_finite())
}

/// The MTPA d current for a q current (0 when `dl_h <= 0`).
#[inline(always)]
pub fn mtpa_id_a(psi_wb: f32, dl_h: f32, iq_a: f32) -> f32 {
    if dl_h <= 0.0 {
        return 0.0;
    }
    let k = 2.0 * dl_h * iq_a;
    -dl_h * 2.0 * iq_a * iq_a / (psi_wb + sqrtf(psi_wb * psi_wb + k * k))
}

/// Constants of the d-current reference, derived once per configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Plan {
    /// `Lq - Ld` when MTPA is on, else 0 \[H\].
    mtpa_dl_h: f32,
    /// The q current of the MTPA point on the current circle \[A\].
    mtpa_iq_max_a: f32,
    psi_wb: f32,
    ld_h: f32,
    lq_h: f32,
    r_ohm: f32,
    /// `min(max_id_a, I_max)` \[A\].
    max_id_a: f32,
    /// `I_max^2` \[A^2\].
    imax_sq: f32,
    /// `bw Ts / Ld` [A / (V rad/s)].
    fw_gain: f32,
    /// `(1 - margin) m_max / sqrt(3)`: the target voltage per bus volt.
    target_per_bus: f32,
    /// The lowest `|w_e|` the integrator's gain is scaled for (half the
    /// no-load base speed at the nominal... per bus volt) [rad/s / V].
    w_floor_per_bus: f32,
    /// The largest rise of the weakening d current per period per bus
    /// volt \[A/V\]: `margin v_max Ts / Ld` (leaving field weakening
    /// takes at most the voltage margin, so the q axis keeps the voltage
    /// that holds the back-EMF); it may deepen [`DEEPEN_RATE`] times as fast.
    rise_per_bus: f32,
    /// `1 / (1 - margin)`: the current loop's circle over the target.
    circle_per_target: f32,
    field_weakening: bool,
    short_circuit: bool,
    /// `1 / (sqrt(3) psi)`: the electrical speed per bus volt above which
    /// the back-EMF's line-to-line peak exceeds the bus.
    rectify_w_per_bus: f32,
    /// `(Ld - Lq) / psi` [1/A]: the reluctance torque's share per d ampere.
    reluctance_per_a: f32,
}

/// The d-current reference: its configuration, constants and the
/// field-weakening integrator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Field {
    config: FieldConfig,
    plan: Plan,
    /// The integrator \[A\].
    id_fb_a: f32,
    /// The field-weakening d current of the last period \[A\] (`<= 0`).
    id_fw_a: f32,
    /// The share of the voltage ellipse's q range in force (0.2 ..= 1):
    /// shrinks while the current loop's output stands on its circle, for
    /// a motor whose inductances are above the model's (its ellipse is
    /// smaller than the one computed).
    q_share: f32,
    /// Periods in a row the current loop's output stood on its circle.
    circle_periods: u16,
}

impl Field {
    /// For `config` on motor `m`, current limit `max_current_a`, PWM
    /// frequency and the current loop's `max_modulation`. An unusable
    /// configuration ([`FieldConfig::check`]) or motor gives [`FieldConfig::OFF`].
    pub fn new(
        config: FieldConfig,
        m: &MotorParams,
        max_current_a: f32,
        pwm_frequency_hz: f32,
        max_modulation: f32,
    ) -> Self {
        let usable = config.check().is_ok()
            && m.ld_h > 0.0
            && m.lq_h > 0.0
            && m.flux_linkage_wb > 0.0
            && m.flux_linkage_wb.is_finite()
            && max_current_a >= 0.0
            && max_current_a.is_finite()
            && pwm_frequency_hz > 0.0
            && derived_finite(&config, m, max_current_a, pwm_frequency_hz);
        let config = if usable { config } else { FieldConfig::OFF };
        let psi = m.flux_linkage_wb;
        let dl = if config.mtpa && is_salient(m) {
            m.lq_h - m.ld_h
        } else {
            0.0
        };
        // The MTPA point at |i| = I_max (the |i| form of the condition).
        let imax = max_current_a;
        let id_at_max = if dl > 0.0 {
            (psi - sqrtf(psi * psi + 8.0 * dl * dl * imax * imax)) / (4.0 * dl)
        } else {
            0.0
        };
        let iq_max_sq = imax * imax - id_at_max * id_at_max;
        let max_id = if config.max_id_a < imax {
            config.max_id_a
        } else {
            imax
        };
        let target_per_bus = (1.0 - config.voltage_margin) * max_modulation * FRAC_1_SQRT_3;
        Self {
            config,
            plan: Plan {
                mtpa_dl_h: dl,
                mtpa_iq_max_a: if iq_max_sq > 0.0 {
                    sqrtf(iq_max_sq)
                } else {
                    0.0
                },
                psi_wb: psi,
                ld_h: m.ld_h,
                lq_h: m.lq_h,
                r_ohm: if m.r_ohm > 0.0 { m.r_ohm } else { 0.0 },
                max_id_a: max_id,
                imax_sq: imax * imax,
                fw_gain: if usable {
                    config.bandwidth_rad_s / (pwm_frequency_hz * m.ld_h)
                } else {
                    0.0
                },
                target_per_bus,
                w_floor_per_bus: 0.5 * target_per_bus / psi,
                circle_per_target: 1.0 / (1.0 - config.voltage_margin),
                rise_per_bus: if usable {
                    config.voltage_margin * max_modulation * FRAC_1_SQRT_3
                        / (pwm_frequency_hz * m.ld_h)
                } else {
                    0.0
                },
                field_weakening: config.field_weakening && max_id > 0.0,
                short_circuit: config.short_circuit,
                rectify_w_per_bus: FRAC_1_SQRT_3 / psi,
                reluctance_per_a: if usable { (m.ld_h - m.lq_h) / psi } else { 0.0 },
            },
            id_fb_a: 0.0,
            id_fw_a: 0.0,
            q_share: 1.0,
            circle_periods: 0,
        }
    }

    /// The configuration in force (`OFF` if the one given was unusable).
    pub fn config(&self) -> &FieldConfig {
        &self.config
    }

    /// The short circuit is the safe state above its speed.
    #[inline]
    pub fn short_circuit(&self) -> bool {
        self.plan.short_circuit
    }

    /// The no-load base speed at bus `v_bus_v` [rad/s, electrical]: where
    /// the back-EMF `w_e psi` meets the voltage target (infinite without
    /// a flux linkage).
    #[inline]
    pub fn base_speed_e_rad_s(&self, v_bus_v: f32) -> f32 {
        if self.plan.psi_wb > 0.0 {
            self.plan.target_per_bus * v_bus_v / self.plan.psi_wb
        } else {
            f32::INFINITY
        }
    }

    /// The electrical speed \[rad/s\] above which the back-EMF's
    /// line-to-line peak `sqrt(3) w_e psi` exceeds the bus `v_bus_v`: the
    /// freewheel diodes rectify into the bus above it.
    #[inline]
    pub fn rectifying_speed_rad_s(&self, v_bus_v: f32) -> f32 {
        self.plan.rectify_w_per_bus * v_bus_v
    }

    /// The q current that gives the torque of `i_dq_a` with `id = 0`:
    /// `iq (1 + (Ld - Lq) id / psi)` \[A\] (the reluctance torque of a
    /// salient rotor counted in): what the torque-fed speed observer takes.
    #[inline(always)]
    pub fn torque_iq_a(&self, i_dq_a: Dq) -> f32 {
        i_dq_a.q * (1.0 + self.plan.reluctance_per_a * i_dq_a.d)
    }

    /// Nothing to compute: `id = 0` and no integrator running.
    #[inline(always)]
    pub fn is_idle(&self) -> bool {
        self.plan.mtpa_dl_h == 0.0 && !self.plan.field_weakening && self.id_fw_a == 0.0
    }

    /// Carry the field-weakening integrator of `old` over (a changed
    /// configuration at speed).
    pub fn keep_integrator(&mut self, old: &Field) {
        self.id_fb_a = old.id_fb_a;
        self.id_fw_a = old.id_fw_a;
        self.q_share = old.q_share;
        self.circle_periods = old.circle_periods;
    }

    /// Forget the integrator (bridge off).
    pub fn reset(&mut self) {
        self.id_fb_a = 0.0;
        self.id_fw_a = 0.0;
        self.q_share = 1.0;
        self.circle_periods = 0;
    }

    /// The field-weakening d current of the last period \[A\] (`<= 0`).
    pub fn weakening_id_a(&self) -> f32 {
        self.id_fw_a
    }

    /// The highest mechanical speed the model reaches at bus `v_bus_v`
    /// with no torque \[rad/s\]: with field weakening the voltage
    /// target less the resistive drop of `max_id`, over the flux left,
    /// `sqrt(v_t^2 - (R max_id)^2) / (psi - Ld max_id) / p` (infinite when
    /// `max_id` reaches the characteristic current); `v_t / psi / p`
    /// without.
    pub fn max_speed_rad_s(&self, v_bus_v: f32, pole_pairs: u8) -> f32 {
        let p = &self.plan;
        let id = if p.field_weakening { p.max_id_a } else { 0.0 };
        let flux = p.psi_wb - p.ld_h * id;
        let v_t = p.target_per_bus * v_bus_v;
        let v2 = v_t * v_t - (p.r_ohm * id) * (p.r_ohm * id);
        if pole_pairs == 0 || v2 <= 0.0 {
            return 0.0;
        }
        if flux <= 0.0 {
            return f32::INFINITY;
        }
        sqrtf(v2) / flux / pole_pairs as f32
    }

    /// This period's current reference for the torque asked, given as
    /// the q current `iq_a` that gives it with `id = 0` (`T / kt`, what
    /// every mode and the speed loop compute), at electrical speed
    /// `w_e_rad_s`, bus `v_bus_v`, with the current loop's last output
    /// `v_dq_last_v`: the d current (MTPA, field weakening), and the q
    /// current that gives that torque with it (`iq / (1 + (Ld - Lq) id /
    /// psi)`, the reluctance torque counted in), within the current circle.
    #[inline(always)]
    pub fn reference(&mut self, iq_a: f32, w_e_rad_s: f32, v_bus_v: f32, v_dq_last_v: Dq) -> Dq {
        let p = self.plan;
        let id_mtpa = if p.mtpa_dl_h > 0.0 {
            // The MTPA point for this torque: one refinement of the q
            // current from the first guess `iq = iq_a`.
            let iq0 = clamp(iq_a, -p.mtpa_iq_max_a, p.mtpa_iq_max_a);
            let id0 = mtpa_id_a(p.psi_wb, p.mtpa_dl_h, iq0);
            let iq1 = clamp(self.q_for(iq_a, id0), -p.mtpa_iq_max_a, p.mtpa_iq_max_a);
            mtpa_id_a(p.psi_wb, p.mtpa_dl_h, iq1)
        } else {
            0.0
        };
        let id_fw = if p.field_weakening || self.id_fw_a < 0.0 {
            self.weaken(iq_a, w_e_rad_s, v_bus_v, v_dq_last_v)
        } else {
            0.0
        };
        let mut id = if id_fw < id_mtpa { id_fw } else { id_mtpa };
        if id < -p.max_id_a && id_mtpa >= -p.max_id_a {
            id = -p.max_id_a;
        }
        let iq = self.q_for(iq_a, id);
        let room = p.imax_sq - id * id;
        let iq_lim = if room > 0.0 { sqrtf(room) } else { 0.0 };
        let (mut lo, mut hi) = (-iq_lim, iq_lim);
        if id_fw < 0.0 {
            let (v_lo, v_hi) = self.voltage_q_range_a(w_e_rad_s, v_bus_v);
            let (v_lo, v_hi) = (v_lo * self.q_share, v_hi * self.q_share);
            lo = if v_lo > lo { v_lo } else { lo };
            hi = if v_hi < hi { v_hi } else { hi };
            if lo > hi {
                // No q current satisfies both: none.
                lo = 0.0;
                hi = 0.0;
            }
        }
        if id.is_finite() {
            Dq::new(id, clamp(iq, lo, hi))
        } else {
            Dq::new(0.0, clamp(iq_a, -iq_lim, iq_lim))
        }
    }

    /// Field weakening: the q currents the voltage allows in steady state
    /// at `w_e_rad_s` with the deepest weakening `id = -max_id` \[A\]: the
    /// roots of `(R id - w Lq iq)^2 + (R iq + w (psi + Ld id))^2 = v_t^2`.
    /// The q current's own voltage `w Lq iq` falls on the d axis, which
    /// the current loop serves first: a q reference beyond it (the speed
    /// loop asking for 10 A of braking at twice base speed on the
    /// interior-PM motor, where at most 5.7 A fit) saturated the d axis,
    /// left the q axis no voltage, and the current it no longer controlled
    /// kept motoring. Taken at the deepest weakening, the range never
    /// stops the loop deepening (the reference may lead it). Beyond the
    /// top speed it is empty, or (with `R > 0`) excludes 0 on the braking
    /// side; where it does not meet the current circle the q reference
    /// is 0.
    #[inline(always)]
    fn voltage_q_range_a(&self, w_e_rad_s: f32, v_bus_v: f32) -> (f32, f32) {
        let p = &self.plan;
        let w = w_e_rad_s.abs();
        let v = p.target_per_bus * v_bus_v;
        let id = -p.max_id_a;
        let (r, wl) = (p.r_ohm, w * p.lq_h);
        let e = w * (p.psi_wb + p.ld_h * id);
        // a iq^2 + b iq + c = 0
        let a = wl * wl + r * r;
        let b = 2.0 * r * (e - id * wl);
        let c = r * r * id * id + e * e - v * v;
        let disc = b * b - 4.0 * a * c;
        if !(a > 0.0 && disc > 0.0) {
            return (0.0, 0.0);
        }
        let root = sqrtf(disc);
        let inv = 0.5 / a;
        // The sign of the speed turns the range over.
        let (lo, hi) = ((-b - root) * inv, (-b + root) * inv);
        if w_e_rad_s >= 0.0 {
            (lo, hi)
        } else {
            (-hi, -lo)
        }
    }

    /// The q current that gives the torque of `iq_a` at `id = 0` with
    /// the d current `id_a` (the reluctance share at most halves it).
    #[inline(always)]
    fn q_for(&self, iq_a: f32, id_a: f32) -> f32 {
        let k = 1.0 + self.plan.reluctance_per_a * id_a;
        iq_a / if k > 0.5 { k } else { 0.5 }
    }

    /// The field-weakening loop's d current (module docs).
    #[inline(always)]
    fn weaken(&mut self, iq_a: f32, w_e_rad_s: f32, v_bus_v: f32, v_last: Dq) -> f32 {
        let p = self.plan;
        let v_t = p.target_per_bus * v_bus_v;
        let w = w_e_rad_s.abs();
        // Feed-forward: the steady-state ellipse at this speed.
        let psi_q = p.lq_h * iq_a;
        let mut id_ff = 0.0;
        if w * p.psi_wb > v_t {
            let psi_max = v_t / w;
            let d2 = psi_max * psi_max - psi_q * psi_q;
            let psi_d = if d2 > 0.0 { sqrtf(d2) } else { 0.0 };
            if psi_d < p.psi_wb {
                id_ff = (psi_d - p.psi_wb) / p.ld_h;
            }
        }
        // Feedback on the voltage the current loop really asked for.
        let v = sqrtf(v_last.d * v_last.d + v_last.q * v_last.q);
        let v_out = v;
        // On the circle (the current loop limited): less q current.
        let circle = p.target_per_bus * v_bus_v * p.circle_per_target;
        self.circle_periods = if v_out >= 0.999 * circle {
            self.circle_periods.saturating_add(1)
        } else {
            0
        };
        self.q_share = if self.circle_periods > Q_SHARE_AFTER_PERIODS {
            let s = self.q_share - Q_SHARE_STEP;
            if s > Q_SHARE_MIN {
                s
            } else {
                Q_SHARE_MIN
            }
        } else {
            let s = self.q_share + 0.1 * Q_SHARE_STEP;
            if s < 1.0 {
                s
            } else {
                1.0
            }
        };
        let w_floor = p.w_floor_per_bus * v_bus_v;
        let w_gain = if w > w_floor { w } else { w_floor };
        let step = if w_gain > 0.0 {
            p.fw_gain * (v_t - v) / w_gain
        } else {
            0.0
        };
        // Switched off, it keeps running both ways until its output is
        // back at 0 (below base speed): a ratchet that only let it rise
        // would creep, on noise, to where the voltage runs out.
        let lo = -p.max_id_a;
        // Below FW_ENTRY_SHARE of base speed the voltage a loop finds short
        // is the resistance's (a hot winding at full current), which a d
        // current only adds to: it may return to 0, not deepen.
        // Deepening must lower the voltage: `d|v|^2 / d id = 2 (R v_d +
        // w Ld v_q)` > 0. Where the resistance's drop dominates (a hot,
        // resistive winding: GL80 at 120 deg C) a deeper d current only
        // adds to it; counted anyway it kept the d current at its limit,
        // the d axis on the whole circle, the q axis starved, the rotor
        // braked to rest.
        // (`|w Ld v_q|`: through a reversal's hard braking the resistive
        // share of v_q can turn its sign; the signed test then stopped
        // the weakening and the interior-PM reversal peaked at 21.4 A
        // against 18.2 A.)
        let lowers = p.r_ohm * v_last.d + w_e_rad_s.abs() * p.ld_h * v_last.q.abs() > 0.0;
        let lo = if lowers && w * p.psi_wb > FW_ENTRY_SHARE * v_t {
            lo
        } else if self.id_fw_a < 0.0 {
            self.id_fw_a
        } else {
            0.0
        };
        let raw = id_ff + self.id_fb_a + step;
        // Slew-limited: a d current that rises at once takes the whole
        // voltage circle (the d axis first) from the q axis, whose voltage
        // holds the back-EMF; the current lost brakes the rotor and pumps
        // the bus (M153 on a non-sinking link: 26 -> 52 V from a 0.05 V
        // rise of the bus before this limit).
        let rise = p.rise_per_bus * v_bus_v;
        let (down, up) = (self.id_fw_a - DEEPEN_RATE * rise, self.id_fw_a + rise);
        let lo = if lo > down { lo } else { down };
        let id_fw = if raw.is_finite() {
            clamp(clamp(raw, lo, up), -p.max_id_a, 0.0)
        } else {
            0.0
        };
        // Taken back to the output (bounds and slew): no wind-up; after a
        // jump of the feed-forward the integrator carries the rest.
        self.id_fb_a = id_fw - id_ff;
        self.id_fw_a = id_fw;
        id_fw
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ipm() -> MotorParams {
        MotorParams {
            pole_pairs: 3,
            r_ohm: 3.6,
            ld_h: 0.036,
            lq_h: 0.051,
            flux_linkage_wb: 0.545,
        }
    }

    fn torque(m: &MotorParams, i: Dq) -> f32 {
        1.5 * m.pole_pairs as f32 * i.q * (m.flux_linkage_wb + (m.ld_h - m.lq_h) * i.d)
    }

    #[test]
    fn mtpa_is_the_torque_per_amp_ridge() {
        let m = ipm();
        let dl = m.lq_h - m.ld_h;
        for iq in [1.0f32, 5.0, 10.0, 15.0] {
            let id = mtpa_id_a(m.flux_linkage_wb, dl, iq);
            let mag = sqrtf(id * id + iq * iq);
            let t = torque(&m, Dq::new(id, iq));
            // Any other split of the same |i| gives less torque.
            for k in 1..40 {
                let beta = k as f32 * 0.02;
                let other = Dq::new(-mag * libm::sinf(beta), mag * libm::cosf(beta));
                assert!(torque(&m, other) <= t * 1.000_01, "iq {iq} beta {beta}");
            }
        }
    }

    #[test]
    fn the_reference_stays_in_the_current_circle() {
        let m = ipm();
        let mut c = FieldConfig::for_motor(&m, 18.2, 15_000.0);
        c.field_weakening = true;
        c.mtpa = true;
        let mut f = Field::new(c, &m, 18.2, 15_000.0, 0.95);
        for iq in [-40.0f32, -18.2, 0.0, 12.0, 18.2, 40.0] {
            for _ in 0..100 {
                let i = f.reference(iq, 3000.0, 540.0, Dq::new(0.0, 400.0));
                assert!(i.d * i.d + i.q * i.q <= 18.2 * 18.2 * 1.0001, "{i:?}");
                assert!(i.d >= -18.2 && i.d <= 0.0);
            }
        }
    }

    #[test]
    fn weakening_is_off_below_base_speed_and_returns_to_zero() {
        let m = ipm();
        let mut c = FieldConfig::for_motor(&m, 18.2, 15_000.0);
        c.field_weakening = true;
        c.mtpa = false;
        let mut f = Field::new(c, &m, 18.2, 15_000.0, 0.95);
        // Well below base speed, a small voltage: no d current.
        let i = f.reference(5.0, 100.0, 540.0, Dq::new(10.0, 60.0));
        assert_eq!(i.d, 0.0);
        // At twice base speed the feed-forward weakens, at its slew rate
        // (`DEEPEN_RATE` times the rise: 0.43 A per period here).
        let step = DEEPEN_RATE * f.plan.rise_per_bus * 540.0;
        let i = f.reference(5.0, 1100.0, 540.0, Dq::new(0.0, 280.0));
        assert!((i.d + step).abs() < 1e-4, "{i:?} {step}");
        // Then the integrator carries on while the voltage is over the
        // target (the current loop's output at the circle).
        for _ in 0..2000 {
            f.reference(5.0, 1100.0, 540.0, Dq::new(0.0, 310.0));
        }
        assert!(f.weakening_id_a() < -5.0, "{f:?}");
        // Switched off at speed, it holds until the voltage allows.
        c.field_weakening = false;
        let before = f.weakening_id_a();
        let mut g = Field::new(c, &m, 18.2, 15_000.0, 0.95);
        g.keep_integrator(&f);
        let i = g.reference(5.0, 1100.0, 540.0, Dq::new(0.0, 290.0));
        assert!(i.d <= before * 0.99, "{i:?} {before}");
        // Back at low speed with voltage to spare it rises to 0.
        for _ in 0..20_000 {
            g.reference(5.0, 100.0, 540.0, Dq::new(0.0, 60.0));
        }
        assert_eq!(g.weakening_id_a(), 0.0);
        assert!(g.is_idle() || g.plan.mtpa_dl_h > 0.0);
    }

    #[test]
    fn bad_configurations_are_off() {
        let m = ipm();
        let mut c = FieldConfig::for_motor(&m, 18.2, 15_000.0);
        c.max_id_a = f32::NAN;
        let f = Field::new(c, &m, 18.2, 15_000.0, 0.95);
        assert_eq!(*f.config(), FieldConfig::OFF);
        let c = FieldConfig::for_motor(&m, 18.2, 15_000.0);
        let f = Field::new(c, &m, f32::NAN, 15_000.0, 0.95);
        assert_eq!(*f.config(), FieldConfig::OFF);
    }

    #[test]
    fn defaults_per_motor() {
        let m = ipm();
        let c = FieldConfig::for_motor(&m, 18.2, 15_000.0);
        assert!(c.mtpa && !c.field_weakening && c.short_circuit);
        assert!((c.max_id_a - MAX_ID_SHARE * 0.545 / 0.036).abs() < 1e-3);
        let surface = MotorParams {
            ld_h: 0.5e-3,
            lq_h: 0.5e-3,
            ..m
        };
        let c = FieldConfig::for_motor(&surface, 18.2, 15_000.0);
        assert!(!c.mtpa && c.max_id_a == 18.2 && !c.short_circuit);
    }
}
