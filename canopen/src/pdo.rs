//! PDO parameters and their rules (CiA 301 §7.2.2): 4 RPDOs and 4 TPDOs,
//! communication parameters (COB-ID, transmission type, inhibit time,
//! event timer) and mappings, with the default (CiA 402) mappings, and
//! the checks a write over SDO must pass before anything changes:
//!
//! - a mapping entry may change only while the PDO is invalid (COB-ID bit
//!   31 set: else [`Abort::DeviceState`]) and its sub 0 is 0 (else
//!   [`Abort::UnsupportedAccess`]); the object must exist
//!   ([`Abort::NoObject`]), be mappable in this direction with its own
//!   length ([`Abort::NotMappable`]);
//! - sub 0 (number of entries) may change only while invalid, and the
//!   entries it enables must fit into 64 bits ([`Abort::PdoTooLong`]);
//! - a valid COB-ID cannot be changed into another valid one
//!   ([`Abort::InvalidValue`]); 29-bit identifiers and the restricted
//!   identifiers of CiA 301 table 70 are refused; a TPDO's bit 30 ("no
//!   RTR") stays set: this node does not answer remote frames;
//! - transmission types: 0..=240, 254, 255 (RTR-only types are not
//!   supported); the inhibit time changes only while the PDO is invalid.
//!
//! The node packs and unpacks the frames ([`crate::node`]).
//!
//! ```
//! use foc_canopen::pdo::PdoConfig;
//! let t1 = PdoConfig::tpdo_default(0, 5);
//! assert_eq!(t1.cob_id, 0x4000_0185); // bit 30: no RTR
//! assert_eq!(t1.id(), 0x185);
//! assert_eq!(t1.map.entries(), &[0x6041_0010]);
//! ```

use crate::od::{self, ObjectDef, RPDO_DEFAULT, TPDO_DEFAULT};
use crate::Abort;

/// PDOs of each direction.
pub const COUNT: usize = 4;
/// COB-ID bit 31: PDO does not exist / is invalid.
pub const INVALID: u32 = 1 << 31;
/// COB-ID bit 30: no RTR allowed (TPDO).
pub const NO_RTR: u32 = 1 << 30;
/// COB-ID bit 29: 29-bit identifier.
pub const EXTENDED: u32 = 1 << 29;

/// A PDO mapping: up to 8 entries `index << 16 | sub << 8 | bits`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PdoMap {
    count: u8,
    slots: [u32; 8],
}

impl PdoMap {
    /// From entries (at most 8 kept).
    pub fn new(entries: &[u32]) -> Self {
        let mut slots = [0; 8];
        for (d, s) in slots.iter_mut().zip(entries) {
            *d = *s;
        }
        Self {
            count: entries.len().min(8) as u8,
            slots,
        }
    }
    /// Number of entries in use (sub 0).
    pub const fn count(&self) -> u8 {
        self.count
    }
    /// Entry `n` (1..=8), in use or not.
    pub fn slot(&self, n: u8) -> Option<u32> {
        self.slots.get(usize::from(n).checked_sub(1)?).copied()
    }
    /// The entries in use.
    pub fn entries(&self) -> &[u32] {
        self.slots.get(..usize::from(self.count)).unwrap_or(&[])
    }
    /// Bytes of the mapped data.
    pub fn bytes(&self) -> usize {
        self.entries().iter().map(|e| (e & 0xFF) as usize / 8).sum()
    }
}

/// One PDO's parameters (for an RPDO inhibit time and event timer stay 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PdoConfig {
    /// COB-ID entry (bit 31 invalid, bit 30 no RTR, bits 0..11 the id).
    pub cob_id: u32,
    /// Transmission type.
    pub transmission: u8,
    /// TPDO inhibit time [100 µs].
    pub inhibit_100us: u16,
    /// TPDO event timer \[ms\] (0: off).
    pub event_ms: u16,
    /// The mapping.
    pub map: PdoMap,
}

/// Is `id` (11-bit) one of CiA 301's restricted identifiers?
pub const fn restricted(id: u32) -> bool {
    matches!(id, 0x000 | 0x001..=0x07F | 0x101..=0x180 | 0x581..=0x5FF | 0x601..=0x67F | 0x6E0..=0x6FF | 0x701..=0x7FF)
}

impl PdoConfig {
    /// RPDO `n` (0..4) at its defaults for `node_id`.
    pub fn rpdo_default(n: usize, node_id: u8) -> Self {
        Self {
            cob_id: 0x200 + 0x100 * n as u32 + u32::from(node_id),
            transmission: 255,
            inhibit_100us: 0,
            event_ms: 0,
            map: PdoMap::new(RPDO_DEFAULT.get(n).copied().unwrap_or(&[])),
        }
    }

    /// TPDO `n` (0..4) at its defaults for `node_id`.
    pub fn tpdo_default(n: usize, node_id: u8) -> Self {
        Self {
            cob_id: NO_RTR | (0x180 + 0x100 * n as u32 + u32::from(node_id)),
            transmission: 255,
            inhibit_100us: 0,
            event_ms: 0,
            map: PdoMap::new(TPDO_DEFAULT.get(n).copied().unwrap_or(&[])),
        }
    }

    /// The PDO exists (COB-ID bit 31 clear).
    pub const fn valid(&self) -> bool {
        self.cob_id & INVALID == 0
    }

    /// Its 11-bit identifier.
    pub const fn id(&self) -> u16 {
        (self.cob_id & 0x7FF) as u16
    }

    /// Synchronous (types 0..=240).
    pub const fn synchronous(&self) -> bool {
        self.transmission <= 240
    }

    /// The parameters after writing `v` to the communication object's
    /// `sub`, checked; `self` is unchanged either way.
    pub fn with_comm(&self, rx: bool, sub: u8, v: u32) -> Result<Self, Abort> {
        let mut c = *self;
        match sub {
            1 => {
                if v & EXTENDED != 0 || v & 0x1FFF_F800 != 0 {
                    return Err(Abort::InvalidValue);
                }
                // A TPDO cannot be requested by a remote frame here:
                // bit 30 ("no RTR") stays set.
                if !rx && v & NO_RTR == 0 {
                    return Err(Abort::InvalidValue);
                }
                let new_valid = v & INVALID == 0;
                if new_valid && restricted(v & 0x7FF) {
                    return Err(Abort::InvalidValue);
                }
                if new_valid && self.valid() && (v & 0x7FF) != (self.cob_id & 0x7FF) {
                    return Err(Abort::InvalidValue);
                }
                c.cob_id = v;
            }
            2 => {
                if !(v <= 240 || v == 254 || v == 255) {
                    return Err(Abort::InvalidValue);
                }
                c.transmission = v as u8;
            }
            3 if !rx => {
                if self.valid() {
                    return Err(Abort::InvalidValue);
                }
                c.inhibit_100us = v as u16;
            }
            5 if !rx => c.event_ms = v as u16,
            _ => return Err(Abort::NoSubIndex),
        }
        Ok(c)
    }

    /// The parameters after writing `v` to the mapping object's `sub`,
    /// checked; `self` is unchanged either way.
    pub fn with_mapping(&self, rx: bool, sub: u8, v: u32) -> Result<Self, Abort> {
        if self.valid() {
            return Err(Abort::DeviceState);
        }
        let mut c = *self;
        if sub == 0 {
            let n = usize::try_from(v).map_err(|_| Abort::ValueTooHigh)?;
            let entries = self.map.slots.get(..n).ok_or(Abort::ValueTooHigh)?;
            let mut bits = 0u32;
            for &e in entries {
                check_entry(e, rx)?;
                bits += e & 0xFF;
            }
            if bits > 64 {
                return Err(Abort::PdoTooLong);
            }
            c.map.count = n as u8;
            return Ok(c);
        }
        if self.map.count != 0 {
            return Err(Abort::UnsupportedAccess);
        }
        if v != 0 {
            check_entry(v, rx)?;
        }
        let slot = c
            .map
            .slots
            .get_mut(usize::from(sub).wrapping_sub(1))
            .ok_or(Abort::NoSubIndex)?;
        *slot = v;
        Ok(c)
    }
}

/// The object a mapping entry names, if it may be mapped in this
/// direction (`rx`: RPDO, the object must be writable) with its own
/// length.
pub fn check_entry(entry: u32, rx: bool) -> Result<&'static ObjectDef, Abort> {
    let index = (entry >> 16) as u16;
    let sub = ((entry >> 8) & 0xFF) as u8;
    let def = od::lookup(index, sub)?;
    let dir_ok = if rx {
        def.access.writable()
    } else {
        def.access.readable()
    };
    if !def.pdo_mappable || !dir_ok || def.mapping() != entry {
        return Err(Abort::NotMappable);
    }
    Ok(def)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cob_id_rules() {
        let t = PdoConfig::tpdo_default(0, 5);
        assert_eq!(t.with_comm(false, 1, 0x186), Err(Abort::InvalidValue));
        assert_eq!(
            t.with_comm(false, 1, 0x185 | EXTENDED),
            Err(Abort::InvalidValue)
        );
        assert_eq!(
            t.with_comm(false, 1, 0x185 | NO_RTR).map(|c| c.cob_id),
            Ok(0x4000_0185)
        );
        assert_eq!(
            t.with_comm(false, 1, 0x185),
            Err(Abort::InvalidValue),
            "a TPDO keeps bit 30 (no RTR)"
        );
        let off = t.with_comm(false, 1, INVALID | NO_RTR | 0x185).unwrap();
        assert!(!off.valid());
        assert_eq!(
            off.with_comm(false, 1, NO_RTR | 0x701),
            Err(Abort::InvalidValue),
            "restricted"
        );
        assert_eq!(
            off.with_comm(false, 1, NO_RTR | 0x186).map(|c| c.id()),
            Ok(0x186)
        );
        assert_eq!(
            t.with_comm(true, 3, 0),
            Err(Abort::NoSubIndex),
            "RPDO has no inhibit time"
        );
        assert_eq!(t.with_comm(false, 2, 252), Err(Abort::InvalidValue));
        assert_eq!(
            t.with_comm(false, 2, 240).map(|c| c.synchronous()),
            Ok(true)
        );
    }

    #[test]
    fn mapping_rules() {
        let mut r = PdoConfig::rpdo_default(0, 5);
        r.cob_id |= INVALID;
        assert_eq!(
            r.with_mapping(true, 1, 0x607A_0020),
            Err(Abort::UnsupportedAccess)
        );
        let r = r.with_mapping(true, 0, 0).unwrap();
        let r = r.with_mapping(true, 2, 0x607A_0020).unwrap();
        assert_eq!(r.with_mapping(true, 9, 0), Err(Abort::NoSubIndex));
        let r = r.with_mapping(true, 0, 2).unwrap();
        assert_eq!(r.map.entries(), &[0x6040_0010, 0x607A_0020]);
        assert_eq!(r.map.bytes(), 6);
        assert_eq!(check_entry(0x6041_0010, true), Err(Abort::NotMappable));
        assert!(check_entry(0x6041_0010, false).is_ok());
        assert_eq!(check_entry(0x6040_0020, true), Err(Abort::NotMappable));
    }
}
