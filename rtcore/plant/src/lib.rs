//! The pendulum/admittance plant (skeleton; filled in by the plant work).
