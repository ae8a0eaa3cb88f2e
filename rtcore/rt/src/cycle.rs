//! One cycle of the loop, top to bottom, each step a named method (like ros2's
//! admittance_controller `update_and_write_commands`):
//!
//! 1. `adopt_params` / `advance_ramp`: a new parameter set applies between cycles, whole; the
//!    gains then ramp linearly from their current values over `ramp_time_s`. Linear, because
//!    the stability bound h·B/I < 1 is linear in (I, B): every point of a ramp between two
//!    accepted sets is itself stable. The position state is never touched, so nothing jumps.
//! 2. `take_force`: drain the sample ring to the newest sample (stale check, tare feed).
//! 3. `condition_force`: bias, deadband, low-pass.
//! 4. `step_joints`: torque = force[axis] × lever_arm, one admittance step with limited state,
//!    or a hold (velocity zero, no integration) while the force is stale.
//! 5. `write_goals`: one SyncWrite of every goal tick; the latency of a new sample is measured
//!    to the end of this write.
//! 6. `read_present`: every `sync_read_divisor` cycles, with a deadline inside the period.
//! 7. `publish`: telemetry records and counters.
//!
//! Bus errors are counted and the cycle goes on: the next cycle writes fresh goals anyway.
use crate::bus::{BusError, JointBus, Transport};
use crate::clock::Clock;
use crate::filter::{deadband, LowPass, TareAverager};
use crate::joint::{integrate, user_torque, TickMap};
use crate::params::{JointGains, Limits, LoopParams, SensorParams};
use crate::sensor::{ForceIntake, Intake};
use crate::shared::Shared;
use crate::telemetry::{LoopStats, Record};
use plant::State;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// How a joint is wired: its servo ID, its force axis, its tick mapping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointWiring {
    pub id: u8,
    /// 0..6: fx, fy, fz, tx, ty, tz.
    pub axis: usize,
    pub ticks: TickMap,
}

struct JointSlot {
    wiring: JointWiring,
    state: State,
    limits: Limits,
    ramp_from: JointGains,
    ramp_to: JointGains,
    gains: JointGains,
    force: f64,
    torque: f64,
    present: i64,
}

/// The fixed inputs of a controller.
pub struct ControllerParts {
    pub rate_hz: f64,
    pub joints: Vec<JointWiring>,
    pub initial: LoopParams,
    pub bus: JointBus,
    pub sync_read_divisor: u64,
    pub force_ring: rtrb::Consumer<crate::sensor::ForceSample>,
    pub params: triple_buffer::Output<LoopParams>,
    pub telemetry: rtrb::Producer<Record>,
    pub shared: Arc<Shared>,
}

pub struct Controller {
    h: f64,
    period_ns: u64,
    joints: Vec<JointSlot>,
    goals: Vec<i64>,
    ramp_progress: f64,
    ramp_time_s: f64,
    sensor: SensorParams,
    lowpass: LowPass,
    tare: TareAverager,
    bias: [f64; 6],
    bias_generation: u64,
    intake: ForceIntake,
    params: triple_buffer::Output<LoopParams>,
    bus: JointBus,
    sync_read_divisor: u64,
    cycle: u64,
    latency_from_ns: Option<u64>,
    telemetry: rtrb::Producer<Record>,
    shared: Arc<Shared>,
}

impl Controller {
    pub fn new(parts: ControllerParts) -> Self {
        let h = 1.0 / parts.rate_hz;
        let p = &parts.initial;
        let joints = parts
            .joints
            .iter()
            .zip(&p.joints)
            .map(|(wiring, jp)| JointSlot {
                wiring: *wiring,
                state: State::default(),
                limits: jp.limits,
                ramp_from: jp.gains,
                ramp_to: jp.gains,
                gains: jp.gains,
                force: 0.0,
                torque: 0.0,
                present: -1,
            })
            .collect::<Vec<_>>();
        let mut lowpass = LowPass::default();
        lowpass.configure(p.sensor.lowpass_hz, h);
        parts.shared.publish_bias(&p.bias);
        Controller {
            h,
            period_ns: (1e9 / parts.rate_hz).round() as u64,
            goals: vec![0; joints.len()],
            joints,
            ramp_progress: 1.0,
            ramp_time_s: p.ramp_time_s,
            sensor: p.sensor,
            lowpass,
            tare: TareAverager::default(),
            bias: p.bias,
            bias_generation: p.bias_generation,
            intake: ForceIntake::new(parts.force_ring),
            params: parts.params,
            bus: parts.bus,
            sync_read_divisor: parts.sync_read_divisor,
            cycle: 0,
            latency_from_ns: None,
            telemetry: parts.telemetry,
            shared: parts.shared,
        }
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Bumpless start: the model starts where each servo is, so the first goal is no jump.
    /// With `enable_torque`, the goals are first set to the present positions and only then is
    /// torque enabled, so a servo never lunges towards a goal left over from before.
    pub fn start_at_present(&mut self, t: &mut dyn Transport, deadline_ns: u64, enable_torque: bool) -> Result<(), BusError> {
        let ticks = self.bus.read_present(t, deadline_ns)?;
        for ((slot, goal), &tick) in self.joints.iter_mut().zip(self.goals.iter_mut()).zip(ticks) {
            slot.state = State { theta: slot.wiring.ticks.theta_of(tick), omega: 0.0 };
            slot.present = tick;
            *goal = tick;
        }
        if enable_torque {
            self.bus.write_goals(t, &self.goals)?;
            self.bus.set_torque(t, true)?;
        }
        Ok(())
    }

    /// Marks the loop's start for the stale clock (no sample yet counts from here).
    pub fn begin(&mut self, now_ns: u64) {
        self.intake.start(now_ns);
    }

    /// The model states, in joint order (θ, ω).
    pub fn states(&self) -> impl Iterator<Item = State> + '_ {
        self.joints.iter().map(|j| j.state)
    }

    /// The current (ramped) gains, in joint order.
    pub fn gains(&self) -> impl Iterator<Item = JointGains> + '_ {
        self.joints.iter().map(|j| j.gains)
    }

    /// Runs the cycle whose deadline was `deadline_ns`.
    pub fn run_cycle<C: Clock + ?Sized>(&mut self, t: &mut dyn Transport, clock: &C, deadline_ns: u64) {
        let wake_ns = clock.now_ns();
        self.adopt_params();
        self.advance_ramp();
        let intake = self.take_force(wake_ns);
        let force = self.condition_force(&intake.newest.forces);
        self.step_joints(&force, intake.stale);
        let written = self.write_goals(t);
        let latency_ns = self.measure_latency(&intake, written, clock.now_ns());
        let read = self.read_present(t, deadline_ns + self.period_ns - self.period_ns / 10);
        self.publish(wake_ns, wake_ns.saturating_sub(deadline_ns), latency_ns, read);
        self.shared.stats.work.record(clock.now_ns().saturating_sub(wake_ns));
    }

    fn adopt_params(&mut self) {
        if !self.params.updated() {
            return;
        }
        let p = self.params.read();
        for (slot, jp) in self.joints.iter_mut().zip(&p.joints) {
            slot.ramp_from = slot.gains;
            slot.ramp_to = jp.gains;
            slot.limits = jp.limits;
        }
        self.ramp_progress = 0.0;
        self.ramp_time_s = p.ramp_time_s;
        self.sensor = p.sensor;
        self.lowpass.configure(p.sensor.lowpass_hz, self.h);
        if p.bias_generation != self.bias_generation {
            self.bias_generation = p.bias_generation;
            self.bias = p.bias;
            self.shared.publish_bias(&self.bias);
        }
    }

    fn advance_ramp(&mut self) {
        if self.ramp_progress >= 1.0 {
            return;
        }
        self.ramp_progress = if self.ramp_time_s > 0.0 {
            (self.ramp_progress + self.h / self.ramp_time_s).min(1.0)
        } else {
            1.0
        };
        for slot in &mut self.joints {
            slot.gains = slot.ramp_from.lerp(&slot.ramp_to, self.ramp_progress);
        }
    }

    fn take_force(&mut self, now_ns: u64) -> Intake {
        let requested = self.shared.tare_request.swap(0, Ordering::Relaxed);
        if requested > 0 {
            self.tare.request(requested);
        }
        let timeout_ns = (self.sensor.stale_timeout_ms * 1e6) as u64;
        let (intake, tared) = self.intake.take(now_ns, timeout_ns, &mut self.tare);
        if let Some(bias) = tared {
            self.bias = bias;
            self.shared.publish_bias(&bias);
        }
        LoopStats::add(&self.shared.stats.sensor_samples, intake.drained);
        if intake.became_stale {
            LoopStats::add(&self.shared.stats.sensor_stale_events, 1);
        }
        intake
    }

    fn condition_force(&mut self, raw: &[f64; 6]) -> [f64; 6] {
        let mut f = [0.0; 6];
        for (k, v) in f.iter_mut().enumerate() {
            *v = deadband(raw[k] - self.bias[k], self.sensor.deadband);
        }
        self.lowpass.apply(&f)
    }

    fn step_joints(&mut self, force: &[f64; 6], hold: bool) {
        for (slot, goal) in self.joints.iter_mut().zip(self.goals.iter_mut()) {
            slot.force = force[slot.wiring.axis];
            slot.torque = user_torque(force, slot.wiring.axis, &slot.gains);
            if hold {
                slot.state.omega = 0.0;
            } else {
                integrate(&mut slot.state, &slot.gains, &slot.limits, slot.torque, self.h);
            }
            *goal = slot.wiring.ticks.goal_tick(slot.state.theta);
        }
    }

    fn write_goals(&mut self, t: &mut dyn Transport) -> bool {
        let ok = self.bus.write_goals(t, &self.goals).is_ok();
        if !ok {
            LoopStats::add(&self.shared.stats.bus_errors, 1);
        }
        ok
    }

    /// The latency of the sample that this write used first; −1 when there is none.
    fn measure_latency(&mut self, intake: &Intake, written: bool, now_ns: u64) -> i64 {
        if intake.new_arrival {
            self.latency_from_ns = Some(intake.newest.t_ns);
        }
        if intake.stale {
            self.latency_from_ns = None;
        }
        match (written, self.latency_from_ns) {
            (true, Some(arrival)) => {
                self.latency_from_ns = None;
                let latency = now_ns.saturating_sub(arrival);
                self.shared.stats.latency.record(latency);
                latency as i64
            }
            _ => -1,
        }
    }

    /// Reads the present positions when due; true if this cycle read them.
    fn read_present(&mut self, t: &mut dyn Transport, deadline_ns: u64) -> bool {
        if self.sync_read_divisor == 0 || !self.cycle.is_multiple_of(self.sync_read_divisor) {
            return false;
        }
        match self.bus.read_present(t, deadline_ns) {
            Ok(ticks) => {
                for (slot, &tick) in self.joints.iter_mut().zip(ticks) {
                    slot.present = tick;
                }
                LoopStats::add(&self.shared.stats.sync_reads, 1);
                true
            }
            Err(_) => {
                LoopStats::add(&self.shared.stats.bus_errors, 1);
                false
            }
        }
    }

    fn publish(&mut self, wake_ns: u64, period_error_ns: u64, latency_ns: i64, read: bool) {
        let stats = &self.shared.stats;
        for (slot, &goal) in self.joints.iter().zip(&self.goals) {
            let record = Record {
                cycle: self.cycle,
                t_ns: wake_ns,
                id: slot.wiring.id as i64,
                force: slot.force,
                torque: slot.torque,
                theta: slot.state.theta,
                omega: slot.state.omega,
                goal_tick: goal,
                present_tick: if read { slot.present } else { -1 },
                period_error_ns: period_error_ns as i64,
                latency_ns,
            };
            if self.telemetry.push(record).is_err() {
                LoopStats::add(&stats.telemetry_drops, 1);
            }
        }
        stats.period.record(period_error_ns);
        self.cycle += 1;
        LoopStats::add(&stats.cycles, 1);
    }

    /// The stop policy's last traffic: Torque Enable = 0 on every joint.
    pub fn torque_off(&mut self, t: &mut dyn Transport) -> Result<(), BusError> {
        self.bus.set_torque(t, false)
    }
}

#[cfg(test)]
#[path = "cycle_tests.rs"]
pub(crate) mod tests;
