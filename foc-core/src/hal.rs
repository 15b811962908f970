//! Hardware traits: the only way control code reaches a board.
//!
//! Each trait is narrow, has its own `Error` type and never needs to allocate
//! or block (the CAN port's are [`embedded_can`]'s, see [`CanPort`]). Boards (`board-support`), the emulated board and the host test
//! bench implement them; the control loops never know which.
//!
//! ```
//! use foc_core::hal::{PwmDriver, PhaseCurrents};
//! struct FakePwm { cmp: [u16; 3], on: bool }
//! impl PwmDriver for FakePwm {
//!     type Error = core::convert::Infallible;
//!     fn period_counts(&self) -> u16 { 4200 }
//!     fn set_compare(&mut self, cmp: [u16; 3]) -> Result<(), Self::Error> { self.cmp = cmp; Ok(()) }
//!     fn enable(&mut self) -> Result<(), Self::Error> { self.on = true; Ok(()) }
//!     fn disable(&mut self) { self.on = false; }
//!     fn is_enabled(&self) -> bool { self.on }
//! }
//! let mut pwm = FakePwm { cmp: [0; 3], on: false };
//! pwm.set_duties([0.5, 0.25, 0.75]).unwrap();
//! assert_eq!(pwm.cmp, [2100, 1050, 3150]);
//! ```

use crate::angle::MechanicalAngle;
use crate::frames::Abc;

/// Three-phase PWM stage (timer plus gate driver).
///
/// Duty convention: fraction of the PWM period during which the phase's
/// high-side switch conducts. Compare values are for centre-aligned
/// counting from 0 to [`PwmDriver::period_counts`] and back.
pub trait PwmDriver {
    /// Error reported by the driver.
    type Error;

    /// Timer period in counts (the auto-reload value of a centre-aligned timer).
    fn period_counts(&self) -> u16;

    /// Set the three compare values (phase A, B, C), each `<= period_counts()`.
    fn set_compare(&mut self, compare: [u16; 3]) -> Result<(), Self::Error>;

    /// Set the three duties in `[0, 1]` (values outside are clamped, non-finite
    /// ones centred).
    fn set_duties(&mut self, duties: [f32; 3]) -> Result<(), Self::Error> {
        let cmp = crate::svpwm::compare_values(duties, self.period_counts());
        self.set_compare(cmp)
    }

    /// Enable the bridge outputs (leave the safe state).
    fn enable(&mut self) -> Result<(), Self::Error>;

    /// Put the bridge in its safe state (all switches off, high impedance).
    ///
    /// Infallible on purpose: an implementation must reach the safe state
    /// whatever else has failed, from any context (also a panic handler).
    fn disable(&mut self);

    /// True while the outputs are enabled.
    fn is_enabled(&self) -> bool;

    /// The active short circuit (design §30): the three low-side switches
    /// on, the high sides off, entered through the timer's dead time.
    ///
    /// Default: compare values 0, then enable if off. In centre-aligned
    /// PWM mode 1 with complementary outputs a compare of 0 keeps each
    /// phase's high side off for the whole period and its low side on, the
    /// new compare taking effect at the next update event as every duty
    /// does. A board whose bridge cannot do that must override this and
    /// return an error (the caller then disables). After a break or any
    /// latch that makes [`Self::enable`] refuse, this fails too: a fault
    /// that forbids switching turns everything off.
    fn short_circuit(&mut self) -> Result<(), Self::Error> {
        self.set_compare([0; 3])?;
        if self.is_enabled() {
            Ok(())
        } else {
            self.enable()
        }
    }
    /// The operator cleared the drive's faults: release a hardware fault
    /// latch (e.g. a timer break input that fired), so that [`Self::enable`]
    /// may turn the outputs on again. Until then `enable` must refuse: a
    /// break is a one-way latch until an explicit clear. Default: nothing
    /// to release.
    fn release_fault_latch(&mut self) {}
}

/// One phase-current sample \[A\], as a board measures it.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PhaseCurrents {
    /// Two shunts (phases A and B); the third is derived as `c = -a - b`.
    TwoPhase {
        /// Phase A current \[A\].
        a_a: f32,
        /// Phase B current \[A\].
        b_a: f32,
    },
    /// Three shunts; `a + b + c` is a plausibility check (design §2).
    ThreePhase(Abc),
}

impl PhaseCurrents {
    /// The three phase currents, deriving the third from two if needed.
    #[inline]
    pub fn to_abc(self) -> Abc {
        match self {
            PhaseCurrents::TwoPhase { a_a, b_a } => Abc::new(a_a, b_a, -a_a - b_a),
            PhaseCurrents::ThreePhase(abc) => abc,
        }
    }
    /// `a + b + c` when three phases are measured, `None` with two shunts.
    #[inline]
    pub fn measured_sum_a(&self) -> Option<f32> {
        match self {
            PhaseCurrents::TwoPhase { .. } => None,
            PhaseCurrents::ThreePhase(abc) => Some(abc.sum()),
        }
    }
    /// The readings as measured, per phase (a, b, c): `None` for the
    /// phase a two-shunt board derives.
    #[inline]
    pub fn channels(&self) -> [Option<f32>; 3] {
        match *self {
            PhaseCurrents::TwoPhase { a_a, b_a } => [Some(a_a), Some(b_a), None],
            PhaseCurrents::ThreePhase(abc) => [Some(abc.a), Some(abc.b), Some(abc.c)],
        }
    }
}

/// Phase-current measurement, sampled in step with the PWM.
pub trait CurrentSense {
    /// Error reported by the sensor (e.g. ADC overrun, sample not ready).
    type Error;

    /// The latest sample in amperes, offsets already subtracted.
    fn read_currents(&mut self) -> Result<PhaseCurrents, Self::Error>;

    /// Offsets \[A\] currently subtracted from the raw readings (A, B, C; C is 0
    /// with two shunts).
    fn offsets_a(&self) -> Abc;

    /// Replace the offsets \[A\] subtracted from the raw readings. Offset
    /// calibration reads with the bridge off, averages, and calls this.
    fn set_offsets_a(&mut self, offsets: Abc);
}

/// A rotor angle sensor (encoder, hall, magnetic sensor, or an observer).
pub trait AngleSensor {
    /// Error reported by the sensor (bad frame, parity, magnet missing...).
    type Error;

    /// Mechanical angle of the rotor. A reading the sensor knows to be bad
    /// is an error, never an angle.
    fn read_angle(&mut self) -> Result<MechanicalAngle, Self::Error>;

    /// Mechanical velocity [rad/s] if the sensor measures it itself.
    fn velocity_rad_s(&mut self) -> Option<f32> {
        None
    }

    /// The reading latched at the encoder's index pulse since the last
    /// call, if it pulsed (design §33). The default: no index.
    fn take_index(&mut self) -> Option<MechanicalAngle> {
        None
    }
}

/// DC-bus voltage (and temperature where the board has it).
pub trait BusVoltage {
    /// Error reported by the measurement.
    type Error;

    /// The latest bus voltage \[V\].
    fn read_bus_voltage_v(&mut self) -> Result<f32, Self::Error>;

    /// Power-stage temperature [deg C] (e.g. a FET thermistor) if the board
    /// measures it: the supervisor's over-temperature fault and the power
    /// limits' stage derating read it (design §18). `None`: the board has
    /// no sensor; `Some(Err(_))`: it has one and the reading failed (open
    /// or shorted thermistor), which the stage derating treats as a
    /// missing sensor (no current).
    fn read_temperature_c(&mut self) -> Option<Result<f32, Self::Error>> {
        None
    }
}

/// The switch of a brake resistor across the DC bus (a "brake chopper"),
/// where the board has one (design §18). The current stage decides on/off
/// each period ([`crate::control::power::BrakeChopper`], reported in
/// `Feedback::power.brake_on`); the caller applies it here.
///
/// Infallible on purpose, like [`PwmDriver::disable`]: switching the
/// resistor off must work from any context (also a panic handler), and a
/// board without a resistor implements it with [`NoBrake`].
pub trait BrakeOutput {
    /// Conduct (`true`: the resistor dissipates the bus energy) or not.
    fn set_brake(&mut self, on: bool);

    /// True while the resistor conducts.
    fn is_brake_on(&self) -> bool;
}

/// A board without a brake resistor: [`BrakeOutput::set_brake`] does
/// nothing and the brake never conducts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NoBrake;

impl BrakeOutput for NoBrake {
    #[inline]
    fn set_brake(&mut self, _on: bool) {}

    #[inline]
    fn is_brake_on(&self) -> bool {
        false
    }
}

/// Fault-confinement state of a CAN controller (ISO 11898-1 fault
/// confinement, the same three states on every controller). The CANopen
/// node treats bus-off as a lost connection and reports the recovery
/// (CiA 301 error code `0x8140` "recovered from bus off"); it does not
/// report error passive (`0x8120`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BusState {
    /// Both error counters at most 127: the node takes full part in
    /// error signalling.
    ErrorActive,
    /// The transmit or the receive error counter above 127: the node
    /// still sends and receives, but signals errors only passively.
    ErrorPassive,
    /// The transmit error counter went above 255: the node is off the bus
    /// and sends nothing until it has recovered (on the STM32's bxCAN, by
    /// itself after 128 occurrences of 11 recessive bits when automatic
    /// bus-off management is on).
    BusOff,
}

impl BusState {
    /// True while the node is off the bus.
    #[inline]
    pub const fn is_bus_off(self) -> bool {
        matches!(self, BusState::BusOff)
    }
}

/// A CAN controller: frames in and out through `embedded-can`'s
/// non-blocking [`embedded_can::nb::Can`] (frames are
/// [`embedded_can::Frame`]s, errors [`embedded_can::Error`]s), plus the
/// controller's fault-confinement state, which a CANopen node needs and
/// `embedded-can` does not carry.
///
/// `transmit` follows `embedded-can`: when every transmit buffer is full
/// it may replace a pending frame of lower priority and return it
/// (`Ok(Some(frame))`): the caller sends that one again later or counts it
/// as lost. `Err(nb::Error::WouldBlock)`: nothing was queued (also while
/// the controller is off the bus or not started). `receive` returns
/// `WouldBlock` when no frame is waiting.
///
/// ```
/// use embedded_can::{nb::Can, ErrorKind, Frame, Id, StandardId};
/// use foc_core::hal::{BusState, CanPort};
///
/// #[derive(Clone, Debug, PartialEq)]
/// struct F { id: StandardId, len: usize, data: [u8; 8] }
/// impl Frame for F {
///     fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
///         let Id::Standard(id) = id.into() else { return None };
///         let mut d = [0; 8];
///         d.get_mut(..data.len())?.copy_from_slice(data);
///         Some(F { id, len: data.len(), data: d })
///     }
///     fn new_remote(_: impl Into<Id>, _: usize) -> Option<Self> { None }
///     fn is_extended(&self) -> bool { false }
///     fn is_remote_frame(&self) -> bool { false }
///     fn id(&self) -> Id { Id::Standard(self.id) }
///     fn dlc(&self) -> usize { self.len }
///     fn data(&self) -> &[u8] { &self.data[..self.len] }
/// }
///
/// /// A loop-back port: what is sent is received.
/// struct Loopback { frame: Option<F>, state: BusState }
/// impl Can for Loopback {
///     type Frame = F;
///     type Error = ErrorKind;
///     fn transmit(&mut self, f: &F) -> nb::Result<Option<F>, ErrorKind> {
///         if self.state.is_bus_off() || self.frame.is_some() {
///             return Err(nb::Error::WouldBlock);
///         }
///         self.frame = Some(f.clone());
///         Ok(None)
///     }
///     fn receive(&mut self) -> nb::Result<F, ErrorKind> {
///         self.frame.take().ok_or(nb::Error::WouldBlock)
///     }
/// }
/// impl CanPort for Loopback {
///     fn bus_state(&self) -> BusState { self.state }
/// }
///
/// let mut port = Loopback { frame: None, state: BusState::ErrorActive };
/// let heartbeat = F::new(StandardId::new(0x701).unwrap(), &[0x05]).unwrap();
/// assert_eq!(port.transmit(&heartbeat), Ok(None));
/// assert_eq!(port.receive(), Ok(heartbeat.clone()));
/// port.state = BusState::BusOff;
/// assert_eq!(port.transmit(&heartbeat), Err(nb::Error::WouldBlock));
/// ```
pub trait CanPort: embedded_can::nb::Can {
    /// The controller's fault-confinement state now (read from the
    /// hardware, cheap enough to poll every millisecond).
    fn bus_state(&self) -> BusState;

    /// Service the port, at least every millisecond: e.g. move queued
    /// frames into free transmit buffers, drop what is queued while
    /// bus-off. Default: nothing.
    fn poll(&mut self) {}
}
