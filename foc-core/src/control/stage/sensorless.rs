//! Sensorless (design §27): the angle the current loop uses, the field of
//! a start, and the hand-overs between the field and the observer.

use super::*;
use crate::control::flux_observer::ObserverConfig;
use crate::control::sensorless::{Region, Switch};

/// A dq vector of a frame read in a frame `rotate_rad` behind it.
fn turned(v: Dq, rotate_rad: f32) -> Dq {
    let (s, c) = libm::sincosf(rotate_rad);
    let ab = transforms::inverse_park(v, s, c);
    Dq::new(ab.alpha, ab.beta)
}

impl CurrentStage {
    /// The sensorless angle source, when configured.
    pub fn sensorless(&self) -> Option<&Sensorless> {
        self.sensorless.as_ref()
    }

    /// Install the flux observer beside the angle sensor (`None`: remove
    /// it; design §27). Its motor is the current loop's. It restarts (it
    /// must agree with the sensor again before it may take over). A drive
    /// running on the observer (sensorless, or limp-home) keeps doing so:
    /// the observer beside the sensor runs once it is on its sensor again
    /// ([`Self::set_sensorless`]`(None)`).
    pub fn set_beside(&mut self, cfg: Option<BesideConfig>) {
        let motor = self.config.current.motor;
        let cfg = cfg.map(|mut c| {
            c.sensorless.observer.motor = motor;
            c
        });
        if cfg == self.config.fallback {
            return;
        }
        self.config.fallback = cfg;
        self.fallback = cfg
            .filter(|_| self.config.sensorless.is_none())
            .map(super::fallback::Fallback::new);
    }

    /// Run without the angle sensor with `cfg` (design §27), or on the
    /// sensor again with `None`; its observer's motor is the current
    /// loop's. The observer and the start restart (alignment at the next
    /// enable), the angle tracker and the speed observer start again from
    /// the new source's first angle; the same configuration again changes
    /// nothing. Take it with
    /// the bridge off: the drive's rules refuse a configuration change
    /// while it runs. Torque, position and impedance commands are refused
    /// while sensorless ([`Mode::needs_angle_sensor`]) unless injection
    /// gives the angle at standstill; an active refused one is dropped to
    /// `Disable`.
    pub fn set_sensorless(&mut self, cfg: Option<SensorlessConfig>) {
        let motor = self.config.current.motor;
        let cfg = cfg.map(|c| SensorlessConfig {
            observer: ObserverConfig {
                motor,
                ..c.observer
            },
            ..c
        });
        if cfg == self.config.sensorless {
            return;
        }
        self.config.sensorless = cfg;
        self.sensorless = cfg.map(Sensorless::new);
        // On the sensor again (or not): the observer beside it restarts.
        self.state.limp_home = false;
        self.fallback = self
            .config
            .fallback
            .filter(|_| cfg.is_none())
            .map(super::fallback::Fallback::new);
        // The angle comes from elsewhere now: the tracker and the speed
        // observer start again from its first reading.
        self.state.last_innovation_rad = 0.0;
        self.tracker.reset();
        self.observer.reset();
        self.model.reset();
        // A refused mode, or a closed loop on a calibration made without
        // the sensor now that the sensor is back: dropped.
        let mode = self.state.active.mode();
        if self.sensorless_refuses(mode) || (mode.is_closed_loop() && !self.is_calibrated()) {
            self.state.active = Command::Disable;
        }
    }

    /// True when `mode` is refused: it needs the angle at standstill
    /// ([`Mode::needs_angle_sensor`]) and the drive runs sensorless without
    /// injection (with it, design §28, it holds torque at standstill).
    pub(super) fn sensorless_refuses(&self, mode: Mode) -> bool {
        self.sensorless
            .as_ref()
            .is_some_and(|s| !s.holds_torque_at_standstill())
            && mode.needs_angle_sensor()
    }

    /// The region in force (`None`: the drive runs on its angle sensor).
    pub fn sensorless_region(&self) -> Option<Region> {
        self.sensorless.as_ref().map(|s| s.region())
    }

    /// Sensorless period start: the observer takes the currents, its
    /// angle is the one used, the tracker and the speed observer follow
    /// the mechanical angle made from it; the supervisor's checks as with a
    /// sensor, less the reading's (there is none).
    #[inline(never)]
    pub(super) fn sense_sensorless(&mut self, s: &Sample) -> Sensed {
        let mut sensed = Sensed::unread(s);
        let pp = self.config.angle.pole_pairs;
        let (Some(cur), Some(v_bus_v), Some(sl)) =
            (s.currents, s.v_bus_v, self.sensorless.as_mut())
        else {
            let f = if s.currents.is_none() {
                Fault::CurrentSenseError
            } else {
                Fault::BusSenseError
            };
            self.supervisor.trip(f);
            return sensed;
        };
        sensed.i_abc = cur.to_abc();
        sensed.channels = cur.channels();
        sensed.i_ab = transforms::clarke(sensed.i_abc);
        let mech = sl.sense(sensed.i_ab, pp);
        sensed.theta_e = sl.angle();
        self.tracker.update(mech);
        self.observer.update(mech, self.state.torque_iq_a);
        let i_ab = sensed.i_ab;
        let vector_sq = i_ab.alpha * i_ab.alpha + i_ab.beta * i_ab.beta;
        self.supervisor.check_vector_sq(
            &Checks {
                i_abc_a: sensed.i_abc,
                measured_sum_a: cur.measured_sum_a(),
                vector_current_a: 0.0,
                v_bus_v,
                angle_innovation_rad: 0.0,
                angle_step_rad: 0.0,
                speed_rad_s: self.tracker.velocity_rad_s(),
                temperature_c: s.temperature_c,
            },
            vector_sq,
        );
        sensed
    }

    /// Sensorless: decides the region. In `Align` and `Field` it runs the
    /// current loop on the field and returns its output, reference and
    /// angle (`Ok`); in the injection's regions likewise on the
    /// injection's angle ([`Self::hfi_period`]); in `Observer` the closed loop's reference `closed`
    /// after a hand-over's turn of the loop's frame, with the field's d
    /// current still added and the q current held until the speed stage's
    /// next step (`Err`: the closed loop runs on the observer's angle).
    /// A lost lock latches [`Fault::ObserverLostLock`] (bridge off).
    #[inline(never)]
    pub(super) fn sensorless_field(
        &mut self,
        closed: Option<Dq>,
        sensed: &Sensed,
        w_e: f32,
        from_speed_a: f32,
    ) -> Result<(Option<CurrentLoopOutput>, Dq, ElectricalAngle), Option<Dq>> {
        let pp = f32::from(self.config.angle.pole_pairs);
        let Some(sl) = self.sensorless.as_mut() else {
            return Err(closed);
        };
        let target = match self.state.active {
            Command::Velocity { rad_s } => rad_s * pp,
            _ => 0.0,
        };
        match sl.step(closed.is_some(), target, self.state.last_i_dq) {
            Err(_) => {
                self.supervisor.trip(Fault::ObserverLostLock);
                self.state.active = Command::Disable;
                self.model.reset();
                return Ok((None, Dq::ZERO, sensed.theta_e));
            }
            Ok(Switch::Turn {
                rotate_rad,
                to_observer,
            }) => {
                let i = turned(self.state.last_i_dq, rotate_rad);
                let v = turned(self.state.last_out_v_dq, rotate_rad);
                // At the speed the loop's next step decouples with.
                let w = if to_observer {
                    w_e
                } else {
                    sl.field_speed_rad_s()
                };
                self.current.preload(v, i, w);
                if to_observer {
                    // The q current that carried the rotor is held until
                    // the speed stage's next step, which starts from it.
                    self.state.iq_interp_a = i.q;
                    self.state.iq_target_a = from_speed_a;
                    self.state.iq_step_a = 0.0;
                    sl.hold_iq(i.q, from_speed_a);
                }
            }
            Ok(Switch::Stay) => {}
        }
        if sl.region().injects() {
            return Ok(self.hfi_period(closed, sensed, from_speed_a));
        }
        if !matches!(sl.region(), Region::Align | Region::Field) {
            let Some(i) = closed else {
                return Err(None);
            };
            let blend = sl.take_blend_a();
            let q = match sl.held_iq(from_speed_a) {
                Some(held) => {
                    let lim = self.config.limits.max_current_a;
                    let held = crate::clamp(held, -lim, lim);
                    self.state.iq_interp_a = held;
                    held
                }
                None => i.q,
            };
            return Err(Some(Dq::new(i.d + blend, q)));
        }
        let field = sl.current_angle();
        // Within the current limit in force (a start current configured
        // above it, an identification's lower limit).
        let lim = self.config.limits.max_current_a;
        let i_ref = Dq::new(sl.field_current_a().min(lim), 0.0);
        let out = self.current.step_inline_ab(
            &CurrentLoopInput {
                i_abc_a: sensed.i_abc,
                theta_e: field,
                omega_e_rad_s: sl.field_speed_rad_s(),
                v_bus_v: sensed.v_bus_v,
                i_dq_ref_a: i_ref,
            },
            sensed.i_ab,
        );
        // The speed stage tracks the q current the field gives the rotor
        // as the observer sees it (bumpless hand-over).
        let to_rotor = field.diff_radians(sensed.theta_e);
        self.state.iq_interp_a = turned(out.i_dq_a, to_rotor).q;
        self.state.iq_target_a = from_speed_a;
        self.state.iq_step_a = 0.0;
        // The field is not the rotor's angle: the model check waits.
        self.model.idle(sensed.theta_e);
        Ok((Some(out), i_ref, field))
    }

    /// Injection (design §28): the current loop on the injection's angle
    /// and speed, on the mean of the last two samples (the injection's
    /// ripple cancels in it), with the injection's d voltage added to its
    /// output. Its reference: none while the estimate settles, the
    /// polarity test's d pulses, then the closed loop's `closed`. The
    /// model check waits (its model has no injection).
    #[inline(never)]
    fn hfi_period(
        &mut self,
        closed: Option<Dq>,
        sensed: &Sensed,
        from_speed_a: f32,
    ) -> (Option<CurrentLoopOutput>, Dq, ElectricalAngle) {
        let pp = f32::from(self.config.angle.pole_pairs.max(1));
        let Some(sl) = self.sensorless.as_mut() else {
            return (None, Dq::ZERO, sensed.theta_e);
        };
        let starting = sl.region().starting();
        let lim = self.config.limits.max_current_a;
        let i_ref = if starting {
            Dq::new(crate::clamp(sl.polarity_current_a(), -lim, lim), 0.0)
        } else {
            closed.unwrap_or(Dq::ZERO)
        };
        let angle = sl.angle();
        let (v_inject, mean) = sl.injection(sensed.i_ab);
        let mut out = self.current.step_inline_ab(
            &CurrentLoopInput {
                i_abc_a: sensed.i_abc,
                theta_e: angle,
                omega_e_rad_s: sl.speed_rad_s(),
                v_bus_v: sensed.v_bus_v,
                i_dq_ref_a: i_ref,
            },
            mean,
        );
        if !out.invalid {
            let (s, c) = out.sin_cos;
            let add = transforms::inverse_park(Dq::new(v_inject, 0.0), s, c);
            out.v_ab_v = crate::frames::AlphaBeta::new(
                out.v_ab_v.alpha + add.alpha,
                out.v_ab_v.beta + add.beta,
            );
            out.svpwm = crate::svpwm::svpwm_inline(out.v_ab_v, sensed.v_bus_v);
            out.duties = out.svpwm.duties;
            out.invalid = out.svpwm.invalid;
        }
        if starting {
            // The outer loops wait; the speed stage starts from no torque.
            self.state.iq_interp_a = 0.0;
            self.state.iq_target_a = from_speed_a;
            self.state.iq_step_a = 0.0;
        }
        self.model.idle(sensed.theta_e);
        // In the closed loop the currents must follow their reference (the
        // tracking check, design §16; the model check waits). On the
        // injection's angle (at low speed: the injection hands over to the
        // observer once it agrees) there is little back-EMF to excuse a
        // voltage limit, only the slewing of a large inductance: twice the
        // current range at half the voltage. A winding that does not take the current
        // (an open phase, where the injection locks onto the other two
        // phases' axis) trips here instead of leaving a load to turn the
        // rotor unopposed.
        self.state.limited_periods = if out.voltage_limited {
            self.state.limited_periods.saturating_add(1)
        } else {
            0
        };
        let v_max = self.config.current.max_modulation * sensed.v_bus_v * crate::FRAC_1_SQRT_3;
        let slew_s = 4.0 * self.config.current.motor.lq_h * lim / v_max;
        let slewing = (self.state.limited_periods as f32) * self.config.current.ts_s < slew_s;
        let w_e = self.tracker.velocity_rad_s() * pp;
        if !starting && !self.currents_track(Some(&out), i_ref, w_e, slewing) {
            self.state.active = Command::Disable;
            return (None, i_ref, angle);
        }
        (Some(out), i_ref, angle)
    }

    /// Sensorless end of period: the observer records the duties (or
    /// pauses with the bridge off); on a start's field the feedback
    /// reports open loop (the outer loops wait) and the speed observer
    /// takes the q current in the observer's frame; the published speed
    /// is the flux observer's PLL (its bandwidth is ten times the speed
    /// observer's, which a start's field feeds with a torque known too
    /// roughly) and no disturbance (the speed loop's integrator takes the
    /// load).
    #[inline(never)]
    pub(super) fn publish_sensorless(
        &mut self,
        duties: Option<[f32; 3]>,
        v_bus_v: f32,
        fb: &mut Feedback,
    ) {
        let pp = f32::from(self.config.angle.pole_pairs.max(1));
        let Some(sl) = self.sensorless.as_mut() else {
            return;
        };
        let on_field = sl.region().starting() && duties.is_some();
        sl.record(duties, v_bus_v);
        let injects = sl.region().injects();
        self.state.torque_iq_a = if on_field {
            self.state.iq_interp_a
        } else if injects {
            // Under injection the d reference is 0 (design §30): the q
            // current alone (the injection's d ripple times iq biased it),
            // less the anticogging's feed-forward (design §32).
            fb.i_dq_a.q - self.cogging.last_a
        } else {
            // On the flux observer MTPA and field weakening act: the
            // reluctance torque counted in.
            self.net_torque_iq_a(fb.i_dq_a)
        };
        if on_field {
            fb.mode = Mode::OpenLoop;
        }
        // On the injection's angle (the rotor's, from a PLL whose speed is
        // noisy) the torque-fed speed observer's estimate, which fuses the
        // torque in, stays the speed loop's feedback.
        let Some(sl) = self.sensorless.as_ref() else {
            return;
        };
        if !injects {
            fb.velocity_rad_s = sl.speed_rad_s() / pp;
        }
        // The speed observer's disturbance: with injection (it followed
        // the rotor's true angle and torque from the start) in every
        // region, so that a hand-over steps no feed-forward; without, none
        // (a start's field fed it a torque known too roughly: the speed
        // loop's integrator takes the load).
        if !sl.holds_torque_at_standstill() {
            fb.disturbance_rad_s2 = 0.0;
        }
        fb.angle_in_use = if self.state.limp_home {
            AngleInUse::LimpHome
        } else {
            AngleInUse::Sensorless
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A vector read in a frame 0.4 rad behind reads 0.4 rad further on;
    /// turning back restores it.
    #[test]
    fn turned_reads_a_vector_in_a_frame_behind() {
        let v = Dq::new(1.0, 0.0);
        let t = turned(v, 0.4);
        assert!((t.d - libm::cosf(0.4)).abs() < 1e-6 && (t.q - libm::sinf(0.4)).abs() < 1e-6);
        let back = turned(t, -0.4);
        assert!((back.d - 1.0).abs() < 1e-6 && back.q.abs() < 1e-6);
    }
}
