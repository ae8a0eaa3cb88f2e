//! Forward sensitivities: the simulated angle and its derivatives with respect to chosen
//! parameters and the initial state, in ONE pass per trial.
//!
//! Identification's Levenberg–Marquardt needs, per iteration, ∂θ(t_i)/∂z for the free
//! parameters and each trial's (θ0, ω0). By finite differences that is 1 + P + 2 simulations;
//! here the plant's own substep (`model::step`, unchanged: the angle is bit for bit the one
//! `trial::simulate_into` gives) is run once and, beside it, the tangent of that substep: the
//! exact derivative of the discrete map, propagated forward (dθ' = dθ + h·dω',
//! dω' = ∂ω'/∂θ·dθ + ∂ω'/∂ω·dω + ∂ω'/∂p). Its cost is that of about two simulations whatever
//! the number of parameters.
//!
//! **Stick friction.** A substep that ends stuck sets ω' = 0 whatever the inputs: its tangent
//! is 0 (the joint stays where it stopped, dθ carries on unchanged). A substep that slips is
//! smooth in everything. So the derivative is the one of the branch the plant took; where a
//! perturbation would change the branch (the step at which the joint sticks or breaks away)
//! the map has a kink, and the one-sided derivative is what a gradient method can use (a
//! finite difference across the kink is a chord, not a slope). The friction level is clipped
//! at 0 (`friction::level`); where the unclipped level is negative its derivative is 0, where
//! it is exactly 0 (no friction at all) the derivative is the upward one, the side a bounded
//! fit can move to.
//!
//! Derivatives of parameters that only act on a measured torque (gain, bias, drift, delay)
//! are 0 on a trial without one, as their effect is (`trial::simulate_into`). The delay's
//! derivative is the torque's rate of change, that of the linear interpolation's segment.
use rayon::prelude::*;

use crate::batch::in_pool;
use crate::error::{require_finite, PlantError};
use crate::friction::{direction, FrictionLaw};
use crate::model::{step, Load, State};
use crate::params::{Params, N_PARAMS};
use crate::trig;
use crate::trial::{validate_max_step, walk, TorqueCursor, Trial, Walk};

/// Parameter indices (`PARAM_NAMES` order) with a closed-form derivative here: all of them.
const MOTOR_INERTIA: usize = 0;
const DAMPING: usize = 1;
const COULOMB: usize = 2;
const COULOMB_ASYM: usize = 3;
const STRIBECK_TORQUE: usize = 4;
const STRIBECK_VELOCITY: usize = 5;
const LOAD_COULOMB: usize = 6;
const ANGLE_OFFSET: usize = 7;
const QUADRATIC_DRAG: usize = 8;
const COGGING_AMPLITUDE: usize = 9;
const COGGING_PERIOD: usize = 10;
const COGGING_PHASE: usize = 11;
const TIME_DELAY: usize = 12;
const TORQUE_BIAS: usize = 13;
const TORQUE_DRIFT: usize = 14;
const TANH_K: usize = 15;
const TORQUE_GAIN: usize = 16;
const SPRING_STIFFNESS: usize = 17;
const SPRING_NEUTRAL: usize = 18;
const RIPPLE_AMPLITUDE: usize = 19;
const RIPPLE_PERIOD: usize = 20;
const RIPPLE_PHASE: usize = 21;

/// One request: every trial under ONE parameter set, each from its own initial state.
pub struct Sensitivities<'a> {
    pub trials: &'a [&'a Trial],
    pub params: &'a Params,
    /// `x0[k]` is trial k's initial state.
    pub x0: &'a [State],
    /// The parameters to differentiate by (indices into `PARAM_NAMES`, each at most once).
    pub wrt: &'a [usize],
    pub law: FrictionLaw,
    pub max_step: f64,
    /// Worker threads; `None` uses rayon's global pool (one per core).
    pub threads: Option<usize>,
}

impl Sensitivities<'_> {
    /// Rows per trial in the output: θ, one per `wrt` entry, then θ0 and ω0.
    pub fn rows(&self) -> usize {
        self.wrt.len() + 3
    }

    fn validate(&self) -> Result<(), PlantError> {
        validate_max_step(self.max_step)?;
        self.params.validate()?;
        if self.x0.len() != self.trials.len() {
            return Err(PlantError::Shape(format!(
                "x0 has {} initial states for {} trials",
                self.x0.len(),
                self.trials.len()
            )));
        }
        for (i, x) in self.x0.iter().enumerate() {
            require_finite(&format!("x0 theta #{i}"), x.theta)?;
            require_finite(&format!("x0 omega #{i}"), x.omega)?;
        }
        for (i, &j) in self.wrt.iter().enumerate() {
            if j >= N_PARAMS {
                return Err(PlantError::InvalidValue(format!("wrt[{i}] = {j} is not a parameter index")));
            }
            if self.wrt[..i].contains(&j) {
                return Err(PlantError::InvalidValue(format!("wrt names parameter {j} twice")));
            }
        }
        if self.threads == Some(0) {
            return Err(PlantError::InvalidValue("threads must be >= 1".into()));
        }
        Ok(())
    }

    /// Runs every trial (in parallel). Returns one buffer per trial, row-major
    /// (`rows()`, n_samples): θ, ∂θ/∂p for each `wrt`, ∂θ/∂θ0, ∂θ/∂ω0.
    pub fn run(&self) -> Result<Vec<Vec<f64>>, PlantError> {
        self.validate()?;
        let rows = self.rows();
        let mut outs: Vec<Vec<f64>> = self.trials.iter().map(|tr| vec![0.0; rows * tr.n_samples()]).collect();
        in_pool(self.threads, || {
            outs.par_iter_mut().enumerate().for_each(|(k, out)| {
                sensitivities_into(self.trials[k], self.params, self.law, self.x0[k], self.max_step, self.wrt, out)
            })
        })?;
        Ok(outs)
    }
}

/// One trial: fills `out` (row-major (wrt.len() + 3, n_samples), see `Sensitivities::run`).
/// Expects validated inputs.
pub fn sensitivities_into(
    trial: &Trial,
    p: &Params,
    law: FrictionLaw,
    x0: State,
    max_step: f64,
    wrt: &[usize],
    out: &mut [f64],
) {
    let n = trial.n_samples();
    let n_dir = wrt.len() + 2;
    // Tangents per direction: the parameters of `wrt`, then θ0 and ω0 (unit initial tangents).
    let mut d_theta = vec![0.0; n_dir];
    let mut d_omega = vec![0.0; n_dir];
    d_theta[n_dir - 2] = 1.0;
    d_omega[n_dir - 1] = 1.0;
    let mut forcing = vec![0.0; wrt.len()];
    let load = trial.load();
    let t0 = trial.t()[0];
    let mut state = x0;
    // As `trial::simulate_into`: without a measured torque, gain, bias and drift act on nothing.
    let (p, tau) = match trial.tau() {
        Some(tau) => (*p, Some(tau)),
        None => (Params { torque_bias: 0.0, torque_drift: 0.0, ..*p }, None),
    };
    let mut cursor = tau.map(|tau| TorqueCursor::new(trial.t(), tau));
    let needs = Needs::new(&p, wrt);
    walk(trial.t(), max_step, |event| match event {
        Walk::Substep { t, h } => {
            let (applied, rate) = match cursor.as_mut() {
                Some(c) => c.at_with_rate(t - p.time_delay),
                None => (0.0, 0.0),
            };
            let before = state;
            step(&mut state, &p, &load, law, applied, t - t0, h);
            let input = Input { applied, rate, measured: tau.is_some(), t_rel: t - t0, h };
            let lin = Substep::new(&p, &load, law, before, state.omega, &input, &needs);
            for (b, &j) in forcing.iter_mut().zip(wrt) {
                *b = lin.forcing(&p, j, &input, before);
            }
            for d in 0..n_dir {
                let b = if d < wrt.len() { forcing[d] } else { 0.0 };
                let dw = lin.c_theta * d_theta[d] + lin.c_omega * d_omega[d] + b;
                d_theta[d] += h * dw;
                d_omega[d] = dw;
            }
        }
        Walk::Sample(i) => {
            out[i] = state.theta;
            for d in 0..n_dir {
                out[(d + 1) * n + i] = d_theta[d];
            }
        }
    });
}

/// Which angle-periodic and Stribeck terms a trial's tangent must evaluate: those switched on,
/// and those whose size is differentiated by (their derivative is their shape). The others
/// are skipped, each a transcendental function per substep.
struct Needs {
    cogging: bool,
    ripple: bool,
    stribeck: bool,
}

impl Needs {
    fn new(p: &Params, wrt: &[usize]) -> Self {
        Needs {
            cogging: p.cogging_amplitude != 0.0 || wrt.contains(&COGGING_AMPLITUDE),
            ripple: p.friction_ripple_amplitude != 0.0 || wrt.contains(&RIPPLE_AMPLITUDE),
            stribeck: p.stribeck_torque != 0.0 || wrt.contains(&STRIBECK_TORQUE),
        }
    }
}

/// The substep's inputs besides the state and the parameters.
struct Input {
    applied: f64,
    /// d(applied)/dt at the delayed time.
    rate: f64,
    measured: bool,
    t_rel: f64,
    h: f64,
}

/// One substep linearised at its start: ∂ω'/∂θ, ∂ω'/∂ω, and what `forcing` needs for ∂ω'/∂p.
struct Substep {
    c_theta: f64,
    c_omega: f64,
    /// Stuck: ω' = 0 whatever the inputs, every derivative is 0.
    stuck: bool,
    gh: f64,
    inertia: f64,
    /// 1 / (1 + (h/I)·dissipation): ω' is a numerator times this.
    inv_den: f64,
    /// The level's coefficient in ω': sign(free) (stick) or tanh(kω) (tanh).
    s: f64,
    omega: f64,
    omega_new: f64,
    drive: f64,
    level: f64,
    dissipation: f64,
    /// 1 when the unclipped level is ≥ 0 (its derivative passes), else 0.
    level_on: f64,
    dir: f64,
    gt_cos: f64,
    cog: (f64, f64),
    ripple: (f64, f64),
    stribeck: f64,
    /// sign and size of the gearbox's load torque (gravity − corrected torque).
    load: (f64, f64),
    sech2: f64,
    theta: f64,
}

impl Substep {
    fn new(p: &Params, load: &Load, law: FrictionLaw, before: State, omega_new: f64, input: &Input, needs: &Needs) -> Self {
        let State { theta, omega } = before;
        let inertia = p.motor_inertia + load.inertia;
        let gh = input.h / inertia;
        let tc = p.torque_gain * input.applied - p.torque_bias - p.torque_drift * input.t_rel;
        let (sg, cg) = trig::sin_cos(theta - p.angle_offset);
        let gravity = load.gravity_torque * sg;
        let cog = if needs.cogging { trig::sin_cos(p.cogging_period * theta + p.cogging_phase) } else { (0.0, 0.0) };
        let ripple =
            if needs.ripple { trig::sin_cos(p.friction_ripple_period * theta + p.friction_ripple_phase) } else { (0.0, 0.0) };
        let spring = p.spring_stiffness * (theta - p.spring_neutral);
        let drive = tc - gravity - p.cogging_amplitude * cog.0 - spring;
        let dir = direction(omega, drive);
        // exp(−(ω/v_s)²), also where the Stribeck term is off (its derivative by the torque is
        // this); a velocity of 0 is allowed then, and the limit is taken.
        let stribeck = if !needs.stribeck {
            0.0
        } else if p.stribeck_velocity != 0.0 {
            let r = omega / p.stribeck_velocity;
            trig::exp(-r * r)
        } else if omega == 0.0 {
            1.0
        } else {
            0.0
        };
        let load_torque = gravity - tc;
        let raw = p.coulomb
            + dir * p.coulomb_asym
            + p.friction_ripple_amplitude * ripple.0
            + p.stribeck_torque * stribeck
            + p.load_coulomb * load_torque.abs();
        let level = raw.max(0.0);
        let level_on = if raw >= 0.0 { 1.0 } else { 0.0 };
        let dissipation = p.damping + p.quadratic_drag * omega.abs();
        let inv_den = 1.0 / (1.0 + gh * dissipation);
        let free = omega + gh * drive;
        let (stuck, s, sech2) = match law {
            FrictionLaw::Stick => (omega_new == 0.0, free.signum(), 0.0),
            FrictionLaw::Tanh => {
                let t = (p.tanh_k * omega).tanh();
                (false, t, 1.0 - t * t)
            }
        };
        let mut sub = Substep {
            c_theta: 0.0,
            c_omega: 0.0,
            stuck,
            gh,
            inertia,
            inv_den,
            s,
            omega,
            omega_new,
            drive,
            level,
            dissipation,
            level_on,
            dir,
            gt_cos: load.gravity_torque * cg,
            cog,
            ripple,
            stribeck,
            load: (sign(load_torque), load_torque.abs()),
            sech2,
            theta,
        };
        if !stuck {
            let drive_theta = -sub.gt_cos - p.cogging_amplitude * p.cogging_period * cog.1 - p.spring_stiffness;
            let level_theta = level_on
                * (p.friction_ripple_amplitude * p.friction_ripple_period * ripple.1
                    + p.load_coulomb * sub.load.0 * sub.gt_cos);
            let level_omega =
                level_on * p.stribeck_torque * stribeck * (-2.0 * omega / (p.stribeck_velocity * p.stribeck_velocity));
            let diss_omega = p.quadratic_drag * sign(omega);
            let tanh_omega = level * sech2 * p.tanh_k;
            sub.c_theta = gh * (drive_theta - s * level_theta) * inv_den;
            sub.c_omega = (1.0 + gh * (-s * level_omega - omega_new * diss_omega - tanh_omega)) * inv_den;
        }
        sub
    }

    /// ∂ω'/∂p_j at fixed state.
    fn forcing(&self, p: &Params, j: usize, input: &Input, before: State) -> f64 {
        if self.stuck {
            return 0.0;
        }
        // Each parameter moves some of: h/I, the drive, the friction level, the dissipation,
        // the tanh steepness; the gravity G and the corrected torque τc also reach the level
        // through a load-dependent Coulomb term (|G − τc|).
        let (mut d_gh, mut d_drive, mut d_level, mut d_diss, mut d_k) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let (mut d_gravity, mut d_tc) = (0.0, 0.0);
        let measured = if input.measured { 1.0 } else { 0.0 };
        match j {
            MOTOR_INERTIA => d_gh = -self.gh / self.inertia,
            DAMPING => d_diss = 1.0,
            COULOMB => d_level = 1.0,
            COULOMB_ASYM => d_level = self.dir,
            STRIBECK_TORQUE => d_level = self.stribeck,
            STRIBECK_VELOCITY => {
                let v = p.stribeck_velocity;
                d_level = p.stribeck_torque * self.stribeck * 2.0 * self.omega * self.omega / (v * v * v);
            }
            LOAD_COULOMB => d_level = self.load.1,
            ANGLE_OFFSET => d_gravity = -self.gt_cos,
            QUADRATIC_DRAG => d_diss = self.omega.abs(),
            COGGING_AMPLITUDE => d_drive = -self.cog.0,
            COGGING_PERIOD => d_drive = -p.cogging_amplitude * before.theta * self.cog.1,
            COGGING_PHASE => d_drive = -p.cogging_amplitude * self.cog.1,
            TIME_DELAY => d_tc = -p.torque_gain * input.rate * measured,
            TORQUE_BIAS => d_tc = -measured,
            TORQUE_DRIFT => d_tc = -input.t_rel * measured,
            TANH_K => d_k = 1.0,
            TORQUE_GAIN => d_tc = input.applied * measured,
            SPRING_STIFFNESS => d_drive = -(self.theta - p.spring_neutral),
            SPRING_NEUTRAL => d_drive = p.spring_stiffness,
            RIPPLE_AMPLITUDE => d_level = self.ripple.0,
            RIPPLE_PERIOD => d_level = p.friction_ripple_amplitude * self.theta * self.ripple.1,
            RIPPLE_PHASE => d_level = p.friction_ripple_amplitude * self.ripple.1,
            _ => {}
        }
        d_drive += d_tc - d_gravity;
        d_level = self.level_on * (d_level + p.load_coulomb * self.load.0 * (d_gravity - d_tc));
        let tanh_term = self.level * self.sech2 * self.omega * d_k;
        ((self.drive - self.s * self.level - self.omega_new * self.dissipation) * d_gh
            + self.gh * (d_drive - self.s * d_level - self.omega_new * d_diss - tanh_term))
            * self.inv_den
    }
}

/// sign(x), 0 at 0: the derivative of |x| where it has one.
#[inline]
fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}
