//! Dynamixel protocol codec (skeleton; filled in by the dxl work).
