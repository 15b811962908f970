//! Current-loop PI tuning from motor parameters (design §11).
//!
//! Two rules, both pole-zero cancelling (`tau_i = Kp / Ki = L / R`, the
//! electrical time constant of the winding):
//!
//! - [`technical_optimum`] (design §11): from the PWM period alone,
//!   `Kp = L / (3 Ts)`, `Ki = R / (3 Ts)`, about 4.3 % overshoot.
//! - [`bandwidth`]: from a chosen open-loop crossover `wc`,
//!   `Kp = L wc`, `Ki = R wc` (first-order closed loop with time constant
//!   `1/wc` when delays are negligible). The technical optimum is the
//!   special case `wc = 1 / (3 Ts)` ([`technical_optimum_wc_rad_s`]).
//!
//! `Ki` is the continuous-time integral gain in 1/s units, as
//! [`crate::pi::PiConfig::ki_per_s`] expects; the PI multiplies it by its
//! sample period. All functions are `const fn` so gains can be computed at
//! compile time; they do no validation (non-finite or zero inputs give
//! non-finite gains, which [`crate::pi::Pi`] treats as unusable).
//!
//! ```
//! use foc_core::tuning::{technical_optimum, bandwidth, technical_optimum_dq};
//! // 100 uH, 0.1 ohm, 15 kHz PWM: Kp = 1e-4 * 15000 / 3 = 0.5 V/A, Ki = 500 V/(A s).
//! const G: foc_core::tuning::CurrentPiGains = technical_optimum(100e-6, 0.1, 1.0 / 15_000.0);
//! assert!((G.kp_v_per_a - 0.5).abs() < 1e-6 && (G.ki_v_per_a_s - 500.0).abs() < 1e-3);
//! let b = bandwidth(100e-6, 0.1, 2000.0); // wc = 2000 rad/s
//! assert!((b.kp_v_per_a - 0.2).abs() < 1e-6 && (b.ki_v_per_a_s - 200.0).abs() < 1e-3);
//! let dq = technical_optimum_dq(80e-6, 120e-6, 0.1, 1.0 / 15_000.0);
//! assert!(dq.q.kp_v_per_a > dq.d.kp_v_per_a); // Lq > Ld (IPM motor)
//! ```

use crate::pi::{AntiWindup, PiConfig};

/// The source's lumped delay of computation plus PWM, in PWM periods:
/// `T = 1.5 Ts` (design §11).
pub const LUMPED_DELAY_PERIODS: f32 = 1.5;

/// PI gains for one current axis.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CurrentPiGains {
    /// Proportional gain [V/A].
    pub kp_v_per_a: f32,
    /// Integral gain [V/(A s)].
    pub ki_v_per_a_s: f32,
}

impl CurrentPiGains {
    /// Integral time `tau_i = Kp / Ki` \[s\] (equals `L / R` for both rules).
    pub const fn integral_time_s(&self) -> f32 {
        self.kp_v_per_a / self.ki_v_per_a_s
    }

    /// A [`PiConfig`] with these gains, sample period `ts_s` \[s\] and a
    /// symmetric output limit `+-limit_v` \[V\].
    pub const fn pi_config(self, ts_s: f32, limit_v: f32, anti_windup: AntiWindup) -> PiConfig {
        PiConfig {
            kp: self.kp_v_per_a,
            ki_per_s: self.ki_v_per_a_s,
            ts_s,
            out_min: -limit_v,
            out_max: limit_v,
            anti_windup,
        }
    }

    /// The usual back-calculation tracking gain `kb = Ki / Kp = R / L` [1/s]
    /// (0 when `Kp` is not positive).
    pub const fn back_calculation_gain_per_s(&self) -> f32 {
        if self.kp_v_per_a > 0.0 {
            self.ki_v_per_a_s / self.kp_v_per_a
        } else {
            0.0
        }
    }
}

/// Gains of the d and q current controllers.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DqPiGains {
    /// d-axis (flux) controller, from `Ld`.
    pub d: CurrentPiGains,
    /// q-axis (torque) controller, from `Lq`.
    pub q: CurrentPiGains,
}

/// Technical optimum (design §11): `Kp = L/(3 Ts)`, `Ki = R/(3 Ts)`.
///
/// Derivation (design §11): the plant is `G(s) = 1 / (L s + R)`;
/// computation delay and PWM are lumped into one first-order lag with
/// `T = 1.5 Ts` ([`LUMPED_DELAY_PERIODS`]; PWM gain 1). The PI
/// `Kp (tau_i s + 1) / (tau_i s)` with `tau_i = L / R` cancels the plant
/// pole, leaving `G_open = K / (s (T s + 1))` with `K = Kp / L`. The
/// technical (second-order) optimum `K T = 0.5` gives a closed loop with
/// damping `1/sqrt(2)`, about 4.3 % step overshoot, so
/// `Kp = L / (2 T) = L / (3 Ts)` and `Ki = Kp / tau_i = R / (3 Ts)`.
///
/// `l_h` \[H\], `r_ohm` \[ohm\], `ts_s` = PWM / current-loop period \[s\].
pub const fn technical_optimum(l_h: f32, r_ohm: f32, ts_s: f32) -> CurrentPiGains {
    CurrentPiGains {
        kp_v_per_a: l_h / (3.0 * ts_s),
        ki_v_per_a_s: r_ohm / (3.0 * ts_s),
    }
}

/// Bandwidth rule: `Kp = L wc`, `Ki = R wc` for an open-loop crossover
/// `wc_rad_s` [rad/s] (pole-zero cancellation as in design §11).
/// Keep `wc` well below `1 / (3 Ts)` when the loop delay matters.
pub const fn bandwidth(l_h: f32, r_ohm: f32, wc_rad_s: f32) -> CurrentPiGains {
    CurrentPiGains {
        kp_v_per_a: l_h * wc_rad_s,
        ki_v_per_a_s: r_ohm * wc_rad_s,
    }
}

/// The `wc` for which [`bandwidth`] equals [`technical_optimum`]:
/// `K = 1 / (2 T) = 1 / (3 Ts)` [rad/s] (design §11).
pub const fn technical_optimum_wc_rad_s(ts_s: f32) -> f32 {
    1.0 / (2.0 * LUMPED_DELAY_PERIODS * ts_s)
}

/// Technical optimum for both axes (design §11):
/// `Kp_d = Ld/(3 Ts)`, `Kp_q = Lq/(3 Ts)`, `Ki_d = Ki_q = R/(3 Ts)`.
pub const fn technical_optimum_dq(ld_h: f32, lq_h: f32, r_ohm: f32, ts_s: f32) -> DqPiGains {
    DqPiGains {
        d: technical_optimum(ld_h, r_ohm, ts_s),
        q: technical_optimum(lq_h, r_ohm, ts_s),
    }
}

/// Bandwidth rule for both axes: `Kp_d = Ld wc`, `Kp_q = Lq wc`,
/// `Ki_d = Ki_q = R wc`.
pub const fn bandwidth_dq(ld_h: f32, lq_h: f32, r_ohm: f32, wc_rad_s: f32) -> DqPiGains {
    DqPiGains {
        d: bandwidth(ld_h, r_ohm, wc_rad_s),
        q: bandwidth(lq_h, r_ohm, wc_rad_s),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pi::Pi;

    fn close(a: f32, b: f32, rel: f32) -> bool {
        (a - b).abs() <= rel * b.abs()
    }

    #[test]
    fn technical_optimum_hand_values() {
        // L = 250 uH, R = 0.36 ohm, 20 kHz: 3 Ts = 150 us.
        // Kp = 250e-6 / 150e-6 = 1.6667 V/A, Ki = 0.36 / 150e-6 = 2400 V/(A s).
        let g = technical_optimum(250e-6, 0.36, 50e-6);
        assert!(close(g.kp_v_per_a, 1.666_666_7, 1e-6), "{g:?}");
        assert!(close(g.ki_v_per_a_s, 2400.0, 1e-6), "{g:?}");
        assert!(close(g.integral_time_s(), 250e-6 / 0.36, 1e-6));
        assert!(close(g.back_calculation_gain_per_s(), 0.36 / 250e-6, 1e-6));
    }

    #[test]
    fn bandwidth_hand_values_and_equivalence() {
        // L = 1 mH, R = 2 ohm, wc = 2 pi 300 = 1884.9556 rad/s:
        // Kp = 1.8849556 V/A, Ki = 3769.9112 V/(A s).
        let g = bandwidth(1e-3, 2.0, 1_884.955_6);
        assert!(close(g.kp_v_per_a, 1.884_955_6, 1e-6));
        assert!(close(g.ki_v_per_a_s, 3_769.911_2, 1e-6));
        let ts = 1.0 / 15_000.0;
        assert!(close(technical_optimum_wc_rad_s(ts), 5000.0, 1e-6));
        let a = technical_optimum(1e-3, 2.0, ts);
        let b = bandwidth(1e-3, 2.0, technical_optimum_wc_rad_s(ts));
        assert!(close(a.kp_v_per_a, b.kp_v_per_a, 1e-6));
        assert!(close(a.ki_v_per_a_s, b.ki_v_per_a_s, 1e-6));
    }

    #[test]
    fn dq_uses_ld_and_lq() {
        let g = technical_optimum_dq(0.2e-3, 0.5e-3, 1.0, 1e-4);
        // 3 Ts = 3e-4: Kp_d = 0.6667, Kp_q = 1.6667, Ki = 3333.3.
        assert!(close(g.d.kp_v_per_a, 0.666_666_7, 1e-6));
        assert!(close(g.q.kp_v_per_a, 1.666_666_7, 1e-6));
        assert!(close(g.d.ki_v_per_a_s, 3333.333, 1e-6));
        assert_eq!(g.d.ki_v_per_a_s, g.q.ki_v_per_a_s);
        let b = bandwidth_dq(0.2e-3, 0.5e-3, 1.0, 1000.0);
        assert!(close(b.d.kp_v_per_a, 0.2, 1e-6) && close(b.q.kp_v_per_a, 0.5, 1e-6));
        assert!(close(b.q.ki_v_per_a_s, 1000.0, 1e-6));
    }

    #[test]
    fn const_evaluable() {
        const G: CurrentPiGains = technical_optimum(1e-4, 0.1, 1e-4);
        const C: PiConfig = G.pi_config(1e-4, 12.0, AntiWindup::Clamp);
        assert_eq!(C.out_max, 12.0);
        assert_eq!(C.out_min, -12.0);
        assert_eq!(C.kp, G.kp_v_per_a);
    }

    /// The technical optimum's promise (design §11): with the plant
    /// `1/(L s + R)` behind a first-order lag of `1.5 Ts`, a current step
    /// overshoots by about 4.3 %. Simulated in continuous time (fine Euler
    /// steps) with the project's own [`Pi`] running at the same fine rate.
    #[test]
    fn technical_optimum_step_overshoot_about_4_percent() {
        let (l, r, ts) = (200e-6f32, 0.2f32, 1.0 / 15_000.0f32);
        let g = technical_optimum(l, r, ts);
        let dt = ts / 200.0;
        let mut pi = Pi::new(g.pi_config(dt, 1e6, AntiWindup::Clamp));
        let t_lag = LUMPED_DELAY_PERIODS * ts;
        let (mut u_lag, mut i) = (0.0f32, 0.0f32);
        let mut peak = 0.0f32;
        for _ in 0..(200 * 60) {
            let u = pi.step(1.0, i);
            u_lag += dt / t_lag * (u - u_lag);
            i += dt / l * (u_lag - r * i);
            if i > peak {
                peak = i;
            }
        }
        assert!((i - 1.0).abs() < 1e-3, "settles: {i}");
        let overshoot = peak - 1.0;
        assert!(
            overshoot > 0.035 && overshoot < 0.052,
            "overshoot {overshoot}"
        );
    }
}
