//! The pendulum/admittance plant: friction models and a fixed-step batch simulator (no I/O).
//!
//! `I·ω' = gain·τ(t − delay) − bias − drift·t − G·sin(θ − offset) − cogging(θ) − k·(θ − θ_k) − B·ω − c·ω|ω| + friction`
//! (docs/architecture.md, Contract 1; docs/plant.md for the reasoning).
//!
//! - `params`: the 22-entry parameter vector and its names (`PARAM_NAMES`).
//! - `friction`: the friction level and the stick / tanh laws.
//! - `model`: one semi-implicit Euler substep of the plant (`step`), used by the mock bus.
//! - `trial`: a trial's inputs and its simulation at the sample times.
//! - `batch`: parameter sets × trials in parallel (rayon), for identification.
//! - `sensitivity`: the angle and its derivatives by parameters and initial state in one pass
//!   (forward sensitivities of the substep), for identification's Jacobians.
//! - `trig`: the plant's sine and exponential: the C library's, or with the `libm-sine` feature
//!   the `libm` crate's (bench/identify_perturbed.py).
//! - `inverse`: the model read backwards (the torque a recorded motion needs), for `predict`.
//! - `admittance`: the RT loop's virtual joint and its stability gate.
//! - `servo`: how a position servo's horn follows its goal (fitted by `fidelity`, inverted by
//!   the RT loop's compensation).
//!
//! ```
//! use plant::{step, FrictionLaw, Load, Params, State};
//! let p = Params { motor_inertia: 0.0147, damping: 0.03, coulomb: 0.08, ..Params::default() };
//! p.validate().unwrap();
//! let load = Load { inertia: 0.0, gravity_torque: 0.0 };
//! let mut s = State { theta: 0.0, omega: 0.0 };
//! step(&mut s, &p, &load, FrictionLaw::Stick, 0.05, 0.0, 5e-4); // 0.05 < coulomb: stuck
//! assert_eq!(s, State { theta: 0.0, omega: 0.0 });
//! ```
//!
//! Semi-implicit (symplectic) Euler rather than RK4: the stick law is a per-step constraint
//! that a multi-stage method would straddle, and symplectic Euler keeps a frictionless
//! pendulum's energy bounded over thousands of periods at first-order cost.
pub mod admittance;
pub mod batch;
pub mod error;
pub mod friction;
pub mod inverse;
pub mod lanes;
pub mod model;
pub mod params;
pub mod sensitivity;
pub mod servo;
pub mod trial;
pub mod trig;

pub use batch::{Batch, Output};
pub use error::PlantError;
pub use friction::FrictionLaw;
pub use model::{step, Load, State};
pub use params::{param_index, Params, N_PARAMS, PARAM_NAMES};
pub use sensitivity::Sensitivities;
pub use trial::{simulate, Trial};
