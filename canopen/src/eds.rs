//! EDS writer (CiA 306 v1.3 electronic data sheet) from the object table
//! [`crate::od::OBJECTS`]: one section per object and sub-object, the
//! object lists, the device's bit rates and PDO counts. The output depends
//! only on the table and the [`EdsInfo`] (no clock): the checked-in
//! `docs/canopen/foc-drive.eds` is compared with it by a test.
//!
//! ```
//! use foc_canopen::eds::{write_eds, EdsInfo};
//! let mut s = String::new();
//! write_eds(&mut s, &EdsInfo::FOC_DRIVE).unwrap();
//! assert!(s.contains("[1000]\nParameterName=Device type\n"));
//! ```

use core::fmt::{Result, Write};

use crate::node::CommSettings;
use crate::od::{DataType, Default, Kind, ObjectDef, OBJECTS};
use crate::pdo::COUNT;

/// What the EDS says about the file and the device beyond the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EdsInfo<'a> {
    /// `FileName`.
    pub file_name: &'a str,
    /// `FileVersion`.
    pub file_version: u8,
    /// `FileRevision`.
    pub file_revision: u8,
    /// `Description`.
    pub description: &'a str,
    /// `CreationDate` / `ModificationDate` (`mm-dd-yyyy`).
    pub date: &'a str,
    /// `CreationTime` / `ModificationTime` (`hh:mm(AM|PM)`).
    pub time: &'a str,
    /// `CreatedBy` / `ModifiedBy`.
    pub created_by: &'a str,
    /// `VendorName`.
    pub vendor_name: &'a str,
    /// `VendorNumber` (0x1018 sub 1).
    pub vendor_number: u32,
    /// `ProductName` (also 0x1008's default).
    pub product_name: &'a str,
    /// `ProductNumber` (0x1018 sub 2).
    pub product_number: u32,
    /// `RevisionNumber` (0x1018 sub 3).
    pub revision_number: u32,
    /// `OrderCode`.
    pub order_code: &'a str,
}

impl EdsInfo<'static> {
    /// The FOC drive's EDS header (`docs/canopen/foc-drive.eds`).
    pub const FOC_DRIVE: Self = Self {
        file_name: "foc-drive.eds",
        file_version: 1,
        file_revision: 0,
        description: "FOC motor drive, CiA 301 node with the CiA 402 drive profile",
        date: "01-01-2026",
        time: "12:00PM",
        created_by: "foc-canopen write_eds",
        vendor_name: "FOC drive project",
        vendor_number: 0,
        product_name: "FOC drive",
        product_number: 0x0000_0402,
        revision_number: 0x0001_0000,
        order_code: "foc-drive",
    };
}

fn is_mandatory(index: u16) -> bool {
    matches!(index, 0x1000 | 0x1001 | 0x1018)
}

fn is_manufacturer(index: u16) -> bool {
    (0x2000..=0x5FFF).contains(&index)
}

/// The distinct indices of the table, in order, that pass `keep`.
fn indices(keep: impl Fn(u16) -> bool) -> impl Iterator<Item = u16> {
    OBJECTS
        .iter()
        .filter(|d| d.sub == 0)
        .map(|d| d.index)
        .filter(move |&i| keep(i))
}

fn write_list<W: Write>(w: &mut W, name: &str, keep: impl Fn(u16) -> bool + Copy) -> Result {
    writeln!(w, "[{name}]")?;
    writeln!(w, "SupportedObjects={}", indices(keep).count())?;
    for (n, i) in indices(keep).enumerate() {
        writeln!(w, "{}=0x{i:04X}", n + 1)?;
    }
    writeln!(w)
}

fn write_default<W: Write>(w: &mut W, d: &ObjectDef, info: &EdsInfo) -> Result {
    write!(w, "DefaultValue=")?;
    match d.default {
        Default::Int(v) if d.data_type == DataType::Unsigned32 => write!(w, "0x{:08X}", v as u32)?,
        Default::Int(v) => write!(w, "{v}")?,
        Default::Real(r) => write!(w, "{r}")?,
        Default::NodeId(b) => write!(w, "$NODEID+0x{b:X}")?,
        Default::Str(s) => write!(w, "{s}")?,
        Default::Device => match (d.index, d.sub) {
            (0x1008, 0) => write!(w, "{}", info.product_name)?,
            (0x1018, 1) => write!(w, "0x{:08X}", info.vendor_number)?,
            (0x1018, 2) => write!(w, "0x{:08X}", info.product_number)?,
            (0x1018, 3) => write!(w, "0x{:08X}", info.revision_number)?,
            _ if d.data_type == DataType::VisibleString => {}
            _ if d.data_type == DataType::Real32 => write!(w, "0.0")?,
            _ => write!(w, "0")?,
        },
    }
    writeln!(w)
}

fn write_entry<W: Write>(w: &mut W, d: &ObjectDef, info: &EdsInfo, section: &str) -> Result {
    writeln!(w, "[{section}]")?;
    writeln!(w, "ParameterName={}", d.name)?;
    writeln!(w, "ObjectType=0x7")?;
    writeln!(w, "DataType=0x{:04X}", d.data_type.code())?;
    writeln!(w, "AccessType={}", d.access.eds())?;
    write_default(w, d, info)?;
    writeln!(w, "PDOMapping={}", u8::from(d.pdo_mappable))?;
    if let Some((lo, hi)) = d.limits {
        writeln!(w, "LowLimit={lo}")?;
        writeln!(w, "HighLimit={hi}")?;
    }
    writeln!(w)
}

/// Write the whole EDS.
pub fn write_eds<W: Write>(w: &mut W, info: &EdsInfo) -> Result {
    writeln!(w, "[FileInfo]")?;
    writeln!(w, "FileName={}", info.file_name)?;
    writeln!(w, "FileVersion={}", info.file_version)?;
    writeln!(w, "FileRevision={}", info.file_revision)?;
    writeln!(w, "EDSVersion=4.0")?;
    writeln!(w, "Description={}", info.description)?;
    writeln!(w, "CreationTime={}", info.time)?;
    writeln!(w, "CreationDate={}", info.date)?;
    writeln!(w, "CreatedBy={}", info.created_by)?;
    writeln!(w, "ModificationTime={}", info.time)?;
    writeln!(w, "ModificationDate={}", info.date)?;
    writeln!(w, "ModifiedBy={}", info.created_by)?;
    writeln!(w)?;
    writeln!(w, "[DeviceInfo]")?;
    writeln!(w, "VendorName={}", info.vendor_name)?;
    writeln!(w, "VendorNumber=0x{:08X}", info.vendor_number)?;
    writeln!(w, "ProductName={}", info.product_name)?;
    writeln!(w, "ProductNumber=0x{:08X}", info.product_number)?;
    writeln!(w, "RevisionNumber=0x{:08X}", info.revision_number)?;
    writeln!(w, "OrderCode={}", info.order_code)?;
    for rate in [10u16, 20, 50, 125, 250, 500, 800, 1000] {
        writeln!(
            w,
            "BaudRate_{rate}={}",
            u8::from(CommSettings::BIT_RATES.contains(&rate))
        )?;
    }
    writeln!(w, "SimpleBootUpMaster=0")?;
    writeln!(w, "SimpleBootUpSlave=1")?;
    writeln!(w, "Granularity=8")?;
    writeln!(w, "DynamicChannelsSupported=0")?;
    writeln!(w, "GroupMessaging=0")?;
    writeln!(w, "NrOfRXPDO={COUNT}")?;
    writeln!(w, "NrOfTXPDO={COUNT}")?;
    writeln!(w, "LSS_Supported=0")?;
    writeln!(w)?;
    writeln!(w, "[DummyUsage]")?;
    for n in 1..=7 {
        writeln!(w, "Dummy{n:04}=0")?;
    }
    writeln!(w)?;
    write_list(w, "MandatoryObjects", is_mandatory)?;
    write_list(w, "OptionalObjects", |i| {
        !is_mandatory(i) && !is_manufacturer(i)
    })?;
    write_list(w, "ManufacturerObjects", is_manufacturer)?;
    let mut i = 0;
    while let Some(first) = OBJECTS.get(i) {
        let subs = OBJECTS
            .get(i..)
            .unwrap_or(&[])
            .iter()
            .take_while(|d| d.index == first.index)
            .count()
            .max(1);
        match first.kind {
            Kind::Var => write_entry(w, first, info, &Section(first.index, None).text())?,
            Kind::Array(_) | Kind::Record(_) => {
                writeln!(w, "[{:04X}]", first.index)?;
                writeln!(w, "ParameterName={}", first.object)?;
                writeln!(w, "ObjectType=0x{:X}", first.kind.code())?;
                writeln!(w, "SubNumber={subs}")?;
                writeln!(w)?;
                for d in OBJECTS.get(i..i + subs).unwrap_or(&[]) {
                    write_entry(w, d, info, &Section(d.index, Some(d.sub)).text())?;
                }
            }
        }
        i += subs;
    }
    Ok(())
}

/// A section name: `1018` or `1018sub2`.
struct Section(u16, Option<u8>);

impl Section {
    fn text(&self) -> SectionText {
        let mut t = SectionText::default();
        let _ = match self.1 {
            None => write!(t, "{:04X}", self.0),
            Some(s) => write!(t, "{:04X}sub{s:X}", self.0),
        };
        t
    }
}

#[derive(Default)]
struct SectionText {
    buf: [u8; 12],
    len: usize,
}

impl Write for SectionText {
    fn write_str(&mut self, s: &str) -> Result {
        for b in s.bytes() {
            *self.buf.get_mut(self.len).ok_or(core::fmt::Error)? = b;
            self.len += 1;
        }
        Ok(())
    }
}

impl core::ops::Deref for SectionText {
    type Target = str;
    fn deref(&self) -> &str {
        core::str::from_utf8(self.buf.get(..self.len).unwrap_or(&[])).unwrap_or("")
    }
}
