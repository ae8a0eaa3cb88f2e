//! A trial (sample times, applied torque, load) and its simulation at the sample times.
//!
//! Between consecutive samples `t[i]` → `t[i+1]` the simulator takes n equal substeps,
//! `n = ceil((t[i+1] − t[i]) / max_step)`, so non-uniform sampling needs no resampling and every
//! sample time is hit exactly (no interpolation of the state). The ceiling forgives a
//! relative 1e-9 of rounding, so an interval that is a whole number of steps in decimal does
//! not get an extra substep from binary arithmetic.
//!
//! The applied torque is linearly interpolated at (substep time − time_delay), held at the
//! end values outside the series. A cursor walks the series as time advances, so each lookup
//! is O(1) and a simulation allocates nothing.
use crate::error::{require_finite, PlantError};
use crate::friction::FrictionLaw;
use crate::lanes::{simulate_lanes, Run};
use crate::model::{Load, State};
use crate::params::Params;

/// The inputs of one experiment, copied once and simulated many times.
#[derive(Debug, Clone, PartialEq)]
pub struct Trial {
    t: Vec<f64>,
    tau: Option<Vec<f64>>,
    load: Load,
}

impl Trial {
    /// Checks and takes the arrays: `t` strictly increasing and finite, `tau` (when given) of
    /// the same length and finite, the load's inertia finite and ≥ 0.
    pub fn new(t: Vec<f64>, tau: Option<Vec<f64>>, load: Load) -> Result<Self, PlantError> {
        if t.is_empty() {
            return Err(PlantError::Shape("a trial needs at least one sample time".into()));
        }
        for (i, &ti) in t.iter().enumerate() {
            require_finite(&format!("t[{i}]"), ti)?;
        }
        if let Some(i) = t.windows(2).position(|w| w[1] <= w[0]) {
            return Err(PlantError::InvalidValue(format!(
                "t must be strictly increasing: t[{}] = {} follows t[{}] = {}",
                i + 1,
                t[i + 1],
                i,
                t[i]
            )));
        }
        if let Some(tau) = &tau {
            if tau.len() != t.len() {
                return Err(PlantError::Shape(format!(
                    "tau has {} samples but t has {}",
                    tau.len(),
                    t.len()
                )));
            }
            for (i, &v) in tau.iter().enumerate() {
                require_finite(&format!("tau[{i}]"), v)?;
            }
        }
        require_finite("load_inertia", load.inertia)?;
        require_finite("gravity_torque", load.gravity_torque)?;
        if load.inertia < 0.0 {
            return Err(PlantError::InvalidValue(format!(
                "load_inertia must be >= 0, got {}",
                load.inertia
            )));
        }
        Ok(Trial { t, tau, load })
    }

    pub fn n_samples(&self) -> usize {
        self.t.len()
    }

    /// Last sample time minus the first.
    pub fn duration(&self) -> f64 {
        self.t[self.t.len() - 1] - self.t[0]
    }

    pub fn t(&self) -> &[f64] {
        &self.t
    }

    pub fn tau(&self) -> Option<&[f64]> {
        self.tau.as_deref()
    }

    pub fn load(&self) -> Load {
        self.load
    }

    pub(crate) fn load_ref(&self) -> &Load {
        &self.load
    }

    /// Substeps the simulation takes at `max_step` (for throughput figures).
    pub fn substeps(&self, max_step: f64) -> u64 {
        self.t.windows(2).map(|w| substep_count(w[1] - w[0], max_step) as u64).sum()
    }
}

/// Number of equal substeps for a sample interval `dt` at most `max_step` long.
#[inline]
pub fn substep_count(dt: f64, max_step: f64) -> usize {
    ((dt / max_step) - 1e-9).ceil().max(1.0) as usize
}

/// A checked torque series with its interpolating cursor (for `inverse::corrected_torque`).
pub struct TorqueSeries<'a> {
    cursor: TorqueCursor<'a>,
}

impl<'a> TorqueSeries<'a> {
    /// `t` strictly increasing and finite, `tau` finite and of the same (non-zero) length.
    pub fn new(t: &'a [f64], tau: &'a [f64]) -> Result<Self, PlantError> {
        if t.is_empty() || t.len() != tau.len() {
            return Err(PlantError::Shape(format!(
                "t and tau must have one non-zero length, got {} and {}",
                t.len(),
                tau.len()
            )));
        }
        for (i, (&ti, &v)) in t.iter().zip(tau).enumerate() {
            require_finite(&format!("t[{i}]"), ti)?;
            require_finite(&format!("tau[{i}]"), v)?;
        }
        if let Some(i) = t.windows(2).position(|w| w[1] <= w[0]) {
            return Err(PlantError::InvalidValue(format!("t must be strictly increasing at t[{}]", i + 1)));
        }
        Ok(TorqueSeries { cursor: TorqueCursor::new(t, tau) })
    }

    /// The torque at time `q`, linearly interpolated, held at the end values outside the series.
    pub fn at(&mut self, q: f64) -> f64 {
        self.cursor.at(q)
    }
}

/// Linear interpolation in a time series whose queries mostly move forward (the applied torque
/// here; the servo model's goal and torque in `crate::servo`).
pub(crate) struct TorqueCursor<'a> {
    t: &'a [f64],
    tau: &'a [f64],
    j: usize,
    /// Slope of the segment [t[j], t[j+1]], kept so a lookup in the same segment (most of
    /// them: several substeps per sample) costs no division.
    slope: f64,
}

impl<'a> TorqueCursor<'a> {
    pub(crate) fn new(t: &'a [f64], tau: &'a [f64]) -> Self {
        let mut cursor = TorqueCursor { t, tau, j: 0, slope: 0.0 };
        cursor.update_slope();
        cursor
    }

    fn update_slope(&mut self) {
        let (t, tau, j) = (self.t, self.tau, self.j);
        if j + 1 < t.len() {
            self.slope = (tau[j + 1] - tau[j]) / (t[j + 1] - t[j]);
        }
    }

    #[inline]
    pub(crate) fn at(&mut self, q: f64) -> f64 {
        let (t, tau) = (self.t, self.tau);
        let last = t.len() - 1;
        if q <= t[0] {
            return tau[0];
        }
        if q >= t[last] {
            return tau[last];
        }
        let start = self.j;
        while q < t[self.j] {
            self.j -= 1;
        }
        while q >= t[self.j + 1] {
            self.j += 1;
        }
        if self.j != start {
            self.update_slope();
        }
        tau[self.j] + self.slope * (q - t[self.j])
    }

    /// The torque at `q` and its rate of change there (0 where the series is held at an end
    /// value): what a sensitivity to the time delay needs.
    #[inline]
    pub(crate) fn at_with_rate(&mut self, q: f64) -> (f64, f64) {
        let value = self.at(q);
        let inside = q > self.t[0] && q < self.t[self.t.len() - 1];
        (value, if inside { self.slope } else { 0.0 })
    }
}

/// `Ok(())` when `max_step` is a usable substep bound.
pub fn validate_max_step(max_step: f64) -> Result<(), PlantError> {
    if max_step.is_finite() && max_step > 0.0 {
        Ok(())
    } else {
        Err(PlantError::InvalidValue(format!("max_step must be finite and > 0, got {max_step}")))
    }
}

/// Simulates `trial` from `x0` and hands the state at every sample time to `record(i, &state)`
/// (i = 0 is `x0` itself). Expects validated `p` and `max_step`.
///
/// Gain, bias and drift correct a *measured* torque, so on a trial without `tau` they are left
/// out (the applied torque is then truly zero; the gain multiplies that zero). Drift is counted from the trial's first sample.
///
/// A trial with no applied torque (a drop) that comes to rest for good under stick friction
/// (`model::rests_for_good`) is not stepped further: its remaining samples are filled with the
/// rest state, the numbers `step` would have given to the bit. A drop spends most of its record
/// at rest, so this is most of the identification's simulation time.
pub fn simulate_into<F: FnMut(usize, &State)>(
    trial: &Trial,
    p: &Params,
    law: FrictionLaw,
    x0: State,
    max_step: f64,
    mut record: F,
) {
    simulate_lanes([Run { trial, params: p, x0 }], law, max_step, |_, i, state| record(i, state));
}

/// One event of a walk through sample times (`walk`).
pub(crate) enum Walk {
    /// A substep that starts at `t` and lasts `h`.
    Substep { t: f64, h: f64 },
    /// Sample `i` is reached (0 first, before any substep).
    Sample(usize),
}

/// Walks the intervals between consecutive times of `t` in equal substeps of at most
/// `max_step` (`substep_count`), telling `visit` each substep and each sample reached: the
/// stepping scheme of the servo's simulator and the sensitivities, and of each lane of
/// `lanes::simulate_lanes` (which walks its lanes' trials side by side instead).
#[inline(always)]
pub(crate) fn walk(t: &[f64], max_step: f64, mut visit: impl FnMut(Walk)) {
    visit(Walk::Sample(0));
    for i in 1..t.len() {
        let n = substep_count(t[i] - t[i - 1], max_step);
        let h = (t[i] - t[i - 1]) / n as f64;
        for k in 0..n {
            visit(Walk::Substep { t: t[i - 1] + k as f64 * h, h });
        }
        visit(Walk::Sample(i));
    }
}

/// Simulates one trial and returns the state at every sample time (checks its inputs).
pub fn simulate(
    trial: &Trial,
    p: &Params,
    law: FrictionLaw,
    x0: State,
    max_step: f64,
) -> Result<Vec<State>, PlantError> {
    p.validate()?;
    validate_max_step(max_step)?;
    require_finite("theta0", x0.theta)?;
    require_finite("omega0", x0.omega)?;
    let mut out = vec![State::default(); trial.n_samples()];
    simulate_into(trial, p, law, x0, max_step, |i, s| out[i] = *s);
    Ok(out)
}
