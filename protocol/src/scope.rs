//! Scope capture over the link (design §22): the wire layout of the scope
//! messages and the device's side of them.
//!
//! The capture itself is [`foc_core::scope::Scope`], recorded by the
//! firmware's current loop every period; the protocol reaches it through a
//! [`ScopePort`] (in the firmware a lock around the shared resource, one
//! short critical section per call).
//!
//! | request | body | reply |
//! |---|---|---|
//! | 0x50 `SetScope` | `signals: 8 x u8` (signal codes, 0xFF unused, used ones first), `divider:u16`, `samples:u16` (0: as many as fit), `pre_trigger:u16`, `trigger:u8`, `trigger_signal:u8`, `level:f32` | `Ack` (the scope goes idle) |
//! | 0x51 `ArmScope` | - | `Ack` |
//! | 0x52 `TriggerScope` | - | `Ack`, or `Nack` `ScopeState` when not armed |
//! | 0x53 `ReadScope` | - | `Scope` |
//! | 0x54 `ReadScopeData` | `offset:u16` (value index) | `ScopeData`, or `Nack` `ScopeState` before the capture is done |
//!
//! | response | body |
//! |---|---|
//! | 0x8A `Scope` | `state:u8` (0 idle, 1 armed, 2 triggered, 3 done), the configuration as in `SetScope` (`samples` resolved), `captured:u16`, `trigger_index:u16`, `trigger_period:u32`, `sample_period_s:f32`, `capacity:u16` |
//! | 0x8B `ScopeData` | `offset:u16 count:u8` then `count` (<= 12) x `f32`: values `offset ..`, sample-major (value `k n + c` is signal `c` of sample `k`), oldest first |

use crate::message::ErrorCode;
use crate::wire::{DecodeError, Reader, Writer};
use foc_core::control::Feedback;
use foc_core::scope::{
    Scope, ScopeConfig, ScopeError, ScopeStatus, Signal, State, TriggerKind, MAX_CHANNELS,
};

/// Values in one `ScopeData` frame.
pub const DATA_PER_FRAME: usize = 12;

/// Signal slot marker: unused.
pub const UNUSED: u8 = 0xFF;

/// Field numbers of `SetScope` (what an out-of-range Nack points at).
pub mod fields {
    /// The first signal slot (slots are fields 0..=7).
    pub const SIGNALS: u8 = 0;
    /// `divider`.
    pub const DIVIDER: u8 = 8;
    /// `samples`.
    pub const SAMPLES: u8 = 9;
    /// `pre_trigger`.
    pub const PRE_TRIGGER: u8 = 10;
    /// `trigger`.
    pub const TRIGGER: u8 = 11;
    /// `trigger_signal`.
    pub const TRIGGER_SIGNAL: u8 = 12;
    /// `level`.
    pub const LEVEL: u8 = 13;
}

/// The `Scope` reply: the scope's status and its sample period.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScopeReport {
    /// State, configuration, extent of the capture.
    pub status: ScopeStatus,
    /// Time between samples \[s\] (`divider` PWM periods).
    pub sample_period_s: f32,
}

/// A run of captured values.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScopeData {
    /// Index of the first value.
    pub offset: u16,
    /// Values in `values` (<= [`DATA_PER_FRAME`]).
    pub count: u8,
    /// The values (the first `count`).
    pub values: [f32; DATA_PER_FRAME],
}

impl ScopeData {
    /// The values carried.
    pub fn values(&self) -> &[f32] {
        self.values
            .get(..usize::from(self.count))
            .unwrap_or(&self.values)
    }
}

/// The device's scope, as the protocol uses it.
pub trait ScopePort {
    /// Take a configuration whole, or refuse it (nothing changes).
    fn configure(&mut self, c: &ScopeConfig) -> Result<(), ScopeError>;
    /// Start recording; `now` is the latest feedback.
    fn arm(&mut self, now: &Feedback);
    /// Trigger at the next recorded sample (armed only).
    fn force(&mut self) -> Result<(), ScopeError>;
    /// State and configuration.
    fn status(&mut self) -> ScopeStatus;
    /// Values of a finished capture from `offset` on; returns how many.
    fn read(&mut self, offset: usize, out: &mut [f32]) -> usize;
}

impl<B: AsRef<[f32]> + AsMut<[f32]>> ScopePort for Scope<B> {
    fn configure(&mut self, c: &ScopeConfig) -> Result<(), ScopeError> {
        Scope::configure(self, *c)
    }
    fn arm(&mut self, now: &Feedback) {
        Scope::arm(self, now);
    }
    fn force(&mut self) -> Result<(), ScopeError> {
        Scope::force(self)
    }
    fn status(&mut self) -> ScopeStatus {
        Scope::status(self)
    }
    fn read(&mut self, offset: usize, out: &mut [f32]) -> usize {
        Scope::read(self, offset, out)
    }
}

/// The Nack of a refused configuration or request.
pub fn scope_nack(e: ScopeError) -> ErrorCode {
    let field = match e {
        ScopeError::Channels => fields::SIGNALS,
        ScopeError::Divider => fields::DIVIDER,
        ScopeError::Samples => fields::SAMPLES,
        ScopeError::PreTrigger => fields::PRE_TRIGGER,
        ScopeError::Level => fields::LEVEL,
        ScopeError::State => return ErrorCode::ScopeState,
    };
    ErrorCode::OutOfRange { field }
}

/// Write a configuration (`SetScope`'s body).
pub(crate) fn put_config(w: &mut Writer<'_>, c: &ScopeConfig) {
    let used = c.used();
    for i in 0..MAX_CHANNELS {
        w.u8(used.get(i).map_or(UNUSED, |s| *s as u8));
    }
    w.u16(c.divider);
    w.u16(c.samples);
    w.u16(c.pre_trigger);
    w.u8(c.trigger as u8);
    w.u8(c.trigger_signal as u8);
    w.f32(c.level);
}

/// Read a configuration: unknown codes, a used slot after an unused one or
/// no signal at all are refused with the slot's field number.
pub(crate) fn get_config(r: &mut Reader<'_>) -> Result<ScopeConfig, DecodeError> {
    let mut signals = [Signal::IqA; MAX_CHANNELS];
    let mut channels = 0u8;
    for (i, slot) in signals.iter_mut().enumerate() {
        let code = r.u8()?;
        let field = i as u8;
        if code == UNUSED {
            continue;
        }
        if usize::from(channels) != i {
            return Err(DecodeError::BadField(field));
        }
        *slot = Signal::from_code(code).ok_or(DecodeError::BadField(field))?;
        channels = channels.saturating_add(1);
    }
    if channels == 0 {
        return Err(DecodeError::BadField(fields::SIGNALS));
    }
    let divider = r.u16()?;
    let samples = r.u16()?;
    let pre_trigger = r.u16()?;
    let trigger = TriggerKind::from_code(r.u8()?).ok_or(DecodeError::BadField(fields::TRIGGER))?;
    let trigger_signal =
        Signal::from_code(r.u8()?).ok_or(DecodeError::BadField(fields::TRIGGER_SIGNAL))?;
    Ok(ScopeConfig {
        signals,
        channels,
        divider,
        samples,
        pre_trigger,
        trigger,
        trigger_signal,
        level: r.f32()?,
    })
}

/// Write a `Scope` reply's body.
pub(crate) fn put_report(w: &mut Writer<'_>, r: &ScopeReport) {
    let s = &r.status;
    w.u8(s.state as u8);
    put_config(w, &s.config);
    w.u16(s.captured);
    w.u16(s.trigger_index);
    w.u32(s.trigger_period);
    w.f32(r.sample_period_s);
    w.u16(s.capacity);
}

/// Read a `Scope` reply's body.
pub(crate) fn get_report(r: &mut Reader<'_>) -> Result<ScopeReport, DecodeError> {
    let state = State::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?;
    let config = get_config(r)?;
    let captured = r.u16()?;
    let trigger_index = r.u16()?;
    let trigger_period = r.u32()?;
    let sample_period_s = r.f32()?;
    let capacity = r.u16()?;
    Ok(ScopeReport {
        status: ScopeStatus {
            state,
            config,
            captured,
            trigger_index,
            trigger_period,
            capacity,
        },
        sample_period_s,
    })
}

/// Write a `ScopeData` body.
pub(crate) fn put_data(w: &mut Writer<'_>, d: &ScopeData) {
    w.u16(d.offset);
    let v = d.values();
    w.u8(v.len() as u8);
    for x in v {
        w.f32(*x);
    }
}

/// Read a `ScopeData` body.
pub(crate) fn get_data(r: &mut Reader<'_>) -> Result<ScopeData, DecodeError> {
    let offset = r.u16()?;
    let count = r.u8()?;
    if usize::from(count) > DATA_PER_FRAME {
        return Err(DecodeError::BadField(1));
    }
    let mut values = [0.0; DATA_PER_FRAME];
    for v in values.iter_mut().take(usize::from(count)) {
        *v = r.f32()?;
    }
    Ok(ScopeData {
        offset,
        count,
        values,
    })
}
