"""admittance: real-time admittance control for Dynamixel servos, and the system
identification that feeds it.

Subpackages (each one concept):
- ``admittance.ident``     fit I, B, friction and missing effects from pendulum data
- ``admittance.drivers``   Dynamixel setup (dynamixel-sdk), force-sensor readers
- ``admittance.mockbench`` simulated Dynamixel bus and force sensor on pseudo-terminals
- ``admittance.daemon``    the supervisor: configuration, RT loop, Zenoh, systemd
- ``admittance._rtcore``   the Rust core (plant simulator, Dynamixel codec, RT loop)
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("admittance")
except PackageNotFoundError:  # running from a source tree without an install
    __version__ = "0.0.0+unknown"
