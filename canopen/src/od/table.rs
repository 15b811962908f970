//! The object table: every object and sub-object, sorted by index and
//! sub-index (a test checks it). Built by a `const fn` so that the four
//! PDO parameter sets are written once.
//!
//! Its functions are private `const fn`s evaluated only for the `static`
//! table: an index out of range fails the build, it cannot panic at run
//! time (hence the `indexing_slicing` allowance, this module only).
#![allow(clippy::indexing_slicing)]

use super::{Access, DataType, Default, Kind, ObjectDef};
use crate::cia402::{OpMode, INC_PER_REV};
use Access::{Const, Ro, Rw};
use DataType::*;

/// Every object and sub-object of the dictionary, sorted by
/// `(index, sub)`: the single source of the objects' metadata.
pub static OBJECTS: &[ObjectDef] = &TABLE;

static TABLE: [ObjectDef; LEN] = trim(&build());

const MAX: usize = 256;
const LEN: usize = build().n;

struct Builder {
    t: [ObjectDef; MAX],
    n: usize,
}

const PLACEHOLDER: ObjectDef = ObjectDef {
    index: 0,
    sub: 0,
    object: "",
    name: "",
    kind: Kind::Var,
    data_type: Unsigned8,
    access: Ro,
    pdo_mappable: false,
    limits: None,
    default: Default::Device,
};

const fn trim(b: &Builder) -> [ObjectDef; LEN] {
    let mut out = [PLACEHOLDER; LEN];
    let mut i = 0;
    while i < LEN {
        out[i] = b.t[i];
        i += 1;
    }
    out
}

impl Builder {
    const fn push(mut self, d: ObjectDef) -> Self {
        self.t[self.n] = d;
        self.n += 1;
        self
    }

    /// A VAR.
    #[allow(clippy::too_many_arguments)]
    const fn var(
        self,
        index: u16,
        name: &'static str,
        data_type: DataType,
        access: Access,
        pdo_mappable: bool,
        limits: Option<(i64, i64)>,
        default: Default,
    ) -> Self {
        self.push(ObjectDef {
            index,
            sub: 0,
            object: name,
            name,
            kind: Kind::Var,
            data_type,
            access,
            pdo_mappable,
            limits,
            default,
        })
    }

    /// Sub 0 of a compound ("Highest sub-index supported").
    const fn head(self, index: u16, object: &'static str, kind: Kind, access: Access) -> Self {
        let (n, name) = match kind {
            Kind::Var => (0, "Highest sub-index supported"),
            Kind::Array(n) | Kind::Record(n) => (n, "Highest sub-index supported"),
        };
        self.push(ObjectDef {
            index,
            sub: 0,
            object,
            name,
            kind,
            data_type: Unsigned8,
            access,
            pdo_mappable: false,
            limits: Some((0, n as i64)),
            default: Default::Int(n as i64),
        })
    }

    /// A sub-object of a compound.
    #[allow(clippy::too_many_arguments)]
    const fn sub(
        self,
        index: u16,
        sub: u8,
        object: &'static str,
        name: &'static str,
        kind: Kind,
        data_type: DataType,
        access: Access,
        default: Default,
    ) -> Self {
        self.push(ObjectDef {
            index,
            sub,
            object,
            name,
            kind,
            data_type,
            access,
            pdo_mappable: false,
            limits: None,
            default,
        })
    }

    /// RPDO `n` (0..4) communication parameters.
    const fn rpdo_comm(self, n: u16) -> Self {
        let i = 0x1400 + n;
        let o = RPDO_COMM[n as usize];
        let k = Kind::Record(2);
        self.head(i, o, k, Const)
            .sub(
                i,
                1,
                o,
                "COB-ID used by RPDO",
                k,
                Unsigned32,
                Rw,
                Default::NodeId(0x200 + 0x100 * n as u32),
            )
            .sub(
                i,
                2,
                o,
                "Transmission type",
                k,
                Unsigned8,
                Rw,
                Default::Int(255),
            )
    }

    /// TPDO `n` (0..4) communication parameters (sub 4 reserved).
    const fn tpdo_comm(self, n: u16) -> Self {
        let i = 0x1800 + n;
        let o = TPDO_COMM[n as usize];
        let k = Kind::Record(5);
        self.head(i, o, k, Const)
            .sub(
                i,
                1,
                o,
                "COB-ID used by TPDO",
                k,
                Unsigned32,
                Rw,
                // Bit 30: no RTR (this node does not answer remote frames).
                Default::NodeId(0x4000_0000 | (0x180 + 0x100 * n as u32)),
            )
            .sub(
                i,
                2,
                o,
                "Transmission type",
                k,
                Unsigned8,
                Rw,
                Default::Int(255),
            )
            .sub(i, 3, o, "Inhibit time", k, Unsigned16, Rw, Default::Int(0))
            .sub(i, 5, o, "Event timer", k, Unsigned16, Rw, Default::Int(0))
    }

    /// A PDO mapping (8 entries) with its default entries.
    const fn mapping(mut self, index: u16, object: &'static str, default: &[u32]) -> Self {
        let k = Kind::Record(8);
        self = self.push(ObjectDef {
            index,
            sub: 0,
            object,
            name: "Number of mapped objects",
            kind: k,
            data_type: Unsigned8,
            access: Rw,
            pdo_mappable: false,
            limits: Some((0, 8)),
            default: Default::Int(default.len() as i64),
        });
        let mut s = 0;
        while s < 8 {
            let d = if s < default.len() { default[s] } else { 0 };
            self = self.sub(
                index,
                s as u8 + 1,
                object,
                MAPPED[s],
                k,
                Unsigned32,
                Rw,
                Default::Int(d as i64),
            );
            s += 1;
        }
        self
    }

    /// A CiA 402 VAR, PDO-mappable or not.
    const fn p(
        self,
        index: u16,
        name: &'static str,
        ty: DataType,
        access: Access,
        pdo: bool,
        default: Default,
    ) -> Self {
        self.var(index, name, ty, access, pdo, None, default)
    }
}

const RPDO_COMM: [&str; 4] = [
    "RPDO1 communication parameter",
    "RPDO2 communication parameter",
    "RPDO3 communication parameter",
    "RPDO4 communication parameter",
];
const TPDO_COMM: [&str; 4] = [
    "TPDO1 communication parameter",
    "TPDO2 communication parameter",
    "TPDO3 communication parameter",
    "TPDO4 communication parameter",
];
const RPDO_MAP: [&str; 4] = [
    "RPDO1 mapping parameter",
    "RPDO2 mapping parameter",
    "RPDO3 mapping parameter",
    "RPDO4 mapping parameter",
];
const TPDO_MAP: [&str; 4] = [
    "TPDO1 mapping parameter",
    "TPDO2 mapping parameter",
    "TPDO3 mapping parameter",
    "TPDO4 mapping parameter",
];
const MAPPED: [&str; 8] = [
    "Application object 1",
    "Application object 2",
    "Application object 3",
    "Application object 4",
    "Application object 5",
    "Application object 6",
    "Application object 7",
    "Application object 8",
];
const ERRORS: [&str; 8] = [
    "Standard error field 1",
    "Standard error field 2",
    "Standard error field 3",
    "Standard error field 4",
    "Standard error field 5",
    "Standard error field 6",
    "Standard error field 7",
    "Standard error field 8",
];

/// Default PDO mappings (CiA 402's): `[RPDO1..4]`, `[TPDO1..4]`.
pub(crate) const RPDO_DEFAULT: [&[u32]; 4] = [
    &[0x6040_0010],
    &[0x6040_0010, 0x6060_0008],
    &[0x6040_0010, 0x607A_0020],
    &[0x6040_0010, 0x60FF_0020],
];
/// Default TPDO mappings.
pub(crate) const TPDO_DEFAULT: [&[u32]; 4] = [
    &[0x6041_0010],
    &[0x6041_0010, 0x6061_0008],
    &[0x6041_0010, 0x6064_0020],
    &[0x6041_0010, 0x606C_0020],
];

/// The profile's defaults: one definition, `Params::DEFAULT`.
const P402: crate::cia402::Params = crate::cia402::Params::DEFAULT;

const fn build() -> Builder {
    let mut b = Builder {
        t: [PLACEHOLDER; MAX],
        n: 0,
    };
    b = b
        .var(
            0x1000,
            "Device type",
            Unsigned32,
            Const,
            false,
            None,
            Default::Int(0x0002_0192),
        )
        .var(
            0x1001,
            "Error register",
            Unsigned8,
            Ro,
            true,
            None,
            Default::Int(0),
        );
    let pef = "Pre-defined error field";
    let k = Kind::Array(8);
    b = b.push(ObjectDef {
        index: 0x1003,
        sub: 0,
        object: pef,
        name: "Number of errors",
        kind: k,
        data_type: Unsigned8,
        access: Rw,
        pdo_mappable: false,
        limits: None,
        default: Default::Int(0),
    });
    let mut s = 0;
    while s < 8 {
        b = b.sub(
            0x1003,
            s as u8 + 1,
            pef,
            ERRORS[s],
            k,
            Unsigned32,
            Ro,
            Default::Int(0),
        );
        s += 1;
    }
    b = b
        .var(
            0x1005,
            "COB-ID SYNC",
            Unsigned32,
            Rw,
            false,
            None,
            Default::Int(0x80),
        )
        .var(
            0x1006,
            "Communication cycle period",
            Unsigned32,
            Rw,
            false,
            None,
            Default::Int(1000),
        )
        .var(
            0x1008,
            "Manufacturer device name",
            VisibleString,
            Const,
            false,
            None,
            Default::Device,
        )
        .var(
            0x1009,
            "Manufacturer hardware version",
            VisibleString,
            Const,
            false,
            None,
            Default::Device,
        )
        .var(
            0x100A,
            "Manufacturer software version",
            VisibleString,
            Const,
            false,
            None,
            Default::Device,
        );
    let (o, k) = ("Store parameters", Kind::Array(1));
    b = b.head(0x1010, o, k, Const).sub(
        0x1010,
        1,
        o,
        "Save all parameters",
        k,
        Unsigned32,
        Rw,
        Default::Int(1),
    );
    let o = "Restore default parameters";
    b = b
        .head(0x1011, o, k, Const)
        .sub(
            0x1011,
            1,
            o,
            "Restore all default parameters",
            k,
            Unsigned32,
            Rw,
            Default::Int(1),
        )
        .var(
            0x1014,
            "COB-ID EMCY",
            Unsigned32,
            Ro,
            false,
            None,
            Default::NodeId(0x80),
        );
    let o = "Consumer heartbeat time";
    b = b
        .head(0x1016, o, k, Const)
        .sub(
            0x1016,
            1,
            o,
            "Consumer heartbeat time 1",
            k,
            Unsigned32,
            Rw,
            Default::Int(0),
        )
        .var(
            0x1017,
            "Producer heartbeat time",
            Unsigned16,
            Rw,
            false,
            None,
            Default::Int(100),
        );
    let (o, k) = ("Identity object", Kind::Record(4));
    b = b
        .head(0x1018, o, k, Const)
        .sub(
            0x1018,
            1,
            o,
            "Vendor-ID",
            k,
            Unsigned32,
            Ro,
            Default::Device,
        )
        .sub(
            0x1018,
            2,
            o,
            "Product code",
            k,
            Unsigned32,
            Ro,
            Default::Device,
        )
        .sub(
            0x1018,
            3,
            o,
            "Revision number",
            k,
            Unsigned32,
            Ro,
            Default::Device,
        )
        .sub(
            0x1018,
            4,
            o,
            "Serial number",
            k,
            Unsigned32,
            Ro,
            Default::Device,
        );
    b = b.rpdo_comm(0).rpdo_comm(1).rpdo_comm(2).rpdo_comm(3);
    let mut n = 0;
    while n < 4 {
        b = b.mapping(0x1600 + n as u16, RPDO_MAP[n], RPDO_DEFAULT[n]);
        n += 1;
    }
    b = b.tpdo_comm(0).tpdo_comm(1).tpdo_comm(2).tpdo_comm(3);
    let mut n = 0;
    while n < 4 {
        b = b.mapping(0x1A00 + n as u16, TPDO_MAP[n], TPDO_DEFAULT[n]);
        n += 1;
    }
    // Manufacturer objects: the drive's configuration and calibration.
    let d = Default::Device;
    b = b
        .p(0x2000, "Motor pole pairs", Unsigned8, Ro, false, d)
        .p(0x2001, "Motor phase resistance [ohm]", Real32, Ro, false, d)
        .p(0x2002, "Motor d-axis inductance [H]", Real32, Ro, false, d)
        .p(0x2003, "Motor q-axis inductance [H]", Real32, Ro, false, d)
        .p(0x2004, "Motor flux linkage [Wb]", Real32, Ro, false, d)
        .p(0x2005, "Drive calibrated", Boolean, Ro, false, d)
        .p(0x2006, "Firmware version", Unsigned32, Ro, false, d)
        .p(
            0x2007,
            "Angle in use (0 sensor, 1 sensorless, 2 observer, 3 limp-home)",
            Unsigned8,
            Ro,
            false,
            d,
        );
    // The d-current reference (design §30): each setting written alone,
    // the whole judged by the drive (only while disabled).
    let (o, k) = ("D-current reference", Kind::Record(4));
    b = b
        .head(0x2008, o, k, Const)
        .sub(0x2008, 1, o, "Field weakening", k, Boolean, Rw, d)
        .sub(0x2008, 2, o, "MTPA", k, Boolean, Rw, d)
        .sub(
            0x2008,
            3,
            o,
            "Field weakening max d current [A]",
            k,
            Real32,
            Rw,
            d,
        )
        .sub(0x2008, 4, o, "Short circuit safe state", k, Boolean, Rw, d);
    // The tables kept with the configuration (design §32, §33): the
    // switch (only while disabled), the calibration (write 1 to start it,
    // only while disabled and calibrated; reads 1 while it runs) and the
    // table's peak.
    let (o, k) = ("Anticogging", Kind::Record(3));
    b = b
        .head(0x2009, o, k, Const)
        .sub(0x2009, 1, o, "Anticogging on", k, Boolean, Rw, d)
        .sub(0x2009, 2, o, "Measure the map", k, Unsigned8, Rw, d)
        .sub(0x2009, 3, o, "Map peak [A]", k, Real32, Ro, d);
    let (o, k) = ("Encoder linearisation", Kind::Record(3));
    b = b
        .head(0x200A, o, k, Const)
        .sub(0x200A, 1, o, "Encoder linearisation on", k, Boolean, Rw, d)
        .sub(0x200A, 2, o, "Learn the correction", k, Unsigned8, Rw, d)
        .sub(0x200A, 3, o, "Correction peak [rad]", k, Real32, Ro, d);
    b = b
        .p(0x2010, "Current loop kp [V per A]", Real32, Ro, false, d)
        .p(0x2011, "Current loop ki [V per A s]", Real32, Ro, false, d)
        .p(
            0x2012,
            "Speed loop kp [A per rad per s]",
            Real32,
            Rw,
            false,
            d,
        )
        .p(0x2013, "Speed loop ki [A per rad]", Real32, Rw, false, d)
        .p(0x2014, "Position loop kp [1 per s]", Real32, Ro, false, d)
        .var(
            0x2100,
            "CAN node id",
            Unsigned8,
            Rw,
            false,
            Some((1, 127)),
            Default::Int(1),
        )
        .var(
            0x2101,
            "CAN bit rate [kbit per s]",
            Unsigned16,
            Rw,
            false,
            Some((125, 1000)),
            Default::Int(1000),
        );
    // CiA 402.
    b = b
        .var(
            0x6007,
            "Abort connection option code",
            Integer16,
            Rw,
            false,
            Some((0, 3)),
            Default::Int(P402.abort_connection_option as i64),
        )
        .p(0x603F, "Error code", Unsigned16, Ro, true, Default::Int(0))
        .p(0x6040, "Controlword", Unsigned16, Rw, true, Default::Int(0))
        .p(0x6041, "Statusword", Unsigned16, Ro, true, Default::Int(0))
        .var(
            0x605A,
            "Quick stop option code",
            Integer16,
            Rw,
            false,
            // 0, 1, 2, 5, 6 (3 and 4 are refused: no current-limit stop).
            Some((0, 6)),
            Default::Int(P402.quick_stop_option as i64),
        )
        .p(
            0x6060,
            "Modes of operation",
            Integer8,
            Rw,
            true,
            Default::Int(0),
        )
        .p(
            0x6061,
            "Modes of operation display",
            Integer8,
            Ro,
            true,
            Default::Int(0),
        )
        .p(
            0x6062,
            "Position demand value",
            Integer32,
            Ro,
            true,
            Default::Int(0),
        )
        .p(
            0x6064,
            "Position actual value",
            Integer32,
            Ro,
            true,
            Default::Int(0),
        )
        .p(
            0x6065,
            "Following error window",
            Unsigned32,
            Rw,
            false,
            Default::Int(P402.following_error_window_inc as i64),
        )
        .p(
            0x6066,
            "Following error time out",
            Unsigned16,
            Rw,
            false,
            Default::Int(P402.following_error_timeout_ms as i64),
        )
        .p(
            0x6067,
            "Position window",
            Unsigned32,
            Rw,
            false,
            Default::Int(P402.position_window_inc as i64),
        )
        .p(
            0x6068,
            "Position window time",
            Unsigned16,
            Rw,
            false,
            Default::Int(P402.position_window_time_ms as i64),
        )
        .p(
            0x606B,
            "Velocity demand value",
            Integer32,
            Ro,
            true,
            Default::Int(0),
        )
        .p(
            0x606C,
            "Velocity actual value",
            Integer32,
            Ro,
            true,
            Default::Int(0),
        )
        .p(
            0x606D,
            "Velocity window",
            Unsigned16,
            Rw,
            false,
            Default::Int(P402.velocity_window_inc_s as i64),
        )
        .p(
            0x606E,
            "Velocity window time",
            Unsigned16,
            Rw,
            false,
            Default::Int(P402.velocity_window_time_ms as i64),
        )
        .p(
            0x6071,
            "Target torque",
            Integer16,
            Rw,
            true,
            Default::Int(0),
        )
        .p(
            0x6072,
            "Max torque",
            Unsigned16,
            Rw,
            false,
            Default::Int(P402.max_torque_permille as i64),
        )
        .p(0x6075, "Motor rated current", Unsigned32, Ro, false, d)
        .p(0x6076, "Motor rated torque", Unsigned32, Ro, false, d)
        .p(
            0x6077,
            "Torque actual value",
            Integer16,
            Ro,
            true,
            Default::Int(0),
        )
        .p(
            0x6078,
            "Current actual value",
            Integer16,
            Ro,
            true,
            Default::Int(0),
        )
        .p(
            0x6079,
            "DC link circuit voltage",
            Unsigned32,
            Ro,
            true,
            Default::Int(0),
        )
        .p(
            0x607A,
            "Target position",
            Integer32,
            Rw,
            true,
            Default::Int(0),
        )
        .p(
            0x607F,
            "Max profile velocity",
            Unsigned32,
            Rw,
            false,
            Default::Int(P402.max_profile_velocity_inc_s as i64),
        )
        .p(
            0x6081,
            "Profile velocity",
            Unsigned32,
            Rw,
            false,
            Default::Int(P402.profile_velocity_inc_s as i64),
        )
        .p(
            0x6083,
            "Profile acceleration",
            Unsigned32,
            Rw,
            false,
            Default::Int(P402.profile_acceleration_inc_s2 as i64),
        )
        .p(
            0x6084,
            "Profile deceleration",
            Unsigned32,
            Rw,
            false,
            Default::Int(P402.profile_deceleration_inc_s2 as i64),
        )
        .p(
            0x6085,
            "Quick stop deceleration",
            Unsigned32,
            Rw,
            false,
            Default::Int(P402.quick_stop_deceleration_inc_s2 as i64),
        )
        .p(
            0x6087,
            "Torque slope",
            Unsigned32,
            Rw,
            false,
            Default::Int(P402.torque_slope_permille_s as i64),
        );
    let (o, k) = ("Position encoder resolution", Kind::Array(2));
    b = b
        .head(0x608F, o, k, Const)
        .sub(
            0x608F,
            1,
            o,
            "Encoder increments",
            k,
            Unsigned32,
            Const,
            Default::Int(INC_PER_REV as i64),
        )
        .sub(
            0x608F,
            2,
            o,
            "Motor revolutions",
            k,
            Unsigned32,
            Const,
            Default::Int(1),
        )
        .p(
            0x60B1,
            "Velocity offset",
            Integer32,
            Rw,
            true,
            Default::Int(0),
        )
        .p(
            0x60B2,
            "Torque offset",
            Integer16,
            Rw,
            true,
            Default::Int(0),
        );
    let (o, k) = ("Interpolation time period", Kind::Record(2));
    b = b
        .head(0x60C2, o, k, Const)
        .sub(
            0x60C2,
            1,
            o,
            "Interpolation time period value",
            k,
            Unsigned8,
            Ro,
            Default::Int(1),
        )
        .sub(
            0x60C2,
            2,
            o,
            "Interpolation time index",
            k,
            Integer8,
            Ro,
            Default::Int(-3),
        )
        .p(
            0x60F4,
            "Following error actual value",
            Integer32,
            Ro,
            true,
            Default::Int(0),
        )
        .p(
            0x60FF,
            "Target velocity",
            Integer32,
            Rw,
            true,
            Default::Int(0),
        )
        .p(
            0x6502,
            "Supported drive modes",
            Unsigned32,
            Const,
            false,
            Default::Int(OpMode::SUPPORTED_MASK as i64),
        );
    b
}
