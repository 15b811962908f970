//! The emulated board's options, parsed from the semihosting command line.
//!
//! QEMU is started with
//! `-semihosting-config enable=on,target=native,arg=firmware,arg=store=PATH,arg=sensor=absolute,arg=rotor=1.3,arg=mission=NAME,arg=supply=nonsinking,arg=brake=2`
//! and `SYS_GET_CMDLINE` hands the `arg=` values back joined by single
//! spaces, the first one being the program name (without any `arg=`, QEMU
//! falls back to the kernel file name followed by the `-append` string).
//! Every space-separated token of the form `key=value` is looked at; tokens
//! without `=` (the program name) and unknown keys are ignored, a malformed
//! value leaves that option at its default. Parsing never panics.
//!
//! | key       | value                          | default                   |
//! |-----------|--------------------------------|---------------------------|
//! | `store`   | host path, < 128 bytes, no spaces | none: no store         |
//! | `sensor`  | `absolute` or `incremental`    | incremental               |
//! | `rotor`   | start angle [rad], finite f32  | 0.0                       |
//! | `mission` | name, <= 16 bytes UTF-8        | empty                     |
//! | `supply`  | `nonsinking` or `ideal`        | ideal: no DC link         |
//! | `brake`   | brake resistor [ohm], finite, > 0 | none                   |
//! | `identify`| `on` or `off`: identify at start-up (as configured) or boot as a real board does | on |
//!
//! `supply=nonsinking` gives the emulated plant a DC link (bulk capacitor,
//! a 24 V source that cannot take current back); `brake=OHMS` fits a brake
//! resistor across it and tells the firmware the board has a brake output
//! (see the emulated board's module docs for what each one builds).
//!
//! ```
//! use board_support::logic::emu_args::{EmuArgs, EmuSupply};
//! let a = EmuArgs::parse(b"firmware store=/tmp/s.bin sensor=absolute rotor=1.3 mission=calib");
//! assert_eq!(a.store_path(), Some(&b"/tmp/s.bin"[..]));
//! assert!(a.absolute_sensor);
//! assert_eq!(a.rotor_start_rad, 1.3);
//! assert_eq!(a.mission(), "calib");
//! assert_eq!(a.supply, EmuSupply::Ideal);
//!
//! let b = EmuArgs::parse(b"firmware mission=brake supply=nonsinking brake=2");
//! assert_eq!(b.supply, EmuSupply::NonSinking);
//! assert_eq!(b.brake_resistor_ohm, Some(2.0));
//! ```

/// Capacity of the store path, terminating NUL included [bytes].
pub const STORE_PATH_CAPACITY: usize = 128;
/// Capacity of the mission name [bytes].
pub const MISSION_CAPACITY: usize = 16;

/// The emulated board's DC supply (`supply=`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmuSupply {
    /// No DC link: an ideal source behind a small resistance, which takes
    /// any regenerated current back (the default, `supply=ideal`).
    Ideal,
    /// A DC link with a bulk capacitor fed by a source that cannot sink
    /// current (a diode-fed bench supply): `supply=nonsinking`.
    NonSinking,
}

/// Options of the emulated board (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmuArgs {
    /// Host file backing the store: path bytes, NUL-terminated (the form
    /// semihosting `SYS_OPEN` wants); `None` without `store=`.
    store_path: Option<[u8; STORE_PATH_CAPACITY]>,
    /// Length of the store path without its NUL [bytes].
    store_path_len: usize,
    /// `sensor=absolute`: the simulated rotor sensor is an absolute
    /// (AS5047P-like) one, not an incremental encoder.
    pub absolute_sensor: bool,
    /// `rotor=X`: mechanical angle of the rotor at reset [rad].
    pub rotor_start_rad: f32,
    /// Mission name bytes (valid UTF-8, checked at parse).
    mission: [u8; MISSION_CAPACITY],
    /// Length of the mission name [bytes].
    mission_len: usize,
    /// `supply=`: the DC supply the emulated plant runs from.
    pub supply: EmuSupply,
    /// `brake=R`: a brake resistor of `R` ohm across the DC link, switched
    /// by the firmware's chopper; `None` without (no brake output).
    pub brake_resistor_ohm: Option<f32>,
    /// `identify=off`: boot without the start-up identification, as a real
    /// board does (`on`, the default: as the firmware is configured).
    pub identify_at_start_up: bool,
}

impl Default for EmuArgs {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl EmuArgs {
    /// No store, incremental encoder, rotor at 0 rad, no mission, ideal
    /// supply, no brake resistor.
    pub const DEFAULT: EmuArgs = EmuArgs {
        store_path: None,
        store_path_len: 0,
        absolute_sensor: false,
        rotor_start_rad: 0.0,
        mission: [0; MISSION_CAPACITY],
        mission_len: 0,
        supply: EmuSupply::Ideal,
        brake_resistor_ohm: None,
        identify_at_start_up: true,
    };

    /// Parse a command line (see the module docs); never fails.
    pub fn parse(cmdline: &[u8]) -> Self {
        let mut args = Self::DEFAULT;
        // The host's string may carry its NUL terminator: stop there.
        let end = cmdline
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(cmdline.len());
        for token in cmdline.get(..end).unwrap_or(cmdline).split(|&b| b == b' ') {
            if let Some(eq) = token.iter().position(|&b| b == b'=') {
                let (key, rest) = token.split_at(eq);
                args.apply(key, rest.get(1..).unwrap_or(&[]));
            }
        }
        args
    }

    /// Apply one `key=value` pair; unknown keys and bad values are ignored.
    fn apply(&mut self, key: &[u8], value: &[u8]) {
        match key {
            b"store" => self.set_store_path(value),
            b"sensor" => match value {
                b"absolute" => self.absolute_sensor = true,
                b"incremental" => self.absolute_sensor = false,
                _ => {}
            },
            b"rotor" => {
                if let Some(x) = parse_f32(value) {
                    self.rotor_start_rad = x;
                }
            }
            b"mission" => self.set_mission(value),
            b"identify" => match value {
                b"on" => self.identify_at_start_up = true,
                b"off" => self.identify_at_start_up = false,
                _ => {}
            },
            b"supply" => match value {
                b"nonsinking" => self.supply = EmuSupply::NonSinking,
                b"ideal" => self.supply = EmuSupply::Ideal,
                _ => {}
            },
            b"brake" => {
                if let Some(r) = parse_f32(value).filter(|&r| r > 0.0) {
                    self.brake_resistor_ohm = Some(r);
                }
            }
            _ => {}
        }
    }

    fn set_store_path(&mut self, path: &[u8]) {
        if path.is_empty() || path.len() >= STORE_PATH_CAPACITY || path.contains(&0) {
            return;
        }
        let mut buf = [0u8; STORE_PATH_CAPACITY];
        let Some(dst) = buf.get_mut(..path.len()) else {
            return;
        };
        dst.copy_from_slice(path);
        self.store_path = Some(buf);
        self.store_path_len = path.len();
    }

    fn set_mission(&mut self, name: &[u8]) {
        if name.len() > MISSION_CAPACITY || core::str::from_utf8(name).is_err() {
            return;
        }
        let mut buf = [0; MISSION_CAPACITY];
        let Some(dst) = buf.get_mut(..name.len()) else {
            return;
        };
        dst.copy_from_slice(name);
        self.mission = buf;
        self.mission_len = name.len();
    }

    /// The store's host path (without NUL), if `store=` was given.
    pub fn store_path(&self) -> Option<&[u8]> {
        self.store_path
            .as_ref()
            .and_then(|p| p.get(..self.store_path_len.min(STORE_PATH_CAPACITY - 1)))
    }

    /// The store's host path with its terminating NUL (for `SYS_OPEN`).
    pub fn store_path_with_nul(&self) -> Option<&[u8]> {
        self.store_path
            .as_ref()
            .and_then(|p| p.get(..(self.store_path_len + 1).min(STORE_PATH_CAPACITY)))
    }

    /// The mission name (`""` without `mission=`).
    pub fn mission(&self) -> &str {
        let bytes = self
            .mission
            .get(..self.mission_len.min(MISSION_CAPACITY))
            .unwrap_or(&[]);
        core::str::from_utf8(bytes).unwrap_or("")
    }
}

/// A finite `f32` from ASCII, or `None`.
fn parse_f32(s: &[u8]) -> Option<f32> {
    let x: f32 = core::str::from_utf8(s).ok()?.parse().ok()?;
    if x.is_finite() {
        Some(x)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn defaults_without_args() {
        assert_eq!(EmuArgs::parse(b""), EmuArgs::DEFAULT);
        assert_eq!(EmuArgs::parse(b"firmware"), EmuArgs::DEFAULT);
        let a = EmuArgs::parse(b"target/thumbv7em-none-eabihf/release/firmware");
        assert_eq!(a.store_path(), None);
        assert!(!a.absolute_sensor);
        assert_eq!(a.rotor_start_rad, 0.0);
        assert_eq!(a.mission(), "");
        assert_eq!(a.supply, EmuSupply::Ideal);
        assert_eq!(a.brake_resistor_ohm, None);
    }

    #[test]
    fn supply_and_brake() {
        let a = EmuArgs::parse(b"firmware mission=brake supply=nonsinking brake=2");
        assert_eq!(a.mission(), "brake");
        assert_eq!(a.supply, EmuSupply::NonSinking);
        assert_eq!(a.brake_resistor_ohm, Some(2.0));
        // Each option alone; the other keeps its default.
        let a = EmuArgs::parse(b"fw supply=nonsinking");
        assert_eq!(a.supply, EmuSupply::NonSinking);
        assert_eq!(a.brake_resistor_ohm, None);
        let a = EmuArgs::parse(b"fw brake=0.5");
        assert_eq!(a.supply, EmuSupply::Ideal);
        assert_eq!(a.brake_resistor_ohm, Some(0.5));
        // A later valid value wins.
        let a = EmuArgs::parse(b"fw supply=nonsinking supply=ideal brake=1 brake=bad brake=3.3");
        assert_eq!(a.supply, EmuSupply::Ideal);
        assert_eq!(a.brake_resistor_ohm, Some(3.3));
    }

    #[test]
    fn malformed_supply_and_brake_keep_defaults() {
        let a = EmuArgs::parse(
            b"fw supply= supply=sinking supply=NonSinking brake= brake=0 brake=-2 brake=nan brake=inf brake=1e40 brake=2ohm",
        );
        assert_eq!(a, EmuArgs::DEFAULT);
    }

    #[test]
    fn full_command_line() {
        let a = EmuArgs::parse(
            b"firmware store=out/store.bin sensor=absolute rotor=-0.25 mission=restart\0junk",
        );
        assert_eq!(a.store_path(), Some(&b"out/store.bin"[..]));
        assert_eq!(a.store_path_with_nul(), Some(&b"out/store.bin\0"[..]));
        assert!(a.absolute_sensor);
        assert_eq!(a.rotor_start_rad, -0.25);
        assert_eq!(a.mission(), "restart");
    }

    #[test]
    fn malformed_values_keep_defaults() {
        let long_path = [b'a'; STORE_PATH_CAPACITY];
        let mut line = [0u8; 6 + STORE_PATH_CAPACITY];
        line[..6].copy_from_slice(b"store=");
        line[6..].copy_from_slice(&long_path);
        assert_eq!(EmuArgs::parse(&line).store_path(), None);
        let a = EmuArgs::parse(
            b"fw store= sensor=magic rotor=nan rotor=1e40 rotor=x mission=abcdefghijklmnopq colour=red =",
        );
        assert_eq!(a, EmuArgs::DEFAULT);
        // A later valid value wins; spaces around are tolerated.
        let a = EmuArgs::parse(b"  fw  rotor=1.3  rotor=bad sensor=absolute sensor=incremental ");
        assert_eq!(a.rotor_start_rad, 1.3);
        assert!(!a.absolute_sensor);
    }

    #[test]
    fn longest_accepted_values() {
        let mut line = [b'p'; 6 + STORE_PATH_CAPACITY - 1];
        line[..6].copy_from_slice(b"store=");
        let a = EmuArgs::parse(&line);
        assert_eq!(
            a.store_path().map(<[u8]>::len),
            Some(STORE_PATH_CAPACITY - 1)
        );
        assert_eq!(
            a.store_path_with_nul().and_then(|p| p.last().copied()),
            Some(0)
        );
        assert_eq!(
            EmuArgs::parse(b"mission=abcdefghijklmnop").mission(),
            "abcdefghijklmnop"
        );
    }

    proptest! {
        #[test]
        fn never_panics(line in proptest::collection::vec(any::<u8>(), 0..400)) {
            let a = EmuArgs::parse(&line);
            let _ = a.mission();
            prop_assert!(a.rotor_start_rad.is_finite());
            if let Some(r) = a.brake_resistor_ohm {
                prop_assert!(r.is_finite() && r > 0.0);
            }
            if let Some(p) = a.store_path_with_nul() {
                prop_assert_eq!(p.last().copied(), Some(0));
            }
        }
    }
}
