//! Current-loop PI tuning from motor parameters (source section 11).
//! PLACEHOLDER: completed in the core-math work.

/// PI gains for one current axis.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CurrentPiGains {
    /// Proportional gain [V/A].
    pub kp_v_per_a: f32,
    /// Integral gain [V/(A s)].
    pub ki_v_per_a_s: f32,
}

/// Technical optimum (source section 11): `Kp = L/(3 Ts)`, `Ki = R/(3 Ts)`.
pub const fn technical_optimum(l_h: f32, r_ohm: f32, ts_s: f32) -> CurrentPiGains {
    CurrentPiGains {
        kp_v_per_a: l_h / (3.0 * ts_s),
        ki_v_per_a_s: r_ohm / (3.0 * ts_s),
    }
}
