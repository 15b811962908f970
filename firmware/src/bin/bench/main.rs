//! Exact instruction counts of the control code on the Cortex-M4F, under
//! QEMU (`cargo xtask bench`; emulated board only).
//!
//! QEMU runs with `-icount shift=10,align=off`: every instruction advances
//! virtual time by exactly 1024 ns, and SysTick (core clock, reload
//! 0xFFFFFF) by exactly 172.032 ticks (see the book, docs/src/reference/instruction-counts.md).
//! Each item is measured between two reads of `SYST_CVR`, minus the cost
//! of an empty measurement, over several inputs; a block of 100 `nop`s is
//! measured first as a self-check (the difference of a call with and
//! without them must read exactly 100).
//!
//! These are *instruction* counts, not cycles: on the M4F most instructions
//! take one cycle, loads and branches can take two or three, `vdiv`/`vsqrt`
//! take 14. The firmware's real timing on a board comes from the DWT cycle
//! counter (`current_loop` keeps its maximum).
#![no_std]
#![no_main]
// The benchmark harness (not the product): its fixtures may index and
// unwrap; a failure there is the benchmark failing.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use board_support::board;
use core::hint::black_box;
use cortex_m::peripheral::{syst::SystClkSource, SYST};
use defmt_semihosting as _;
use foc_core::angle::ElectricalAngle;
use foc_core::control::current::{CurrentLoop, CurrentLoopInput};
use foc_core::control::dead_time::DeadTimeCompensation;
use foc_core::control::stage::{PositionStage, SpeedStage, VelocityRef};
use foc_core::control::{Command, Feedback, Mode, MotorParams};
use foc_core::drive::cascade::CascadeConfig;
use foc_core::frames::{Abc, AlphaBeta, Dq};
use foc_core::{svpwm, transforms, trig};

mod breakdown;
mod drive;
mod registers;
mod sweeps;

const TICKS_PER_INSTRUCTION: f32 = 172.032;

/// Instructions of one item over its inputs.
#[derive(Clone, Copy)]
struct Stats {
    min: u32,
    max: u32,
    mean: f32,
    median: u32,
}

/// Up to 64 counts, summarised.
struct Samples {
    counts: [u32; 64],
    n: usize,
}

impl Samples {
    const fn new() -> Self {
        Self {
            counts: [0; 64],
            n: 0,
        }
    }

    /// Adds a count in SysTick ticks.
    fn push_ticks(&mut self, t: u32) {
        if self.n < self.counts.len() {
            self.counts[self.n] = (t as f32 / TICKS_PER_INSTRUCTION + 0.5) as u32;
            self.n += 1;
        }
    }

    fn stats(&mut self) -> Stats {
        let c = &mut self.counts[..self.n.max(1)];
        c.sort_unstable();
        let sum: u32 = c.iter().sum();
        Stats {
            min: c[0],
            max: c[c.len() - 1],
            mean: sum as f32 / c.len() as f32,
            median: c[c.len() / 2],
        }
    }
}

fn ticks(f: &mut dyn FnMut()) -> u32 {
    let t0 = SYST::get_current();
    f();
    let t1 = SYST::get_current();
    t0.wrapping_sub(t1) & 0x00FF_FFFF
}

/// Instructions of `f` over `n` (at most 64) runs, `prep(k)` untimed.
fn measure(baseline: u32, n: u32, prep: &mut dyn FnMut(u32), f: &mut dyn FnMut(u32)) -> Stats {
    let mut s = Samples::new();
    for k in 0..n {
        prep(k);
        s.push_ticks(ticks(&mut || f(k)).saturating_sub(baseline));
    }
    s.stats()
}

/// Like [`measure`] for the self-check: `n` timed runs after one untimed.
fn measure_warm(baseline: u32, n: u32, f: &mut dyn FnMut()) -> Stats {
    let mut s = Samples::new();
    for k in 0..=n {
        let t = ticks(&mut || f()).saturating_sub(baseline);
        if k > 0 {
            s.push_ticks(t);
        }
    }
    s.stats()
}

/// Like [`measure`] for the drive's period: physics and `prep` untimed
/// before it, `after` and the slower loops untimed after it.
fn measure_rig(
    rig: &mut drive::Rig,
    baseline: u32,
    n: u32,
    prep: fn(&mut drive::Rig, u32),
    after: &mut dyn FnMut(&drive::Rig),
) -> Stats {
    let mut s = Samples::new();
    for k in 0..n {
        board::sim::step_physics();
        prep(rig, k);
        s.push_ticks(ticks(&mut || rig.period()).saturating_sub(baseline));
        after(rig);
        rig.slower();
    }
    s.stats()
}

fn report(name: &str, r: Stats) {
    defmt::println!(
        "BENCH {=str} {=u32} {=u32} {=f32} {=u32}",
        name,
        r.min,
        r.max,
        r.mean,
        r.median
    );
}

fn motor() -> MotorParams {
    let m = board::SIM_MOTOR;
    MotorParams {
        pole_pairs: m.pole_pairs,
        r_ohm: m.r_ohm,
        ld_h: m.ld_h,
        lq_h: m.lq_h,
        flux_linkage_wb: m.flux_linkage_wb,
    }
}

/// The current loop's dead-time compensation as the firmware sets it
/// (`config::cascade`): the board's dead time, the band a share of the
/// 10 A limit.
fn dead_time_compensation() -> DeadTimeCompensation {
    DeadTimeCompensation::for_current_limit(board::DEAD_TIME_NS as f32 * 1e-9, 10.0)
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let mut cp = cortex_m::Peripherals::take().unwrap_or_else(|| mission_exit(1));
    let dp = board_support::pac::Peripherals::take().unwrap_or_else(|| mission_exit(1));
    let b = board::init(dp);
    board::sim::stop_period_source();
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(0x00FF_FFFF);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();

    let baseline = ticks(&mut || {});
    // The first of the calls is untimed (`k == 0`, the warm-up): QEMU's
    // first pass through a translation block ending at the SysTick read
    // counted 3 instructions more once, after an unrelated change moved
    // the code (`cargo xtask bench` prints the raw calls when this fails).
    let with = measure_warm(baseline, 4, &mut || nop100());
    let without = measure_warm(baseline, 4, &mut || nop0());
    report("self-check raw: call with 100 nops", with);
    report("self-check raw: call with none", without);
    report(
        "self-check: 100 nops (difference of two calls, expect 100)",
        Stats {
            min: with.min - without.min,
            max: with.max - without.max,
            mean: with.mean - without.mean,
            median: with.median - without.median,
        },
    );
    defmt::println!(
        "BASELINE {=u32}",
        (baseline as f32 / TICKS_PER_INSTRUCTION + 0.5) as u32
    );

    let mut cfg = CascadeConfig::for_motor(motor(), board::PWM_FREQUENCY_HZ as f32, 10.0);
    // The product's current loop: the board's dead time compensated.
    cfg.current.current.dead_time = dead_time_compensation();
    let angles: [u32; 8] = [
        0,
        0x1555_5555,
        0x2AAA_AAAB,
        0x4000_0000,
        0x6000_0000,
        0x9000_0000,
        0xC000_0000,
        0xE800_0000,
    ];
    let theta = |k: u32| ElectricalAngle::from_bits(angles[(k % 8) as usize]);
    // Balanced 2 A currents at each angle, computed before timing anything.
    let mut table = [Abc::default(); 8];
    for (k, t) in table.iter_mut().enumerate() {
        let th = ElectricalAngle::from_bits(angles[k]).to_radians();
        *t = Abc::new(
            2.0 * libm::cosf(th),
            2.0 * libm::cosf(th - 2.094_395_1),
            2.0 * libm::cosf(th + 2.094_395_1),
        );
    }
    let currents = |k: u32| table[(k % 8) as usize];
    // A 8 V voltage vector at each angle.
    let mut voltages = [AlphaBeta::new(0.0, 0.0); 8];
    for (k, v) in voltages.iter_mut().enumerate() {
        let th = ElectricalAngle::from_bits(angles[k]).to_radians();
        *v = AlphaBeta::new(8.0 * libm::cosf(th), 8.0 * libm::sinf(th));
    }
    let n = 64;

    // 1. Pieces.
    let mut sink = 0.0f32;
    report(
        "sin_cos",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let (s, c) = sin_cos_part(black_box(theta(k)));
            sink += black_box(s + c);
        }),
    );
    report(
        "Clarke + Park",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let d = clarke_park_part(black_box(currents(k)), black_box(0.3), black_box(0.95));
            sink += black_box(d.d + d.q);
        }),
    );
    report(
        "SVPWM (seven-segment) + compare values",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            black_box(svpwm_part(
                black_box(voltages[(k % 8) as usize]),
                black_box(24.0),
            ));
        }),
    );

    // 2. The current-loop math step: currents + angle in, compare values out.
    let mut cl = CurrentLoop::new(cfg.current.current);
    report(
        "current-loop math step (Clarke..SVPWM, compare values)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            black_box(math_step_part(
                &mut cl,
                black_box(&CurrentLoopInput {
                    i_abc_a: currents(k),
                    theta_e: theta(k),
                    omega_e_rad_s: 300.0,
                    v_bus_v: 24.0,
                    i_dq_ref_a: Dq::new(0.0, 2.0),
                }),
            ));
        }),
    );

    // 3. The drive's per-period call as the firmware makes it, in every
    //    scenario, then its parts one by one.
    let mut rig = drive::Rig::start(b);
    let worst = drive::measure_all(&mut rig, baseline);
    let (parts, emulated_io) = breakdown::measure_pieces(&mut rig, baseline, &currents);
    let real_io = registers::measure_real_board(baseline);
    defmt::println!(
        "INFO a real board's period, estimated: the call's worst case {=u32} - the emulated I/O {=u32} + the IHM07M1 register path {=u32} = {=u32}",
        worst.max,
        emulated_io,
        real_io,
        (worst.max + real_io).saturating_sub(emulated_io)
    );
    defmt::println!(
        "INFO the parts' worst cases, each measured alone (with its own call overhead), add up to {=u32}; the whole call's worst case is {=u32}",
        parts,
        worst.max
    );

    // 4. Speed and position stages with a live feedback (precomputed, so
    //    preparing the input is not timed).
    let mut fbs = [Feedback::INIT; 64];
    for (k, f) in fbs.iter_mut().enumerate() {
        f.mode = Mode::Velocity;
        f.active = Command::Velocity { rad_s: 50.0 };
        f.velocity_rad_s = 40.0 + k as f32 * 0.1;
    }
    let mut speed = SpeedStage::new(cfg.speed);
    report(
        "speed-loop step (SpeedStage::step)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let f = &fbs[(k % 64) as usize];
            sink += black_box(speed_part(&mut speed, black_box(f)));
        }),
    );
    for (k, f) in fbs.iter_mut().enumerate() {
        f.mode = Mode::Position;
        f.active = Command::Position { rad: 100.0 };
        f.position_rad = k as f32 * 0.01;
    }
    let mut pos = PositionStage::new(cfg.position);
    report(
        "position-loop step (PositionStage::step, trapezoid)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let r = position_part(&mut pos, black_box(&fbs[(k % 64) as usize]));
            sink += black_box(r.rad_s);
        }),
    );
    black_box(sink);

    // 5. The scope's per-period record (design §22), on the feedback the
    //    current loop publishes: idle, and armed with 4 and 8 signals,
    //    triggered on a command (never fires here: the whole ring is
    //    written every run).
    measure_scope(baseline, n, &fbs);

    // 6. The calibration routines' own work in each period of a short run
    //    (the drive's period through whole runs is among the scenarios).
    sweeps::measure_sweeps(baseline);
    defmt::println!("BENCH-DONE");
    mission_exit(0)
}

/// The scope's record in the states the current loop sees.
fn measure_scope(baseline: u32, n: u32, fbs: &[Feedback; 64]) {
    use foc_core::scope::{Scope, ScopeConfig, Signal};
    let mut scope = Scope::new([0.0f32; 1024]);
    report(
        "scope record, idle",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            scope_part(&mut scope, black_box(&fbs[(k % 64) as usize]));
        }),
    );
    for signals in [&Signal::ALL[..4], &Signal::ALL[..8]] {
        let mut c = ScopeConfig::new(signals);
        c.samples = 100;
        c.pre_trigger = 10;
        let _ = scope.configure(c);
        scope.arm(&fbs[0]);
        let name = if signals.len() == 4 {
            "scope record, armed, 4 signals, command trigger"
        } else {
            "scope record, armed, 8 signals, command trigger"
        };
        report(
            name,
            measure(baseline, n, &mut |_| {}, &mut |k| {
                scope_part(&mut scope, black_box(&fbs[(k % 64) as usize]));
            }),
        );
    }
}

#[inline(never)]
fn scope_part(s: &mut foc_core::scope::Scope<[f32; 1024]>, fb: &Feedback) {
    s.record(fb);
}

// The items are called through functions of their own, never inlined into
// the measuring closures, so that their counts depend on the library code
// only, not on how the bench's own code is optimised around them.

#[inline(never)]
fn sin_cos_part(theta: ElectricalAngle) -> (f32, f32) {
    trig::sin_cos(theta)
}

#[inline(never)]
fn clarke_park_part(i: Abc, sin: f32, cos: f32) -> Dq {
    transforms::park(transforms::clarke(i), sin, cos)
}

#[inline(never)]
fn svpwm_part(v: AlphaBeta, v_bus_v: f32) -> [u16; 3] {
    svpwm::compare_values(svpwm::svpwm(v, v_bus_v).duties, 4200)
}

#[inline(never)]
fn math_step_part(cl: &mut CurrentLoop, inp: &CurrentLoopInput) -> [u16; 3] {
    svpwm::compare_values(cl.step(inp).duties, 4200)
}

#[inline(never)]
fn speed_part(s: &mut SpeedStage, fb: &Feedback) -> f32 {
    s.step(fb, VelocityRef::default())
}

#[inline(never)]
fn position_part(p: &mut PositionStage, fb: &Feedback) -> VelocityRef {
    p.step(fb)
}

/// Exactly 100 `nop`s.
#[inline(never)]
fn nop100() {
    // SAFETY: plain `nop`s, no memory, stack or flags touched.
    unsafe {
        core::arch::asm!(
            ".rept 100",
            "nop",
            ".endr",
            options(nomem, nostack, preserves_flags)
        )
    }
}

/// The same call with an empty body (for the self-check's difference).
#[inline(never)]
fn nop0() {
    // SAFETY: empty.
    unsafe { core::arch::asm!("", options(nomem, nostack, preserves_flags)) }
}

fn mission_exit(code: u32) -> ! {
    board::sim::exit(code)
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    board::emergency_disable();
    defmt::println!("panic: {}", defmt::Display2Format(info));
    mission_exit(1)
}
