//! The control channel (for tests): one line in, one line out.
//!
//! | line | effect | answer |
//! |---|---|---|
//! | `fault <node-id> <kind>` | inject a drive fault through its plant or sensors ([`crate::bus::BusNode::inject_fault`]; kinds of the real drive: [`foc_simdrive::FaultKind`]) | `ok <what>` |
//! | `bus-off <node-id> <ms>` | that node's controller goes bus-off for `ms` of bus time ([`crate::bus::Bus::bus_off`]) | `ok bus-off <id> until <us>` |
//! | `reset <node-id>` | power-cycle that drive (its flash kept) and boot it | `ok reset <id>` |
//! | `time` | - | `ok <bus time us>` |
//! | `nodes` | - | `ok <id> <id> ...` |
//! | `quit` | stop the server (the binary exits) | `ok quit` |
//!
//! Anything else, or a bad argument, answers `err <why>` and changes
//! nothing.

use crate::bus::Bus;

fn node_id(s: Option<&str>) -> Result<u8, String> {
    let s = s.ok_or("missing node id")?;
    s.parse::<u8>()
        .ok()
        .filter(|id| (1..=127).contains(id))
        .ok_or_else(|| format!("bad node id {s:?}"))
}

/// Run one control line on `bus`: the text after `ok `, or the error.
pub fn run(bus: &mut Bus, line: &str) -> Result<String, String> {
    let words: Vec<&str> = line.split_whitespace().collect();
    let args = |n: usize| {
        if words.len() == n + 1 {
            Ok(())
        } else {
            Err(format!(
                "{} takes {n} argument(s)",
                words.first().unwrap_or(&"")
            ))
        }
    };
    let word = |i: usize| words.get(i).copied();
    match word(0).unwrap_or("") {
        "fault" => {
            args(2)?;
            let id = node_id(word(1))?;
            let kind = word(2).ok_or("missing fault kind")?;
            let node = bus.node_mut(id).ok_or_else(|| format!("no node {id}"))?;
            node.inject_fault(kind)
        }
        "bus-off" => {
            args(2)?;
            let id = node_id(word(1))?;
            let ms_s = word(2).ok_or("missing ms")?;
            let ms = ms_s
                .parse::<u64>()
                .map_err(|_| format!("bad ms {ms_s:?}"))?;
            bus.bus_off(id, ms)?;
            let until = bus.now_us().saturating_add(ms.saturating_mul(1000));
            Ok(format!("bus-off {id} until {until}"))
        }
        "reset" => {
            args(1)?;
            let id = node_id(word(1))?;
            bus.reset(id)?;
            Ok(format!("reset {id}"))
        }
        "time" => args(0).map(|()| bus.now_us().to_string()),
        "nodes" => args(0).map(|()| {
            bus.node_ids()
                .iter()
                .map(u8::to_string)
                .collect::<Vec<_>>()
                .join(" ")
        }),
        "quit" => args(0).map(|()| "quit".into()),
        "" => Err("empty line".into()),
        other => Err(format!("unknown command {other:?}")),
    }
}
