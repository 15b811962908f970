//! `foc-canbus`: the host CAN test bus (see the library's docs).
//!
//! Prints `listening 127.0.0.1:PORT` once ready, then reads control
//! lines on stdin (`fault <id> <kind>`, `bus-off <id> <ms>`,
//! `reset <id>`, `time`, `nodes`, `quit`) and answers each with one line
//! `ok ...` / `err ...`. End of stdin leaves it serving (stop it with
//! `quit` or a signal).

use clap::{Parser, ValueEnum};
use foc_canbus::{start, NodeKind, Options};
use std::io::{BufRead, Write};

#[derive(Clone, Copy, Debug, ValueEnum)]
enum Node {
    /// The real drive (foc-core + plant) under the CANopen node (CiA 301 +
    /// CiA 402).
    Canopen,
    /// The real drive under a minimal stand-in protocol (bus tests).
    Drive,
    /// The fake node (no drive).
    Fake,
}

/// Host CAN test bus: simulated drives and SLCAN-over-TCP clients on one
/// virtual bus, in simulated time (each SYNC advances it by the cycle).
#[derive(Parser, Debug)]
#[command(name = "foc-canbus", version)]
struct Args {
    /// Number of hosted drives.
    #[arg(long, default_value_t = 3)]
    nodes: u8,
    /// Node ID of the first drive; the others follow.
    #[arg(long, default_value_t = 1)]
    first_id: u8,
    /// TCP port on 127.0.0.1 (0: any free one).
    #[arg(long, default_value_t = 0)]
    port: u16,
    /// Communication cycle period a SYNC advances the bus by \[us\].
    #[arg(long, default_value_t = 1000)]
    cycle_us: u32,
    /// The hosted node.
    #[arg(long, value_enum, default_value_t = Node::Canopen)]
    node: Node,
    /// Connect out to an SLCAN TCP endpoint (tcp:HOST:PORT) and make it a
    /// participant (repeatable).
    #[arg(long)]
    relay: Vec<String>,
}

fn main() -> std::process::ExitCode {
    let a = Args::parse();
    let o = Options {
        nodes: a.nodes,
        first_id: a.first_id,
        node: match a.node {
            Node::Canopen => NodeKind::Canopen,
            Node::Drive => NodeKind::Drive,
            Node::Fake => NodeKind::Fake,
        },
        cycle_us: a.cycle_us,
        port: a.port,
        relays: a.relay,
    };
    let server = match start(&o) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("foc-canbus: {e}");
            return std::process::ExitCode::FAILURE;
        }
    };
    let mut stdout = std::io::stdout();
    let _ = writeln!(stdout, "listening {}", server.addr());
    let _ = stdout.flush();
    for line in std::io::stdin().lock().lines() {
        let Ok(line) = line else { break };
        if line.trim().is_empty() {
            continue;
        }
        let answer = server.control(&line);
        let _ = writeln!(stdout, "{answer}");
        let _ = stdout.flush();
        if line.trim() == "quit" || server.stopped() {
            server.shutdown();
            return std::process::ExitCode::SUCCESS;
        }
    }
    // Stdin closed: keep serving until killed.
    loop {
        std::thread::park();
    }
}
