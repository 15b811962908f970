//! # The RTIC v2 FOC application
//!
//! One binary per board (`cargo xtask build --board <name>`). Tasks, from
//! the highest priority down:
//!
//! | task | bound to | priority | rate (20 kHz PWM) | does |
//! |---|---|---|---|---|
//! | `bridge_break` | `TIM1_BRK_TIM9` | 5 | on fault | timer break / gate-driver fault: bridge off, latch `GateDriverFault` |
//! | `current_loop` | `ADC` (injected end of conversion, triggered by TIM1 at the PWM centre) | 4 | every PWM period, 20 kHz | start-up calibration, then read currents/angle/bus, `CurrentStage::step`, write PWM, pend the slower loops, measure its own time |
//! | `speed_loop` | `EXTI1` (pended by `current_loop`) | 3 | every `SPEED_DIVIDER` = 10 periods, 2 kHz | `SpeedStage::step`: velocity PI -> `iq_ref` |
//! | `position_loop` | `EXTI2` (pended by `current_loop`) | 2 | every `POSITION_DIVIDER` = 20 periods, 1 kHz | `PositionStage::step`: trajectory + P -> velocity reference |
//! | `housekeeping` | `EXTI3` (pended by `current_loop`) | 1 | every 400 periods, 50 Hz | start-up command, telemetry log, command-channel poll (link watchdog, streamed telemetry: at most one sample per run, so up to 50 Hz) |
//! | `serial` | `USART2` (`board::SERIAL_IRQ`, the command UART) | 1 | per received / sent byte | command channel: bytes to `DeviceState::on_byte`, replies queued (see `comms`) |
//! | `idle` | - | 0 | background | feeds the watchdog only while the current loop runs |
//!
//! `EXTI1..3` are used only as software-pended vectors: no EXTI line is
//! configured, so nothing else can trigger them.
//!
//! Start-up: clocks and pins (`board::init`, bridge off), current-offset
//! calibration (1024 periods with the bridge off, rejected when far from
//! mid-scale or noisy), an angle-sensor check, then (emulated board, or
//! `config::IDENTIFY_AT_STARTUP`) the motor identification (`calibrate`),
//! then the disabled mode, waiting for a command (`config::START_COMMAND` is
//! `None` by default). Until an identification (at start-up or on command)
//! has succeeded the current stage is uncalibrated and refuses torque,
//! velocity and position commands: a motor never runs closed loop on an
//! unknown electrical zero.
//!
//! Safety: any fault latched by the supervisor puts the bridge in the safe
//! state in the same period. The panic and HardFault handlers call
//! `board::emergency_disable()` before anything else, then log.
#![no_std]
#![no_main]

mod calibrate;
mod comms;
mod config;
#[cfg(feature = "qemu")]
mod mission;
mod timing;
mod watchdog;

use board_support::board;
use core::sync::atomic::AtomicU32;
#[cfg(not(feature = "qemu"))]
use defmt_rtt as _;
#[cfg(feature = "qemu")]
use defmt_semihosting as _;

/// Current-loop runs; `idle` feeds the watchdog only when this advances.
static CURRENT_LOOP_RUNS: AtomicU32 = AtomicU32::new(0);

#[rtic::app(device = board_support::pac, peripherals = true)]
mod app {
    use super::{comms, config, timing, watchdog, CURRENT_LOOP_RUNS};
    use board_support::board;
    use board_support::pac::Interrupt;
    use core::sync::atomic::Ordering;
    use foc_core::calibration::offsets::{OffsetCalibrator, OffsetLimits, OffsetStep};
    use foc_core::calibration::Calibrated;
    use foc_core::control::stage::{CurrentStage, PositionStage, SpeedStage, VelocityRef};
    use foc_core::control::{drive, Command, CommandSlot, Fault, Feedback};
    use foc_core::frames::Abc;
    use foc_core::hal::{CurrentSense, PwmDriver};

    /// Start-up phase of the current-loop task.
    #[derive(Clone, Copy, PartialEq, Eq, defmt::Format)]
    pub enum Phase {
        /// Averaging the current-sensor offsets with the bridge off.
        OffsetCalibration,
        /// Checking that the angle sensor answers.
        SensorCheck(u32),
        /// Motor identification (R, L, gains, alignment, flux linkage).
        Identify,
        /// Control running.
        Run,
    }

    #[shared]
    struct Shared {
        /// Command mailbox. Written by `housekeeping` (prio 1: start
        /// command, QEMU mission, link watchdog) and `serial` (prio 1:
        /// commands, keep-alives, fault clears from the link); read by
        /// `current_loop` (prio 4).
        command: CommandSlot,
        /// Feedback published every period. Written by `current_loop` (4);
        /// read by `speed_loop` (3), `position_loop` (2), `housekeeping` (1).
        feedback: Feedback,
        /// q-current reference [A]. Written by `speed_loop` (3); read by
        /// `current_loop` (4).
        iq_ref_a: f32,
        /// Velocity reference and torque feed-forward. Written by
        /// `position_loop` (2); read by `speed_loop` (3).
        velocity_ref: VelocityRef,
        /// Current-loop timing. Written by `current_loop` (4); read by
        /// `housekeeping` (1).
        timing: timing::LoopTiming,
        /// Set by `bridge_break` (5) when the break input fired; taken
        /// (cleared) by `current_loop` (4), which latches the fault.
        break_fired: bool,
        /// Start-up phase. Written by `current_loop` (4); read by
        /// `housekeeping` (1) and `serial` (1).
        phase: Phase,
        /// Configuration changes from the command channel. Written (merged)
        /// by `serial` and `housekeeping` (1); each part taken by its owner:
        /// `current` by `current_loop` (4), `speed` by `speed_loop` (3),
        /// `position` by `position_loop` (2), at their next run.
        config_request: comms::ConfigMailbox,
        /// Offsets calibrated and the current stage holds a calibration
        /// permit (closed-loop modes allowed). Written by `current_loop`
        /// (4) when it changes; read by `serial` and `housekeeping` (1).
        calibrated: bool,
        /// The command channel (UART, decoder, protocol state, settings).
        /// Used by `serial` and `housekeeping`, both priority 1, so never
        /// contended.
        comms: comms::Comms,
    }

    #[local]
    struct Local {
        /// `current_loop` only: the board's drivers and the current stage.
        pwm: board::Pwm,
        currents: board::Currents,
        angle: board::Angle,
        bus: board::Bus,
        stage: CurrentStage,
        offsets: OffsetCalibrator,
        tick: u32,
        /// `current_loop` only: speed / position dividers in force
        /// (changed through `config_request` while disabled).
        dividers: (u32, u32),
        /// `current_loop` only: offsets calibrated (false until the
        /// start-up calibration succeeds, and while it is re-run).
        offsets_ok: bool,
        /// `current_loop` only: last value written to `calibrated`.
        calibrated_seen: bool,
        /// `current_loop` only: the identification sequencer (phase `Identify`).
        identifier: super::calibrate::Identifier,
        /// `current_loop` only: the shared mailbox's command number when the
        /// identification started (a newer `Disable` aborts it).
        identify_seq: u32,
        /// `speed_loop` only.
        speed: SpeedStage,
        /// `position_loop` only.
        position: PositionStage,
        /// `housekeeping` only: start command posted.
        started: bool,
        /// `idle` only: last run count seen.
        seen_runs: u32,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let mut cp = cx.core;
        cp.DCB.enable_trace();
        cp.DWT.enable_cycle_counter();
        let watchdog_reset = watchdog::take_reset_flag();
        let b = board::init(cx.device);
        let cfg = config::cascade(board::PWM_FREQUENCY_HZ as f32);
        let mut stage = CurrentStage::new(cfg.current);
        if watchdog_reset {
            defmt::error!("reset by the watchdog");
            stage.report_fault(Fault::Watchdog);
        }
        // The ODrive's DRV8301 is configured over SPI in `board::init`.
        #[cfg(feature = "odrive-v3")]
        if b.gate_driver_config.is_err() {
            defmt::error!("DRV8301 configuration failed");
            stage.report_fault(Fault::GateDriverFault);
        }
        let mut currents = b.currents;
        currents.set_offsets_a(Abc::default());
        let budget = (board::SYSCLK_HZ as f32 / board::PWM_FREQUENCY_HZ as f32)
            * config::CURRENT_LOOP_BUDGET_FRACTION;
        defmt::info!(
            "{}: {} Hz PWM, speed /{}, position /{}, budget {} cycles",
            board::NAME,
            board::PWM_FREQUENCY_HZ,
            config::SPEED_DIVIDER,
            config::POSITION_DIVIDER,
            budget as u32
        );
        watchdog::start(config::WATCHDOG_TIMEOUT_MS);
        (
            Shared {
                command: CommandSlot::INIT,
                feedback: Feedback::INIT,
                iq_ref_a: 0.0,
                velocity_ref: VelocityRef::default(),
                timing: timing::LoopTiming {
                    budget_cycles: budget as u32,
                    ..Default::default()
                },
                break_fired: false,
                phase: Phase::OffsetCalibration,
                config_request: comms::ConfigMailbox::EMPTY,
                calibrated: false,
                comms: comms::Comms::new(b.serial),
            },
            Local {
                pwm: b.pwm,
                currents,
                angle: b.angle,
                bus: b.bus,
                stage,
                offsets: OffsetCalibrator::new(OffsetLimits {
                    samples: config::OFFSET_CAL_SAMPLES,
                    max_offset_a: config::OFFSET_CAL_MAX_A,
                    max_noise_a: config::OFFSET_CAL_MAX_NOISE_A,
                }),
                tick: 0,
                dividers: (
                    u32::from(cfg.rates.speed_divider.max(1)),
                    u32::from(cfg.rates.position_divider.max(1)),
                ),
                offsets_ok: false,
                calibrated_seen: false,
                identifier: super::calibrate::Identifier::new(
                    config::identification(board::PWM_FREQUENCY_HZ as f32),
                    &CommandSlot::INIT,
                ),
                identify_seq: 0,
                speed: SpeedStage::new(cfg.speed),
                position: PositionStage::new(cfg.position),
                started: false,
                seen_runs: 0,
            },
        )
    }

    #[idle(local = [seen_runs])]
    fn idle(cx: idle::Context) -> ! {
        loop {
            let runs = CURRENT_LOOP_RUNS.load(Ordering::Relaxed);
            if runs != *cx.local.seen_runs {
                *cx.local.seen_runs = runs;
                watchdog::feed();
            }
            cortex_m::asm::wfi();
        }
    }

    /// Timer break input / gate-driver fault: bridge off at once.
    #[task(binds = TIM1_BRK_TIM9, priority = 5, shared = [break_fired])]
    fn bridge_break(mut cx: bridge_break::Context) {
        board::emergency_disable();
        board::break_isr_ack();
        cx.shared.break_fired.lock(|b| *b = true);
    }

    /// The current loop: every PWM period, at the ADC end of conversion.
    #[task(
        binds = ADC,
        priority = 4,
        shared = [command, feedback, iq_ref_a, timing, break_fired, phase, config_request, calibrated],
        local = [pwm, currents, angle, bus, stage, offsets, tick, dividers, offsets_ok, calibrated_seen, identifier, identify_seq]
    )]
    fn current_loop(mut cx: current_loop::Context) {
        let t0 = timing::now_cycles();
        let l = cx.local;
        let sample = drive::read_sample(l.currents, l.angle, l.bus);
        let mut phase = cx.shared.phase.lock(|p| *p);
        // Configuration from the command channel (validated there; only
        // sent while disabled), before this period's command is read.
        if let Some(ch) = cx.shared.config_request.lock(|m| m.current.take()) {
            if let Some(lim) = ch.limits {
                l.stage.set_limits(lim);
            }
            if let Some(cur) = ch.current {
                // Keep the closed-loop permit: the same angle calibration
                // with the new gains, checked for plausibility.
                let angle = l.stage.config().angle;
                match Calibrated::supplied(angle, cur) {
                    Ok(p) if l.stage.is_calibrated() => l.stage.set_calibration(&p),
                    _ => l.stage.set_current_config(cur),
                }
            }
            if let Some((n, m)) = ch.dividers {
                *l.dividers = (u32::from(n.max(1)), u32::from(m.max(1)));
            }
            if let Some(f) = ch.fault {
                l.stage.report_fault(f);
            }
            if ch.identify
                && phase == Phase::Run
                && l.stage.active() == Command::Disable
                && !l.stage.supervisor().is_faulted()
            {
                let shared = cx.shared.command.lock(|c| *c);
                *l.identifier = super::calibrate::Identifier::new(
                    config::identification(board::PWM_FREQUENCY_HZ as f32),
                    &shared,
                );
                // A new identification never runs on the old calibration.
                l.stage.revoke_calibration();
                *l.identify_seq = shared.seq;
                phase = Phase::Identify;
                cx.shared.phase.lock(|p| *p = phase);
            }
            if ch.calibrate_offsets && phase == Phase::Run && l.stage.active() == Command::Disable {
                l.currents.set_offsets_a(Abc::default());
                *l.offsets = OffsetCalibrator::new(OffsetLimits {
                    samples: config::OFFSET_CAL_SAMPLES,
                    max_offset_a: config::OFFSET_CAL_MAX_A,
                    max_noise_a: config::OFFSET_CAL_MAX_NOISE_A,
                });
                *l.offsets_ok = false;
                phase = Phase::OffsetCalibration;
                cx.shared.phase.lock(|p| *p = phase);
            }
        }
        let next_phase = match phase {
            Phase::OffsetCalibration => {
                l.pwm.disable();
                let reading = sample.currents.map(|c| c.to_abc());
                match reading.map(|r| l.offsets.step(r)) {
                    Some(OffsetStep::InProgress) => phase,
                    Some(OffsetStep::Done(o)) => {
                        l.currents.set_offsets_a(o);
                        *l.offsets_ok = true;
                        defmt::info!("current offsets [A]: {}", o);
                        Phase::SensorCheck(0)
                    }
                    Some(OffsetStep::Failed(e)) => {
                        defmt::error!("offset calibration failed: {}", e);
                        l.stage.report_fault(Fault::CalibrationFailed);
                        Phase::Run
                    }
                    None => {
                        l.stage.report_fault(Fault::CurrentSenseError);
                        Phase::Run
                    }
                }
            }
            Phase::SensorCheck(n) => {
                l.pwm.disable();
                if sample.angle.is_none() {
                    defmt::error!("angle sensor check failed");
                    l.stage.report_fault(Fault::AngleSensorError);
                    Phase::Run
                } else if n + 1 >= config::SENSOR_CHECK_READS {
                    if config::IDENTIFY_AT_STARTUP {
                        defmt::info!("sensor check done: identifying the motor");
                        Phase::Identify
                    } else {
                        defmt::info!(
                            "start-up done: disabled and uncalibrated, waiting for a command"
                        );
                        Phase::Run
                    }
                } else {
                    Phase::SensorCheck(n + 1)
                }
            }
            Phase::Identify => {
                use super::calibrate::Outcome;
                if cx.shared.break_fired.lock(core::mem::take) || board::gate_driver_fault() {
                    l.stage.report_fault(Fault::GateDriverFault);
                }
                let iq = cx.shared.iq_ref_a.lock(|x| *x);
                // An operator `Disable` on the shared mailbox aborts.
                let shared = cx.shared.command.lock(|c| *c);
                let abort = shared.seq != *l.identify_seq && shared.command == Command::Disable;
                let outcome = if abort {
                    l.identifier.abort(l.stage, iq, &sample)
                } else {
                    l.identifier.step(l.stage, iq, &sample)
                };
                let (bridge, fb, next) = match outcome {
                    Outcome::Running(b, fb) => (b, fb, phase),
                    Outcome::Done(r, b, fb) => {
                        defmt::info!(
                            "identified: R {=f32} ohm, Ld {=f32} H, Lq {=f32} H, psi {=f32} Wb, {}",
                            r.r_ohm,
                            r.ld_h,
                            r.lq_h,
                            r.flux_linkage_wb,
                            r.angle
                        );
                        super::calibrate::publish(r);
                        (b, fb, Phase::Run)
                    }
                    Outcome::Failed(e, st, b, fb) => {
                        defmt::error!("identification failed in {}: {}", st, e);
                        (b, fb, Phase::Run)
                    }
                    Outcome::Aborted(f, st, b, fb) => {
                        defmt::error!("identification aborted in {}: fault {}", st, f);
                        (b, fb, Phase::Run)
                    }
                };
                if next == Phase::Run {
                    // Back to the shared mailbox with a fresh `Disable`, so
                    // no command sent before (or during) the identification
                    // starts the motor when it ends.
                    cx.shared.command.lock(|c| c.post(Command::Disable));
                }
                if let Err(f) = drive::apply(l.pwm, bridge) {
                    l.stage.report_fault(f);
                }
                cx.shared.feedback.lock(|f| *f = fb);
                next
            }
            Phase::Run => {
                if cx.shared.break_fired.lock(core::mem::take) || board::gate_driver_fault() {
                    l.stage.report_fault(Fault::GateDriverFault);
                }
                let slot = cx.shared.command.lock(|c| *c);
                let iq = cx.shared.iq_ref_a.lock(|x| *x);
                let (bridge, fb) = l.stage.step(&slot, iq, &sample);
                if let Err(f) = drive::apply(l.pwm, bridge) {
                    l.stage.report_fault(f);
                }
                cx.shared.feedback.lock(|f| *f = fb);
                phase
            }
        };
        if next_phase != phase {
            cx.shared.phase.lock(|p| *p = next_phase);
        }
        let calibrated = *l.offsets_ok && next_phase == Phase::Run && l.stage.is_calibrated();
        if calibrated != *l.calibrated_seen {
            *l.calibrated_seen = calibrated;
            cx.shared.calibrated.lock(|c| *c = calibrated);
        }
        *l.tick = l.tick.wrapping_add(1);
        let t = *l.tick;
        if t % l.dividers.0 == 0 {
            rtic::pend(Interrupt::EXTI1);
        }
        if t % l.dividers.1 == 0 {
            rtic::pend(Interrupt::EXTI2);
        }
        if t % config::HOUSEKEEPING_DIVIDER == 0 {
            rtic::pend(Interrupt::EXTI3);
        }
        CURRENT_LOOP_RUNS.fetch_add(1, Ordering::Relaxed);
        let dt = timing::now_cycles().wrapping_sub(t0);
        // Overrun: over the cycle budget, or the next period's conversion
        // (the interrupt that triggers this task) already pending again.
        let repended = cortex_m::peripheral::NVIC::is_pending(board::CURRENT_IRQ);
        if cx.shared.timing.lock(|tm| tm.record(dt, repended)) {
            // Takes effect (safe state) at the next period at the latest.
            l.stage.report_fault(Fault::LoopOverrun);
            l.pwm.disable();
        }
    }

    /// The speed loop: every `SPEED_DIVIDER` periods.
    #[task(binds = EXTI1, priority = 3, shared = [feedback, iq_ref_a, velocity_ref, config_request], local = [speed])]
    fn speed_loop(mut cx: speed_loop::Context) {
        if let Some(c) = cx.shared.config_request.lock(|m| m.speed.take()) {
            cx.local.speed.speed_loop().set_config(c);
        }
        let fb = cx.shared.feedback.lock(|f| *f);
        let vr = cx.shared.velocity_ref.lock(|v| *v);
        let iq = cx.local.speed.step(&fb, vr);
        cx.shared.iq_ref_a.lock(|x| *x = iq);
    }

    /// The position loop: every `POSITION_DIVIDER` periods.
    #[task(binds = EXTI2, priority = 2, shared = [feedback, velocity_ref, config_request], local = [position])]
    fn position_loop(mut cx: position_loop::Context) {
        if let Some(c) = cx.shared.config_request.lock(|m| m.position.take()) {
            cx.local.position.set_config(c);
        }
        let fb = cx.shared.feedback.lock(|f| *f);
        let vr = cx.local.position.step(&fb);
        cx.shared.velocity_ref.lock(|v| *v = vr);
    }

    /// Take a snapshot of the shared state for the command channel.
    fn link_snapshot(
        fb: &Feedback,
        tm: &timing::LoopTiming,
        phase: Phase,
        calibrated: bool,
    ) -> comms::Snapshot {
        comms::Snapshot {
            feedback: *fb,
            max_loop_cycles: tm.max_cycles,
            running: phase == Phase::Run,
            calibrated,
        }
    }

    /// The command channel: bytes from the UART to the protocol, replies
    /// back; each request's changes committed before the next is read.
    #[task(
        binds = USART2,
        priority = 1,
        shared = [command, feedback, timing, phase, config_request, calibrated, comms]
    )]
    fn serial(mut cx: serial::Context) {
        cx.shared.comms.lock(|c| c.serial.on_interrupt());
        // Bounded: every frame takes at least one byte of the RX ring.
        for _ in 0..board_support::hw::serial::RX_CAPACITY {
            let fb = cx.shared.feedback.lock(|f| *f);
            let tm = cx.shared.timing.lock(|t| *t);
            let phase = cx.shared.phase.lock(|p| *p);
            let cal = cx.shared.calibrated.lock(|c| *c);
            let snap = link_snapshot(&fb, &tm, phase, cal);
            let Some(out) = cx.shared.comms.lock(|c| c.receive(snap)) else {
                break;
            };
            if out.touches_config() {
                cx.shared.config_request.lock(|m| m.merge(&out.config));
            }
            if out.touches_command() {
                cx.shared.command.lock(|c| out.apply_command(c));
            }
        }
    }

    /// Housekeeping: start-up command, command-channel poll and telemetry, at 50 Hz.
    #[task(
        binds = EXTI3,
        priority = 1,
        shared = [command, feedback, timing, phase, config_request, calibrated, comms],
        local = [started]
    )]
    fn housekeeping(mut cx: housekeeping::Context) {
        let phase = cx.shared.phase.lock(|p| *p);
        if phase == Phase::Run && !*cx.local.started {
            *cx.local.started = true;
            if let Some(cmd) = config::START_COMMAND {
                cx.shared.command.lock(|c| c.post(cmd));
            }
        }
        let fb = cx.shared.feedback.lock(|f| *f);
        let tm = cx.shared.timing.lock(|t| *t);
        // Command channel: link watchdog and streamed telemetry.
        let cal = cx.shared.calibrated.lock(|c| *c);
        let snap = link_snapshot(&fb, &tm, phase, cal);
        let out = cx.shared.comms.lock(|c| c.poll(snap, fb.period));
        if out.touches_config() {
            cx.shared.config_request.lock(|m| m.merge(&out.config));
        }
        if out.touches_command() {
            cx.shared.command.lock(|c| out.apply_command(c));
        }
        #[cfg(feature = "qemu")]
        {
            let running = phase == Phase::Run;
            // Only this task writes the mailbox: copy, update, write back,
            // so the current loop is never blocked for the mission's logging.
            let mut slot = cx.shared.command.lock(|c| *c);
            let before = slot;
            let done = super::mission::tick(&fb, &mut slot, running, tm.overruns);
            if slot != before {
                cx.shared.command.lock(|c| *c = slot);
            }
            if let Some(code) = done {
                defmt::info!(
                    "current loop: {=u32} runs, max {=u32} cycles (DWT; 0 under QEMU), {=u32} overruns",
                    tm.runs,
                    tm.max_cycles,
                    tm.overruns
                );
                super::mission::exit(code);
            }
        }
        defmt::debug!(
            "mode {} w {} rad/s p {} rad iq {} A fault {} loop max {} cyc",
            fb.mode,
            fb.velocity_rad_s,
            fb.position_rad,
            fb.i_dq_a.q,
            fb.first_fault,
            tm.max_cycles
        );
    }
}

/// Panic: bridge off first, then log, then stop in a HardFault.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    board::emergency_disable();
    defmt::error!("panic: {}", defmt::Display2Format(info));
    #[cfg(feature = "qemu")]
    mission::panic_exit();
    #[cfg(not(feature = "qemu"))]
    cortex_m::asm::udf()
}

/// HardFault: bridge off first, then log, then wait for the watchdog.
#[cortex_m_rt::exception]
unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
    board::emergency_disable();
    defmt::error!("HardFault at pc {=u32:#x}", ef.pc());
    #[cfg(feature = "qemu")]
    mission::exit(mission::EXIT_HARDFAULT);
    #[cfg(not(feature = "qemu"))]
    loop {
        cortex_m::asm::nop();
    }
}

/// Runs in `defmt::panic!` and friends: same path as a Rust panic.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    board::emergency_disable();
    cortex_m::asm::udf()
}
