//! The loop's tunable parameters: their names, their validation and their all-or-nothing update.
//!
//! Why validate in the caller: `set_params` runs in the Python thread, builds a complete
//! candidate from the current values plus every change, and checks the candidate as a whole
//! (plant's `check_stable` at h = 1/rate for each joint, finite numbers, consistent limits)
//! before anything reaches the loop. Either the whole candidate is published or nothing is, so
//! a rejected key never leaves a half-applied set behind.
//!
//! Names are the configuration's keys: per joint `virtual_inertia`, `virtual_damping`,
//! `virtual_coulomb`, `lever_arm`, `position_min`, `position_max`, `velocity_max`,
//! `acceleration_max`, `servo_compensation`, `passivity_guard`, `passivity_margin`,
//! `passivity_damping_max` (bare = every joint, `"<id>.name"` = one joint, an
//! optional `limits.` before the limit names); loop-wide `deadband`, `lowpass_hz`,
//! `stale_timeout_ms`, `ramp_time_s` and `bias` (6 numbers).
//!
//! This is the second gate. The daemon's schema (`admittance/daemon/config.py`) checks every
//! live value against its documented, physical bounds before a set reaches the loop; the
//! [`envelope`] here is wider, and exists so that no caller of the library (the daemon, a
//! test, a script driving `AdmittanceLoop` directly) can hand the RT thread a value that
//! makes it panic (`clamp` with a NaN or crossed bounds), divide by zero, or wind a goal past
//! the servo's range.
use plant::admittance::{check_stable, AdmittanceParams};
use crate::passivity::PassivityParams;
use plant::servo::ServoModel;

/// The loop's own bounds on every parameter: numerical safety, not taste (see the module doc).
pub mod envelope {
    /// kg·m²: a floor far from 0, so a ramp's interpolation can never round to 0.
    pub const INERTIA: (f64, f64) = (1e-6, 1e3);
    /// N·m·s/rad
    pub const DAMPING_MAX: f64 = 1e4;
    /// N·m
    pub const COULOMB_MAX: f64 = 1e3;
    /// m, on |lever_arm|: non-zero, and no longer than a lab.
    pub const LEVER_ARM: (f64, f64) = (1e-4, 10.0);
    /// rad/s
    pub const VELOCITY_MAX: f64 = 100.0;
    /// rad/s²
    pub const ACCELERATION_MAX: f64 = 1e5;
    /// N
    pub const DEADBAND_MAX: f64 = 1e4;
    /// ms
    pub const STALE_TIMEOUT_MS_MAX: f64 = 10_000.0;
    /// s
    pub const RAMP_TIME_S_MAX: f64 = 60.0;
    /// J: the passivity guard's margin.
    pub const PASSIVITY_MARGIN: (f64, f64) = (1e-9, 1e3);
    /// N and N·m, per component
    pub const BIAS_MAX: f64 = 1e5;
}

/// A number for a message: a shortest round-trip form in the usual range, else 6 significant
/// digits in exponent form, so a reason never echoes a 300-digit number.
pub fn short(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e6).contains(&v.abs()) {
        return format!("{v}");
    }
    let text = format!("{v:.5e}");
    match text.split_once('e') {
        Some((mantissa, exponent)) if mantissa.contains('.') => {
            format!("{}e{exponent}", mantissa.trim_end_matches('0').trim_end_matches('.'))
        }
        _ => text,
    }
}

/// The angles one joint's goal range reaches (the position limits must stay inside).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reach {
    pub id: u8,
    pub theta_min: f64,
    pub theta_max: f64,
}

/// The gains of one joint that ramp when they change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointGains {
    /// kg·m²
    pub inertia: f64,
    /// N·m·s/rad
    pub damping: f64,
    /// N·m
    pub coulomb: f64,
    /// m, signed: torque = force[axis] × lever_arm
    pub lever_arm: f64,
}

impl JointGains {
    /// What the RT thread checks before it integrates with these gains (no allocation): every
    /// value finite, I > 0, B and F ≥ 0, a non-zero lever arm. Ramps between two accepted sets
    /// always pass; this only catches what should never be there.
    pub fn usable(&self) -> bool {
        self.inertia.is_finite()
            && self.inertia > 0.0
            && self.damping.is_finite()
            && self.damping >= 0.0
            && self.coulomb.is_finite()
            && self.coulomb >= 0.0
            && self.lever_arm.is_finite()
            && self.lever_arm != 0.0
    }

    pub fn admittance(&self) -> AdmittanceParams {
        AdmittanceParams { inertia: self.inertia, damping: self.damping, coulomb: self.coulomb }
    }

    /// `(1 − s)·self + s·to`, field by field. The convex form, not `a + s·(b − a)`: at
    /// s = 1 it gives `to` exactly, and a mix of two positive values never rounds below the
    /// smaller one (`a + s·(b − a)` rounded 0.02 → 1e-20 to exactly 0, and the model to NaN).
    pub fn lerp(&self, to: &JointGains, s: f64) -> JointGains {
        let mix = |a: f64, b: f64| (1.0 - s) * a + s * b;
        JointGains {
            inertia: mix(self.inertia, to.inertia),
            damping: mix(self.damping, to.damping),
            coulomb: mix(self.coulomb, to.coulomb),
            lever_arm: mix(self.lever_arm, to.lever_arm),
        }
    }
}

/// Limits on the integrator state of one joint (rad, rad/s, rad/s²).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    pub position_min: f64,
    pub position_max: f64,
    pub velocity_max: f64,
    pub acceleration_max: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointParams {
    pub gains: JointGains,
    pub limits: Limits,
    /// The servo's identified tracking dynamics (from the joint's parameter file); not settable.
    pub servo: Option<ServoModel>,
    /// Weight of the servo compensation in [0, 1] (`servo_compensation`; needs `servo`).
    pub compensation: f64,
    /// The passivity guard (`passivity_guard`, `passivity_margin`, `passivity_damping_max`).
    pub passivity: PassivityParams,
}

/// Force conditioning shared by all joints.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorParams {
    /// N (or N·m): half-width of the dead zone; the smooth edge spans one more width.
    pub deadband: f64,
    /// First-order low-pass cutoff; 0 = off.
    pub lowpass_hz: f64,
    /// A sample older than this holds the joints.
    pub stale_timeout_ms: f64,
}

/// One complete, consistent parameter set: what the triple buffer carries to the loop.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopParams {
    pub joints: Vec<JointParams>,
    pub sensor: SensorParams,
    pub ramp_time_s: f64,
    /// Subtracted from every sample (tare); set by name or measured by a tare request.
    pub bias: [f64; 6],
    /// Bumped whenever `bias` is set by name, so the loop knows to adopt it.
    pub bias_generation: u64,
}

/// A value given for a name: a number, or the 6-vector of `bias`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ParamValue {
    Scalar(f64),
    Vector([f64; 6]),
}

const JOINT_KEYS: [&str; 12] = [
    "virtual_inertia",
    "virtual_damping",
    "virtual_coulomb",
    "lever_arm",
    "position_min",
    "position_max",
    "velocity_max",
    "acceleration_max",
    "servo_compensation",
    "passivity_guard",
    "passivity_margin",
    "passivity_damping_max",
];
const LOOP_KEYS: [&str; 5] = ["deadband", "lowpass_hz", "stale_timeout_ms", "ramp_time_s", "bias"];

/// Every name `set` accepts, bare form (for error messages and `params()`).
pub fn known_names() -> impl Iterator<Item = &'static str> {
    JOINT_KEYS.iter().chain(LOOP_KEYS.iter()).copied()
}

fn joint_field<'a>(j: &'a mut JointParams, key: &str) -> Option<&'a mut f64> {
    Some(match key {
        "virtual_inertia" => &mut j.gains.inertia,
        "virtual_damping" => &mut j.gains.damping,
        "virtual_coulomb" => &mut j.gains.coulomb,
        "lever_arm" => &mut j.gains.lever_arm,
        "position_min" => &mut j.limits.position_min,
        "position_max" => &mut j.limits.position_max,
        "velocity_max" => &mut j.limits.velocity_max,
        "acceleration_max" => &mut j.limits.acceleration_max,
        "servo_compensation" => &mut j.compensation,
        "passivity_guard" => &mut j.passivity.guard,
        "passivity_margin" => &mut j.passivity.margin,
        "passivity_damping_max" => &mut j.passivity.damping_max,
        _ => return None,
    })
}

/// The value of a joint key (for `params()`).
pub fn joint_value(j: &JointParams, key: &str) -> Option<f64> {
    let mut copy = *j;
    joint_field(&mut copy, key).map(|v| *v)
}

/// A name for a message: at most 40 characters (a name is remote input and may be a megabyte).
fn shown(name: &str) -> String {
    match name.char_indices().nth(40) {
        Some((cut, _)) => format!("{}…", &name[..cut]),
        None => name.to_string(),
    }
}

/// The highest Dynamixel ID a joint can have (253 is reserved, 254 is the broadcast ID).
pub const MAX_JOINT_ID: u8 = 252;

/// The `[id.][limits.]key` grammar of a live parameter's name, the one parser of it (the daemon
/// calls it through `_rtcore.split_param_name`): `"3.limits.position_max"` is
/// (Some(3), "position_max"); an id is 0..=MAX_JOINT_ID.
pub fn split_name(name: &str) -> Result<(Option<u8>, &str), String> {
    let (id, key) = match name.split_once('.') {
        Some((head, rest)) if head.chars().all(|c| c.is_ascii_digit()) && !head.is_empty() => {
            let id = head.parse::<u8>().ok().filter(|id| *id <= MAX_JOINT_ID).ok_or_else(|| {
                format!("'{}': joint id {} is not 0..={MAX_JOINT_ID}", shown(name), shown(head))
            })?;
            (Some(id), rest)
        }
        _ => (None, name),
    };
    Ok((id, key.strip_prefix("limits.").unwrap_or(key)))
}

fn scalar(name: &str, value: ParamValue) -> Result<f64, String> {
    match value {
        ParamValue::Scalar(v) => Ok(v),
        ParamValue::Vector(_) => Err(format!("'{}' takes one number, not a list", shown(name))),
    }
}

impl LoopParams {
    /// Sets one named value on this (candidate) set; `ids` are the joints' IDs in order.
    pub fn set(&mut self, ids: &[u8], name: &str, value: ParamValue) -> Result<(), String> {
        let (id, key) = split_name(name)?;
        if JOINT_KEYS.contains(&key) {
            let v = scalar(name, value)?;
            let index = match id {
                Some(id) => Some(
                    ids.iter()
                        .position(|&i| i == id)
                        .ok_or_else(|| format!("'{}': no joint with id {id} (joints: {ids:?})", shown(name)))?,
                ),
                None => None,
            };
            for (k, joint) in self.joints.iter_mut().enumerate() {
                if index.is_none_or(|i| i == k) {
                    *joint_field(joint, key).expect("key is in JOINT_KEYS") = v;
                }
            }
            return Ok(());
        }
        if !LOOP_KEYS.contains(&key) {
            let known: Vec<&str> = known_names().collect();
            return Err(format!("unknown parameter '{}' (known: {})", shown(name), known.join(", ")));
        }
        if id.is_some() {
            return Err(format!("'{}': '{key}' is loop-wide and takes no joint id", shown(name)));
        }
        match (key, value) {
            ("bias", ParamValue::Vector(b)) => {
                self.bias = b;
                self.bias_generation += 1;
            }
            ("bias", ParamValue::Scalar(_)) => return Err("'bias' takes a list of 6 numbers".into()),
            ("deadband", v) => self.sensor.deadband = scalar(name, v)?,
            ("lowpass_hz", v) => self.sensor.lowpass_hz = scalar(name, v)?,
            ("stale_timeout_ms", v) => self.sensor.stale_timeout_ms = scalar(name, v)?,
            (_, v) => self.ramp_time_s = scalar(name, v)?,
        }
        Ok(())
    }

    /// Checks the whole set for a loop running at `rate_hz`, each joint against its reach (in
    /// joint order); the error names the joint and the key.
    pub fn validate(&self, reach: &[Reach], rate_hz: f64) -> Result<(), String> {
        use envelope::*;
        if reach.len() != self.joints.len() {
            return Err(format!("{} joints, but {} reach ranges", self.joints.len(), reach.len()));
        }
        let h = 1.0 / rate_hz;
        for (joint, r) in self.joints.iter().zip(reach) {
            validate_joint(joint, r, h).map_err(|reason| format!("joint {}: {reason}", r.id))?;
        }
        let s = &self.sensor;
        within("deadband", s.deadband, 0.0, DEADBAND_MAX)?;
        require(
            s.lowpass_hz.is_finite() && s.lowpass_hz >= 0.0 && s.lowpass_hz < rate_hz / 2.0,
            "lowpass_hz",
            s.lowpass_hz,
            &format!("in [0, {}) (0 = off; below half the loop rate)", short(rate_hz / 2.0)),
        )?;
        require(
            s.stale_timeout_ms.is_finite() && s.stale_timeout_ms > 0.0 && s.stale_timeout_ms <= STALE_TIMEOUT_MS_MAX,
            "stale_timeout_ms",
            s.stale_timeout_ms,
            &format!("in (0, {}]", short(STALE_TIMEOUT_MS_MAX)),
        )?;
        within("ramp_time_s", self.ramp_time_s, 0.0, RAMP_TIME_S_MAX)?;
        if let Some(b) = self.bias.iter().find(|b| !(b.is_finite() && b.abs() <= BIAS_MAX)) {
            return Err(format!("bias must be 6 numbers within ±{}, got {}", short(BIAS_MAX), short(*b)));
        }
        Ok(())
    }
}

fn require(ok: bool, name: &str, value: f64, what: &str) -> Result<(), String> {
    if ok {
        Ok(())
    } else {
        Err(format!("{name} must be {what}, got {}", short(value)))
    }
}

/// `lo <= value <= hi` (so finite).
fn within(name: &str, value: f64, lo: f64, hi: f64) -> Result<(), String> {
    require(value >= lo && value <= hi, name, value, &format!("in [{}, {}]", short(lo), short(hi)))
}

/// `0 < value <= hi`.
fn positive_up_to(name: &str, value: f64, hi: f64) -> Result<(), String> {
    require(value > 0.0 && value <= hi, name, value, &format!("in (0, {}]", short(hi)))
}

fn validate_joint(j: &JointParams, reach: &Reach, h: f64) -> Result<(), String> {
    use envelope::*;
    let g = &j.gains;
    within("virtual_inertia", g.inertia, INERTIA.0, INERTIA.1)?;
    within("virtual_damping", g.damping, 0.0, DAMPING_MAX)?;
    within("virtual_coulomb", g.coulomb, 0.0, COULOMB_MAX)?;
    check_stable(&g.admittance(), h)?;
    require(
        g.lever_arm.abs() >= LEVER_ARM.0 && g.lever_arm.abs() <= LEVER_ARM.1,
        "lever_arm",
        g.lever_arm,
        &format!("non-zero, {} to {} m either sign", short(LEVER_ARM.0), short(LEVER_ARM.1)),
    )?;
    let l = &j.limits;
    // One tick of slack: the reach is computed from ticks, the limits may come from the same
    // computation done elsewhere (Python) with a different rounding.
    let slack = 1e-9;
    let (lo, hi) = (reach.theta_min - slack, reach.theta_max + slack);
    let range = format!("in [{}, {}] rad (the angles the goal range reaches)", short(reach.theta_min), short(reach.theta_max));
    require(l.position_min >= lo && l.position_min <= hi, "position_min", l.position_min, &range)?;
    require(l.position_max >= lo && l.position_max <= hi, "position_max", l.position_max, &range)?;
    if l.position_min >= l.position_max {
        return Err(format!(
            "position_min ({}) must be below position_max ({})",
            short(l.position_min),
            short(l.position_max)
        ));
    }
    positive_up_to("velocity_max", l.velocity_max, VELOCITY_MAX)?;
    positive_up_to("acceleration_max", l.acceleration_max, ACCELERATION_MAX)?;
    validate_passivity(&j.passivity)?;
    validate_compensation(j)
}

fn validate_passivity(p: &PassivityParams) -> Result<(), String> {
    use envelope::*;
    require(p.guard == 0.0 || p.guard == 1.0, "passivity_guard", p.guard, "0 (off) or 1 (on)")?;
    within("passivity_margin", p.margin, PASSIVITY_MARGIN.0, PASSIVITY_MARGIN.1)?;
    positive_up_to("passivity_damping_max", p.damping_max, DAMPING_MAX)
}

fn validate_compensation(j: &JointParams) -> Result<(), String> {
    let w = j.compensation;
    require((0.0..=1.0).contains(&w), "servo_compensation", w, "in [0, 1] (0 = off, 1 = full)")?;
    if w > 0.0 && j.servo.is_none() {
        return Err(format!(
            "servo_compensation = {w} needs a servo model, and this joint's parameter file has no [servo] \
             table (make one with `admittance fidelity RECORDING --params-out FILE`)"
        ));
    }
    if let Some(model) = &j.servo {
        model.validate().map_err(|e| format!("servo model: {e}"))?;
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub fn joint() -> JointParams {
        JointParams {
            gains: JointGains { inertia: 0.02, damping: 0.05, coulomb: 0.01, lever_arm: 0.1 },
            limits: Limits { position_min: -3.0, position_max: 3.0, velocity_max: 10.0, acceleration_max: 1e3 },
            servo: None,
            compensation: 0.0,
            passivity: PassivityParams::default(),
        }
    }

    /// The reach of `n` joints with ids 1..=n: ±π.
    pub fn reach(n: usize) -> Vec<Reach> {
        (1..=n as u8).map(|id| Reach { id, theta_min: -std::f64::consts::PI, theta_max: std::f64::consts::PI }).collect()
    }

    pub fn params(n: usize) -> LoopParams {
        LoopParams {
            joints: vec![joint(); n],
            sensor: SensorParams { deadband: 0.0, lowpass_hz: 0.0, stale_timeout_ms: 50.0 },
            ramp_time_s: 0.0,
            bias: [0.0; 6],
            bias_generation: 0,
        }
    }

    #[test]
    fn bare_names_set_every_joint_and_prefixed_names_one() {
        let mut p = params(2);
        p.set(&[1, 2], "virtual_damping", ParamValue::Scalar(0.1)).unwrap();
        assert_eq!(p.joints[0].gains.damping, 0.1);
        assert_eq!(p.joints[1].gains.damping, 0.1);
        p.set(&[1, 2], "2.limits.position_max", ParamValue::Scalar(1.0)).unwrap();
        p.set(&[1, 2], "2.lever_arm", ParamValue::Scalar(-0.2)).unwrap();
        assert_eq!(p.joints[0].limits.position_max, 3.0);
        assert_eq!(p.joints[1].limits.position_max, 1.0);
        assert_eq!(p.joints[1].gains.lever_arm, -0.2);
    }

    #[test]
    fn unknown_names_and_ids_are_errors_that_say_why() {
        let mut p = params(1);
        let e = p.set(&[1], "virtual_dampng", ParamValue::Scalar(0.1)).unwrap_err();
        assert!(e.contains("unknown parameter 'virtual_dampng'"), "{e}");
        let e = p.set(&[1], "7.virtual_damping", ParamValue::Scalar(0.1)).unwrap_err();
        assert!(e.contains("no joint with id 7"), "{e}");
        let e = p.set(&[1], "1.deadband", ParamValue::Scalar(0.1)).unwrap_err();
        assert!(e.contains("loop-wide"), "{e}");
        assert!(p.set(&[1], "bias", ParamValue::Scalar(0.1)).is_err());
        assert_eq!(p, params(1));
    }

    #[test]
    fn unstable_and_inconsistent_values_are_refused_with_a_reason() {
        let ids = reach(1);
        let mut p = params(1);
        p.joints[0].gains.damping = 40.0; // h·B/I = 2 at 1 kHz
        let e = p.validate(&ids, 1000.0).unwrap_err();
        assert!(e.contains("joint 1") && e.contains("h·B/I"), "{e}");
        let mut p = params(1);
        p.joints[0].gains.inertia = 0.0;
        assert!(p.validate(&ids, 1000.0).unwrap_err().contains("inertia"));
        let mut p = params(1);
        p.joints[0].limits.position_min = 4.0;
        assert!(p.validate(&ids, 1000.0).unwrap_err().contains("position_min"));
        let mut p = params(1);
        p.sensor.lowpass_hz = 600.0;
        assert!(p.validate(&ids, 1000.0).unwrap_err().contains("lowpass_hz"));
        let mut p = params(1);
        p.sensor.deadband = f64::NAN;
        assert!(p.validate(&ids, 1000.0).is_err());
        assert!(params(1).validate(&ids, 1000.0).is_ok());
    }

    /// Each value just outside the envelope, one at a time: refused, and the reason names the key
    /// without echoing a long number.
    #[test]
    fn the_envelope_bounds_every_value() {
        type Mutation = fn(&mut LoopParams);
        let cases: [(&str, Mutation); 21] = [
            ("passivity_guard", |p| p.joints[0].passivity.guard = 0.5),
            ("passivity_guard", |p| p.joints[0].passivity.guard = f64::NAN),
            ("passivity_margin", |p| p.joints[0].passivity.margin = 0.0),
            ("passivity_margin", |p| p.joints[0].passivity.margin = f64::INFINITY),
            ("passivity_damping_max", |p| p.joints[0].passivity.damping_max = -1.0),
            ("virtual_inertia", |p| p.joints[0].gains.inertia = 1e-20),
            ("virtual_inertia", |p| p.joints[0].gains.inertia = 1e300),
            ("virtual_damping", |p| p.joints[0].gains.damping = f64::INFINITY),
            ("virtual_coulomb", |p| p.joints[0].gains.coulomb = 1e300),
            ("lever_arm", |p| p.joints[0].gains.lever_arm = 0.0),
            ("lever_arm", |p| p.joints[0].gains.lever_arm = -1e9),
            ("position_max", |p| p.joints[0].limits.position_max = 100.0),
            ("position_min", |p| p.joints[0].limits.position_min = -3.2),
            ("velocity_max", |p| p.joints[0].limits.velocity_max = 1e300),
            ("velocity_max", |p| p.joints[0].limits.velocity_max = f64::NAN),
            ("acceleration_max", |p| p.joints[0].limits.acceleration_max = -1.0),
            ("deadband", |p| p.sensor.deadband = 1e300),
            ("stale_timeout_ms", |p| p.sensor.stale_timeout_ms = 1e12),
            ("ramp_time_s", |p| p.ramp_time_s = 1e9),
            ("bias", |p| p.bias[3] = 1e300),
            ("lowpass_hz", |p| p.sensor.lowpass_hz = f64::NAN),
        ];
        for (key, mutate) in cases {
            let mut p = params(1);
            mutate(&mut p);
            let e = p.validate(&reach(1), 1000.0).unwrap_err();
            assert!(e.contains(key.trim_start_matches("virtual_")), "{key}: {e}");
            assert!(e.len() < 200, "{key}: a short reason, got {e}");
        }
    }

    #[test]
    fn short_numbers_read_like_printf_g() {
        assert_eq!(short(0.05), "0.05");
        assert_eq!(short(1e300), "1e300");
        assert_eq!(short(-1.234567891e-20), "-1.23457e-20");
        assert_eq!(short(f64::NAN), "NaN");
    }

    #[test]
    fn long_names_are_not_echoed_in_full() {
        let mut p = params(1);
        let name = "x".repeat(100_000);
        let e = p.set(&[1], &name, ParamValue::Scalar(1.0)).unwrap_err();
        assert!(e.len() < 400, "{}", e.len());
    }

    #[test]
    fn compensation_needs_a_servo_model_and_a_weight_in_0_1() {
        let (ids, reach) = ([1], reach(1));
        let mut p = params(1);
        p.set(&ids, "servo_compensation", ParamValue::Scalar(1.0)).unwrap();
        assert!(p.validate(&reach, 1000.0).unwrap_err().contains("[servo]"));
        p.joints[0].servo = Some(ServoModel::first_order_lag(0.02));
        assert_eq!(p.validate(&reach, 1000.0), Ok(()));
        for bad in [1.5, -0.1, f64::NAN] {
            p.set(&ids, "1.servo_compensation", ParamValue::Scalar(bad)).unwrap();
            assert!(p.validate(&reach, 1000.0).unwrap_err().contains("servo_compensation"), "{bad}");
        }
        p.joints[0].compensation = 0.0;
        p.joints[0].servo = Some(ServoModel { time_constant: -1.0, ..ServoModel::first_order_lag(0.02) });
        assert!(p.validate(&reach, 1000.0).unwrap_err().contains("time_constant"));
    }

    #[test]
    fn a_ramp_between_stable_sets_stays_stable() {
        // h·B/I < 1 is linear in (I, B): every convex mix of two stable sets is stable.
        let a = JointGains { inertia: 0.001, damping: 0.9, coulomb: 0.0, lever_arm: 0.1 };
        let b = JointGains { inertia: 0.5, damping: 0.0, coulomb: 0.3, lever_arm: 0.1 };
        for k in 0..=100 {
            let g = a.lerp(&b, k as f64 / 100.0);
            assert!(check_stable(&g.admittance(), 1e-3).is_ok());
        }
    }

    #[test]
    fn the_ramp_ends_exactly_on_its_target_and_never_rounds_to_zero() {
        // The case: 0.02 → 1e-20 with the affine form a + s·(b − a) gave exactly 0 at s = 1.
        let a = JointGains { inertia: 0.02, damping: 0.0, coulomb: 0.0, lever_arm: 0.1 };
        let b = JointGains { inertia: 1e-20, ..a };
        assert_eq!(a.lerp(&b, 1.0), b);
        assert!((0..=1000).all(|k| a.lerp(&b, k as f64 / 1000.0).inertia >= 1e-20));
    }

    proptest::proptest! {
        /// Any two sets the gate accepts: every point of the ramp between them is usable and
        /// (up to rounding) stable, so a ramp cannot pass through an invalid set.
        #[test]
        fn every_point_of_a_ramp_between_accepted_sets_is_valid(
            a in accepted_gains(), b in accepted_gains(), s in 0.0f64..=1.0,
        ) {
            let g = a.lerp(&b, s);
            proptest::prop_assert!(g.usable());
            proptest::prop_assert!(g.inertia >= a.inertia.min(b.inertia) * (1.0 - 1e-12));
            proptest::prop_assert!(1e-3 * g.damping / g.inertia < 1.0 + 1e-9);
        }
    }

    /// Gains that pass `validate` at 1 kHz (drawn across the whole envelope, log-uniform).
    pub fn accepted_gains() -> impl proptest::strategy::Strategy<Value = JointGains> {
        use proptest::prelude::*;
        (-6.0f64..3.0, 0.0f64..1.0, 0.0f64..envelope::COULOMB_MAX, -4.0f64..1.0, any::<bool>()).prop_filter_map(
            "the set must pass the gate",
            |(log_i, b_frac, coulomb, log_l, flip)| {
                let inertia = 10f64.powf(log_i);
                // h·B/I < 1 at 1 kHz: B below 1000·I, and within the envelope.
                let damping = (b_frac * 999.0 * inertia).min(envelope::DAMPING_MAX);
                let lever_arm = 10f64.powf(log_l) * if flip { -1.0 } else { 1.0 };
                let g = JointGains { inertia, damping, coulomb, lever_arm };
                let mut p = params(1);
                p.joints[0].gains = g;
                p.validate(&reach(1), 1000.0).ok().map(|_| g)
            },
        )
    }
}
