//! Homing (design §21): find where the joint is, and so the output frame's
//! zero.
//!
//! - [`HomingMethod::Present`]: the present position is the home position.
//! - [`HomingMethod::EndStop`]: drive slowly towards a mechanical end stop
//!   and find it by the current it takes to push, then back off.
//!
//! The search runs in impedance mode as a spring dragged at the search
//! speed (the law's position reference advances with its velocity):
//! `kp = kt I_home / backoff_rad`, damped with `kp` over 50 ms, its torque
//! limited to `kt I_home`. In free motion the rotor follows the moving
//! reference a little behind (friction / kp); against the stop the
//! reference runs on, the spring stretches and the law sits on its torque
//! limit: the stop is pressed with the homing current, never more, and
//! the current is steady there (a damper alone would chatter on the
//! sensor's counts). The stop is found when the q-current reference has
//! stayed above `detect_fraction * I_home` with the rotor nearly still for
//! `confirm_s`. The back-off is the same spring, still, at a point
//! `backoff_rad` from the stop: `I_home` at its start.
//!
//! A search gives up after `max_travel_rad`, or after twice the time the
//! travel takes at the search speed plus 2 s.
//!
//! The sequencer only reads [`Feedback`] and returns the commands to post;
//! whoever runs it (the simulated cascade, the firmware's position task)
//! posts them and turns the result into an output frame
//! ([`super::joint::OutputFrame::homed_at`]).
//!
//! Homing to an encoder index is not implemented: the angle-sensor trait
//! reports no index pulse.

use super::joint::Impedance;
use super::{Command, CommandError, Feedback, Limits, Mode};

/// How to home.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingMethod {
    /// The present position is home.
    Present,
    /// Search an end stop.
    EndStop(EndStop),
}

/// End-stop search settings (rotor frame, mechanical).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EndStop {
    /// Search velocity [rad/s]: its sign is the direction (non-zero).
    pub velocity_rad_s: f32,
    /// Homing current \[A\] (> 0, at most the current limit): the most the
    /// stop is pressed with.
    pub current_a: f32,
    /// Fraction of the homing current that, held with the rotor still,
    /// means the stop is reached (in (0, 1)); it must be well above the
    /// friction's share of the homing current.
    pub detect_fraction: f32,
    /// How long the stop must be held to count \[s\] (>= 0).
    pub confirm_s: f32,
    /// Distance to back off from the stop \[rad\] (> 0).
    pub backoff_rad: f32,
    /// Longest search \[rad\] before giving up (> 0).
    pub max_travel_rad: f32,
}

/// Why homing did not finish.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingError {
    /// A setting is out of range, or the search's command would be refused
    /// (its spring or damping above the limits: a longer back-off or a
    /// smaller current).
    Invalid(CommandError),
    /// No stop within `max_travel_rad`.
    NoStop,
    /// Something else took over (a fault, another command, the bridge off).
    Interrupted,
}

/// What the runner does after a step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HomingStep {
    /// Post this command.
    Post(Command),
    /// Keep going.
    Running,
    /// Homed: the rotor position \[rad\] that is home (the stop, or the
    /// present position); the last command posted holds the rotor.
    Done {
        /// Rotor position of the home point [rad, rotor].
        home_rotor_rad: f32,
    },
    /// Failed (the runner disables the bridge).
    Failed(HomingError),
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Sequence {
    Start,
    Search {
        start_rad: f32,
        held_s: f32,
        t_s: f32,
    },
    BackOff {
        stop_rad: f32,
        target_rad: f32,
        t_s: f32,
    },
    Finished,
}

/// The homing sequencer, stepped at any rate (its time is counted from
/// the feedback's period counter).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Homing {
    method: HomingMethod,
    /// Current-loop period \[s\].
    period_s: f32,
    kt_nm_per_a: f32,
    phase: Sequence,
    /// `Feedback::period` of the last step.
    last_period: Option<u32>,
    /// Time since the last step \[s\].
    dt_s: f32,
}

impl EndStop {
    /// Longest search \[s\].
    fn max_search_s(&self) -> f32 {
        2.0 * self.max_travel_rad / self.velocity_rad_s.abs() + 2.0
    }

    /// Check the settings against the limits and a torque constant.
    pub fn validate(&self, l: &Limits, kt_nm_per_a: f32) -> Result<(), CommandError> {
        let v = [
            self.velocity_rad_s,
            self.current_a,
            self.detect_fraction,
            self.confirm_s,
            self.backoff_rad,
            self.max_travel_rad,
        ];
        if !v.iter().all(|x| x.is_finite()) {
            return Err(CommandError::NonFinite);
        }
        if self.velocity_rad_s == 0.0
            || !super::within(self.velocity_rad_s.abs(), l.max_velocity_rad_s)
        {
            return Err(CommandError::VelocityOutOfRange);
        }
        if self.current_a <= 0.0 || !super::within(self.current_a, l.max_current_a) {
            return Err(CommandError::CurrentOutOfRange);
        }
        if !(self.detect_fraction > 0.0 && self.detect_fraction < 1.0)
            || self.confirm_s < 0.0
            || self.backoff_rad <= 0.0
            || self.max_travel_rad <= 0.0
        {
            return Err(CommandError::PositionOutOfRange);
        }
        if kt_nm_per_a <= 0.0 || !kt_nm_per_a.is_finite() {
            return Err(CommandError::NotCalibrated);
        }
        if !super::within(self.backoff_kp(kt_nm_per_a), l.max_kp_nm_per_rad) {
            return Err(CommandError::StiffnessOutOfRange);
        }
        if !super::within(self.backoff_kd(kt_nm_per_a), l.max_kd_nm_s_per_rad) {
            return Err(CommandError::DampingOutOfRange);
        }
        Ok(())
    }

    /// The search's and back-off's spring [N m/rad]: the homing current at
    /// `backoff_rad`.
    fn backoff_kp(&self, kt_nm_per_a: f32) -> f32 {
        kt_nm_per_a * self.current_a / self.backoff_rad
    }

    /// Their damping [N m s/rad]: the spring's over 50 ms (heavily damped
    /// on any rotor whose spring period is shorter).
    fn backoff_kd(&self, kt_nm_per_a: f32) -> f32 {
        0.05 * self.backoff_kp(kt_nm_per_a)
    }
}

impl Homing {
    /// A sequencer for a motor of torque constant `kt` [N m/A] and a
    /// current-loop period `period_s` \[s\] (the unit of
    /// [`Feedback::period`]), its settings checked against `limits`.
    pub fn new(
        method: HomingMethod,
        limits: &Limits,
        kt_nm_per_a: f32,
        period_s: f32,
    ) -> Result<Self, HomingError> {
        if let HomingMethod::EndStop(e) = method {
            e.validate(limits, kt_nm_per_a)
                .map_err(HomingError::Invalid)?;
        }
        if period_s <= 0.0 || !period_s.is_finite() {
            return Err(HomingError::Invalid(CommandError::NonFinite));
        }
        Ok(Self {
            method,
            period_s,
            kt_nm_per_a,
            phase: Sequence::Start,
            last_period: None,
            dt_s: 0.0,
        })
    }

    /// True once done or failed.
    pub fn finished(&self) -> bool {
        self.phase == Sequence::Finished
    }

    /// One step on the latest feedback.
    pub fn step(&mut self, fb: &Feedback, limits: &Limits) -> HomingStep {
        self.dt_s = match self.last_period {
            Some(last) => fb.period.wrapping_sub(last) as f32 * self.period_s,
            None => 0.0,
        };
        self.last_period = Some(fb.period);
        let p = fb.position_rad;
        let e = match self.method {
            HomingMethod::Present => {
                self.phase = Sequence::Finished;
                return HomingStep::Done { home_rotor_rad: p };
            }
            HomingMethod::EndStop(e) => e,
        };
        let step = match self.phase {
            Sequence::Finished => return HomingStep::Running,
            Sequence::Start => {
                self.phase = Sequence::Search {
                    start_rad: p,
                    held_s: 0.0,
                    t_s: 0.0,
                };
                let hold = clamp_range(p, limits);
                return HomingStep::Post(Command::Impedance(Impedance {
                    position_rad: hold,
                    velocity_rad_s: e.velocity_rad_s,
                    kp_nm_per_rad: e.backoff_kp(self.kt_nm_per_a),
                    kd_nm_s_per_rad: e.backoff_kd(self.kt_nm_per_a),
                    torque_ff_nm: 0.0,
                    torque_limit_nm: self.kt_nm_per_a * e.current_a,
                }));
            }
            _ if fb.mode != Mode::Impedance || fb.first_fault.is_some() => {
                HomingStep::Failed(HomingError::Interrupted)
            }
            Sequence::Search {
                start_rad,
                held_s,
                t_s,
            } => self.search(fb, &e, (start_rad, held_s, t_s), limits),
            Sequence::BackOff {
                stop_rad,
                target_rad,
                t_s,
            } => {
                let close = (p - target_rad).abs() <= 0.1 * e.backoff_rad
                    && fb.velocity_rad_s.abs() <= 0.1 * e.velocity_rad_s.abs();
                // A spring with the search's damping settles well within
                // a second; past that it is taken as settled wherever it is.
                if close || t_s >= 1.0 {
                    HomingStep::Done {
                        home_rotor_rad: stop_rad,
                    }
                } else {
                    self.phase = Sequence::BackOff {
                        stop_rad,
                        target_rad,
                        t_s: t_s + self.dt_s,
                    };
                    HomingStep::Running
                }
            }
        };
        if matches!(step, HomingStep::Done { .. } | HomingStep::Failed(_)) {
            self.phase = Sequence::Finished;
        }
        step
    }

    /// One step of the search: `(start_rad, held_s, t_s)` its start, how
    /// long the stop has been pressed, how long it has run.
    fn search(
        &mut self,
        fb: &Feedback,
        e: &EndStop,
        (start_rad, held_s, t_s): (f32, f32, f32),
        limits: &Limits,
    ) -> HomingStep {
        let p = fb.position_rad;
        let pushing = fb.i_dq_ref_a.q * e.velocity_rad_s.signum()
            >= e.detect_fraction * e.current_a
            && fb.velocity_rad_s.abs() <= 0.25 * e.velocity_rad_s.abs();
        let held_s = if pushing { held_s + self.dt_s } else { 0.0 };
        if pushing && held_s >= e.confirm_s {
            let back = -e.velocity_rad_s.signum() * e.backoff_rad;
            let target_rad = clamp_range(p + back, limits);
            self.phase = Sequence::BackOff {
                stop_rad: p,
                target_rad,
                t_s: 0.0,
            };
            return HomingStep::Post(Command::Impedance(Impedance {
                position_rad: target_rad,
                velocity_rad_s: 0.0,
                kp_nm_per_rad: e.backoff_kp(self.kt_nm_per_a),
                kd_nm_s_per_rad: e.backoff_kd(self.kt_nm_per_a),
                torque_ff_nm: 0.0,
                torque_limit_nm: self.kt_nm_per_a * e.current_a,
            }));
        }
        let t_s = t_s + self.dt_s;
        if (p - start_rad).abs() > e.max_travel_rad || t_s > e.max_search_s() {
            return HomingStep::Failed(HomingError::NoStop);
        }
        self.phase = Sequence::Search {
            start_rad,
            held_s,
            t_s,
        };
        HomingStep::Running
    }
}

fn clamp_range(p: f32, l: &Limits) -> f32 {
    crate::clamp(p, l.min_position_rad, l.max_position_rad)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A change to a valid value and the error it must give.
    type Case = (fn(&mut EndStop), CommandError);

    fn limits() -> Limits {
        Limits {
            max_current_a: 10.0,
            max_velocity_rad_s: 100.0,
            min_position_rad: -100.0,
            max_position_rad: 100.0,
            max_open_loop_voltage_v: 5.0,
            max_open_loop_omega_e_rad_s: 100.0,
            max_kp_nm_per_rad: 50.0,
            max_kd_nm_s_per_rad: 2.0,
        }
    }

    fn stop() -> EndStop {
        EndStop {
            velocity_rad_s: -2.0,
            current_a: 2.0,
            detect_fraction: 0.7,
            confirm_s: 0.01,
            backoff_rad: 0.5,
            max_travel_rad: 20.0,
        }
    }

    /// A point rotor on an ideal torque source with a stiff stop at
    /// `stop_rad`, driven by the sequencer's impedance law (its reference
    /// advancing with its velocity, as the current stage's), the sequencer
    /// stepped every 1 ms.
    fn run(e: EndStop, stop_rad: f32) -> (HomingStep, f32) {
        let l = limits();
        let kt = 0.1;
        let mut h = Homing::new(HomingMethod::EndStop(e), &l, kt, 5e-5).unwrap();
        let mut fb = Feedback::INIT;
        let (mut p, mut v) = (0.0f32, 0.0f32);
        let mut cmd: Option<Impedance> = None;
        let mut p_ref = 0.0f32;
        let mut peak_a = 0.0f32;
        for _ in 0..20_000 {
            match h.step(&fb, &l) {
                HomingStep::Post(Command::Impedance(i)) => {
                    cmd = Some(i);
                    p_ref = i.position_rad;
                }
                HomingStep::Post(c) => panic!("{c:?}"),
                HomingStep::Running => {}
                done => return (done, peak_a),
            }
            let c = cmd.unwrap();
            let mut iq = 0.0f32;
            // The drive's law every 50 us (its current loop), the rotor
            // integrated in the same steps.
            for _ in 0..20 {
                p_ref += c.velocity_rad_s * 5e-5;
                let t = (c.kp_nm_per_rad * (p_ref - p)
                    + c.kd_nm_s_per_rad * (c.velocity_rad_s - v)
                    + c.torque_ff_nm)
                    .clamp(-c.torque_limit_nm, c.torque_limit_nm);
                iq = t / kt;
                peak_a = peak_a.max(iq.abs());
                let wall = if (p - stop_rad) * e.velocity_rad_s.signum() > 0.0 {
                    -1e4 * (p - stop_rad) - 5.0 * v
                } else {
                    0.0
                };
                let j = 1e-3;
                v += (t + wall) / j * 5e-5;
                p += v * 5e-5;
            }
            fb.mode = Mode::Impedance;
            fb.period += 20;
            fb.position_rad = p;
            fb.velocity_rad_s = v;
            fb.i_dq_ref_a.q = iq;
        }
        (HomingStep::Running, peak_a)
    }

    #[test]
    fn finds_a_stop_in_either_direction_within_the_homing_current() {
        for (dir, stop_rad) in [(-1.0f32, -3.0f32), (1.0, 4.0)] {
            let mut e = stop();
            e.velocity_rad_s *= -dir;
            let (r, peak) = run(e, stop_rad);
            let HomingStep::Done { home_rotor_rad } = r else {
                panic!("{r:?}")
            };
            // The stop gives 2e-3 rad under 0.2 N m.
            assert!((home_rotor_rad - stop_rad).abs() < 5e-3, "{home_rotor_rad}");
            assert!(peak <= e.current_a * 1.001, "{peak}");
        }
    }

    #[test]
    fn no_stop_within_the_travel_fails() {
        let (r, _) = run(stop(), -50.0);
        assert_eq!(r, HomingStep::Failed(HomingError::NoStop));
    }

    #[test]
    fn bad_settings_are_refused() {
        let l = limits();
        let bad: [Case; 5] = [
            (|e| e.velocity_rad_s = 0.0, CommandError::VelocityOutOfRange),
            (|e| e.current_a = f32::NAN, CommandError::NonFinite),
            (|e| e.current_a = 11.0, CommandError::CurrentOutOfRange),
            (
                |e| e.detect_fraction = 1.0,
                CommandError::PositionOutOfRange,
            ),
            // kp = 0.1 * 2 / 0.001 = 200 > 50
            (|e| e.backoff_rad = 0.001, CommandError::StiffnessOutOfRange),
        ];
        for (f, err) in bad {
            let mut e = stop();
            f(&mut e);
            assert_eq!(
                Homing::new(HomingMethod::EndStop(e), &l, 0.1, 1e-3),
                Err(HomingError::Invalid(err))
            );
        }
    }

    #[test]
    fn present_position_is_home_at_once_and_interruption_is_seen() {
        let l = limits();
        let mut h = Homing::new(HomingMethod::Present, &l, 0.1, 1e-3).unwrap();
        let mut fb = Feedback::INIT;
        fb.position_rad = 1.25;
        assert_eq!(
            h.step(&fb, &l),
            HomingStep::Done {
                home_rotor_rad: 1.25
            }
        );
        let mut h = Homing::new(HomingMethod::EndStop(stop()), &l, 0.1, 1e-3).unwrap();
        assert!(matches!(h.step(&fb, &l), HomingStep::Post(_)));
        // The bridge went off (fb.mode still Disabled): interrupted.
        assert_eq!(
            h.step(&fb, &l),
            HomingStep::Failed(HomingError::Interrupted)
        );
        assert!(h.finished());
    }
}
