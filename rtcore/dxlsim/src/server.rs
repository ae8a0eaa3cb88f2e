//! The bus thread: reads the pty, decodes, lets the servos answer, writes replies on time, and
//! keeps the physics up with the wall clock.
//!
//! One thread owns the pty and the schedule; the servos sit behind one mutex so Python can set
//! a hand torque or read a horn's state at any time. The thread holds the lock only to step the
//! physics and answer a packet, never while it waits for bytes.
//!
//! Timing: `wire` times each reply as a real wire would (instruction and reply bytes at the
//! baud rate, the servo's Return Delay Time); this thread writes it to the pty when it is due.
//!
//! Scheduling and honesty about it: a real servo's firmware answers on time whatever the host
//! does, but this thread is one more thread of a loaded machine. It therefore asks for the
//! scheduling the RT loop gets (`rt_priority`: SCHED_FIFO at that priority when permitted, the
//! same fallback to SCHED_OTHER and the same warning as the loop, via `rt::sched`), and
//! measures how late it ran by its own clock (`Timing`): each reply's write behind its due
//! time, each timed wait's return behind its deadline, and the stalls (either later than
//! `STALL`). A client that times out on a simulated bus can so be told whether the simulation
//! was late, which a real bus never is.
//!
//! Physics runs at a fixed substep (default 2 kHz) up to the wall clock, both on every wait
//! timeout (≤ 1 ms) and before a packet is answered, so reads see current positions
//! (`Shared::advance_physics`, which the in-process link calls too).
//!
//! The daemon's embedded bench gives its loop a `direct::DirectLink` into the same servos
//! instead of this pty: see that module for why.
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

use rt::clock::monotonic_ns;
use rt::histogram::{Histogram, Percentiles};
use rt::sched::{self, Policy, RtReport, RtRequest};

use crate::bus::{Bus, Counters};
use crate::direct::DirectLink;
use crate::pty::Pty;
use crate::wire::{Answerer, PhysicsClock};

/// The longest the thread sleeps between physics catch-ups.
const MAX_WAIT: Duration = Duration::from_millis(1);
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
    pub physics: PhysicsClock,
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
pub(crate) struct Port {
    pub(crate) pty: Option<Arc<Pty>>,
    /// The device path of the current pty (the last one while unplugged).
    path: String,
    link: Option<PathBuf>,
    /// Bumped at every unplug and replug, so the thread and the in-process links drop what was in flight.
    pub(crate) generation: u64,
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
            shared: Arc::new(Mutex::new(Shared { bus, io: IoCounters::default(), physics: PhysicsClock::new(config.physics_rate_hz) })),
            config,
            stop: Arc::new(AtomicBool::new(false)),
            thread: Mutex::new(None),
            timing: Arc::new(Timing::default()),
        })
    }

    fn port(&self) -> MutexGuard<'_, Port> {
        lock(&self.port)
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
        let pty = open_linked(port.link.as_deref())?;
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
        lock(&self.thread)
    }

    /// Starts the bus thread (a no-op when it runs already).
    pub fn start(&self) -> io::Result<()> {
        let mut handle = self.handle();
        if handle.is_some() {
            return Ok(());
        }
        self.stop.store(false, Ordering::SeqCst);
        self.lock().physics.start(monotonic_ns());
        let mut worker =
            Worker::new(self.port.clone(), self.shared.clone(), self.config, self.stop.clone(), self.timing.clone());
        *handle = Some(std::thread::Builder::new().name("dxlsim-bus".into()).spawn(move || worker.run())?);
        Ok(())
    }

    /// The servos' shared state, for another simulated device that acts on them (the bench's
    /// force sensor: `daq`).
    pub fn servos(&self) -> Arc<Mutex<Shared>> {
        self.shared.clone()
    }

    /// The wire's and the physics' settings (the lockstep bench times its link with them).
    pub fn config(&self) -> BusConfig {
        self.config
    }

    /// An in-process link to these servos for one client (the embedded bench's loop): see `direct`.
    pub fn direct_link(&self) -> DirectLink {
        DirectLink::new(self.port.clone(), self.shared.clone(), self.config)
    }

    /// Stops the thread and waits for it; returns the I/O error that ended it early, if any.
    pub fn stop(&self) -> io::Result<()> {
        self.stop.store(true, Ordering::SeqCst);
        let handle = self.handle().take();
        self.lock().physics.pause();
        match handle {
            Some(handle) => handle.join().map_err(|_| io::Error::other("the bus thread panicked"))?,
            None => Ok(()),
        }
    }

    /// The servos, locked (the lock survives a panicked thread: the data stays consistent
    /// because every mutation is a single call).
    pub fn lock(&self) -> MutexGuard<'_, Shared> {
        lock(&self.shared)
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

/// A new pty, with `link` (if any) pointed at it: a replugged adapter, bus or sensor.
pub(crate) fn open_linked(link: Option<&Path>) -> io::Result<Pty> {
    let pty = Pty::open()?;
    if let Some(link) = link {
        point_link(link, pty.path())?;
    }
    Ok(pty)
}

/// Points the symlink `link` at `target`, atomically (a new link renamed over the old one), so
/// a client never finds the path missing while the bus is plugged in.
pub(crate) fn point_link(link: &Path, target: &str) -> io::Result<()> {
    let mut temporary = link.as_os_str().to_owned();
    temporary.push(format!(".{}.new", std::process::id()));
    let temporary = PathBuf::from(temporary);
    let _ = std::fs::remove_file(&temporary);
    std::os::unix::fs::symlink(target, &temporary)?;
    std::fs::rename(&temporary, link)
}

/// The thread's own state.
struct Worker {
    port: Arc<Mutex<Port>>,
    /// The generation of the pty the buffers below belong to.
    generation: u64,
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    /// The SCHED_FIFO priority asked for (0: SCHED_OTHER).
    rt_priority: i32,
    answerer: Answerer,
    /// Bytes the pty did not take yet.
    output: VecDeque<u8>,
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
        let protocol = lock(&shared).bus.protocol();
        let generation = lock(&port).generation;
        let answerer = Answerer::new(protocol, config, monotonic_ns());
        Worker { port, generation, shared, stop, rt_priority: config.rt_priority, answerer, output: VecDeque::new(), timing }
    }

    /// The loop's scheduling for this thread (SCHED_FIFO at `rt_priority`, or SCHED_OTHER),
    /// with the loop's fallback and warning, and its minimal timer slack: the emulated delays
    /// are sleeps, which the default 50 µs slack would make late by that much.
    fn schedule_thread(&self) {
        let priority = self.rt_priority;
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
            self.lock().advance_physics(monotonic_ns());
            // This iteration's reference to the pty; `unplug` waits until it is dropped.
            let Some(pty) = self.current_pty() else {
                std::thread::sleep(MAX_WAIT);
                continue;
            };
            self.flush_due(&pty)?;
            if self.wait(&pty)? {
                let n = pty.read(&mut buf)?;
                let shared = &mut *lock(&self.shared);
                self.answerer.receive(monotonic_ns(), &buf[..n], shared);
            } else {
                let shared = &mut *lock(&self.shared);
                self.answerer.drop_stale_partial(monotonic_ns(), shared);
            }
        }
        Ok(())
    }

    /// The pty plugged in now, if any; after an unplug or replug, what was in flight on the
    /// old wire (a partial packet, replies not yet sent) is gone with it.
    fn current_pty(&mut self) -> Option<Arc<Pty>> {
        let port = lock(&self.port);
        if port.generation != self.generation {
            self.generation = port.generation;
            self.answerer.clear(monotonic_ns());
            self.output.clear();
        }
        port.pty.clone()
    }

    fn lock(&self) -> MutexGuard<'_, Shared> {
        lock(&self.shared)
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
        let now = monotonic_ns();
        let next_reply = self.answerer.next_due_ns().map(|due| Duration::from_nanos(due.saturating_sub(now)));
        let wait = next_reply.map_or(MAX_WAIT, |d| d.min(MAX_WAIT));
        if self.output.is_empty() { wait } else { wait.min(Duration::from_micros(100)) }
    }

    /// Writes every reply whose time has come, then whatever the pty accepts.
    fn flush_due(&mut self, pty: &Pty) -> io::Result<()> {
        let now = monotonic_ns();
        while let Some((due, bytes)) = self.answerer.pop_due(now) {
            self.timing.record(&self.timing.reply_late, Duration::from_nanos(now - due));
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

/// A lock that survives a panicked holder: the data stays consistent because every mutation is
/// a single call. The one way dxlsim takes its locks.
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}
