//! Property: simulations stepped side by side (`lanes::simulate_lanes`, what `Batch` runs), each
//! on its own trial, give each its own numbers, stepped substep by substep through its whole
//! trial with `model::step`, to the bit: the interleaving, each lane's own substep counts, torque
//! and end, the rest of a lane that is no longer stepped, and the end of the call when all lanes
//! are done change nothing.
mod common;
use common::sparse_params;
use plant::lanes::{simulate_lanes, Run};
use plant::trial::{substep_count, TorqueSeries};
use plant::{step, FrictionLaw, Load, Params, State, Trial};
use proptest::prelude::*;

/// TEST ORACLE: the trial walked substep by substep with `model::step`, never skipping a rest;
/// the delayed torque interpolated as Contract 1 says.
fn stepped_alone(trial: &Trial, p: &Params, law: FrictionLaw, x0: State, max_step: f64) -> Vec<State> {
    let (t, tau) = (trial.t(), trial.tau());
    let p = if tau.is_some() { *p } else { Params { torque_bias: 0.0, torque_drift: 0.0, ..*p } };
    let mut series = tau.map(|tau| TorqueSeries::new(t, tau).unwrap());
    let mut state = x0;
    let mut out = vec![state];
    for i in 1..t.len() {
        let n = substep_count(t[i] - t[i - 1], max_step);
        let h = (t[i] - t[i - 1]) / n as f64;
        for k in 0..n {
            let tk = t[i - 1] + k as f64 * h;
            let applied = series.as_mut().map_or(0.0, |s| s.at(tk - p.time_delay));
            step(&mut state, &p, &trial.load(), law, applied, tk - t[0], h);
        }
        out.push(state);
    }
    out
}

fn jittered_times(n: usize, dt: f64, jitter: &[f64]) -> Vec<f64> {
    let mut t = vec![0.0];
    for i in 1..n {
        t.push(t[i - 1] + dt * (1.0 + 0.3 * jitter[i % jitter.len()]));
    }
    t
}

fn bits(states: &[State]) -> Vec<(u64, u64)> {
    states.iter().map(|s| (s.theta.to_bits(), s.omega.to_bits())).collect()
}

const MAX_STEP: f64 = 1e-3;

/// Lanes `runs[..L]` side by side: each lane's states, every sample handed over exactly once,
/// equal to the bit to its own oracle run and to `simulate` (the one-lane call).
fn check<const L: usize>(runs: &[Run], law: FrictionLaw) -> Result<(), TestCaseError> {
    let mut got: Vec<Vec<Option<State>>> = runs[..L].iter().map(|run| vec![None; run.trial.n_samples()]).collect();
    let lanes: [Run; L] = std::array::from_fn(|l| runs[l]);
    simulate_lanes(lanes, law, MAX_STEP, |l, i, s| {
        assert!(got[l][i].replace(*s).is_none(), "lane {l} of {L}: sample {i} handed over twice");
    });
    for (l, run) in runs[..L].iter().enumerate() {
        let got: Vec<State> = got[l].iter().map(|s| s.expect("every sample handed over")).collect();
        let alone = stepped_alone(run.trial, run.params, law, run.x0, MAX_STEP);
        prop_assert_eq!(bits(&got), bits(&alone), "lane {} of {}", l, L);
        let simulated = plant::simulate(run.trial, run.params, law, run.x0, MAX_STEP).unwrap();
        prop_assert_eq!(bits(&simulated), bits(&alone), "simulate, lane {}", l);
    }
    Ok(())
}

/// One lane's trial: its own length, sample period (1 to 12 substeps an interval at MAX_STEP),
/// jitter, load, and a torque or none.
fn trial() -> impl Strategy<Value = Trial> {
    (
        1..250usize,
        prop_oneof![Just(0.0004), Just(0.0025), Just(0.008), Just(0.0117)],
        prop::collection::vec(-1.0..1.0f64, 1..8),
        any::<bool>(),
        0.0..0.05f64,
        -3.0..3.0f64,
    )
        .prop_map(|(n, dt, jitter, driven, load_inertia, gravity)| {
            let t = jittered_times(n, dt, &jitter);
            let tau = driven.then(|| t.iter().map(|x| 0.3 * (3.0 * x).sin()).collect::<Vec<f64>>());
            Trial::new(t, tau, Load { inertia: load_inertia, gravity_torque: gravity }).unwrap()
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    #[test]
    fn lanes_of_different_trials_give_each_its_own_numbers(
        trials in prop::collection::vec(trial(), 4),
        sets in prop::collection::vec(sparse_params(), 4),
        starts in prop::collection::vec((-3.0..3.0f64, prop_oneof![Just(0.0), -5.0..5.0f64]), 4),
        tanh in prop::bool::weighted(0.2),
    ) {
        let runs: Vec<Run> = (0..4)
            .map(|l| Run { trial: &trials[l], params: &sets[l], x0: State { theta: starts[l].0, omega: starts[l].1 } })
            .collect();
        let law = if tanh { FrictionLaw::Tanh } else { FrictionLaw::Stick };
        check::<1>(&runs, law)?;
        check::<2>(&runs, law)?;
        check::<3>(&runs, law)?;
        check::<4>(&runs, law)?;
    }

    /// Lanes of one trial (a Jacobian's sets), as `Batch` packs a trial's sets four at a time.
    #[test]
    fn lanes_of_one_trial_give_each_set_its_own_numbers(
        trial in trial(),
        sets in prop::collection::vec(sparse_params(), 4),
        starts in prop::collection::vec((-3.0..3.0f64, prop_oneof![Just(0.0), -5.0..5.0f64]), 4),
        tanh in prop::bool::weighted(0.2),
    ) {
        let runs: Vec<Run> = (0..4)
            .map(|l| Run { trial: &trial, params: &sets[l], x0: State { theta: starts[l].0, omega: starts[l].1 } })
            .collect();
        check::<4>(&runs, if tanh { FrictionLaw::Tanh } else { FrictionLaw::Stick })?;
    }
}

/// The sample at which a simulation last changes (0 if never): where a drop came to rest.
fn rested_at(trial: &Trial, p: &Params, x0: State) -> usize {
    let alone = plant::simulate(trial, p, FrictionLaw::Stick, x0, MAX_STEP).unwrap();
    (1..alone.len()).rev().find(|&i| alone[i] != alone[i - 1]).unwrap_or(0)
}

/// Four different trials: drops of different lengths and sample periods that rest at different
/// samples, a drop cut short while still swinging, and a driven trial that never rests. The
/// first lane to finish is no longer stepped while the others go on.
#[test]
fn lanes_that_end_at_different_times_keep_their_own_numbers() {
    let load = Load { inertia: 0.018, gravity_torque: 0.59 };
    let uniform = |n: usize, dt: f64| (0..n).map(|i| i as f64 * dt).collect::<Vec<f64>>();
    let long = Trial::new(uniform(1500, 0.00864), None, load).unwrap();
    let coarse = Trial::new(uniform(700, 0.0123), None, load).unwrap();
    let short = Trial::new(uniform(90, 0.00864), None, load).unwrap();
    let t = uniform(400, 0.005);
    let tau: Vec<f64> = t.iter().map(|x| 0.2 * (4.0 * x).sin()).collect();
    let driven = Trial::new(t, Some(tau), load).unwrap();
    let base = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, quadratic_drag: 0.002, ..Params::default() };
    let sets = [0.3, 2.0, 1.0, 1.0].map(|c| Params { coulomb: base.coulomb * c, ..base });
    let x0 = State { theta: 1.6, omega: 0.0 };
    let trials = [&long, &coarse, &short, &driven];
    let runs: Vec<Run> = (0..4).map(|l| Run { trial: trials[l], params: &sets[l], x0 }).collect();
    let ends: Vec<usize> = runs.iter().map(|r| rested_at(r.trial, r.params, x0)).collect();
    assert!(ends[0] < long.n_samples() - 1 && ends[1] < coarse.n_samples() - 1, "the drops rest: {ends:?}");
    assert!(long.t()[ends[0]] > coarse.t()[ends[1]] + 0.5, "at different times: {ends:?}");
    assert_eq!(ends[2], short.n_samples() - 1, "the short drop still swings at its end");
    check::<4>(&runs, FrictionLaw::Stick).unwrap();
}

/// A drop that rests for good is no longer stepped: its remaining samples are handed over at
/// once, while the driven lane beside it still has most of its trial to go. (Stepping it on
/// would give the same numbers, so only the order of the hand-over can tell.)
#[test]
fn a_drop_at_rest_is_no_longer_stepped() {
    let load = Load { inertia: 0.018, gravity_torque: 0.59 };
    let t: Vec<f64> = (0..1500).map(|i| i as f64 * 0.00864).collect();
    let drop = Trial::new(t.clone(), None, load).unwrap();
    let tau: Vec<f64> = t.iter().map(|x| 0.2 * (4.0 * x).sin()).collect();
    let driven = Trial::new(t, Some(tau), load).unwrap();
    let p = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, quadratic_drag: 0.002, ..Params::default() };
    let x0 = State { theta: 1.6, omega: 0.0 };
    let rest = rested_at(&drop, &p, x0);
    assert!(rest < 1000, "the drop rests early: {rest}");
    let mut order = Vec::new();
    simulate_lanes([Run { trial: &drop, params: &p, x0 }, Run { trial: &driven, params: &p, x0 }], FrictionLaw::Stick, MAX_STEP, |l, i, _| order.push((l, i)));
    let drop_done = order.iter().position(|&e| e == (0, 1499)).unwrap();
    let driven_on = order.iter().position(|&e| e == (1, rest + 10)).unwrap();
    assert!(drop_done < driven_on, "the drop's last sample handed over at {drop_done}, after the driven lane's sample {} at {driven_on}", rest + 10);
}
