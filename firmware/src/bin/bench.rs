//! Exact instruction counts of the control code on the Cortex-M4F, under
//! QEMU (`cargo xtask bench`; emulated board only).
//!
//! QEMU runs with `-icount shift=10,align=off`: every instruction advances
//! virtual time by exactly 1024 ns, and SysTick (core clock, reload
//! 0xFFFFFF) by exactly 172.032 ticks (see the README, Instruction counts).
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

use board_support::board;
use core::hint::black_box;
use cortex_m::peripheral::{syst::SystClkSource, SYST};
use defmt_semihosting as _;
use foc_core::angle::ElectricalAngle;
use foc_core::control::cascade::CascadeConfig;
use foc_core::control::current::{CurrentLoop, CurrentLoopInput};
use foc_core::control::stage::{CurrentStage, PositionStage, SpeedStage, VelocityRef};
use foc_core::control::{drive, Command, CommandSlot, Feedback, Mode, MotorParams};
use foc_core::frames::{Abc, Dq};
use foc_core::{svpwm, transforms, trig};

const TICKS_PER_INSTRUCTION: f32 = 172.032;

fn ticks(f: &mut dyn FnMut()) -> u32 {
    let t0 = SYST::get_current();
    f();
    let t1 = SYST::get_current();
    t0.wrapping_sub(t1) & 0x00FF_FFFF
}

/// (min, max, mean) instructions of `f` over `n` runs, `prep(k)` untimed.
fn measure(
    baseline: u32,
    n: u32,
    prep: &mut dyn FnMut(u32),
    f: &mut dyn FnMut(u32),
) -> (u32, u32, f32) {
    let (mut lo, mut hi, mut sum) = (u32::MAX, 0u32, 0f32);
    for k in 0..n {
        prep(k);
        let t = ticks(&mut || f(k)).saturating_sub(baseline);
        let i = (t as f32 / TICKS_PER_INSTRUCTION + 0.5) as u32;
        lo = lo.min(i);
        hi = hi.max(i);
        sum += i as f32;
    }
    (lo, hi, sum / n as f32)
}

fn report(name: &str, r: (u32, u32, f32)) {
    defmt::println!("BENCH {=str} {=u32} {=u32} {=f32}", name, r.0, r.1, r.2);
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

#[cortex_m_rt::entry]
fn main() -> ! {
    let mut cp = cortex_m::Peripherals::take().unwrap_or_else(|| mission_exit(1));
    let dp = board_support::pac::Peripherals::take().unwrap_or_else(|| mission_exit(1));
    let mut b = board::init(dp);
    board::sim::stop_period_source();
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(0x00FF_FFFF);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();

    let baseline = ticks(&mut || {});
    let with = measure(baseline, 4, &mut |_| {}, &mut |_| nop100());
    let without = measure(baseline, 4, &mut |_| {}, &mut |_| nop0());
    report("self-check raw: call with 100 nops", with);
    report("self-check raw: call with none", without);
    report(
        "self-check: 100 nops (difference of two calls, expect 100)",
        (with.0 - without.0, with.1 - without.1, with.2 - without.2),
    );
    defmt::println!(
        "BASELINE {=u32}",
        (baseline as f32 / TICKS_PER_INSTRUCTION + 0.5) as u32
    );

    let cfg = CascadeConfig::for_motor(motor(), board::PWM_FREQUENCY_HZ as f32, 10.0);
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
    let n = 64;

    // 1. Pieces.
    let mut sink = 0.0f32;
    report(
        "sin_cos",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let (s, c) = trig::sin_cos(black_box(theta(k)));
            sink += black_box(s + c);
        }),
    );
    report(
        "Clarke + Park",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let i = transforms::clarke(black_box(currents(k)));
            let d = transforms::park(i, black_box(0.3), black_box(0.95));
            sink += black_box(d.d + d.q);
        }),
    );
    report(
        "SVPWM (seven-segment) + compare values",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let (s, c) = trig::sin_cos(theta(k));
            let v = foc_core::frames::AlphaBeta::new(8.0 * c, 8.0 * s);
            let o = svpwm::svpwm(black_box(v), black_box(24.0));
            black_box(svpwm::compare_values(o.duties, 4200));
        }),
    );

    // 2. The current-loop math step: currents + angle in, compare values out.
    let mut cl = CurrentLoop::new(cfg.current.current);
    report(
        "current-loop math step (Clarke..SVPWM, compare values)",
        measure(baseline, n, &mut |_| {}, &mut |k| {
            let out = cl.step(black_box(&CurrentLoopInput {
                i_abc_a: currents(k),
                theta_e: theta(k),
                omega_e_rad_s: 300.0,
                v_bus_v: 24.0,
                i_dq_ref_a: Dq::new(0.0, 2.0),
            }));
            black_box(svpwm::compare_values(out.duties, 4200));
        }),
    );

    // 3. The whole current-loop task body, trait I/O included: read the
    //    emulated board's sensors, CurrentStage::step (commands, tracker,
    //    supervisor, current loop), write the PWM.
    let mut stage = CurrentStage::new(cfg.current);
    // Closed loop needs a calibration permit (the simulated encoder's zero
    // is on the d axis, so the configured calibration is the true one).
    match foc_core::calibration::Calibrated::supplied(cfg.current.angle, cfg.current.current) {
        Ok(p) => stage.set_calibration(&p),
        Err(_) => mission_exit(1),
    }
    let mut slot = CommandSlot::INIT;
    slot.post(Command::Torque { iq_a: 1.0 });
    use foc_core::hal::{CurrentSense, PwmDriver};
    b.currents.set_offsets_a(Abc::default());
    // Warm up: start-up periods in torque mode.
    for _ in 0..50 {
        board::sim::step_physics();
        let s = drive::read_sample(&mut b.currents, &mut b.angle, &mut b.bus);
        let (br, _) = stage.step(&slot, 0.0, &s);
        let _ = drive::apply(&mut b.pwm, br);
    }
    let mut fb_out = Feedback::INIT;
    report(
        "sensor reads of the emulated board (drive::read_sample)",
        measure(
            baseline,
            n,
            &mut |_| board::sim::step_physics(),
            &mut |_| {
                let s = drive::read_sample(&mut b.currents, &mut b.angle, &mut b.bus);
                black_box(s);
            },
        ),
    );
    report(
        "current-loop task body (sensor reads, CurrentStage::step, PWM write)",
        measure(
            baseline,
            n,
            &mut |_| board::sim::step_physics(),
            &mut |_| {
                let s = drive::read_sample(&mut b.currents, &mut b.angle, &mut b.bus);
                let (br, fb) = stage.step(black_box(&slot), 0.0, &s);
                let _ = drive::apply(&mut b.pwm, br);
                fb_out = fb;
            },
        ),
    );
    defmt::println!(
        "INFO task body ran in mode {} with bridge on: {}",
        fb_out.mode,
        b.pwm.is_enabled()
    );

    // 3b. The same with the power limits the firmware configures on this
    //     board (`config::power_limits`: regen ramp, d-axis braking,
    //     winding and stage derating; issue 17).
    let mut cfg_p = cfg.current;
    cfg_p.power = Some(foc_core::control::power::PowerLimitsConfig::for_board(
        &cfg.current.supervisor,
        cfg.current.current.motor,
        board::STAGE_TEMPERATURE_SENSOR,
    ));
    let mut stage_p = CurrentStage::new(cfg_p);
    match foc_core::calibration::Calibrated::supplied(cfg.current.angle, cfg.current.current) {
        Ok(p) => stage_p.set_calibration(&p),
        Err(_) => mission_exit(1),
    }
    for _ in 0..50 {
        board::sim::step_physics();
        let s = drive::read_sample(&mut b.currents, &mut b.angle, &mut b.bus);
        let (br, _) = stage_p.step(&slot, 0.0, &s);
        let _ = drive::apply(&mut b.pwm, br);
    }
    report(
        "current-loop task body with the board's power limits",
        measure(
            baseline,
            n,
            &mut |_| board::sim::step_physics(),
            &mut |_| {
                let s = drive::read_sample(&mut b.currents, &mut b.angle, &mut b.bus);
                let (br, fb) = stage_p.step(black_box(&slot), 0.0, &s);
                let _ = drive::apply(&mut b.pwm, br);
                fb_out = fb;
            },
        ),
    );
    defmt::println!(
        "INFO power-limited task body: mode {}, active limit {}, winding {=f32} C, stage {=f32} C",
        fb_out.mode,
        fb_out.power.active,
        fb_out.power.winding_c,
        fb_out.power.stage_c
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
            sink += black_box(speed.step(black_box(f), VelocityRef::default()));
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
            let r = pos.step(black_box(&fbs[(k % 64) as usize]));
            sink += black_box(r.rad_s);
        }),
    );
    black_box(sink);
    defmt::println!("BENCH-DONE");
    mission_exit(0)
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
