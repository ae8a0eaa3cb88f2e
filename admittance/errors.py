"""The exception tree of admittance.

Every error a user can cause (bad configuration, bad data, a missing device) is an
``AdmittanceError``; the command line prints it as one line and exits non-zero, without a
traceback. Anything else is a bug and keeps its traceback. Exit statuses: 2 configuration, 3
device, 69 and 75 a fault that stopped a running daemon (``FaultStop``), 1 a bug.
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


# Exit statuses of a run that a fault stopped (sysexits.h; docs/faults.md): systemd restarts the
# first (Restart=on-failure), and not the second (RestartPreventExitStatus in the unit).
EXIT_TEMPFAIL = 75  # EX_TEMPFAIL: a device gone (the bus, a servo, the sensor); a restart may find it
EXIT_UNAVAILABLE = 69  # EX_UNAVAILABLE: a servo a person must look at (an unsafe error, a policy stop)


class FaultStop(DeviceError):
    """A fault the policy stops on while the loop runs; ``cause`` names it (docs/faults.md)."""

    def __init__(self, message: str, exit_code: int, cause: str) -> None:
        super().__init__(message)
        self.exit_code = exit_code
        self.cause = cause
