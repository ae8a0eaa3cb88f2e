//! Reading configuration dicts key by key: the one place that turns a missing, mistyped or
//! unknown key into an `admittance.errors.ConfigError` naming where it was.
//!
//! `MockBus` servo tables and the `AdmittanceLoop` configuration both come from TOML, so they
//! share these rules: `None` counts as absent (TOML has no null, Python callers pass it for
//! "default"), and a key outside the known set is a typo, never something to ignore.
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::config_error;

/// The first key of `d` not in `known`; a non-string key is itself a configuration error.
pub fn first_unknown_key(d: &Bound<'_, PyDict>, known: &[&str], where_: &str) -> PyResult<Option<String>> {
    for key in d.keys() {
        let key: String = key.extract().map_err(|_| config_error(d.py(), format!("{where_}: keys must be strings")))?;
        if !known.contains(&key.as_str()) {
            return Ok(Some(key));
        }
    }
    Ok(None)
}

/// `d[key]` as `T` when present and not None.
pub fn opt<'py, T: FromPyObjectOwned<'py>>(d: &Bound<'py, PyDict>, key: &str, where_: &str) -> PyResult<Option<T>> {
    match d.get_item(key)? {
        Some(v) if !v.is_none() => v.extract::<T>().map(Some).map_err(|e| {
            let e: PyErr = e.into();
            config_error(d.py(), format!("{where_}.{key}: bad value {v}: {e}"))
        }),
        _ => Ok(None),
    }
}
