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
use crate::trial::{simulate_lanes, validate_max_step, Trial};

/// Parameter sets stepped side by side in one work item. Measured by bench/plant_lanes.py (30
/// drops, one thread): 16.4 ns per substep with 2 lanes, 15.1 with 4, 15.0 with 8, against 31
/// alone; 4 take a Jacobian's 6–7 sets of a trial in two items.
pub const LANES: usize = 4;
const _: () = assert!(LANES == 4, "Batch::run_group dispatches 1 to 4 lanes");

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
        // (trial, first set, the sets' rows): up to LANES sets per item (`lanes_for`).
        let mut jobs: Vec<(usize, usize, &mut [f64])> = Vec::with_capacity(n_sets * self.trials.len());
        for (k, out) in outs.iter_mut().enumerate() {
            let row = self.trials[k].n_samples() * width;
            let mut rest: &mut [f64] = out;
            let mut s = 0;
            while s < n_sets {
                let lanes = lanes_for(n_sets - s);
                let (chunk, tail) = std::mem::take(&mut rest).split_at_mut(lanes * row);
                jobs.push((k, s, chunk));
                rest = tail;
                s += lanes;
            }
        }
        in_pool(self.threads, move || {
            jobs.into_par_iter().for_each(|(k, s, chunk)| self.run_group(k, s, chunk));
        })?;
        Ok(outs)
    }

    /// Sets `s..s + n` on trial `k`, `n` = `chunk`'s rows (1 to `LANES`).
    fn run_group(&self, k: usize, s: usize, chunk: &mut [f64]) {
        let row = self.trials[k].n_samples() * self.output.width();
        match chunk.len() / row.max(1) {
            4 => self.run_lanes::<4>(k, s, chunk),
            3 => self.run_lanes::<3>(k, s, chunk),
            2 => self.run_lanes::<2>(k, s, chunk),
            _ => self.run_lanes::<1>(k, s, chunk),
        }
    }

    fn run_lanes<const L: usize>(&self, k: usize, s: usize, chunk: &mut [f64]) {
        let trial = self.trials[k];
        let n = trial.n_samples();
        let params: [&Params; L] = std::array::from_fn(|l| &self.params[s + l]);
        let x0: [State; L] = std::array::from_fn(|l| self.x0[(s + l) * self.trials.len() + k]);
        match self.output {
            Output::Theta => {
                simulate_lanes(trial, params, self.law, x0, self.max_step, |l, i, st| chunk[l * n + i] = st.theta)
            }
            Output::ThetaOmega => simulate_lanes(trial, params, self.law, x0, self.max_step, |l, i, st| {
                chunk[2 * (l * n + i)] = st.theta;
                chunk[2 * (l * n + i) + 1] = st.omega;
            }),
        }
    }
}

/// How many of `remaining` sets the next work item takes: all of them up to `LANES`, and never
/// so many that a single set is left for an item of its own (5 = 3 + 2, not 4 + 1): one lane
/// alone has nothing to overlap with.
fn lanes_for(remaining: usize) -> usize {
    match remaining {
        0..=LANES => remaining,
        5 => 3,
        _ => LANES,
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
