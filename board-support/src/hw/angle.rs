//! Angle sensors on timers and GPIO: quadrature encoder (timer encoder
//! mode, index by input capture) and hall sensors (GPIO + DWT time stamps).

use crate::hw::{cycle_count, PinId};
use crate::logic::encoder::EncoderTracker;
use crate::logic::hall::{HallConfig, HallDecoder, HallError};
use crate::pac;
use foc_core::angle::MechanicalAngle;
use foc_core::drive::AngleKind;
use foc_core::hal::AngleSensor;

/// A general-purpose timer running in encoder mode, with an optional index
/// input on a capture channel.
pub trait EncoderTimer {
    /// Counter value (low 16 bits).
    fn count() -> u16;
    /// The captured counter value at the last index edge, if one occurred
    /// since the previous call (reading `CCRx` clears `CCxIF`).
    fn take_index() -> Option<u16>;
    /// Configure the index channel as input capture on its own input
    /// (rising edge).
    fn setup_index();
}

macro_rules! encoder_timer {
    ($TIM:ident, $ccs:ident, $cce:ident, $ccif:ident, $ccr:expr) => {
        impl EncoderTimer for pac::$TIM {
            #[inline]
            fn count() -> u16 {
                // SAFETY: read of CNT (RM0090 18.4.10).
                unsafe { (*pac::$TIM::ptr()).cnt().read().bits() as u16 }
            }
            #[inline]
            fn take_index() -> Option<u16> {
                // SAFETY: SR / CCRx reads (RM0090 18.4.5, 18.4.13-16);
                // reading CCRx clears CCxIF.
                let t = unsafe { &*pac::$TIM::ptr() };
                if t.sr().read().$ccif().bit_is_set() {
                    Some(t.ccr($ccr).read().bits() as u16)
                } else {
                    None
                }
            }
            fn setup_index() {
                // SAFETY: CCMR2 CCxS = 01 (ICx mapped on TIx), CCER CCxE = 1,
                // rising edge (RM0090 18.4.7-9); other channels untouched.
                let t = unsafe { &*pac::$TIM::ptr() };
                unsafe {
                    t.ccmr2_input().modify(|_, w| w.$ccs().bits(0b01));
                }
                t.ccer().modify(|_, w| w.$cce().set_bit());
            }
        }
    };
}

encoder_timer!(TIM2, cc3s, cc3e, cc3if, 2);
encoder_timer!(TIM3, cc4s, cc4e, cc4if, 3);

/// Quadrature encoder angle sensor.
pub struct QuadEncoder<TIM: EncoderTimer> {
    tracker: EncoderTracker,
    has_index: bool,
    _tim: core::marker::PhantomData<TIM>,
}

impl<TIM: EncoderTimer> QuadEncoder<TIM> {
    /// Encoder with `cpr` counts per turn (x4); timer already in encoder
    /// mode (HAL `Qei`), index capture set up here if `has_index`.
    pub fn new(cpr: u32, has_index: bool) -> Self {
        if has_index {
            TIM::setup_index();
        }
        let mut tracker = EncoderTracker::new(cpr);
        tracker.update(TIM::count());
        Self {
            tracker,
            has_index,
            _tim: core::marker::PhantomData,
        }
    }

    /// Change the counts per turn (x4).
    pub fn set_cpr(&mut self, cpr: u32) {
        self.tracker.set_cpr(cpr);
    }

    /// True once an index pulse has defined the zero.
    pub fn is_indexed(&self) -> bool {
        self.tracker.is_indexed()
    }
}

impl<TIM: EncoderTimer> AngleSensor for QuadEncoder<TIM> {
    type Error = core::convert::Infallible;

    fn read_angle(&mut self) -> Result<MechanicalAngle, Self::Error> {
        self.tracker.update(TIM::count());
        if self.has_index {
            if let Some(c) = TIM::take_index() {
                self.tracker.index_at(c);
            }
        }
        Ok(self.tracker.angle())
    }
}

/// Hall sensors read from three GPIO inputs (A, B, C), time-stamped with
/// the DWT cycle counter.
pub struct HallSensor {
    pins: [PinId; 3],
    decoder: HallDecoder,
    last_velocity_rad_s: f32,
}

impl HallSensor {
    /// Hall sensor on `pins` (already inputs). `cfg.ticks_per_second` must
    /// be the core clock (DWT cycles).
    pub fn new(pins: [PinId; 3], cfg: HallConfig) -> Self {
        Self {
            pins,
            decoder: HallDecoder::new(cfg),
            last_velocity_rad_s: 0.0,
        }
    }

    /// The raw state `(C << 2) | (B << 1) | A`.
    pub fn state(&self) -> u8 {
        (self.pins[0].is_high() as u8)
            | ((self.pins[1].is_high() as u8) << 1)
            | ((self.pins[2].is_high() as u8) << 2)
    }

    /// The decoder (configuration, reset).
    pub fn decoder_mut(&mut self) -> &mut HallDecoder {
        &mut self.decoder
    }
}

impl AngleSensor for HallSensor {
    type Error = HallError;

    fn read_angle(&mut self) -> Result<MechanicalAngle, HallError> {
        let r = self.decoder.update(self.state(), cycle_count())?;
        let pp = self.decoder.config().pole_pairs.max(1) as f32;
        self.last_velocity_rad_s = r.velocity_elec_rad_s / pp;
        Ok(r.mechanical)
    }

    fn velocity_rad_s(&mut self) -> Option<f32> {
        Some(self.last_velocity_rad_s)
    }
}

/// Error of [`AngleInput`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum AngleError {
    /// Hall state invalid.
    Hall(HallError),
}

/// Which sensor drives [`AngleInput`] (a board's encoder and hall inputs
/// share pins, so it is chosen once at `init`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AngleSource {
    /// Quadrature encoder with this many counts per turn (x4).
    Encoder {
        /// Counts per turn (4 x lines).
        cpr: u32,
    },
    /// Hall sensors.
    Hall(HallConfig),
    /// An absolute angle sensor (the AS5047P of the ODrive v3 option):
    /// only in builds that have its driver (feature `as5047p`), so a
    /// board without one cannot select it.
    #[cfg(feature = "as5047p")]
    Absolute {
        /// Counts per turn of the sensor's angle (2^14 for the AS5047P).
        counts_per_rev: u32,
    },
}

impl AngleSource {
    /// What the source tells at reset: an encoder counts from 0
    /// ([`AngleKind::Incremental`]), halls know the sector ([`AngleKind::Hall`]),
    /// an absolute sensor the angle ([`AngleKind::Absolute`]).
    pub const fn kind(&self) -> AngleKind {
        match self {
            AngleSource::Encoder { .. } => AngleKind::Incremental,
            AngleSource::Hall(_) => AngleKind::Hall,
            #[cfg(feature = "as5047p")]
            AngleSource::Absolute { .. } => AngleKind::Absolute,
        }
    }

    /// The sensor's counts per mechanical turn, where it counts (encoder,
    /// absolute sensor); `None` for halls.
    pub const fn counts_per_rev(&self) -> Option<u32> {
        match self {
            AngleSource::Encoder { cpr } => Some(*cpr),
            AngleSource::Hall(_) => None,
            #[cfg(feature = "as5047p")]
            AngleSource::Absolute { counts_per_rev } => Some(*counts_per_rev),
        }
    }
}

/// The board's rotor angle input: encoder or halls.
pub enum AngleInput<TIM: EncoderTimer> {
    /// Quadrature encoder.
    Encoder(QuadEncoder<TIM>),
    /// Hall sensors.
    Hall(HallSensor),
}

impl<TIM: EncoderTimer> AngleSensor for AngleInput<TIM> {
    type Error = AngleError;

    #[inline]
    fn read_angle(&mut self) -> Result<MechanicalAngle, AngleError> {
        match self {
            AngleInput::Encoder(e) => match e.read_angle() {
                Ok(a) => Ok(a),
                Err(never) => match never {},
            },
            AngleInput::Hall(h) => h.read_angle().map_err(AngleError::Hall),
        }
    }

    fn velocity_rad_s(&mut self) -> Option<f32> {
        match self {
            AngleInput::Encoder(e) => e.velocity_rad_s(),
            AngleInput::Hall(h) => h.velocity_rad_s(),
        }
    }
}
