//! The reader thread: a source's bytes → OptoForce records → newtons → the loop's ring, with
//! no Python on the way. The behaviour is the Python readers' (`admittance/drivers/sensor.py`),
//! moved:
//! - a device that fails while running is closed and reopened with backoff (0.05 s doubling to
//!   2 s, reset by the first sample), so a replug recovers without a restart;
//! - a stream silent for `stale_after` is told once ("stale"), and again when it flows ("fresh");
//! - a DAQ fault in the status word never reaches the loop; a saturated sample is held or
//!   passed by the policy; garbage and bad checksums are skipped and counted;
//! - every event is queued as (kind, message) for the Python side, which tells each kind at
//!   most once per period (the same `EventLog` as the Python readers) and marks the records.
//!
//! Why its own thread at a real-time priority below the loop's: a sample must be in the ring
//! within microseconds of its bytes, whatever the interpreter is doing (issue 18: a Python
//! reader's p99.9 gap was 5.6-6.7 ms under load); and below the loop's, so that a flood of
//! frames cannot delay a cycle. The thread allocates only when an event is told.
//!
//! Samples are stamped on CLOCK_MONOTONIC when their bytes are read (the sensor's own counter
//! or timestamps are not trusted: a jump there moves nothing; counter gaps are counted).
use std::collections::VecDeque;
use std::io;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use rt::clock::monotonic_ns;
use rt::sched::{self, Policy, RtRequest};
use rt::sensor::ForceSample;
use rt::ForceSink;

use crate::optoforce::{Converted, Converter, ConverterStats, Parser, ParserStats, Record, Saturation};
use crate::source::{CanStats, Source};

pub const RECONNECT_FIRST_NS: u64 = 50_000_000;
pub const RECONNECT_MAX_NS: u64 = 2_000_000_000;
const READ_TIMEOUT_US: u64 = 20_000;
const MAX_EVENTS: usize = 256;
const MAX_CAPTURE: usize = 200_000;
const MAX_TARE: usize = 100_000;

/// Where samples go: the loop's ring, or (tools, tests) a bounded capture.
pub enum Target {
    Loop(ForceSink),
    Capture,
}

#[derive(Debug, Clone)]
pub struct ReaderConfig {
    pub counts_per_unit: Vec<f64>,
    pub axes: usize,
    pub sensor_index: usize,
    pub saturation: Saturation,
    /// SCHED_FIFO priority of the reader thread; 0 = SCHED_OTHER.
    pub rt_priority: i32,
    pub stale_after_ns: u64,
}

/// The reader's counters; names follow the Python readers' `stats()`.
#[derive(Debug, Clone, Default)]
pub struct ReaderStats {
    pub state: &'static str,
    pub error: Option<String>,
    pub last_error: Option<String>,
    pub samples_pushed: u64,
    pub samples_dropped: u64,
    pub dropped_before_open: u64,
    pub last_sample_ns: u64,
    pub disconnects: u64,
    pub reconnects: u64,
    pub reopen_failures: u64,
    pub stale_events: u64,
    pub stale: bool,
    /// The longest time between two reads that brought samples, since the start (ns).
    pub max_gap_ns: u64,
    /// Where that gap fell: the read that ended it (CLOCK_MONOTONIC ns) and the sensor's
    /// frame counters on either side (the last sample before it, the first after). With the
    /// source's own write times (a bench's DAQ logs them by counter) they split the gap into
    /// the source's share (no frame written) and the reader's (frames written, not yet read).
    pub max_gap: GapAt,
    pub batches: u64,
    pub parser: ParserStats,
    pub converter: ConverterStats,
    pub can: CanStats,
    pub thread_policy: &'static str,
    pub thread_priority: i32,
    pub thread_warnings: Vec<String>,
}

/// Where the reader's longest gap fell (see `ReaderStats::max_gap`); zeros before any gap.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GapAt {
    pub end_ns: u64,
    pub counter_before: u16,
    pub counter_after: u16,
}

struct TareRequest {
    wanted: usize,
    rows: Vec<[f64; 6]>,
}

/// What the reader thread and its owner share.
struct Shared {
    stop: AtomicBool,
    gate_open: AtomicBool,
    stale_after_ns: AtomicU64,
    bias: Mutex<[f64; 6]>,
    stats: Mutex<ReaderStats>,
    events: Mutex<VecDeque<(&'static str, String)>>,
    capture: Mutex<Vec<ForceSample>>,
    tare: Mutex<Option<TareRequest>>,
    tare_done: Condvar,
}

pub struct Reader {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<Box<dyn Source>>>,
    source: Option<Box<dyn Source>>,
    config: ReaderConfig,
    target: Option<Target>,
    describe: String,
    path: &'static str,
}

impl Reader {
    pub fn new(source: Box<dyn Source>, config: ReaderConfig, target: Target) -> Result<Reader, String> {
        Converter::new(&config.counts_per_unit, config.axes, config.sensor_index, config.saturation)?;
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            gate_open: AtomicBool::new(matches!(target, Target::Capture)),
            stale_after_ns: AtomicU64::new(config.stale_after_ns),
            bias: Mutex::new([0.0; 6]),
            stats: Mutex::new(ReaderStats { state: "stopped", ..ReaderStats::default() }),
            events: Mutex::new(VecDeque::new()),
            capture: Mutex::new(Vec::new()),
            tare: Mutex::new(None),
            tare_done: Condvar::new(),
        });
        let (describe, path) = (source.describe(), source.path());
        Ok(Reader { shared, thread: None, source: Some(source), config, target: Some(target), describe, path })
    }

    pub fn describe(&self) -> &str {
        &self.describe
    }

    /// Which reader runs: `rust-serial`, `rust-slcan`, `rust-socketcan`.
    pub fn path(&self) -> &'static str {
        self.path
    }

    /// Open the device here (its failure is the caller's error) and start the thread. A reader
    /// runs once: a stopped reader is not restarted (build a new one).
    pub fn start(&mut self) -> Result<(), String> {
        if self.thread.is_some() {
            return Ok(());
        }
        let (Some(mut source), Some(target)) = (self.source.take(), self.target.take()) else {
            return Err("this reader already ran; build a new one".to_string());
        };
        if let Err(e) = source.open() {
            self.source = Some(source);
            self.target = Some(target);
            return Err(e);
        }
        set_stats(&self.shared, |s| s.state = "streaming");
        let shared = Arc::clone(&self.shared);
        let config = self.config.clone();
        let name = format!("force-{}", self.path);
        let thread = std::thread::Builder::new()
            .name(name)
            .spawn(move || {
                let mut worker = Worker::new(source, config, target, shared);
                worker.run();
                worker.source
            })
            .map_err(|e| format!("cannot start the sensor thread: {e}"))?;
        self.thread = Some(thread);
        Ok(())
    }

    pub fn stop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            if let Ok(mut source) = thread.join() {
                source.close();
            }
        }
        set_stats(&self.shared, |s| s.state = "stopped");
    }

    pub fn running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Let samples through to the loop (before, they feed only a tare; counted).
    pub fn open_gate(&self) {
        self.shared.gate_open.store(true, Ordering::Release);
    }

    pub fn set_stale_after_ns(&self, ns: u64) {
        self.shared.stale_after_ns.store(ns, Ordering::Relaxed);
    }

    pub fn set_bias(&self, bias: [f64; 6]) -> Result<(), String> {
        if bias.iter().any(|b| !b.is_finite()) {
            return Err(format!("a bias has 6 finite values, got {bias:?}"));
        }
        if let Ok(mut b) = self.shared.bias.lock() {
            *b = bias;
        }
        Ok(())
    }

    pub fn bias(&self) -> [f64; 6] {
        self.shared.bias.lock().map(|b| *b).unwrap_or([0.0; 6])
    }

    pub fn stats(&self) -> ReaderStats {
        self.shared.stats.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// The events since the last call, oldest first.
    pub fn take_events(&self) -> Vec<(&'static str, String)> {
        self.shared.events.lock().map(|mut q| q.drain(..).collect()).unwrap_or_default()
    }

    /// The captured samples since the last call (`Target::Capture` only).
    pub fn take_captured(&self) -> Vec<ForceSample> {
        self.shared.capture.lock().map(|mut c| std::mem::take(&mut *c)).unwrap_or_default()
    }

    /// The next `n` raw samples (bias not removed), waiting up to `timeout`: a tare's data.
    pub fn collect_raw(&self, n: usize, timeout: Duration) -> Vec<[f64; 6]> {
        let n = n.min(MAX_TARE);
        let Ok(mut slot) = self.shared.tare.lock() else { return Vec::new() };
        *slot = Some(TareRequest { wanted: n, rows: Vec::with_capacity(n) });
        let deadline = std::time::Instant::now() + timeout;
        while slot.as_ref().is_some_and(|t| t.rows.len() < t.wanted) {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                break;
            }
            match self.shared.tare_done.wait_timeout(slot, left) {
                Ok((s, _)) => slot = s,
                Err(_) => return Vec::new(),
            }
        }
        slot.take().map(|t| t.rows).unwrap_or_default()
    }
}

impl Drop for Reader {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The first and last sample counters among `records` (None: no sample).
fn sample_counters(records: &[Record]) -> Option<(u16, u16)> {
    let mut counters = records.iter().filter_map(|r| match r {
        Record::Sample(s) => Some(s.counter),
        _ => None,
    });
    let first = counters.next()?;
    Some((first, counters.next_back().unwrap_or(first)))
}

fn set_stats(shared: &Shared, f: impl FnOnce(&mut ReaderStats)) {
    if let Ok(mut s) = shared.stats.lock() {
        f(&mut s);
    }
}

struct Worker {
    source: Box<dyn Source>,
    target: Target,
    shared: Arc<Shared>,
    parser: Parser,
    converter: Converter,
    stats: ReaderStats,
    describe: String,
    backoff_ns: u64,
    last_arrival_ns: u64,
    last_batch_ns: u64,
    /// The counter of the last sample read (the start of the next gap).
    last_counter: u16,
    buf: Vec<u8>,
    records: Vec<Record>,
    batch: Vec<[f64; 6]>,
}

impl Worker {
    fn new(source: Box<dyn Source>, config: ReaderConfig, target: Target, shared: Arc<Shared>) -> Worker {
        // Checked in Reader::new; a failure here would be a bug, so fall back to a neutral scale.
        let converter = Converter::new(&config.counts_per_unit, config.axes, config.sensor_index, config.saturation)
            .unwrap_or_else(|_| Converter::new(&[1.0; 3], 3, 0, Saturation::Hold).expect("a 3-axis unit converter is valid"));
        let describe = source.describe();
        let mut stats = ReaderStats { state: "streaming", ..ReaderStats::default() };
        let request = RtRequest {
            policy: if config.rt_priority > 0 { Policy::Fifo } else { Policy::Other },
            priority: config.rt_priority,
            lock_memory: false,
            cpu: None,
        };
        let (report, warnings) = sched::apply_to_current_thread(&request);
        stats.thread_policy = report.policy;
        stats.thread_priority = report.priority;
        stats.thread_warnings = warnings;
        let now = monotonic_ns();
        Worker {
            source, target, shared, parser: Parser::default(), converter, stats, describe,
            backoff_ns: RECONNECT_FIRST_NS, last_arrival_ns: now, last_batch_ns: 0, last_counter: 0, buf: Vec::with_capacity(8192),
            records: Vec::with_capacity(256), batch: Vec::with_capacity(256),
        }
    }

    fn stopping(&self) -> bool {
        self.shared.stop.load(Ordering::Acquire)
    }

    fn run(&mut self) {
        self.publish();
        while !self.stopping() {
            self.buf.clear();
            let mut buf = std::mem::take(&mut self.buf);
            let read = self.source.read(&mut buf, READ_TIMEOUT_US);
            match read {
                Ok(()) => {
                    if !buf.is_empty() {
                        self.handle(&buf);
                    }
                    self.buf = buf;
                    self.watch_staleness();
                }
                Err(e) => {
                    self.buf = buf;
                    self.lost(&e);
                    self.reopen();
                }
            }
            self.publish();
        }
    }

    fn handle(&mut self, data: &[u8]) {
        let t_ns = monotonic_ns();
        let (samples, overloads, faults) = (self.parser.stats.samples, self.converter.stats.overloads, self.converter.stats.status_faults);
        let mut records = std::mem::take(&mut self.records);
        let mut batch = std::mem::take(&mut self.batch);
        records.clear();
        batch.clear();
        self.parser.feed(data, |r| records.push(r));
        let counters = sample_counters(&records);
        for record in &records {
            match *record {
                Record::Sample(sample) => match self.converter.convert(&sample) {
                    Converted::Force(f) | Converted::SaturatedForce(f) => batch.push(f),
                    Converted::Held(_) => {}
                },
                Record::Ack(code) if code != 0 => {
                    self.converter.stats.ack_errors += 1;
                    self.event("ack_error", format!("OptoForce DAQ rejected the configuration packet (ack code {code})"));
                }
                _ => {}
            }
        }
        self.emit(&batch, t_ns);
        (self.records, self.batch) = (records, batch);
        if let (true, Some((first, last))) = (self.parser.stats.samples != samples, counters) {
            self.arrived(t_ns, first, last);
        }
        if self.converter.stats.overloads != overloads {
            let note = self.converter.saturation_note();
            self.event("saturated", format!("{}: {note}", self.describe));
        }
        if self.converter.stats.status_faults != faults {
            let status = self.converter.stats.last_fault_status;
            self.event("status_fault", format!("{}: the DAQ reports an error (status 0x{status:04X}); those samples are dropped", self.describe));
        }
    }

    fn emit(&mut self, vectors: &[[f64; 6]], t_ns: u64) {
        let bias = self.shared.bias.lock().map(|b| *b).unwrap_or([0.0; 6]);
        for raw in vectors {
            self.collect_for_tare(raw);
            let mut forces = [0.0; 6];
            for ((f, r), b) in forces.iter_mut().zip(raw).zip(bias) {
                *f = r - b;
            }
            let sample = ForceSample { t_ns, forces };
            let pushed = if !self.shared.gate_open.load(Ordering::Acquire) {
                self.stats.dropped_before_open += 1;
                true
            } else {
                match &self.target {
                    Target::Loop(sink) => sink.push(sample),
                    Target::Capture => self.capture(sample),
                }
            };
            if pushed {
                self.stats.samples_pushed += 1;
            } else {
                self.stats.samples_dropped += 1;
            }
            self.stats.last_sample_ns = t_ns;
        }
    }

    fn capture(&self, sample: ForceSample) -> bool {
        match self.shared.capture.lock() {
            Ok(mut c) if c.len() < MAX_CAPTURE => {
                c.push(sample);
                true
            }
            _ => false,
        }
    }

    fn collect_for_tare(&self, raw: &[f64; 6]) {
        let Ok(mut slot) = self.shared.tare.try_lock() else { return };
        if let Some(t) = slot.as_mut() {
            if t.rows.len() < t.wanted {
                t.rows.push(*raw);
                if t.rows.len() >= t.wanted {
                    self.shared.tare_done.notify_all();
                }
            }
        }
    }

    /// Samples came at `t_ns`, counters `first..=last`.
    fn arrived(&mut self, t_ns: u64, first: u16, last: u16) {
        let gap = t_ns.saturating_sub(self.last_batch_ns);
        if self.last_batch_ns != 0 && gap > self.stats.max_gap_ns {
            self.stats.max_gap_ns = gap;
            self.stats.max_gap = GapAt { end_ns: t_ns, counter_before: self.last_counter, counter_after: first };
        }
        self.last_batch_ns = t_ns;
        self.last_counter = last;
        self.stats.batches += 1;
        self.last_arrival_ns = t_ns;
        self.backoff_ns = RECONNECT_FIRST_NS;
        if self.stats.stale {
            self.stats.stale = false;
            self.event("fresh", format!("{}: samples flow again", self.describe));
        }
    }

    fn watch_staleness(&mut self) {
        let silent_ns = monotonic_ns().saturating_sub(self.last_arrival_ns);
        if !self.stats.stale && silent_ns > self.shared.stale_after_ns.load(Ordering::Relaxed) {
            self.stats.stale = true;
            self.stats.stale_events += 1;
            self.event("stale", format!("{}: no samples for {:.2} s; the joints hold", self.describe, silent_ns as f64 * 1e-9));
        }
    }

    fn lost(&mut self, e: &io::Error) {
        let text = format!("OSError: {e}");
        self.stats.error = Some(text.clone());
        self.stats.last_error = Some(text.clone());
        self.stats.disconnects += 1;
        self.stats.state = "reconnecting";
        self.event("disconnected", format!("{} failed ({text}); reopening it with backoff, the joints hold meanwhile", self.describe));
        self.source.close();
        self.parser.reset();
        self.last_batch_ns = 0; // a gap across an unplug is not the reader's gap
        self.publish();
    }

    /// Reopen with backoff until it works or the reader is stopped.
    fn reopen(&mut self) {
        loop {
            if !self.sleep_unless_stopped(self.backoff_ns) {
                return;
            }
            self.backoff_ns = (2 * self.backoff_ns).min(RECONNECT_MAX_NS);
            match self.source.open() {
                Ok(()) => {
                    self.stats.reconnects += 1;
                    self.stats.error = None;
                    self.stats.state = "streaming";
                    self.last_arrival_ns = monotonic_ns();
                    let n = self.stats.disconnects;
                    self.event("reconnected", format!("{} is back after {n} disconnection(s)", self.describe));
                    return;
                }
                Err(e) => {
                    self.stats.reopen_failures += 1;
                    self.stats.last_error = Some(e.clone());
                    self.event("reopen_failed", format!("{} is still gone: {e}", self.describe));
                    self.publish();
                }
            }
        }
    }

    /// False when a stop came first.
    fn sleep_unless_stopped(&self, ns: u64) -> bool {
        let end = monotonic_ns() + ns;
        while !self.stopping() {
            let now = monotonic_ns();
            if now >= end {
                return true;
            }
            std::thread::sleep(Duration::from_nanos((end - now).min(10_000_000)));
        }
        false
    }

    fn event(&self, kind: &'static str, message: String) {
        if let Ok(mut q) = self.shared.events.lock() {
            if q.len() >= MAX_EVENTS {
                q.pop_front(); // the Python side counts by kind; a flood keeps the newest
            }
            q.push_back((kind, message));
        }
    }

    fn publish(&mut self) {
        self.stats.parser = self.parser.stats;
        self.stats.converter = self.converter.stats;
        self.stats.can = self.source.can_stats();
        if let Ok(mut s) = self.shared.stats.lock() {
            s.clone_from(&self.stats);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optoforce::encode_sample;
    use std::sync::atomic::AtomicUsize;

    /// A scripted device: serves `frames` once per read, fails the read when `fail` is set, and
    /// refuses `refusals` reopens.
    struct Scripted {
        frame: Vec<u8>,
        fail: Arc<AtomicBool>,
        refusals: Arc<AtomicUsize>,
        silent: Arc<AtomicBool>,
    }

    impl Source for Scripted {
        fn open(&mut self) -> Result<(), String> {
            if self.refusals.load(Ordering::SeqCst) > 0 {
                self.refusals.fetch_sub(1, Ordering::SeqCst);
                return Err("no such device".into());
            }
            Ok(())
        }
        fn read(&mut self, out: &mut Vec<u8>, _timeout_us: u64) -> io::Result<()> {
            std::thread::sleep(Duration::from_millis(1));
            if self.fail.swap(false, Ordering::SeqCst) {
                return Err(io::Error::other("EIO"));
            }
            if !self.silent.load(Ordering::SeqCst) {
                out.extend_from_slice(&self.frame);
            }
            Ok(())
        }
        fn close(&mut self) {}
        fn describe(&self) -> String {
            "optoforce sensor on scripted".into()
        }
        fn path(&self) -> &'static str {
            "rust-test"
        }
    }

    fn wait_for(reader: &Reader, what: impl Fn(&ReaderStats) -> bool) -> ReaderStats {
        for _ in 0..2000 {
            let s = reader.stats();
            if what(&s) {
                return s;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        panic!("timed out; stats {:?}", reader.stats());
    }

    fn scripted() -> (Scripted, Arc<AtomicBool>, Arc<AtomicUsize>, Arc<AtomicBool>) {
        let (fail, refusals, silent) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicUsize::new(0)), Arc::new(AtomicBool::new(false)));
        let frame = encode_sample(0, 0, &[452, 0, 0]).unwrap_or_default();
        (Scripted { frame, fail: fail.clone(), refusals: refusals.clone(), silent: silent.clone() }, fail, refusals, silent)
    }

    fn config() -> ReaderConfig {
        ReaderConfig { counts_per_unit: vec![452.0; 3], axes: 3, sensor_index: 0, saturation: Saturation::Hold, rt_priority: 0, stale_after_ns: 30_000_000 }
    }

    #[test]
    fn a_failed_device_is_reopened_with_backoff_and_told_once_each() {
        let (source, fail, refusals, _) = scripted();
        let mut reader = Reader::new(Box::new(source), config(), Target::Capture).unwrap();
        reader.start().unwrap();
        wait_for(&reader, |s| s.samples_pushed > 5);
        refusals.store(2, Ordering::SeqCst);
        fail.store(true, Ordering::SeqCst);
        let s = wait_for(&reader, |s| s.reconnects == 1 && s.samples_pushed > 20);
        assert_eq!((s.disconnects, s.reopen_failures, s.state), (1, 2, "streaming"));
        let kinds: Vec<&str> = reader.take_events().iter().map(|e| e.0).collect();
        assert_eq!(kinds.iter().filter(|k| **k == "disconnected").count(), 1);
        assert_eq!(kinds.iter().filter(|k| **k == "reopen_failed").count(), 2);
        assert_eq!(kinds.iter().filter(|k| **k == "reconnected").count(), 1);
        let got = reader.take_captured();
        assert!((got[0].forces[0] - 1.0).abs() < 1e-12);
        reader.stop();
    }

    /// Serves two frames a read (counters k, k+1), pauses before frame `pause_at`, and is silent
    /// after `last`.
    struct Counting {
        k: u16,
        pause_at: u16,
        last: u16,
    }

    impl Source for Counting {
        fn open(&mut self) -> Result<(), String> {
            Ok(())
        }
        fn read(&mut self, out: &mut Vec<u8>, _timeout_us: u64) -> io::Result<()> {
            std::thread::sleep(Duration::from_millis(if self.k == self.pause_at { 300 } else { 1 }));
            for _ in 0..2 {
                if self.k <= self.last {
                    out.extend_from_slice(&encode_sample(self.k, 0, &[452, 0, 0]).unwrap_or_default());
                    self.k += 1;
                }
            }
            Ok(())
        }
        fn close(&mut self) {}
        fn describe(&self) -> String {
            "optoforce sensor on counting".into()
        }
        fn path(&self) -> &'static str {
            "rust-test"
        }
    }

    #[test]
    fn the_longest_gap_is_located_by_time_and_frame_counters() {
        let source = Counting { k: 0, pause_at: 10, last: 13 };
        let mut reader = Reader::new(Box::new(source), ReaderConfig { stale_after_ns: 10_000_000_000, ..config() }, Target::Capture).unwrap();
        reader.start().unwrap();
        let s = wait_for(&reader, |s| s.samples_pushed == 14);
        reader.stop();
        let got = reader.take_captured();
        assert_eq!((s.max_gap.counter_before, s.max_gap.counter_after), (9, 10), "the pause was between frames 9 and 10 (reads 8-9, 10-11)");
        assert_eq!(s.max_gap.end_ns, got[10].t_ns, "ended by the read that brought frame 10");
        assert_eq!(s.max_gap_ns, got[10].t_ns - got[9].t_ns);
    }

    #[test]
    fn silence_is_stale_once_then_fresh_and_the_gate_holds_samples_back() {
        let (source, _, _, silent) = scripted();
        let mut reader = Reader::new(Box::new(source), config(), Target::Capture).unwrap();
        reader.start().unwrap();
        wait_for(&reader, |s| s.samples_pushed > 2);
        silent.store(true, Ordering::SeqCst);
        wait_for(&reader, |s| s.stale);
        std::thread::sleep(Duration::from_millis(100)); // many more silent reads: still one event
        silent.store(false, Ordering::SeqCst);
        let s = wait_for(&reader, |s| !s.stale);
        assert_eq!(s.stale_events, 1);
        let kinds: Vec<&str> = reader.take_events().iter().map(|e| e.0).collect();
        assert_eq!(kinds, vec!["stale", "fresh"]);
        let rows = reader.collect_raw(5, Duration::from_secs(5));
        assert_eq!(rows.len(), 5);
        reader.set_bias([1.0, 0.0, 0.0, 0.0, 0.0, 0.0]).unwrap();
        assert!(reader.set_bias([f64::NAN; 6]).is_err());
        reader.stop();
    }
}
