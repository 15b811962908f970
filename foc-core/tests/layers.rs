//! The crate's layers (see the crate docs, "Layers"): no module may name a
//! module of a layer above its own. Read from the source, so it fails the
//! moment an import (a `use`, a path in code) goes upwards; comments and
//! doc examples are not code and are skipped.
//!
//! Same-layer references are allowed; a cycle inside one layer is the
//! layer's own business (the layers are what a reader learns in order).
//! Unit-test modules (`#[cfg(test)] mod ... { }`) are skipped: a test may
//! build its fixture from a higher layer (the stage's tests take the
//! cascade's default configuration); they are not in the product's build.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Bottom to top. Every top-level module of `lib.rs` must be listed.
const LAYERS: &[(&str, &[&str])] = &[
    (
        "math",
        &[
            "math",
            "frames",
            "angle",
            "trig",
            "transforms",
            "svpwm",
            "pi",
            "tuning",
        ],
    ),
    ("hal", &["hal"]),
    ("control", &["control"]),
    ("calibration", &["calibration"]),
    ("drive", &["drive", "scope", "response"]),
];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|(_, mods)| mods.contains(&module))
}

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The source without comments (line, doc and block comments) and string
/// literals' contents (so `"crate::x"` in a message is not a reference).
fn code_only(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = String::with_capacity(s.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
            i += 2;
            while i + 1 < b.len() && !(b[i] == b'*' && b[i + 1] == b'/') {
                i += 1;
            }
            i += 2;
        } else if b[i] == b'"' {
            out.push('"');
            i += 1;
            while i < b.len() && b[i] != b'"' {
                if b[i] == b'\\' {
                    i += 1;
                }
                i += 1;
            }
            out.push('"');
            i += 1;
        } else {
            out.push(b[i] as char);
            i += 1;
        }
    }
    out
}

/// The code without its `#[cfg(test)]` modules.
fn without_test_modules(code: &str) -> String {
    let mut out = String::with_capacity(code.len());
    let mut rest = code;
    while let Some(k) = rest.find("#[cfg(test)]") {
        out.push_str(&rest[..k]);
        let after = &rest[k + "#[cfg(test)]".len()..];
        let item = after.trim_start();
        if !item.starts_with("mod ") {
            // A `#[cfg(test)]` item that is not a module: keep it.
            out.push_str("#[cfg(test)]");
            rest = after;
            continue;
        }
        let Some(open) = after.find('{') else {
            rest = "";
            break;
        };
        let mut depth = 0;
        let mut end = after.len();
        for (i, c) in after[open..].char_indices() {
            match c {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        end = open + i + 1;
                        break;
                    }
                }
                _ => {}
            }
        }
        rest = &after[end..];
    }
    out.push_str(rest);
    out
}

/// The top-level module a file belongs to (`None` for `lib.rs`), and
/// whether the file is that module's root (where `super` is the crate).
fn owner(path: &Path) -> (Option<String>, bool) {
    let rel = path.strip_prefix(src()).unwrap();
    let parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    if parts == ["lib.rs"] {
        return (None, true);
    }
    let first = parts[0].trim_end_matches(".rs").to_string();
    let is_root = parts.len() == 1 || (parts.len() == 2 && parts[1] == "mod.rs");
    (Some(first), is_root)
}

fn ident_at(s: &str) -> String {
    s.chars()
        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
        .collect()
}

/// The first path segment of every item in a `{...}` group at `s[0] == '{'`.
fn group_heads(s: &str) -> Vec<String> {
    let mut heads = Vec::new();
    let mut depth = 0;
    let mut start = true;
    for (i, c) in s.char_indices() {
        match c {
            '{' => {
                depth += 1;
                if depth == 1 {
                    start = true;
                    continue;
                }
            }
            '}' => {
                depth -= 1;
                if depth == 0 {
                    break;
                }
            }
            ',' if depth == 1 => {
                start = true;
                continue;
            }
            _ => {}
        }
        if depth == 1 && start && !c.is_whitespace() {
            heads.push(ident_at(&s[i..]));
            start = false;
        }
    }
    heads
}

/// Top-level names referred to through `prefix` (`crate::` or `super::`).
fn referenced(code: &str, prefix: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut from = 0;
    while let Some(k) = code[from..].find(prefix) {
        let at = from + k;
        from = at + prefix.len();
        // `super::super::` is handled by the caller's prefix; a preceding
        // identifier character means this is not the path's start.
        let before = code[..at].chars().next_back();
        if before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_') {
            continue;
        }
        if prefix == "super::" && code[..at].ends_with("super::") {
            continue;
        }
        let rest = &code[from..];
        if rest.starts_with('{') {
            names.extend(group_heads(rest));
        } else {
            names.push(ident_at(rest));
        }
    }
    names
}

/// Names `lib.rs` re-exports from the math layer at the crate root.
fn root_reexports(lib: &str) -> Vec<String> {
    let mut names = Vec::new();
    for line in lib.lines() {
        let l = line.trim();
        if let Some(rest) = l
            .strip_prefix("pub use math::")
            .or_else(|| l.strip_prefix("pub(crate) use math::"))
        {
            if rest.starts_with('{') {
                names.extend(group_heads(rest));
            } else {
                names.push(ident_at(rest));
            }
        }
    }
    names
}

#[test]
fn every_module_has_a_layer() {
    let lib = std::fs::read_to_string(src().join("lib.rs")).unwrap();
    let mut missing = Vec::new();
    for line in lib.lines() {
        if let Some(m) = line.trim().strip_prefix("pub mod ") {
            let m = m.trim_end_matches(';');
            if layer_of(m).is_none() {
                missing.push(m.to_string());
            }
        }
    }
    assert!(missing.is_empty(), "modules without a layer: {missing:?}");
}

#[test]
fn no_module_imports_a_layer_above_its_own() {
    let lib = std::fs::read_to_string(src().join("lib.rs")).unwrap();
    let math_root = root_reexports(&lib);
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    files.sort();
    let mut violations: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let mut checked = 0;
    for f in &files {
        let (Some(me), is_root) = owner(f) else {
            continue;
        };
        let my_layer = layer_of(&me).unwrap_or_else(|| panic!("{me} has no layer"));
        let code = without_test_modules(&code_only(&std::fs::read_to_string(f).unwrap()));
        let mut targets = referenced(&code, "crate::");
        if is_root {
            // In a top-level module's root file `super` is the crate.
            targets.extend(referenced(&code, "super::"));
        }
        for t in targets {
            let layer = if math_root.contains(&t) {
                layer_of("math")
            } else {
                layer_of(&t)
            };
            checked += 1;
            if let Some(l) = layer {
                if l > my_layer {
                    violations
                        .entry(f.strip_prefix(src()).unwrap().display().to_string())
                        .or_default()
                        .push(format!(
                            "{t} ({} above {})",
                            LAYERS[l].0, LAYERS[my_layer].0
                        ));
                }
            }
        }
    }
    assert!(
        checked > 100,
        "only {checked} references read: the parser is broken"
    );
    assert!(
        violations.is_empty(),
        "imports from a layer above (layers bottom to top: {:?}):\n{violations:#?}",
        LAYERS.iter().map(|l| l.0).collect::<Vec<_>>()
    );
}

/// The checker itself: an upward reference in code is found, one in a
/// comment or a string is not.
#[test]
fn the_checker_sees_code_not_comments() {
    let code = code_only(
        "// crate::drive::x\n/* crate::drive */ let s = \"crate::drive\"; use crate::{control::a, drive::{b, c}};",
    );
    assert_eq!(referenced(&code, "crate::"), ["control", "drive"]);
    assert_eq!(group_heads("{ a::b, c, d::{e, f} }"), ["a", "c", "d"]);
    let t = without_test_modules("use crate::control::x;\n#[cfg(test)]\nmod tests { fn f() { crate::drive::y(); } }\nuse crate::hal;");
    assert_eq!(referenced(&t, "crate::"), ["control", "hal"]);
}
