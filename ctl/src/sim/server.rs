//! [`SimServer`]: a [`SimDevice`] served on TCP, in real time (or a
//! chosen multiple of it), to any number of clients at once.

use super::SimDevice;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// The longest stretch of simulated time one pass runs \[s\]: a machine
/// slower than the requested pace slows the simulation down instead of
/// leaving the clients unanswered.
const MAX_STEP_S: f64 = 0.02;

/// Turns real time into whole PWM periods at `scale` simulated seconds
/// per real second.
#[derive(Debug)]
struct Clock {
    last: Instant,
    carry: f64,
    periods_per_s: f64,
}

impl Clock {
    fn new(pwm_hz: u32, scale: f64) -> Self {
        Self {
            last: Instant::now(),
            carry: 0.0,
            periods_per_s: f64::from(pwm_hz) * scale,
        }
    }

    /// Whole periods due since the last call (fractions carried over, at
    /// most [`MAX_STEP_S`] of simulated time).
    fn periods(&mut self) -> u32 {
        let now = Instant::now();
        self.carry += now.duration_since(self.last).as_secs_f64() * self.periods_per_s;
        self.last = now;
        let cap = (MAX_STEP_S * self.periods_per_s).max(1.0);
        if self.carry > cap {
            self.carry = cap;
        }
        // Periods lent to a request are paid back before any are due.
        if self.carry < 1.0 {
            return 0;
        }
        let n = self.carry.floor();
        self.carry -= n;
        n as u32
    }

    /// As [`Self::periods`], at least `min` (the extra ones borrowed from
    /// the next calls).
    fn periods_at_least(&mut self, min: u32) -> u32 {
        let n = self.periods();
        if n >= min {
            return n;
        }
        self.carry -= f64::from(min - n);
        min
    }
}

/// A client's connection and its session.
struct Conn {
    stream: TcpStream,
    id: u64,
}

impl Conn {
    /// Read what the client sent into its session; `false` when the
    /// client left.
    fn read(&mut self, dev: &mut SimDevice, received: &mut bool) -> bool {
        let mut buf = [0u8; 1024];
        loop {
            match self.stream.read(&mut buf) {
                Ok(0) => return false,
                Ok(n) => {
                    *received = true;
                    dev.receive(self.id, buf.get(..n).unwrap_or_default());
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return true,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(_) => return false,
            }
        }
    }

    /// Send what the client takes now, keep the rest for later (without
    /// blocking: a client that stops reading loses its streamed samples,
    /// past the session's backlog, not the other clients' time); `false`
    /// when it left.
    fn write(&mut self, dev: &mut SimDevice) -> bool {
        let out = dev.take_output(self.id);
        let mut sent = 0;
        while sent < out.len() {
            match self.stream.write(out.get(sent..).unwrap_or_default()) {
                Ok(0) => return false,
                Ok(n) => sent += n,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(_) => return false,
            }
        }
        if sent < out.len() {
            dev.unsend(self.id, out.get(sent..).unwrap_or_default());
        }
        true
    }
}

/// A simulated device served on a TCP listener in a background thread
/// (several clients at once; the device kept across connections).
pub struct SimServer {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<SimDevice>>,
}

impl SimServer {
    /// Serve a fresh [`SimDevice`] in real time.
    pub fn spawn(listener: TcpListener) -> io::Result<Self> {
        Self::spawn_with(listener, SimDevice::default())
    }

    /// Serve `dev` in real time.
    pub fn spawn_with(listener: TcpListener, dev: SimDevice) -> io::Result<Self> {
        Self::spawn_scaled(listener, dev, 1.0)
    }

    /// Serve `dev` at `scale` simulated seconds per real second.
    pub fn spawn_scaled(listener: TcpListener, mut dev: SimDevice, scale: f64) -> io::Result<Self> {
        let addr = listener.local_addr()?;
        listener.set_nonblocking(true)?;
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut clock = Clock::new(dev.drive.pwm_hz(), scale);
            let mut conns: Vec<Conn> = Vec::new();
            while !flag.load(Ordering::Relaxed) {
                serve_once(&listener, &mut dev, &mut conns, &mut clock);
            }
            dev
        });
        Ok(Self {
            addr,
            stop,
            thread: Some(thread),
        })
    }

    /// The address to connect to.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Stop serving and return the device (for inspection).
    pub fn stop(mut self) -> Option<SimDevice> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.take().and_then(|t| t.join().ok())
    }

    /// Serve until the process ends (for `foc-ctl simulate`).
    pub fn wait(mut self) {
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// One pass: new clients, their requests, the drive advanced to now,
/// replies and streamed samples out.
fn serve_once(
    listener: &TcpListener,
    dev: &mut SimDevice,
    conns: &mut Vec<Conn>,
    clock: &mut Clock,
) {
    while let Ok((stream, _)) = listener.accept() {
        if stream.set_nonblocking(true).is_ok() {
            let _ = stream.set_nodelay(true);
            let id = dev.open();
            conns.push(Conn { stream, id });
        }
    }
    let mut received = false;
    conns.retain_mut(|c| {
        let alive = c.read(dev, &mut received) && c.write(dev);
        if !alive {
            dev.close(c.id);
        }
        alive
    });
    // A request's effect (a mailbox taken by the current loop) is seen by
    // the next request, as on a board where a round trip outlasts a PWM
    // period: at least one period after any request, borrowed from the
    // clock.
    let n = clock.periods_at_least(u32::from(received));
    dev.advance(n);
    conns.retain_mut(|c| {
        let alive = c.write(dev);
        if !alive {
            dev.close(c.id);
        }
        alive
    });
    if n == 0 {
        std::thread::sleep(Duration::from_micros(200));
    }
}

impl Drop for SimServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn periods_lent_to_a_request_are_paid_back() {
        let mut c = Clock::new(20_000, 1.0);
        c.carry = 0.0;
        c.last = Instant::now();
        // A request forces one period now...
        assert_eq!(c.periods_at_least(1), 1);
        assert!(c.carry < 0.0);
        // ... so none is due until a whole period of time has passed.
        c.last = Instant::now();
        assert_eq!(c.periods(), 0);
        c.carry += 1.2;
        c.last = Instant::now();
        assert_eq!(c.periods(), 0, "0.2 periods due, not 1");
        c.carry += 1.0;
        c.last = Instant::now();
        assert_eq!(c.periods(), 1);
    }
}
