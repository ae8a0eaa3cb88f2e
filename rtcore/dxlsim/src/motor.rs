//! The servo's DC motor and its PWM drive, after BAM's MX model
//! (Duclusaud et al., ICRA 2025; ../shared/docs/identification-anchors.md §1.2).
//!
//! The firmware turns a control effort into a PWM duty cycle; the H-bridge applies `vin·duty`
//! to the motor; the motor's torque is `kt/R·V − kt²/R·ω` (the second term is back-EMF braking).
//! With torque disabled the bridge is open: no torque and no back-EMF braking (the horn coasts).
//!
//! Why BAM's model and not a current loop: MX firmware in position mode is a voltage (PWM)
//! controller, and BAM measured its two constants on MX servos with an oscilloscope:
//! `error_gain = 0.158` (duty per rad of error per unit of P1 firmware P gain) and
//! `max_pwm = 0.9625` (the duty cap). Their fits give kt and R for MX-64 and MX-106 (model M1);
//! MX-28 has no BAM fit, so its kt and R come from its datasheet (see `for_model`).

/// BAM's measured duty per (rad × P1 firmware P gain unit), MX series.
pub const ERROR_GAIN: f64 = 0.158;
/// BAM's measured maximum duty cycle, MX series.
pub const MAX_PWM: f64 = 0.9625;

/// Electrical constants of one servo's motor, seen at the output shaft.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motor {
    /// Torque constant at the output shaft, N·m/A (= back-EMF constant, V·s/rad).
    pub kt: f64,
    /// Winding resistance, Ω.
    pub resistance: f64,
    /// Supply voltage, V.
    pub vin: f64,
}

impl Motor {
    /// Constants for a model name ("MX-28", "MX-64", "MX-106"); None for an unknown model.
    ///
    /// - MX-64: kt 1.62, R 3.95 (BAM model M1 fit, bam/params/mx64/m1.json).
    /// - MX-106: kt 2.19, R 2.96 (BAM model M1 fit, bam/params/mx106/m1.json).
    /// - MX-28: from the datasheet at 12 V (55 rpm no load, 2.5 N·m stall): kt = V/ω₀ = 2.08,
    ///   R = kt·V/τ_stall = 10.0 Ω. The same recipe on MX-64's datasheet gives kt 1.82, R 3.6,
    ///   close to BAM's fit, which is why it is used here rather than stall torque/stall current.
    pub fn for_model(model: &str, vin: f64) -> Option<Motor> {
        let (kt, resistance) = match model {
            "MX-28" => (2.08, 10.0),
            "MX-64" => (1.62, 3.95),
            "MX-106" => (2.19, 2.96),
            _ => return None,
        };
        Some(Motor { kt, resistance, vin })
    }

    /// Output torque for a duty cycle in [-1, 1] at shaft speed `omega` (rad/s).
    pub fn torque(&self, duty: f64, omega: f64) -> f64 {
        self.kt / self.resistance * (self.vin * duty) - self.kt * self.kt / self.resistance * omega
    }

    /// Winding current (A) for a duty cycle at shaft speed `omega`.
    pub fn current(&self, duty: f64, omega: f64) -> f64 {
        (self.vin * duty - self.kt * omega) / self.resistance
    }

    /// The duty that drives `current` (A) at speed `omega`: what a current-mode firmware applies.
    pub fn duty_for_current(&self, current: f64, omega: f64) -> f64 {
        (current * self.resistance + self.kt * omega) / self.vin
    }

    /// Stall torque at full duty (N·m): the scale of MX-28(2.0)'s and P1's "Present Load".
    pub fn stall_torque(&self) -> f64 {
        self.kt / self.resistance * self.vin * MAX_PWM
    }
}

/// Clips a duty cycle to ±`limit`.
pub fn clip_duty(duty: f64, limit: f64) -> f64 {
    duty.clamp(-limit, limit)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn back_emf_brakes_and_stall_torque_matches_the_datasheet_scale() {
        let m = Motor::for_model("MX-64", 12.0).unwrap();
        assert!(m.torque(0.0, 1.0) < 0.0);
        assert!(m.torque(0.0, -1.0) > 0.0);
        // No-load speed: torque is zero where V·duty = kt·ω.
        let omega0 = 12.0 * 0.5 / m.kt;
        assert!(m.torque(0.5, omega0).abs() < 1e-12);
        // BAM's fit gives a stall torque of the datasheet's order (6 N·m at 12 V).
        let stall = m.stall_torque();
        assert!((4.0..7.0).contains(&stall), "stall {stall}");
    }

    #[test]
    fn current_and_duty_for_current_are_inverse() {
        let m = Motor::for_model("MX-106", 14.8).unwrap();
        for &(i, w) in &[(0.3, 0.0), (-1.2, 2.0), (2.0, -3.5)] {
            let d = m.duty_for_current(i, w);
            assert!((m.current(d, w) - i).abs() < 1e-12);
        }
    }

    #[test]
    fn unknown_models_have_no_constants() {
        assert!(Motor::for_model("AX-12", 12.0).is_none());
    }
}
