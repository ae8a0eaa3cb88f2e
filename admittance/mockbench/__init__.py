"""The simulated bench: a mock Dynamixel bus and a mock force sensor on pseudo-terminals.

- ``admittance.mockbench.bench``  ``MockBench`` / ``BenchConfig``: the whole bench, started and
  stopped together.
- ``admittance.mockbench.simulated_sensor`` the simulated OptoForce sensor (pty or CAN) and the
  ``"mock"`` sensor kind.
- ``admittance.mockbench.hand``   scripted hand-torque profiles.
- ``admittance.mockbench.cli``    ``admittance mock-bench``.

The servos themselves are ``_rtcore.MockBus`` (Rust, crate dxlsim).
"""
