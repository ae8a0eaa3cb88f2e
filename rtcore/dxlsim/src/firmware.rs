//! The servo firmware's controllers: from goal registers to a PWM duty cycle.
//!
//! Position modes use BAM's measured MX law, duty = error_gain · kp_fw · e (e in rad), where
//! kp_fw is the P gain in P1 firmware units (default 32). Both firmwares scale their raw gains
//! to one "real" gain (e-manual: P1 Kp = P/8, Ki = I·1000/2048, Kd = D·4/1000; P2 Kp = P/128,
//! Ki = I/65536, Kd = D/16), so one controller serves both: kp_fw = 8·Kp, and the I and D terms
//! are scaled the same way (duty = 8·error_gain·(Kp·e + Ki·∫e + Kd·ė)). That the I and D terms
//! share BAM's scale is our assumption: BAM fitted P-only logs.
//!
//! The goal is approached through a velocity-limited setpoint (P2 Profile Velocity, P1 Moving
//! Speed; 0 = unlimited), which is how the firmware's trajectory profile looks to a pendulum at
//! these speeds; profile acceleration is not modelled.
use crate::motor::ERROR_GAIN;

/// Raw control-table gains to the firmware's "real" gains, per protocol.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gains {
    pub kp: f64,
    pub ki: f64,
    pub kd: f64,
}

impl Gains {
    pub fn from_p1(p: i64, i: i64, d: i64) -> Gains {
        Gains { kp: p as f64 / 8.0, ki: i as f64 * 1000.0 / 2048.0, kd: d as f64 * 4.0 / 1000.0 }
    }

    pub fn from_p2(p: i64, i: i64, d: i64) -> Gains {
        Gains { kp: p as f64 / 128.0, ki: i as f64 / 65536.0, kd: d as f64 / 16.0 }
    }
}

/// How the firmware turns goals into duty.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mode {
    /// Position control (P2 modes 3, 4, 5; P1 joint and multi-turn modes).
    Position,
    /// P2 velocity mode: a proportional velocity loop on Goal Velocity.
    Velocity,
    /// P2 PWM mode: Goal PWM is the duty.
    Pwm,
    /// P2 current mode: the duty that drives Goal Current at the present speed.
    Current,
    /// P1 wheel mode (both angle limits 0): Moving Speed is an open-loop output, sign-magnitude.
    Wheel,
}

impl Mode {
    /// The P2 Operating Mode value's mode; unknown values fall back to position (the default).
    pub fn from_p2(value: i64) -> Mode {
        match value {
            0 => Mode::Current,
            1 => Mode::Velocity,
            16 => Mode::Pwm,
            _ => Mode::Position,
        }
    }
}

/// The position controller's memory: the profiled setpoint, the integral and the last error.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PositionController {
    pub setpoint: f64,
    integral: f64,
    last_error: f64,
}

impl PositionController {
    /// Restarts from rest at `theta`: what happens when torque is enabled or the mode changes.
    pub fn reset(&mut self, theta: f64) {
        *self = PositionController { setpoint: theta, integral: 0.0, last_error: 0.0 };
    }

    /// Moves the setpoint toward `goal` at most `max_rate` rad/s (None = jump), then returns the
    /// unclipped duty for the error at `theta`. The integral stops growing once its own
    /// contribution alone saturates `duty_limit` (anti-windup).
    pub fn duty(&mut self, goal: f64, max_rate: Option<f64>, theta: f64, gains: Gains, duty_limit: f64, h: f64) -> f64 {
        self.setpoint = match max_rate {
            Some(rate) => self.setpoint + (goal - self.setpoint).clamp(-rate * h, rate * h),
            None => goal,
        };
        let error = self.setpoint - theta;
        let scale = 8.0 * ERROR_GAIN;
        if gains.ki > 0.0 {
            let bound = duty_limit / (scale * gains.ki);
            self.integral = (self.integral + error * h).clamp(-bound, bound);
        }
        let derivative = (error - self.last_error) / h;
        self.last_error = error;
        scale * (gains.kp * error + gains.ki * self.integral + gains.kd * derivative)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn p1_default_gain_reproduces_bams_law() {
        let gains = Gains::from_p1(32, 0, 0);
        let mut c = PositionController::default();
        let duty = c.duty(0.1, None, 0.0, gains, 1.0, 1e-3);
        assert!((duty - ERROR_GAIN * 32.0 * 0.1).abs() < 1e-12);
    }

    #[test]
    fn p2_gain_128_equals_p1_gain_8() {
        let (mut a, mut b) = (PositionController::default(), PositionController::default());
        let da = a.duty(0.3, None, 0.0, Gains::from_p2(128, 0, 0), 1.0, 1e-3);
        let db = b.duty(0.3, None, 0.0, Gains::from_p1(8, 0, 0), 1.0, 1e-3);
        assert!((da - db).abs() < 1e-12);
    }

    #[test]
    fn setpoint_moves_at_the_profile_rate() {
        let mut c = PositionController::default();
        c.reset(0.0);
        for _ in 0..100 {
            c.duty(1.0, Some(2.0), 0.0, Gains::from_p2(850, 0, 0), 1.0, 1e-3);
        }
        assert!((c.setpoint - 0.2).abs() < 1e-9);
    }

    #[test]
    fn integral_is_bounded_by_the_duty_limit() {
        let mut c = PositionController::default();
        let gains = Gains::from_p2(0, 1000, 0);
        let mut duty = 0.0;
        for _ in 0..100_000 {
            duty = c.duty(1.0, None, 0.0, gains, 0.5, 1e-3);
        }
        assert!(duty <= 0.5 + 1e-9, "duty {duty}");
    }

    #[test]
    fn unknown_operating_modes_fall_back_to_position() {
        assert_eq!(Mode::from_p2(3), Mode::Position);
        assert_eq!(Mode::from_p2(16), Mode::Pwm);
        assert_eq!(Mode::from_p2(42), Mode::Position);
    }
}
