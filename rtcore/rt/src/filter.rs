//! Force conditioning between the sensor and the model: tare, deadband, low-pass.
//!
//! Why a deadband with a smooth edge: a biased or noisy sensor makes a pure admittance creep
//! (the most common complaint about admittance set-ups); a hard deadband stops the creep but
//! puts a force step at its edge that the user feels as a click. The quadratic edge used here is
//! C¹: zero and flat up to `d`, a parabola from `d` to `2d`, then the force minus `1.5·d`.
//!
//! Why a cutoff in Hz: `y += α·(x − y)` with a bare α (ros2's filter_coefficient) means nothing
//! to a user without the rate; α = 1 − exp(−2π·f_c·h) gives the same cutoff at any loop rate.

/// The smooth-edged deadband of half-width `d` (≥ 0) applied to one value.
pub fn deadband(x: f64, d: f64) -> f64 {
    let a = x.abs();
    let y = if a <= d {
        0.0
    } else if a < 2.0 * d {
        (a - d) * (a - d) / (2.0 * d)
    } else {
        a - 1.5 * d
    };
    y.copysign(x)
}

/// A first-order low-pass per force component.
#[derive(Debug, Clone, Default)]
pub struct LowPass {
    alpha: f64,
    state: [f64; 6],
    primed: bool,
}

impl LowPass {
    /// Sets the cutoff for a loop step of `h` seconds; 0 Hz turns the filter off.
    pub fn configure(&mut self, cutoff_hz: f64, h: f64) {
        self.alpha = if cutoff_hz > 0.0 { 1.0 - (-2.0 * std::f64::consts::PI * cutoff_hz * h).exp() } else { 1.0 };
    }

    /// Filters one vector; the first one initialises the state, so the filter starts without a ramp.
    pub fn apply(&mut self, x: &[f64; 6]) -> [f64; 6] {
        if !self.primed {
            self.state = *x;
            self.primed = true;
        }
        for (s, v) in self.state.iter_mut().zip(x) {
            *s += self.alpha * (v - *s);
        }
        self.state
    }
}

/// Averages raw samples for a tare request; allocation-free.
#[derive(Debug, Clone, Default)]
pub struct TareAverager {
    sum: [f64; 6],
    have: u32,
    want: u32,
}

impl TareAverager {
    /// Starts averaging the next `n` samples (restarts a tare in progress).
    pub fn request(&mut self, n: u32) {
        *self = TareAverager { want: n.max(1), ..Default::default() };
    }

    pub fn active(&self) -> bool {
        self.want > 0
    }

    /// Adds one raw sample; returns the bias once `n` samples have been seen.
    pub fn add(&mut self, raw: &[f64; 6]) -> Option<[f64; 6]> {
        if !self.active() {
            return None;
        }
        for (s, v) in self.sum.iter_mut().zip(raw) {
            *s += v;
        }
        self.have += 1;
        if self.have < self.want {
            return None;
        }
        let n = self.have as f64;
        let bias = self.sum.map(|s| s / n);
        *self = TareAverager::default();
        Some(bias)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deadband_is_zero_inside_and_continuous_with_slope_one_outside() {
        let d = 2.0;
        assert_eq!(deadband(1.9, d), 0.0);
        assert_eq!(deadband(-2.0, d), 0.0);
        assert_eq!(deadband(10.0, d), 7.0);
        assert_eq!(deadband(-10.0, d), -7.0);
        assert_eq!(deadband(5.0, 0.0), 5.0);
        let eps = 1e-6;
        for edge in [d, 2.0 * d] {
            let jump = deadband(edge + eps, d) - deadband(edge - eps, d);
            assert!(jump.abs() < 1e-5, "value jumps at {edge}");
            let slope_in = (deadband(edge, d) - deadband(edge - eps, d)) / eps;
            let slope_out = (deadband(edge + eps, d) - deadband(edge, d)) / eps;
            assert!((slope_in - slope_out).abs() < 1e-4, "slope jumps at {edge}");
        }
    }

    #[test]
    fn lowpass_reaches_63_percent_after_one_time_constant() {
        let (fc, h) = (10.0, 1e-3);
        let mut lp = LowPass::default();
        lp.configure(fc, h);
        lp.apply(&[0.0; 6]);
        let tau_steps = (1.0 / (2.0 * std::f64::consts::PI * fc) / h).round() as usize;
        let mut y = [0.0; 6];
        for _ in 0..tau_steps {
            y = lp.apply(&[1.0; 6]);
        }
        assert!((y[0] - (1.0 - (-1.0f64).exp())).abs() < 0.01, "{}", y[0]);
        let mut off = LowPass::default();
        off.configure(0.0, h);
        off.apply(&[0.0; 6]);
        assert_eq!(off.apply(&[3.0; 6])[5], 3.0);
    }

    #[test]
    fn tare_averages_exactly_n_samples() {
        let mut t = TareAverager::default();
        assert_eq!(t.add(&[1.0; 6]), None);
        t.request(3);
        assert_eq!(t.add(&[1.0; 6]), None);
        assert_eq!(t.add(&[2.0; 6]), None);
        assert_eq!(t.add(&[6.0; 6]), Some([3.0; 6]));
        assert!(!t.active());
    }

    proptest::proptest! {
        #[test]
        fn deadband_never_grows_a_force_nor_flips_its_sign(x in -1e3f64..1e3, d in 0f64..100.0) {
            let y = deadband(x, d);
            proptest::prop_assert!(y.abs() <= x.abs());
            proptest::prop_assert!(y == 0.0 || y.signum() == x.signum());
        }
    }
}
