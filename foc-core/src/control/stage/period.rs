//! One PWM period of the current stage: sense, control, publish.

use super::*;

impl CurrentStage {
    /// The speed stage runs every `n` periods (0 counts as 1): its q-current
    /// reference is interpolated over that many periods (design §19).
    #[inline]
    pub fn set_speed_periods(&mut self, n: u32) {
        let n = n.max(1);
        if n != self.state.speed_periods {
            self.state.speed_periods = n;
            self.state.speed_inv_periods = 1.0 / n as f32;
        }
    }

    /// The speed stage's output `target_a` \[A\] as the current loop uses it
    /// this period: a new value is reached in a straight line over the
    /// speed-loop period instead of in one step.
    #[inline(always)]
    pub(super) fn interpolate_speed_output(&mut self, target_a: f32) -> f32 {
        let st = &mut self.state;
        if target_a != st.iq_target_a {
            st.iq_target_a = target_a;
            st.iq_step_a = (target_a - st.iq_interp_a) * st.speed_inv_periods;
        }
        let next = st.iq_interp_a + st.iq_step_a;
        let reached = if st.iq_step_a >= 0.0 {
            next >= target_a
        } else {
            next <= target_a
        };
        st.iq_interp_a = if reached { target_a } else { next };
        // Within the current limit in force now (it may have been lowered
        // while a ramp from a larger value was running).
        let lim = self.config.limits.max_current_a;
        clamp(st.iq_interp_a, -lim, lim)
    }

    /// One PWM period: commands, sensors, supervision, control. Returns what
    /// the bridge must do and the feedback for the slower stages.
    pub fn step(
        &mut self,
        slot: &CommandSlot,
        iq_ref_from_speed_a: f32,
        s: &Sample,
    ) -> (BridgeCommand, Feedback) {
        let mut fb = Feedback::INIT;
        let bridge = self.step_into(slot, iq_ref_from_speed_a, s, &mut fb);
        (bridge, fb)
    }

    /// [`Self::step`] with the feedback written in place into `fb` (every
    /// field): the firmware passes the feedback its other tasks read, so
    /// nothing is copied (design §20).
    pub fn step_into(
        &mut self,
        slot: &CommandSlot,
        iq_ref_from_speed_a: f32,
        s: &Sample,
        fb: &mut Feedback,
    ) -> BridgeCommand {
        self.state.period = self.state.period.wrapping_add(1);
        self.take_operator_actions(slot);
        let sensed = self.sense(s, iq_ref_from_speed_a);
        self.apply_command_timeout();
        let (out, i_ref, theta_e) = self.control(&sensed, iq_ref_from_speed_a);
        self.publish(out, i_ref, theta_e, sensed.v_bus_read_v, fb)
    }

    /// Step 2: sensors and supervision: the angle used this period, the phase
    /// currents and the checks of the fault supervisor. A failed read trips
    /// its fault and leaves zeros.
    #[inline(always)]
    pub(super) fn sense(&mut self, s: &Sample, iq_ref_from_speed_a: f32) -> Sensed {
        if self.sensorless.is_some() {
            return self.sense_sensorless(s);
        }
        if self.fallback.is_some() {
            return self.sense_with_fallback(s, iq_ref_from_speed_a);
        }
        self.sense_sensor(s, iq_ref_from_speed_a)
    }

    /// [`Self::sense`] on the angle sensor.
    #[inline(always)]
    pub(super) fn sense_sensor(&mut self, s: &Sample, iq_ref_from_speed_a: f32) -> Sensed {
        let mut sensed = Sensed::unread(s);
        match (s.currents, s.angle, s.v_bus_v) {
            (None, _, _) => self.supervisor.trip(Fault::CurrentSenseError),
            (_, None, _) => self.supervisor.trip(Fault::AngleSensorError),
            (_, _, None) => self.supervisor.trip(Fault::BusSenseError),
            (Some(cur), Some(raw), Some(v_bus_v)) => {
                // The sensor's own error off first (design §33): every
                // use of the angle below sees the corrected reading.
                let mech = self
                    .config
                    .angle
                    .mechanical(self.angle_correction.correct(self.reading(raw)));
                let innovation = self.tracker.update(mech);
                let innovation_step = innovation - self.state.last_innovation_rad;
                self.state.last_innovation_rad = innovation;
                let changed = self.state.last_raw != Some(raw);
                self.state.unchanged_periods = if changed {
                    self.state.speed_at_change_rad_s = self.tracker.velocity_rad_s();
                    self.state.emf_turned_rad = 0.0;
                    0
                } else {
                    self.state.unchanged_periods.saturating_add(1)
                };
                let used = self.angle_used(mech, changed);
                // The torque-fed observer (design §19) takes the angle used
                // (the reading itself for a fine sensor) and the q current
                // measured at the last period's start: the torque that
                // drove the rotor since (with a salient rotor's reluctance
                // torque, design §30).
                let torque_iq = self.net_torque_iq_a(self.state.last_i_dq);
                self.observer.update(used, torque_iq);
                sensed.theta_e = self.config.angle.electrical(used);
                sensed.i_abc = cur.to_abc();
                sensed.channels = cur.channels();
                // |i_ab|^2 against the squared limit: no square root (see
                // `Supervisor::check_vector_sq`).
                sensed.i_ab = transforms::clarke(sensed.i_abc);
                let i_ab = sensed.i_ab;
                let vector_sq = i_ab.alpha * i_ab.alpha + i_ab.beta * i_ab.beta;
                self.supervisor.check_vector_sq(
                    &Checks {
                        i_abc_a: sensed.i_abc,
                        measured_sum_a: cur.measured_sum_a(),
                        vector_current_a: 0.0, // unused: the square is passed
                        v_bus_v,
                        angle_innovation_rad: innovation.abs(),
                        angle_step_rad: innovation_step.abs(),
                        speed_rad_s: self.tracker.velocity_rad_s(),
                        temperature_c: s.temperature_c,
                    },
                    vector_sq,
                );
                self.state.last_raw = Some(raw);
                self.check_stuck(changed, iq_ref_from_speed_a);
            }
        }
        sensed
    }

    /// Step 4: control: the current loop in the active mode (`None`: bridge off).
    /// Returns the output, the dq current reference and the electrical
    /// angle used (the open-loop angle in open loop).
    #[inline(always)]
    pub(super) fn control(
        &mut self,
        sensed: &Sensed,
        iq_ref_from_speed_a: f32,
    ) -> (Option<CurrentLoopOutput>, Dq, ElectricalAngle) {
        let pp = self.config.angle.pole_pairs as f32;
        let w_e = self.tracker.velocity_rad_s() * pp;
        let requested = self.requested_iq(iq_ref_from_speed_a);
        self.state.travel_window_a = None;
        // The anticogging feed-forward (design §32) before the travel
        // limits, so that they hold against it too.
        let requested = self.with_cogging(requested, sensed.theta_e, w_e);
        let requested = requested.map(|iq| self.travel(iq));
        // The d current (MTPA, field weakening) and the q current within
        // the current circle (design §30).
        // Not under injection (design §28): its angle is the saliency's
        // at id = 0, which a d current would move.
        let i_ref =
            match requested {
                Some(iq) if !self.field.is_idle() && !self.injecting() => Some(
                    self.field
                        .reference(iq, w_e, sensed.v_bus_v, self.state.last_out_v_dq),
                ),
                Some(iq) => Some(Dq::new(0.0, iq)),
                None => None,
            };
        // Stepped every period (winding estimate, chopper), faulted or not.
        let windowed = self.power_window(sensed, w_e, i_ref.unwrap_or(Dq::ZERO));
        if self.supervisor.is_faulted() {
            self.state.active = Command::Disable;
            self.model.reset();
            self.field.reset();
            return (None, Dq::ZERO, sensed.theta_e);
        }
        // The closed-loop modes share one (inlined) current-loop call.
        let w = &self.power_report;
        let closed = i_ref.map(|i| {
            if windowed {
                braked(i, w, self.config.limits.max_current_a)
            } else {
                i
            }
        });
        let closed = if self.sensorless.is_some() {
            // Sensorless (design §27): on a start's field the loop runs here.
            match self.sensorless_field(closed, sensed, w_e, iq_ref_from_speed_a) {
                Ok(field) => return field,
                Err(closed) => closed,
            }
        } else {
            closed
        };
        let (out, i_ref, theta_e) = self.current_loop(closed, sensed, w_e);
        // The model takes its speed from the angle's change; for a coarse
        // sensor (halls) from the torque-fed observer, which knows the
        // acceleration between the edges (design §19).
        let w_observer = self.observer.velocity_rad_s() * pp;
        if closed.is_some()
            && !(self.sensors_plausible(out.as_ref(), sensed, i_ref, w_observer)
                && self.currents_track(out.as_ref(), i_ref, w_e, true))
        {
            // The bridge goes off: nothing recorded this period was applied.
            self.model.reset();
            self.state.active = Command::Disable;
            return (None, i_ref, theta_e);
        }
        if closed.is_none() {
            // Open loop or off: the angle does not drive the bridge; the
            // model waits, its speed window counts the reading's increments.
            self.model.idle(sensed.theta_e);
        }
        (out, i_ref, theta_e)
    }

    /// The sensorless drive runs on high-frequency injection (design §28).
    #[inline(always)]
    fn injecting(&self) -> bool {
        self.sensorless
            .as_ref()
            .is_some_and(|sl| sl.region().injects())
    }

    /// The q-current the active closed-loop mode asks for, before the
    /// travel limits and the power window (`None`: off or open loop); the
    /// speed stage's interpolation follows the mode.
    #[inline(always)]
    fn requested_iq(&mut self, iq_ref_from_speed_a: f32) -> Option<f32> {
        let lim = self.config.limits.max_current_a;
        let from_speed = if iq_ref_from_speed_a.is_finite() {
            clamp(iq_ref_from_speed_a, -lim, lim)
        } else {
            0.0
        };
        match self.state.active {
            Command::Disable | Command::OpenLoop { .. } => {
                self.state.iq_interp_a = 0.0;
                self.state.iq_target_a = from_speed;
                self.state.iq_step_a = 0.0;
                None
            }
            Command::Torque { iq_a } => {
                // The speed stage tracks this reference: entering velocity
                // mode interpolates from it.
                self.state.iq_interp_a = iq_a;
                self.state.iq_target_a = from_speed;
                self.state.iq_step_a = 0.0;
                Some(iq_a)
            }
            Command::Velocity { .. } | Command::Position { .. } => {
                Some(self.interpolate_speed_output(from_speed))
            }
            Command::Impedance(_) => {
                let iq = clamp(self.impedance_iq(), -lim, lim);
                // As in torque mode: the speed stage tracks it.
                self.state.iq_interp_a = iq;
                self.state.iq_target_a = from_speed;
                self.state.iq_step_a = 0.0;
                Some(iq)
            }
        }
    }

    /// The current loop on the closed-loop reference `closed`, else the
    /// open-loop voltage at the open-loop angle, else nothing; with the dq
    /// reference and the electrical angle used.
    #[inline(always)]
    fn current_loop(
        &mut self,
        closed: Option<Dq>,
        sensed: &Sensed,
        w_e: f32,
    ) -> (Option<CurrentLoopOutput>, Dq, ElectricalAngle) {
        match (closed, self.state.active) {
            (Some(i_ref), _) => {
                // `i_ab` is `clarke(i_abc)` (both zero when a read failed).
                let out = self.current.step_inline_ab(
                    &CurrentLoopInput {
                        i_abc_a: sensed.i_abc,
                        theta_e: sensed.theta_e,
                        omega_e_rad_s: w_e,
                        v_bus_v: sensed.v_bus_v,
                        i_dq_ref_a: i_ref,
                    },
                    sensed.i_ab,
                );
                (Some(out), i_ref, sensed.theta_e)
            }
            (
                None,
                Command::OpenLoop {
                    v_d_v,
                    v_q_v,
                    omega_e_rad_s,
                    ..
                },
            ) => {
                let th = self.state.ol_theta;
                self.state.ol_theta = th.add_radians(omega_e_rad_s * self.config.current.ts_s);
                let out = self.current.step_voltage(
                    sensed.i_abc,
                    th,
                    Dq::new(v_d_v, v_q_v),
                    sensed.v_bus_v,
                );
                (Some(out), Dq::ZERO, th)
            }
            (None, _) => (None, Dq::ZERO, sensed.theta_e),
        }
    }

    /// Step 5: the bridge command and the feedback. A control output that is
    /// itself invalid is a fault too.
    #[inline(always)]
    pub(super) fn publish(
        &mut self,
        out: Option<CurrentLoopOutput>,
        i_ref: Dq,
        theta_e: ElectricalAngle,
        v_bus_read_v: Option<f32>,
        fb: &mut Feedback,
    ) -> BridgeCommand {
        let v_bus = v_bus_read_v.unwrap_or(0.0);
        let out = match out {
            Some(o) if o.invalid => {
                self.supervisor.trip(Fault::NonFinite);
                self.state.active = Command::Disable;
                None
            }
            o => o,
        };
        self.note_speed(out.is_some());
        let (bridge, duties, v_dq, i_dq, limited) = match out {
            Some(o) => (
                BridgeCommand::Duties(o.duties),
                o.duties,
                o.v_dq_v,
                o.i_dq_a,
                o.voltage_limited,
            ),
            None => {
                self.current.reset();
                self.field.reset();
                (
                    self.safe_state(v_bus_read_v),
                    [0.5; 3],
                    Dq::ZERO,
                    Dq::ZERO,
                    false,
                )
            }
        };
        self.state.last_out_v_dq = v_dq;
        self.state.last_i_dq = i_dq;
        *fb = Feedback {
            mode: self.state.active.mode(),
            active: self.state.active,
            position_rad: self.tracker.position().to_radians(),
            velocity_rad_s: self.observer.velocity_rad_s(),
            disturbance_rad_s2: self.observer.disturbance_rad_s2(),
            theta_e,
            i_dq_a: i_dq,
            i_dq_ref_a: i_ref,
            v_dq_v: v_dq,
            v_bus_v: v_bus,
            duties,
            faults: self.supervisor.faults(),
            first_fault: self.supervisor.first_fault(),
            voltage_limited: limited,
            current_limit_a: self.config.limits.max_current_a,
            power: self.published_window(),
            period: self.state.period,
            angle_in_use: AngleInUse::Sensor,
        };
        if self.sensorless.is_some() {
            self.publish_sensorless(out.map(|o| o.duties), v_bus, fb);
        } else if self.fallback.is_some() {
            self.publish_beside(out.map(|o| o.duties), v_bus, fb);
        }
        bridge
    }
}

/// The power window's reference on top of the d-current reference `i`
/// (design §18, §30): the regen ramp's d braking is the window's `id`
/// less the `i.d` it was given; the deeper of the two d currents is
/// taken, not their sum (summed, the interior-PM stop from twice base
/// speed asked -18.2 A, beyond `psi / Ld`), and the q current stays in
/// the window and the current circle.
#[inline(always)]
fn braked(i: Dq, w: &PowerReport, max_current_a: f32) -> Dq {
    let brake = w.id_ref_a - i.d;
    let d = if brake < i.d { brake } else { i.d };
    let q = w.clamp(i.q);
    if i.d == 0.0 {
        // No d-current reference: the window as it always was.
        return Dq::new(w.id_ref_a, q);
    }
    let room = max_current_a * max_current_a - d * d;
    let lim = if room > 0.0 { crate::sqrtf(room) } else { 0.0 };
    Dq::new(d, clamp(q, -lim, lim))
}

impl Sensed {
    /// Nothing read yet: zeros, the bus and the temperature as read.
    #[inline(always)]
    pub(super) fn unread(s: &Sample) -> Self {
        Self {
            theta_e: ElectricalAngle::ZERO,
            i_abc: crate::frames::Abc::default(),
            channels: [None; 3],
            i_ab: crate::frames::AlphaBeta::new(0.0, 0.0),
            v_bus_v: s.v_bus_v.unwrap_or(0.0),
            v_bus_read_v: s.v_bus_v,
            temperature_c: s.temperature_c,
        }
    }
}

/// What [`CurrentStage::step`] measured this period (zeros where a read
/// failed).
#[derive(Clone, Copy, Debug)]
pub(super) struct Sensed {
    /// Electrical angle of the d axis from the sensor.
    pub(super) theta_e: ElectricalAngle,
    /// Phase currents \[A\].
    pub(super) i_abc: crate::frames::Abc,
    /// The channels as read (the frozen-channel check).
    pub(super) channels: [Option<f32>; 3],
    /// `clarke(i_abc)` \[A\].
    pub(super) i_ab: crate::frames::AlphaBeta,
    /// Bus voltage \[V\] (0 when the read failed).
    pub(super) v_bus_v: f32,
    /// The bus voltage as read.
    pub(super) v_bus_read_v: Option<f32>,
    /// Power-stage temperature as read.
    pub(super) temperature_c: Option<f32>,
}
