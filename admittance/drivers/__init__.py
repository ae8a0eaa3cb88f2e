"""Device drivers: Dynamixel setup and force-sensor readers.

- ``admittance.drivers.dynamixel``  ``ServoBus``: scan, model detection, control-table items by
  name and unit, Return Delay Time, operating mode, torque, alert recovery (dynamixel-sdk; used
  at setup only, the RT loop speaks the Rust codec).
- ``admittance.drivers.control_table`` items by name and their SI units, from the shared model
  table (``_rtcore.model_table()``).
- ``admittance.drivers.force_reader``     ``ForceSensor`` base, tare/bias, and the registry of kinds
  (``create_sensor(section, sink)``).
- ``admittance.drivers.optoforce``  the OptoForce DAQ wire format and the serial reader.
- ``admittance.drivers.can_sensor`` the same frames over CAN, through python-can.
- ``admittance.drivers.usb_latency`` the FTDI latency-timer check.
- ``admittance.drivers.ports``      why a device could not be opened, with the likely fix.

Nothing here imports the daemon or the RT loop; importing this package loads neither pyserial,
python-can nor dynamixel-sdk (each module imports its library when a device is opened).
"""

from admittance.drivers.force_reader import ForceSensor, TareResult, create_sensor, estimate_bias, sensor_class

__all__ = ["ForceSensor", "TareResult", "create_sensor", "estimate_bias", "sensor_class"]
