//! Python bindings of `plant::servo`: the servo's tracking dynamics (docs/fidelity.md).
//!
//! `ServoTrial` copies a recorded run's arrays into Rust once; `servo_simulate_batch` runs every
//! trial under every parameter row without the GIL (rayon), which is what the fidelity fit's
//! Jacobians need; `servo_lead` is the compensation's inverse, vectorised, for checks and plots.
use numpy::{PyArray1, PyArrayMethods};
use plant::servo::{
    self, PlaySide, ServoModel, ServoTrial, N_SERVO_PARAMS, SERVO_DOMAIN, SERVO_PARAM_DEFAULTS, SERVO_PARAM_NAMES,
};
use plant::State;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::plant::{f64_array, value_error};

/// One recorded run: horn-angle times `t`; goal and hand torque on their own times `t_in`.
#[pyclass(name = "ServoTrial", module = "admittance._rtcore", frozen)]
pub struct PyServoTrial {
    inner: ServoTrial,
}

#[pymethods]
impl PyServoTrial {
    #[new]
    fn new(t: &Bound<'_, PyAny>, t_in: &Bound<'_, PyAny>, goal: &Bound<'_, PyAny>, tau: &Bound<'_, PyAny>) -> PyResult<Self> {
        let inner = ServoTrial::new(
            f64_array(t, "t", 1)?.0,
            f64_array(t_in, "t_in", 1)?.0,
            f64_array(goal, "goal", 1)?.0,
            f64_array(tau, "tau", 1)?.0,
        )
        .map_err(value_error)?;
        Ok(PyServoTrial { inner })
    }

    #[getter]
    fn n_samples(&self) -> usize {
        self.inner.n_samples()
    }
}

fn models(params: &Bound<'_, PyAny>) -> PyResult<Vec<ServoModel>> {
    let (data, shape) = f64_array(params, "params", 2)?;
    if shape[1] != N_SERVO_PARAMS {
        return Err(PyValueError::new_err(format!(
            "params must have {N_SERVO_PARAMS} columns (SERVO_PARAM_NAMES), got shape {shape:?}"
        )));
    }
    data.chunks(N_SERVO_PARAMS).take(shape[0]).map(|row| ServoModel::from_slice(row).map_err(value_error)).collect()
}

/// The horn angle of every trial under every parameter row: per trial an (S, n_samples) array.
/// `params` (S, 7) in SERVO_PARAM_NAMES order; `x0` (S, T, 2) initial (θ, ω).
#[pyfunction]
#[pyo3(signature = (trials, params, x0, *, max_step=5e-4))]
fn servo_simulate_batch<'py>(
    py: Python<'py>,
    trials: Vec<Bound<'py, PyServoTrial>>,
    params: &Bound<'py, PyAny>,
    x0: &Bound<'py, PyAny>,
    max_step: f64,
) -> PyResult<Vec<Bound<'py, PyAny>>> {
    let models = models(params)?;
    let (data, shape) = f64_array(x0, "x0", 3)?;
    if shape != [models.len(), trials.len(), 2] {
        return Err(PyValueError::new_err(format!(
            "x0 must have shape (S, T, 2) = ({}, {}, 2), got {shape:?}",
            models.len(),
            trials.len()
        )));
    }
    let x0: Vec<State> = data.chunks(2).map(|c| State { theta: c[0], omega: c[1] }).collect();
    let refs: Vec<&ServoTrial> = trials.iter().map(|t| &t.get().inner).collect();
    let outs = py.detach(|| servo::simulate_batch(&refs, &models, &x0, max_step)).map_err(value_error)?;
    outs.into_iter()
        .zip(&refs)
        .map(|(buf, trial)| Ok(PyArray1::from_vec(py, buf).reshape([models.len(), trial.n_samples()])?.into_any()))
        .collect()
}

/// The compensation's goal offset (rad) for a reference moving at `omega` with acceleration
/// `alpha` under hand torque `tau` (arrays of one length); `params` is one model (7 values).
/// With `h` (s) the samples are consecutive cycles of that length, and the gear play's inverse
/// (`PlaySide`, which carries its side from one cycle to the next) is added, as the loop does.
#[pyfunction]
#[pyo3(signature = (params, omega, alpha, tau, *, h=None))]
fn servo_lead<'py>(
    py: Python<'py>,
    params: &Bound<'py, PyAny>,
    omega: &Bound<'py, PyAny>,
    alpha: &Bound<'py, PyAny>,
    tau: &Bound<'py, PyAny>,
    h: Option<f64>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let model = ServoModel::from_slice(&f64_array(params, "params", 1)?.0).map_err(value_error)?;
    let (w, a, q) = (f64_array(omega, "omega", 1)?.0, f64_array(alpha, "alpha", 1)?.0, f64_array(tau, "tau", 1)?.0);
    if a.len() != w.len() || q.len() != w.len() {
        return Err(PyValueError::new_err("omega, alpha and tau must have the same length"));
    }
    let mut play = PlaySide::default();
    let out: Vec<f64> = (0..w.len())
        .map(|i| {
            let played = h.map_or(0.0, |h| play.update(&model, w[i], a[i], q[i], h));
            servo::lead(&model, w[i], a[i], q[i]) + played
        })
        .collect();
    Ok(PyArray1::from_vec(py, out))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("SERVO_PARAM_NAMES", PyTuple::new(m.py(), SERVO_PARAM_NAMES)?)?;
    m.add("SERVO_DOMAIN", PyTuple::new(m.py(), SERVO_DOMAIN)?)?;
    m.add("SERVO_PARAM_DEFAULTS", PyTuple::new(m.py(), SERVO_PARAM_DEFAULTS)?)?;
    m.add_class::<PyServoTrial>()?;
    m.add_function(wrap_pyfunction!(servo_simulate_batch, m)?)?;
    m.add_function(wrap_pyfunction!(servo_lead, m)?)?;
    Ok(())
}
