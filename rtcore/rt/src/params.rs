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
//! `acceleration_max`, `servo_compensation` (bare = every joint, `"<id>.name"` = one joint, an
//! optional `limits.` before the limit names); loop-wide `deadband`, `lowpass_hz`,
//! `stale_timeout_ms`, `ramp_time_s` and `bias` (6 numbers).
use plant::admittance::{check_stable, AdmittanceParams};
use plant::servo::ServoModel;

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
    pub fn admittance(&self) -> AdmittanceParams {
        AdmittanceParams { inertia: self.inertia, damping: self.damping, coulomb: self.coulomb }
    }

    /// `self + s·(to − self)`, field by field.
    pub fn lerp(&self, to: &JointGains, s: f64) -> JointGains {
        let mix = |a: f64, b: f64| a + s * (b - a);
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

const JOINT_KEYS: [&str; 9] = [
    "virtual_inertia",
    "virtual_damping",
    "virtual_coulomb",
    "lever_arm",
    "position_min",
    "position_max",
    "velocity_max",
    "acceleration_max",
    "servo_compensation",
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
        _ => return None,
    })
}

/// The value of a joint key (for `params()`).
pub fn joint_value(j: &JointParams, key: &str) -> Option<f64> {
    let mut copy = *j;
    joint_field(&mut copy, key).map(|v| *v)
}

/// Splits `"3.limits.position_max"` into (Some(3), "position_max").
fn split_name(name: &str) -> Result<(Option<u8>, &str), String> {
    let (id, key) = match name.split_once('.') {
        Some((head, rest)) if head.chars().all(|c| c.is_ascii_digit()) && !head.is_empty() => {
            let id = head.parse::<u8>().map_err(|_| format!("'{name}': joint id {head} is not 0..=253"))?;
            (Some(id), rest)
        }
        _ => (None, name),
    };
    Ok((id, key.strip_prefix("limits.").unwrap_or(key)))
}

fn scalar(name: &str, value: ParamValue) -> Result<f64, String> {
    match value {
        ParamValue::Scalar(v) => Ok(v),
        ParamValue::Vector(_) => Err(format!("'{name}' takes one number, not a list")),
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
                        .ok_or_else(|| format!("'{name}': no joint with id {id} (joints: {ids:?})"))?,
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
            return Err(format!("unknown parameter '{name}' (known: {})", known.join(", ")));
        }
        if id.is_some() {
            return Err(format!("'{name}': '{key}' is loop-wide and takes no joint id"));
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

    /// Checks the whole set for a loop running at `rate_hz`; the error names the joint and key.
    pub fn validate(&self, ids: &[u8], rate_hz: f64) -> Result<(), String> {
        let h = 1.0 / rate_hz;
        for (joint, id) in self.joints.iter().zip(ids) {
            validate_joint(joint, h).map_err(|reason| format!("joint {id}: {reason}"))?;
        }
        let s = &self.sensor;
        require(s.deadband.is_finite() && s.deadband >= 0.0, "deadband", s.deadband, "finite and >= 0")?;
        require(
            s.lowpass_hz.is_finite() && s.lowpass_hz >= 0.0 && s.lowpass_hz < rate_hz / 2.0,
            "lowpass_hz",
            s.lowpass_hz,
            &format!("in [0, {}) (0 = off; below half the loop rate)", rate_hz / 2.0),
        )?;
        require(
            s.stale_timeout_ms.is_finite() && s.stale_timeout_ms > 0.0,
            "stale_timeout_ms",
            s.stale_timeout_ms,
            "finite and > 0",
        )?;
        require(self.ramp_time_s.is_finite() && self.ramp_time_s >= 0.0, "ramp_time_s", self.ramp_time_s, "finite and >= 0")?;
        if let Some(b) = self.bias.iter().find(|b| !b.is_finite()) {
            return Err(format!("bias must be 6 finite numbers, got {b}"));
        }
        Ok(())
    }
}

fn require(ok: bool, name: &str, value: f64, what: &str) -> Result<(), String> {
    if ok {
        Ok(())
    } else {
        Err(format!("{name} must be {what}, got {value}"))
    }
}

fn validate_joint(j: &JointParams, h: f64) -> Result<(), String> {
    check_stable(&j.gains.admittance(), h)?;
    require(j.gains.lever_arm.is_finite(), "lever_arm", j.gains.lever_arm, "finite")?;
    let l = &j.limits;
    require(l.position_min.is_finite(), "position_min", l.position_min, "finite")?;
    require(l.position_max.is_finite(), "position_max", l.position_max, "finite")?;
    if l.position_min >= l.position_max {
        return Err(format!(
            "position_min ({}) must be below position_max ({})",
            l.position_min, l.position_max
        ));
    }
    require(l.velocity_max.is_finite() && l.velocity_max > 0.0, "velocity_max", l.velocity_max, "finite and > 0")?;
    require(
        l.acceleration_max.is_finite() && l.acceleration_max > 0.0,
        "acceleration_max",
        l.acceleration_max,
        "finite and > 0",
    )?;
    validate_compensation(j)
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
        }
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
        let ids = [1];
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

    #[test]
    fn compensation_needs_a_servo_model_and_a_weight_in_0_1() {
        let ids = [1];
        let mut p = params(1);
        p.set(&ids, "servo_compensation", ParamValue::Scalar(1.0)).unwrap();
        assert!(p.validate(&ids, 1000.0).unwrap_err().contains("[servo]"));
        p.joints[0].servo = Some(ServoModel::first_order_lag(0.02));
        assert_eq!(p.validate(&ids, 1000.0), Ok(()));
        for bad in [1.5, -0.1, f64::NAN] {
            p.set(&ids, "1.servo_compensation", ParamValue::Scalar(bad)).unwrap();
            assert!(p.validate(&ids, 1000.0).unwrap_err().contains("servo_compensation"), "{bad}");
        }
        p.joints[0].compensation = 0.0;
        p.joints[0].servo = Some(ServoModel { time_constant: -1.0, ..ServoModel::first_order_lag(0.02) });
        assert!(p.validate(&ids, 1000.0).unwrap_err().contains("time_constant"));
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
}
