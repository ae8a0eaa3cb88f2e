//! The bus thread: reads the pty, decodes, lets the servos answer, writes replies on time, and
//! keeps the physics up with the wall clock.
//!
//! One thread owns the pty and the schedule; the servos sit behind one mutex so Python can set
//! a hand torque or read a horn's state at any time. The thread holds the lock only to step the
//! physics and answer a packet, never while it waits for bytes.
//!
//! Timing (with `wire_delay`): a pty delivers bytes instantly, so the mock adds what a real
//! bus takes. A reply's first byte may start when the instruction's last byte would have
//! arrived (instruction length × 10 bits / baud after it was read) plus the servo's Return
//! Delay Time; the reply is written when its own last byte would have arrived. Chained replies
//! (broadcast PING, Sync/Bulk Read) follow each other the same way, each after its servo's
//! Return Delay Time. Without `wire_delay` replies go out at once.
//!
//! Scheduling and honesty about it: a real servo's firmware answers on time whatever the host
//! does, but this thread is one more thread of a loaded machine. It therefore asks for the
//! scheduling the RT loop gets (`rt_priority`: SCHED_FIFO at that priority when permitted, the
//! same fallback to SCHED_OTHER and the same warning as the loop, via `rtloop::sched`), and
//! measures how late it ran by its own clock (`Timing`): each reply's write behind its due
//! time, each timed wait's return behind its deadline, and the stalls (either later than
//! `STALL`). A client that times out on a simulated bus can so be told whether the simulation
//! was late, which a real bus never is.
//!
//! Physics runs at a fixed substep (default 2 kHz) up to the wall clock, both on every wait
//! timeout (≤ 1 ms) and before a packet is answered, so reads see current positions. If the
//! thread was starved for more than `MAX_CATCH_UP`, the lost time is skipped (and counted)
//! rather than simulated in one burst that would starve it again.
//!
//! Unplug and replug (the USB adapter pulled out and put back): `unplug` closes the pty, so a
//! client's descriptor hangs up as on a real unplug (reads return end-of-file, writes EIO) and
//! its device node disappears; the servos keep their power and state. `replug` opens a new pty.
//! A pty's number changes with it, so a client that must find the bus again uses the stable
//! path of `set_link`: a symlink that `unplug` removes and `replug` points at the new pty, as
//! udev's /dev/serial/by-id links do for a real adapter.
use std::collections::VecDeque;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use dxl::{protocol1, protocol2, DecodeError, Kind, Packet, Protocol};
use rtloop::histogram::{Histogram, Percentiles};
use rtloop::sched::{self, Policy, RtReport, RtRequest};

use crate::bus::{Bus, Counters, Reply};
use crate::pty::Pty;

/// The longest the thread sleeps between physics catch-ups.
const MAX_WAIT: Duration = Duration::from_millis(1);
/// The most simulated time one catch-up may run; beyond it time is skipped.
const MAX_CATCH_UP: Duration = Duration::from_millis(250);
/// A partial packet older than this is dropped: the e-manual's 1.5 ms inter-byte timeout,
/// after which a servo waits for a new header. Clients write a packet in one call, so on a
/// pty a packet's bytes arrive together and only a truncated packet ever waits this long.
const INTER_BYTE_TIMEOUT: Duration = Duration::from_micros(1500);
/// A reply or a wake-up later than this is a stall of the thread: a quarter of a 1 kHz loop's
/// period, beyond which a 1 kHz client's read window (most of a period, less the wire time) is
/// at risk. Only a count; the histograms keep every lateness.
pub const STALL: Duration = Duration::from_micros(250);
/// Replies beyond this many unsent bytes are dropped (a client that stopped reading).
const MAX_PENDING_OUTPUT: usize = 64 * 1024;

/// How the bus runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BusConfig {
    pub baudrate: u32,
    pub wire_delay: bool,
    pub physics_rate_hz: f64,
    /// The bus thread's SCHED_FIFO priority (1..=99; refused → SCHED_OTHER with a warning);
    /// 0 = SCHED_OTHER.
    pub rt_priority: i32,
}

/// How late the bus thread ran, by its own clock, and the scheduling it obtained.
#[derive(Default)]
pub struct Timing {
    /// Each reply: when it was written − when it was due (its emulated wire and Return Delay Time).
    reply_late: Histogram,
    /// Each timed wait that ended at or after its deadline: the return − the deadline. A wait
    /// that bytes ended early is not a sample (how late the thread saw them is not measurable).
    wake_late: Histogram,
    stalls: AtomicU64,
    report: Mutex<(RtReport, Vec<String>)>,
}

impl Timing {
    fn record(&self, histogram: &Histogram, late: Duration) {
        histogram.record(late.as_nanos() as u64);
        if late > STALL {
            self.stalls.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// What `timing()` reports.
#[derive(Clone, Debug, PartialEq)]
pub struct TimingReport {
    pub reply_late_us: Percentiles,
    pub wake_late_us: Percentiles,
    /// Replies and wake-ups later than `STALL`.
    pub stalls: u64,
    /// The bus thread's scheduling (the default SCHED_OTHER report before it started).
    pub rt: RtReport,
    /// Why it did not get what it asked for (SCHED_FIFO refused), once each.
    pub warnings: Vec<String>,
}

/// I/O and timing counters of the thread, next to the bus's own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct IoCounters {
    pub bytes_in: u64,
    pub bytes_out: u64,
    pub garbage_bytes: u64,
    pub framing_errors: u64,
    pub foreign_status_packets: u64,
    pub dropped_reply_bytes: u64,
    pub truncated_packets: u64,
    pub physics_steps: u64,
    pub skipped_steps: u64,
    pub unplugs: u64,
    pub replugs: u64,
}

/// The state the thread and Python share.
pub struct Shared {
    pub bus: Bus,
    pub io: IoCounters,
}

/// What `stats()` reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stats {
    pub bus: Counters,
    pub io: IoCounters,
}

/// A simulated bus on a pty, running in its own thread between `start` and `stop`.
///
/// Every method takes `&self` (the thread handle sits behind its own mutex), so one thread
/// may stop the bus while another still sets a hand torque: Python's bench does exactly that.
pub struct MockBus {
    port: Arc<Mutex<Port>>,
    shared: Arc<Mutex<Shared>>,
    config: BusConfig,
    stop: Arc<AtomicBool>,
    thread: Mutex<Option<JoinHandle<io::Result<()>>>>,
    timing: Arc<Timing>,
}

/// The bus's end of the wire: the pty while plugged in, and the stable link to it.
struct Port {
    pty: Option<Arc<Pty>>,
    /// The device path of the current pty (the last one while unplugged).
    path: String,
    link: Option<PathBuf>,
    /// Bumped at every unplug and replug, so the thread drops what was in flight.
    generation: u64,
}

impl MockBus {
    /// Opens the pty; the servos stay still until `start`. The physics rate must be within
    /// 1 Hz..=1 MHz (InvalidInput otherwise).
    pub fn new(bus: Bus, config: BusConfig) -> io::Result<MockBus> {
        if !(1.0..=1e6).contains(&config.physics_rate_hz) {
            let message = format!("physics rate {} Hz is outside 1..=1e6", config.physics_rate_hz);
            return Err(io::Error::new(io::ErrorKind::InvalidInput, message));
        }
        if !(0..=99).contains(&config.rt_priority) {
            let message = format!("rt_priority {} is outside 0..=99", config.rt_priority);
            return Err(io::Error::new(io::ErrorKind::InvalidInput, message));
        }
        let pty = Pty::open()?;
        let port = Port { path: pty.path().to_string(), pty: Some(Arc::new(pty)), link: None, generation: 0 };
        Ok(MockBus {
            port: Arc::new(Mutex::new(port)),
            shared: Arc::new(Mutex::new(Shared { bus, io: IoCounters::default() })),
            config,
            stop: Arc::new(AtomicBool::new(false)),
            thread: Mutex::new(None),
            timing: Arc::new(Timing::default()),
        })
    }

    fn port(&self) -> MutexGuard<'_, Port> {
        self.port.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// The device a client opens now, e.g. `/dev/pts/7` (the last one while unplugged).
    pub fn port_path(&self) -> String {
        self.port().path.clone()
    }

    /// The stable path (see `set_link`), if one was set.
    pub fn link_path(&self) -> Option<PathBuf> {
        self.port().link.clone()
    }

    pub fn is_plugged(&self) -> bool {
        self.port().pty.is_some()
    }

    /// Makes `link` a symlink to the bus's pty, kept pointing at it across replugs and removed
    /// while unplugged and when the bus is dropped. An existing file at `link` is replaced.
    pub fn set_link(&self, link: &Path) -> io::Result<()> {
        let mut port = self.port();
        if let Some(old) = port.link.take() {
            let _ = std::fs::remove_file(old);
        }
        if port.pty.is_some() {
            point_link(link, &port.path)?;
        }
        port.link = Some(link.to_path_buf());
        Ok(())
    }

    /// Pulls the adapter out: the pty closes (a client's descriptor hangs up) and the link goes.
    /// Returns once the pty is closed; false if it was unplugged already.
    pub fn unplug(&self) -> bool {
        let mut pty = {
            let mut port = self.port();
            let Some(pty) = port.pty.take() else { return false };
            port.generation += 1;
            if let Some(link) = &port.link {
                let _ = std::fs::remove_file(link);
            }
            pty
        };
        // The thread holds its own reference for one iteration at most (≤ MAX_WAIT): wait for
        // it, so that the pty really is closed when this returns.
        loop {
            match Arc::try_unwrap(pty) {
                Ok(closed) => break drop(closed),
                Err(shared) => {
                    pty = shared;
                    std::thread::sleep(Duration::from_micros(200));
                }
            }
        }
        self.lock().io.unplugs += 1;
        true
    }

    /// Puts the adapter back: a new pty (a new `/dev/pts/N`), the link pointed at it. Returns
    /// false if it was plugged in already.
    pub fn replug(&self) -> io::Result<bool> {
        let mut port = self.port();
        if port.pty.is_some() {
            return Ok(false);
        }
        let pty = Pty::open()?;
        if let Some(link) = &port.link {
            point_link(link, pty.path())?;
        }
        port.path = pty.path().to_string();
        port.pty = Some(Arc::new(pty));
        port.generation += 1;
        drop(port);
        self.lock().io.replugs += 1;
        Ok(true)
    }

    pub fn is_running(&self) -> bool {
        self.handle().as_ref().is_some_and(|t| !t.is_finished())
    }

    fn handle(&self) -> MutexGuard<'_, Option<JoinHandle<io::Result<()>>>> {
        self.thread.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Starts the bus thread (a no-op when it runs already).
    pub fn start(&self) -> io::Result<()> {
        let mut handle = self.handle();
        if handle.is_some() {
            return Ok(());
        }
        self.stop.store(false, Ordering::SeqCst);
        let mut worker =
            Worker::new(self.port.clone(), self.shared.clone(), self.config, self.stop.clone(), self.timing.clone());
        *handle = Some(std::thread::Builder::new().name("dxlsim-bus".into()).spawn(move || worker.run())?);
        Ok(())
    }

    /// Stops the thread and waits for it; returns the I/O error that ended it early, if any.
    pub fn stop(&self) -> io::Result<()> {
        self.stop.store(true, Ordering::SeqCst);
        let handle = self.handle().take();
        match handle {
            Some(handle) => handle.join().map_err(|_| io::Error::other("the bus thread panicked"))?,
            None => Ok(()),
        }
    }

    /// The servos, locked (the lock survives a panicked thread: the data stays consistent
    /// because every mutation is a single call).
    pub fn lock(&self) -> MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    pub fn stats(&self) -> Stats {
        let shared = self.lock();
        Stats { bus: shared.bus.counters, io: shared.io }
    }

    /// How late the bus thread ran (by its own clock) and the scheduling it obtained.
    pub fn timing(&self) -> TimingReport {
        let t = &self.timing;
        let (rt, warnings) = t.report.lock().map(|r| r.clone()).unwrap_or_default();
        TimingReport {
            reply_late_us: t.reply_late.percentiles(),
            wake_late_us: t.wake_late.percentiles(),
            stalls: t.stalls.load(Ordering::Relaxed),
            rt,
            warnings,
        }
    }
}

impl Drop for MockBus {
    fn drop(&mut self) {
        let _ = self.stop();
        if let Some(link) = self.port().link.take() {
            let _ = std::fs::remove_file(link);
        }
    }
}

/// Points the symlink `link` at `target`, atomically (a new link renamed over the old one), so
/// a client never finds the path missing while the bus is plugged in.
fn point_link(link: &Path, target: &str) -> io::Result<()> {
    let mut temporary = link.as_os_str().to_owned();
    temporary.push(format!(".{}.new", std::process::id()));
    let temporary = PathBuf::from(temporary);
    let _ = std::fs::remove_file(&temporary);
    std::os::unix::fs::symlink(target, &temporary)?;
    std::fs::rename(&temporary, link)
}

/// A packet decoder for the bus's protocol (the two decoders are different types).
enum Decoder {
    V1(protocol1::Decoder),
    V2(protocol2::Decoder),
}

impl Decoder {
    fn new(protocol: Protocol) -> Decoder {
        match protocol {
            Protocol::V1 => Decoder::V1(protocol1::Decoder::new(protocol1::Expect::Instruction)),
            Protocol::V2 => Decoder::V2(protocol2::Decoder::new()),
        }
    }

    fn push(&mut self, bytes: &[u8]) -> usize {
        match self {
            Decoder::V1(d) => d.push(bytes),
            Decoder::V2(d) => d.push(bytes),
        }
    }

    fn next(&mut self) -> Option<Result<Packet<'_>, DecodeError>> {
        match self {
            Decoder::V1(d) => d.next(),
            Decoder::V2(d) => d.next(),
        }
    }

    fn skipped_bytes(&self) -> u64 {
        match self {
            Decoder::V1(d) => d.skipped_bytes(),
            Decoder::V2(d) => d.skipped_bytes(),
        }
    }

    fn buffered(&self) -> usize {
        match self {
            Decoder::V1(d) => d.buffered(),
            Decoder::V2(d) => d.buffered(),
        }
    }

    fn clear(&mut self) {
        match self {
            Decoder::V1(d) => d.clear(),
            Decoder::V2(d) => d.clear(),
        }
    }
}

/// The thread's own state.
struct Worker {
    port: Arc<Mutex<Port>>,
    /// The generation of the pty the buffers below belong to.
    generation: u64,
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    decoder: Decoder,
    config: BusConfig,
    step: Duration,
    epoch: Instant,
    steps_done: u64,
    /// Replies waiting for their due time, in wire order.
    schedule: VecDeque<(Instant, Vec<u8>)>,
    /// Bytes the pty did not take yet.
    output: VecDeque<u8>,
    /// When the bus is free again (the last scheduled reply's end).
    bus_free: Instant,
    /// When the last bytes arrived (for the inter-byte timeout).
    last_rx: Instant,
    timing: Arc<Timing>,
}

impl Worker {
    fn new(
        port: Arc<Mutex<Port>>,
        shared: Arc<Mutex<Shared>>,
        config: BusConfig,
        stop: Arc<AtomicBool>,
        timing: Arc<Timing>,
    ) -> Worker {
        let protocol = shared.lock().unwrap_or_else(|p| p.into_inner()).bus.protocol();
        let generation = port.lock().unwrap_or_else(|p| p.into_inner()).generation;
        let now = Instant::now();
        Worker {
            port,
            generation,
            shared,
            stop,
            decoder: Decoder::new(protocol),
            config,
            step: Duration::from_secs_f64(1.0 / config.physics_rate_hz),
            epoch: now,
            steps_done: 0,
            schedule: VecDeque::new(),
            output: VecDeque::new(),
            bus_free: now,
            last_rx: now,
            timing,
        }
    }

    /// The loop's scheduling for this thread (SCHED_FIFO at `rt_priority`, or SCHED_OTHER),
    /// with the loop's fallback and warning, and its minimal timer slack: the emulated delays
    /// are sleeps, which the default 50 µs slack would make late by that much.
    fn schedule_thread(&self) {
        let priority = self.config.rt_priority;
        let policy = if priority > 0 { Policy::Fifo } else { Policy::Other };
        let request = RtRequest { policy, priority, lock_memory: false, cpu: None };
        let (report, warnings) = sched::apply_to_current_thread(&request);
        let warnings = warnings.into_iter().map(|w| format!("simulated bus thread: {w}")).collect();
        if let Ok(mut slot) = self.timing.report.lock() {
            *slot = (report, warnings);
        }
    }

    fn run(&mut self) -> io::Result<()> {
        self.schedule_thread();
        let mut buf = [0u8; 4096];
        while !self.stop.load(Ordering::SeqCst) {
            self.advance_physics();
            // This iteration's reference to the pty; `unplug` waits until it is dropped.
            let Some(pty) = self.current_pty() else {
                std::thread::sleep(MAX_WAIT);
                continue;
            };
            self.flush_due(&pty)?;
            if self.wait(&pty)? {
                let n = pty.read(&mut buf)?;
                self.receive(&buf[..n]);
            } else {
                self.drop_stale_partial();
            }
        }
        Ok(())
    }

    /// The pty plugged in now, if any; after an unplug or replug, what was in flight on the
    /// old wire (a partial packet, replies not yet sent) is gone with it.
    fn current_pty(&mut self) -> Option<Arc<Pty>> {
        let port = self.port.lock().unwrap_or_else(|p| p.into_inner());
        if port.generation != self.generation {
            self.generation = port.generation;
            self.decoder.clear();
            self.schedule.clear();
            self.output.clear();
            self.bus_free = Instant::now();
        }
        port.pty.clone()
    }

    fn lock(&self) -> MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Steps every servo up to the wall clock.
    fn advance_physics(&mut self) {
        let due = (self.epoch.elapsed().as_nanos() / self.step.as_nanos()) as u64;
        let max_burst = (MAX_CATCH_UP.as_nanos() / self.step.as_nanos()) as u64;
        let mut n = due.saturating_sub(self.steps_done);
        let h = self.step.as_secs_f64();
        let shared = &mut *self.shared.lock().unwrap_or_else(|p| p.into_inner());
        if n > max_burst {
            shared.io.skipped_steps += n - max_burst;
            self.steps_done += n - max_burst;
            n = max_burst;
        }
        for _ in 0..n {
            shared.bus.step(h);
        }
        self.steps_done += n;
        shared.io.physics_steps += n;
        shared.bus.publish();
    }

    /// Waits for bytes (see `wait_time`); true when some arrived. A wait that ends at or after
    /// its deadline records how late the thread got to run again.
    fn wait(&self, pty: &Pty) -> io::Result<bool> {
        let timeout = self.wait_time();
        let deadline = Instant::now() + timeout;
        let readable = pty.wait_readable(timeout)?;
        let now = Instant::now();
        if now >= deadline {
            self.timing.record(&self.timing.wake_late, now - deadline);
        }
        Ok(readable)
    }

    /// How long to wait for bytes: until the next reply is due, at most `MAX_WAIT`.
    fn wait_time(&self) -> Duration {
        let now = Instant::now();
        let next_reply = self.schedule.front().map(|(due, _)| due.saturating_duration_since(now));
        let wait = next_reply.map_or(MAX_WAIT, |d| d.min(MAX_WAIT));
        if self.output.is_empty() { wait } else { wait.min(Duration::from_micros(100)) }
    }

    /// Time `n` bytes take on the wire: 10 bits per byte (start, 8 data, stop).
    fn wire_time(&self, n: usize) -> Duration {
        if self.config.wire_delay && self.config.baudrate > 0 {
            Duration::from_secs_f64(n as f64 * 10.0 / self.config.baudrate as f64)
        } else {
            Duration::ZERO
        }
    }

    /// Forgets a partial packet once the inter-byte timeout has passed.
    fn drop_stale_partial(&mut self) {
        if self.decoder.buffered() > 0 && self.last_rx.elapsed() > INTER_BYTE_TIMEOUT {
            self.decoder.clear();
            self.lock().io.truncated_packets += 1;
        }
    }

    fn receive(&mut self, mut bytes: &[u8]) {
        let arrival = Instant::now();
        self.drop_stale_partial();
        self.last_rx = arrival;
        self.lock().io.bytes_in += bytes.len() as u64;
        while !bytes.is_empty() {
            let taken = self.decoder.push(bytes);
            bytes = &bytes[taken..];
            self.drain_packets(arrival);
        }
        let skipped = self.decoder.skipped_bytes();
        self.lock().io.garbage_bytes = skipped;
    }

    /// Answers every whole packet the decoder holds.
    fn drain_packets(&mut self, arrival: Instant) {
        self.advance_physics();
        loop {
            let answered = {
                let shared = &mut *self.shared.lock().unwrap_or_else(|p| p.into_inner());
                let protocol = shared.bus.protocol();
                match self.decoder.next() {
                    None => return,
                    Some(Ok(Packet { id, kind: Kind::Instruction(code), params })) => {
                        Some((shared.bus.handle(id, code, params), packet_len(protocol, params.len())))
                    }
                    Some(Ok(Packet { kind: Kind::Status(_), .. })) => {
                        shared.io.foreign_status_packets += 1;
                        None
                    }
                    Some(Err(DecodeError::Crc { id, .. } | DecodeError::Checksum { id, .. })) => {
                        Some((shared.bus.handle_corrupt(id), packet_len(protocol, 0)))
                    }
                    Some(Err(DecodeError::Length { .. })) => {
                        shared.io.framing_errors += 1;
                        None
                    }
                }
            };
            if let Some((replies, length)) = answered {
                self.schedule_replies(arrival + self.wire_time(length), replies);
            }
        }
    }

    /// Queues replies back to back after `start`, each after its servo's Return Delay Time.
    fn schedule_replies(&mut self, start: Instant, replies: Vec<Reply>) {
        let mut t = start.max(self.bus_free);
        for reply in replies.into_iter().filter(|r| !r.bytes.is_empty()) {
            if self.config.wire_delay {
                t += Duration::from_micros(reply.delay_us);
            }
            t += self.wire_time(reply.bytes.len());
            self.schedule.push_back((t, reply.bytes));
        }
        self.bus_free = t;
    }

    /// Writes every reply whose time has come, then whatever the pty accepts.
    fn flush_due(&mut self, pty: &Pty) -> io::Result<()> {
        let now = Instant::now();
        while self.schedule.front().is_some_and(|(due, _)| *due <= now) {
            let Some((due, bytes)) = self.schedule.pop_front() else { break };
            self.timing.record(&self.timing.reply_late, now - due);
            if self.output.len() + bytes.len() > MAX_PENDING_OUTPUT {
                self.lock().io.dropped_reply_bytes += bytes.len() as u64;
            } else {
                self.output.extend(bytes);
            }
        }
        while !self.output.is_empty() {
            let (front, _) = self.output.as_slices();
            let n = pty.write(front)?;
            if n == 0 {
                break;
            }
            self.output.drain(..n);
            self.lock().io.bytes_out += n as u64;
        }
        Ok(())
    }
}

/// The size of an instruction packet with `n_params` parameter bytes (unstuffed; the
/// difference stuffing makes is a few bytes of wire time at most).
fn packet_len(protocol: Protocol, n_params: usize) -> usize {
    match protocol {
        Protocol::V1 => protocol1::PREFIX_LEN + 2 + n_params,
        Protocol::V2 => protocol2::PREFIX_LEN + 3 + n_params,
    }
}
