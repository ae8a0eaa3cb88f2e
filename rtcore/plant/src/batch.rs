//! Many trials × many parameter sets in one call, in parallel.
//!
//! Identification needs, per iteration, every trial simulated under S = 1 + n_params
//! parameter sets (a forward-difference Jacobian), and many times every trial under a single
//! set (a damped trial of its fit). Each (set, trial) pair is independent: the S×T pairs are
//! cut, in order (a trial's sets together), into rayon work items of up to `LANES` pairs
//! stepped side by side (`lanes::simulate_lanes`), whichever trials they are of. Each pair
//! writes its own disjoint slice of the output, so there is no locking and no per-step
//! allocation. Everything is validated before any thread starts: a batch runs completely or
//! returns an error.
use rayon::prelude::*;

use crate::error::{require_finite, PlantError};
use crate::friction::FrictionLaw;
use crate::model::State;
use crate::params::Params;
use crate::lanes::{simulate_lanes, Run};
use crate::trial::{validate_max_step, Trial};

/// Simulations stepped side by side in one work item. Measured by bench/plant_lanes.py (30
/// drops, one thread, lanes of one trial): 16.4 ns per substep with 2 lanes, 15.1 with 4, 15.0
/// with 8, against 31 alone.
pub const LANES: usize = 4;
const _: () = assert!(LANES == 4, "Batch::run_item dispatches 1 to 4 lanes");

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
        let mut pairs: Vec<Pair> = Vec::with_capacity(n_sets * self.trials.len());
        for (k, out) in outs.iter_mut().enumerate() {
            let row = self.trials[k].n_samples() * width;
            pairs.extend(out.chunks_mut(row).enumerate().map(|(s, out)| Pair { s, k, out }));
        }
        let items = work_items(&mut pairs);
        in_pool(self.threads, move || {
            items.into_par_iter().for_each(|item| self.run_item(item));
        })?;
        Ok(outs)
    }

    /// One work item: 1 to `LANES` pairs stepped side by side.
    fn run_item(&self, item: &mut [Pair]) {
        match item.len() {
            4 => self.run_lanes::<4>(item),
            3 => self.run_lanes::<3>(item),
            2 => self.run_lanes::<2>(item),
            _ => self.run_lanes::<1>(item),
        }
    }

    fn run_lanes<const L: usize>(&self, item: &mut [Pair]) {
        let n_trials = self.trials.len();
        let runs: [Run; L] = std::array::from_fn(|l| {
            let Pair { s, k, .. } = item[l];
            Run { trial: self.trials[k], params: &self.params[s], x0: self.x0[s * n_trials + k] }
        });
        let mut rows = item.iter_mut().map(|pair| &mut *pair.out);
        let rows: [&mut [f64]; L] = std::array::from_fn(|_| rows.next().unwrap());
        match self.output {
            Output::Theta => simulate_lanes(runs, self.law, self.max_step, |l, i, st| rows[l][i] = st.theta),
            Output::ThetaOmega => simulate_lanes(runs, self.law, self.max_step, |l, i, st| {
                rows[l][2 * i] = st.theta;
                rows[l][2 * i + 1] = st.omega;
            }),
        }
    }
}

/// One (parameter set, trial) pair of a batch and its row of the output.
struct Pair<'a> {
    s: usize,
    k: usize,
    out: &'a mut [f64],
}

/// `pairs` cut in order into work items of `LANES`, but the last two: a single pair is never
/// left for an item of its own (5 = 3 + 2, not 4 + 1), since one lane alone has nothing to
/// overlap with. Any two pairs may share an item: lanes of different trials are as fast as
/// lanes of one (docs/plant.md, *The batch simulator*).
fn work_items<T>(pairs: &mut [T]) -> Vec<&mut [T]> {
    let mut items = Vec::with_capacity(pairs.len() / LANES + 1);
    let mut rest = pairs;
    while !rest.is_empty() {
        let (item, tail) = rest.split_at_mut(lanes_for(rest.len()));
        items.push(item);
        rest = tail;
    }
    items
}

/// How many of `remaining` pairs the next work item takes (`work_items`).
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Every item has `LANES` pairs but the last two, which split 5 as 3 + 2; none has one pair
    /// unless the whole batch has; the pairs stay in order, each in one item.
    #[test]
    fn items_are_full_but_the_last_and_never_a_lone_pair() {
        for n in 0..40 {
            let mut pairs: Vec<usize> = (0..n).collect();
            let items = work_items(&mut pairs);
            let sizes: Vec<usize> = items.iter().map(|item| item.len()).collect();
            assert_eq!(items.concat(), (0..n).collect::<Vec<usize>>(), "{n} pairs");
            assert_eq!(sizes.len(), n.div_ceil(LANES), "{n} pairs: {sizes:?}");
            let full = sizes.len().saturating_sub(2);
            assert!(sizes[..full].iter().all(|&s| s == LANES), "{n} pairs: {sizes:?}");
            assert!(n == 1 || !sizes.contains(&1), "{n} pairs: {sizes:?}");
        }
    }
}
