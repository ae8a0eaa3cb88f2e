//! The one mapping from Rust errors to the Python exception tree `admittance.errors`.
//!
//! User-caused errors become `ConfigError` / `DeviceError`, so the command line prints one
//! line without a traceback. If the Python package cannot be imported (the extension used on
//! its own), they degrade to `ValueError`.
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyType;

/// An `admittance.errors.<class_name>` carrying `message`.
fn admittance_error(py: Python<'_>, class_name: &str, message: String) -> PyErr {
    let class = py.import("admittance.errors").and_then(|m| m.getattr(class_name));
    match class.map(|c| c.cast_into::<PyType>()) {
        Ok(Ok(ty)) => PyErr::from_type(ty, message),
        _ => PyValueError::new_err(message),
    }
}

pub fn config_error(py: Python<'_>, message: impl Into<String>) -> PyErr {
    admittance_error(py, "ConfigError", message.into())
}

pub fn device_error(py: Python<'_>, message: impl Into<String>) -> PyErr {
    admittance_error(py, "DeviceError", message.into())
}
