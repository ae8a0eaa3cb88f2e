//! Building a bus from a configuration, with every check a user's typo needs.
//!
//! The binding (and any Rust caller) describes servos with plain values; this module checks
//! them all before anything runs, so a bad configuration is one clear message and never a
//! half-built bus.
use dxl::Protocol;
use plant::{FrictionLaw, Load, Params};

use crate::bus::Bus;
use crate::catalog::{control_table, find_model};
use crate::motor::Motor;
use crate::servo::{Servo, ServoSpec, DEFAULT_REBOOT_TIME_S};

/// One servo as a configuration gives it.
#[derive(Clone, Debug)]
pub struct ServoConfig {
    pub id: u8,
    pub model: String,
    pub protocol: Protocol,
    pub params: Params,
    pub load: Load,
    pub friction: FrictionLaw,
    /// Motor constants; `None` takes the model's documented values (`Motor::for_model`).
    pub kt: Option<f64>,
    pub resistance: Option<f64>,
    pub input_voltage: f64,
    pub initial_theta: f64,
    pub ambient_temperature: f64,
    /// Initial register values by item name (e.g. "Return Delay Time" = 0), range-checked.
    pub registers: Vec<(String, i64)>,
    /// s: a horn that lags its goal instead of the firmware and motor model (hand.rs).
    pub first_order_lag: Option<f64>,
    /// Seconds a REBOOT keeps the servo silent (0..=10).
    pub reboot_time_s: f64,
    /// Seconds of stall at the duty limit before the overload bit sets; None: never.
    pub overload_time_s: Option<f64>,
    /// Its firmware answers Fast Sync Read (0x8A; Protocol 2.0 only). False: a firmware
    /// without it, which ignores the broadcast as any unknown instruction.
    pub fast_sync_read: bool,
}

impl ServoConfig {
    /// A servo with the defaults: MX-64, Protocol 2.0, 12 V, at rest hanging down, 25 °C.
    pub fn new(id: u8, params: Params) -> ServoConfig {
        ServoConfig {
            id,
            model: "MX-64".into(),
            protocol: Protocol::V2,
            params,
            load: Load::default(),
            friction: FrictionLaw::Stick,
            kt: None,
            resistance: None,
            input_voltage: 12.0,
            initial_theta: 0.0,
            ambient_temperature: 25.0,
            registers: Vec::new(),
            first_order_lag: None,
            reboot_time_s: DEFAULT_REBOOT_TIME_S,
            overload_time_s: None,
            fast_sync_read: true,
        }
    }
}

/// Builds the bus, or says what is wrong with the configuration.
pub fn build_bus(configs: Vec<ServoConfig>, baudrate: u32) -> Result<Bus, String> {
    let protocol = configs.first().ok_or("a mock bus needs at least one servo")?.protocol;
    let mut ids = Vec::new();
    let mut servos = Vec::new();
    for config in configs {
        if config.protocol != protocol {
            return Err("all servos on one bus must use the same protocol".into());
        }
        if ids.contains(&config.id) {
            return Err(format!("servo ID {} appears twice on the bus", config.id));
        }
        ids.push(config.id);
        servos.push(build_servo(config, baudrate)?);
    }
    Ok(Bus::new(protocol, servos))
}

fn build_servo(config: ServoConfig, baudrate: u32) -> Result<Servo, String> {
    let max_id = match config.protocol {
        Protocol::V1 => dxl::protocol1::MAX_ID,
        Protocol::V2 => dxl::protocol2::MAX_ID,
    };
    let id = config.id;
    if id > max_id {
        return Err(format!("servo ID {id} is out of range 0..={max_id} for protocol {}", config.protocol.number()));
    }
    config.params.validate().map_err(|e| format!("servo {id}: {e}"))?;
    check_physical(id, &config)?;
    let model = find_model(&config.model, config.protocol)?;
    let vin = config.input_voltage;
    let motor = match (Motor::for_model(model.name, vin), config.kt, config.resistance) {
        (_, Some(kt), Some(resistance)) => Motor { kt, resistance, vin },
        (Some(m), kt, resistance) => {
            Motor { kt: kt.unwrap_or(m.kt), resistance: resistance.unwrap_or(m.resistance), vin }
        }
        (None, _, _) => return Err(format!("servo {id}: no motor constants for {}; give kt and resistance", model.name)),
    };
    let mut table = control_table(model);
    if let Some(code) = baud_code(config.protocol, baudrate) {
        table.set_checked("Baud Rate", code).map_err(|_| format!("servo {id}: baud code {code} refused"))?;
    }
    for (name, value) in &config.registers {
        table
            .set_checked(name, *value)
            .map_err(|e| format!("servo {id}: register {name:?} = {value} refused ({e:?})"))?;
    }
    let spec = ServoSpec {
        id,
        protocol: config.protocol,
        params: config.params,
        load: config.load,
        friction: config.friction,
        motor,
        initial_theta: config.initial_theta,
        ambient_temperature: config.ambient_temperature,
        first_order_lag: config.first_order_lag,
        reboot_time_s: config.reboot_time_s,
        overload_time_s: config.overload_time_s,
        fast_sync_read: config.fast_sync_read && config.protocol == Protocol::V2,
    };
    Ok(Servo::new(spec, table))
}

fn check_physical(id: u8, c: &ServoConfig) -> Result<(), String> {
    let checks = [
        ("load_inertia", c.load.inertia, c.load.inertia >= 0.0),
        ("gravity_torque", c.load.gravity_torque, true),
        ("input_voltage", c.input_voltage, c.input_voltage > 0.0),
        ("kt", c.kt.unwrap_or(1.0), c.kt.unwrap_or(1.0) > 0.0),
        ("resistance", c.resistance.unwrap_or(1.0), c.resistance.unwrap_or(1.0) > 0.0),
        ("initial_theta", c.initial_theta, true),
        ("ambient_temperature", c.ambient_temperature, true),
        ("first_order_lag", c.first_order_lag.unwrap_or(1.0), c.first_order_lag.unwrap_or(1.0) > 0.0),
        ("reboot_time_s", c.reboot_time_s, (0.0..=10.0).contains(&c.reboot_time_s)),
        ("overload_time_s", c.overload_time_s.unwrap_or(1.0), c.overload_time_s.unwrap_or(1.0) > 0.0),
    ];
    for (name, value, ok) in checks {
        if !value.is_finite() || !ok {
            return Err(format!("servo {id}: {name} = {value} is not allowed"));
        }
    }
    Ok(())
}

/// The Baud Rate register value for a bit rate, if the firmware has one (protocols.md §3.3).
pub fn baud_code(protocol: Protocol, baudrate: u32) -> Option<i64> {
    match protocol {
        Protocol::V2 => {
            let rates = [9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000];
            rates.iter().position(|&r| r == baudrate).map(|k| k as i64)
        }
        Protocol::V1 => match baudrate {
            2_250_000 => Some(250),
            2_500_000 => Some(251),
            3_000_000 => Some(252),
            0 => None,
            b => {
                // bps = 2 000 000 / (value + 1), within the firmware's 3 % tolerance.
                let value = (2_000_000.0 / b as f64 - 1.0).round();
                let actual = 2_000_000.0 / (value + 1.0);
                ((0.0..250.0).contains(&value) && (actual / b as f64 - 1.0).abs() < 0.03).then_some(value as i64)
            }
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> Params {
        Params { motor_inertia: 0.0147, damping: 0.03, coulomb: 0.08, ..Params::default() }
    }

    fn error(configs: Vec<ServoConfig>) -> String {
        build_bus(configs, 1_000_000).err().expect("the configuration should be refused")
    }

    #[test]
    fn baud_codes_of_both_firmwares() {
        assert_eq!(baud_code(Protocol::V2, 1_000_000), Some(3));
        assert_eq!(baud_code(Protocol::V2, 57_600), Some(1));
        assert_eq!(baud_code(Protocol::V2, 12_345), None);
        assert_eq!(baud_code(Protocol::V1, 1_000_000), Some(1));
        assert_eq!(baud_code(Protocol::V1, 57_600), Some(34));
        assert_eq!(baud_code(Protocol::V1, 3_000_000), Some(252));
    }

    #[test]
    fn configuration_errors_are_reported() {
        let base = ServoConfig::new(1, params());
        assert!(error(vec![]).contains("at least one"));
        assert!(error(vec![base.clone(), base.clone()]).contains("twice"));
        let p1 = ServoConfig { id: 2, protocol: Protocol::V1, ..base.clone() };
        assert!(error(vec![base.clone(), p1]).contains("same protocol"));
        let unknown = ServoConfig { model: "AX-12".into(), ..base.clone() };
        assert!(error(vec![unknown]).contains("unknown servo model"));
        let bad_register = ServoConfig { registers: vec![("Return Delay Time".into(), 999)], ..base.clone() };
        assert!(error(vec![bad_register]).contains("Return Delay Time"));
        let no_inertia = ServoConfig::new(1, Params::default());
        assert!(error(vec![no_inertia]).contains("motor_inertia"));
        let bad_id = ServoConfig { id: 253, ..base };
        assert!(error(vec![bad_id]).contains("out of range"));
    }

    #[test]
    fn the_baud_register_follows_the_bus() {
        let bus = build_bus(vec![ServoConfig::new(1, params())], 1_000_000).unwrap();
        assert_eq!(bus.servo(1).unwrap().table.get("Baud Rate"), Some(3));
    }
}
