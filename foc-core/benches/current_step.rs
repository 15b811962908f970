//! Host benchmark of one full current-loop math step: Clarke, sin/cos,
//! Park, two PI, inverse Park, SVPWM and the three compare values
//! (design §4-8). Run with
//! `cargo bench -p foc-core --bench current_step`.
//!
//! The numbers are host nanoseconds, for spotting regressions; the
//! Cortex-M4F cost is counted separately (instructions under emulation).
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use criterion::{criterion_group, criterion_main, Criterion};
use foc_core::angle::ElectricalAngle;
use foc_core::frames::Dq;
use foc_core::pi::{AntiWindup, Pi};
use foc_core::svpwm::{compare_values, svpwm};
use foc_core::transforms::{clarke_2phase, inverse_park, park};
use foc_core::trig::sin_cos;
use foc_core::tuning::technical_optimum;
use std::hint::black_box;

const TS_S: f32 = 1.0 / 20_000.0;
const V_BUS_V: f32 = 24.0;
const PERIOD_COUNTS: u16 = 4200;

struct Loop {
    pi_d: Pi,
    pi_q: Pi,
}

impl Loop {
    fn new() -> Self {
        let g = technical_optimum(120e-6, 0.15, TS_S);
        let limit = V_BUS_V * foc_core::FRAC_1_SQRT_3;
        let aw = AntiWindup::BackCalculation {
            kb_per_s: g.back_calculation_gain_per_s(),
        };
        let cfg = g.pi_config(TS_S, limit, aw);
        Self {
            pi_d: Pi::new(cfg),
            pi_q: Pi::new(cfg),
        }
    }

    #[inline(never)]
    fn step(&mut self, i_a: f32, i_b: f32, theta: ElectricalAngle, iq_ref: f32) -> [u16; 3] {
        let i_ab = clarke_2phase(i_a, i_b);
        let (s, c) = sin_cos(theta);
        let i_dq = park(i_ab, s, c);
        let v_d = self.pi_d.step(0.0, i_dq.d);
        let v_q = self.pi_q.step(iq_ref, i_dq.q);
        let v_ab = inverse_park(Dq::new(v_d, v_q), s, c);
        let out = svpwm(v_ab, V_BUS_V);
        compare_values(out.duties, PERIOD_COUNTS)
    }
}

fn bench(c: &mut Criterion) {
    // Measured currents of a rotating 5 A vector with some ripple, so the
    // sectors, PI branches and saturation all vary from step to step.
    let samples: Vec<(f32, f32)> = (0..1024)
        .map(|k| {
            let t = k as f32 * 0.0613;
            let ripple = 0.3 * (7.0 * t).sin();
            (5.0 * t.cos() + ripple, 5.0 * (t - 2.094_395).cos() - ripple)
        })
        .collect();
    let mut lp = Loop::new();
    let mut theta = ElectricalAngle::ZERO;
    let step = ElectricalAngle::from_degrees(3.7);
    let mut k = 0usize;
    c.bench_function("current_step", |b| {
        b.iter(|| {
            let (i_a, i_b) = samples[k & 1023];
            k = k.wrapping_add(1);
            theta = theta.wrapping_add(step);
            black_box(lp.step(
                black_box(i_a),
                black_box(i_b),
                black_box(theta),
                black_box(4.0),
            ))
        })
    });
    c.bench_function("sin_cos", |b| {
        b.iter(|| {
            theta = theta.wrapping_add(step);
            black_box(sin_cos(black_box(theta)))
        })
    });
    c.bench_function("svpwm", |b| {
        b.iter(|| {
            let (a, bb) = samples[k & 1023];
            k = k.wrapping_add(1);
            black_box(svpwm(
                black_box(foc_core::frames::AlphaBeta::new(a * 2.0, bb * 2.0)),
                V_BUS_V,
            ))
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
