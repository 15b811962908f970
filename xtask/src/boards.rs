//! The boards the firmware is built for: the one list every subcommand uses.
//!
//! A board's name is also its cargo feature in `firmware` and, for the
//! boards themselves, in `board-support` (`odrive-v3-as5047p` is the
//! firmware's name for `odrive-v3` with board-support's `as5047p` option).
//! Exactly one board is built per cargo invocation (the HAL's chip features
//! clash when two are unified).

use std::fmt;

/// One supported board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Board {
    /// Name on the command line (`--board <name>`).
    pub name: &'static str,
    /// Cargo feature of `firmware` that selects it (and of `board-support`,
    /// except for a board option such as `odrive-v3-as5047p`).
    pub feature: &'static str,
    /// Chip name for `probe-rs run --chip <chip>`.
    pub chip: &'static str,
    /// Whether the firmware can run under QEMU's `netduinoplus2` machine,
    /// which models an STM32F405 (QEMU 7.2 and later).
    pub qemu: bool,
    /// Human description: MCU board + power stage.
    pub description: &'static str,
    /// 256 KiB of program flash: the release build uses the
    /// `release-small` profile (size first, Cargo.toml).
    pub small_flash: bool,
}

/// All boards, the default one first.
pub const BOARDS: [Board; 5] = [
    Board {
        name: "nucleo-f446re-ihm07m1",
        feature: "nucleo-f446re-ihm07m1",
        chip: "STM32F446RETx",
        qemu: false,
        description: "NUCLEO-F446RE + X-NUCLEO-IHM07M1 (default)",
        small_flash: true,
    },
    Board {
        name: "nucleo-f401re-ihm07m1",
        feature: "nucleo-f401re-ihm07m1",
        chip: "STM32F401RETx",
        qemu: false,
        description: "NUCLEO-F401RE + X-NUCLEO-IHM07M1",
        small_flash: true,
    },
    Board {
        name: "odrive-v3",
        feature: "odrive-v3",
        chip: "STM32F405RGTx",
        qemu: false,
        description: "ODrive v3.x (STM32F405)",
        small_flash: false,
    },
    Board {
        name: "odrive-v3-as5047p",
        feature: "odrive-v3-as5047p",
        chip: "STM32F405RGTx",
        qemu: false,
        description: "ODrive v3.x (STM32F405) + AS5047P on the SPI bus",
        small_flash: false,
    },
    Board {
        name: "qemu",
        feature: "qemu",
        chip: "STM32F405RGTx",
        qemu: true,
        description: "emulated: QEMU netduinoplus2 (STM32F405) + simulated motor",
        small_flash: false,
    },
];

/// The default board (`cargo xtask build` with no `--board`).
pub const DEFAULT_BOARD: &Board = &BOARDS[0];

/// Memory-use goals of the default board, in bytes: (flash, static RAM).
pub const DEFAULT_BOARD_GOALS: (u64, u64) = (96 * 1024, 8 * 1024);

impl Board {
    /// The size goals (flash, RAM) in bytes, if this board has any.
    pub fn goals(&self) -> Option<(u64, u64)> {
        (self.name == DEFAULT_BOARD.name).then_some(DEFAULT_BOARD_GOALS)
    }
}

impl fmt::Display for Board {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name)
    }
}

/// Looks a board up by name.
pub fn find(name: &str) -> Option<&'static Board> {
    BOARDS.iter().find(|b| b.name == name)
}

/// Parses a `--board` value: a board name or `all`. Used as clap's value parser.
pub fn parse_selection(s: &str) -> Result<Selection, String> {
    if s == "all" {
        return Ok(Selection::All);
    }
    match find(s) {
        Some(b) => Ok(Selection::One(b)),
        None => Err(format!(
            "unknown board `{s}`; known boards: {}, or `all`",
            BOARDS.iter().map(|b| b.name).collect::<Vec<_>>().join(", ")
        )),
    }
}

/// What `--board` selected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Selection {
    /// Every board, one after the other.
    All,
    /// One board.
    One(&'static Board),
}

impl Selection {
    /// The selected boards, in [`BOARDS`] order.
    pub fn boards(self) -> Vec<&'static Board> {
        match self {
            Selection::All => BOARDS.iter().collect(),
            Selection::One(b) => vec![b],
        }
    }
}

impl Default for Selection {
    fn default() -> Self {
        Selection::One(DEFAULT_BOARD)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_features_and_unique() {
        for (i, b) in BOARDS.iter().enumerate() {
            assert_eq!(b.name, b.feature);
            assert!(BOARDS[i + 1..].iter().all(|o| o.name != b.name));
        }
    }

    #[test]
    fn selection_parses() {
        assert_eq!(parse_selection("all"), Ok(Selection::All));
        assert_eq!(
            parse_selection("odrive-v3").map(Selection::boards),
            Ok(vec![&BOARDS[2]])
        );
        assert_eq!(
            parse_selection("odrive-v3-as5047p").map(Selection::boards),
            Ok(vec![&BOARDS[3]])
        );
        assert!(parse_selection("nucleo").is_err());
        assert_eq!(Selection::default().boards(), vec![DEFAULT_BOARD]);
    }
}
