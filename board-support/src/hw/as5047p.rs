//! AS5047P over an embedded-hal 1.0 `SpiDevice` (SPI mode 1, up to 10 MHz,
//! 8-bit words, two per frame, MSB first), implementing `AngleSensor`.
//!
//! Every call sends `READ ANGLECOM` and decodes the answer to the previous
//! command (the AS5047P answers one frame late), so the angle is one call
//! old. After an error flag the next call reads (and so clears) `ERRFL`.
//!
//! Each frame is one `SpiDevice` transaction: a wait of
//! [`CSN_SETUP_NS`] after CSn falls (the sensor's `tL`; the device's
//! `DelayNs` provides it), then the two-byte transfer. Calls must be at
//! least `tCSn` = [`T_CSN_NS`] apart (CSn high between frames): once per
//! PWM period is far more.
//!
//! ```ignore
//! // On a board: SPI bus + chip select + delay as an embedded-hal-bus device.
//! let dev = embedded_hal_bus::spi::ExclusiveDevice::new(spi, ncs, delay)?;
//! let mut sensor = As5047p::new(dev);
//! let _ = sensor.read_angle(); // first frame: no answer yet
//! let angle = sensor.read_angle()?;
//! ```

#[cfg(doc)]
use crate::logic::as5047p::T_CSN_NS;
use crate::logic::as5047p::{
    angle_bits, decode_response, read_command, FrameError, Response, ANGLECOM, CSN_SETUP_NS, ERRFL,
};
use embedded_hal::spi::{Operation, SpiDevice};
use foc_core::angle::MechanicalAngle;
use foc_core::hal::AngleSensor;

/// AS5047P error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum As5047pError {
    /// The SPI transfer failed.
    Spi,
    /// Bad parity or error flag.
    Frame(FrameError),
    /// The answer belongs to an `ERRFL` read (or is the first frame).
    NotAnAngle,
}

/// What the next answer frame is the reply to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pending {
    Nothing,
    Angle,
    Errfl,
}

/// AS5047P on a `SpiDevice`.
pub struct As5047p<SPI> {
    spi: SPI,
    pending: Pending,
    next_errfl: bool,
}

impl<SPI: SpiDevice<u8>> As5047p<SPI> {
    /// Sensor on `spi` (configured for mode 1).
    pub const fn new(spi: SPI) -> Self {
        Self {
            spi,
            pending: Pending::Nothing,
            next_errfl: false,
        }
    }

    /// Release the SPI device.
    pub fn release(self) -> SPI {
        self.spi
    }

    fn frame(&mut self, cmd: u16) -> Result<u16, As5047pError> {
        let tx = cmd.to_be_bytes();
        let mut rx = [0u8; 2];
        self.spi
            .transaction(&mut [
                Operation::DelayNs(CSN_SETUP_NS),
                Operation::Transfer(&mut rx, &tx),
            ])
            .map_err(|_| As5047pError::Spi)?;
        Ok(u16::from_be_bytes(rx))
    }
}

impl<SPI: SpiDevice<u8>> AngleSensor for As5047p<SPI> {
    type Error = As5047pError;

    fn read_angle(&mut self) -> Result<MechanicalAngle, As5047pError> {
        let (cmd, next) = if self.next_errfl {
            (read_command(ERRFL), Pending::Errfl)
        } else {
            (read_command(ANGLECOM), Pending::Angle)
        };
        let answer = self.frame(cmd);
        let answered = self.pending;
        self.pending = if answer.is_ok() {
            next
        } else {
            Pending::Nothing
        };
        self.next_errfl = false;
        let answer = answer?;
        match decode_response(answer) {
            Err(e) => {
                if e == FrameError::ErrorFlag {
                    self.next_errfl = true;
                }
                Err(As5047pError::Frame(e))
            }
            Ok(Response::Data(d)) => match answered {
                Pending::Angle => Ok(MechanicalAngle::from_bits(angle_bits(d))),
                Pending::Errfl | Pending::Nothing => Err(As5047pError::NotAnAngle),
            },
        }
    }
}
