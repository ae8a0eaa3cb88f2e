//! The real-time loop (skeleton; filled in by the rt work).
