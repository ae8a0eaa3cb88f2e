//! Simulated Dynamixel bus (skeleton; filled in by the dxlsim work).
