//! The simulated bench's force sensor: an OptoForce serial DAQ on its own pty, streaming the
//! hand's torque from a thread of its own, beside the simulated bus.
//!
//! Why in Rust: the daemon's sensor reader and loop run without the GIL, so a simulated DAQ
//! written in Python (`admittance.mockbench.simulated_sensor`) became the one part of the
//! embedded bench that waited for the interpreter. On a loaded machine its samples came late
//! in bursts and the loop held the joint for want of force (issue 18: 52 stale-sensor holds in
//! 600 s with two CPU burners). A real DAQ streams on its own clock whatever the host does;
//! this thread does the same, at the bus thread's scheduling.
//!
//! Each sample, on absolute deadlines: the hand's torque τ(t) from the tabulated profile
//! (`HandProfile`; Python defines the profiles and tabulates them), applied to the hand's servo
//! (`set_external_torque`) and read back as what a sensor between hand and horn reads (the
//! profile's torque, or with a gripping hand what it transmits), then counts per axis
//! (`ForceModel`: lever arm, sensitivity, bias, seeded noise, int16 clipping with the overload
//! bit, as the DAQ does) in a sample frame. Bytes the host sends are read after each sample:
//! a configuration packet sets the rate (SPEED 0 stops the stream), tares or clears the tare,
//! and is acknowledged. If the thread falls behind it catches up with a burst, as a USB DAQ
//! delivers a backlog, and after `MAX_CATCH_UP` skips ahead instead of flooding.
//!
//! Fault modes (set from any thread, read once per sample): silence, saturation of the hand's
//! axis, status bits, garbage before the next frame, frames with a wrong checksum, and unplug /
//! replug of the pty (the stable link follows, as /dev/serial/by-id does).
//!
//! The Python streaming mocks stay the reference for the CAN outputs; a test feeds both the
//! same profile and compares their frames.

use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use forceread::optoforce::{self, Parser, Record, STATUS_OVERLOAD_MASK};
use rt::clock::{monotonic_ns, Clock, MonotonicClock};
use rt::sched::{self, Policy, RtReport, RtRequest};

use crate::pty::Pty;
use crate::server::{lock, open_linked, point_link, Shared};

/// Behind by more than this, the stream skips ahead instead of sending the backlog.
const MAX_CATCH_UP: Duration = Duration::from_millis(100);
const INT16_MAX: f64 = 32767.0;
/// Points at most in a tabulated profile (16 MB of f64 pairs): a longer one is refused.
pub const MAX_PROFILE_POINTS: usize = 1_000_000;
/// OptoForce overload flags: bit 9 (fx) down to bit 4 (tz).
const fn overload_bit(axis: usize) -> u16 {
    1 << (9 - axis)
}
const _: () = assert!(overload_bit(0) | overload_bit(5) == 0b10_0001 << 4 && STATUS_OVERLOAD_MASK == 0b11_1111 << 4);

/// The hand's torque over time: (t, τ) points, linearly interpolated; repeated every `period`
/// seconds when given, else held at its first and last values.
#[derive(Debug, Clone, PartialEq)]
pub struct HandProfile {
    t: Vec<f64>,
    tau: Vec<f64>,
    period: Option<f64>,
}

impl HandProfile {
    /// `Err` says what is wrong: no points, too many, unequal lengths, a non-finite value, a
    /// time that does not increase, a period that is not positive or shorter than the table.
    pub fn new(t: Vec<f64>, tau: Vec<f64>, period: Option<f64>) -> Result<HandProfile, String> {
        if t.is_empty() || t.len() != tau.len() {
            return Err(format!("a hand profile needs as many times as torques, at least one ({} and {})", t.len(), tau.len()));
        }
        if t.len() > MAX_PROFILE_POINTS {
            return Err(format!("a hand profile has at most {MAX_PROFILE_POINTS} points, not {}", t.len()));
        }
        if !t.iter().chain(&tau).all(|v| v.is_finite()) || t.windows(2).any(|w| w[1] <= w[0]) {
            return Err("a hand profile's values must be finite and its times increase strictly".into());
        }
        if let Some(p) = period {
            if !(p.is_finite() && p > 0.0 && t[0] >= 0.0 && *t.last().unwrap_or(&0.0) <= p + 1e-9) {
                return Err(format!("a periodic profile's period must be positive and cover its table, got {p}"));
            }
        }
        Ok(HandProfile { t, tau, period })
    }

    /// τ at `t` seconds after the stream started.
    pub fn at(&self, t: f64) -> f64 {
        let t = match self.period {
            Some(p) => t.rem_euclid(p),
            None => t,
        };
        let i = self.t.partition_point(|&x| x <= t);
        match i {
            0 => self.tau[0],
            i if i == self.t.len() => self.tau[i - 1],
            i => {
                let (t0, t1, y0, y1) = (self.t[i - 1], self.t[i], self.tau[i - 1], self.tau[i]);
                y0 + (y1 - y0) * (t - t0) / (t1 - t0)
            }
        }
    }
}

/// Hand torque → the counts the sensor on the horn reports (the Python `ForceModel`'s rule).
#[derive(Debug, Clone, PartialEq)]
pub struct ForceModel {
    /// m from the joint axis to the point the hand pushes: F = τ / lever_arm.
    pub lever_arm: f64,
    /// The axis the hand pushes along (0 x, 1 y, 2 z).
    pub axis: usize,
    /// Counts per N (forces) or per N·m (torques), 3 or 6 of them: the frame's channel count.
    pub counts_per_unit: Vec<f64>,
    pub bias_n: f64,
    pub noise_std_n: f64,
}

impl ForceModel {
    pub fn validate(&self) -> Result<(), String> {
        let finite = [self.lever_arm, self.bias_n, self.noise_std_n].iter().chain(&self.counts_per_unit).all(|v| v.is_finite());
        if !finite || self.lever_arm <= 0.0 || self.noise_std_n < 0.0 {
            return Err("the force model needs a positive lever arm and finite values, noise ≥ 0".into());
        }
        if !matches!(self.counts_per_unit.len(), 3 | 6) || self.axis > 2 {
            return Err("the force model has 3 or 6 channels and pushes along x, y or z".into());
        }
        Ok(())
    }

    /// (counts per channel, status word with the overload bits of clipped channels).
    fn counts(&self, tau: f64, noise: &mut Gaussian) -> (Vec<i16>, u16) {
        let mut status = 0;
        let counts = (self.counts_per_unit.iter().enumerate())
            .map(|(i, cpu)| {
                let force = if i == self.axis { tau / self.lever_arm } else { 0.0 };
                let bias = if i < 3 { self.bias_n } else { 0.0 };
                let value = ((force + bias + noise.sample(self.noise_std_n)) * cpu).round();
                if value.abs() > INT16_MAX || value.is_nan() {
                    status |= overload_bit(i);
                }
                value.clamp(-INT16_MAX, INT16_MAX) as i16 // NaN casts to 0
            })
            .collect();
        (counts, status)
    }

    /// The forces (N) and torques (N·m) a reader decodes from the counts of `tau` (the lockstep
    /// bench's sensor: the same quantization and noise as the stream's).
    pub(crate) fn forces(&self, tau: f64, noise: &mut Gaussian) -> [f64; 6] {
        let mut out = [0.0; 6];
        let (counts, _) = self.counts(tau, noise);
        for ((slot, count), cpu) in out.iter_mut().zip(counts).zip(&self.counts_per_unit) {
            *slot = if *cpu != 0.0 { f64::from(count) / cpu } else { 0.0 };
        }
        out
    }
}

/// Seeded Gaussian noise (splitmix64 + Box–Muller): repeatable, no dependency.
pub(crate) struct Gaussian {
    state: u64,
    spare: Option<f64>,
}

impl Gaussian {
    pub(crate) fn new(seed: u64) -> Gaussian {
        Gaussian { state: seed, spare: None }
    }

    pub(crate) fn uniform(&mut self) -> f64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn sample(&mut self, std: f64) -> f64 {
        if std == 0.0 {
            return 0.0;
        }
        if let Some(z) = self.spare.take() {
            return z * std;
        }
        let (u, v) = (1.0 - self.uniform(), self.uniform()); // u in (0, 1]: ln(u) finite
        let r = (-2.0 * u.ln()).sqrt();
        self.spare = Some(r * (std::f64::consts::TAU * v).sin());
        r * (std::f64::consts::TAU * v).cos() * std
    }
}

/// What the DAQ is told and counts, shared with Python (every field readable at any time).
#[derive(Default)]
pub struct DaqState {
    pub silent: AtomicBool,
    pub saturated: AtomicBool,
    pub fault_status: AtomicU32,
    garbage: AtomicU32,
    corrupt: AtomicU32,
    pub samples_sent: AtomicU64,
    pub samples_dropped: AtomicU64,
    pub configs_received: AtomicU64,
    pub late_skips: AtomicU64,
    pub faulty_frames: AtomicU64,
    /// The longest time between two frames written one after the other (ns): the source's own
    /// gap, to set beside the reader's (a stop, a silence or a dropped frame starts afresh).
    pub max_write_gap_ns: AtomicU64,
    /// f64 bits: samples per second (0 once the host stopped the stream).
    rate_hz: AtomicU64,
    /// f64 bits: the torque the sensor read at the last sample.
    last_torque: AtomicU64,
    /// f64 bits: the stream's time (s) at which the hand starts its profile; until then it
    /// keeps off the joint (+∞: not yet told). 0 by default.
    hand_from: AtomicU64,
    /// f64 bits: the stream's time (s) at its last sample.
    now: AtomicU64,
}

impl DaqState {
    pub fn rate_hz(&self) -> f64 {
        f64::from_bits(self.rate_hz.load(Ordering::Relaxed))
    }

    pub fn streaming(&self) -> bool {
        self.rate_hz() > 0.0
    }

    pub fn last_torque(&self) -> f64 {
        f64::from_bits(self.last_torque.load(Ordering::Relaxed))
    }

    /// The hand keeps off the joint until `start_hand` (the daemon tares its sensor first).
    pub fn hold_hand(&self) {
        self.hand_from.store(f64::INFINITY.to_bits(), Ordering::Relaxed);
    }

    /// The hand starts its profile (from its beginning) `delay` seconds from now.
    pub fn start_hand(&self, delay: f64) {
        let now = f64::from_bits(self.now.load(Ordering::Relaxed));
        self.hand_from.store((now + delay.max(0.0)).to_bits(), Ordering::Relaxed);
    }

    /// The torque the hand applies at stream time `t`.
    fn hand_torque(&self, profile: &HandProfile, t: f64) -> f64 {
        self.now.store(t.to_bits(), Ordering::Relaxed);
        let from = f64::from_bits(self.hand_from.load(Ordering::Relaxed));
        if t >= from { profile.at(t - from) } else { 0.0 }
    }

    /// `n` bytes of noise (never a header byte) before the next frame.
    pub fn inject_garbage(&self, n: u32) {
        self.garbage.store(n, Ordering::Relaxed);
    }

    /// The next `n` frames go out with a wrong checksum.
    pub fn corrupt(&self, n: u32) {
        self.corrupt.store(n, Ordering::Relaxed);
    }
}

/// The DAQ's end of its USB cable: the pty while plugged in, and the stable link to it.
struct DaqPort {
    pty: Option<Pty>,
    path: String,
    link: Option<PathBuf>,
    /// The tail of a frame the full pty did not take: finished before anything new goes out.
    backlog: Vec<u8>,
    unplugs: u64,
    replugs: u64,
}

impl DaqPort {
    /// Sends one whole frame; false if it had to be dropped (pty full, or unplugged).
    fn send(&mut self, frame: &[u8]) -> bool {
        let Some(pty) = &self.pty else { return false };
        if !self.backlog.is_empty() {
            let n = pty.write(&self.backlog).unwrap_or(0);
            self.backlog.drain(..n);
            if !self.backlog.is_empty() {
                return false;
            }
        }
        // A frame cut short by a full pty is finished before anything new goes out; a frame
        // that does not fit at all is dropped (a DAQ's USB buffer overflowing).
        let n = pty.write(frame).unwrap_or(0);
        if n > 0 {
            self.backlog.extend_from_slice(&frame[n..]);
        }
        n > 0
    }

    fn receive(&mut self, buf: &mut [u8]) -> usize {
        self.pty.as_ref().map_or(0, |pty| pty.read(buf).unwrap_or(0))
    }
}

/// What the stream needs besides its port: the profile, the sensor, the servo the hand holds.
pub struct DaqConfig {
    pub profile: HandProfile,
    pub model: ForceModel,
    pub hand_servo: u8,
    pub rate_hz: f64,
    pub seed: u64,
    /// SCHED_FIFO priority of the stream's thread (0: SCHED_OTHER), as the bus thread's.
    pub rt_priority: i32,
}

/// A simulated OptoForce DAQ on a pty, streaming from its own thread between `start` and `stop`.
pub struct SimulatedDaq {
    port: Arc<Mutex<DaqPort>>,
    profile: Arc<Mutex<HandProfile>>,
    state: Arc<DaqState>,
    stop: Arc<AtomicBool>,
    thread: Mutex<Option<JoinHandle<()>>>,
    stream: Mutex<Option<Stream>>,
    report: Arc<Mutex<(RtReport, Vec<String>)>>,
}

impl SimulatedDaq {
    /// Opens the pty; the stream starts with `start`. `servos` is the simulated bus's state
    /// (`MockBus::servos`): the hand pushes on `config.hand_servo` there.
    pub fn new(config: DaqConfig, servos: Arc<Mutex<Shared>>) -> Result<SimulatedDaq, String> {
        config.model.validate()?;
        if !(config.rate_hz > 0.0 && config.rate_hz <= 10_000.0) {
            return Err(format!("the simulated DAQ's rate must be in (0, 10000] Hz, got {}", config.rate_hz));
        }
        if !(0..=99).contains(&config.rt_priority) {
            return Err(format!("rt_priority {} is outside 0..=99", config.rt_priority));
        }
        if lock(&servos).bus.servo_mut(config.hand_servo).is_none() {
            return Err(format!("the hand pushes on servo {}, which is not on the bus", config.hand_servo));
        }
        let pty = Pty::open().map_err(|e| format!("cannot open the simulated sensor's pty: {e}"))?;
        let port = DaqPort { path: pty.path().to_string(), pty: Some(pty), link: None, backlog: Vec::new(), unplugs: 0, replugs: 0 };
        let state = DaqState::default();
        state.rate_hz.store(config.rate_hz.to_bits(), Ordering::Relaxed);
        let noise = Gaussian::new(config.seed);
        // The profile moves into the mutex `set_profile` replaces: no second copy (up to 16 MB).
        let DaqConfig { profile, model, hand_servo, rt_priority, .. } = config;
        let profile = Arc::new(Mutex::new(profile));
        let stream = Stream {
            profile: profile.clone(), model, hand_servo, servos, noise, parser: Parser::default(), tare: None,
            last_counts: Vec::new(), counter: 0, rt_priority, last_write_ns: 0,
        };
        Ok(SimulatedDaq {
            port: Arc::new(Mutex::new(port)),
            profile,
            state: Arc::new(state),
            stop: Arc::new(AtomicBool::new(false)),
            thread: Mutex::new(None),
            stream: Mutex::new(Some(stream)),
            report: Arc::new(Mutex::new((RtReport::default(), Vec::new()))),
        })
    }

    pub fn state(&self) -> &DaqState {
        &self.state
    }

    /// A new profile for the hand, on the same time base (the stream's clock, as before).
    pub fn set_profile(&self, profile: HandProfile) {
        *lock(&self.profile) = profile;
    }

    /// The pty a host opens now (a new one after each replug; the last one while unplugged).
    pub fn port_path(&self) -> String {
        lock(&self.port).path.clone()
    }

    pub fn link_path(&self) -> Option<PathBuf> {
        lock(&self.port).link.clone()
    }

    pub fn is_plugged(&self) -> bool {
        lock(&self.port).pty.is_some()
    }

    /// (unplugs, replugs) so far.
    pub fn plug_counts(&self) -> (u64, u64) {
        let port = lock(&self.port);
        (port.unplugs, port.replugs)
    }

    /// Makes `link` a symlink to the pty, kept pointing at it across replugs, removed while
    /// unplugged and when the DAQ is dropped.
    pub fn set_link(&self, link: &Path) -> io::Result<()> {
        let mut port = lock(&self.port);
        if port.pty.is_some() {
            point_link(link, &port.path)?;
        }
        port.link = Some(link.to_path_buf());
        Ok(())
    }

    /// Pulls the cable: the pty closes (a host's descriptor hangs up), the link goes.
    pub fn unplug(&self) -> bool {
        let mut port = lock(&self.port);
        if port.pty.take().is_none() {
            return false;
        }
        port.backlog.clear();
        if let Some(link) = &port.link {
            let _ = std::fs::remove_file(link);
        }
        port.unplugs += 1;
        true
    }

    /// Puts it back: a new pty, the link pointed at it.
    pub fn replug(&self) -> io::Result<bool> {
        let mut port = lock(&self.port);
        if port.pty.is_some() {
            return Ok(false);
        }
        let pty = open_linked(port.link.as_deref())?;
        port.path = pty.path().to_string();
        port.pty = Some(pty);
        port.replugs += 1;
        Ok(true)
    }

    /// Starts the stream's thread (once: a stopped DAQ stays stopped, as its ptys are closed).
    pub fn start(&self) -> io::Result<()> {
        let Some(mut stream) = lock(&self.stream).take() else { return Ok(()) };
        let (port, state, stop, report) = (self.port.clone(), self.state.clone(), self.stop.clone(), self.report.clone());
        let handle = std::thread::Builder::new()
            .name("dxlsim-daq".into())
            .spawn(move || stream.run(&port, &state, &stop, &report))?;
        *lock(&self.thread) = Some(handle);
        Ok(())
    }

    pub fn stop(&self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(handle) = lock(&self.thread).take() {
            let _ = handle.join();
        }
    }

    /// Stops the stream and closes its pty and link for good.
    pub fn close(&self) {
        self.stop();
        let mut port = lock(&self.port);
        port.pty = None;
        if let Some(link) = port.link.take() {
            let _ = std::fs::remove_file(link);
        }
    }

    /// The scheduling the thread obtained, and its warnings (empty before `start`).
    pub fn scheduling(&self) -> (RtReport, Vec<String>) {
        lock(&self.report).clone()
    }
}

impl Drop for SimulatedDaq {
    fn drop(&mut self) {
        self.close();
    }
}

/// The thread's own state.
struct Stream {
    /// The hand's profile: `SimulatedDaq::set_profile` may replace it while the stream runs.
    profile: Arc<Mutex<HandProfile>>,
    model: ForceModel,
    hand_servo: u8,
    servos: Arc<Mutex<Shared>>,
    noise: Gaussian,
    parser: Parser,
    tare: Option<Vec<i16>>,
    last_counts: Vec<i16>,
    counter: u16,
    rt_priority: i32,
    /// When the last frame went out (0: the last tick wrote none).
    last_write_ns: u64,
}

impl Stream {
    fn run(&mut self, port: &Mutex<DaqPort>, state: &DaqState, stop: &AtomicBool, report: &Mutex<(RtReport, Vec<String>)>) {
        let policy = if self.rt_priority > 0 { Policy::Fifo } else { Policy::Other };
        let request = RtRequest { policy, priority: self.rt_priority, lock_memory: false, cpu: None };
        let (obtained, warnings) = sched::apply_to_current_thread(&request);
        *lock(report) = (obtained, warnings.into_iter().map(|w| format!("simulated sensor thread: {w}")).collect());
        let mut clock = MonotonicClock;
        let t0 = monotonic_ns();
        let mut deadline = t0;
        let mut buf = [0u8; 512];
        while !stop.load(Ordering::SeqCst) {
            let now = clock.now_ns();
            if deadline > now {
                clock.sleep_until(deadline);
            } else if now - deadline > MAX_CATCH_UP.as_nanos() as u64 {
                state.late_skips.fetch_add(1, Ordering::Relaxed);
                deadline = now;
            }
            self.tick((deadline - t0) as f64 * 1e-9, port, state);
            let n = lock(port).receive(&mut buf);
            self.handle_host_bytes(&buf[..n], port, state); // after the tick: a tare takes the load just sampled
            let rate = state.rate_hz();
            // A stopped stream still keeps its clock (at 1 kHz) to read the host's packets.
            deadline += (1e9 / if rate > 0.0 { rate } else { 1000.0 }) as u64;
        }
    }

    fn tick(&mut self, t: f64, port: &Mutex<DaqPort>, state: &DaqState) {
        let tau = state.hand_torque(&lock(&self.profile), t);
        let sensed = self.push_hand(tau);
        state.last_torque.store(sensed.to_bits(), Ordering::Relaxed);
        let (mut counts, mut status) = self.model.counts(sensed, &mut self.noise);
        self.last_counts.clone_from(&counts);
        if !state.streaming() || state.silent.load(Ordering::Relaxed) {
            self.last_write_ns = 0;
            return;
        }
        if let Some(tare) = &self.tare {
            counts.iter_mut().zip(tare).for_each(|(c, z)| *c = c.saturating_sub(*z));
        }
        status |= state.fault_status.load(Ordering::Relaxed) as u16;
        if state.saturated.load(Ordering::Relaxed) {
            let i = self.model.axis;
            counts[i] = if counts[i] >= 0 { INT16_MAX as i16 } else { -INT16_MAX as i16 };
            status |= overload_bit(i);
        }
        let Some(frame) = optoforce::encode_sample(self.counter, status, &counts) else {
            self.last_write_ns = 0;
            return;
        };
        self.counter = self.counter.wrapping_add(1);
        let frame = self.faulty(frame, state);
        let sent = lock(port).send(&frame);
        self.note_write(sent, state);
        let counter = if sent { &state.samples_sent } else { &state.samples_dropped };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// The source's own gap: the time between this frame's write and the previous one's.
    fn note_write(&mut self, sent: bool, state: &DaqState) {
        let now = if sent { monotonic_ns() } else { 0 };
        if now != 0 && self.last_write_ns != 0 {
            state.max_write_gap_ns.fetch_max(now - self.last_write_ns, Ordering::Relaxed);
        }
        self.last_write_ns = now;
    }

    /// Applies τ to the hand's servo; what the sensor reads (τ, or what a gripping hand transmits).
    fn push_hand(&self, tau: f64) -> f64 {
        let mut shared = lock(&self.servos);
        match shared.bus.servo_mut(self.hand_servo) {
            Some(servo) => {
                servo.set_external_torque(tau);
                servo.snapshot().hand_torque
            }
            None => tau,
        }
    }

    /// Garbage before the frame, or a wrong checksum, while those faults are pending.
    fn faulty(&mut self, mut frame: Vec<u8>, state: &DaqState) -> Vec<u8> {
        let take = |slot: &AtomicU32, n: u32| slot.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |v| Some(v.saturating_sub(n)));
        if take(&state.corrupt, 1).is_ok_and(|before| before > 0) {
            state.faulty_frames.fetch_add(1, Ordering::Relaxed);
            if let Some(last) = frame.last_mut() {
                *last ^= 0x5A;
            }
        }
        let garbage = state.garbage.swap(0, Ordering::Relaxed);
        if garbage > 0 {
            // No 0xAA in the noise: it must not be able to start a frame of its own.
            let mut noise: Vec<u8> = (0..garbage).map(|_| (self.noise.uniform() * f64::from(optoforce::HEADER_BYTE)) as u8).collect();
            noise.append(&mut frame);
            frame = noise;
        }
        frame
    }

    fn handle_host_bytes(&mut self, data: &[u8], port: &Mutex<DaqPort>, state: &DaqState) {
        let mut configs = Vec::new();
        self.parser.feed(data, |record| {
            if let Record::Config { speed, zero, .. } = record {
                configs.push((speed, zero));
            }
        });
        for (speed, zero) in configs {
            state.configs_received.fetch_add(1, Ordering::Relaxed);
            // SPEED is the sample period in ms; 0 stops the stream.
            let rate = if speed == 0 { 0.0 } else { 1000.0 / f64::from(speed) };
            state.rate_hz.store(rate.to_bits(), Ordering::Relaxed);
            match zero {
                255 => self.tare = Some(self.last_counts.clone()),
                0 => self.tare = None,
                _ => {}
            }
            lock(port).send(&optoforce::encode_ack(0));
        }
    }
}

#[cfg(test)]
#[path = "daq_tests.rs"]
mod tests;
