//! What each fault means and what to do about it, for the dashboard: the
//! book's two tables (`docs/src/tables/faults.md`: when it trips;
//! `docs/src/guide/faults.md`: what to do), built into the binary, so the
//! page and the book say the same.

use foc_core::control::Fault;
use serde_json::{json, Value};

const TRIPS: &str = include_str!("../../../docs/src/tables/faults.md");
const GUIDE: &str = include_str!("../../../docs/src/guide/faults.md");

/// The cells of a table row (`| a | b |` -> `["a", "b"]`).
fn cells(line: &str) -> Vec<String> {
    let inner = line.trim().trim_start_matches('|').trim_end_matches('|');
    // `\|` inside a cell is a literal bar.
    inner
        .replace("\\|", "\u{1}")
        .split('|')
        .map(|c| c.trim().replace('\u{1}', "|"))
        .collect()
}

/// The cell `col` of the row whose first cell lists `code` (`"1, 2"`
/// lists 1 and 2).
fn lookup(table: &str, code: u8, col: usize) -> Option<String> {
    table
        .lines()
        .filter(|l| l.trim_start().starts_with('|'))
        .map(cells)
        .find(|c| {
            c.first().is_some_and(|first| {
                first
                    .split(',')
                    .any(|n| n.trim().parse::<u8>().ok() == Some(code))
            })
        })
        .and_then(|c| c.get(col).cloned())
}

/// When fault `code` trips, in the book's words.
pub(super) fn trips_when(code: u8) -> Option<String> {
    lookup(TRIPS, code, 2)
}

/// What to do about fault `code`, in the book's words.
pub(super) fn what_to_do(code: u8) -> Option<String> {
    let start = GUIDE.find("## What to do")?;
    lookup(GUIDE.get(start..)?, code, 2)
}

/// The latched set `bits` and the first fault as JSON: each fault's name,
/// code, when it trips and what to do.
pub(super) fn fault_json(bits: u32, first_code: u8) -> Value {
    let list: Vec<Value> = Fault::ALL
        .iter()
        .filter(|f| bits & (1 << f.code()) != 0)
        .map(|f| {
            json!({
                "code": f.code(),
                "name": f.name(),
                "trips_when": trips_when(f.code()),
                "what_to_do": what_to_do(f.code()),
            })
        })
        .collect();
    json!({"latched": list, "first": first_code})
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_fault_has_its_meaning_and_what_to_do() {
        for f in Fault::ALL {
            let c = f.code();
            assert!(
                trips_when(c).is_some_and(|t| !t.is_empty()),
                "{f:?}: no `trips when`"
            );
            assert!(
                what_to_do(c).is_some_and(|t| t.len() > 20),
                "{f:?}: no `what to do`"
            );
        }
        assert!(trips_when(2).unwrap().contains("|i_alpha_beta|"));
        assert!(what_to_do(3).unwrap().contains("brake resistor"));
    }
}
