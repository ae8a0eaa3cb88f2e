//! Many trials × many parameter sets in one call, in parallel.
//!
//! Identification needs, per iteration, every trial simulated under S = 1 + n_params
//! parameter sets (a forward-difference Jacobian). Each (set, trial) pair is independent, so
//! the S×T pairs are the rayon work items; each writes its own disjoint slice of the output,
//! so there is no locking and no per-step allocation. Everything is validated before any
//! thread starts: a batch runs completely or returns an error.
use rayon::prelude::*;

use crate::error::{require_finite, PlantError};
use crate::friction::FrictionLaw;
use crate::model::State;
use crate::params::Params;
use crate::trial::{simulate_into, validate_max_step, Trial};

/// What a batch returns per sample: the angle, or the angle and the velocity.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    Theta,
    ThetaOmega,
}

impl Output {
    fn width(self) -> usize {
        match self {
            Output::Theta => 1,
            Output::ThetaOmega => 2,
        }
    }
}

/// One batch: `x0[s * trials.len() + k]` is the initial state of parameter set `s` on trial `k`.
pub struct Batch<'a> {
    pub trials: &'a [&'a Trial],
    pub params: &'a [Params],
    pub x0: &'a [State],
    pub law: FrictionLaw,
    pub max_step: f64,
    pub output: Output,
    /// Worker threads; `None` uses rayon's global pool (one per core).
    pub threads: Option<usize>,
}

impl Batch<'_> {
    fn validate(&self) -> Result<(), PlantError> {
        validate_max_step(self.max_step)?;
        for (s, p) in self.params.iter().enumerate() {
            p.validate().map_err(|e| PlantError::InvalidValue(format!("parameter set {s}: {e}")))?;
        }
        let expected = self.params.len() * self.trials.len();
        if self.x0.len() != expected {
            return Err(PlantError::Shape(format!(
                "x0 has {} initial states, expected {} parameter sets × {} trials = {expected}",
                self.x0.len(),
                self.params.len(),
                self.trials.len()
            )));
        }
        for (i, x) in self.x0.iter().enumerate() {
            require_finite(&format!("x0 theta #{i}"), x.theta)?;
            require_finite(&format!("x0 omega #{i}"), x.omega)?;
        }
        if self.threads == Some(0) {
            return Err(PlantError::InvalidValue("threads must be >= 1".into()));
        }
        Ok(())
    }

    /// Runs the batch. Returns one buffer per trial, row-major (S, n_samples[, 2]).
    pub fn run(&self) -> Result<Vec<Vec<f64>>, PlantError> {
        self.validate()?;
        let width = self.output.width();
        let n_sets = self.params.len();
        let mut outs: Vec<Vec<f64>> =
            self.trials.iter().map(|tr| vec![0.0; n_sets * tr.n_samples() * width]).collect();
        let mut jobs: Vec<(usize, usize, &mut [f64])> = Vec::with_capacity(n_sets * self.trials.len());
        for (k, out) in outs.iter_mut().enumerate() {
            let row = self.trials[k].n_samples() * width;
            for (s, chunk) in out.chunks_mut(row.max(1)).enumerate() {
                jobs.push((s, k, chunk));
            }
        }
        in_pool(self.threads, move || {
            jobs.into_par_iter().for_each(|(s, k, chunk)| self.run_one(s, k, chunk));
        })?;
        Ok(outs)
    }

    fn run_one(&self, s: usize, k: usize, out: &mut [f64]) {
        let x0 = self.x0[s * self.trials.len() + k];
        let p = &self.params[s];
        match self.output {
            Output::Theta => {
                simulate_into(self.trials[k], p, self.law, x0, self.max_step, |i, st| out[i] = st.theta)
            }
            Output::ThetaOmega => simulate_into(self.trials[k], p, self.law, x0, self.max_step, |i, st| {
                out[2 * i] = st.theta;
                out[2 * i + 1] = st.omega;
            }),
        }
    }
}

/// Runs `work` on rayon's global pool (`threads` None) or on a pool of `threads` workers.
pub(crate) fn in_pool<F: FnOnce() + Send>(threads: Option<usize>, work: F) -> Result<(), PlantError> {
    match threads {
        None => work(),
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .map_err(|e| PlantError::InvalidValue(format!("cannot start {n} threads: {e}")))?
            .install(work),
    }
    Ok(())
}
