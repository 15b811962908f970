//! Scope capture (design §22): selected signals of the drive's
//! [`Feedback`], recorded every `divider`-th PWM period into a RAM ring,
//! with a trigger and samples kept from before it, read out afterwards.
//!
//! The firmware calls [`Scope::record`] once per current-loop period, right
//! after the drive has written the period's feedback. While the scope is
//! idle or its capture is done, that is one comparison; while armed, it
//! reads the selected signals into the ring and looks for the trigger (the
//! firmware bench counts the instructions, `cargo xtask bench`).
//!
//! Trigger sources ([`TriggerKind`]): none (only [`Scope::force`]), a new
//! active command (a period in which [`Feedback::active`] differs from the
//! period before), a newly latched fault, or a signal crossing a level
//! (rising, falling, either; checked on recorded samples). Command and
//! fault events are watched every period; the trigger sample is the first
//! recorded sample at or after the event (the event's own period when the
//! divider is 1, up to `divider - 1` periods later otherwise). The trigger sample and the
//! `samples - pre_trigger - 1` after it are kept, and up to `pre_trigger`
//! samples before it (fewer when the trigger came sooner after arming).
//!
//! Positions and velocities are the drive's own: rotor frame, mechanical.
//!
//! ```
//! use foc_core::control::{Command, Feedback};
//! use foc_core::scope::{Scope, ScopeConfig, Signal, State, TriggerKind};
//!
//! let mut scope = Scope::new([0.0f32; 256]);
//! let mut cfg = ScopeConfig::new(&[Signal::IqRefA, Signal::IqA]);
//! cfg.samples = 20;
//! cfg.pre_trigger = 5;
//! cfg.trigger = TriggerKind::Command;
//! scope.configure(cfg).unwrap();
//! let mut fb = Feedback::INIT;
//! scope.arm(&fb);
//! for k in 0..40 {
//!     if k == 10 {
//!         fb.active = Command::Torque { iq_a: 1.0 };
//!         fb.i_dq_ref_a.q = 1.0;
//!     }
//!     fb.period = k;
//!     scope.record(&fb);
//! }
//! let st = scope.status();
//! assert_eq!(st.state, State::Done);
//! assert_eq!((st.captured, st.trigger_index, st.trigger_period), (20, 5, 10));
//! let mut v = [0.0; 4];
//! // Samples 4 and 5 (the trigger), both channels: the reference steps.
//! assert_eq!(scope.read(8, &mut v), 4);
//! assert_eq!((v[0], v[2]), (0.0, 1.0));
//! ```

use crate::control::{Command, FaultSet, Feedback};

/// Most signals recorded at once.
pub const MAX_CHANNELS: usize = 8;

macro_rules! signals {
    ($($(#[$m:meta])* $name:ident = $code:expr, $text:expr, $unit:expr;)*) => {
        /// A recordable signal (rotor frame for positions and velocities).
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[repr(u8)]
        pub enum Signal {
            $($(#[$m])* $name = $code,)*
        }

        impl Signal {
            /// Every signal, in code order.
            pub const ALL: &'static [Signal] = &[$(Signal::$name),*];

            /// The signal with this wire code.
            pub const fn from_code(code: u8) -> Option<Self> {
                match code {
                    $($code => Some(Signal::$name),)*
                    _ => None,
                }
            }

            /// Short name (CSV column, command line).
            pub const fn name(self) -> &'static str {
                match self {
                    $(Signal::$name => $text,)*
                }
            }

            /// Unit of the value.
            pub const fn unit(self) -> &'static str {
                match self {
                    $(Signal::$name => $unit,)*
                }
            }
        }
    };
}

signals! {
    /// Measured d current \[A\].
    IdA = 0, "id", "A";
    /// Measured q current \[A\].
    IqA = 1, "iq", "A";
    /// d current reference \[A\].
    IdRefA = 2, "id_ref", "A";
    /// q current reference \[A\].
    IqRefA = 3, "iq_ref", "A";
    /// Commanded d voltage \[V\].
    VdV = 4, "vd", "V";
    /// Commanded q voltage \[V\].
    VqV = 5, "vq", "V";
    /// Estimated velocity [rad/s] (rotor, mechanical).
    VelocityRadS = 6, "velocity", "rad/s";
    /// Multi-turn position \[rad\] (rotor, mechanical).
    PositionRad = 7, "position", "rad";
    /// Bus voltage \[V\].
    BusV = 8, "vbus", "V";
    /// Phase A duty (0..1).
    DutyA = 9, "duty_a", "1";
    /// Phase B duty (0..1).
    DutyB = 10, "duty_b", "1";
    /// Phase C duty (0..1).
    DutyC = 11, "duty_c", "1";
    /// Electrical angle \[rad\] (0..2 pi).
    ThetaERad = 12, "theta_e", "rad";
    /// The active command's set-point: torque iq \[A\], velocity [rad/s],
    /// position \[rad\], impedance position \[rad\] (rotor); 0 otherwise.
    Target = 13, "target", "A | rad/s | rad";
    /// Mode code (0 disabled .. 5 impedance).
    ModeCode = 14, "mode", "code";
}

impl Signal {
    /// The signal's value in this period's feedback.
    #[inline]
    pub fn read(self, fb: &Feedback) -> f32 {
        match self {
            Signal::IdA => fb.i_dq_a.d,
            Signal::IqA => fb.i_dq_a.q,
            Signal::IdRefA => fb.i_dq_ref_a.d,
            Signal::IqRefA => fb.i_dq_ref_a.q,
            Signal::VdV => fb.v_dq_v.d,
            Signal::VqV => fb.v_dq_v.q,
            Signal::VelocityRadS => fb.velocity_rad_s,
            Signal::PositionRad => fb.position_rad,
            Signal::BusV => fb.v_bus_v,
            Signal::DutyA => fb.duties[0],
            Signal::DutyB => fb.duties[1],
            Signal::DutyC => fb.duties[2],
            Signal::ThetaERad => fb.theta_e.to_radians(),
            Signal::Target => target(&fb.active),
            Signal::ModeCode => fb.mode as u8 as f32,
        }
    }
}

/// The set-point of a command ([`Signal::Target`]).
pub fn target(c: &Command) -> f32 {
    match *c {
        Command::Torque { iq_a } => iq_a,
        Command::Velocity { rad_s } => rad_s,
        Command::Position { rad } => rad,
        Command::Impedance(i) => i.position_rad,
        Command::Disable | Command::OpenLoop { .. } => 0.0,
    }
}

/// What starts the part of the capture after the trigger.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum TriggerKind {
    /// Only [`Scope::force`].
    Manual = 0,
    /// A new active command.
    Command = 1,
    /// A newly latched fault.
    Fault = 2,
    /// The trigger signal rises through the level.
    Rising = 3,
    /// The trigger signal falls through the level.
    Falling = 4,
    /// Either crossing.
    Either = 5,
}

impl TriggerKind {
    /// The kind with this wire code.
    pub const fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            0 => Self::Manual,
            1 => Self::Command,
            2 => Self::Fault,
            3 => Self::Rising,
            4 => Self::Falling,
            5 => Self::Either,
            _ => return None,
        })
    }

    /// True for the level triggers.
    pub const fn is_level(self) -> bool {
        matches!(self, Self::Rising | Self::Falling | Self::Either)
    }
}

/// What to record and when.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScopeConfig {
    /// The signals; the first `channels` are recorded.
    pub signals: [Signal; MAX_CHANNELS],
    /// Signals recorded (1..=[`MAX_CHANNELS`]).
    pub channels: u8,
    /// Record every `divider`-th period (>= 1).
    pub divider: u16,
    /// Samples per signal (>= 2, at most capacity / channels); 0 = as many
    /// as the buffer holds.
    pub samples: u16,
    /// Samples kept before the trigger (< samples).
    pub pre_trigger: u16,
    /// Trigger source.
    pub trigger: TriggerKind,
    /// The signal a level trigger watches.
    pub trigger_signal: Signal,
    /// The level [the signal's unit] (finite for a level trigger).
    pub level: f32,
}

impl ScopeConfig {
    /// `signals` (at most [`MAX_CHANNELS`] taken), every period, as many
    /// samples as fit, a tenth before the trigger, triggered by a new
    /// command.
    pub fn new(signals: &[Signal]) -> Self {
        let mut s = [Signal::IqA; MAX_CHANNELS];
        let n = signals.len().min(MAX_CHANNELS);
        for (d, x) in s.iter_mut().zip(signals) {
            *d = *x;
        }
        Self {
            signals: s,
            channels: n as u8,
            divider: 1,
            samples: 0,
            pre_trigger: 0,
            trigger: TriggerKind::Command,
            trigger_signal: Signal::IqA,
            level: 0.0,
        }
    }

    /// The recorded signals.
    pub fn used(&self) -> &[Signal] {
        self.signals
            .get(..usize::from(self.channels))
            .unwrap_or(&[])
    }

    /// Checked against a buffer of `capacity` values: the configuration
    /// with `samples` resolved.
    pub fn resolve(mut self, capacity: usize) -> Result<Self, ScopeError> {
        let n = usize::from(self.channels);
        if n == 0 || n > MAX_CHANNELS {
            return Err(ScopeError::Channels);
        }
        if self.divider == 0 {
            return Err(ScopeError::Divider);
        }
        let fit = (capacity / n).min(usize::from(u16::MAX));
        if self.samples == 0 {
            self.samples = fit as u16;
        }
        if self.samples < 2 || usize::from(self.samples) > fit {
            return Err(ScopeError::Samples);
        }
        if self.pre_trigger >= self.samples {
            return Err(ScopeError::PreTrigger);
        }
        if self.trigger.is_level() && !self.level.is_finite() {
            return Err(ScopeError::Level);
        }
        Ok(self)
    }
}

/// Why a configuration was refused (nothing changed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScopeError {
    /// No signal, or more than [`MAX_CHANNELS`].
    Channels,
    /// Divider 0.
    Divider,
    /// Fewer than 2 samples, or more than the buffer holds.
    Samples,
    /// Pre-trigger samples not below the samples.
    PreTrigger,
    /// A level trigger's level is not finite.
    Level,
    /// The scope is not in the state the request needs (trigger while not
    /// armed, read before the capture is done).
    State,
}

/// Where a capture is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum State {
    /// Not recording.
    Idle = 0,
    /// Recording, waiting for the trigger.
    Armed = 1,
    /// Triggered, recording the rest.
    Triggered = 2,
    /// Capture complete: can be read.
    Done = 3,
}

impl State {
    /// The state with this wire code.
    pub const fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            0 => Self::Idle,
            1 => Self::Armed,
            2 => Self::Triggered,
            3 => Self::Done,
            _ => return None,
        })
    }
}

/// A scope's state and configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScopeStatus {
    /// Where the capture is.
    pub state: State,
    /// The configuration in force (`samples` resolved).
    pub config: ScopeConfig,
    /// Samples per signal recorded so far (armed: up to `samples`); when
    /// done, the samples per signal [`Scope::read`] returns.
    pub captured: u16,
    /// Index of the trigger sample in the readout (triggered or done).
    pub trigger_index: u16,
    /// The feedback's period counter at the trigger sample.
    pub trigger_period: u32,
    /// Values the buffer holds.
    pub capacity: u16,
}

/// The default configuration: q-current reference and measurement, d
/// current, q voltage, every period, a tenth of the samples before a new
/// command.
pub fn default_config(capacity: usize) -> ScopeConfig {
    let mut c = ScopeConfig::new(&[Signal::IqRefA, Signal::IqA, Signal::IdA, Signal::VqV]);
    let samples = (capacity / 4).clamp(2, usize::from(u16::MAX)) as u16;
    c.samples = samples;
    c.pre_trigger = samples / 10;
    c
}

/// The capture ring over a buffer `B` of `f32` values (an array, or a
/// `&'static mut [f32]` in the firmware).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scope<B> {
    buf: B,
    config: ScopeConfig,
    state: State,
    /// Ring slot (sample index) the next sample goes to.
    head: u16,
    /// Samples recorded since arming (saturating at `samples`).
    recorded: u16,
    /// Periods until the next recorded sample.
    countdown: u16,
    /// Samples still to record after the trigger.
    post_left: u16,
    /// Ring slot of the trigger sample.
    trigger_slot: u16,
    trigger_index: u16,
    trigger_period: u32,
    /// A trigger event waits for the next recorded sample.
    pending: bool,
    last_active: Command,
    last_faults: FaultSet,
    /// The trigger signal at the last recorded sample, once there is one.
    last_level: Option<f32>,
}

impl<B: AsRef<[f32]> + AsMut<[f32]>> Scope<B> {
    /// Idle, with [`default_config`] (buffers beyond `u16::MAX` values use
    /// only that many).
    pub fn new(buf: B) -> Self {
        let capacity = Self::capacity_of(&buf);
        let config = default_config(capacity);
        Self {
            buf,
            config,
            state: State::Idle,
            head: 0,
            recorded: 0,
            countdown: 1,
            post_left: 0,
            trigger_slot: 0,
            trigger_index: 0,
            trigger_period: 0,
            pending: false,
            last_active: Command::Disable,
            last_faults: FaultSet::EMPTY,
            last_level: None,
        }
    }

    fn capacity_of(buf: &B) -> usize {
        buf.as_ref().len().min(usize::from(u16::MAX))
    }

    /// Values the buffer holds.
    pub fn capacity(&self) -> usize {
        Self::capacity_of(&self.buf)
    }

    /// Take a configuration (checked whole; refused, nothing changes). The
    /// scope goes idle and its capture is dropped.
    pub fn configure(&mut self, config: ScopeConfig) -> Result<(), ScopeError> {
        self.config = config.resolve(self.capacity())?;
        self.state = State::Idle;
        self.recorded = 0;
        Ok(())
    }

    /// The configuration in force.
    pub fn config(&self) -> &ScopeConfig {
        &self.config
    }

    /// Start recording, waiting for the trigger. `now` is the latest
    /// feedback the caller has: its command and faults do not trigger (a
    /// command posted but not yet taken by the drive does, when it is).
    pub fn arm(&mut self, now: &Feedback) {
        self.state = State::Armed;
        self.head = 0;
        self.recorded = 0;
        self.countdown = 1;
        self.pending = false;
        self.trigger_index = 0;
        self.trigger_period = 0;
        self.last_active = now.active;
        self.last_faults = now.faults;
        self.last_level = None;
    }

    /// Stop (the capture is dropped).
    pub fn stop(&mut self) {
        self.state = State::Idle;
        self.recorded = 0;
    }

    /// Trigger now (at the next recorded sample); refused unless armed.
    pub fn force(&mut self) -> Result<(), ScopeError> {
        if self.state != State::Armed {
            return Err(ScopeError::State);
        }
        self.pending = true;
        Ok(())
    }

    /// State, configuration and the capture's extent.
    pub fn status(&self) -> ScopeStatus {
        let captured = match self.state {
            State::Done => self.trigger_index.saturating_add(self.post_count()),
            _ => self.recorded,
        };
        ScopeStatus {
            state: self.state,
            config: self.config,
            captured,
            trigger_index: self.trigger_index,
            trigger_period: self.trigger_period,
            capacity: self.capacity() as u16,
        }
    }

    /// Samples from the trigger on.
    fn post_count(&self) -> u16 {
        self.config.samples.saturating_sub(self.config.pre_trigger)
    }

    /// One period's feedback: records it when due, watches the trigger.
    #[inline]
    pub fn record(&mut self, fb: &Feedback) {
        if matches!(self.state, State::Idle | State::Done) {
            return;
        }
        self.record_armed(fb);
    }

    fn record_armed(&mut self, fb: &Feedback) {
        if self.state == State::Armed {
            self.watch_events(fb);
        }
        self.countdown = self.countdown.saturating_sub(1);
        if self.countdown > 0 {
            return;
        }
        self.countdown = self.config.divider;
        let slot = self.head;
        self.write_sample(slot, fb);
        if self.state == State::Armed {
            self.watch_level(fb);
            if self.pending {
                self.trigger_at(slot, fb.period);
            }
        }
        self.head = if slot.saturating_add(1) >= self.config.samples {
            0
        } else {
            slot + 1
        };
        self.recorded = self.recorded.saturating_add(1).min(self.config.samples);
        if self.state == State::Triggered {
            self.post_left = self.post_left.saturating_sub(1);
            if self.post_left == 0 {
                self.state = State::Done;
            }
        }
    }

    /// Command and fault triggers, every period.
    fn watch_events(&mut self, fb: &Feedback) {
        match self.config.trigger {
            TriggerKind::Command => {
                if fb.active != self.last_active {
                    self.pending = true;
                }
                self.last_active = fb.active;
            }
            TriggerKind::Fault => {
                if fb.faults.0 & !self.last_faults.0 != 0 {
                    self.pending = true;
                }
                self.last_faults = fb.faults;
            }
            _ => {}
        }
    }

    /// Level triggers, on recorded samples.
    fn watch_level(&mut self, fb: &Feedback) {
        let kind = self.config.trigger;
        if !kind.is_level() {
            return;
        }
        let v = self.config.trigger_signal.read(fb);
        let Some(last) = self.last_level.replace(v) else {
            return;
        };
        let level = self.config.level;
        let rising = last < level && v >= level;
        let falling = last > level && v <= level;
        let crossed = match kind {
            TriggerKind::Rising => rising,
            TriggerKind::Falling => falling,
            _ => rising || falling,
        };
        self.pending |= crossed;
    }

    fn trigger_at(&mut self, slot: u16, period: u32) {
        self.pending = false;
        self.state = State::Triggered;
        self.trigger_slot = slot;
        self.trigger_period = period;
        self.trigger_index = self.recorded.min(self.config.pre_trigger);
        self.post_left = self.post_count();
    }

    fn write_sample(&mut self, slot: u16, fb: &Feedback) {
        let n = usize::from(self.config.channels);
        let base = usize::from(slot) * n;
        let signals = self.config.signals;
        if let Some(dst) = self.buf.as_mut().get_mut(base..base + n) {
            for (d, s) in dst.iter_mut().zip(signals.iter()) {
                *d = s.read(fb);
            }
        }
    }

    /// Copy values of a finished capture from value `offset` on into
    /// `out`: sample-major (value `k * n + c` is signal `c` of sample `k`,
    /// `n` the signals recorded), the oldest sample first. Returns the
    /// values copied (0 past the end, or when the capture is not done).
    pub fn read(&self, offset: usize, out: &mut [f32]) -> usize {
        if self.state != State::Done {
            return 0;
        }
        let n = usize::from(self.config.channels);
        let depth = usize::from(self.config.samples);
        let total = usize::from(self.status().captured) * n;
        let first = (usize::from(self.trigger_slot) + depth - usize::from(self.trigger_index))
            % depth.max(1);
        let buf = self.buf.as_ref();
        let mut copied = 0;
        for (i, o) in out.iter_mut().enumerate() {
            let v = offset.saturating_add(i);
            if v >= total {
                break;
            }
            let (k, c) = (v / n, v % n);
            let slot = (first + k) % depth;
            *o = buf.get(slot * n + c).copied().unwrap_or(f32::NAN);
            copied += 1;
        }
        copied
    }

    /// Values a finished capture holds (signals x samples).
    pub fn values(&self) -> usize {
        if self.state != State::Done {
            return 0;
        }
        usize::from(self.status().captured) * usize::from(self.config.channels)
    }
}

#[cfg(test)]
mod tests;
