//! A loop seen from outside: build it from a configuration, start it, steer it, stop it.
//!
//! Every method takes `&self` and is safe to call from any (non-RT) thread: the parts the RT
//! thread owns were moved into it at `start`; what is left here are the producer ends (force
//! ring behind a mutex only Python threads take, the triple buffer's input), the telemetry
//! consumer and the shared atomics.
//!
//! `start` reads every servo's present position first (bumpless start), then spawns the thread
//! and waits until it has applied its real-time settings, so `stats()["rt"]` and `warnings()`
//! are already meaningful when `start` returns. A failed start gives the controller back, so
//! `start` may be retried.
use crate::bus::{BusError, JointBus, Transport};
use crate::clock::{monotonic_ns, MonotonicClock};
use crate::config::LoopConfig;
use crate::cycle::{Controller, ControllerParts, StartRefusal};
use crate::doorbell::{ArrivalEstimator, Doorbell};
use crate::fault::Faults;
use crate::params::{LoopParams, ParamValue, Reach};
use crate::recovery::StopRequest;
use crate::port::SerialTransport;
use crate::sched;
use crate::sensor::ForceSample;
use crate::shared::{ServoSnapshot, Shared};
use crate::telemetry::{Record, StatsSnapshot};
use crate::trigger::{TriggerMode, TriggerSnapshot};
use std::fmt;
use std::sync::atomic::Ordering;
use std::sync::{mpsc, Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

/// What `stop` does to the servos.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopPolicy {
    /// The last goal stays: the servos hold where the model was.
    Hold,
    /// Torque Enable = 0 on every joint (one SyncWrite).
    TorqueOff,
}

#[derive(Debug)]
pub enum StartError {
    AlreadyStarted,
    /// The serial device could not be opened.
    Port(String),
    /// The servos did not report their present positions.
    NoAnswer(String),
    /// A servo's position could not be trusted (`anchor`): torque stays off.
    Position(String),
    Thread(String),
}

impl fmt::Display for StartError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StartError::AlreadyStarted => write!(f, "the loop was already started; build a new one to run again"),
            StartError::Port(e) | StartError::NoAnswer(e) | StartError::Position(e) | StartError::Thread(e) => f.write_str(e),
        }
    }
}

impl std::error::Error for StartError {}

/// The force-sample producer handed to sensor readers. A push puts the sample in the ring and
/// rings the loop's doorbell, which starts the cycle when the loop waits for a sample.
#[derive(Clone)]
pub struct ForceSink {
    inner: Arc<Mutex<SinkState>>,
    bell: Arc<Doorbell>,
}

struct SinkState {
    ring: rtrb::Producer<ForceSample>,
    arrivals: ArrivalEstimator,
}

impl ForceSink {
    pub(crate) fn new(ring: rtrb::Producer<ForceSample>, bell: Arc<Doorbell>) -> Self {
        ForceSink { inner: Arc::new(Mutex::new(SinkState { ring, arrivals: ArrivalEstimator::default() })), bell }
    }

    /// A sample the loop can use: finite forces (a NaN would reach the goal tick, and a NaN goal
    /// is a jump to the end of the range) stamped on CLOCK_MONOTONIC (a wall-clock stamp lies in
    /// the far future, so the sample would never go stale).
    pub fn check(sample: &ForceSample) -> Result<(), String> {
        Self::check_at(sample, monotonic_ns())
    }

    fn check_at(sample: &ForceSample, now_ns: u64) -> Result<(), String> {
        if let Some(bad) = sample.forces.iter().find(|f| !f.is_finite()) {
            return Err(format!("forces must be finite, got {bad}"));
        }
        if sample.t_ns > now_ns + 1_000_000_000 {
            return Err(format!(
                "t_ns {} is in the future of CLOCK_MONOTONIC; stamp samples with time.monotonic_ns()",
                sample.t_ns
            ));
        }
        Ok(())
    }

    /// False when the sample is dropped: the ring is full, or the sample is invalid (see
    /// `ForceSink::check`).
    pub fn push(&self, sample: ForceSample) -> bool {
        self.push_at(sample, monotonic_ns())
    }

    /// `push` at a given CLOCK_MONOTONIC time (the tests' fake clock).
    pub(crate) fn push_at(&self, sample: ForceSample, now_ns: u64) -> bool {
        if Self::check_at(&sample, now_ns).is_err() {
            return false;
        }
        let Ok(mut state) = self.inner.lock() else { return false };
        if state.ring.push(sample).is_err() {
            return false;
        }
        if let Some(timing) = state.arrivals.observe(now_ns) {
            self.bell.publish(timing);
        }
        drop(state); // the wake-up syscall need not hold up other pushers
        self.bell.ring();
        true
    }
}

struct ParamsWriter {
    input: triple_buffer::Input<LoopParams>,
    current: LoopParams,
}

type Running = JoinHandle<(Controller, Box<dyn Transport>)>;

pub struct LoopHandle {
    config: LoopConfig,
    ids: Vec<u8>,
    reach: Vec<Reach>,
    shared: Arc<Shared>,
    params: Mutex<ParamsWriter>,
    sink: ForceSink,
    bell: Arc<Doorbell>,
    telemetry: Mutex<rtrb::Consumer<Record>>,
    idle: Mutex<Option<Controller>>,
    thread: Mutex<Option<Running>>,
}

impl LoopHandle {
    /// Validates the configuration and builds every buffer the loop will use.
    pub fn new(config: LoopConfig) -> Result<LoopHandle, String> {
        config.validate()?;
        let shared = Arc::new(Shared::for_joints(config.joints.len()));
        let initial = config.initial_params();
        let (force_tx, force_rx) = rtrb::RingBuffer::new(config.force_capacity);
        let (telemetry_tx, telemetry_rx) = rtrb::RingBuffer::new(config.telemetry_capacity);
        let (params_in, params_out) = triple_buffer::triple_buffer(&initial);
        let ids = config.ids();
        let bell = Arc::new(Doorbell::default());
        let mut bus = JointBus::new(config.protocol, config.registers(), &ids);
        bus.choose_read(config.bus_read, config.models_have_fast_sync_read());
        let mut controller = Controller::new(ControllerParts {
            rate_hz: config.rate_hz,
            joints: config.wiring(),
            initial: initial.clone(),
            bus,
            sync_read_divisor: config.sync_read_divisor,
            force_ring: force_rx,
            params: params_out,
            telemetry: telemetry_tx,
            shared: shared.clone(),
        });
        controller.set_fault_policy(config.faults, config.torque_on_start);
        Ok(LoopHandle {
            ids,
            reach: config.reach(),
            shared,
            params: Mutex::new(ParamsWriter { input: params_in, current: initial }),
            sink: ForceSink::new(force_tx, bell.clone()),
            bell,
            telemetry: Mutex::new(telemetry_rx),
            idle: Mutex::new(Some(controller)),
            thread: Mutex::new(None),
            config,
        })
    }

    pub fn config(&self) -> &LoopConfig {
        &self.config
    }

    /// The present-position read the start settled on, for the stats and the start line; a
    /// line when `auto` had to fall back.
    fn note_bus_read(&self, bus: &JointBus) {
        if let Ok(mut read) = self.shared.link.read.lock() {
            *read = bus.read_name();
        }
        if bus.fell_back() {
            self.shared.warn(
                "Fast Sync Read went unanswered at start (a firmware without it?): the loop reads with Sync Read".into(),
            );
        }
    }

    /// Opens the configured serial port and starts the loop on it.
    pub fn start(&self) -> Result<(), StartError> {
        if self.running() {
            return Err(StartError::AlreadyStarted);
        }
        // A write may wait one period for room; longer would make the next deadline late anyway.
        let write_timeout_ns = (1e9 / self.config.rate_hz) as u64;
        let link = self.shared.link.clone();
        let (transport, warnings) = SerialTransport::open(&self.config.port, self.config.baudrate, write_timeout_ns, link)
            .map_err(|e| StartError::Port(format!("cannot open the Dynamixel bus: {e}")))?;
        warnings.into_iter().for_each(|w| self.shared.warn(w));
        self.start_with(Box::new(transport))
    }

    /// Starts the loop on any transport (the tests' in-memory bus, a serial port).
    pub fn start_with(&self, mut transport: Box<dyn Transport>) -> Result<(), StartError> {
        let mut idle = self.idle.lock().map_err(|_| StartError::Thread("loop state poisoned".into()))?;
        let mut controller = idle.take().ok_or(StartError::AlreadyStarted)?;
        if let Ok(mut kind) = self.shared.link.kind.lock() {
            *kind = transport.kind();
        }
        let deadline = monotonic_ns() + (self.config.start_timeout_ms * 1e6) as u64;
        let started = controller.start_at_present(transport.as_mut(), &MonotonicClock, deadline, self.config.torque_on_start);
        self.note_bus_read(controller.bus());
        if let Err(refusal) = started {
            *idle = Some(controller);
            return Err(match refusal {
                StartRefusal::Bus(e) => StartError::NoAnswer(self.no_answer_message(&e)),
                StartRefusal::Position(why) => StartError::Position(why),
            });
        }
        let (ready_tx, ready_rx) = mpsc::channel();
        let shared = self.shared.clone();
        let bell = self.bell.clone();
        let (request, trigger) = (self.config.rt, self.config.trigger);
        let spawned = std::thread::Builder::new()
            .name("admittance-rt".into())
            .spawn(move || rt_thread(controller, transport, RtThread { shared, bell, request, trigger }, ready_tx));
        let handle = spawned.map_err(|e| StartError::Thread(format!("cannot spawn the loop thread: {e}")))?;
        ready_rx
            .recv_timeout(Duration::from_secs(5))
            .map_err(|_| StartError::Thread("the loop thread did not come up within 5 s".into()))?;
        *self.thread.lock().map_err(|_| StartError::Thread("loop state poisoned".into()))? = Some(handle);
        Ok(())
    }

    fn no_answer_message(&self, e: &BusError) -> String {
        format!(
            "no present position from servo id(s) {:?} on '{}' within {} ms ({e}); check power, \
             IDs, baud rate ({}) and protocol ({})",
            self.ids,
            self.config.port,
            self.config.start_timeout_ms,
            self.config.baudrate,
            self.config.protocol.number()
        )
    }

    /// Stops the loop and applies `policy`; a no-op when it is not running.
    pub fn stop(&self, policy: StopPolicy) -> Result<(), String> {
        let handle = self.thread.lock().map_err(|_| "loop state poisoned".to_string())?.take();
        let Some(handle) = handle else { return Ok(()) };
        self.shared.stop.store(true, Ordering::Relaxed);
        self.bell.wake(); // a loop waiting for a sample sees the stop at once
        let (mut controller, mut transport) = handle.join().map_err(|_| "the loop thread panicked".to_string())?;
        if self.shared.stats.rt.lock().map(|r| r.memory_locked).unwrap_or(false) {
            sched::release_memory_lock();
        }
        match policy {
            StopPolicy::Hold => Ok(()),
            StopPolicy::TorqueOff => controller
                .torque_off(transport.as_mut())
                .map_err(|e| format!("torque off failed on '{}': {e}", self.config.port)),
        }
    }

    pub fn force_sink(&self) -> ForceSink {
        self.sink.clone()
    }

    /// Validates `changes` as a whole against the current set; publishes all of them or none.
    pub fn set_params(&self, changes: &[(String, ParamValue)]) -> Result<(), String> {
        let mut writer = self.params.lock().map_err(|_| "parameter state poisoned".to_string())?;
        let mut candidate = writer.current.clone();
        for (name, value) in changes {
            candidate.set(&self.ids, name, *value)?;
        }
        candidate.validate(&self.reach, self.config.rate_hz)?;
        if candidate.bias_generation != writer.current.bias_generation {
            // Visible in params() at once, even before (or without) a running loop adopting it.
            self.shared.publish_bias(&candidate.bias);
        }
        writer.input.write(candidate.clone());
        writer.current = candidate;
        Ok(())
    }

    /// The accepted parameters (the gains' ramp targets), with the bias the loop uses now.
    /// The parameters as the loop runs them: the last accepted set, with the bias the loop
    /// subtracts and, while it runs, each joint's limits as the loop adopted them (a set
    /// accepted but not yet adopted shows its old limits). A loop not started runs nothing yet:
    /// it adopts the accepted set as it starts.
    pub fn params(&self) -> LoopParams {
        let mut p = self.params.lock().map(|w| w.current.clone()).unwrap_or_else(|e| e.into_inner().current.clone());
        p.bias = self.shared.bias();
        if !self.running() {
            return p;
        }
        for (k, joint) in p.joints.iter_mut().enumerate() {
            if let Some(limits) = self.shared.adopted_limits(k) {
                joint.limits = limits;
            }
        }
        p
    }

    pub fn ids(&self) -> &[u8] {
        &self.ids
    }

    /// Asks the loop to average the next `samples` force samples into the bias.
    pub fn tare(&self, samples: u32) {
        self.shared.tare_request.store(samples.max(1), Ordering::Relaxed);
    }

    /// Moves every queued telemetry record into `out`.
    pub fn drain_telemetry(&self, out: &mut Vec<Record>) {
        if let Ok(mut rx) = self.telemetry.lock() {
            out.reserve(rx.slots());
            while let Ok(r) = rx.pop() {
                out.push(r);
            }
        }
    }

    pub fn stats(&self) -> StatsSnapshot {
        self.shared.stats.snapshot(self.config.rate_hz)
    }

    /// How the cycles started (sample arrivals, the schedule), and the sensor timing seen.
    pub fn trigger_stats(&self) -> (TriggerMode, TriggerSnapshot) {
        (self.config.trigger, self.shared.trigger.snapshot())
    }

    pub fn warnings(&self) -> Vec<String> {
        self.shared.warnings()
    }

    /// Cycles so far: a watchdog checks that it advances.
    pub fn heartbeat(&self) -> u64 {
        self.shared.stats.cycles.load(Ordering::Relaxed)
    }

    pub fn running(&self) -> bool {
        self.shared.running.load(Ordering::Relaxed)
    }

    /// The loop's request to be stopped: a fault its policy does not recover from.
    pub fn stop_request(&self) -> Option<StopRequest> {
        self.shared.stop_request()
    }

    /// Per joint: its servo's recovery.
    pub fn servos(&self) -> Vec<ServoSnapshot> {
        self.shared.servos.iter().map(|s| s.snapshot()).collect()
    }

    /// Per joint: its passivity guard (`passivity`).
    pub fn passivity(&self) -> Vec<crate::passivity::PassivityView> {
        self.shared.passivity.iter().map(|s| s.snapshot()).collect()
    }

    /// The bus link: (lost for how long in ns or None, losses, reconnects, reopen attempts,
    /// reopen failures, the last error).
    pub fn link(&self) -> LinkSnapshot {
        let l = &self.shared.link;
        let since = l.lost_since_ns.load(Ordering::Relaxed);
        LinkSnapshot {
            lost_for_ns: (since != 0).then(|| monotonic_ns().saturating_sub(since)),
            losses: l.losses.load(Ordering::Relaxed),
            loss_errno: l.loss_errno.load(Ordering::Relaxed),
            reconnects: l.reconnects.load(Ordering::Relaxed),
            reopen_attempts: l.reopen_attempts.load(Ordering::Relaxed),
            reopen_failures: l.reopen_failures.load(Ordering::Relaxed),
            last_error: l.last_error(),
            kind: l.kind.lock().map(|k| *k).unwrap_or_default(),
            read: l.read.lock().map(|r| *r).unwrap_or_default(),
        }
    }

    /// Raises the faults that only an outside observer sees (the sensor's: `FaultKind::EXTERNAL`)
    /// for the cycles from now on; the records mark them.
    pub fn set_external_faults(&self, faults: Faults) {
        self.shared.external_faults.set(faults);
    }
}

/// The bus link as `LoopHandle::link` reports it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkSnapshot {
    pub lost_for_ns: Option<u64>,
    pub losses: u64,
    pub loss_errno: i32,
    pub reconnects: u64,
    pub reopen_attempts: u64,
    pub reopen_failures: u64,
    pub last_error: String,
    /// The transport (`Transport::kind`; empty before the first start).
    pub kind: &'static str,
    /// The present-position read (`JointBus::read_name`; empty before the first start).
    pub read: &'static str,
}

impl Drop for LoopHandle {
    fn drop(&mut self) {
        let _ = self.stop(StopPolicy::Hold);
    }
}

/// What the loop thread takes along besides its controller and bus.
struct RtThread {
    shared: Arc<Shared>,
    bell: Arc<Doorbell>,
    request: sched::RtRequest,
    trigger: TriggerMode,
}

fn rt_thread(
    mut controller: Controller,
    mut transport: Box<dyn Transport>,
    RtThread { shared, bell, request, trigger }: RtThread,
    ready: mpsc::Sender<()>,
) -> (Controller, Box<dyn Transport>) {
    sched::prefault_stack();
    let (report, warnings) = sched::apply_to_current_thread(&request);
    warnings.into_iter().for_each(|w| shared.warn(w));
    if let Ok(mut rt) = shared.stats.rt.lock() {
        *rt = report;
    }
    let running = RunningFlag::raise(&shared);
    let _ = ready.send(());
    crate::runner::run(&mut controller, transport.as_mut(), &mut MonotonicClock, &shared, &bell, trigger, || true);
    drop(running);
    (controller, transport)
}

/// `running` is true exactly while the loop thread is in its loop, even if it unwinds.
struct RunningFlag<'a>(&'a Shared);

impl<'a> RunningFlag<'a> {
    fn raise(shared: &'a Shared) -> Self {
        shared.running.store(true, Ordering::Relaxed);
        RunningFlag(shared)
    }
}

impl Drop for RunningFlag<'_> {
    fn drop(&mut self) {
        self.0.running.store(false, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::memory::MemoryTransport;
    use crate::config::JointConfig;
    use crate::sched::{Policy, RtRequest};
    use dxl::Protocol;

    fn handle(ids: &[u8]) -> LoopHandle {
        let config = LoopConfig {
            port: "memory".into(),
            joints: ids.iter().map(|&id| JointConfig::new(id, Protocol::V2)).collect(),
            rt: RtRequest { policy: Policy::Other, priority: 0, lock_memory: false, cpu: None },
            ..Default::default()
        };
        LoopHandle::new(config).unwrap()
    }

    #[test]
    fn a_set_with_one_bad_value_changes_nothing() {
        let h = handle(&[1, 2]);
        let before = h.params();
        let changes = [
            ("1.virtual_damping".to_string(), ParamValue::Scalar(0.2)),
            ("deadband".to_string(), ParamValue::Scalar(1.0)),
            ("2.virtual_inertia".to_string(), ParamValue::Scalar(-1.0)),
        ];
        let reason = h.set_params(&changes).unwrap_err();
        assert!(reason.contains("joint 2") && reason.contains("inertia"), "{reason}");
        assert_eq!(h.params(), before);
        let unstable = [("virtual_damping".to_string(), ParamValue::Scalar(50.0))];
        assert!(h.set_params(&unstable).unwrap_err().contains("h·B/I"));
        assert_eq!(h.params(), before);
        h.set_params(&changes[..2]).unwrap();
        let after = h.params();
        assert_eq!(after.joints[0].gains.damping, 0.2);
        assert_eq!(after.joints[1].gains.damping, before.joints[1].gains.damping);
        assert_eq!(after.sensor.deadband, 1.0);
    }

    #[test]
    fn the_sink_drops_non_finite_samples() {
        let sink = handle(&[1]).force_sink();
        assert!(!sink.push(ForceSample { t_ns: 1, forces: [f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0] }));
        assert!(sink.push(ForceSample { t_ns: 2, forces: [1.0; 6] }));
        let wall_clock = 1_700_000_000_000_000_000;
        assert!(!sink.push(ForceSample { t_ns: wall_clock, forces: [1.0; 6] }));
    }

    #[test]
    fn a_started_loop_runs_reports_and_turns_torque_off_at_stop() {
        let h = handle(&[1]);
        let bus = MemoryTransport::new(true, &[(1, 2048)]);
        h.start_with(Box::new(bus.clone())).unwrap();
        assert!(h.running());
        assert!(matches!(h.start_with(Box::new(bus.clone())), Err(StartError::AlreadyStarted)));
        let sink = h.force_sink();
        while h.heartbeat() < 20 {
            sink.push(ForceSample { t_ns: monotonic_ns(), forces: [1.0, 0.0, 0.0, 0.0, 0.0, 0.0] });
            std::thread::sleep(Duration::from_millis(1));
        }
        h.stop(StopPolicy::TorqueOff).unwrap();
        assert!(!h.running());
        let stats = h.stats();
        assert!(stats.cycles >= 20 && stats.sensor_samples > 0);
        assert_eq!(stats.rt.policy, "SCHED_OTHER");
        let mut records = Vec::new();
        h.drain_telemetry(&mut records);
        assert_eq!(records.len() as u64, stats.cycles);
        let last = bus.written().pop().unwrap();
        assert_eq!(&last[8..12], &[64, 0, 1, 0], "SyncWrite of Torque Enable (address 64, 1 byte)");
    }

    #[test]
    fn params_report_the_limits_a_running_loop_adopted() {
        let h = handle(&[1]);
        h.start_with(Box::new(MemoryTransport::new(true, &[(1, 2048)]))).unwrap();
        let narrowed = [("1.limits.position_max".to_string(), ParamValue::Scalar(0.5))];
        h.set_params(&narrowed).unwrap();
        let sink = h.force_sink();
        let adopted_by = h.heartbeat() + 5; // the loop adopts a set at its next cycle
        let give_up = std::time::Instant::now() + Duration::from_secs(10);
        while h.heartbeat() < adopted_by && std::time::Instant::now() < give_up {
            sink.push(ForceSample { t_ns: monotonic_ns(), forces: [0.0; 6] });
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(h.params().joints[0].limits.position_max, 0.5, "what the loop adopted");
        h.stop(StopPolicy::Hold).unwrap();
    }

    #[test]
    fn a_silent_bus_fails_the_start_and_the_start_can_be_retried() {
        let h = handle(&[1, 2]);
        let silent = MemoryTransport::new(true, &[(1, 2048)]);
        let e = h.start_with(Box::new(silent)).unwrap_err().to_string();
        assert!(e.contains("[1, 2]") && e.contains("did not answer"), "{e}");
        assert!(!h.running());
        h.start_with(Box::new(MemoryTransport::new(true, &[(1, 2048), (2, 10)]))).unwrap();
        h.stop(StopPolicy::Hold).unwrap();
    }
}
