//! Flash per feature group, from the ELF's symbols.
//!
//! `llvm-nm --print-size --size-sort --demangle` lists every sized symbol.
//! Only symbols that occupy flash are counted: code (`t`/`T`), read-only
//! data (`r`/`R`, incl. the vector table's `__RESET_VECTOR`, `__EXCEPTIONS`,
//! `__INTERRUPTS`) and initialised RAM data (`d`/`D`, whose initial values
//! are stored in flash). `.bss` (`b`/`B`) and defmt's format strings (`N`,
//! a non-loaded section) are not flash.
//!
//! Each symbol goes to the first group of [`RULES`] whose pattern matches its
//! path (see [`subject`] for trait impls such as `<A as B>::f`). Named
//! symbols no rule matches are reported as `other`. What no named symbol
//! covers is reported as `unattributed`: anonymous constants (`.Lanon.*`:
//! string literals, panic locations, lookup tables whose owner the compiler
//! did not record), read-only data with no symbol at all (merged constant
//! sections), the vector table's initial stack pointer word, and alignment
//! padding between symbols. It is the llvm-size flash figure
//! minus everything attributed, so the rows always sum to that figure.
//!
//! ```text
//! firmware tasks (inlined)   31.2 KiB
//! control                    40.3 KiB
//! ...
//! unattributed                6.0 KiB  (.Lanon constants 4.5 KiB, padding and gaps 1.5 KiB)
//! total (= flash)           143.2 KiB
//! ```

use std::collections::BTreeMap;
use std::path::Path;

use crate::util::{command, kib, output, Result};

/// Group of the RTIC tasks' interrupt handlers. RTIC generates each bound
/// task as the handler itself (`ADC`, `EXTI1`, ...) with the task body and
/// most of what it calls inlined, so their bytes cannot be split between
/// control, protocol and storage: they get a group of their own. `init`
/// (`__rtic_init_resources`: clocks, pins, peripherals, the stored
/// configuration's load) is inlined the same way and counted here too.
pub const TASKS: &str = "firmware tasks (inlined)";

/// Named symbols that match no rule.
pub const OTHER: &str = "other";

/// Flash that no named symbol covers.
pub const UNATTRIBUTED: &str = "unattributed";

/// The groups in report order (then [`OTHER`] and [`UNATTRIBUTED`]).
pub const GROUPS: [&str; 7] = [
    TASKS,
    "control",
    "calibration",
    "protocol",
    "storage",
    "HAL",
    "runtime",
];

/// (pattern, group), first match wins. A pattern matches a path equal to it
/// or starting with it followed by `::`; a pattern ending in `*` matches any
/// path starting with what precedes the `*`.
pub const RULES: &[(&str, &str)] = &[
    // The RTIC tasks (this app binds the same interrupts on every board).
    ("ADC", TASKS),
    ("EXTI1", TASKS),
    ("EXTI2", TASKS),
    ("EXTI3", TASKS),
    ("USART2", TASKS),
    ("TIM1_BRK_TIM9", TASKS),
    ("firmware::app::main::__rtic_init_resources", TASKS),
    // Calibration before control: `drive::identify` is under `drive`.
    ("foc_core::drive::identify", "calibration"),
    // The lifecycle's identification phase (the routines inlined into it).
    (
        "foc_core::drive::lifecycle::Lifecycle::step_identify",
        "calibration",
    ),
    ("foc_core::calibration", "calibration"),
    ("foc_core::tuning", "calibration"),
    ("foc_core::control", "control"),
    ("foc_core::drive", "control"),
    ("foc_core::transforms", "control"),
    ("foc_core::svpwm", "control"),
    ("foc_core::trig", "control"),
    ("foc_core::pi", "control"),
    ("foc_core::math", "control"),
    ("foc_core::angle", "control"),
    ("foc_core::frames", "control"),
    ("foc_core::hal", "HAL"),
    ("foc_core", "control"),
    ("foc_protocol", "protocol"),
    ("firmware::comms", "protocol"),
    ("foc_store", "storage"),
    ("sequential_storage", "storage"),
    ("embedded_storage*", "storage"),
    ("postcard", "storage"),
    ("serde*", "storage"),
    ("embassy_futures", "storage"),
    ("firmware::persist", "storage"),
    ("firmware::store_mission", "storage"),
    ("crc", "storage"),
    (".L.crctable*", "storage"),
    // Everything else the firmware crate defines is RTIC glue (the
    // dispatchers, `idle`, the exception handlers) or board bring-up.
    ("firmware", "HAL"),
    ("stm32f4xx_hal", "HAL"),
    ("stm32f4", "HAL"),
    ("board_support", "HAL"),
    ("cortex_m*", "HAL"),
    ("rtic*", "HAL"),
    ("RTIC_*", "HAL"),
    ("embedded_hal*", "HAL"),
    ("fugit", "HAL"),
    ("critical_section", "HAL"),
    // cortex-m-rt's entry, default handlers and the vector table.
    ("main", "HAL"),
    ("Reset", "HAL"),
    ("DefaultHandler*", "HAL"),
    ("DefaultPreInit", "HAL"),
    ("HardFault", "HAL"),
    ("_HardFault", "HAL"),
    ("__RESET_VECTOR", "HAL"),
    ("__EXCEPTIONS", "HAL"),
    ("__INTERRUPTS", "HAL"),
    // Compiler runtime, formatting, logging, panics.
    ("compiler_builtins", "runtime"),
    ("__aeabi_*", "runtime"),
    ("__udivmoddi4", "runtime"),
    ("__divmoddi4", "runtime"),
    ("fmaxf", "runtime"),
    ("fminf", "runtime"),
    ("libm", "runtime"),
    ("core", "runtime"),
    ("defmt*", "runtime"),
    ("_defmt_*", "runtime"),
    ("__defmt_*", "runtime"),
    ("_SEGGER_RTT", "runtime"),
    ("panic_probe", "runtime"),
    ("__rustc", "runtime"),
    ("rust_begin_unwind", "runtime"),
    ("heapless", "runtime"),
    // Inherent methods of primitive types (`<i64>::rem_euclid`).
    ("i8", "runtime"),
    ("i16", "runtime"),
    ("i32", "runtime"),
    ("i64", "runtime"),
    ("u8", "runtime"),
    ("u16", "runtime"),
    ("u32", "runtime"),
    ("u64", "runtime"),
    ("usize", "runtime"),
    ("isize", "runtime"),
    ("f32", "runtime"),
    ("f64", "runtime"),
    // opt-level "z" turns on LLVM's machine outliner: instruction sequences
    // shared by functions of any group, factored out into
    // `OUTLINED_FUNCTION_<n>`. They have no owner.
    ("OUTLINED_FUNCTION_*", OTHER),
];

/// One flash symbol of `llvm-nm --print-size` output.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Symbol {
    /// Address.
    pub addr: u64,
    /// Size in bytes.
    pub size: u64,
    /// Its name, demangled.
    pub name: String,
}

/// Whether an nm symbol type letter is in flash (code, read-only data, and
/// initialised data whose initial values live in flash).
fn in_flash(kind: &str) -> bool {
    matches!(kind, "t" | "T" | "r" | "R" | "d" | "D")
}

/// Parses one `address size type name` line; `None` for other lines and
/// for symbols that are not in flash or have no size.
fn parse_line(line: &str) -> Option<Symbol> {
    let mut fields = line.splitn(4, ' ');
    let addr = u64::from_str_radix(fields.next()?, 16).ok()?;
    let size = u64::from_str_radix(fields.next()?, 16).ok()?;
    let kind = fields.next()?;
    let name = fields.next()?.trim();
    (in_flash(kind) && size > 0).then(|| Symbol {
        addr,
        size,
        name: demangle(name),
    })
}

/// Parses `llvm-nm --print-size` output into flash symbols, one per
/// address (aliases are counted once: the largest).
pub fn parse_nm(out: &str) -> Vec<Symbol> {
    let mut by_addr: BTreeMap<u64, Symbol> = BTreeMap::new();
    for sym in out.lines().filter_map(parse_line) {
        let keep = by_addr.get(&sym.addr).is_none_or(|s| s.size < sym.size);
        if keep {
            by_addr.insert(sym.addr, sym);
        }
    }
    by_addr.into_values().collect()
}

/// The escapes of Rust's legacy symbol mangling, which llvm-nm's demangler
/// leaves in place (`_$LT$foo..Bar$u20$as$u20$baz..Qux$GT$::f::h0123..`).
const ESCAPES: [(&str, &str); 13] = [
    ("$LT$", "<"),
    ("$GT$", ">"),
    ("$RF$", "&"),
    ("$BP$", "*"),
    ("$SP$", "@"),
    ("$C$", ","),
    ("$u20$", " "),
    ("$u27$", "'"),
    ("$u5b$", "["),
    ("$u5d$", "]"),
    ("$u7b$", "{"),
    ("$u7d$", "}"),
    ("$u7e$", "~"),
];

/// Finishes demangling: decodes a still-mangled `_ZN..E` (switch tables
/// are named `.Lswitch.table.<mangled owner>`), the legacy escapes, `..`
/// as `::`, and drops the `::h<hash>` suffix.
pub fn demangle(name: &str) -> String {
    let name = name.strip_prefix(".Lswitch.table.").unwrap_or(name);
    let mut s = decode_zn(name).unwrap_or_else(|| name.to_string());
    if s.starts_with("_$") {
        s.remove(0);
    }
    s = s.replace("::_$", "::$");
    for (from, to) in ESCAPES {
        s = s.replace(from, to);
    }
    let s = s.replace("..", "::");
    strip_hash(&s).to_string()
}

/// Decodes `_ZN<len><ident>...E` (legacy mangling) into `a::b::c`.
fn decode_zn(name: &str) -> Option<String> {
    let mut rest = name.strip_prefix("_ZN")?;
    let mut parts = Vec::new();
    while !rest.starts_with('E') {
        let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
        let len: usize = rest[..digits].parse().ok()?;
        parts.push(rest.get(digits..digits + len)?);
        rest = &rest[digits + len..];
    }
    Some(parts.join("::"))
}

/// Drops LLVM's `.<n>` suffixes and a trailing `::h<16 hex digits>`.
fn strip_hash(mut s: &str) -> &str {
    while let Some((head, n)) = s.rsplit_once('.') {
        if n.is_empty() || !n.bytes().all(|b| b.is_ascii_digit()) {
            break;
        }
        s = head;
    }
    match s.rsplit_once("::h") {
        Some((head, hash)) if hash.len() == 16 && hash.bytes().all(|b| b.is_ascii_hexdigit()) => {
            head
        }
        _ => s,
    }
}

/// The paths a symbol is grouped by, in order: its own path; for a trait
/// impl `<A as B>::f`, the type `A` (references, pointers and slices
/// stripped) then the trait `B`; for an inherent `<A>::f`, `A`.
pub fn subject(name: &str) -> Vec<&str> {
    let Some(inner) = name.strip_prefix('<') else {
        return vec![name];
    };
    let close = matching_close(inner).unwrap_or(inner.len());
    let inner = &inner[..close];
    let (ty, tr) = match inner.split_once(" as ") {
        Some((ty, tr)) => (ty, Some(tr)),
        None => (inner, None),
    };
    let ty = ty.trim_start_matches(['&', '*', '[']);
    let ty = ["mut ", "const ", "dyn "]
        .iter()
        .fold(ty, |t, p| t.strip_prefix(p).unwrap_or(t));
    let mut out = vec![ty];
    out.extend(tr);
    out
}

/// Index of the `>` that closes an already-opened `<`.
fn matching_close(s: &str) -> Option<usize> {
    let mut depth = 1;
    for (i, c) in s.char_indices() {
        match c {
            '<' => depth += 1,
            '>' => depth -= 1,
            _ => {}
        }
        if depth == 0 {
            return Some(i);
        }
    }
    None
}

/// Whether a rule's pattern matches a path (see [`RULES`]).
fn matches(pattern: &str, path: &str) -> bool {
    match pattern.strip_suffix('*') {
        Some(prefix) => path.starts_with(prefix),
        None => path
            .strip_prefix(pattern)
            .is_some_and(|rest| rest.is_empty() || rest.starts_with("::")),
    }
}

/// The group of a demangled symbol name: the first rule matching any of
/// its [`subject`] paths, tried in order; [`UNATTRIBUTED`] for anonymous
/// constants; else [`OTHER`].
pub fn group_of(name: &str) -> &'static str {
    if name.starts_with(".Lanon") {
        return UNATTRIBUTED;
    }
    subject(name)
        .into_iter()
        .find_map(|path| {
            RULES
                .iter()
                .find(|(pattern, _)| matches(pattern, path))
                .map(|&(_, group)| group)
        })
        .unwrap_or(OTHER)
}

/// Flash per group, in report order ([`GROUPS`], [`OTHER`],
/// [`UNATTRIBUTED`]), summing to `flash`. The second value is the bytes of
/// anonymous constants inside [`UNATTRIBUTED`].
pub fn totals(symbols: &[Symbol], flash: u64) -> (Vec<(&'static str, u64)>, u64) {
    let mut rows: Vec<(&'static str, u64)> = GROUPS
        .iter()
        .chain(&[OTHER, UNATTRIBUTED])
        .map(|&g| (g, 0))
        .collect();
    for sym in symbols {
        let group = group_of(&sym.name);
        if let Some(row) = rows.iter_mut().find(|(g, _)| *g == group) {
            row.1 += sym.size;
        }
    }
    let anon = rows.last().map_or(0, |r| r.1);
    let named: u64 = rows.iter().map(|r| r.1).sum::<u64>() - anon;
    if let Some(last) = rows.last_mut() {
        last.1 = flash.saturating_sub(named);
    }
    (rows, anon)
}

/// Runs llvm-nm on an ELF and returns its flash symbols.
pub fn read_symbols(llvm_nm: &Path, elf: &Path) -> Result<Vec<Symbol>> {
    let cmd = command(
        &llvm_nm.to_string_lossy(),
        [
            "--print-size".as_ref(),
            "--size-sort".as_ref(),
            "--demangle".as_ref(),
            elf.as_os_str(),
        ],
    );
    Ok(parse_nm(&output(cmd)?))
}

/// Prints the groups of one board's ELF, and its largest symbols.
pub fn print_groups(board: &str, symbols: &[Symbol], flash: u64) {
    let (rows, anon) = totals(symbols, flash);
    println!();
    println!("flash per feature group, {board} (from llvm-nm; first rule wins):");
    for (group, bytes) in &rows {
        let share = 100.0 * *bytes as f64 / flash.max(1) as f64;
        let note = if *group == UNATTRIBUTED {
            format!(
                "  (.Lanon constants {}; unnamed rodata, SP word, padding {})",
                kib(anon),
                kib(bytes.saturating_sub(anon))
            )
        } else {
            String::new()
        };
        println!("  {group:<26} {:>10} {share:>5.1} %{note}", kib(*bytes));
    }
    println!("  {:<26} {:>10}", "total (= flash)", kib(flash));
    print_largest(symbols, 8);
}

/// Prints the `n` largest symbols with their groups.
fn print_largest(symbols: &[Symbol], n: usize) {
    let mut sorted: Vec<&Symbol> = symbols.iter().collect();
    sorted.sort_by_key(|s| std::cmp::Reverse(s.size));
    println!("  largest symbols:");
    for sym in sorted.into_iter().take(n) {
        let name: String = sym.name.chars().take(70).collect();
        println!(
            "    {:>10}  {:<26} {name}",
            kib(sym.size),
            group_of(&sym.name)
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Trimmed from a real release build of the default board.
    const NM: &str = "\
00000007 00000000 N __DEFMT_MARKER_DEBUG_END
00000009 00000001 N {\"package\":\"firmware\",\"tag\":\"defmt_info\",\"data\":\"identified: R {=f32} ohm\"}
08000000 00000000 R __vector_table
08000004 00000004 R __RESET_VECTOR
08000008 00000038 R __EXCEPTIONS
08000040 00000184 R __INTERRUPTS
20000000 00000006 d defmt_rtt::NAME::hd2ad5f68fca6e927
20000008 00000030 D _SEGGER_RTT
200016a4 00000400 b defmt_rtt::BUFFER::ha9ef7030d8564bbd
08000220 000014fe T ADC
08001720 00000584 T EXTI1
080001c8 00000000 T EXTI15_10
08023b94 00000006 r .Lswitch.table.ADC.531
08022950 0000000c r .Lswitch.table._ZN42_$LT$$RF$T$u20$as$u20$core..fmt..Debug$GT$3fmt17h23f2097ab015ea18E
08023c84 0000000c r .Lswitch.table._ZN70_$LT$foc_store..store..StoreError$u20$as$u20$defmt..traits..Format$GT$12_format_data17h4af1ce23db7bba23E
08022750 00000200 r .L.crctable
08022cc8 00000404 r .Lanon.f2189392ada71fadab2bfc9e77a47180.39
08010cd8 00007198 t foc_core::drive::lifecycle::Lifecycle::step::hb494d694d5634f39
08010000 00000100 t foc_core::drive::identify::Identify::step::h0123456789abcdef
080181b8 00002aac t foc_core::control::stage::CurrentStage::step::hbd2a44930e036408
08017f68 00000250 t foc_core::pi::Pi::step_error::h21d30e5ec0a2ac1e
08010274 000001b8 t foc_core::calibration::common::CircularMean::mean::ha949633ba61c63e7
0801b56c 00000a74 t _$LT$foc_protocol..message..Response$u20$as$u20$foc_protocol..message..Message$GT$::encode_body::h6f3310c9345243f4
0800c4dc 0000036a t firmware::comms::Link::save::h917d7dcd51e1cd36
0800cce0 00000bd8 t firmware::persist::admit::h5eda07cc548e6cf2
0801e058 000001e4 t _$LT$$RF$mut$u20$postcard..ser..serializer..Serializer$LT$F$GT$$u20$as$u20$serde_core..ser..SerializeStruct$GT$::serialize_field::h0be9d8e196b5b7d9
08006cb4 0000034c t sequential_storage::map::MapStorage$LT$K$C$S$C$C$GT$::migrate_items::_$u7b$$u7b$closure$u7d$$u7d$::ha4247627fd1c1656
0800dc5c 000001c6 t _$LT$board_support..hw..flash..StoreFlash$u20$as$u20$embedded_storage..nor_flash..NorFlash$GT$::write::h34334e720c444899
0801fb8e 000001f0 t stm32f4xx_hal::rcc::f4::pll::I2sPll::setup::h0b8acfce7f92c364
08008818 00002fcc t firmware::app::main::__rtic_init_resources::h807ab88fc15222ff
08000400 00000034 t firmware::app::idle::hbab78562dcedd1b6
08000500 0000003e T Reset
08020d90 00000308 t compiler_builtins::float::mul::__muldf3
08000600 0000000c t __aeabi_dmul
0800e608 00000200 t <core::fmt::Formatter>::pad_integral
0800de8c 00000630 t <&str as core::fmt::Display>::fmt
08000700 00000028 t __rustc::rust_begin_unwind
08000800 00000010 t mystery::thing::h0123456789abcdef
08000800 00000008 t mystery_alias
";

    #[test]
    fn parses_only_sized_flash_symbols() {
        let syms = parse_nm(NM);
        let names: Vec<&str> = syms.iter().map(|s| s.name.as_str()).collect();
        // Not flash: N (defmt), b (bss); no size: markers, EXTI15_10.
        assert!(!names
            .iter()
            .any(|n| n.contains("DEFMT") || n.contains("BUFFER")));
        assert!(!names.contains(&"EXTI15_10") && !names.contains(&"__vector_table"));
        // Initialised data counts (its initial values are in flash).
        assert!(names.contains(&"defmt_rtt::NAME") && names.contains(&"_SEGGER_RTT"));
        // Aliases at one address count once, the largest.
        assert!(names.contains(&"mystery::thing") && !names.contains(&"mystery_alias"));
        assert_eq!(syms.len(), 33);
        assert_eq!(parse_nm("garbage\n\n"), vec![]);
    }

    #[test]
    fn demangles_legacy_leftovers() {
        assert_eq!(
            demangle("_$LT$board_support..hw..flash..StoreFlash$u20$as$u20$embedded_storage..nor_flash..NorFlash$GT$::write::h34334e720c444899"),
            "<board_support::hw::flash::StoreFlash as embedded_storage::nor_flash::NorFlash>::write"
        );
        assert_eq!(
            demangle("sequential_storage::map::MapStorage$LT$K$C$S$C$C$GT$::migrate_items::_$u7b$$u7b$closure$u7d$$u7d$::ha4247627fd1c1656"),
            "sequential_storage::map::MapStorage<K,S,C>::migrate_items::{{closure}}"
        );
        assert_eq!(demangle(".Lswitch.table.ADC.531"), "ADC");
        assert_eq!(demangle(".L.crctable.470"), ".L.crctable");
        assert_eq!(demangle("EXTI1"), "EXTI1");
        assert_eq!(
            demangle(".Lswitch.table._ZN70_$LT$foc_store..store..StoreError$u20$as$u20$defmt..traits..Format$GT$12_format_data17h4af1ce23db7bba23E"),
            "<foc_store::store::StoreError as defmt::traits::Format>::_format_data"
        );
        assert_eq!(
            demangle("<core::fmt::Formatter>::pad_integral"),
            "<core::fmt::Formatter>::pad_integral"
        );
        assert_eq!(
            demangle("foc_core::pi::Pi::step::hzzzz"),
            "foc_core::pi::Pi::step::hzzzz"
        );
    }

    #[test]
    fn subjects_of_impls() {
        assert_eq!(
            subject("<&mut postcard::Serializer<F> as serde_core::ser::SerializeStruct>::f"),
            [
                "postcard::Serializer<F>",
                "serde_core::ser::SerializeStruct"
            ]
        );
        assert_eq!(
            subject("<&str as core::fmt::Display>::fmt"),
            ["str", "core::fmt::Display"]
        );
        assert_eq!(
            subject("<core::fmt::Formatter>::pad"),
            ["core::fmt::Formatter"]
        );
        assert_eq!(
            subject("foc_core::pi::Pi::step"),
            ["foc_core::pi::Pi::step"]
        );
    }

    #[test]
    fn groups_by_first_matching_rule() {
        let cases = [
            ("ADC", TASKS),
            ("EXTI15_10", OTHER), // size 0 (an alias of DefaultHandler): never counted
            ("firmware::app::main::__rtic_init_resources", TASKS),
            ("firmware::app::idle", "HAL"),
            ("foc_core::drive::identify::Identify::step", "calibration"),
            ("foc_core::drive::lifecycle::Lifecycle::step", "control"),
            ("foc_core::pi::Pi::step_error", "control"),
            ("foc_core::pidgin::x", "control"),
            ("firmware::comms::Link::save", "protocol"),
            ("firmware::persist::admit", "storage"),
            ("<[u8] as sequential_storage::Value>::serialize_into", "storage"),
            ("<&T as core::fmt::Debug>::fmt", "runtime"),
            ("<board_support::hw::flash::StoreFlash as embedded_storage::nor_flash::NorFlash>::write", "HAL"),
            (".L.crctable", "storage"),
            (".Lanon.f2189392ada71fadab2bfc9e77a47180.39", UNATTRIBUTED),
            (&demangle(".Lanon.1234.5"), UNATTRIBUTED),
            ("crcx::f", OTHER),
            ("mystery::thing", OTHER),
            ("OUTLINED_FUNCTION_12", OTHER),
            ("<i64>::rem_euclid", "runtime"),
            ("embassy_futures::block_on::block_on", "storage"),
        ];
        for (name, group) in cases {
            assert_eq!(group_of(name), group, "{name}");
        }
    }

    #[test]
    fn totals_sum_to_flash() {
        let syms = parse_nm(NM);
        let named: u64 = syms.iter().map(|s| s.size).sum::<u64>() - 0x404;
        let flash = named + 0x404 + 100;
        let (rows, anon) = totals(&syms, flash);
        assert_eq!(rows.iter().map(|r| r.1).sum::<u64>(), flash);
        assert_eq!(anon, 0x404);
        let get = |g: &str| rows.iter().find(|r| r.0 == g).unwrap().1;
        assert_eq!(get(UNATTRIBUTED), 0x404 + 100);
        assert_eq!(get(TASKS), 0x14fe + 0x584 + 6 + 0x2fcc);
        assert_eq!(get("calibration"), 0x100 + 0x1b8);
        assert_eq!(get("protocol"), 0xa74 + 0x36a);
        assert_eq!(get(OTHER), 0x10);
        print_groups("test", &syms, flash);
    }
}
