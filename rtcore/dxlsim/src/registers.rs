//! The control-table items the simulated firmware reads and writes, resolved once per servo.
//!
//! Items are found by their e-manual names in the model's table (`dxl::models`); an item a
//! model lacks (P1 has no Operating Mode, MX-28(2.0) no Present Current) is `None` and its
//! part of the firmware is skipped. Resolving indices once keeps the 2 kHz physics loop free of
//! name look-ups.
use crate::table::ControlTable;

/// Indices into `ControlTable::items()` of the items the firmware uses.
#[derive(Clone, Debug, Default)]
pub struct Registers {
    pub model_number: Option<usize>,
    pub firmware_version: Option<usize>,
    pub id: Option<usize>,
    pub baud_rate: Option<usize>,
    pub return_delay_time: Option<usize>,
    pub status_return_level: Option<usize>,
    pub operating_mode: Option<usize>,
    pub torque_enable: Option<usize>,
    pub registered: Option<usize>,
    pub hardware_error: Option<usize>,
    pub shutdown: Option<usize>,
    pub temperature_limit: Option<usize>,
    pub min_voltage_limit: Option<usize>,
    pub max_voltage_limit: Option<usize>,
    pub p_gain: Option<usize>,
    pub i_gain: Option<usize>,
    pub d_gain: Option<usize>,
    pub velocity_p_gain: Option<usize>,
    pub goal_position: Option<usize>,
    pub goal_velocity: Option<usize>,
    pub goal_pwm: Option<usize>,
    pub goal_current: Option<usize>,
    pub profile_velocity: Option<usize>,
    pub velocity_limit: Option<usize>,
    pub pwm_limit: Option<usize>,
    pub current_limit: Option<usize>,
    pub torque_limit: Option<usize>,
    pub cw_angle_limit: Option<usize>,
    pub ccw_angle_limit: Option<usize>,
    pub min_position_limit: Option<usize>,
    pub max_position_limit: Option<usize>,
    pub moving_threshold: Option<usize>,
    pub present_position: Option<usize>,
    pub present_velocity: Option<usize>,
    pub present_load: Option<usize>,
    pub present_current: Option<usize>,
    pub present_pwm: Option<usize>,
    pub present_voltage: Option<usize>,
    pub present_temperature: Option<usize>,
    pub moving: Option<usize>,
    pub realtime_tick: Option<usize>,
}

impl Registers {
    /// Resolves every item the firmware uses; each accepts its P2 and P1 e-manual names.
    pub fn resolve(table: &ControlTable) -> Registers {
        let find = |names: &[&str]| names.iter().find_map(|n| table.index_of(n));
        Registers {
            model_number: find(&["Model Number"]),
            firmware_version: find(&["Firmware Version", "Version of Firmware"]),
            id: find(&["ID"]),
            baud_rate: find(&["Baud Rate"]),
            return_delay_time: find(&["Return Delay Time"]),
            status_return_level: find(&["Status Return Level"]),
            operating_mode: find(&["Operating Mode"]),
            torque_enable: find(&["Torque Enable"]),
            registered: find(&["Registered Instruction", "Registered"]),
            hardware_error: find(&["Hardware Error Status"]),
            shutdown: find(&["Shutdown", "Alarm Shutdown"]),
            temperature_limit: find(&["Temperature Limit", "Highest Limit Temperature"]),
            min_voltage_limit: find(&["Min Voltage Limit", "Lowest Limit Voltage"]),
            max_voltage_limit: find(&["Max Voltage Limit", "Highest Limit Voltage"]),
            p_gain: find(&["Position P Gain", "P Gain"]),
            i_gain: find(&["Position I Gain", "I Gain"]),
            d_gain: find(&["Position D Gain", "D Gain"]),
            velocity_p_gain: find(&["Velocity P Gain"]),
            goal_position: find(&["Goal Position"]),
            goal_velocity: find(&["Goal Velocity", "Moving Speed"]),
            goal_pwm: find(&["Goal PWM"]),
            goal_current: find(&["Goal Current"]),
            profile_velocity: find(&["Profile Velocity"]),
            velocity_limit: find(&["Velocity Limit"]),
            pwm_limit: find(&["PWM Limit"]),
            current_limit: find(&["Current Limit"]),
            torque_limit: find(&["Torque Limit"]),
            cw_angle_limit: find(&["CW Angle Limit"]),
            ccw_angle_limit: find(&["CCW Angle Limit"]),
            min_position_limit: find(&["Min Position Limit"]),
            max_position_limit: find(&["Max Position Limit"]),
            moving_threshold: find(&["Moving Threshold"]),
            present_position: find(&["Present Position"]),
            present_velocity: find(&["Present Velocity", "Present Speed"]),
            present_load: find(&["Present Load"]),
            present_current: find(&["Present Current", "Current"]),
            present_pwm: find(&["Present PWM"]),
            present_voltage: find(&["Present Input Voltage", "Present Voltage"]),
            present_temperature: find(&["Present Temperature"]),
            moving: find(&["Moving"]),
            realtime_tick: find(&["Realtime Tick"]),
        }
    }
}
