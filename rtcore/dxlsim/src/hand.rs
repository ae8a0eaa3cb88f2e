//! The simulated bench's other truths about the horn: a hand that grips it, and a servo that
//! simply lags its goal.
//!
//! **A gripping hand.** A scripted hand torque is a pure force source: whatever the horn does,
//! the sensor reads the script, so nothing the loop does can feed back through the hand. A real
//! hand has inertia, damping and stiffness of its own, and the sensor between it and the horn
//! measures the torque the hand *transmits*: the muscle's torque minus what it takes to move the
//! hand with the horn. That coupling is what makes a too-light virtual joint oscillate
//! (Keemink et al., IJRR 2018: the rendered inertia against the inertia behind the sensor), so
//! the bench models it: the hand's inertia rides on the horn, its damping and stiffness pull
//! the horn towards where it gripped, and `Hand::sensed` is what the sensor reads.
//!
//! **A first-order-lag servo.** `first_order_lag` replaces the firmware and motor by a horn
//! that follows its goal as θ' = (goal − θ)/T, whatever pushes on it: a servo of another kind
//! than the BAM-style MX model, for checks that must not be fitted by the model that made them.
use plant::State;

/// A hand on the horn: inertia (kg·m²), damping (N·m·s/rad), stiffness (N·m/rad) about `anchor`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Hand {
    pub inertia: f64,
    pub damping: f64,
    pub stiffness: f64,
    /// The angle where the hand gripped the horn (its spring's rest).
    pub anchor: f64,
    /// The torque the sensor read at the end of the last substep.
    pub sensed: f64,
}

impl Hand {
    /// Checks the constants (each finite and ≥ 0).
    pub fn new(inertia: f64, damping: f64, stiffness: f64, anchor: f64) -> Result<Hand, String> {
        for (name, v) in [("inertia", inertia), ("damping", damping), ("stiffness", stiffness)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("hand {name} must be finite and >= 0, got {v}"));
            }
        }
        Ok(Hand { inertia, damping, stiffness, anchor, sensed: 0.0 })
    }

    /// The muscle's torque plus the arm's damping and spring at `state`: what acts on the horn
    /// besides the hand's inertia.
    pub fn applied(&self, muscle: f64, state: &State) -> f64 {
        muscle - self.damping * state.omega - self.stiffness * (state.theta - self.anchor)
    }

    /// What the sensor between hand and horn reads once the horn accelerated by `alpha`.
    pub fn record(&mut self, applied: f64, alpha: f64) {
        self.sensed = applied - self.inertia * alpha;
    }
}

/// One substep of a horn that lags its goal by `time_constant` (exactly: an exponential).
pub fn follow_lag(state: &mut State, goal: f64, time_constant: f64, h: f64) {
    let before = state.theta;
    state.theta = goal + (before - goal) * (-h / time_constant).exp();
    state.omega = (state.theta - before) / h;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lagging_horn_reaches_63_percent_in_one_time_constant() {
        let mut s = State::default();
        for _ in 0..250 {
            follow_lag(&mut s, 1.0, 0.025, 1e-4);
        }
        assert!((s.theta - (1.0 - (-1.0f64).exp())).abs() < 1e-9);
    }

    #[test]
    fn the_sensor_reads_the_muscle_minus_the_arms_impedance() {
        let mut hand = Hand::new(0.005, 0.1, 2.0, 0.1).unwrap();
        let applied = hand.applied(0.5, &State { theta: 0.2, omega: 1.0 });
        assert!((applied - (0.5 - 0.1 - 0.2)).abs() < 1e-12);
        hand.record(applied, 10.0);
        assert!((hand.sensed - (0.2 - 0.05)).abs() < 1e-12);
        assert!(Hand::new(-1.0, 0.0, 0.0, 0.0).is_err());
    }
}
