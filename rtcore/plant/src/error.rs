//! Why a simulation request was refused.
//!
//! One error type for the whole crate: every check happens before the first substep, so a
//! batch either runs completely or not at all, and the message names the offending value.
use std::fmt;

#[derive(Debug, Clone, PartialEq)]
pub enum PlantError {
    /// A parameter or an input value is out of its domain (NaN, inertia <= 0, ...).
    InvalidValue(String),
    /// Array lengths or counts that must agree do not.
    Shape(String),
    /// A friction law name that is neither "stick" nor "tanh".
    UnknownFrictionLaw(String),
}

impl fmt::Display for PlantError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PlantError::InvalidValue(msg) | PlantError::Shape(msg) => f.write_str(msg),
            PlantError::UnknownFrictionLaw(name) => {
                write!(f, "unknown friction law {name:?}: expected \"stick\" or \"tanh\"")
            }
        }
    }
}

impl std::error::Error for PlantError {}

/// `Ok(())` when `value` is finite, otherwise an error naming it.
pub(crate) fn require_finite(name: &str, value: f64) -> Result<(), PlantError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(PlantError::InvalidValue(format!("{name} must be finite, got {value}")))
    }
}
