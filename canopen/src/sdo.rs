//! SDO server (CiA 301 §7.2.4): expedited and segmented upload and
//! download over the default SDO (request 0x600 + id, response 0x580 +
//! id). Block transfer is not supported (aborted as an unknown command).
//!
//! The server only frames the transfer: what an object holds and whether
//! a value may be written is the [`ObjectAccess`]'s business. A download
//! is handed to [`ObjectAccess::write`] whole, once its last byte arrived,
//! so the object sees one complete value and validates it before anything
//! changes.
//!
//! ```
//! use foc_canopen::sdo::{ObjectAccess, SdoServer};
//! use foc_canopen::{od::Data, Abort};
//! struct One(u32);
//! impl ObjectAccess for One {
//!     fn read(&mut self, i: u16, s: u8) -> Result<Data, Abort> {
//!         if (i, s) == (0x1017, 0) { Ok(Data::from_bytes(&self.0.to_le_bytes())) } else { Err(Abort::NoObject) }
//!     }
//!     fn check_write(&mut self, _: u16, _: u8) -> Result<usize, Abort> { Err(Abort::ReadOnly) }
//!     fn write(&mut self, _: u16, _: u8, _: &[u8]) -> Result<(), Abort> { Err(Abort::ReadOnly) }
//! }
//! let mut sdo = SdoServer::new();
//! let r = sdo.on_request(&[0x40, 0x17, 0x10, 0, 0, 0, 0, 0], 0, &mut One(7)).unwrap();
//! assert_eq!(r, [0x43, 0x17, 0x10, 0, 7, 0, 0, 0]);
//! ```

use crate::od::Data;
use crate::Abort;

/// A segmented transfer silent for this long is aborted
/// ([`Abort::Timeout`]) \[µs\].
pub const TIMEOUT_US: u64 = 1_000_000;

/// The dictionary as the SDO server sees it.
pub trait ObjectAccess {
    /// The value's bytes (checks existence and read access).
    fn read(&mut self, index: u16, sub: u8) -> Result<Data, Abort>;
    /// Before a segmented download starts: the object exists and may be
    /// written; its size in bytes (0: variable).
    fn check_write(&mut self, index: u16, sub: u8) -> Result<usize, Abort>;
    /// Write a whole value: validated completely before anything changes.
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), Abort>;
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Transfer {
    Idle,
    Download {
        index: u16,
        sub: u8,
        size: Option<usize>,
        toggle: bool,
        buf: Data,
        last_us: u64,
    },
    Upload {
        index: u16,
        sub: u8,
        data: Data,
        pos: usize,
        toggle: bool,
        last_us: u64,
    },
}

/// The SDO server's state: idle or one segmented transfer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SdoServer {
    transfer: Transfer,
}

impl Default for SdoServer {
    fn default() -> Self {
        Self::new()
    }
}

/// The abort frame for `index`/`sub`.
pub fn abort_frame(index: u16, sub: u8, a: Abort) -> [u8; 8] {
    let [i0, i1] = index.to_le_bytes();
    let [c0, c1, c2, c3] = a.code().to_le_bytes();
    [0x80, i0, i1, sub, c0, c1, c2, c3]
}

impl SdoServer {
    /// Idle.
    pub const fn new() -> Self {
        Self {
            transfer: Transfer::Idle,
        }
    }

    /// True while a segmented transfer runs.
    pub const fn busy(&self) -> bool {
        !matches!(self.transfer, Transfer::Idle)
    }

    /// Forget any transfer (NMT reset).
    pub fn reset(&mut self) {
        self.transfer = Transfer::Idle;
    }

    /// A running transfer silent for [`TIMEOUT_US`]: the abort to send.
    pub fn poll(&mut self, now_us: u64) -> Option<[u8; 8]> {
        let (index, sub, last) = match self.transfer {
            Transfer::Idle => return None,
            Transfer::Download {
                index,
                sub,
                last_us,
                ..
            }
            | Transfer::Upload {
                index,
                sub,
                last_us,
                ..
            } => (index, sub, last_us),
        };
        if now_us.saturating_sub(last) >= TIMEOUT_US {
            self.transfer = Transfer::Idle;
            return Some(abort_frame(index, sub, Abort::Timeout));
        }
        None
    }

    /// One request's data bytes: the response (`None` after a client's
    /// abort). Anything malformed is answered with an abort.
    pub fn on_request<A: ObjectAccess + ?Sized>(
        &mut self,
        req: &[u8],
        now_us: u64,
        od: &mut A,
    ) -> Option<[u8; 8]> {
        let (index, sub) = match self.transfer {
            Transfer::Download { index, sub, .. } | Transfer::Upload { index, sub, .. } => {
                (index, sub)
            }
            Transfer::Idle => (0, 0),
        };
        let Ok(req) = <&[u8; 8]>::try_from(req) else {
            self.transfer = Transfer::Idle;
            let i = match (req.get(1), req.get(2)) {
                (Some(&a), Some(&b)) => u16::from_le_bytes([a, b]),
                _ => index,
            };
            let s = req.get(3).copied().unwrap_or(sub);
            return Some(abort_frame(i, s, Abort::InvalidCommand));
        };
        let r = match req[0] >> 5 {
            1 => self.initiate_download(req, now_us, od),
            0 => self.download_segment(req, now_us, od),
            2 => self.initiate_upload(req, now_us, od),
            3 => self.upload_segment(req, now_us),
            4 => {
                self.transfer = Transfer::Idle;
                return None;
            }
            _ => Err((index, sub, Abort::InvalidCommand)),
        };
        match r {
            Ok(resp) => Some(resp),
            Err((i, s, a)) => {
                self.transfer = Transfer::Idle;
                Some(abort_frame(i, s, a))
            }
        }
    }

    fn initiate_download<A: ObjectAccess + ?Sized>(
        &mut self,
        req: &[u8; 8],
        now_us: u64,
        od: &mut A,
    ) -> Result<[u8; 8], (u16, u8, Abort)> {
        let [b0, i0, i1, sub, d0, d1, d2, d3] = *req;
        let index = u16::from_le_bytes([i0, i1]);
        let err = |a| (index, sub, a);
        self.transfer = Transfer::Idle;
        let expedited = b0 & 0x02 != 0;
        let sized = b0 & 0x01 != 0;
        let ok = [0x60, i0, i1, sub, 0, 0, 0, 0];
        if expedited {
            let len = if sized {
                4 - usize::from((b0 >> 2) & 3)
            } else {
                // Size not indicated: the object's own size.
                match od.check_write(index, sub).map_err(err)? {
                    n @ 1..=4 => n,
                    _ => 4,
                }
            };
            let data = [d0, d1, d2, d3];
            od.write(index, sub, data.get(..len).unwrap_or(&data))
                .map_err(err)?;
            return Ok(ok);
        }
        let object_size = od.check_write(index, sub).map_err(err)?;
        let size = if sized {
            let n = u32::from_le_bytes([d0, d1, d2, d3]) as usize;
            if object_size != 0 && n > object_size {
                return Err(err(Abort::TooLong));
            }
            if object_size != 0 && n < object_size {
                return Err(err(Abort::TooShort));
            }
            if n > Data::CAPACITY {
                return Err(err(Abort::TooLong));
            }
            Some(n)
        } else {
            None
        };
        self.transfer = Transfer::Download {
            index,
            sub,
            size,
            toggle: false,
            buf: Data::empty(),
            last_us: now_us,
        };
        Ok(ok)
    }

    fn download_segment<A: ObjectAccess + ?Sized>(
        &mut self,
        req: &[u8; 8],
        now_us: u64,
        od: &mut A,
    ) -> Result<[u8; 8], (u16, u8, Abort)> {
        let Transfer::Download {
            index,
            sub,
            size,
            toggle,
            mut buf,
            ..
        } = self.transfer
        else {
            return Err((0, 0, Abort::InvalidCommand));
        };
        let err = |a| (index, sub, a);
        let b0 = req[0];
        let t = b0 & 0x10 != 0;
        if t != toggle {
            return Err(err(Abort::ToggleBit));
        }
        let unused = usize::from((b0 >> 1) & 7);
        let last = b0 & 0x01 != 0;
        let seg = req.get(1..8 - unused).unwrap_or(&[]);
        for &b in seg {
            if !buf.push(b) {
                return Err(err(Abort::TooLong));
            }
        }
        if let Some(n) = size {
            if buf.bytes().len() > n {
                return Err(err(Abort::TooLong));
            }
        }
        let resp = [0x20 | (b0 & 0x10), 0, 0, 0, 0, 0, 0, 0];
        if !last {
            self.transfer = Transfer::Download {
                index,
                sub,
                size,
                toggle: !toggle,
                buf,
                last_us: now_us,
            };
            return Ok(resp);
        }
        self.transfer = Transfer::Idle;
        if let Some(n) = size {
            if buf.bytes().len() != n {
                return Err(err(Abort::LengthMismatch));
            }
        }
        od.write(index, sub, buf.bytes()).map_err(err)?;
        Ok(resp)
    }

    fn initiate_upload<A: ObjectAccess + ?Sized>(
        &mut self,
        req: &[u8; 8],
        now_us: u64,
        od: &mut A,
    ) -> Result<[u8; 8], (u16, u8, Abort)> {
        let [_, i0, i1, sub, ..] = *req;
        let index = u16::from_le_bytes([i0, i1]);
        self.transfer = Transfer::Idle;
        let data = od.read(index, sub).map_err(|a| (index, sub, a))?;
        let bytes = data.bytes();
        let n = bytes.len();
        if (1..=4).contains(&n) {
            let mut resp = [0x43 | (((4 - n) as u8) << 2), i0, i1, sub, 0, 0, 0, 0];
            for (dst, src) in resp.iter_mut().skip(4).zip(bytes) {
                *dst = *src;
            }
            return Ok(resp);
        }
        let [s0, s1, s2, s3] = (n as u32).to_le_bytes();
        self.transfer = Transfer::Upload {
            index,
            sub,
            data,
            pos: 0,
            toggle: false,
            last_us: now_us,
        };
        Ok([0x41, i0, i1, sub, s0, s1, s2, s3])
    }

    fn upload_segment(&mut self, req: &[u8; 8], now_us: u64) -> Result<[u8; 8], (u16, u8, Abort)> {
        let Transfer::Upload {
            index,
            sub,
            data,
            pos,
            toggle,
            ..
        } = self.transfer
        else {
            return Err((0, 0, Abort::InvalidCommand));
        };
        let t = req[0] & 0x10 != 0;
        if t != toggle {
            return Err((index, sub, Abort::ToggleBit));
        }
        let rest = data.bytes().get(pos..).unwrap_or(&[]);
        let n = rest.len().min(7);
        let last = rest.len() <= 7;
        let mut resp = [0u8; 8];
        resp[0] = (req[0] & 0x10) | (((7 - n) as u8) << 1) | u8::from(last);
        for (dst, src) in resp.iter_mut().skip(1).zip(rest.iter().take(n)) {
            *dst = *src;
        }
        self.transfer = if last {
            Transfer::Idle
        } else {
            Transfer::Upload {
                index,
                sub,
                data,
                pos: pos + n,
                toggle: !toggle,
                last_us: now_us,
            }
        };
        Ok(resp)
    }
}
