"""Dynamixel setup through dynamixel-sdk: find the servos and put them in the loop's state.

This runs once, before the real-time loop starts (which then speaks the Rust codec on its own
port); so it favours clear errors over speed and uses ROBOTIS's own SDK, the reference every
servo and adapter is tested against. :class:`ServoBus` is a small python-can-style interface:
one class, one method per operation, typed errors (:class:`ServoTimeout` also is a
``TimeoutError``), and no return codes to check.

What it does, by the e-manual (shared protocols.md §1–§3):

- scan: a broadcast ping on Protocol 2.0 (one round trip for the whole bus), or a ping per ID;
  the model comes from the model number through ``_rtcore.model_table()``, MX-28/64/106 on
  both firmwares and the X series;
- items by name, in SI units (control_table.py);
- Return Delay Time 0 (the default 500 µs would eat half of a 1 ms cycle), and position mode:
  Operating Mode 3 on P2 (an EEPROM item, so torque goes off first) or joint mode through the
  angle limits (0, 4095) on P1;
- alerts: bit 7 of a P2 status error (or the hardware bits of a P1 error byte) means the servo
  shut down. With ``auto_recover`` the bus reads Hardware Error Status, logs the causes,
  REBOOTs the servo, waits for it to answer again and retries the operation once; P1 has no
  REBOOT, so there the alert is raised with its causes.

The SDK's reply timeout assumes a 16 ms FTDI latency timer on every port; the port handler
here uses the adapter's real timer (0 for a pty), so a scan of absent IDs takes a fraction of
the SDK's 34 ms each, and a timer left at 16 ms is reported with its fix (usb_latency.py).

Late replies: a status packet names its servo but not the instruction it answers. So an
instruction sent again after a timeout leaves two replies on their way, and the second is taken
as the answer to whatever is sent next (a Firmware Version of 45 read as Hardware Error Status
0x2D: "input voltage, overheating, motor encoder, overload" on a healthy servo). A reply that
misses its timeout (a host, or a simulated bus's thread, not scheduled in time) is therefore
first awaited a while longer without sending anything (``late_reply_ms``) before the
instruction is sent again: it is still the answer to the instruction that is out. Only
silence through that window sends it again (the last attempt has no such wait: nothing is
sent after it, so an absent servo costs no more).
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, TypeVar

from admittance.drivers.control_table import ControlTable, Item, table_for_number
from admittance.drivers.ports import exclusive_serial, open_error_message
from admittance.drivers.usb_latency import latency_warning, read_latency_timer
from admittance.errors import ConfigError, DeviceError

log = logging.getLogger(__name__)

T = TypeVar("T")

BROADCAST_ID = 0xFE
MAX_ID = {1: 253, 2: 252}
POSITION_MODE = 3
P1_JOINT_MODE_LIMITS = (0, 4095)
P2_ALERT_BIT = 0x80
P2_ERRORS = {
    1: "Result Fail",
    2: "Instruction Error",
    3: "CRC Error",
    4: "Data Range Error",
    5: "Data Length Error",
    6: "Data Limit Error",
    7: "Access Error",
}
P1_ERROR_BITS = {
    0x01: "input voltage",
    0x02: "angle limit",
    0x04: "overheating",
    0x08: "range",
    0x10: "checksum",
    0x20: "overload",
    0x40: "instruction",
}
P1_HARDWARE_BITS = 0x01 | 0x04 | 0x20
HARDWARE_ERROR_BITS = {0: "input voltage", 2: "overheating", 3: "motor encoder", 4: "electrical shock", 5: "overload"}
REBOOT_WAIT_S = 3.0
DEFAULT_REPLY_SLACK_MS = 20.0  # a servo's firmware plus a desktop host's scheduling
LATE_REPLY_FACTOR = 1.0  # the wait for a late reply before a resend, in reply slacks (ServoBus.late_reply_ms)
READ_POLL_S = 0.002  # the port's read timeout: the reply wait sleeps in select, it does not spin


# ---------------------------------------------------------------------------------------------
# Errors


class ServoError(DeviceError):
    """Something went wrong talking to a servo."""


class ServoTimeout(ServoError, TimeoutError):
    """No status packet came back (absent ID, wrong baud rate or protocol, wiring)."""


class ServoCommError(ServoError):
    """A reply came back corrupt, or the port failed."""


class ServoStatusError(ServoError):
    """The servo answered with an instruction error (range, access, ...)."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


class ServoAlert(ServoError):
    """The servo reports a hardware error (overload, overheating, voltage...) and shut down."""

    def __init__(self, servo_id: int, causes: list[str], detail: str = ""):
        what = ", ".join(causes) if causes else "cause not reported"
        super().__init__(f"servo {servo_id} reports a hardware alert ({what}){detail}")
        self.servo_id = servo_id
        self.causes = causes


@dataclass(frozen=True)
class ServoInfo:
    id: int
    model_number: int
    model: str  # the model table's name, or "unknown"
    protocol: int
    firmware: int | None = None


def decode_hardware_error(value: int) -> list[str]:
    """The causes set in a P2 Hardware Error Status byte."""
    return [name for bit, name in HARDWARE_ERROR_BITS.items() if value & (1 << bit)]


def decode_p1_error(value: int) -> list[str]:
    return [name for bit, name in P1_ERROR_BITS.items() if value & bit]


# ---------------------------------------------------------------------------------------------


def _port_handler(port: str, latency_ms: float, slack_ms: float, late_ms: float) -> Any:
    """A dynamixel-sdk PortHandler whose reply timeout uses the adapter's real latency, and
    whose port is opened exclusively (ports.py): a second daemon on the bus fails here, at
    its first open, before it has written anything.

    Inside :meth:`listening` it sends nothing and keeps what has arrived: an SDK call made
    there only receives, for ``late_ms``, the reply to the instruction it sent before (the
    module doc, late replies); the SDK parses it as it would have on time.
    """
    from dynamixel_sdk import PortHandler

    class _PortHandler(PortHandler):
        late = False

        @contextlib.contextmanager
        def listening(self) -> Iterator[None]:
            self.late = True
            try:
                yield
            finally:
                self.late = False

        def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802 - SDK's name
            self.packet_start_time = self.getCurrentTime()
            on_time = self.tx_time_per_byte * packet_length + 2.0 * latency_ms + slack_ms
            self.packet_timeout = late_ms if self.late else on_time

        def clearPort(self) -> None:  # noqa: N802 - SDK's name; called before each instruction
            if not self.late:  # listening, what arrived is the reply awaited
                super().clearPort()

        def writePort(self, packet: list[int]) -> int:  # noqa: N802 - SDK's name
            return len(packet) if self.late else super().writePort(packet)

        def setupPort(self, cflag_baud: int) -> bool:  # noqa: N802 - the SDK's, with an exclusive open
            if self.is_open:
                self.closePort()
            # A read timeout, not 0: the SDK polls for a reply in a loop, and a non-blocking read
            # made that loop spin a core, starving a simulated bus of the time to answer.
            self.ser = exclusive_serial(self.port_name, self.baudrate, bytesize=8, timeout=READ_POLL_S)
            self.is_open = True
            self.ser.reset_input_buffer()
            self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
            return True

    return _PortHandler(port)


class ServoBus:
    """One serial port with Dynamixel servos on it, opened on construction.

    ``reply_slack_ms`` is added to the wire and latency time of every reply (the servo's
    Return Delay Time and the host's scheduling). An addressed operation whose reply misses
    that is tried ``1 + retries`` times in all (a reply lost to noise or a busy host is worth one
    more try at setup), each retry only after the reply was awaited ``late_reply_ms`` longer
    (default ``LATE_REPLY_FACTOR`` slacks); the pings of a scan are tried once, since most IDs
    are simply absent.
    """

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = 1_000_000,
        protocol: int = 2,
        auto_recover: bool = True,
        reply_slack_ms: float = DEFAULT_REPLY_SLACK_MS,
        late_reply_ms: float | None = None,
        retries: int = 1,
        sysfs_root: str = "/sys",
    ):
        if protocol not in (1, 2):
            raise ConfigError(f"Dynamixel protocol is 1 or 2, not {protocol}")
        import serial
        from dynamixel_sdk import PacketHandler

        self.port = port
        self.baudrate = baudrate
        self.protocol = protocol
        self.auto_recover = auto_recover
        self.attempts = 1 + max(0, retries)
        self.warning = latency_warning(port, sysfs_root=sysfs_root)
        if self.warning:
            log.warning("%s", self.warning)
        latency = read_latency_timer(port, sysfs_root=sysfs_root) or 0
        late_ms = LATE_REPLY_FACTOR * reply_slack_ms if late_reply_ms is None else late_reply_ms
        self._port = _port_handler(port, float(latency), reply_slack_ms, late_ms)
        try:
            supported = self._port.setBaudRate(baudrate)
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(open_error_message("the Dynamixel port", port, exc)) from None
        if not supported:
            raise ConfigError(f"baud rate {baudrate} is not one dynamixel-sdk can set on {port}")
        self._packet = PacketHandler(float(protocol))
        self._tables: dict[int, ControlTable] = {}
        self._last_error = 0

    def close(self) -> None:
        if self._port.is_open:
            self._port.closePort()

    def __enter__(self) -> ServoBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the transaction core ---------------------------------------------------------------------

    def _call(
        self, servo_id: int, what: str, fn: Callable[..., tuple], *args: Any, alert_ok: bool = False, attempts: int | None = None
    ) -> Any:
        """Run one SDK transaction; return its value (or None) or raise the typed error."""
        from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS

        out = self._transact(servo_id, what, fn, args, attempts or self.attempts)
        result, error = out[-2], out[-1]
        if result == COMM_RX_TIMEOUT:
            raise ServoTimeout(f"servo {servo_id} did not answer {what} on {self.port} (ID, baud rate {self.baudrate}, protocol {self.protocol}?)")
        if result != COMM_SUCCESS:
            raise ServoCommError(f"{what} on servo {servo_id}: {self._packet.getTxRxResult(result)}")
        self._last_error = error
        self._check_status(servo_id, what, error, alert_ok)
        return out[0] if len(out) == 3 else None

    def _transact(self, servo_id: int, what: str, fn: Callable[..., tuple], args: tuple, attempts: int) -> tuple:
        """The SDK call, sent again while no reply comes (up to ``attempts`` times); a reply that
        missed its timeout is awaited before the call is sent again, so that no reply to an
        earlier copy is left on the wire (the module doc)."""
        from dynamixel_sdk import COMM_RX_TIMEOUT

        def run() -> tuple:
            try:
                return fn(self._port, servo_id, *args)
            except OSError as exc:
                raise ServoCommError(f"{what} on servo {servo_id}: the port {self.port} failed ({exc})") from None

        for attempt in range(1, attempts + 1):
            out = run()
            if out[-2] == COMM_RX_TIMEOUT and attempt < attempts:
                with self._port.listening():  # the same call again, receiving only
                    out = run()
            if out[-2] != COMM_RX_TIMEOUT:
                break
        return out

    def _check_status(self, servo_id: int, what: str, error: int, alert_ok: bool) -> None:
        if self.protocol == 2:
            code, alert = error & ~P2_ALERT_BIT, bool(error & P2_ALERT_BIT)
            if code:
                raise ServoStatusError(f"servo {servo_id} refused {what}: {P2_ERRORS.get(code, f'error {code}')}", code)
        else:
            code, alert = error & ~P1_HARDWARE_BITS, bool(error & P1_HARDWARE_BITS)
            if code:
                raise ServoStatusError(f"servo {servo_id} refused {what}: {', '.join(decode_p1_error(code))} error", code)
        if alert and not alert_ok:
            raise ServoAlert(servo_id, [])

    def _recovering(self, servo_id: int, op: Callable[[], T]) -> T:
        """Run ``op``; on an alert, recover (P2, auto_recover) and retry once, else raise with causes."""
        try:
            return op()
        except ServoAlert:
            if not self.auto_recover or self.protocol == 1:
                raise ServoAlert(servo_id, self.hardware_error(servo_id), self._no_recovery_hint()) from None
        self.recover(servo_id)
        return op()

    def _no_recovery_hint(self) -> str:
        if self.protocol == 1:
            return ": Protocol 1.0 has no REBOOT; remove the cause, then power-cycle the servo"
        return ": call recover() or pass auto_recover=True to reboot it"

    # -- discovery ---------------------------------------------------------------------------------

    def ping(self, servo_id: int, *, attempts: int | None = None) -> ServoInfo | None:
        """The servo at ``servo_id``, or None if nobody answers."""
        try:
            number = self._call(servo_id, "PING", self._packet.ping, alert_ok=True, attempts=attempts)
        except ServoTimeout:
            return None
        return self._identify(servo_id, number)

    def scan(self, ids: Iterable[int] | None = None) -> list[ServoInfo]:
        """Every servo that answers: a broadcast ping on P2 when ``ids`` is None, else one ping per ID."""
        if ids is None and self.protocol == 2:
            return self._broadcast_scan()
        found = (self.ping(i, attempts=1) for i in (range(MAX_ID[self.protocol] + 1) if ids is None else ids))
        return [info for info in found if info is not None]

    def _broadcast_scan(self) -> list[ServoInfo]:
        from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS

        answers, result = self._packet.broadcastPing(self._port)
        if result not in (COMM_SUCCESS, COMM_RX_TIMEOUT):
            raise ServoCommError(f"broadcast ping on {self.port}: {self._packet.getTxRxResult(result)}")
        return [self._identify(i, number, firmware) for i, (number, firmware) in sorted(answers.items())]

    def _identify(self, servo_id: int, number: int, firmware: int | None = None) -> ServoInfo:
        try:
            table = table_for_number(self.protocol, number)
        except DeviceError:
            return ServoInfo(servo_id, number, "unknown", self.protocol, firmware)
        self._tables[servo_id] = table
        if firmware is None:
            firmware = self.read_raw(servo_id, "Firmware Version", alert_ok=True)
        return ServoInfo(servo_id, number, table.name, self.protocol, firmware)

    def table(self, servo_id: int) -> ControlTable:
        """The control table of the servo (detected by a ping on first use)."""
        if servo_id not in self._tables:
            info = self.ping(servo_id)
            if info is None:
                raise ServoTimeout(f"servo {servo_id} did not answer PING on {self.port}")
            if servo_id not in self._tables:
                raise DeviceError(f"servo {servo_id} has model number {info.model_number}, which is not a supported model")
        return self._tables[servo_id]

    # -- items ---------------------------------------------------------------------------------------

    def _item(self, servo_id: int, name: str) -> Item:
        return self.table(servo_id).item(name)

    def read_raw(self, servo_id: int, name: str, *, alert_ok: bool = False) -> int:
        """A register value; ``alert_ok`` reads it even from a servo in alert (no recovery)."""
        item = self._item(servo_id, name)

        def read() -> int:
            data = self._call(servo_id, f"READ {item.name}", self._packet.readTxRx, item.address, item.size, alert_ok=alert_ok)
            return item.decode(data)

        return read() if alert_ok else self._recovering(servo_id, read)

    def write_raw(self, servo_id: int, name: str, raw: int) -> None:
        item = self._item(servo_id, name)
        if not item.writable:
            raise ConfigError(f"{item.name} is read-only")
        data = list(item.encode(int(raw)))
        self._recovering(servo_id, lambda: self._call(servo_id, f"WRITE {item.name}", self._packet.writeTxRx, item.address, item.size, data))

    def read(self, servo_id: int, name: str) -> float:
        """An item in SI units (rad, rad/s, s, V, A, °C; % and plain numbers as is)."""
        return self._item(servo_id, name).unit.to_si(self.read_raw(servo_id, name))

    def write(self, servo_id: int, name: str, value: float) -> None:
        self.write_raw(servo_id, name, self._item(servo_id, name).unit.from_si(value))

    # -- setup operations ------------------------------------------------------------------------

    def set_torque(self, servo_id: int, on: bool) -> None:
        self.write_raw(servo_id, "Torque Enable", 1 if on else 0)

    def clear_turns(self, servo_id: int) -> None:
        """CLEAR (Protocol 2.0): fold a multi-turn Present Position back into one turn.

        With torque off a hand can turn the horn past a full revolution; the firmware then
        reports a position that position mode's Goal Position refuses (Data Limit Error). The
        servo answers Result Fail (a ``ServoStatusError``) while the horn still moves.
        """
        if self.protocol == 1:
            raise DeviceError(f"servo {servo_id}: Protocol 1.0 has no CLEAR (its position is always one turn)")
        self._call(servo_id, "CLEAR", self._packet.clearMultiTurn)

    def set_return_delay_time(self, servo_id: int, seconds: float = 0.0) -> None:
        """An EEPROM item: written only when it differs (torque off first on Protocol 2.0)."""
        self._ensure_eeprom(servo_id, "Return Delay Time", self._item(servo_id, "Return Delay Time").unit.from_si(seconds))

    def set_position_mode(self, servo_id: int) -> None:
        """P2: Operating Mode 3; P1: joint mode via the angle limits. Only what differs is written."""
        if self.protocol == 2:
            self._ensure_eeprom(servo_id, "Operating Mode", POSITION_MODE)
        else:
            self._ensure_eeprom(servo_id, "CW Angle Limit", P1_JOINT_MODE_LIMITS[0])
            self._ensure_eeprom(servo_id, "CCW Angle Limit", P1_JOINT_MODE_LIMITS[1])

    def _ensure_eeprom(self, servo_id: int, name: str, raw: int) -> None:
        """Write an EEPROM item only when its value differs.

        EEPROM survives about 100,000 writes, and a daemon that restarts (systemd
        Restart=on-failure) must not wear it out by rewriting the same setup at every start.
        On Protocol 2.0 EEPROM is write-locked while torque is on, so torque goes off first
        (and stays off: the caller turns it on when the loop is ready).
        """
        if self.read_raw(servo_id, name) == int(raw):
            return
        if self.protocol == 2:
            self.set_torque(servo_id, False)
        self.write_raw(servo_id, name, raw)

    def hardware_error(self, servo_id: int) -> list[str]:
        """The causes of the servo's alert: Hardware Error Status (P2) or the status error bits (P1)."""
        if self.protocol == 2:
            return decode_hardware_error(self.read_raw(servo_id, "Hardware Error Status", alert_ok=True))
        self.read_raw(servo_id, "Present Temperature", alert_ok=True)
        return decode_p1_error(self._last_error & P1_HARDWARE_BITS)

    def reboot(self, servo_id: int, *, wait_s: float = REBOOT_WAIT_S) -> None:
        """REBOOT (P2 only), then wait until the servo answers a ping again."""
        if self.protocol == 1:
            raise ServoError("Protocol 1.0 has no REBOOT instruction: power-cycle the servo")
        self._call(servo_id, "REBOOT", self._packet.reboot, alert_ok=True)
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            time.sleep(0.05)
            try:
                self._call(servo_id, "PING", self._packet.ping, alert_ok=True, attempts=1)
                return
            except ServoTimeout:
                continue
        raise ServoTimeout(f"servo {servo_id} did not come back within {wait_s:g} s of a REBOOT")

    def recover(self, servo_id: int) -> list[str]:
        """Read why the servo shut down, reboot it, and return the causes."""
        causes = self.hardware_error(servo_id)
        if self.protocol == 1:
            raise ServoAlert(servo_id, causes, self._no_recovery_hint())
        log.warning("servo %d hardware alert (%s): rebooting it", servo_id, ", ".join(causes) or "no cause reported")
        self.reboot(servo_id)
        return causes

    def prepare(self, servo_id: int) -> ServoInfo:
        """Everything the loop needs from one servo: found, RDT 0, position mode, no alert.

        Torque is switched off only when an EEPROM item has to change (a servo already set up
        keeps holding its arm); the caller turns torque on when the loop is about to command it.
        """
        info = self.ping(servo_id)
        if info is None:
            raise ServoTimeout(f"servo {servo_id} did not answer PING on {self.port} (baud rate {self.baudrate}, protocol {self.protocol})")
        if info.model == "unknown":
            raise DeviceError(f"servo {servo_id} has model number {info.model_number}, which is not a supported model")
        causes = self.hardware_error(servo_id) if self.protocol == 2 else []
        if causes and not self.auto_recover:
            raise ServoAlert(servo_id, causes, self._no_recovery_hint())
        if causes:
            self.recover(servo_id)
        self.set_return_delay_time(servo_id, 0.0)
        self.set_position_mode(servo_id)
        return info
