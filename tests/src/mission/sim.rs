//! [`Sim`]: the drive's cascade against the bench plant, period by period,
//! with an optional trace.

use super::*;

/// Names of the trace columns written by [`Sim`].
pub const TRACE_COLUMNS: [&str; 23] = [
    "id_a",
    "iq_a",
    "id_ref_a",
    "iq_ref_a",
    "vd_v",
    "vq_v",
    "speed_rad_s",
    "speed_est_rad_s",
    "speed_ref_rad_s",
    "position_rad",
    "position_est_rad",
    "position_ref_rad",
    "duty_a",
    "duty_b",
    "duty_c",
    "v_bus_v",
    "mode",
    "fault",
    "load_nm",
    "iq_true_a",
    "id_true_a",
    "bridge_on",
    "disturbance_rad_s2",
];

/// Plant + controller, stepped one PWM period at a time.
#[derive(Clone, Debug)]
pub struct Sim {
    /// The plant.
    pub plant: Plant,
    /// The controller.
    pub cascade: Cascade,
    /// Load torque applied from the next period [N m] (opposes positive rotation).
    pub load_nm: f32,
    pub(super) last: Measurements,
    pub(super) last_bridge: BridgeCommand,
    pub(super) trace: Option<Trace>,
    /// Encoder-frame position of the plant's true position 0 \[rad\]: `est = true - offset`.
    pub(super) encoder_offset_rad: f64,
    /// Current-sense offsets removed from every sample \[A\] (once calibrated).
    pub(super) current_offsets: Option<Abc>,
    /// The position stage has run since position mode was entered: its
    /// reference is this move's (before that it is the last move's, or 0).
    pub(super) position_planned: bool,
}

impl Sim {
    /// New simulation with the controller calibrated from the bench's
    /// knowledge ([`Setup::supplied_calibration`]), ready for closed loop.
    pub fn new_calibrated(setup: &Setup, config: CascadeConfig, record: bool) -> Self {
        let mut sim = Self::new(setup, config, record);
        sim.cascade
            .set_calibration(&setup.supplied_calibration(&config));
        sim
    }

    /// New simulation (bridge off, first sample taken), optionally recording
    /// a trace. The controller is uncalibrated (open loop only) until
    /// [`align`] or `cascade.set_calibration`.
    pub fn new(setup: &Setup, config: CascadeConfig, record: bool) -> Self {
        Self::with_plant(setup, Plant::new(setup.motor, setup.bench), config, record)
    }

    /// As [`Sim::new`] on a plant the caller prepared (e.g. with injected
    /// faults); `setup` gives the encoder offset of the true-position column.
    pub fn with_plant(
        setup: &Setup,
        mut plant: Plant,
        config: CascadeConfig,
        record: bool,
    ) -> Self {
        let last = plant.step_period([0.5; 3], false, 0.0);
        Self {
            plant,
            cascade: Cascade::new(config),
            load_nm: 0.0,
            last,
            last_bridge: BridgeCommand::SafeState,
            trace: record.then(|| Trace::new(&TRACE_COLUMNS)),
            encoder_offset_rad: setup.bench.sensors.encoder_offset_rad as f64,
            current_offsets: None,
            position_planned: false,
        }
    }

    /// Put the rotor at `theta_m` \[rad\] before the controller starts, and
    /// take a fresh sample there (one period with the bridge off).
    pub fn set_rotor_angle(&mut self, theta_m_rad: f64) {
        self.plant.set_rotor_angle(theta_m_rad as _);
        self.last = self.plant.step_period([0.5; 3], false, 0.0);
    }

    /// The plant's latest measurements (raw: current offsets not removed).
    pub fn last_sample(&self) -> &Measurements {
        &self.last
    }

    /// The sample the controller sees next: [`Sim::last_sample`] with the
    /// current offsets removed once [`Sim::set_current_offsets`] was called.
    pub fn sample(&self) -> Sample {
        let mut s = sample_of(&self.last);
        if let (Some(o), Some(c)) = (self.current_offsets, s.currents) {
            s.currents = Some(remove_offsets(c, o));
        }
        s
    }

    /// Remove these current-sense offsets \[A\] from every later sample (what
    /// the firmware's `CurrentSense::set_offsets_a` does after the offset
    /// calibration).
    pub fn set_current_offsets(&mut self, offsets: Abc) {
        self.current_offsets = Some(offsets);
    }

    /// The installed current-sense offsets \[A\].
    pub fn current_offsets(&self) -> Option<Abc> {
        self.current_offsets
    }

    /// The bridge command of the last step.
    pub fn last_bridge(&self) -> BridgeCommand {
        self.last_bridge
    }

    /// The recorded trace (if recording).
    pub fn trace(&self) -> Option<&Trace> {
        self.trace.as_ref()
    }

    /// Take the recorded trace.
    pub fn take_trace(&mut self) -> Option<Trace> {
        self.trace.take()
    }

    /// Rows recorded so far.
    pub fn rows(&self) -> usize {
        self.trace.as_ref().map_or(0, Trace::len)
    }

    /// One PWM period: the controller on the latest sample, then the plant.
    pub fn step(&mut self) -> BridgeCommand {
        let sample = self.sample();
        self.step_with(&sample)
    }

    /// As [`Sim::step`] with a sample the caller may have altered.
    pub fn step_with(&mut self, sample: &Sample) -> BridgeCommand {
        let bridge = self.cascade.step(sample);
        let (duties, on) = match bridge {
            BridgeCommand::SafeState => ([0.5; 3], false),
            BridgeCommand::ShortCircuit => ([0.0; 3], true),
            BridgeCommand::Duties(d) => (d, true),
        };
        if self.trace.is_some() {
            self.record(on);
        }
        self.last_bridge = bridge;
        // The brake chopper the drive asks for (a no-op without a DC link).
        self.plant.set_brake(self.cascade.feedback().power.brake_on);
        // What the firmware's `CurrentSense::set_offsets_a` does when the
        // drive hands over calibrated offsets.
        if let Some(o) = self.cascade.take_offsets() {
            self.set_current_offsets(o);
        }
        self.last = self.plant.step_period(duties, on, self.load_nm);
        bridge
    }

    /// Run `n` periods.
    pub fn run(&mut self, n: usize) {
        for _ in 0..n {
            self.step();
        }
    }

    /// True position in the encoder's frame (unwrapped) \[rad\].
    pub fn true_position_rad(&self) -> f64 {
        self.plant.position_rad() as f64 - self.encoder_offset_rad
    }

    pub(super) fn record(&mut self, on: bool) {
        let fb = *self.cascade.feedback();
        let nan = f64::NAN;
        let speed_ref = match fb.active {
            Command::Velocity { rad_s } => rad_s as f64,
            Command::Position { .. } => self.cascade.velocity_ref().rad_s as f64,
            _ => nan,
        };
        // The position stage runs every few periods: in the first periods
        // of a move its reference is still the previous move's (or 0).
        let position_mode = matches!(fb.active, Command::Position { .. });
        self.position_planned = position_mode
            && (self.position_planned
                || self.cascade.last_output().is_some_and(|o| o.run_position));
        let pos_ref = if self.position_planned {
            self.cascade.position.position_loop().reference().position as f64
        } else {
            nan
        };
        let row = [
            fb.i_dq_a.d as f64,
            fb.i_dq_a.q as f64,
            fb.i_dq_ref_a.d as f64,
            fb.i_dq_ref_a.q as f64,
            fb.v_dq_v.d as f64,
            fb.v_dq_v.q as f64,
            self.plant.omega_m_rad_s() as f64,
            fb.velocity_rad_s as f64,
            speed_ref,
            self.true_position_rad(),
            fb.position_rad as f64,
            pos_ref,
            fb.duties[0] as f64,
            fb.duties[1] as f64,
            fb.duties[2] as f64,
            fb.v_bus_v as f64,
            fb.mode as u8 as f64,
            fb.first_fault.map_or(0.0, |f| f.code() as f64),
            self.load_nm as f64,
            self.plant.iq_a() as f64,
            self.plant.id_a() as f64,
            if on { 1.0 } else { 0.0 },
            fb.disturbance_rad_s2 as f64,
        ];
        let t = self.last.time_s;
        if let Some(tr) = self.trace.as_mut() {
            tr.push(t, &row);
        }
    }
}
