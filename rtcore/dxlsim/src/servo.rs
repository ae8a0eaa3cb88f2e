//! One simulated servo: its control table, its firmware and the horn's physics.
//!
//! Each physics substep the firmware reads its goal registers, computes a PWM duty
//! (`firmware`), the motor turns it into torque (`motor`), and the rtcore plant integrates the
//! horn with the fitted friction of that motor (`plant::step`, the same code the identification
//! and the admittance loop use) plus the external torque a hand applies. `publish` then writes
//! the present values back into the table, so a client's READ sees the simulated state.
//!
//! Hardware errors use the P2 Hardware Error Status bit layout (bit 0 input voltage, 2
//! overheating, 3 encoder, 4 electrical shock, 5 overload). P1's error byte has voltage,
//! overheating and overload at the same bit positions, so one value serves both protocols.
//! A bit in the Shutdown mask (P1: Alarm Shutdown) turns torque off and keeps it off: a write
//! of Torque Enable = 1 is taken and undone at once, until a REBOOT (P2) or until the cause is
//! gone (P1, which has no reboot).
//!
//! Silence: after a REBOOT (once its status packet is sent) and after a brown-out, the servo
//! boots for a while and neither answers nor executes anything (`is_silent`); its horn keeps
//! moving under the physics meanwhile.
use std::collections::VecDeque;

use dxl::packet::Protocol;
use plant::{FrictionLaw, Load, Params, State};

use crate::firmware::{Gains, Mode, PositionController};
use crate::hand::{follow_lag, Hand};
use crate::motor::{clip_duty, Motor, MAX_PWM};
use crate::registers::Registers;
use crate::table::{ControlTable, TableError};
use crate::units::*;

/// Hardware Error Status bit: input voltage outside the voltage limits.
pub const HW_INPUT_VOLTAGE: u8 = 0x01;
/// Hardware Error Status bit: overheating.
pub const HW_OVERHEATING: u8 = 0x04;
/// Hardware Error Status bit: overload (a persistent load above the motor's output).
pub const HW_OVERLOAD: u8 = 0x20;
/// How long a servo is silent after a REBOOT by default: an XC330 answers again after about
/// 0.4 s (ROBOTIS-GIT/emanual issue 1698); the e-manual gives no figure for MX servos.
pub const DEFAULT_REBOOT_TIME_S: f64 = 0.4;
/// The hardware bits P1's error byte can carry (voltage, overheating, overload).
pub const P1_HARDWARE_BITS: u8 = 0x25;
/// Moving threshold (rad/s) when the model has no Moving Threshold item: P2's default of
/// 10 × 0.229 rpm.
const DEFAULT_MOVING_THRESHOLD: f64 = 10.0 * P2_VELOCITY_UNIT;
/// Thermal model: winding-to-ambient resistance (K/W) and heat capacity (J/K). Illustrative
/// values giving a 300 s time constant and about a minute of stall to reach 80 °C from 25 °C.
const THERMAL_RESISTANCE: f64 = 5.0;
const HEAT_CAPACITY: f64 = 60.0;

/// Everything that defines a simulated servo besides its control-table layout (which carries
/// the model): a `setup::ServoConfig` after its defaults are resolved and its values checked.
#[derive(Clone, Debug)]
pub struct ServoSpec {
    pub id: u8,
    pub protocol: Protocol,
    pub params: Params,
    pub load: Load,
    pub friction: FrictionLaw,
    pub motor: Motor,
    pub initial_theta: f64,
    pub ambient_temperature: f64,
    /// s: the horn follows its goal as a first-order lag instead of by firmware and motor.
    pub first_order_lag: Option<f64>,
    /// Seconds a REBOOT keeps the servo silent after its status packet.
    pub reboot_time_s: f64,
    /// Seconds of stall at the duty limit before the overload bit sets (None: never).
    pub overload_time_s: Option<f64>,
    /// Its firmware answers Fast Sync Read (`setup::ServoConfig::fast_sync_read`).
    pub fast_sync_read: bool,
}

/// What Python's `servo_state` reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Snapshot {
    pub theta: f64,
    pub omega: f64,
    pub goal_tick: i64,
    pub present_tick: i64,
    pub torque_enabled: bool,
    pub duty: f64,
    pub motor_torque: f64,
    pub external_torque: f64,
    /// What a sensor between the hand and the horn reads (the external torque without a hand).
    pub hand_torque: f64,
    pub temperature: f64,
    pub hardware_error: u8,
    pub time: f64,
    /// Booting (after a REBOOT or a brown-out): no answers, no instructions executed.
    pub silent: bool,
}

/// An injected encoder glitch (`Servo::glitch_position`).
#[derive(Debug, Clone, Copy)]
struct Glitch {
    offset: i64,
    every: u32,
    since: u32,
}

pub struct Servo {
    pub spec: ServoSpec,
    pub table: ControlTable,
    reg: Registers,
    state: State,
    controller: PositionController,
    mode: Option<Mode>,
    torque_was_on: bool,
    external_torque: f64,
    duty: f64,
    motor_torque: f64,
    current: f64,
    temperature: f64,
    hardware_error: u8,
    /// Bits raised by `set_hardware_error`: their cause is the injection, so P1 keeps them
    /// until they are cleared the same way (P2 until a REBOOT).
    injected: u8,
    time: f64,
    /// A REG_WRITE waiting for ACTION: (address, data).
    pub registered: Option<(u16, Vec<u8>)>,
    /// Applied torques of the last `time_delay` seconds, oldest first (the plant's delay).
    torque_history: VecDeque<f64>,
    /// Whole turns CLEAR removed from the reported position (ticks): reported = encoder + this.
    tick_offset: i64,
    hand: Option<Hand>,
    /// Simulated time until which the servo boots (silent).
    silent_until: f64,
    /// Seconds the motor has stalled at its duty limit (the overload detector).
    stalled_s: f64,
    /// An injected encoder glitch: ticks added, every how many reads of Present Position (0:
    /// the next one only), and the reads since the last glitched one.
    glitch: Option<Glitch>,
}

impl Servo {
    /// A servo at rest at `spec.initial_theta`, its table at the model's defaults with `spec.id`.
    pub fn new(spec: ServoSpec, mut table: ControlTable) -> Servo {
        let reg = Registers::resolve(&table);
        if let Some(k) = reg.id {
            table.store(k, spec.id as i64);
        }
        let state = State { theta: spec.initial_theta, omega: 0.0 };
        let temperature = spec.ambient_temperature;
        let mut servo = Servo {
            spec,
            table,
            reg,
            state,
            controller: PositionController::default(),
            mode: None,
            torque_was_on: false,
            external_torque: 0.0,
            duty: 0.0,
            motor_torque: 0.0,
            current: 0.0,
            temperature,
            hardware_error: 0,
            injected: 0,
            time: 0.0,
            registered: None,
            torque_history: VecDeque::new(),
            tick_offset: 0,
            hand: None,
            silent_until: 0.0,
            stalled_s: 0.0,
            glitch: None,
        };
        servo.publish();
        servo.hold_present_position();
        servo
    }

    /// Goal Position := Present Position, as a servo does at power-up and after a reboot, so
    /// enabling torque holds the horn where it is.
    fn hold_present_position(&mut self) {
        if let (Some(goal), Some(present)) = (self.reg.goal_position, self.reg.present_position) {
            let tick = self.table.value(present);
            self.table.store(goal, tick);
        }
    }

    /// The ID the servo answers to now (a client may have rewritten it).
    pub fn id(&self) -> u8 {
        self.reg.id.map_or(self.spec.id, |k| self.table.value(k) as u8)
    }

    pub fn protocol(&self) -> Protocol {
        self.spec.protocol
    }

    /// 0 = reply to PING only, 1 = PING and READ, 2 = everything.
    pub fn status_return_level(&self) -> i64 {
        self.reg.status_return_level.map_or(2, |k| self.table.value(k))
    }

    /// Return Delay Time in µs (the register counts 2 µs units).
    pub fn return_delay_us(&self) -> u64 {
        self.reg.return_delay_time.map_or(0, |k| 2 * self.table.value(k).max(0) as u64)
    }

    pub fn model_number(&self) -> u16 {
        self.reg.model_number.map_or(0, |k| self.table.value(k) as u16)
    }

    pub fn firmware_version(&self) -> u8 {
        self.reg.firmware_version.map_or(0, |k| self.table.value(k) as u8)
    }

    pub fn hardware_error(&self) -> u8 {
        self.hardware_error
    }

    /// Booting after a REBOOT or a brown-out: the servo neither answers nor executes.
    pub fn is_silent(&self) -> bool {
        self.time < self.silent_until
    }

    fn torque_enabled(&self) -> bool {
        self.reg.torque_enable.is_some_and(|k| self.table.value(k) != 0)
    }

    /// A client write, with the table's rules; P2 locks EEPROM while torque is on, and a goal
    /// beyond its Limit item is refused (nothing is written).
    pub fn write(&mut self, address: u16, data: &[u8]) -> Result<(), TableError> {
        self.check_limits(address, data)?;
        let locked = self.eeprom_locked();
        self.table.write(address, data, locked)?;
        // Torque Enable = 1 during a shutdown is taken and undone at once.
        self.enforce_shutdown();
        Ok(())
    }

    /// Whether `write` would accept this now, without writing (REG_WRITE checks up front).
    pub fn check_write(&self, address: u16, data: &[u8]) -> Result<(), TableError> {
        self.check_limits(address, data)?;
        self.table.clone().write(address, data, self.eeprom_locked())
    }

    /// P2 firmware refuses EEPROM writes while torque is on (P1 firmware does not).
    fn eeprom_locked(&self) -> bool {
        self.spec.protocol == Protocol::V2 && self.torque_enabled()
    }

    /// Data Limit Error (P2) / Angle Limit Error (P1): a goal outside the range its Limit
    /// items allow now. Goal Position is bounded only in single-turn position mode.
    fn check_limits(&self, address: u16, data: &[u8]) -> Result<(), TableError> {
        let r = &self.reg;
        let symmetric = |limit: Option<usize>| limit.map(|k| (-self.table.value(k), self.table.value(k)));
        let position = match self.spec.protocol {
            Protocol::V2 if self.value(r.operating_mode) == 3 => {
                r.min_position_limit.zip(r.max_position_limit).map(|(lo, hi)| (self.table.value(lo), self.table.value(hi)))
            }
            Protocol::V1 if self.mode() == Mode::Position && !self.multi_turn_p1() => {
                r.cw_angle_limit.zip(r.ccw_angle_limit).map(|(lo, hi)| (self.table.value(lo), self.table.value(hi)))
            }
            _ => None,
        };
        let checks = [
            (r.goal_position, position),
            (r.goal_pwm, symmetric(r.pwm_limit)),
            (r.goal_current, symmetric(r.current_limit)),
            (r.goal_velocity, if self.spec.protocol == Protocol::V2 { symmetric(r.velocity_limit) } else { None }),
        ];
        for (goal, bounds) in checks {
            let (Some(goal), Some((lo, hi))) = (goal, bounds) else { continue };
            let item = &self.table.items()[goal];
            let start = item.address as usize;
            let end = start + item.size as usize;
            let offset = address as usize;
            if start >= offset && end <= offset + data.len() {
                let value = item.decode(&data[start - offset..end - offset]);
                if value < lo || value > hi {
                    return Err(TableError::Limit);
                }
            }
        }
        Ok(())
    }

    pub fn set_external_torque(&mut self, tau: f64) {
        self.external_torque = tau;
    }

    /// Raises hardware error bits (P2 layout); a bit in the Shutdown mask turns torque off.
    pub fn set_hardware_error(&mut self, bits: u8) {
        self.hardware_error = bits;
        self.injected = bits;
        self.enforce_shutdown();
        self.publish();
    }

    /// REBOOT: RAM back to defaults (torque off), hardware errors cleared, EEPROM and the
    /// horn's physical state kept; silent for `reboot_time_s` (the caller has queued the
    /// status packet already: a servo answers REBOOT, then boots).
    pub fn reboot(&mut self) {
        self.reset_ram();
        self.silent_until = self.time + self.spec.reboot_time_s;
    }

    /// A brown-out: the supply dipped and the servo reset as at power-up (RAM back to
    /// defaults, torque off, errors cleared, the position folded into one turn), then boots
    /// for `seconds` in silence.
    pub fn brown_out(&mut self, seconds: f64) {
        let tick = rad_to_tick(self.state.theta) + self.tick_offset;
        self.tick_offset -= 4096 * tick.div_euclid(4096);
        self.reset_ram();
        self.silent_until = self.time + seconds.max(0.0);
    }

    /// An encoder glitch: a read of Present Position reports `offset` ticks more than the horn
    /// is at (a loose encoder, noise that passed the CRC): the next read only (`every` 0), or
    /// the next and then every `every`-th read until cleared (offset 0). The horn itself is
    /// untouched.
    pub fn glitch_position(&mut self, offset: i64, every: u32) {
        self.glitch = (offset != 0).then_some(Glitch { offset, every, since: every.saturating_sub(1) });
    }

    /// The control table's `len` bytes at `address`, as a READ or SYNC_READ answers them: a
    /// pending encoder glitch is added to Present Position when the read covers it.
    pub fn read_table(&mut self, address: u16, len: u16) -> Result<Vec<u8>, TableError> {
        let mut bytes = self.table.read(address, len)?.to_vec();
        let item = self.reg.present_position.map(|k| &self.table.items()[k]);
        let (Some(item), Some(glitch)) = (item, self.glitch.as_mut()) else { return Ok(bytes) };
        let start = usize::from(item.address.wrapping_sub(address));
        if item.address < address || start + usize::from(item.size) > bytes.len() {
            return Ok(bytes);
        }
        glitch.since += 1;
        if glitch.since < glitch.every.max(1) {
            return Ok(bytes);
        }
        glitch.since = 0;
        let offset = glitch.offset;
        if glitch.every == 0 {
            self.glitch = None;
        }
        let field = &mut bytes[start..start + usize::from(item.size)];
        let mut value = [0u8; 8];
        value[..field.len()].copy_from_slice(field);
        let glitched = (i64::from_le_bytes(value) + offset).to_le_bytes();
        field.copy_from_slice(&glitched[..field.len()]);
        Ok(bytes)
    }

    /// Torque Enable cleared with no error bit: torque found off (another client's write, a
    /// firmware that does not flag it).
    pub fn torque_off(&mut self) {
        if let Some(k) = self.reg.torque_enable {
            self.table.store(k, 0);
        }
        self.torque_was_on = false;
    }

    fn reset_ram(&mut self) {
        self.table.reload_ram();
        self.hardware_error = 0;
        self.injected = 0;
        self.registered = None;
        self.stalled_s = 0.0;
        self.torque_was_on = false;
        self.publish();
        self.hold_present_position();
    }

    /// CLEAR (P2): the reported position loses its whole turns, back into 0..4095. Refused
    /// while the horn moves (the caller answers Result Fail).
    pub fn clear_turns(&mut self) -> bool {
        if self.state.omega.abs() > self.moving_threshold() {
            return false;
        }
        let tick = rad_to_tick(self.state.theta) + self.tick_offset;
        self.tick_offset -= 4096 * tick.div_euclid(4096);
        self.publish();
        true
    }

    /// Advances the horn by one substep of `h` seconds.
    pub fn step(&mut self, h: f64) {
        self.update_alarms();
        self.enforce_shutdown();
        if let Some(tc) = self.spec.first_order_lag.filter(|_| self.torque_enabled() && self.mode() == Mode::Position) {
            self.step_lagging(tc, h);
            return;
        }
        let duty = if self.torque_enabled() { self.firmware_duty(h) } else { 0.0 };
        let omega = self.state.omega;
        self.duty = duty;
        // An open H-bridge carries no current: no torque and no back-EMF braking.
        let (torque, current) = if self.torque_enabled() {
            (self.spec.motor.torque(duty, omega), self.spec.motor.current(duty, omega))
        } else {
            (0.0, 0.0)
        };
        self.motor_torque = torque;
        self.current = current;
        let (applied, hand_inertia) = self.hand_applied();
        let tau = self.delayed(torque + applied, h);
        let load = Load { inertia: self.spec.load.inertia + hand_inertia, ..self.spec.load };
        let before = self.state.omega;
        plant::step(&mut self.state, &self.spec.params, &load, self.spec.friction, tau, self.time, h);
        self.record_hand(applied, (self.state.omega - before) / h);
        self.heat(h);
        self.detect_overload(h);
        self.time += h;
    }

    /// `first_order_lag`: the horn follows its goal, whatever pushes on it (hand.rs).
    fn step_lagging(&mut self, time_constant: f64, h: f64) {
        let (applied, _) = self.hand_applied();
        let before = self.state.omega;
        let goal = self.position_goal();
        follow_lag(&mut self.state, goal, time_constant, h);
        self.record_hand(applied, (self.state.omega - before) / h);
        (self.duty, self.motor_torque, self.current) = (0.0, 0.0, 0.0);
        self.time += h;
    }

    /// A hand on the horn (`None`: the scripted torque alone, a pure force source).
    pub fn set_hand(&mut self, hand: Option<Hand>) {
        self.hand = hand;
    }

    /// The hand's torque on the horn besides its inertia, and that inertia.
    fn hand_applied(&self) -> (f64, f64) {
        match &self.hand {
            Some(hand) => (hand.applied(self.external_torque, &self.state), hand.inertia),
            None => (self.external_torque, 0.0),
        }
    }

    fn record_hand(&mut self, applied: f64, alpha: f64) {
        if let Some(hand) = &mut self.hand {
            hand.record(applied, alpha);
        }
    }

    /// The overload detector (when configured): a motor held at its duty limit without moving
    /// for `overload_time_s` sets the overload bit (a shutdown bit by default).
    fn detect_overload(&mut self, h: f64) {
        let Some(limit_s) = self.spec.overload_time_s else { return };
        let saturated = self.torque_enabled() && self.duty.abs() >= self.duty_limit() * 0.999 && self.duty != 0.0;
        let stalled = self.state.omega.abs() <= self.moving_threshold();
        self.stalled_s = if saturated && stalled { self.stalled_s + h } else { 0.0 };
        if self.stalled_s >= limit_s {
            self.hardware_error |= HW_OVERLOAD;
        } else if self.spec.protocol == Protocol::V1 && self.stalled_s == 0.0 {
            self.hardware_error &= !(HW_OVERLOAD & !self.injected); // P1 clears a bit once its cause is gone
        }
    }

    /// The applied torque of `time_delay` ago (Contract 1: τ(t − time_delay)); before that much
    /// history exists, the oldest value is held, as the trial simulator holds its end values.
    fn delayed(&mut self, tau: f64, h: f64) -> f64 {
        let n = (self.spec.params.time_delay / h).round() as usize;
        if n == 0 {
            return tau;
        }
        self.torque_history.push_back(tau);
        if self.torque_history.len() > n {
            self.torque_history.pop_front().unwrap_or(tau)
        } else {
            self.torque_history.front().copied().unwrap_or(tau)
        }
    }

    /// The duty the firmware applies this substep, clipped to its limit.
    fn firmware_duty(&mut self, h: f64) -> f64 {
        let mode = self.mode();
        let theta = self.state.theta;
        if !self.torque_was_on || self.mode != Some(mode) {
            self.controller.reset(theta);
            self.mode = Some(mode);
        }
        self.torque_was_on = true;
        let limit = self.duty_limit();
        let raw = match mode {
            Mode::Position => {
                let gains = self.gains();
                let goal = self.position_goal();
                let rate = self.profile_rate();
                self.controller.duty(goal, rate, theta, gains, limit, h)
            }
            Mode::Velocity => self.velocity_duty(),
            Mode::Pwm => self.value(self.reg.goal_pwm) as f64 / P2_PWM_FULL,
            Mode::Current => {
                let amps = self.value(self.reg.goal_current) as f64 * P2_CURRENT_UNIT;
                self.spec.motor.duty_for_current(amps, self.state.omega)
            }
            Mode::Wheel => from_sign_magnitude(self.value(self.reg.goal_velocity)) / P1_MAGNITUDE_MAX as f64,
        };
        clip_duty(raw, limit)
    }

    fn value(&self, index: Option<usize>) -> i64 {
        index.map_or(0, |k| self.table.value(k))
    }

    fn mode(&self) -> Mode {
        match self.spec.protocol {
            Protocol::V2 => Mode::from_p2(self.reg.operating_mode.map_or(3, |k| self.table.value(k))),
            Protocol::V1 => {
                let wheel = self.value(self.reg.cw_angle_limit) == 0 && self.value(self.reg.ccw_angle_limit) == 0;
                if wheel && self.reg.cw_angle_limit.is_some() {
                    Mode::Wheel
                } else {
                    Mode::Position
                }
            }
        }
    }

    fn gains(&self) -> Gains {
        let (p, i, d) = (self.value(self.reg.p_gain), self.value(self.reg.i_gain), self.value(self.reg.d_gain));
        match self.spec.protocol {
            Protocol::V1 => Gains::from_p1(p, i, d),
            Protocol::V2 => Gains::from_p2(p, i, d),
        }
    }

    /// Goal Position in rad (writes beyond the position limits are refused by `check_limits`).
    fn position_goal(&self) -> f64 {
        tick_to_rad(self.value(self.reg.goal_position) - self.tick_offset)
    }

    fn multi_turn_p1(&self) -> bool {
        self.value(self.reg.cw_angle_limit) == 4095 && self.value(self.reg.ccw_angle_limit) == 4095
    }

    /// The setpoint's speed limit in rad/s (None = unlimited).
    fn profile_rate(&self) -> Option<f64> {
        let rate = match self.spec.protocol {
            Protocol::V2 => self.value(self.reg.profile_velocity) as f64 * P2_VELOCITY_UNIT,
            Protocol::V1 => self.value(self.reg.goal_velocity) as f64 * P1_SPEED_UNIT,
        };
        (rate > 0.0).then_some(rate)
    }

    fn velocity_duty(&self) -> f64 {
        let goal = self.value(self.reg.goal_velocity) as f64 * P2_VELOCITY_UNIT;
        let kp = self.value(self.reg.velocity_p_gain) as f64 / 128.0;
        8.0 * crate::motor::ERROR_GAIN * kp * (goal - self.state.omega)
    }

    /// BAM's duty cap, scaled down by P2 PWM Limit or P1 Torque Limit.
    fn duty_limit(&self) -> f64 {
        let fraction = match (self.reg.pwm_limit, self.reg.torque_limit) {
            (Some(k), _) => self.table.value(k) as f64 / P2_PWM_FULL,
            (None, Some(k)) => self.table.value(k) as f64 / P1_MAGNITUDE_MAX as f64,
            (None, None) => 1.0,
        };
        MAX_PWM * fraction.clamp(0.0, 1.0)
    }

    fn heat(&mut self, h: f64) {
        let loss = self.current * self.current * self.spec.motor.resistance;
        let cooling = (self.temperature - self.spec.ambient_temperature) / THERMAL_RESISTANCE;
        self.temperature += h * (loss - cooling) / HEAT_CAPACITY;
    }

    /// Sets the overheating bit above Temperature Limit and the input-voltage bit outside the
    /// voltage limits. P2 keeps a bit until a reboot; P1, which has no reboot, clears it once
    /// the condition is gone.
    fn update_alarms(&mut self) {
        let above = |limit: Option<usize>, value: f64| limit.is_some_and(|k| value > self.table.value(k) as f64);
        let below = |limit: Option<usize>, value: f64| limit.is_some_and(|k| value < self.table.value(k) as f64);
        let volts = self.spec.motor.vin * 10.0;
        let conditions = [
            (HW_OVERHEATING, above(self.reg.temperature_limit, self.temperature)),
            (HW_INPUT_VOLTAGE, below(self.reg.min_voltage_limit, volts) || above(self.reg.max_voltage_limit, volts)),
        ];
        for (bit, active) in conditions {
            if active {
                self.hardware_error |= bit;
            } else if self.spec.protocol == Protocol::V1 {
                self.hardware_error &= !(bit & !self.injected);
            }
        }
    }

    /// A hardware error in the Shutdown mask keeps torque off until a reboot (P2) or until the
    /// error is cleared (P1, which has no reboot).
    fn enforce_shutdown(&mut self) {
        let mask = self.reg.shutdown.map_or(0, |k| self.table.value(k)) as u8;
        if self.hardware_error & mask != 0 {
            if let Some(k) = self.reg.torque_enable {
                self.table.store(k, 0);
            }
        }
        if !self.torque_enabled() {
            self.torque_was_on = false;
        }
    }

    /// Writes the simulated state into the present-value items.
    pub fn publish(&mut self) {
        let (theta, omega) = (self.state.theta, self.state.omega);
        let p1 = self.spec.protocol == Protocol::V1;
        let tick = rad_to_tick(theta) + self.tick_offset;
        let load = self.motor_torque / self.spec.motor.stall_torque() * PER_MILLE;
        let values = [
            (self.reg.present_position, if p1 { tick.rem_euclid(4096) } else { tick }),
            (
                self.reg.present_velocity,
                if p1 { sign_magnitude(omega / P1_SPEED_UNIT) } else { (omega / P2_VELOCITY_UNIT).round() as i64 },
            ),
            (self.reg.present_load, if p1 { sign_magnitude(load) } else { load.round() as i64 }),
            (
                self.reg.present_current,
                if p1 {
                    2048 + (self.current / P1_CURRENT_UNIT).round() as i64
                } else {
                    (self.current / P2_CURRENT_UNIT).round() as i64
                },
            ),
            (self.reg.present_pwm, (self.duty * P2_PWM_FULL).round() as i64),
            (self.reg.present_voltage, (self.spec.motor.vin * 10.0).round() as i64),
            (self.reg.present_temperature, self.temperature.round() as i64),
            (self.reg.moving, (omega.abs() > self.moving_threshold()) as i64),
            (self.reg.realtime_tick, ((self.time * 1000.0) as i64).rem_euclid(32768)),
            (self.reg.hardware_error, self.hardware_error as i64),
            (self.reg.registered, self.registered.is_some() as i64),
        ];
        for (index, value) in values {
            if let Some(k) = index {
                self.table.store(k, value);
            }
        }
    }

    fn moving_threshold(&self) -> f64 {
        self.reg.moving_threshold.map_or(DEFAULT_MOVING_THRESHOLD, |k| self.table.value(k) as f64 * P2_VELOCITY_UNIT)
    }

    pub fn snapshot(&self) -> Snapshot {
        Snapshot {
            theta: self.state.theta,
            omega: self.state.omega,
            goal_tick: self.value(self.reg.goal_position),
            present_tick: self.value(self.reg.present_position),
            torque_enabled: self.torque_enabled(),
            duty: self.duty,
            motor_torque: self.motor_torque,
            external_torque: self.external_torque,
            hand_torque: self.hand.map_or(self.external_torque, |hand| hand.sensed),
            temperature: self.temperature,
            hardware_error: self.hardware_error,
            time: self.time,
            silent: self.is_silent(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::Bus;
    use crate::setup::{build_bus, ServoConfig};

    const H: f64 = 5e-4;

    fn bus_with(protocol: Protocol, model: &str, load: Load, theta0: f64) -> Bus {
        let params = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, ..Params::default() };
        let config = ServoConfig {
            protocol,
            model: model.into(),
            load,
            initial_theta: theta0,
            ..ServoConfig::new(1, params)
        };
        build_bus(vec![config], 1_000_000).unwrap()
    }

    fn servo(bus: &mut Bus) -> &mut Servo {
        bus.servo_mut(1).unwrap()
    }

    #[test]
    fn a_glitch_offsets_the_reads_of_present_position_it_is_armed_for_and_no_other() {
        let mut bus = bus_with(Protocol::V2, "MX-64", Load::default(), 0.0);
        let s = servo(&mut bus);
        let item = s.table.item("Present Position").unwrap().clone();
        let (address, size) = (item.address, u16::from(item.size));
        let read = |s: &mut Servo| i32::from_le_bytes(s.read_table(address, size).unwrap().try_into().unwrap());
        let truth = read(s);
        s.glitch_position(2000, 0);
        assert_eq!(read(s), truth + 2000, "the next read only");
        assert_eq!(read(s), truth);
        s.glitch_position(-700, 3);
        let reads: Vec<i32> = (0..6).map(|_| read(s)).collect();
        assert_eq!(reads, [truth - 700, truth, truth, truth - 700, truth, truth], "the next, then every third");
        s.glitch_position(0, 0);
        assert!((0..4).all(|_| read(s) == truth), "cleared");
        // A read that does not cover Present Position is never touched.
        s.glitch_position(2000, 1);
        assert_eq!(s.read_table(address - 4, 4).unwrap(), s.table.read(address - 4, 4).unwrap());
    }

    fn run(servo: &mut Servo, seconds: f64) {
        for _ in 0..(seconds / H) as usize {
            servo.step(H);
        }
        servo.publish();
    }

    fn set(servo: &mut Servo, name: &str, value: i64) {
        servo.table.set_checked(name, value).unwrap();
    }

    /// Runs a servo to goal tick 2560 (0.785 rad) under `gravity`; returns its snapshot.
    fn hold_goal(protocol: Protocol, model: &str, gravity: f64) -> Snapshot {
        let mut bus = bus_with(protocol, model, Load { inertia: 0.01, gravity_torque: gravity }, 0.0);
        let s = servo(&mut bus);
        set(s, "Goal Position", 2048 + 512);
        set(s, "Torque Enable", 1);
        run(s, 3.0);
        s.snapshot()
    }

    #[test]
    fn position_loop_converges_on_the_goal_in_both_protocols() {
        for (protocol, model) in [(Protocol::V2, "MX-64"), (Protocol::V1, "MX-28"), (Protocol::V2, "MX-106")] {
            let snap = hold_goal(protocol, model, 0.0);
            // Within the friction band of a P-only loop: coulomb / stiffness, a few ticks.
            assert!((snap.present_tick - 2560).abs() <= 6, "{model} P{}: {snap:?}", protocol.number());
            assert!(snap.omega.abs() < 1e-3);
        }
    }

    #[test]
    fn a_gravity_load_makes_the_p_loop_droop_more_at_lower_gain() {
        // P1 default P = 32 is softer than P2 default 850 (= 53 in P1 units): it sags further.
        let soft = hold_goal(Protocol::V1, "MX-64", 0.5);
        let stiff = hold_goal(Protocol::V2, "MX-64", 0.5);
        assert!(soft.present_tick < stiff.present_tick && stiff.present_tick < 2560, "{soft:?} {stiff:?}");
    }

    #[test]
    fn torque_off_swings_freely_under_gravity_without_back_emf() {
        let mut bus = bus_with(Protocol::V2, "MX-64", Load { inertia: 0.01, gravity_torque: 1.0 }, 1.2);
        let s = servo(&mut bus);
        let mut lowest = f64::MAX;
        for _ in 0..4000 {
            s.step(H);
            lowest = lowest.min(s.snapshot().theta);
            assert_eq!(s.snapshot().motor_torque, 0.0);
        }
        assert!(lowest < -0.5, "swung to {lowest}");
        run(s, 20.0);
        let snap = s.snapshot();
        assert_eq!(snap.omega, 0.0, "stuck by friction");
        assert!(snap.theta.abs() <= (0.084f64 / 1.0).asin() + 1e-3);
    }

    #[test]
    fn enabled_motor_at_zero_duty_brakes_by_back_emf() {
        let spin = |torque_on: bool| {
            let mut bus = bus_with(Protocol::V2, "MX-64", Load::default(), 0.0);
            let s = servo(&mut bus);
            set(s, "Operating Mode", 16);
            set(s, "Torque Enable", i64::from(torque_on));
            s.set_external_torque(0.5);
            run(s, 2.0);
            s.snapshot().omega
        };
        let (free, braked) = (spin(false), spin(true));
        assert!(free > 2.0 * braked && braked > 0.0, "free {free}, braked {braked}");
    }

    #[test]
    fn stall_heats_the_motor_until_the_overheating_shutdown() {
        let mut bus = bus_with(Protocol::V2, "MX-64", Load::default(), 0.0);
        let s = servo(&mut bus);
        set(s, "Temperature Limit", 26);
        set(s, "Torque Enable", 1);
        s.set_external_torque(6.0);
        run(s, 10.0);
        let snap = s.snapshot();
        assert_eq!(snap.hardware_error & HW_OVERHEATING, HW_OVERHEATING);
        assert!(!snap.torque_enabled, "Shutdown turns torque off");
        assert_eq!(s.table.get("Hardware Error Status"), Some(HW_OVERHEATING as i64));
    }

    #[test]
    fn a_stall_at_the_duty_limit_trips_the_overload_shutdown_when_configured() {
        let stall = |overload_time_s: Option<f64>, protocol: Protocol| {
            let params = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, ..Params::default() };
            let config = ServoConfig { overload_time_s, protocol, ..ServoConfig::new(1, params) };
            let mut bus = build_bus(vec![config], 1_000_000).unwrap();
            let s = servo(&mut bus);
            // A goal far away saturates the duty (4.74 N·m at 12 V); a hand pushing back with
            // 4.7 N·m holds the horn where it is: a stall at the duty limit.
            set(s, "Goal Position", 2048 + 1000);
            set(s, "Torque Enable", 1);
            s.set_external_torque(-4.7);
            run(s, 1.0);
            s.snapshot()
        };
        let tripped = stall(Some(0.3), Protocol::V2);
        assert_eq!(tripped.hardware_error, HW_OVERLOAD);
        assert!(!tripped.torque_enabled, "overload is in the default Shutdown mask");
        let p1 = stall(Some(0.3), Protocol::V1);
        assert!(!p1.torque_enabled, "P1 Alarm Shutdown has overload too");
        let off = stall(None, Protocol::V2);
        assert_eq!(off.hardware_error, 0, "no detector configured: no overload");
        assert!(off.torque_enabled);
    }

    #[test]
    fn a_supply_outside_the_voltage_limits_raises_the_voltage_bit() {
        let params = Params { motor_inertia: 0.0147, ..Params::default() };
        let config = ServoConfig { input_voltage: 18.0, ..ServoConfig::new(1, params) };
        let mut bus = build_bus(vec![config], 1_000_000).unwrap();
        let s = servo(&mut bus);
        run(s, 0.01);
        assert_eq!(s.hardware_error(), HW_INPUT_VOLTAGE);
        assert_eq!(s.table.get("Present Input Voltage"), Some(180));
    }

    #[test]
    fn time_delay_postpones_the_applied_torque() {
        let delay = 0.05;
        let params = Params { motor_inertia: 0.0147, time_delay: delay, ..Params::default() };
        let mut bus = build_bus(vec![ServoConfig::new(1, params)], 1_000_000).unwrap();
        let s = servo(&mut bus);
        s.step(H);
        s.set_external_torque(0.5);
        run(s, delay - 2.0 * H);
        assert_eq!(s.snapshot().omega, 0.0, "the hand's torque has not arrived yet");
        run(s, 4.0 * H);
        assert!(s.snapshot().omega > 0.0);
    }

    #[test]
    fn clear_folds_the_reported_position_into_one_turn_at_rest_only() {
        let mut bus = bus_with(Protocol::V2, "MX-64", Load::default(), 7.0);
        let s = servo(&mut bus);
        let before = s.table.get("Present Position").unwrap();
        assert!(before > 4095);
        assert!(s.clear_turns());
        assert_eq!(s.table.get("Present Position"), Some(before - 4096));
        s.set_external_torque(1.0);
        run(s, 0.2);
        assert!(!s.clear_turns(), "refused while moving");
    }

    #[test]
    fn p1_wheel_mode_spins_and_reports_sign_magnitude_speed() {
        let mut bus = bus_with(Protocol::V1, "MX-64", Load::default(), 0.0);
        let s = servo(&mut bus);
        set(s, "CCW Angle Limit", 0);
        set(s, "Moving Speed", 1024 + 600); // CW: negative
        set(s, "Torque Enable", 1);
        run(s, 1.0);
        assert!(s.snapshot().omega < -1.0);
        let speed = s.table.get("Present Speed").unwrap();
        assert!(speed & 1024 != 0 && speed & 1023 > 0, "speed {speed}");
        assert_eq!(s.table.get("Moving"), Some(1));
    }

    #[test]
    fn p2_present_values_follow_the_state() {
        let mut bus = bus_with(Protocol::V2, "MX-64", Load::default(), -0.5);
        let s = servo(&mut bus);
        assert_eq!(s.table.get("Goal Position"), s.table.get("Present Position"), "goal starts at present");
        s.set_external_torque(-0.3);
        run(s, 0.5);
        assert!(s.table.get("Present Velocity").unwrap() < 0);
        assert_eq!(s.table.get("Present Position"), Some(rad_to_tick(s.snapshot().theta)));
        assert_eq!(s.table.get("Present Input Voltage"), Some(120));
        assert_eq!(s.table.get("Realtime Tick"), Some(500));
    }

    #[test]
    fn a_first_order_lag_servo_follows_its_goal_whatever_pushes_it() {
        let params = Params { motor_inertia: 0.0147, ..Params::default() };
        let config = ServoConfig { first_order_lag: Some(0.025), ..ServoConfig::new(1, params) };
        let mut bus = build_bus(vec![config], 1_000_000).unwrap();
        let s = servo(&mut bus);
        set(s, "Torque Enable", 1);
        set(s, "Goal Position", 2048 + 512);
        s.set_external_torque(2.0); // ignored: the horn only follows the goal
        run(s, 0.025);
        let quarter = std::f64::consts::FRAC_PI_4;
        assert!((s.snapshot().theta - quarter * (1.0 - (-1.0f64).exp())).abs() < 1e-6, "{:?}", s.snapshot());
        run(s, 1.0);
        assert!((s.snapshot().theta - quarter).abs() < 1e-9);
    }

    #[test]
    fn a_gripping_hand_adds_its_inertia_and_the_sensor_reads_what_it_transmits() {
        let spin = |hand: Option<Hand>| {
            let mut bus = bus_with(Protocol::V2, "MX-64", Load::default(), 0.0);
            let s = servo(&mut bus);
            s.set_hand(hand);
            s.set_external_torque(0.5);
            run(s, 0.05);
            s.snapshot()
        };
        let free = spin(None);
        let held = spin(Some(Hand::new(0.0147, 0.0, 0.0, 0.0).unwrap()));
        assert_eq!(free.hand_torque, 0.5, "no hand: the sensor reads the script");
        assert!(held.omega < 0.6 * free.omega, "twice the inertia: {} vs {}", held.omega, free.omega);
        // Equal inertias: the hand's takes half of what accelerates the pair (push − Coulomb −
        // damping), so the sensor reads 0.5 − (0.5 − 0.084 − B·ω)/2 ≈ 0.29 + B·ω/2.
        assert!((held.hand_torque - 0.5 * (0.5 + 0.084)).abs() < 0.02, "{}", held.hand_torque);
    }
}
