//! A minimal SLCAN client over TCP for the tests (no Python).
#![allow(dead_code)]

use foc_canopen::slcan::{encode, Decoder, Event};
use foc_canopen::CanFrame;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

/// What the server sent, in order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Rx {
    /// A frame.
    Frame(CanFrame),
    /// A `\r` (ok).
    Ok,
    /// A BEL (error).
    Bell,
    /// Any other line (a version answer, ...).
    Other,
}

pub struct Client {
    pub stream: TcpStream,
    dec: Decoder,
    line_len: usize,
    /// Everything received so far.
    pub rx: Vec<Rx>,
}

impl Client {
    pub fn connect(addr: SocketAddr) -> Self {
        Self::from_stream(TcpStream::connect(addr).unwrap())
    }

    /// Over an accepted connection (a relay's end).
    pub fn from_stream(stream: TcpStream) -> Self {
        stream.set_nodelay(true).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_millis(20)))
            .unwrap();
        Self {
            stream,
            dec: Decoder::new(),
            line_len: 0,
            rx: Vec::new(),
        }
    }

    /// Connect and open the channel as python-can does (`C`, `S8`, an
    /// empty data bit rate, `O`).
    pub fn open(addr: SocketAddr) -> Self {
        let mut c = Self::connect(addr);
        c.raw(b"C\rS8\r\rO\r");
        c
    }

    pub fn raw(&mut self, bytes: &[u8]) {
        self.stream.write_all(bytes).unwrap();
    }

    pub fn send(&mut self, f: CanFrame) {
        let mut line = [0u8; 27];
        let n = encode(&f, &mut line);
        self.raw(&line[..n]);
    }

    pub fn frame(&mut self, id: u16, data: &[u8]) {
        self.send(CanFrame::new(id, data).unwrap());
    }

    /// Read what is there (waits up to 20 ms).
    pub fn poll(&mut self) {
        let mut buf = [0u8; 4096];
        if let Ok(n) = self.stream.read(&mut buf) {
            for &b in &buf[..n] {
                self.byte(b);
            }
        }
    }

    fn byte(&mut self, b: u8) {
        if b == 0x07 {
            self.dec.reset();
            self.line_len = 0;
            self.rx.push(Rx::Bell);
            return;
        }
        let empty = b == b'\r' && self.line_len == 0;
        self.line_len = if b == b'\r' { 0 } else { self.line_len + 1 };
        match self.dec.push(b) {
            Some(Event::Frame(f)) => self.rx.push(Rx::Frame(f)),
            Some(_) => self.rx.push(Rx::Other),
            None if empty => self.rx.push(Rx::Ok),
            None => {}
        }
    }

    /// Frames received so far.
    pub fn frames(&self) -> Vec<CanFrame> {
        self.rx
            .iter()
            .filter_map(|r| match r {
                Rx::Frame(f) => Some(*f),
                _ => None,
            })
            .collect()
    }

    /// Read until `done(received)` holds (panics after 20 s).
    pub fn wait_until(&mut self, mut done: impl FnMut(&[Rx]) -> bool) {
        let t0 = Instant::now();
        while !done(&self.rx) {
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "timed out; got {:?}",
                self.rx
            );
            self.poll();
        }
    }

    /// Read until a frame with this id arrives; everything received.
    pub fn wait_for_id(&mut self, id: u16) -> CanFrame {
        self.wait_until(|rx| rx.iter().any(|r| matches!(r, Rx::Frame(f) if f.id == id)));
        self.frames()
            .into_iter()
            .rev()
            .find(|f| f.id == id)
            .unwrap()
    }

    /// Read until `n` frames with this id arrived in total.
    pub fn wait_count(&mut self, id: u16, n: usize) {
        self.wait_until(|rx| {
            rx.iter()
                .filter(|r| matches!(r, Rx::Frame(f) if f.id == id))
                .count()
                >= n
        });
    }

    /// Read for `ms` more (to see that nothing else arrives).
    pub fn settle(&mut self, ms: u64) {
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_millis(ms) {
            self.poll();
        }
    }
}

pub fn f(id: u16, d: &[u8]) -> CanFrame {
    CanFrame::new(id, d).unwrap()
}
