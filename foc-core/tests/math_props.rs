//! Property tests of the frame transforms, trig, sqrt and angles
//! (design §3, §4, §5, §7), including how the source's own formulas
//! map onto this project's convention.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::angle::{ElectricalAngle, MechanicalAngle, MultiTurn};
use foc_core::frames::{Abc, AlphaBeta, Dq};
use foc_core::svpwm::{svpwm, Sector};
use foc_core::transforms::{self, source};
use foc_core::trig::{sin_cos, sin_cos_bits, SIN_COS_MAX_ABS_ERROR};
use proptest::prelude::*;
use std::f64::consts::TAU;

fn angle_rad(bits: u32) -> f64 {
    bits as f64 * (TAU / 4_294_967_296.0)
}

/// |a - b| <= tol * (1 + scale)
fn near(a: f32, b: f32, tol: f32, scale: f32) -> bool {
    (a - b).abs() <= tol * (1.0 + scale)
}

fn balanced(amp: f32, theta: f64) -> Abc {
    let c = |ph: f64| (amp as f64 * (theta + ph).cos()) as f32;
    Abc::new(c(0.0), c(-TAU / 3.0), c(TAU / 3.0))
}

proptest! {
    /// abc -> alpha/beta -> dq -> alpha/beta -> abc is the identity for
    /// zero-sum inputs (design §4's requirement), at any angle.
    #[test]
    fn clarke_park_round_trip(a in -100.0f32..100.0, b in -100.0f32..100.0, bits in any::<u32>()) {
        let abc = Abc::new(a, b, -a - b);
        let (s, c) = sin_cos(ElectricalAngle::from_bits(bits));
        let dq = transforms::park(transforms::clarke(abc), s, c);
        let back = transforms::inverse_clarke(transforms::inverse_park(dq, s, c));
        let scale = a.abs() + b.abs();
        prop_assert!(near(back.a, abc.a, 1e-5, scale), "{abc:?} -> {back:?}");
        prop_assert!(near(back.b, abc.b, 1e-5, scale), "{abc:?} -> {back:?}");
        prop_assert!(near(back.c, abc.c, 1e-5, scale), "{abc:?} -> {back:?}");
    }

    /// Park then inverse Park is the identity on alpha/beta, and preserves length.
    #[test]
    fn park_is_a_rotation(al in -100.0f32..100.0, be in -100.0f32..100.0, bits in any::<u32>()) {
        let (s, c) = sin_cos_bits(bits);
        let v = AlphaBeta::new(al, be);
        let dq = transforms::park(v, s, c);
        prop_assert!(near(dq.magnitude(), v.magnitude(), 1e-5, v.magnitude()));
        let back = transforms::inverse_park(dq, s, c);
        prop_assert!(near(back.alpha, al, 1e-5, v.magnitude()));
        prop_assert!(near(back.beta, be, 1e-5, v.magnitude()));
    }

    /// Two-phase Clarke equals three-phase Clarke when a + b + c = 0.
    #[test]
    fn clarke_2phase_equals_3phase(a in -100.0f32..100.0, b in -100.0f32..100.0) {
        let three = transforms::clarke(Abc::new(a, b, -a - b));
        let two = transforms::clarke_2phase(a, b);
        let scale = a.abs() + b.abs();
        prop_assert!(near(three.alpha, two.alpha, 1e-6, scale));
        prop_assert!(near(three.beta, two.beta, 1e-6, scale));
    }

    /// Amplitude invariance: a balanced set `A cos(theta + phi - k 120 deg)`
    /// gives |alpha/beta| = A and, in the frame at theta, d = A cos(phi),
    /// q = A sin(phi) (phi > 0: current ahead of d, i.e. towards +q).
    #[test]
    fn amplitude_invariance(amp in 0.01f32..100.0, bits in any::<u32>(), phi in -3.1f64..3.1) {
        let theta = angle_rad(bits);
        let abc = balanced(amp, theta + phi);
        let ab = transforms::clarke(abc);
        prop_assert!(near(ab.magnitude(), amp, 1e-5, amp));
        let (s, c) = sin_cos_bits(bits);
        let dq = transforms::park(ab, s, c);
        prop_assert!(near(dq.d, amp * phi.cos() as f32, 1e-5, amp), "{dq:?}");
        prop_assert!(near(dq.q, amp * phi.sin() as f32, 1e-5, amp), "{dq:?}");
        prop_assert!(near(dq.magnitude(), amp, 1e-5, amp));
    }

    /// Positive rotation A -> B -> C: the current vector of a balanced set at
    /// electrical angle theta points at theta in our alpha/beta frame.
    #[test]
    fn beta_is_ahead_of_alpha(amp in 0.1f32..10.0, bits in any::<u32>()) {
        let theta = angle_rad(bits);
        let ab = transforms::clarke(balanced(amp, theta));
        prop_assert!(near(ab.alpha, amp * theta.cos() as f32, 1e-5, amp));
        prop_assert!(near(ab.beta, amp * theta.sin() as f32, 1e-5, amp));
    }

    /// How the source's formulas (design §4, §5, §7) map onto ours:
    /// - Clarke: `beta_src = -beta`;
    /// - Park at the same theta: `Iq_src = d`, `Id_src = -q`; equivalently the
    ///   source's (Id, Iq) at theta are our (d, q) at `theta - 90 deg`, i.e. the
    ///   source's angle is that of our q axis;
    /// - a current in phase with theta is pure `Iq_src` (design §5);
    /// - inverse Park returns `(alpha, beta_src)` consistently, so the source's
    ///   whole chain round-trips too.
    #[test]
    fn source_convention_mapping(a in -50.0f32..50.0, b in -50.0f32..50.0, bits in any::<u32>()) {
        let scale = a.abs() + b.abs();
        let ours = transforms::clarke_2phase(a, b);
        let (al_src, be_src) = source::clarke(a, b);
        prop_assert!(near(al_src, ours.alpha, 1e-6, scale));
        prop_assert!(near(be_src, -ours.beta, 1e-6, scale));

        let (s, c) = sin_cos_bits(bits);
        let dq = transforms::park(ours, s, c);
        let (id_src, iq_src) = source::park(al_src, be_src, s, c);
        prop_assert!(near(iq_src, dq.d, 1e-5, scale), "Iq_src {iq_src} vs d {}", dq.d);
        prop_assert!(near(id_src, -dq.q, 1e-5, scale), "Id_src {id_src} vs -q {}", dq.q);

        let (s90, c90) = sin_cos_bits(bits.wrapping_sub(1 << 30)); // theta - 90 deg
        let dq90 = transforms::park(ours, s90, c90);
        prop_assert!(near(id_src, dq90.d, 1e-5, scale));
        prop_assert!(near(iq_src, dq90.q, 1e-5, scale));

        let (v_al, v_be_src) = source::inverse_park(id_src, iq_src, s, c);
        let back = transforms::inverse_clarke(AlphaBeta::new(v_al, -v_be_src));
        prop_assert!(near(back.a, a, 1e-5, scale) && near(back.b, b, 1e-5, scale));

        // ... and our inverse Park of our (d, q) = (Iq_src, -Id_src) agrees.
        let ours_back = transforms::inverse_park(Dq::new(iq_src, -id_src), s, c);
        prop_assert!(near(ours_back.alpha, v_al, 1e-5, scale));
        prop_assert!(near(ours_back.beta, -v_be_src, 1e-5, scale));
    }

    #[test]
    fn source_in_phase_current_is_pure_iq(amp in 0.1f32..10.0, bits in any::<u32>()) {
        let abc = balanced(amp, angle_rad(bits));
        let (al, be_src) = source::clarke(abc.a, abc.b);
        let (s, c) = sin_cos_bits(bits);
        let (id_src, iq_src) = source::park(al, be_src, s, c);
        prop_assert!(near(iq_src, amp, 1e-5, amp));
        prop_assert!(near(id_src, 0.0, 1e-5, amp));
    }

    /// The SVPWM table (design §8) is written for our beta: fed with
    /// our beta a vector at 0..60 deg is in sector I; fed the source's
    /// reversed `beta_src` it would land in the mirrored sector VI.
    #[test]
    fn svpwm_table_uses_our_beta(deg in 1.0f64..59.0, mag in 0.5f32..10.0) {
        let r = deg.to_radians();
        let v = AlphaBeta::new(mag * r.cos() as f32, mag * r.sin() as f32);
        prop_assert_eq!(svpwm(v, 24.0).sector, Sector::I);
        let beta_src = -v.beta;
        prop_assert_eq!(svpwm(AlphaBeta::new(v.alpha, beta_src), 24.0).sector, Sector::VI);
    }

    #[test]
    fn sin_cos_matches_f64(bits in any::<u32>()) {
        let (s, c) = sin_cos_bits(bits);
        let t = angle_rad(bits);
        prop_assert!((s as f64 - t.sin()).abs() < SIN_COS_MAX_ABS_ERROR as f64);
        prop_assert!((c as f64 - t.cos()).abs() < SIN_COS_MAX_ABS_ERROR as f64);
    }

    #[test]
    fn sqrtf_relative_error(x in proptest::num::f32::ANY) {
        let got = foc_core::sqrtf(x);
        if x > 0.0 && x.is_finite() {
            let want = (x as f64).sqrt();
            prop_assert!(((got as f64) - want).abs() <= 1e-6 * want, "{x}: {got}");
        } else if x == f32::INFINITY {
            prop_assert_eq!(got, f32::INFINITY);
        } else {
            prop_assert_eq!(got, 0.0, "{}", x);
        }
    }

    /// Many turns of random increments: the wrapped angle matches an exact
    /// integer reference, and radians-based increments drift by no more than
    /// their f32 rounding per step.
    #[test]
    fn angle_wraps_over_many_turns(steps in proptest::collection::vec(any::<i32>(), 1..2000), pp in 1u8..=50) {
        let mut m = MechanicalAngle::ZERO;
        let mut e = ElectricalAngle::ZERO;
        let mut reference: i64 = 0;
        let mut multi = MultiTurn::ZERO;
        for &s in &steps {
            let step = MechanicalAngle::from_bits(s as u32);
            m = m.wrapping_add(step);
            reference += s as i64;
            e = e.wrapping_add(step.to_electrical(pp));
            multi.update(m);
        }
        prop_assert_eq!(m.to_bits(), reference.rem_euclid(1 << 32) as u32);
        prop_assert_eq!(m.to_electrical(pp), e);
        // |step| < half a turn, so MultiTurn's count is exact.
        let total_turns = reference.div_euclid(1 << 32);
        prop_assert_eq!(multi.turns as i64, total_turns);
        prop_assert_eq!(multi.angle, m);
    }

    #[test]
    fn add_radians_many_turns(start in any::<u32>(), rad in -10.0f32..10.0, n in 1u32..5000) {
        let mut a = ElectricalAngle::from_bits(start);
        for _ in 0..n {
            a = a.add_radians(rad);
        }
        // Each step is exact to within one rounding of the step itself.
        let step = ElectricalAngle::from_radians(rad).to_bits();
        let expect = start.wrapping_add(step.wrapping_mul(n));
        prop_assert_eq!(a.to_bits(), expect);
        let exact_turns = (start as f64 / 4_294_967_296.0) + (rad as f64) * n as f64 / TAU;
        let frac = exact_turns.rem_euclid(1.0);
        let diff = (a.to_turns() as f64 - frac).abs();
        let diff = diff.min(1.0 - diff);
        // The step is rounded once (f32 radians -> turns, about 2 ulp relative)
        // and then added exactly, so the drift is at most n times that.
        let step_turns = (rad as f64 / TAU).abs();
        prop_assert!(diff <= 1e-6 + n as f64 * (step_turns * 2.5e-7 + 2.4e-10), "diff {diff}");
    }
}

#[test]
fn park_q_axis_sign() {
    // A known Park sign defect elsewhere: at theta = 0, a current along +beta
    // (phase B side) must be +q.
    let dq = transforms::park(AlphaBeta::new(0.0, 1.0), 0.0, 1.0);
    assert_eq!((dq.d, dq.q), (0.0, 1.0));
    let (s, c) = sin_cos(ElectricalAngle::from_degrees(90.0));
    let dq = transforms::park(AlphaBeta::new(0.0, 1.0), s, c);
    assert!((dq.d - 1.0).abs() < 1e-6 && dq.q.abs() < 1e-6);
}
