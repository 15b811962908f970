//! The bus on TCP: SLCAN clients, relays and the control channel.
//!
//! One thread owns the [`Bus`]; every connection has a reader thread that
//! hands its bytes over (a channel), so the bus handles one inbound chunk
//! at a time, in arrival order, and writes what it produces to the
//! connections before it takes the next. Per connection an SLCAN
//! [`Decoder`] turns bytes into events:
//!
//! - a frame (`t`/`r`) from a client whose channel is open goes on the bus
//!   ([`Bus::send`]); from a closed or listen-only channel it is refused
//!   with BEL (as an adapter refuses to transmit then); a 29-bit frame is
//!   ignored;
//! - `O` / `L` (listen-only) open the channel (the first client to open gets the frames
//!   the bus kept since boot: see [`crate::bus`]), `C` closes it; the
//!   answer is `\r`; `V` answers [`VERSION`], `v` [`VERSION`] too, `N`
//!   [`SERIAL`], `F` `F00`; every other command `\r` (bit rates,
//!   timestamps, filters are accepted and have no effect: the bus has no
//!   bit timing);
//! - a malformed line is answered with BEL and otherwise ignored; an
//!   empty line (python-can sends one for "no data bit rate") gets no
//!   answer;
//! - a client that disconnects (or cannot be written to for
//!   [`WRITE_TIMEOUT`]) is detached; nothing else changes.
//!
//! A relay ([`Server::spawn`]'s `relays`, e.g. QEMU's UART chardev
//! server) is a participant whose channel is always open: frames both
//! ways as SLCAN lines, no command answers.

use crate::bus::{Bus, Origin, PortId, PortKind};
use foc_canopen::slcan::{encode, encode_reply, Cmd, Decoder, Event, ERROR, OK};
use std::collections::BTreeMap;
use std::io::{self, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Hardware and software version answered to `V` / `v`.
pub const VERSION: (u8, u8) = (1, 0);
/// Serial number answered to `N`.
pub const SERIAL: &[u8; 4] = b"FOCB";
/// A client that does not take its bytes for this long is detached.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a relay is tried before giving up.
pub const RELAY_CONNECT_TIMEOUT: Duration = Duration::from_secs(30);

enum Msg {
    Connected {
        id: PortId,
        stream: TcpStream,
        kind: PortKind,
    },
    Bytes {
        id: PortId,
        data: Vec<u8>,
    },
    Closed {
        id: PortId,
    },
    Control {
        line: String,
        reply: Sender<String>,
    },
}

struct Conn {
    stream: TcpStream,
    decoder: Decoder,
    kind: PortKind,
    /// Opened with `L`: receives, may not send.
    listen_only: bool,
    /// Bytes to write once the current message is handled.
    pending: Vec<u8>,
}

/// The running server (see the module docs).
pub struct Server {
    addr: SocketAddr,
    tx: Sender<Msg>,
    stop: Arc<AtomicBool>,
    bus_thread: Option<JoinHandle<()>>,
}

impl Server {
    /// Serve `bus` (booted here, at time 0) on `listener`, and connect out
    /// to every relay address (`HOST:PORT`, retried for
    /// [`RELAY_CONNECT_TIMEOUT`]).
    pub fn spawn(mut bus: Bus, listener: TcpListener, relays: &[String]) -> io::Result<Self> {
        let addr = listener.local_addr()?;
        listener.set_nonblocking(true)?;
        let (tx, rx) = channel();
        let stop = Arc::new(AtomicBool::new(false));
        bus.boot();
        let next_id = Arc::new(std::sync::atomic::AtomicU32::new(1));
        for r in relays {
            let (tx, stop, r) = (tx.clone(), stop.clone(), r.clone());
            let id = next_id.fetch_add(1, Ordering::Relaxed);
            std::thread::spawn(move || {
                if let Some(stream) = connect_relay(&r, &stop) {
                    attach(id, stream, PortKind::Relay, &tx);
                } else {
                    eprintln!("foc-canbus: relay {r}: no connection");
                }
            });
        }
        {
            let (tx, stop) = (tx.clone(), stop.clone());
            std::thread::spawn(move || accept_loop(listener, tx, stop, next_id));
        }
        let stop2 = stop.clone();
        let bus_thread = std::thread::spawn(move || bus_loop(bus, rx, stop2));
        Ok(Self {
            addr,
            tx,
            stop,
            bus_thread: Some(bus_thread),
        })
    }

    /// The listening address.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Run one control line ([`crate::control`]): the answer line. `quit`
    /// stops the bus (answered `ok quit`).
    pub fn control(&self, line: &str) -> String {
        let (reply, answer) = channel();
        let msg = Msg::Control {
            line: line.to_string(),
            reply,
        };
        if self.tx.send(msg).is_err() {
            return "err bus stopped".into();
        }
        answer.recv().unwrap_or_else(|_| "err bus stopped".into())
    }

    /// True once the bus stopped (`quit`).
    pub fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// Stop the bus, close every connection, wait for the bus thread.
    pub fn shutdown(mut self) {
        self.stop_now();
    }

    fn stop_now(&mut self) {
        if !self.stopped() {
            let _ = self.control("quit");
        }
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.bus_thread.take() {
            let _ = h.join();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop_now();
    }
}

fn connect_relay(addr: &str, stop: &AtomicBool) -> Option<TcpStream> {
    let t0 = Instant::now();
    while t0.elapsed() < RELAY_CONNECT_TIMEOUT && !stop.load(Ordering::Relaxed) {
        let addrs = addr.to_socket_addrs().ok()?;
        for a in addrs {
            if let Ok(s) = TcpStream::connect_timeout(&a, Duration::from_millis(500)) {
                return Some(s);
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    None
}

/// Hand a connection to the bus and start its reader.
fn attach(id: PortId, stream: TcpStream, kind: PortKind, tx: &Sender<Msg>) {
    let _ = stream.set_nodelay(true);
    let _ = stream.set_write_timeout(Some(WRITE_TIMEOUT));
    let Ok(mut reader) = stream.try_clone() else {
        return;
    };
    if tx.send(Msg::Connected { id, stream, kind }).is_err() {
        return;
    }
    let tx = tx.clone();
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        loop {
            match reader.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    let data = buf.get(..n).unwrap_or(&[]).to_vec();
                    if tx.send(Msg::Bytes { id, data }).is_err() {
                        return;
                    }
                }
            }
        }
        let _ = tx.send(Msg::Closed { id });
    });
}

fn accept_loop(
    listener: TcpListener,
    tx: Sender<Msg>,
    stop: Arc<AtomicBool>,
    next_id: Arc<std::sync::atomic::AtomicU32>,
) {
    while !stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((stream, _)) => {
                if stream.set_nonblocking(false).is_ok() {
                    let id = next_id.fetch_add(1, Ordering::Relaxed);
                    attach(id, stream, PortKind::Client, &tx);
                }
            }
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(50)),
        }
    }
}

fn bus_loop(mut bus: Bus, rx: Receiver<Msg>, stop: Arc<AtomicBool>) {
    let mut conns: BTreeMap<PortId, Conn> = BTreeMap::new();
    while let Ok(msg) = rx.recv() {
        match msg {
            Msg::Connected { id, stream, kind } => {
                bus.add_port(id, kind);
                conns.insert(
                    id,
                    Conn {
                        stream,
                        decoder: Decoder::new(),
                        kind,
                        listen_only: false,
                        pending: Vec::new(),
                    },
                );
            }
            Msg::Bytes { id, data } => {
                for b in data {
                    let Some(c) = conns.get_mut(&id) else { break };
                    let Some(ev) = c.decoder.push(b) else {
                        continue;
                    };
                    handle_event(&mut bus, &mut conns, id, ev);
                    route(&mut bus, &mut conns);
                }
            }
            Msg::Closed { id } => {
                bus.remove_port(id);
                conns.remove(&id);
            }
            Msg::Control { line, reply } => {
                if line.trim() == "quit" {
                    let _ = reply.send("ok quit".into());
                    break;
                }
                let answer = bus.control(&line);
                route(&mut bus, &mut conns);
                flush(&mut bus, &mut conns);
                let _ = reply.send(answer);
            }
        }
        flush(&mut bus, &mut conns);
    }
    stop.store(true, Ordering::Relaxed);
    for c in conns.values() {
        let _ = c.stream.shutdown(Shutdown::Both);
    }
}

/// One decoded event of connection `id`.
fn handle_event(bus: &mut Bus, conns: &mut BTreeMap<PortId, Conn>, id: PortId, ev: Event) {
    let Some((kind, listen_only)) = conns.get(&id).map(|c| (c.kind, c.listen_only)) else {
        return;
    };
    let reply: &[u8] = match (kind, ev) {
        (_, Event::Frame(f)) => {
            if bus.port_open(id) && !listen_only {
                bus.send(Origin::Port(id), f);
                &[]
            } else {
                &[ERROR]
            }
        }
        (_, Event::Extended) => &[],
        (PortKind::Relay, _) => &[],
        (PortKind::Client, Event::Error) => &[ERROR],
        (PortKind::Client, Event::Command(cmd)) => {
            match cmd {
                Cmd::Open | Cmd::ListenOnly => bus.open_port(id),
                Cmd::Close => bus.close_port(id),
                _ => {}
            }
            let mut line = [0u8; 8];
            let n = encode_reply(cmd, VERSION, SERIAL, 0, &mut line);
            if let Some(c) = conns.get_mut(&id) {
                match cmd {
                    Cmd::Open | Cmd::Close => c.listen_only = false,
                    Cmd::ListenOnly => c.listen_only = true,
                    _ => {}
                }
                c.pending.extend_from_slice(line.get(..n).unwrap_or(&[OK]));
            }
            &[]
        }
    };
    if let Some(c) = conns.get_mut(&id) {
        c.pending.extend_from_slice(reply);
    }
}

/// The bus's frames for the ports, into their pending bytes.
fn route(bus: &mut Bus, conns: &mut BTreeMap<PortId, Conn>) {
    for (port, frame) in bus.take_outbox() {
        if let Some(c) = conns.get_mut(&port) {
            let mut line = [0u8; 27];
            let n = encode(&frame, &mut line);
            c.pending.extend_from_slice(line.get(..n).unwrap_or(&[]));
        }
    }
}

/// Write every connection's pending bytes; detach the ones that fail.
fn flush(bus: &mut Bus, conns: &mut BTreeMap<PortId, Conn>) {
    route(bus, conns);
    let mut dead = Vec::new();
    for (id, c) in conns.iter_mut() {
        if c.pending.is_empty() {
            continue;
        }
        let bytes = std::mem::take(&mut c.pending);
        if c.stream.write_all(&bytes).is_err() {
            dead.push(*id);
        }
    }
    for id in dead {
        if let Some(c) = conns.remove(&id) {
            let _ = c.stream.shutdown(Shutdown::Both);
        }
        bus.remove_port(id);
    }
}
