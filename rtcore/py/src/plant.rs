//! Python bindings of the `plant` crate: `PARAM_NAMES`, `Trial`, `simulate_batch`,
//! `simulate_sensitivities` (the angle and its derivatives in one pass), and the model
//! read backwards (`required_torque`, `corrected_torque`) for `admittance predict`.
//!
//! A `Trial` copies its arrays into Rust once; `simulate_batch` then only reads parameter
//! rows and initial states, releases the GIL (`py.detach`) and runs the S×T simulations on
//! rayon. Inputs are converted with `numpy.asarray` semantics (lists, float32, strided views
//! are all accepted) and every error is a `ValueError` naming the bad input.
use numpy::{AllowTypeChange, PyArray1, PyArrayLikeDyn, PyArrayMethods, PyUntypedArrayMethods};
use plant::{
    param_index, Batch, FrictionLaw, Load, Output, Params, PlantError, Sensitivities, State, Trial, N_PARAMS, PARAM_NAMES,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;

pub(crate) fn value_error(e: PlantError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// Copies an array-like of numbers with exactly `ndim` dimensions; returns data and shape.
pub(crate) fn f64_array(obj: &Bound<'_, PyAny>, name: &str, ndim: usize) -> PyResult<(Vec<f64>, Vec<usize>)> {
    let arr: PyArrayLikeDyn<'_, f64, AllowTypeChange> = obj
        .extract()
        .map_err(|e| PyValueError::new_err(format!("{name} must be an array of numbers: {e}")))?;
    if arr.ndim() != ndim {
        return Err(PyValueError::new_err(format!(
            "{name} must have {ndim} dimension(s), got shape {:?}",
            arr.shape()
        )));
    }
    let shape = arr.shape().to_vec();
    let data: Vec<f64> = arr.as_array().iter().copied().collect();
    Ok((data, shape))
}

/// One experiment's sample times, applied torque (optional) and load; immutable.
#[pyclass(name = "Trial", module = "admittance._rtcore", frozen)]
pub struct PyTrial {
    inner: Trial,
}

#[pymethods]
impl PyTrial {
    #[new]
    #[pyo3(signature = (t, tau=None, load_inertia=0.0, gravity_torque=0.0))]
    fn new(
        t: &Bound<'_, PyAny>,
        tau: Option<&Bound<'_, PyAny>>,
        load_inertia: f64,
        gravity_torque: f64,
    ) -> PyResult<Self> {
        let (t, _) = f64_array(t, "t", 1)?;
        let tau = match tau {
            Some(obj) if !obj.is_none() => Some(f64_array(obj, "tau", 1)?.0),
            _ => None,
        };
        let load = Load { inertia: load_inertia, gravity_torque };
        Ok(PyTrial { inner: Trial::new(t, tau, load).map_err(value_error)? })
    }

    #[getter]
    fn n_samples(&self) -> usize {
        self.inner.n_samples()
    }

    #[getter]
    fn duration(&self) -> f64 {
        self.inner.duration()
    }

    #[getter]
    fn load_inertia(&self) -> f64 {
        self.inner.load().inertia
    }

    #[getter]
    fn gravity_torque(&self) -> f64 {
        self.inner.load().gravity_torque
    }

    #[getter]
    fn has_tau(&self) -> bool {
        self.inner.tau().is_some()
    }

    /// A copy of the sample times.
    #[getter]
    fn t<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.inner.t())
    }

    /// A copy of the applied torque, or None for a free swing.
    #[getter]
    fn tau<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.inner.tau().map(|tau| PyArray1::from_slice(py, tau))
    }

    /// Number of substeps a simulation at `max_step` takes.
    fn substeps(&self, max_step: f64) -> PyResult<u64> {
        plant::trial::validate_max_step(max_step).map_err(value_error)?;
        Ok(self.inner.substeps(max_step))
    }

    fn __repr__(&self) -> String {
        let load = self.inner.load();
        format!(
            "Trial(n_samples={}, duration={}, tau={}, load_inertia={}, gravity_torque={})",
            self.inner.n_samples(),
            self.inner.duration(),
            if self.inner.tau().is_some() { "yes" } else { "None" },
            load.inertia,
            load.gravity_torque
        )
    }
}

/// Reads the (S, P) parameter array into `Params`.
fn param_sets(params: &Bound<'_, PyAny>) -> PyResult<Vec<Params>> {
    let (data, shape) = f64_array(params, "params", 2)?;
    if shape[1] != N_PARAMS {
        return Err(PyValueError::new_err(format!(
            "params must have {N_PARAMS} columns (PARAM_NAMES), got shape {shape:?}"
        )));
    }
    data.chunks(N_PARAMS.max(1))
        .take(shape[0])
        .map(|row| Params::from_slice(row).map_err(value_error))
        .collect()
}

/// Reads the (S, T, 2) initial states.
fn initial_states(x0: &Bound<'_, PyAny>, n_sets: usize, n_trials: usize) -> PyResult<Vec<State>> {
    let (data, shape) = f64_array(x0, "x0", 3)?;
    if shape != [n_sets, n_trials, 2] {
        return Err(PyValueError::new_err(format!(
            "x0 must have shape (S, T, 2) = ({n_sets}, {n_trials}, 2), got {shape:?}"
        )));
    }
    Ok(data.chunks(2).map(|c| State { theta: c[0], omega: c[1] }).collect())
}

/// The inputs both simulations read alike, checked before the GIL is let go (in this order,
/// so a call with several bad inputs names the same one as before): the friction law, the
/// parameter sets (`read_params`), the (S, T, 2) initial states, and the trials' Rust sides.
struct SimulationInputs<'a> {
    law: FrictionLaw,
    params: Vec<Params>,
    x0: Vec<State>,
    trials: Vec<&'a Trial>,
}

impl<'a> SimulationInputs<'a> {
    fn read(
        trials: &'a [Bound<'_, PyTrial>],
        params: &Bound<'_, PyAny>,
        read_params: impl FnOnce(&Bound<'_, PyAny>) -> PyResult<Vec<Params>>,
        x0: &Bound<'_, PyAny>,
        friction: &str,
    ) -> PyResult<Self> {
        let law: FrictionLaw = friction.parse().map_err(value_error)?;
        let params = read_params(params)?;
        let x0 = initial_states(x0, params.len(), trials.len())?;
        let trials = trials.iter().map(|t| &t.get().inner).collect();
        Ok(Self { law, params, x0, trials })
    }

    /// Each trial's flat output as an array of shape `shape(n_samples)`.
    fn arrays<'py>(
        &self,
        py: Python<'py>,
        outs: Vec<Vec<f64>>,
        shape: impl Fn(usize) -> Vec<usize>,
    ) -> PyResult<Vec<Bound<'py, PyAny>>> {
        outs.into_iter()
            .zip(&self.trials)
            .map(|(buf, trial)| Ok(PyArray1::from_vec(py, buf).reshape(shape(trial.n_samples()))?.into_any()))
            .collect()
    }
}

/// Simulates every trial under every parameter set; see docs/architecture.md, Contract 1.
#[pyfunction]
#[pyo3(signature = (trials, params, x0, *, max_step=5e-4, friction="stick", return_velocity=false, threads=None))]
#[allow(clippy::too_many_arguments)]
fn simulate_batch<'py>(
    py: Python<'py>,
    trials: Vec<Bound<'py, PyTrial>>,
    params: &Bound<'py, PyAny>,
    x0: &Bound<'py, PyAny>,
    max_step: f64,
    friction: &str,
    return_velocity: bool,
    threads: Option<usize>,
) -> PyResult<Vec<Bound<'py, PyAny>>> {
    let inputs = SimulationInputs::read(&trials, params, param_sets, x0, friction)?;
    let SimulationInputs { law, params, x0, trials: trial_refs } = &inputs;
    let output = if return_velocity { Output::ThetaOmega } else { Output::Theta };
    let batch = Batch { trials: trial_refs, params, x0, law: *law, max_step, output, threads };
    let outs = py.detach(|| batch.run()).map_err(value_error)?;
    let n_sets = params.len();
    inputs.arrays(py, outs, |n| if return_velocity { vec![n_sets, n, 2] } else { vec![n_sets, n] })
}

/// The angle of every trial under one parameter set and, from the same pass, its derivatives
/// by the parameters named in `wrt` and by the trial's initial state (`plant::sensitivity`).
/// Per trial an array (len(wrt) + 3, n_samples): θ, ∂θ/∂p for each of `wrt`, ∂θ/∂θ0, ∂θ/∂ω0.
#[pyfunction]
#[pyo3(signature = (trials, params, x0, wrt, *, max_step=5e-4, friction="stick", threads=None))]
#[allow(clippy::too_many_arguments)]
fn simulate_sensitivities<'py>(
    py: Python<'py>,
    trials: Vec<Bound<'py, PyTrial>>,
    params: &Bound<'py, PyAny>,
    x0: &Bound<'py, PyAny>,
    wrt: Vec<String>,
    max_step: f64,
    friction: &str,
    threads: Option<usize>,
) -> PyResult<Vec<Bound<'py, PyAny>>> {
    let one_set = |p: &Bound<'_, PyAny>| Ok(vec![param_vector(p)?]);
    let inputs = SimulationInputs::read(&trials, params, one_set, x0, friction)?;
    let wrt = wrt
        .iter()
        .map(|name| {
            param_index(name).ok_or_else(|| PyValueError::new_err(format!("wrt: {name:?} is not a parameter name")))
        })
        .collect::<PyResult<Vec<usize>>>()?;
    let SimulationInputs { law, params, x0, trials: trial_refs } = &inputs;
    let request = Sensitivities { trials: trial_refs, params: &params[0], x0, wrt: &wrt, law: *law, max_step, threads };
    let rows = request.rows();
    let outs = py.detach(|| request.run()).map_err(value_error)?;
    inputs.arrays(py, outs, |n| vec![rows, n])
}

/// Reads one parameter vector (`PARAM_NAMES` order) into `Params`.
fn param_vector(params: &Bound<'_, PyAny>) -> PyResult<Params> {
    let (data, _) = f64_array(params, "params", 1)?;
    Params::from_slice(&data).map_err(value_error)
}

/// The corrected applied torque that makes the joint move with (θ, ω, ω') at each sample: the
/// plant equation solved for the torque (see `plant::inverse`).
#[pyfunction]
#[pyo3(signature = (params, theta, omega, alpha, *, load_inertia=0.0, gravity_torque=0.0, friction="stick", velocity_eps=1e-3))]
#[allow(clippy::too_many_arguments)]
fn required_torque<'py>(
    py: Python<'py>,
    params: &Bound<'py, PyAny>,
    theta: &Bound<'py, PyAny>,
    omega: &Bound<'py, PyAny>,
    alpha: &Bound<'py, PyAny>,
    load_inertia: f64,
    gravity_torque: f64,
    friction: &str,
    velocity_eps: f64,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let law: FrictionLaw = friction.parse().map_err(value_error)?;
    let p = param_vector(params)?;
    let (theta, _) = f64_array(theta, "theta", 1)?;
    let (omega, _) = f64_array(omega, "omega", 1)?;
    let (alpha, _) = f64_array(alpha, "alpha", 1)?;
    let load = Load { inertia: load_inertia, gravity_torque };
    let out = plant::inverse::required_torques(&p, &load, law, &theta, &omega, &alpha, velocity_eps)
        .map_err(value_error)?;
    Ok(PyArray1::from_vec(py, out))
}

/// A measured torque series as the model sees it: gain·τ(t − delay) − bias − drift·(t − t₀).
#[pyfunction]
fn corrected_torque<'py>(
    py: Python<'py>,
    params: &Bound<'py, PyAny>,
    t: &Bound<'py, PyAny>,
    tau: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let p = param_vector(params)?;
    let (t, _) = f64_array(t, "t", 1)?;
    let (tau, _) = f64_array(tau, "tau", 1)?;
    let out = plant::inverse::corrected_torque(&p, &t, &tau).map_err(value_error)?;
    Ok(PyArray1::from_vec(py, out))
}

/// `None` when the virtual joint is safe to integrate at step `h`, else the reason.
#[pyfunction]
fn admittance_check_stable(inertia: f64, damping: f64, coulomb: f64, h: f64) -> Option<String> {
    let p = plant::admittance::AdmittanceParams { inertia, damping, coulomb };
    plant::admittance::check_stable(&p, h).err()
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("PARAM_NAMES", PyTuple::new(py, PARAM_NAMES)?)?;
    m.add("PARAM_DEFAULTS", PyTuple::new(py, Params::default().to_array())?)?;
    m.add_class::<PyTrial>()?;
    m.add_function(wrap_pyfunction!(simulate_batch, m)?)?;
    m.add_function(wrap_pyfunction!(simulate_sensitivities, m)?)?;
    m.add_function(wrap_pyfunction!(required_torque, m)?)?;
    m.add_function(wrap_pyfunction!(corrected_torque, m)?)?;
    m.add_function(wrap_pyfunction!(admittance_check_stable, m)?)?;
    Ok(())
}
