//! Clarke and Park transforms and their inverses (design §4, §5, §7).
//!
//! **Convention used throughout this project** (amplitude invariant):
//!
//! ```text
//! Clarke:          alpha = a
//!                  beta  = (a + 2 b) / sqrt(3)            (beta 90 deg ahead of A)
//! Park:            d =  alpha cos(theta_e) + beta sin(theta_e)
//!                  q = -alpha sin(theta_e) + beta cos(theta_e)
//! Inverse Park:    alpha = d cos(theta_e) - q sin(theta_e)
//!                  beta  = d sin(theta_e) + q cos(theta_e)
//! Inverse Clarke:  a = alpha
//!                  b = -alpha / 2 + (sqrt(3)/2) beta
//!                  c = -alpha / 2 - (sqrt(3)/2) beta
//! ```
//!
//! The source (`MC_FOC_DRIVE.c`) writes `I_beta = -(1/sqrt3) I_a - (2/sqrt3) I_b`,
//! i.e. our beta with the sign reversed; its Park and inverse Park are written
//! for that reversed axis. The functions in [`source`] restate the source's
//! formulas verbatim so tests can show exactly how they map onto this
//! convention.
//!
//! ```
//! use foc_core::{frames::Abc, transforms, trig};
//! use foc_core::angle::ElectricalAngle;
//! let theta = ElectricalAngle::from_degrees(30.0);
//! let (s, c) = trig::sin_cos(theta);
//! let i_ab = transforms::clarke(Abc::new(1.0, -0.5, -0.5));
//! let i_dq = transforms::park(i_ab, s, c);
//! let back = transforms::inverse_clarke(transforms::inverse_park(i_dq, s, c));
//! assert!((back.a - 1.0).abs() < 1e-4);
//! ```

use crate::frames::{Abc, AlphaBeta, Dq};
use crate::{FRAC_1_SQRT_3, SQRT_3_2};

/// Clarke transform from three measured phases (amplitude invariant;
/// design §4, with our beta axis = minus the source's).
///
/// Uses `a` and `b` and the star-point constraint through `c` as
/// `alpha = (2a - b - c)/3`, `beta = (b - c)/sqrt(3)`: with three shunts this
/// averages out a common-mode error in the measurement; when
/// `a + b + c = 0` it equals [`clarke_2phase`].
#[inline]
pub fn clarke(i: Abc) -> AlphaBeta {
    AlphaBeta {
        alpha: (2.0 * i.a - i.b - i.c) * (1.0 / 3.0),
        beta: (i.b - i.c) * FRAC_1_SQRT_3,
    }
}

/// Clarke transform from two phases, the third derived as `c = -a - b`
/// (design §2): `alpha = a`, `beta = (a + 2b)/sqrt(3)` (design
/// §4 with our beta axis = minus the source's).
#[inline]
pub fn clarke_2phase(a: f32, b: f32) -> AlphaBeta {
    AlphaBeta {
        alpha: a,
        beta: (a + 2.0 * b) * FRAC_1_SQRT_3,
    }
}

/// Inverse Clarke: alpha/beta to three phases with zero sum (the inverse of
/// design §4; used to check SVPWM line-to-line voltages).
#[inline]
pub fn inverse_clarke(v: AlphaBeta) -> Abc {
    let half_alpha = -0.5 * v.alpha;
    let k_beta = SQRT_3_2 * v.beta;
    Abc {
        a: v.alpha,
        b: half_alpha + k_beta,
        c: half_alpha - k_beta,
    }
}

/// Park transform: stationary alpha/beta to the rotor dq frame, given
/// `sin(theta_e)` and `cos(theta_e)` (design §5 in our convention:
/// the source's `(I_d, I_q)` at `theta` are our `(-q, d)` at `theta`, i.e.
/// our `(d, q)` at `theta - 90 deg`; see `tests/math_props.rs`).
#[inline]
pub fn park(v: AlphaBeta, sin: f32, cos: f32) -> Dq {
    Dq {
        d: v.alpha * cos + v.beta * sin,
        q: -v.alpha * sin + v.beta * cos,
    }
}

/// Inverse Park: rotor dq frame to stationary alpha/beta (design §7
/// in our convention).
#[inline]
pub fn inverse_park(v: Dq, sin: f32, cos: f32) -> AlphaBeta {
    AlphaBeta {
        alpha: v.d * cos - v.q * sin,
        beta: v.d * sin + v.q * cos,
    }
}

/// The source's formulas, verbatim, for traceability and mapping tests.
///
/// Not used by the control code. The source's beta axis is the negative of
/// ours (`beta_src = -beta`).
pub mod source {
    use crate::{FRAC_1_SQRT_3, FRAC_2_SQRT_3};

    /// Design §4: `I_alpha = I_a`, `I_beta = -(1/sqrt3) I_a - (2/sqrt3) I_b`.
    /// Returns `(I_alpha, I_beta_src)`.
    #[inline]
    pub fn clarke(i_a: f32, i_b: f32) -> (f32, f32) {
        (i_a, -FRAC_1_SQRT_3 * i_a - FRAC_2_SQRT_3 * i_b)
    }

    /// Design §5: `I_q = I_alpha cos - I_beta sin`,
    /// `I_d = I_alpha sin + I_beta cos`. Returns `(I_d_src, I_q_src)`.
    #[inline]
    pub fn park(i_alpha: f32, i_beta_src: f32, sin: f32, cos: f32) -> (f32, f32) {
        let i_q = i_alpha * cos - i_beta_src * sin;
        let i_d = i_alpha * sin + i_beta_src * cos;
        (i_d, i_q)
    }

    /// Design §7: `V_alpha = V_q cos + V_d sin`,
    /// `V_beta = -V_q sin + V_d cos`. Returns `(V_alpha, V_beta_src)`.
    #[inline]
    pub fn inverse_park(v_d: f32, v_q: f32, sin: f32, cos: f32) -> (f32, f32) {
        (v_q * cos + v_d * sin, -v_q * sin + v_d * cos)
    }
}
