//! The q-current window the power and regen limits leave: the bus power
//! as a quadratic in the q current, its roots, and the window planned once
//! per configuration ([`WindowPlan`]).

use super::*;

/// Which limit set a bound of the q-current window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum ActiveLimit {
    /// No limit below the current limit.
    None = 0,
    /// The bus-voltage regen ramp ([`PowerLimitsConfig::regen_start_v`]).
    Regen = 1,
    /// [`PowerLimitsConfig::bus_current_motoring_max_a`].
    BusCurrentMotoring = 2,
    /// [`PowerLimitsConfig::bus_current_regen_max_a`].
    BusCurrentRegen = 3,
    /// [`PowerLimitsConfig::power_motoring_max_w`].
    PowerMotoring = 4,
    /// [`PowerLimitsConfig::power_regen_max_w`].
    PowerRegen = 5,
    /// Winding-temperature derating (the modelled temperature).
    WindingTemperature = 6,
    /// Power-stage temperature derating (the measured temperature).
    StageTemperature = 7,
    /// A needed input missing or not finite (the bus voltage, the speed,
    /// `i_d`, the current limit, a temperature): window `[0, 0]`.
    MissingSensor = 8,
    /// The motor model is not finite or its resistance negative: window
    /// `[0, 0]`.
    InvalidModel = 9,
}

/// The q-current window for this period.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IqWindow {
    /// Lowest allowed q-current \[A\] (`<= 0`).
    pub min_a: f32,
    /// Highest allowed q-current \[A\] (`>= 0`).
    pub max_a: f32,
    /// The limit that set `min_a` ([`ActiveLimit::None`]: the current limit).
    pub min_by: ActiveLimit,
    /// The limit that set `max_a`.
    pub max_by: ActiveLimit,
    /// The limit that cut the window the most (of `min_by` / `max_by`, by
    /// [`Self::factor`]); [`ActiveLimit::None`] when nothing cut.
    pub active: ActiveLimit,
    /// How much of the current limit is left at the more restricted end,
    /// in `[0, 1]`: `min(max_a, -min_a) / current_limit_a` (1 with a zero
    /// current limit; 0 for the safe window).
    pub factor: f32,
    /// The d-current reference \[A\]: [`PowerInputs::i_d_a`] plus the d-axis
    /// braking current (`<= 0`, see [`PowerLimitsConfig::regen_id_max_a`]).
    pub id_a: f32,
}

impl IqWindow {
    /// No current: the answer to a missing or invalid input.
    pub const fn zero(why: ActiveLimit) -> Self {
        Self {
            min_a: 0.0,
            max_a: 0.0,
            min_by: why,
            max_by: why,
            active: why,
            factor: 0.0,
            id_a: 0.0,
        }
    }

    /// `iq_a` clamped into the window; NaN gives 0.
    #[inline]
    pub fn clamp(&self, iq_a: f32) -> f32 {
        if iq_a < self.min_a {
            self.min_a
        } else if iq_a > self.max_a {
            self.max_a
        } else if iq_a.is_nan() {
            0.0
        } else {
            iq_a
        }
    }

    /// True when `iq_a` lies in the window.
    #[inline]
    pub fn contains(&self, iq_a: f32) -> bool {
        self.min_a <= iq_a && iq_a <= self.max_a
    }
}

/// What [`iq_window`] needs each period.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PowerInputs {
    /// Measured bus voltage \[V\] (`None`: the read failed).
    pub v_bus_v: Option<f32>,
    /// Electrical angular velocity [rad/s] (the tracker's speed times the
    /// pole pairs).
    pub omega_e_rad_s: f32,
    /// d-axis current \[A\] (the reference, or the measurement), without the
    /// d-axis braking this module adds.
    pub i_d_a: f32,
    /// The q-current the controller asks for before the window \[A\]: only
    /// its direction against the speed matters (braking or not, for the
    /// d-axis braking).
    pub iq_request_a: f32,
    /// The q-current limit before this module \[A\] (`Limits::max_current_a`
    /// or the stage's limit in force), finite and `>= 0`.
    pub current_limit_a: f32,
    /// Winding temperature [deg C] ([`ThermalEstimate::checked_temperature_c`]):
    /// needed (the power model's `R(T)` and the winding derating).
    pub winding_temperature_c: Option<f32>,
    /// Measured power-stage temperature [deg C]; `None` where the board
    /// has no sensor, allowed only with stage derating off.
    pub stage_temperature_c: Option<f32>,
}

/// The steady-state bus power \[W\] at q-current `iq_a` (the model of this
/// module: `1.5 R(T) (i_d^2 + i_q^2) + 1.5 w_e (psi + (L_d - L_q) i_d) i_q`);
/// `None` for the inputs [`iq_window`] refuses.
pub fn bus_power_w(cfg: &PowerLimitsConfig, inputs: &PowerInputs, iq_a: f32) -> Option<f32> {
    let (a, b, c) = coefficients(cfg, inputs, inputs.i_d_a)?;
    let p = (a * iq_a + b) * iq_a + c;
    if p.is_finite() {
        Some(p)
    } else {
        None
    }
}

/// `(a, b, c)` of `P(i_q) = a i_q^2 + b i_q + c` \[W\], `None` when an
/// input or the model is not valid.
pub(super) fn coefficients(
    cfg: &PowerLimitsConfig,
    inp: &PowerInputs,
    i_d_a: f32,
) -> Option<(f32, f32, f32)> {
    let t = inp.winding_temperature_c?;
    let m = &cfg.motor;
    if !(all_finite([
        m.r_ohm,
        m.ld_h,
        m.lq_h,
        m.flux_linkage_wb,
        inp.omega_e_rad_s,
        i_d_a,
        t,
    ]) && m.r_ohm >= 0.0)
    {
        return None;
    }
    let r = cfg.r_at_ohm(t);
    let psi_eff = m.flux_linkage_wb + (m.ld_h - m.lq_h) * i_d_a;
    let a = 1.5 * r;
    let b = 1.5 * inp.omega_e_rad_s * psi_eff;
    let c = a * i_d_a * i_d_a;
    if all_finite([a, b, c]) {
        Some((a, b, c))
    } else {
        None
    }
}

/// The interval around 0 where `a x^2 + b x + q <= 0`, for `q <= 0`,
/// `a >= 0` (the roots on each side of 0, in the forms without
/// cancellation).
#[inline(always)]
pub(super) fn below_roots(a: f32, b: f32, q: f32) -> (f32, f32) {
    let s = sqrtf(b * b - 4.0 * a * q); // >= |b|
                                        // Both roots 0 (a > 0, q = 0, b = 0), or no bound (a = 0).
    let flat = if q < 0.0 || a == 0.0 {
        f32::INFINITY
    } else {
        0.0
    };
    let hi = if b >= 0.0 {
        let d = b + s;
        if d > 0.0 {
            -2.0 * q / d
        } else {
            flat
        }
    } else {
        (s - b) / (2.0 * a)
    };
    let lo = if b <= 0.0 {
        let d = s - b;
        if d > 0.0 {
            2.0 * q / d
        } else {
            -flat
        }
    } else {
        -(b + s) / (2.0 * a)
    };
    (lo, hi)
}

/// The interval around 0 where `a x^2 + b x + q >= 0`, for `q >= 0`,
/// `a >= 0`: unbounded except on the side of the roots (`-b`'s sign),
/// bounded there by the root nearer 0.
#[inline(always)]
pub(super) fn above_roots(a: f32, b: f32, q: f32) -> (f32, f32) {
    let disc = b * b - 4.0 * a * q;
    if disc <= 0.0 {
        return (f32::NEG_INFINITY, f32::INFINITY);
    }
    if disc.is_nan() {
        return (0.0, 0.0); // NaN: the safe interval
    }
    let s = sqrtf(disc); // <= |b|
    if b > 0.0 {
        (-2.0 * q / (b + s), f32::INFINITY)
    } else {
        // b < 0 (b = 0 gives disc <= 0)
        (f32::NEG_INFINITY, 2.0 * q / (s - b))
    }
}

/// One end of the window being narrowed.
#[derive(Clone, Copy)]
pub(super) struct End {
    pub(super) mag: f32,
    pub(super) by: ActiveLimit,
}

impl End {
    #[inline(always)]
    pub(super) fn cut(&mut self, mag: f32, by: ActiveLimit) {
        // A NaN bound cuts to 0 (never widens).
        if mag.is_nan() || mag < self.mag {
            self.mag = if mag > 0.0 { mag } else { 0.0 };
            self.by = by;
        }
    }
}

/// The q-current window for this period: the current limit, derated by
/// temperature, cut by the power and bus-current limits (exact roots of the
/// steady-state power balance, see the module docs), its regenerating end
/// scaled by the bus-voltage regen factor.
///
/// Always contains 0 for valid inputs (a limit never forces torque);
/// `[0, 0]` with [`ActiveLimit::MissingSensor`] when the bus voltage is
/// missing, non-finite or `<= 0`, when the speed, `i_d`, the current limit
/// or a needed temperature is missing or not finite (or the current limit
/// negative), and with [`ActiveLimit::InvalidModel`] for an invalid motor
/// model. Expects a [`sanitized`](PowerLimitsConfig::sanitized) `cfg`; an
/// unsanitized NaN limit still gives no current in its direction.
pub fn iq_window(cfg: &PowerLimitsConfig, inp: &PowerInputs) -> IqWindow {
    iq_window_planned(cfg, &WindowPlan::of(cfg), inp)
}

/// What [`iq_window`] decides from the configuration alone, worked out
/// once per configuration instead of every period (design §20).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WindowPlan {
    /// The motor model is finite with `R >= 0`.
    pub(super) model_ok: bool,
    /// No bus-current or power limit is configured (each is `+inf`).
    pub(super) no_bus_or_power_limit: bool,
}

impl WindowPlan {
    /// The plan of `cfg`.
    pub fn of(cfg: &PowerLimitsConfig) -> Self {
        let m = &cfg.motor;
        Self {
            model_ok: all_finite([m.r_ohm, m.ld_h, m.lq_h, m.flux_linkage_wb]) && m.r_ohm >= 0.0,
            no_bus_or_power_limit: cfg.bus_current_motoring_max_a == f32::INFINITY
                && cfg.bus_current_regen_max_a == f32::INFINITY
                && cfg.power_motoring_max_w == f32::INFINITY
                && cfg.power_regen_max_w == f32::INFINITY,
        }
    }
}

/// [`iq_window`] with the configuration's plan (`plan` must be
/// `WindowPlan::of(cfg)`).
#[inline(always)]
pub(super) fn iq_window_planned(
    cfg: &PowerLimitsConfig,
    plan: &WindowPlan,
    inp: &PowerInputs,
) -> IqWindow {
    let missing = IqWindow::zero(ActiveLimit::MissingSensor);
    let g = match admitted(cfg, plan, inp) {
        Ok(g) => g,
        Err(w) => return w,
    };
    let (v, i_lim, k, s) = (g.v_bus_v, g.i_lim_a, g.k, g.s);
    // The common case, cheaply: no derating, the bus below the regen ramp,
    // no d-current and no bus-current or power limit configured: the
    // window is the current limit (what the full computation gives then).
    if k >= 1.0
        && s >= 1.0
        && inp.i_d_a == 0.0
        && inp.omega_e_rad_s.is_finite()
        && g.t_winding_c.is_finite()
        && plan.no_bus_or_power_limit
    {
        return IqWindow {
            min_a: 0.0 - i_lim,
            max_a: i_lim,
            min_by: ActiveLimit::None,
            max_by: ActiveLimit::None,
            active: ActiveLimit::None,
            factor: 1.0,
            id_a: 0.0,
        };
    }
    // The d-axis braking current (bus in the regen ramp, braking asked).
    let id_brake = braking_id_a(cfg, s, inp, k * i_lim, cfg.r_at_ohm(g.t_winding_c));
    let i_d = inp.i_d_a + id_brake;
    let Some((a, b, c)) = coefficients(cfg, inp, i_d) else {
        return missing;
    };
    let (mut lo, mut hi) = current_limit_ends(&g, i_d, id_brake);
    cut_by_power(cfg, v, (a, b, c), &mut lo, &mut hi);

    // 4. The bus-voltage regen ramp on the regenerating end (i_q b < 0),
    // never below the current of zero net power (the copper loss of the
    // d-current pays for that much braking).
    if s < 1.0 {
        let keep = zero_power_q_a(a, b, c);
        if b > 0.0 {
            let m = lo.mag;
            lo.cut(max_of(s * m, min_of(keep, m)), ActiveLimit::Regen);
        } else if b < 0.0 {
            let m = hi.mag;
            hi.cut(max_of(s * m, min_of(keep, m)), ActiveLimit::Regen);
        }
    }

    if !(lo.mag >= 0.0 && hi.mag >= 0.0) {
        return missing; // unreachable for finite inputs; NaN-safe anyway
    }
    window_of(lo, hi, i_lim, i_d)
}

/// What the window is computed from, once the inputs are admitted.
struct Admitted {
    v_bus_v: f32,
    i_lim_a: f32,
    /// The thermal derating factor and the limit it comes from.
    k: f32,
    k_by: ActiveLimit,
    /// The bus-voltage regen factor.
    s: f32,
    t_winding_c: f32,
}

/// The inputs checked (the zero window naming what is missing or invalid
/// otherwise), and step 1: the thermal derating of the current limit
/// (both ends).
#[inline(always)]
fn admitted(
    cfg: &PowerLimitsConfig,
    plan: &WindowPlan,
    inp: &PowerInputs,
) -> Result<Admitted, IqWindow> {
    if !plan.model_ok {
        return Err(IqWindow::zero(ActiveLimit::InvalidModel));
    }
    let missing = IqWindow::zero(ActiveLimit::MissingSensor);
    let v = match inp.v_bus_v {
        Some(v) if v > 0.0 && v < f32::INFINITY => v,
        _ => return Err(missing),
    };
    let i_lim = inp.current_limit_a;
    if !(0.0..f32::INFINITY).contains(&i_lim) {
        return Err(missing);
    }
    let k_stage = match inp.stage_temperature_c {
        Some(t) if t.is_finite() => cfg.stage_factor(t),
        None if !cfg.stage_derating_on() => 1.0,
        _ => return Err(missing),
    };
    let Some(t_winding) = inp.winding_temperature_c else {
        return Err(missing);
    };
    let k_winding = cfg.winding_factor(t_winding);
    let (k, k_by) = if k_stage < k_winding {
        (k_stage, ActiveLimit::StageTemperature)
    } else {
        (k_winding, ActiveLimit::WindingTemperature)
    };
    Ok(Admitted {
        v_bus_v: v,
        i_lim_a: i_lim,
        k,
        k_by,
        s: cfg.regen_factor(v),
        t_winding_c: t_winding,
    })
}

/// Both ends at the (derated) current limit, and the current vector within
/// it: `|i_q| <= sqrt(I^2 - i_d^2)`.
#[inline(always)]
fn current_limit_ends(g: &Admitted, i_d: f32, id_brake: f32) -> (End, End) {
    let (i_lim, k, k_by) = (g.i_lim_a, g.k, g.k_by);
    let mut lo = End {
        mag: i_lim,
        by: ActiveLimit::None,
    };
    let mut hi = lo;
    lo.cut(k * i_lim, k_by);
    hi.cut(k * i_lim, k_by);
    if i_d != 0.0 {
        let kk = k * i_lim;
        let room = kk * kk - i_d * i_d;
        let q = if room > 0.0 { sqrtf(room) } else { 0.0 };
        let by = if id_brake != 0.0 {
            ActiveLimit::Regen
        } else {
            k_by
        };
        lo.cut(q, by);
        hi.cut(q, by);
    }
    (lo, hi)
}

/// Steps 2 and 3: the power balance `P(iq) = a iq^2 + b iq + c` within the
/// motoring and regenerating power and bus-current limits (NaN limits read
/// as 0).
#[inline(always)]
fn cut_by_power(
    cfg: &PowerLimitsConfig,
    v: f32,
    (a, b, c): (f32, f32, f32),
    lo: &mut End,
    hi: &mut End,
) {
    // 2. Motoring: P(iq) <= P_mot.
    let p_bus_mot = v * cfg.bus_current_motoring_max_a;
    let p_cfg = limit_or_zero(cfg.power_motoring_max_w);
    let p_bus_mot = limit_or_zero(p_bus_mot);
    let (p_mot, mot_by) = if p_cfg <= p_bus_mot {
        (p_cfg, ActiveLimit::PowerMotoring)
    } else {
        (p_bus_mot, ActiveLimit::BusCurrentMotoring)
    };
    if p_mot < f32::INFINITY {
        // The loss of i_d alone is not this module's to limit: 0 stays in.
        let q = if c > p_mot { 0.0 } else { c - p_mot };
        let (x_lo, x_hi) = below_roots(a, b, q);
        lo.cut(-x_lo, mot_by);
        hi.cut(x_hi, mot_by);
    }

    // 3. Regeneration: P(iq) >= -P_regen.
    let p_bus_regen = v * cfg.bus_current_regen_max_a;
    let p_cfg = limit_or_zero(cfg.power_regen_max_w);
    let p_bus_regen = limit_or_zero(p_bus_regen);
    let (p_regen, regen_by) = if p_cfg <= p_bus_regen {
        (p_cfg, ActiveLimit::PowerRegen)
    } else {
        (p_bus_regen, ActiveLimit::BusCurrentRegen)
    };
    if p_regen < f32::INFINITY {
        let (x_lo, x_hi) = above_roots(a, b, c + p_regen);
        lo.cut(-x_lo, regen_by);
        hi.cut(x_hi, regen_by);
    }
}

/// The window of the two ends, with the factor of the tighter one.
#[inline(always)]
fn window_of(lo: End, hi: End, i_lim: f32, i_d: f32) -> IqWindow {
    let (factor, active) = if i_lim > 0.0 {
        let (tight, by) = if lo.mag < hi.mag {
            (lo.mag, lo.by)
        } else {
            (hi.mag, hi.by)
        };
        let f = tight / i_lim;
        if f >= 1.0 {
            (1.0, ActiveLimit::None)
        } else {
            (f, by)
        }
    } else {
        (1.0, ActiveLimit::None)
    };
    IqWindow {
        min_a: 0.0 - lo.mag, // +0.0, not -0.0, for an empty end
        max_a: hi.mag,
        min_by: lo.by,
        max_by: hi.by,
        active,
        factor,
        id_a: i_d,
    }
}

/// The d-axis braking current \[A\] (`<= 0`): `-(1 - s) min(regen_id_max_a,
/// limit)` while `s < 1` and the requested q-current regenerates (it
/// opposes the speed, and the back-EMF's power exceeds the copper loss of
/// the q-current the ramp admits, `|w_e psi| > R min(|i_q|, s I)`; below
/// that speed braking already draws from the bus), else 0 (also for any
/// non-finite input).
#[inline(always)]
pub(super) fn braking_id_a(
    cfg: &PowerLimitsConfig,
    s: f32,
    inp: &PowerInputs,
    limit_a: f32,
    r_ohm: f32,
) -> f32 {
    let iq = inp.iq_request_a;
    let w = inp.omega_e_rad_s;
    let emf = w * cfg.motor.flux_linkage_wb;
    // Against the q-current the ramp admits (`s` of the limit), not the
    // request alone: near `s = 0` any braking request qualifies, so the
    // d-current does not switch on and off with the speed there.
    let iq_mag = if iq < 0.0 { -iq } else { iq };
    let admitted = min_of(iq_mag, s * limit_a);
    let braking = iq * w < 0.0 && emf * emf > (r_ohm * admitted) * (r_ohm * admitted);
    if !(s < 1.0 && braking && cfg.regen_id_max_a > 0.0) {
        return 0.0;
    }
    let cap = min_of(cfg.regen_id_max_a, limit_a);
    let id = -(1.0 - s) * cap;
    if id <= 0.0 && id > f32::NEG_INFINITY {
        id
    } else {
        0.0
    }
}

/// The regenerating q-current magnitude up to which `P >= 0` (the smaller
/// root of `a m^2 - |b| m + c = 0`, `m` along the regenerating direction):
/// 0 without a d-current (`c = 0`). When `P > 0` everywhere on that side
/// (`b^2 < 4 a c`) the vertex `|b| / (2 a)`, where that root ends up as
/// `b^2` falls to `4 a c`: continuous in the speed and the d-current (a
/// jump from the vertex to the whole range would make the window, and the
/// current reference, flip between the two).
#[inline(always)]
pub(super) fn zero_power_q_a(a: f32, b: f32, c: f32) -> f32 {
    // `c` is `>= 0` (a square); 0 (or NaN): no d-current to pay for any.
    if c.is_nan() || c <= 0.0 {
        return 0.0;
    }
    let bb = if b < 0.0 { -b } else { b };
    let disc = bb * bb - 4.0 * a * c;
    if disc < 0.0 {
        // a > 0 here (a = 0 gives disc = b^2 >= 0).
        return bb / (2.0 * a);
    }
    let d = bb + sqrtf(disc);
    if d > 0.0 {
        2.0 * c / d
    } else {
        0.0
    }
}

#[inline(always)]
pub(super) fn min_of(x: f32, y: f32) -> f32 {
    if x < y {
        x
    } else {
        y
    }
}

#[inline(always)]
pub(super) fn max_of(x: f32, y: f32) -> f32 {
    if x > y {
        x
    } else {
        y
    }
}
