//! Property: parameter sets stepped side by side (`trial::simulate_lanes`, what `Batch` runs)
//! give each set the numbers of its own simulation, stepped substep by substep through the
//! whole trial with `model::step`, to the bit: the interleaving, the rest of a lane that is
//! no longer stepped, and the end of the walk when all lanes rest change nothing.
mod common;
use common::sparse_params;
use plant::trial::{substep_count, simulate_lanes, TorqueSeries};
use plant::{step, FrictionLaw, Load, Params, State, Trial};
use proptest::prelude::*;

/// TEST ORACLE: the trial walked substep by substep with `model::step`, never skipping a rest;
/// the delayed torque interpolated as Contract 1 says.
fn stepped_alone(t: &[f64], tau: Option<&[f64]>, load: Load, p: &Params, law: FrictionLaw, x0: State, max_step: f64) -> Vec<State> {
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
            step(&mut state, &p, &load, law, applied, tk - t[0], h);
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

fn check<const L: usize>(trial: &Trial, params: &[Params], x0: &[State], law: FrictionLaw) -> Result<(), TestCaseError> {
    let mut got = vec![vec![State::default(); trial.n_samples()]; L];
    let refs: [&Params; L] = std::array::from_fn(|l| &params[l]);
    let starts: [State; L] = std::array::from_fn(|l| x0[l]);
    simulate_lanes(trial, refs, law, starts, 1e-3, |l, i, s| got[l][i] = *s);
    for l in 0..L {
        let alone = stepped_alone(trial.t(), trial.tau(), trial.load(), &params[l], law, x0[l], 1e-3);
        for (i, (a, b)) in got[l].iter().zip(&alone).enumerate() {
            prop_assert!(a.theta == b.theta && a.omega == b.omega, "lane {l} of {L}, sample {i}: {a:?} against {b:?}");
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    #[test]
    fn lanes_give_each_set_its_own_numbers(
        sets in prop::collection::vec(sparse_params(), 4),
        starts in prop::collection::vec((-3.0..3.0f64, prop_oneof![Just(0.0), -5.0..5.0f64]), 4),
        driven in any::<bool>(),
        tanh in prop::bool::weighted(0.2),
        load_inertia in 0.0..0.05f64,
        gravity in -3.0..3.0f64,
        jitter in prop::collection::vec(-1.0..1.0f64, 1..8),
    ) {
        let t = jittered_times(300, 0.008, &jitter);
        let tau = driven.then(|| t.iter().map(|x| 0.3 * (3.0 * x).sin()).collect::<Vec<f64>>());
        let trial = Trial::new(t, tau, Load { inertia: load_inertia, gravity_torque: gravity }).unwrap();
        let x0: Vec<State> = starts.iter().map(|&(theta, omega)| State { theta, omega }).collect();
        let law = if tanh { FrictionLaw::Tanh } else { FrictionLaw::Stick };
        check::<1>(&trial, &sets, &x0, law)?;
        check::<2>(&trial, &sets, &x0, law)?;
        check::<3>(&trial, &sets, &x0, law)?;
        check::<4>(&trial, &sets, &x0, law)?;
    }
}

/// Drops that rest at different times: the first lane to rest is no longer stepped while the
/// others swing on, and its rest is what stepping would have kept.
#[test]
fn lanes_that_rest_at_different_times_keep_their_own_rest() {
    let t: Vec<f64> = (0..1500).map(|i| i as f64 * 0.00864).collect();
    let load = Load { inertia: 0.018, gravity_torque: 0.59 };
    let trial = Trial::new(t, None, load).unwrap();
    let base = Params { motor_inertia: 0.0147, damping: 0.035, coulomb: 0.084, quadratic_drag: 0.002, ..Params::default() };
    let sets: Vec<Params> = [0.3, 1.0, 2.0, 4.0].iter().map(|&c| Params { coulomb: base.coulomb * c, ..base }).collect();
    let x0 = vec![State { theta: 1.6, omega: 0.0 }; 4];
    let mut rested_at = Vec::new();
    for p in &sets {
        let alone = plant::simulate(&trial, p, FrictionLaw::Stick, x0[0], 1e-3).unwrap();
        rested_at.push((1..alone.len()).rev().find(|&i| alone[i] != alone[i - 1]).unwrap());
    }
    assert!(rested_at.windows(2).all(|w| w[0] > w[1]), "the lanes rest at different samples: {rested_at:?}");
    check::<4>(&trial, &sets, &x0, FrictionLaw::Stick).unwrap();
}
