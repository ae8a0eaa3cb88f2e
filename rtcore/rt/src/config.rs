//! The loop's configuration: every key, its default, and the checks that need the whole set.
//!
//! The Python supervisor fills the register addresses from the model table; the defaults here
//! are the ones every supported model shares (MX-28/64/106, XM430-W350, XL330-M288: Protocol 2.0
//! goal 116/4, present 132/4, torque enable 64; MX Protocol 1.0 goal 30/2, present 36/2, torque
//! enable 24), so a bare configuration works on the usual bench. Gains default to the MX-64's
//! fitted plant (thesis table 3.3) so that the joint feels like the passive servo.
use crate::bus::{ReadChoice, Registers};
use crate::cycle::JointWiring;
use crate::joint::TickMap;
use crate::passivity::PassivityParams;
use crate::params::{JointGains, JointParams, Limits, LoopParams, Reach, SensorParams};
use crate::recovery::FaultPolicy;
use crate::sched::RtRequest;
use crate::trigger::TriggerMode;
use dxl::Protocol;

#[derive(Debug, Clone, PartialEq)]
pub struct JointConfig {
    pub id: u8,
    /// Free label (the model table's name), reported back.
    pub model: String,
    pub registers: Registers,
    pub ticks: TickMap,
    /// 0..6: fx, fy, fz, tx, ty, tz.
    pub axis: usize,
    pub gains: JointGains,
    pub limits: Limits,
    /// The servo's tracking dynamics (the parameter file's `[servo]`), if identified.
    pub servo: Option<plant::servo::ServoModel>,
    /// Weight of the servo compensation in [0, 1]; needs `servo`.
    pub compensation: f64,
    /// The passivity guard's settings (`passivity`).
    pub passivity: PassivityParams,
}

impl JointConfig {
    /// A joint with every default for `protocol`: position limits = the tick range.
    pub fn new(id: u8, protocol: Protocol) -> Self {
        let registers = match protocol {
            Protocol::V2 => Registers { goal_address: 116, goal_size: 4, present_address: 132, present_size: 4, torque_enable_address: 64 },
            Protocol::V1 => Registers { goal_address: 30, goal_size: 2, present_address: 36, present_size: 2, torque_enable_address: 24 },
        };
        let ticks = TickMap { zero_tick: 2048, direction: 1, ticks_per_rev: 4096.0, tick_min: 0, tick_max: 4095 };
        let (position_min, position_max) = ticks.theta_range();
        JointConfig {
            id,
            model: "MX-64".into(),
            registers,
            ticks,
            axis: 0,
            gains: JointGains { inertia: 0.01467, damping: 0.03471, coulomb: 0.08426, lever_arm: 0.1 },
            limits: Limits { position_min, position_max, velocity_max: 6.0, acceleration_max: 200.0 },
            servo: None,
            compensation: 0.0,
            passivity: PassivityParams::default(),
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct LoopConfig {
    pub port: String,
    pub baudrate: u32,
    pub protocol: Protocol,
    /// How the present positions are read (`[bus] read`).
    pub bus_read: ReadChoice,
    pub rate_hz: f64,
    pub rt: RtRequest,
    /// What starts a cycle: a force sample's arrival (default) or the fixed schedule.
    pub trigger: TriggerMode,
    pub joints: Vec<JointConfig>,
    /// Read present positions every N cycles; 0 = never.
    pub sync_read_divisor: u64,
    pub sensor: SensorParams,
    pub ramp_time_s: f64,
    pub bias: [f64; 6],
    /// Force samples the ring holds between two cycles.
    pub force_capacity: usize,
    /// Telemetry records (one per joint per cycle) held until Python drains them.
    pub telemetry_capacity: usize,
    /// How long `start` waits for the servos' present positions.
    pub start_timeout_ms: f64,
    /// `start` sets each goal to the present position, then enables torque.
    pub torque_on_start: bool,
    /// What the loop does about servo and bus faults (`recovery`).
    pub faults: FaultPolicy,
}

impl Default for LoopConfig {
    fn default() -> Self {
        LoopConfig {
            port: String::new(),
            baudrate: 1_000_000,
            protocol: Protocol::V2,
            bus_read: ReadChoice::default(),
            rate_hz: 1000.0,
            rt: RtRequest::default(),
            trigger: TriggerMode::default(),
            joints: Vec::new(),
            sync_read_divisor: 10,
            sensor: SensorParams { deadband: 0.0, lowpass_hz: 0.0, stale_timeout_ms: 50.0 },
            ramp_time_s: 0.5,
            bias: [0.0; 6],
            force_capacity: 4096,
            telemetry_capacity: 1 << 16,
            start_timeout_ms: 200.0,
            torque_on_start: true,
            faults: FaultPolicy::default(),
        }
    }
}

impl LoopConfig {
    /// Every joint's model (on this protocol) answers Fast Sync Read (`dxl::models`).
    pub fn models_have_fast_sync_read(&self) -> bool {
        let has = |j: &JointConfig| dxl::models::find_by_name(&j.model, self.protocol).is_some_and(|m| m.fast_sync_read());
        self.joints.iter().all(has)
    }

    pub fn ids(&self) -> Vec<u8> {
        self.joints.iter().map(|j| j.id).collect()
    }

    /// Each joint's id and the angles its goal range reaches, in joint order (what the
    /// position limits are checked against).
    pub fn reach(&self) -> Vec<Reach> {
        self.joints
            .iter()
            .map(|j| {
                let (theta_min, theta_max) = j.ticks.theta_range();
                Reach { id: j.id, theta_min, theta_max }
            })
            .collect()
    }

    pub fn initial_params(&self) -> LoopParams {
        LoopParams {
            joints: self
                .joints
                .iter()
                .map(|j| JointParams {
                    gains: j.gains,
                    limits: j.limits,
                    servo: j.servo,
                    compensation: j.compensation,
                    passivity: j.passivity,
                })
                .collect(),
            sensor: self.sensor,
            ramp_time_s: self.ramp_time_s,
            bias: self.bias,
            bias_generation: 0,
        }
    }

    pub fn wiring(&self) -> Vec<JointWiring> {
        self.joints.iter().map(|j| JointWiring { id: j.id, axis: j.axis, ticks: j.ticks }).collect()
    }

    /// The shared registers (checked equal across joints by `validate`).
    pub fn registers(&self) -> Registers {
        self.joints[0].registers
    }

    /// Everything that must hold before a loop is built; the error says which key and why.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.rate_hz.is_finite() && self.rate_hz >= 1.0 && self.rate_hz <= 20_000.0) {
            return Err(format!("rate_hz must be in [1, 20000], got {}", self.rate_hz));
        }
        if self.joints.is_empty() {
            return Err("joints: at least one joint is needed".into());
        }
        if !(1..=99).contains(&self.rt.priority) && self.rt.policy == crate::sched::Policy::Fifo {
            return Err(format!("rt_priority must be in 1..=99 for SCHED_FIFO (0 = SCHED_OTHER), got {}", self.rt.priority));
        }
        if self.force_capacity == 0 || self.telemetry_capacity == 0 {
            return Err("force_capacity and telemetry_capacity must be > 0".into());
        }
        if !(self.start_timeout_ms.is_finite() && self.start_timeout_ms > 0.0) {
            return Err(format!("start_timeout_ms must be > 0, got {}", self.start_timeout_ms));
        }
        self.faults.validate()?;
        if self.bus_read == ReadChoice::Fast && !self.models_have_fast_sync_read() {
            return Err("bus_read \"fast\" needs Protocol 2.0 and models that have Fast Sync Read (every joint's); \
                        \"auto\" uses it where they do"
                .into());
        }
        let ids = self.ids();
        for (k, j) in self.joints.iter().enumerate() {
            validate_joint(j, self.protocol).map_err(|e| format!("joints[{k}] (id {}): {e}", j.id))?;
            if ids[..k].contains(&j.id) {
                return Err(format!("joints[{k}]: id {} appears twice", j.id));
            }
            if j.registers != self.joints[0].registers {
                return Err(format!(
                    "joints[{k}] (id {}): registers {:?} differ from joint {}'s {:?}; one SyncWrite and one \
                     SyncRead address every joint, so they must be equal",
                    j.id, j.registers, self.joints[0].id, self.joints[0].registers
                ));
            }
        }
        self.initial_params().validate(&self.reach(), self.rate_hz)
    }
}

fn validate_joint(j: &JointConfig, protocol: Protocol) -> Result<(), String> {
    if j.id > 252 {
        return Err(format!("id must be 0..=252, got {}", j.id));
    }
    if j.axis > 5 {
        return Err(format!("axis must be one of x, y, z, tx, ty, tz (0..=5), got {}", j.axis));
    }
    let r = &j.registers;
    for (name, size) in [("goal_size", r.goal_size), ("present_size", r.present_size)] {
        if ![1, 2, 4].contains(&size) {
            return Err(format!("{name} must be 1, 2 or 4 bytes, got {size}"));
        }
    }
    if protocol == Protocol::V1 {
        let widest = [r.goal_address, r.present_address, r.torque_enable_address].into_iter().max().unwrap_or(0);
        if widest > 255 {
            return Err(format!("Protocol 1.0 addresses are one byte; {widest} is too large"));
        }
    }
    let t = &j.ticks;
    if t.direction != 1 && t.direction != -1 {
        return Err(format!("direction must be 1 or -1, got {}", t.direction));
    }
    if !(t.ticks_per_rev.is_finite() && t.ticks_per_rev > 0.0) {
        return Err(format!("ticks_per_rev must be > 0, got {}", t.ticks_per_rev));
    }
    if t.tick_min >= t.tick_max {
        return Err(format!("tick_min ({}) must be below tick_max ({})", t.tick_min, t.tick_max));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(n: u8) -> LoopConfig {
        LoopConfig { joints: (1..=n).map(|id| JointConfig::new(id, Protocol::V2)).collect(), ..Default::default() }
    }

    #[test]
    fn the_defaults_are_valid() {
        assert_eq!(config(3).validate(), Ok(()));
        assert!(config(0).validate().unwrap_err().contains("at least one joint"));
    }

    #[test]
    fn fast_sync_read_is_asked_for_only_where_every_model_has_it() {
        let mut c = config(2);
        c.bus_read = ReadChoice::Fast;
        assert_eq!(c.validate(), Ok(()));
        c.joints[1].model = "a servo not in the table".into();
        assert!(c.validate().unwrap_err().contains("Fast Sync Read"));
        assert!(!c.models_have_fast_sync_read());
        c.bus_read = ReadChoice::Auto;
        assert_eq!(c.validate(), Ok(()), "auto reads with Sync Read there");
        let mut p1 = LoopConfig { protocol: Protocol::V1, joints: vec![JointConfig::new(1, Protocol::V1)], ..Default::default() };
        p1.bus_read = ReadChoice::Fast;
        assert!(p1.validate().unwrap_err().contains("Protocol 2.0"));
    }

    #[test]
    fn each_bad_key_is_named() {
        let mut c = config(2);
        c.joints[1].id = 1;
        assert!(c.validate().unwrap_err().contains("appears twice"));
        let mut c = config(2);
        c.joints[1].registers.goal_address = 30;
        assert!(c.validate().unwrap_err().contains("must be equal"));
        let mut c = config(1);
        c.joints[0].ticks.direction = 2;
        assert!(c.validate().unwrap_err().contains("direction"));
        let mut c = config(1);
        c.rate_hz = 0.0;
        assert!(c.validate().unwrap_err().contains("rate_hz"));
        let mut c = config(1);
        c.joints[0].gains.damping = 100.0;
        assert!(c.validate().unwrap_err().contains("h·B/I"));
        let mut c = config(1);
        c.protocol = Protocol::V1;
        c.joints[0].registers.goal_address = 300;
        assert!(c.validate().unwrap_err().contains("one byte"));
        c.joints[0] = JointConfig::new(1, Protocol::V1);
        assert_eq!(c.validate(), Ok(()));
    }
}
