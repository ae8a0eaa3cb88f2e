//! The in-process link: the daemon's embedded bench gives its loop the simulated servos by
//! function call instead of through a pseudo-terminal.
//!
//! Why: a real servo answers on time whatever the host does (its firmware has its own MCU).
//! On a pty the simulation cannot: the bytes pass through a kernel worker that is not
//! real-time, and the bus thread must itself be woken to answer; on a loaded, virtualised or
//! non-preemptible kernel either wakes late by milliseconds, and the loop counts read timeouts
//! that are artefacts of the simulation (docs/mock-bench.md has the measurements). Here a
//! request is answered when it is written (physics first brought up to that instant), and its
//! reply becomes readable exactly when the wire model says (`wire`: instruction and reply bytes
//! at the baud rate, the Return Delay Time); the loop waits for it on its own clock. No thread
//! has to be woken for a reply, so what can still make one late is the loop's own scheduling
//! and, briefly, the simulation's lock (the pty thread and the hand's torque take it too).
//!
//! What this costs the loop, and only on the embedded bench: the simulated firmware (parsing,
//! the control table, the physics brought up to date) runs on the RT thread, allocating its
//! packets as the pty path does. Its timings include that work; a real bus has none of it. A
//! panic in the simulation is caught here and becomes EIO (the loop's bus-lost path), so the
//! RT thread never unwinds.
//!
//! The pty stays for every other client (the daemon's start-up checks, `mock-bench`, the
//! ROBOTIS SDK). Unplug and replug act on this link as on the pty: while unplugged, writes and
//! reads fail with EIO (the loop's bus-lost path), a replug breaks the old link once, and
//! `reconnect` is true once the adapter is back.
use std::collections::VecDeque;
use std::io;
use std::panic::AssertUnwindSafe;
use std::sync::{Arc, Mutex};

use rt::bus::Transport;
use rt::clock::{monotonic_ns, Clock, MonotonicClock};

use crate::server::{lock, BusConfig, Port, Shared};
use crate::wire::Answerer;

/// One client's in-process wire to the simulated servos (see the module doc).
pub struct DirectLink {
    port: Arc<Mutex<Port>>,
    shared: Arc<Mutex<Shared>>,
    answerer: Answerer,
    /// Due reply bytes the client has not read yet.
    output: VecDeque<u8>,
    /// Bytes read since the last write: counted in the write's lock (one lock per transaction).
    unreported_out: u64,
    /// The adapter this link was opened on (a replug makes a new one).
    generation: u64,
    clock: MonotonicClock,
}

impl DirectLink {
    pub(crate) fn new(port: Arc<Mutex<Port>>, shared: Arc<Mutex<Shared>>, config: BusConfig) -> DirectLink {
        let generation = lock(&port).generation;
        let protocol = lock(&shared).bus.protocol();
        let answerer = Answerer::new(protocol, config, monotonic_ns());
        DirectLink { port, shared, answerer, output: VecDeque::new(), unreported_out: 0, generation, clock: MonotonicClock }
    }

    /// (plugged in, the adapter's generation) now.
    fn adapter(&self) -> (bool, u64) {
        let port = lock(&self.port);
        (port.pty.is_some(), port.generation)
    }

    /// A new adapter: what was in flight on the old one is gone with it.
    fn take_new_wire(&mut self, generation: u64) {
        self.generation = generation;
        self.answerer.clear(monotonic_ns());
        self.output.clear();
    }

    /// EIO while unplugged, and once after a replug (the old adapter's link is dead).
    fn check_plugged(&mut self) -> io::Result<()> {
        let (plugged, generation) = self.adapter();
        if generation != self.generation {
            self.take_new_wire(generation);
            return Err(io::Error::from_raw_os_error(libc::EIO));
        }
        if plugged { Ok(()) } else { Err(io::Error::from_raw_os_error(libc::EIO)) }
    }

    /// Copies up to `buf.len()` due bytes out; how many.
    fn take_output(&mut self, buf: &mut [u8]) -> usize {
        let n = buf.len().min(self.output.len());
        for (slot, byte) in buf.iter_mut().zip(self.output.drain(..n)) {
            *slot = byte;
        }
        self.unreported_out += n as u64;
        n
    }
}

impl Transport for DirectLink {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.check_plugged()?;
        let now = monotonic_ns();
        let shared = &mut *lock(&self.shared);
        shared.io.bytes_out += std::mem::take(&mut self.unreported_out);
        let answerer = &mut self.answerer;
        std::panic::catch_unwind(AssertUnwindSafe(|| answerer.receive(now, bytes, shared)))
            .map_err(|_| io::Error::from_raw_os_error(libc::EIO))
    }

    fn read_until(&mut self, buf: &mut [u8], deadline_ns: u64) -> io::Result<usize> {
        loop {
            self.check_plugged()?;
            let now = monotonic_ns();
            while let Some((_, bytes)) = self.answerer.pop_due(now) {
                self.output.extend(bytes);
            }
            if !self.output.is_empty() {
                return Ok(self.take_output(buf));
            }
            match self.answerer.next_due_ns() {
                Some(due) if due <= deadline_ns => self.clock.sleep_until(due),
                _ => {
                    if now < deadline_ns {
                        self.clock.sleep_until(deadline_ns);
                    }
                    return Ok(0);
                }
            }
        }
    }

    fn kind(&self) -> &'static str {
        "in-process"
    }

    fn reconnect(&mut self) -> bool {
        let (plugged, generation) = self.adapter();
        if plugged && generation != self.generation {
            self.take_new_wire(generation);
        }
        plugged
    }
}
