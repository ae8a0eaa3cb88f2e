"""The exception tree of admittance.

Every error a user can cause (bad configuration, bad data, a missing device) is an
``AdmittanceError``; the command line prints it as one line and exits non-zero, without a
traceback. Anything else is a bug and keeps its traceback.
"""


class AdmittanceError(Exception):
    """Base of every user-facing error."""

    exit_code = 2


class ConfigError(AdmittanceError):
    """A configuration file or a parameter value is invalid."""


class DataError(AdmittanceError):
    """A dataset, a trial file or a recording is invalid."""


class DeviceError(AdmittanceError):
    """A device (serial port, servo, force sensor, CAN interface) is missing or misbehaves."""

    exit_code = 3


class RefusedError(AdmittanceError):
    """A running daemon refused a request, or does not know a name asked for."""

    exit_code = 1
