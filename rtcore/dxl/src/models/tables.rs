//! The control tables, transcribed from the ROBOTIS e-manual model pages (emanual
//! `docs/en/dxl/mx/mx-28.md`, `mx-64.md`, `mx-106.md`, `mx-28-2.md`, `mx-64-2.md`,
//! `mx-106-2.md`, `docs/en/dxl/x/xm430-w350.md`, `xl330-m288.md`; see docs/dynamixel.md).
//! Ranges are the static write bounds of the e-manual; items bounded by another item (Goal
//! Current by Current Limit, ...) carry the widest bound that limit item allows.
use super::{Access, Item, Model};
use crate::packet::Protocol;

#[allow(clippy::too_many_arguments)] // one argument per column of the e-manual table
const fn item(
    name: &'static str,
    address: u16,
    size: u8,
    access: Access,
    eeprom: bool,
    default: Option<i64>,
    range: Option<(i64, i64)>,
    unit: &'static str,
) -> Item {
    let (min, max) = match range {
        Some((lo, hi)) => (Some(lo), Some(hi)),
        None => (None, None),
    };
    let signed = matches!(range, Some((lo, _)) if lo < 0);
    Item { name, address, size, access, eeprom, signed, default, min, max, unit, count: 1, default_step: 0, first_number: 1 }
}

/// EEPROM, read-write.
const fn ee(name: &'static str, address: u16, size: u8, default: i64, lo: i64, hi: i64, unit: &'static str) -> Item {
    item(name, address, size, Access::RW, true, Some(default), Some((lo, hi)), unit)
}

/// RAM, read-write.
const fn rw(name: &'static str, address: u16, size: u8, default: Option<i64>, lo: i64, hi: i64, unit: &'static str) -> Item {
    item(name, address, size, Access::RW, false, default, Some((lo, hi)), unit)
}

/// Read-only; `signed` for two's-complement values.
const fn ro(name: &'static str, address: u16, size: u8, eeprom: bool, default: Option<i64>, signed: bool, unit: &'static str) -> Item {
    let mut it = item(name, address, size, Access::R, eeprom, default, None, unit);
    it.signed = signed;
    it
}

/// A run of `count` RAM read-write items.
#[allow(clippy::too_many_arguments)] // one argument per column of the e-manual table
const fn run(name: &'static str, first: u16, address: u16, size: u8, count: u16, default: i64, step: i64, lo: i64, hi: i64) -> Item {
    let mut it = rw(name, address, size, Some(default), lo, hi, "");
    it.first_number = first;
    it.count = count;
    it.default_step = step;
    it
}

/// The filler an array is built from in const context; never left in a table (`join` checks).
const BLANK: Item = ro("", 0, 1, false, None, false, "");

const fn total(parts: &[&[Item]]) -> usize {
    let (mut n, mut p) = (0, 0);
    while p < parts.len() {
        n += parts[p].len();
        p += 1;
    }
    n
}

/// Concatenate table segments at compile time, so items shared by several models are
/// written once (a wrong length fails the build, never a run).
const fn join<const N: usize>(parts: &[&[Item]]) -> [Item; N] {
    let mut out = [BLANK; N];
    let (mut n, mut p) = (0, 0);
    while p < parts.len() {
        let mut i = 0;
        while i < parts[p].len() {
            out[n] = parts[p][i];
            n += 1;
            i += 1;
        }
        p += 1;
    }
    assert!(n == N, "segment lengths do not add up to the table length");
    out
}

const RPM: &str = "0.229 rev/min";
const PULSE: &str = "pulse";
const VOLT: &str = "0.1 V";
const CELSIUS: &str = "1 degC";
const ACCEL: &str = "214.577 rev/min^2";
const PWM: &str = "0.113 %";
const RDT: &str = "2 us";

pub static MODELS: [Model; 8] = [
    Model { name: "MX-28", number: 29, protocol: Protocol::V1, items: &MX28_P1 },
    Model { name: "MX-64", number: 310, protocol: Protocol::V1, items: &MX64_P1 },
    Model { name: "MX-106", number: 320, protocol: Protocol::V1, items: &MX106_P1 },
    Model { name: "MX-28", number: 30, protocol: Protocol::V2, items: &MX28_P2 },
    Model { name: "MX-64", number: 311, protocol: Protocol::V2, items: &MX64_P2 },
    Model { name: "MX-106", number: 321, protocol: Protocol::V2, items: &MX106_P2 },
    Model { name: "XM430-W350", number: 1020, protocol: Protocol::V2, items: &XM430_W350 },
    Model { name: "XL330-M288", number: 1200, protocol: Protocol::V2, items: &XL330_M288 },
];

// ---- Protocol 1.0 firmware (MX series) -------------------------------------------------------

const fn p1_head(number: i64) -> [Item; 5] {
    [
        ro("Model Number", 0, 2, true, Some(number), false, ""),
        ro("Firmware Version", 2, 1, true, None, false, ""),
        ee("ID", 3, 1, 1, 0, 253, ""),
        ee("Baud Rate", 4, 1, 34, 0, 254, ""),
        ee("Return Delay Time", 5, 1, 250, 0, 254, RDT),
    ]
}

const P1_ANGLE_LIMITS: [Item; 2] = [
    ee("CW Angle Limit", 6, 2, 0, 0, 4095, PULSE),
    ee("CCW Angle Limit", 8, 2, 4095, 0, 4095, PULSE),
];

/// MX-106 only (P1): dual-servo mode.
const P1_DRIVE_MODE: [Item; 1] = [ee("Drive Mode", 10, 1, 0, 0, 3, "")];

const fn p1_limits(max_voltage: i64) -> [Item; 3] {
    [
        ee("Temperature Limit", 11, 1, 80, 0, 99, CELSIUS),
        ee("Min Voltage Limit", 12, 1, 60, 50, 250, VOLT),
        ee("Max Voltage Limit", 13, 1, max_voltage, 50, 250, VOLT),
    ]
}

const P1_COMMON: [Item; 26] = [
    ee("Max Torque", 14, 2, 1023, 0, 1023, "0.1 %"),
    ee("Status Return Level", 16, 1, 2, 0, 2, ""),
    ee("Alarm LED", 17, 1, 36, 0, 127, ""),
    ee("Shutdown", 18, 1, 36, 0, 127, ""),
    ee("Multi Turn Offset", 20, 2, 0, -24576, 24576, PULSE),
    ee("Resolution Divider", 22, 1, 1, 1, 4, ""),
    rw("Torque Enable", 24, 1, Some(0), 0, 1, ""),
    rw("LED", 25, 1, Some(0), 0, 1, ""),
    rw("D Gain", 26, 1, Some(0), 0, 254, ""),
    rw("I Gain", 27, 1, Some(0), 0, 254, ""),
    rw("P Gain", 28, 1, Some(32), 0, 254, ""),
    rw("Goal Position", 30, 2, None, -28672, 28672, PULSE),
    rw("Moving Speed", 32, 2, None, 0, 2047, "0.114 rev/min"),
    rw("Torque Limit", 34, 2, Some(1023), 0, 1023, "0.1 %"),
    ro("Present Position", 36, 2, false, None, true, PULSE),
    ro("Present Speed", 38, 2, false, None, false, "0.11 rev/min, bit 10 = CW"),
    ro("Present Load", 40, 2, false, None, false, "0.1 %, bit 10 = CW"),
    ro("Present Voltage", 42, 1, false, None, false, VOLT),
    ro("Present Temperature", 43, 1, false, None, false, CELSIUS),
    ro("Registered Instruction", 44, 1, false, Some(0), false, ""),
    ro("Moving", 46, 1, false, Some(0), false, ""),
    rw("Lock", 47, 1, Some(0), 0, 1, ""),
    rw("Punch", 48, 2, Some(0), 0, 1023, ""),
    ro("Realtime Tick", 50, 2, false, Some(0), false, "1 ms"),
    rw("Current", 68, 2, Some(0), 0, 4095, "4.5 mA, 2048 = 0"),
    rw("Torque Ctrl Mode Enable", 70, 1, Some(0), 0, 1, ""),
];

/// Goal Torque exists on MX-64/106 only; the MX-28 also lacks Current and Torque Ctrl Mode.
const P1_GOAL_TORQUE: [Item; 1] = [rw("Goal Torque", 71, 2, Some(0), 0, 2047, "4.5 mA, bit 10 = CW")];
const P1_GOAL_ACCELERATION: [Item; 1] = [rw("Goal Acceleration", 73, 1, Some(0), 0, 254, "8.583 deg/s^2")];
/// P1_COMMON up to Realtime Tick (the items every MX has).
const P1_BASE: &[Item] = P1_COMMON.split_at(24).0;

const MX28_P1_PARTS: &[&[Item]] = &[&p1_head(29), &P1_ANGLE_LIMITS, &p1_limits(160), P1_BASE, &P1_GOAL_ACCELERATION];
static MX28_P1: [Item; total(MX28_P1_PARTS)] = join(MX28_P1_PARTS);

const MX64_P1_PARTS: &[&[Item]] =
    &[&p1_head(310), &P1_ANGLE_LIMITS, &p1_limits(240), &P1_COMMON, &P1_GOAL_TORQUE, &P1_GOAL_ACCELERATION];
static MX64_P1: [Item; total(MX64_P1_PARTS)] = join(MX64_P1_PARTS);

const MX106_P1_PARTS: &[&[Item]] = &[
    &p1_head(320), &P1_ANGLE_LIMITS, &P1_DRIVE_MODE, &p1_limits(160), &P1_COMMON, &P1_GOAL_TORQUE, &P1_GOAL_ACCELERATION,
];
static MX106_P1: [Item; total(MX106_P1_PARTS)] = join(MX106_P1_PARTS);

// ---- Protocol 2.0 firmware (MX(2.0), X series) -----------------------------------------------

const fn p2_head(number: i64, baud_max: i64, protocol: (i64, i64)) -> [Item; 12] {
    [
        ro("Model Number", 0, 2, true, Some(number), false, ""),
        ro("Model Information", 2, 4, true, None, false, ""),
        ro("Firmware Version", 6, 1, true, None, false, ""),
        ee("ID", 7, 1, 1, 0, 252, ""),
        ee("Baud Rate", 8, 1, 1, 0, baud_max, ""),
        ee("Return Delay Time", 9, 1, 250, 0, 254, RDT),
        ee("Drive Mode", 10, 1, 0, 0, 5, ""),
        ee("Operating Mode", 11, 1, 3, 0, 16, ""),
        ee("Secondary ID", 12, 1, 255, 0, 255, ""),
        ee("Protocol Type", 13, 1, 2, protocol.0, protocol.1, ""),
        ee("Homing Offset", 20, 4, 0, -1_044_479, 1_044_479, PULSE),
        ee("Moving Threshold", 24, 4, 10, 0, 1023, RPM),
    ]
}

/// Temperature, voltage and PWM limits (addresses 31..37).
const fn p2_limits(temp: i64, max_v: i64, min_v: i64, v_lo: i64, v_hi: i64) -> [Item; 4] {
    [
        ee("Temperature Limit", 31, 1, temp, 0, 100, CELSIUS),
        ee("Max Voltage Limit", 32, 2, max_v, v_lo, v_hi, VOLT),
        ee("Min Voltage Limit", 34, 2, min_v, v_lo, v_hi, VOLT),
        ee("PWM Limit", 36, 2, 885, 0, 885, PWM),
    ]
}

const fn current_limit(default: i64, unit: &'static str) -> [Item; 1] {
    [ee("Current Limit", 38, 2, default, 0, default, unit)]
}

const P2_ACCELERATION_LIMIT: [Item; 1] = [ee("Acceleration Limit", 40, 4, 32767, 0, 32767, ACCEL)];

const fn p2_motion_limits(velocity_limit: i64, velocity_max: i64) -> [Item; 3] {
    [
        ee("Velocity Limit", 44, 4, velocity_limit, 0, velocity_max, RPM),
        ee("Max Position Limit", 48, 4, 4095, 0, 4095, PULSE),
        ee("Min Position Limit", 52, 4, 0, 0, 4095, PULSE),
    ]
}

/// Which hardware errors shut the motor down (bitmask of Hardware Error Status bits).
const fn shutdown(default: i64) -> [Item; 1] {
    [ee("Shutdown", 63, 1, default, 0, 255, "")]
}

/// XL330 only: start-up behaviour and PWM slope.
const XL330_STARTUP: [Item; 2] = [
    ee("Startup Configuration", 60, 1, 0, 0, 3, ""),
    ee("PWM Slope", 62, 1, 140, 1, 255, "1.977 mV/ms"),
];

const fn p2_ram_head(vel_i: i64, vel_p: i64, pos_p: i64) -> [Item; 14] {
    [
        rw("Torque Enable", 64, 1, Some(0), 0, 1, ""),
        rw("LED", 65, 1, Some(0), 0, 1, ""),
        rw("Status Return Level", 68, 1, Some(2), 0, 2, ""),
        ro("Registered Instruction", 69, 1, false, Some(0), false, ""),
        ro("Hardware Error Status", 70, 1, false, Some(0), false, ""),
        rw("Velocity I Gain", 76, 2, Some(vel_i), 0, 16383, ""),
        rw("Velocity P Gain", 78, 2, Some(vel_p), 0, 16383, ""),
        rw("Position D Gain", 80, 2, Some(0), 0, 16383, ""),
        rw("Position I Gain", 82, 2, Some(0), 0, 16383, ""),
        rw("Position P Gain", 84, 2, Some(pos_p), 0, 16383, ""),
        rw("Feedforward 2nd Gain", 88, 2, Some(0), 0, 16383, ""),
        rw("Feedforward 1st Gain", 90, 2, Some(0), 0, 16383, ""),
        rw("Bus Watchdog", 98, 1, Some(0), 0, 127, "20 ms"),
        rw("Goal PWM", 100, 2, None, -885, 885, PWM),
    ]
}

const fn goal_current(limit: i64, unit: &'static str) -> [Item; 1] {
    [rw("Goal Current", 102, 2, None, -limit, limit, unit)]
}

const fn p2_goals(velocity_max: i64) -> [Item; 8] {
    [
        rw("Goal Velocity", 104, 4, None, -velocity_max, velocity_max, RPM),
        rw("Profile Acceleration", 108, 4, Some(0), 0, 32767, ACCEL),
        rw("Profile Velocity", 112, 4, Some(0), 0, 32767, RPM),
        rw("Goal Position", 116, 4, None, -1_048_575, 1_048_575, PULSE),
        ro("Realtime Tick", 120, 2, false, None, false, "1 ms"),
        ro("Moving", 122, 1, false, Some(0), false, ""),
        ro("Moving Status", 123, 1, false, Some(0), false, ""),
        ro("Present PWM", 124, 2, false, None, true, PWM),
    ]
}

/// Address 126: Present Current (signed, in the model's current unit) or, on the MX-28(2.0),
/// Present Load (0.1 %).
const fn present_126(name: &'static str, unit: &'static str) -> [Item; 1] {
    [ro(name, 126, 2, false, None, true, unit)]
}

const P2_PRESENT: [Item; 6] = [
    ro("Present Velocity", 128, 4, false, None, true, RPM),
    ro("Present Position", 132, 4, false, None, true, PULSE),
    ro("Velocity Trajectory", 136, 4, false, None, true, RPM),
    ro("Position Trajectory", 140, 4, false, None, true, PULSE),
    ro("Present Input Voltage", 144, 2, false, None, false, VOLT),
    ro("Present Temperature", 146, 1, false, None, false, CELSIUS),
];

const XL330_BACKUP_READY: [Item; 1] = [ro("Backup Ready", 147, 1, false, None, false, "")];

/// Indirect Address 1..28 → Data 1..28, and 29..56 (addresses 578..661, P2 only).
const P2_INDIRECT_56: [Item; 4] = [
    run("Indirect Address", 1, 168, 2, 28, 224, 1, 64, 661),
    run("Indirect Data", 1, 224, 1, 28, 0, 0, 0, 255),
    run("Indirect Address", 29, 578, 2, 28, 634, 1, 64, 661),
    run("Indirect Data", 29, 634, 1, 28, 0, 0, 0, 255),
];

/// XL330: only 20 indirect slots.
const XL330_INDIRECT: [Item; 2] = [
    run("Indirect Address", 1, 168, 2, 20, 208, 1, 64, 227),
    run("Indirect Data", 1, 208, 1, 20, 0, 0, 0, 255),
];

const MX_CURRENT_UNIT: &str = "3.36 mA";

const MX28_P2_PARTS: &[&[Item]] = &[
    &p2_head(30, 7, (1, 2)), &p2_limits(80, 160, 95, 95, 160), &P2_ACCELERATION_LIMIT, &p2_motion_limits(230, 1023), &shutdown(52),
    &p2_ram_head(1920, 100, 850), &p2_goals(1023), &present_126("Present Load", "0.1 %"), &P2_PRESENT, &P2_INDIRECT_56,
];
static MX28_P2: [Item; total(MX28_P2_PARTS)] = join(MX28_P2_PARTS);

const MX64_P2_PARTS: &[&[Item]] = &[
    &p2_head(311, 7, (1, 2)), &p2_limits(80, 160, 95, 95, 160), &current_limit(1941, MX_CURRENT_UNIT),
    &P2_ACCELERATION_LIMIT, &p2_motion_limits(435, 1023), &shutdown(52), &p2_ram_head(1920, 100, 850),
    &goal_current(1941, MX_CURRENT_UNIT), &p2_goals(1023), &present_126("Present Current", MX_CURRENT_UNIT),
    &P2_PRESENT, &P2_INDIRECT_56,
];
static MX64_P2: [Item; total(MX64_P2_PARTS)] = join(MX64_P2_PARTS);

const MX106_P2_PARTS: &[&[Item]] = &[
    &p2_head(321, 7, (1, 2)), &p2_limits(80, 160, 95, 95, 160), &current_limit(2047, MX_CURRENT_UNIT),
    &P2_ACCELERATION_LIMIT, &p2_motion_limits(360, 1023), &shutdown(52), &p2_ram_head(1920, 100, 850),
    &goal_current(2047, MX_CURRENT_UNIT), &p2_goals(1023), &present_126("Present Current", MX_CURRENT_UNIT),
    &P2_PRESENT, &P2_INDIRECT_56,
];
static MX106_P2: [Item; total(MX106_P2_PARTS)] = join(MX106_P2_PARTS);

const XM430_W350_PARTS: &[&[Item]] = &[
    &p2_head(1020, 7, (1, 2)), &p2_limits(80, 160, 95, 95, 160), &current_limit(1193, "2.69 mA"),
    &P2_ACCELERATION_LIMIT, &p2_motion_limits(350, 1023), &shutdown(52), &p2_ram_head(1920, 100, 800),
    &goal_current(1193, "2.69 mA"), &p2_goals(1023), &present_126("Present Current", "2.69 mA"), &P2_PRESENT,
    &P2_INDIRECT_56,
];
static XM430_W350: [Item; total(XM430_W350_PARTS)] = join(XM430_W350_PARTS);

const XL330_M288_PARTS: &[&[Item]] = &[
    &p2_head(1200, 6, (2, 22)), &p2_limits(70, 70, 35, 31, 70), &current_limit(1750, "1 mA"),
    &p2_motion_limits(445, 2047), &XL330_STARTUP, &shutdown(53), &p2_ram_head(1600, 180, 400), &goal_current(1750, "1 mA"),
    &p2_goals(2047), &present_126("Present Current", "1 mA"), &P2_PRESENT, &XL330_BACKUP_READY, &XL330_INDIRECT,
];
static XL330_M288: [Item; total(XL330_M288_PARTS)] = join(XL330_M288_PARTS);
