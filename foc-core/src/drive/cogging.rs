//! The anticogging calibration driven through the current stage (design
//! §32): [`CoggingCalibration`] stepped once per PWM period by the
//! [`Lifecycle`](super::Lifecycle), its velocity requests posted through a
//! private [`CommandSlot`] as `Command::Velocity`, so the speed loop, the
//! fault supervisor and the safe state work as in normal control.
//!
//! **The sweep is a stiff spring.** Where the rotor's inertia `J` is
//! known (the speed observer's `kt / J`, from an identification or the
//! configuration), the sweep runs in impedance mode (design §21): a
//! spring-damper of natural frequency [`SWEEP_SPRING_HZ`], critically
//! damped, pulls the rotor along a reference that moves at the sweep
//! speed. The cogging's own stiffness (`T_cog N_cycles` per mechanical
//! radian) is negative on half of every cycle; the speed loop's (its
//! integral gain, 20 Hz) is far below it on a light rotor, and in
//! velocity mode the DJI M2006 stuck and slipped from tooth to tooth and
//! the HKC cheetah stuck for good. The spring is 3 to 7 times stiffer
//! than the cogging on every motor file. Without a known inertia the
//! sweep runs in velocity mode.
//!
//! Each finished pass's map is installed in the stage at once (the next
//! pass runs with it); a failed or aborted calibration puts the map the
//! stage had before back.

use crate::calibration::cogging::{CoggingCalConfig, CoggingCalibration};
use crate::calibration::{CalError, CalInput, CalStep, ClosedLoopFeedback};
use crate::control::cogging::CoggingMap;
use crate::control::joint::Impedance;
use crate::control::stage::{CurrentStage, Sample};
use crate::control::{BridgeCommand, Command, CommandSlot, Fault, Feedback, Mode};

/// Natural frequency of the sweep's spring \[Hz\]: inside the angle
/// tracker's 80 Hz, and stiffer than the cogging of every motor file.
pub const SWEEP_SPRING_HZ: f32 = 35.0;

/// How an anticogging period ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CoggingOutcome {
    /// Still running.
    Running,
    /// Finished: the stage holds the new map (its peak \[A\]).
    Done {
        /// The map's largest feed-forward \[A\].
        peak_a: f32,
        /// Periods the calibration took.
        periods: u32,
    },
    /// The routine failed (fault `CalibrationFailed` latched, old map back).
    Failed(CalError),
    /// Stopped by a supervisor fault or an operator `Disable` (`None`).
    Aborted(Option<Fault>),
}

/// The routine plus the private mailbox it drives the stage with.
#[derive(Clone, Copy, Debug)]
pub struct CoggingRun {
    cal: CoggingCalibration,
    slot: CommandSlot,
    last_fb: Option<Feedback>,
    /// The stage's map before the calibration (put back on failure).
    before: CoggingMap,
    installed_passes: u8,
    /// The spring of the sweep (stiffness, damping), when the inertia
    /// is known.
    spring: Option<(f32, f32)>,
    /// Direction of the sweep posted last (0: none yet).
    posted_dir: i8,
}

impl CoggingRun {
    /// A calibration on `stage` with the defaults for its motor, pole
    /// pairs and current limit ([`CoggingCalConfig::new`]).
    pub fn for_stage(stage: &CurrentStage, operator: &CommandSlot) -> Self {
        Self::new(defaults(stage), stage, operator)
    }

    /// [`Self::for_stage`] built in place in `dst`, for the interrupt that
    /// starts the run. The value is about 6 KB (the routine's tables, the
    /// stage's map before); `Some(Self::for_stage(..))` was built in a
    /// temporary on the stack and copied into the `Option` (about 6300
    /// instructions on the F4). Here the tables are zeroed where they stay
    /// and the stage's map copied in once (what the thumbv7em build does;
    /// without `unsafe` it is the optimiser's choice, not a guarantee).
    pub fn start_in<'a>(
        dst: &'a mut Option<Self>,
        stage: &CurrentStage,
        operator: &CommandSlot,
    ) -> &'a mut Self {
        let run = dst.insert(Self::without_before(defaults(stage), stage, operator));
        run.before = *stage.cogging();
        run
    }

    /// A calibration with `config`, through a private mailbox that starts
    /// as a copy of `operator` (as the identification's does).
    pub fn new(config: CoggingCalConfig, stage: &CurrentStage, operator: &CommandSlot) -> Self {
        let mut run = Self::without_before(config, stage, operator);
        run.before = *stage.cogging();
        run
    }

    /// All but the stage's map (`before` left empty). The small inputs
    /// are computed before the value is written, and it is inlined, so
    /// that the compiler writes it (mostly zeros) straight into its
    /// destination (not inlined, a kilobyte of it went through a
    /// temporary).
    #[inline(always)]
    fn without_before(
        config: CoggingCalConfig,
        stage: &CurrentStage,
        operator: &CommandSlot,
    ) -> Self {
        let mut slot = *operator;
        slot.seq = operator.seq.wrapping_add(0x4000_0000);
        slot.command = Command::Disable;
        let spring = spring_of(stage);
        Self {
            cal: CoggingCalibration::new(config),
            slot,
            last_fb: None,
            before: CoggingMap::EMPTY,
            installed_passes: 0,
            spring,
            posted_dir: 0,
        }
    }

    /// The routine (its progress, its last map).
    pub fn calibration(&self) -> &CoggingCalibration {
        &self.cal
    }

    fn input(&self, stage: &CurrentStage, s: &Sample) -> Option<CalInput> {
        let i_abc = s.currents?.to_abc();
        let mut inp = CalInput::open_loop(i_abc, stage.reading(s.angle?), s.v_bus_v?);
        inp.closed_loop = self
            .last_fb
            .filter(|f| matches!(f.mode, Mode::Velocity | Mode::Impedance))
            .map(|f| ClosedLoopFeedback {
                v_dq_v: f.v_dq_v,
                i_dq_a: f.i_dq_a,
                velocity_rad_s: f.velocity_rad_s,
                theta_e: f.theta_e,
            });
        Some(inp)
    }

    /// One PWM period through `stage`.
    pub fn step(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
    ) -> (CoggingOutcome, BridgeCommand, Feedback) {
        // A failed read is the stage's fault (it trips below), not the
        // routine's.
        let step = self.input(stage, s).map(|inp| self.cal.step(&inp));
        // A pass's map the stage refuses (a routine's share of a larger
        // limit than the stage's) fails the calibration, the old map back.
        let step = match step {
            Some(CalStep::Velocity { .. } | CalStep::Done(())) if !self.install_new_map(stage) => {
                Some(CalStep::Failed(CalError::ImplausibleResult))
            }
            other => other,
        };
        match step {
            None => {}
            Some(CalStep::Velocity { rad_s }) => self.post_sweep(rad_s),
            Some(CalStep::Done(())) => {
                // The peak from the map's scale (no scan: this period also
                // runs the stage).
                let out = CoggingOutcome::Done {
                    peak_a: stage.cogging().full_scale_a(),
                    periods: self.cal.elapsed_periods(),
                };
                return self.finish(stage, iq_ref_a, s, out);
            }
            Some(CalStep::Failed(e)) => {
                self.put_back(stage);
                stage.report_fault(Fault::CalibrationFailed);
                return self.finish(stage, iq_ref_a, s, CoggingOutcome::Failed(e));
            }
            // The routine asks for nothing else.
            Some(_) => {}
        }
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        self.last_fb = Some(fb);
        if let Some(f) = fb.first_fault {
            self.put_back(stage);
            return (CoggingOutcome::Aborted(Some(f)), b, fb);
        }
        (CoggingOutcome::Running, b, fb)
    }

    /// The sweep at `rad_s`: in velocity mode, or (with the spring) an
    /// impedance reference from where the rotor is, moving at the sweep
    /// speed in the requested direction, posted when the direction
    /// changes (the reference moves on by itself between).
    fn post_sweep(&mut self, rad_s: f32) {
        let Some((kp, kd)) = self.spring else {
            if self.slot.command != (Command::Velocity { rad_s }) {
                self.slot.post(Command::Velocity { rad_s });
            }
            return;
        };
        let dir: i8 = if rad_s < 0.0 { -1 } else { 1 };
        let Some(fb) = self.last_fb else {
            return;
        };
        if dir == self.posted_dir {
            return;
        }
        let c = self.cal.config();
        let w = c.sweep_e_rad_s / c.pole_pairs as f32;
        self.posted_dir = dir;
        self.slot.post(Command::Impedance(Impedance {
            position_rad: fb.position_rad,
            velocity_rad_s: dir as f32 * w,
            kp_nm_per_rad: kp,
            kd_nm_s_per_rad: kd,
            torque_ff_nm: 0.0,
            torque_limit_nm: f32::INFINITY,
        }));
    }

    /// A pass finished: its map goes into the stage (the next pass runs
    /// with it); false when the stage refused it.
    fn install_new_map(&mut self, stage: &mut CurrentStage) -> bool {
        if self.cal.passes_done() <= self.installed_passes {
            return true;
        }
        self.installed_passes = self.cal.passes_done();
        stage.set_cogging(self.cal.map()).is_ok()
    }

    fn put_back(&mut self, stage: &mut CurrentStage) {
        let _taken = stage.set_cogging(&self.before);
    }

    /// Stop on operator request: bridge off, the old map back.
    pub fn abort(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
    ) -> (CoggingOutcome, BridgeCommand, Feedback) {
        self.put_back(stage);
        self.finish(stage, iq_ref_a, s, CoggingOutcome::Aborted(None))
    }

    /// The last period: `Disable` through the private mailbox.
    fn finish(
        &mut self,
        stage: &mut CurrentStage,
        iq_ref_a: f32,
        s: &Sample,
        out: CoggingOutcome,
    ) -> (CoggingOutcome, BridgeCommand, Feedback) {
        self.slot.post(Command::Disable);
        let (b, fb) = stage.step(&self.slot, iq_ref_a, s);
        (out, b, fb)
    }
}

/// The calibration's defaults for `stage`'s motor, pole pairs and current
/// limit.
fn defaults(stage: &CurrentStage) -> CoggingCalConfig {
    let c = stage.config();
    CoggingCalConfig::new(
        c.angle.pole_pairs,
        1.0 / c.current.ts_s,
        c.limits.max_current_a,
    )
}

/// The sweep's spring `(kp, kd)` [N m/rad, N m s/rad] for the stage's
/// rotor: `J w^2` and `2 J w` at [`SWEEP_SPRING_HZ`], within the stage's
/// impedance limits; `None` when the inertia is unknown.
fn spring_of(stage: &CurrentStage) -> Option<(f32, f32)> {
    let c = stage.config();
    let a = c.observer.accel_per_a_rad_s2;
    let kt = c.current.motor.torque_constant_nm_per_a();
    if !(a.is_finite() && a > 0.0 && kt.is_finite() && kt > 0.0) {
        return None;
    }
    let j = kt / a;
    let w = core::f32::consts::TAU * SWEEP_SPRING_HZ;
    let kp = (j * w * w).min(c.limits.max_kp_nm_per_rad);
    let kd = (2.0 * j * w).min(c.limits.max_kd_nm_s_per_rad);
    (kp > 0.0 && kd > 0.0).then_some((kp, kd))
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::control::cogging::COGGING_BINS;
    use crate::control::MotorParams;
    use crate::drive::cascade::CascadeConfig;
    use std::format;

    /// Built in place, the run is the one built by value, whatever the
    /// destination held.
    #[test]
    fn started_in_place_as_built_by_value() {
        let motor = MotorParams {
            pole_pairs: 7,
            r_ohm: 0.2,
            ld_h: 100e-6,
            lq_h: 100e-6,
            flux_linkage_wb: 0.005,
        };
        let mut stage = CurrentStage::new(CascadeConfig::for_motor(motor, 20_000.0, 10.0).current);
        let map = CoggingMap::from_amps(&[0.1; COGGING_BINS]).unwrap();
        stage.set_cogging(&map).unwrap();
        let mut operator = CommandSlot::INIT;
        operator.post(Command::Velocity { rad_s: 1.0 });
        let by_value = CoggingRun::for_stage(&stage, &operator);
        let mut empty = None;
        let mut old = CoggingRun::for_stage(&stage, &CommandSlot::INIT);
        old.installed_passes = 3;
        let mut used = Some(old);
        for dst in [&mut empty, &mut used] {
            let run = CoggingRun::start_in(dst, &stage, &operator);
            assert_eq!(format!("{run:?}"), format!("{by_value:?}"));
            assert_eq!(run.before, map);
        }
    }
}
