//! The batch runner: same numbers as single runs, any thread count, refuses bad shapes.
mod common;
use common::*;
use plant::{Batch, FrictionLaw, Load, Output, Params, PlantError, State, Trial};

fn trials() -> Vec<Trial> {
    let t = times(1.0, 1.0 / 120.0);
    let tau: Vec<f64> = t.iter().map(|x| 0.04 * (5.0 * x).sin()).collect();
    vec![
        Trial::new(t.clone(), Some(tau), Load { inertia: 1e-3, gravity_torque: 0.1 }).unwrap(),
        Trial::new(t[..60].to_vec(), None, Load { inertia: 0.0, gravity_torque: 0.2 }).unwrap(),
    ]
}

fn param_sets() -> Vec<Params> {
    (0..3)
        .map(|s| Params { damping: 0.01 * s as f64, coulomb: 0.005, time_delay: 0.01, ..bare(2e-3) })
        .collect()
}

fn x0(n: usize) -> Vec<State> {
    (0..n).map(|i| at(0.1 * i as f64, 0.0)).collect()
}

/// The trials, parameter sets and initial states every test here starts from.
fn request() -> (Vec<Trial>, Vec<Params>, Vec<State>) {
    let params = param_sets();
    let starts = x0(params.len() * 2);
    (trials(), params, starts)
}

fn batch<'a>(trials: &'a [&'a Trial], params: &'a [Params], x0: &'a [State]) -> Batch<'a> {
    Batch { trials, params, x0, law: FrictionLaw::Stick, max_step: 5e-4, output: Output::ThetaOmega, threads: None }
}

#[test]
fn batch_matches_single_runs_on_any_thread_count() {
    let (owned, params, starts) = request();
    let refs: Vec<&Trial> = owned.iter().collect();
    let parallel = batch(&refs, &params, &starts).run().unwrap();
    let serial = Batch { threads: Some(1), ..batch(&refs, &params, &starts) }.run().unwrap();
    assert_eq!(parallel, serial);
    for (k, trial) in refs.iter().enumerate() {
        let n = trial.n_samples();
        for (s, p) in params.iter().enumerate() {
            let single = run(trial, p, FrictionLaw::Stick, starts[s * refs.len() + k], 5e-4);
            let row = &parallel[k][s * n * 2..(s + 1) * n * 2];
            for (i, st) in single.iter().enumerate() {
                assert_eq!((row[2 * i], row[2 * i + 1]), (st.theta, st.omega));
            }
        }
    }
}

/// Trials of different lengths and sample periods (jittered), driven and not, with loads that
/// let some drops rest early, some late and one not before its end.
fn mixed_trials() -> Vec<Trial> {
    let jittered = |n: usize, dt: f64| {
        let mut t = vec![0.0];
        for i in 1..n {
            t.push(t[i - 1] + dt * (1.0 + 0.3 * ((i * 7 % 11) as f64 / 11.0 - 0.5)));
        }
        t
    };
    let driven = |t: Vec<f64>| {
        let tau = t.iter().map(|x| 0.04 * (5.0 * x).sin()).collect();
        Trial::new(t, Some(tau), Load { inertia: 1e-3, gravity_torque: 0.1 }).unwrap()
    };
    vec![
        Trial::new(jittered(300, 0.0083), None, Load { inertia: 1e-3, gravity_torque: 0.05 }).unwrap(),
        driven(jittered(121, 0.0041)),
        Trial::new(jittered(45, 0.012), None, Load { inertia: 0.0, gravity_torque: 0.2 }).unwrap(),
        Trial::new(times(1.0, 1.0 / 120.0), None, Load { inertia: 2e-3, gravity_torque: 0.02 }).unwrap(),
        driven(times(0.5, 1.0 / 250.0)),
        Trial::new(vec![0.0], None, Load::default()).unwrap(),
        Trial::new(jittered(200, 0.0007), None, Load { inertia: 0.0, gravity_torque: 0.3 }).unwrap(),
    ]
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Any number of sets over trials of every kind: the batch cuts the (set, trial) pairs into
/// items of up to four, a trial's sets together and the rest packed across trials (1 set over 7
/// trials: 4 + 3 items of different trials; 6 sets: items of two trials), and every pair still
/// gets its own numbers, to the bit, on both outputs, both laws, one thread or two.
#[test]
fn batches_of_one_to_nine_sets_match_single_runs() {
    let owned = mixed_trials();
    let refs: Vec<&Trial> = owned.iter().collect();
    let mut rests = 0;
    for n_sets in 1..=9 {
        let params: Vec<Params> = (0..n_sets)
            .map(|s| Params {
                damping: 0.003 * s as f64,
                coulomb: 0.002 + 0.004 * s as f64,
                time_delay: 0.002 * s as f64,
                torque_bias: 0.001,
                ..bare(2e-3)
            })
            .collect();
        let starts: Vec<State> = (0..n_sets * refs.len()).map(|i| at(0.05 * i as f64 - 0.4, 0.3 * (i % 3) as f64)).collect();
        for law in [FrictionLaw::Stick, FrictionLaw::Tanh] {
            for output in [Output::Theta, Output::ThetaOmega] {
                let request = Batch { law, output, ..batch(&refs, &params, &starts) };
                let out = request.run().unwrap();
                assert_eq!(out, Batch { threads: Some(1), ..request }.run().unwrap());
                let width = if output == Output::Theta { 1 } else { 2 };
                for (k, trial) in refs.iter().enumerate() {
                    let n = trial.n_samples();
                    for (s, p) in params.iter().enumerate() {
                        let single = run(trial, p, law, starts[s * refs.len() + k], 5e-4);
                        let row = &out[k][s * n * width..(s + 1) * n * width];
                        let want: Vec<f64> = match output {
                            Output::Theta => thetas(&single),
                            Output::ThetaOmega => single.iter().flat_map(|st| [st.theta, st.omega]).collect(),
                        };
                        assert_eq!(bits(row), bits(&want), "{n_sets} sets, set {s}, trial {k}, {law:?}, {output:?}");
                        rests += usize::from(law == FrictionLaw::Stick && n > 2 && single[n - 1] == single[n / 2]);
                    }
                }
            }
        }
    }
    assert!(rests > 0, "some drops rest for good");
}

#[test]
fn batch_refuses_bad_requests_before_running() {
    let (owned, params, starts) = request();
    let refs: Vec<&Trial> = owned.iter().collect();
    let short = x0(2);
    assert!(matches!(batch(&refs, &params, &short).run(), Err(PlantError::Shape(_))));
    let bad_step = Batch { max_step: 0.0, ..batch(&refs, &params, &starts) };
    assert!(matches!(bad_step.run(), Err(PlantError::InvalidValue(_))));
    let mut no_inertia = params.clone();
    no_inertia[1].motor_inertia = -1.0;
    let err = batch(&refs, &no_inertia, &starts).run().unwrap_err();
    assert!(err.to_string().contains("parameter set 1"), "{err}");
    let mut nan_start = starts.clone();
    nan_start[0].omega = f64::NAN;
    assert!(batch(&refs, &params, &nan_start).run().is_err());
    assert!(Batch { threads: Some(0), ..batch(&refs, &params, &starts) }.run().is_err());
}

#[test]
fn trial_refuses_bad_arrays() {
    let load = Load::default();
    assert!(Trial::new(vec![], None, load).is_err());
    assert!(Trial::new(vec![0.0, 0.1, 0.1], None, load).is_err());
    assert!(Trial::new(vec![0.0, f64::NAN], None, load).is_err());
    assert!(Trial::new(vec![0.0, 0.1], Some(vec![0.0]), load).is_err());
    assert!(Trial::new(vec![0.0, 0.1], Some(vec![0.0, f64::INFINITY]), load).is_err());
    assert!(Trial::new(vec![0.0, 0.1], None, Load { inertia: -1.0, gravity_torque: 0.0 }).is_err());
    assert!("viscous".parse::<FrictionLaw>().is_err());
    assert_eq!("tanh".parse::<FrictionLaw>(), Ok(FrictionLaw::Tanh));
}

#[test]
fn param_vector_round_trips_in_name_order() {
    let v: Vec<f64> = (0..plant::N_PARAMS).map(|i| i as f64 + 0.5).collect();
    let p = Params::from_slice(&v).unwrap();
    assert_eq!(p.to_array().to_vec(), v);
    assert_eq!(p.time_delay, v[plant::param_index("time_delay").unwrap()]);
    assert!(Params::from_slice(&v[..3]).is_err());
}
