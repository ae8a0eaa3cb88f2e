"""The systemd unit verifies cleanly and stays hardened; the udev rule sets the FTDI latency.

`systemd-analyze verify` exits 0 even on bad values (it only prints them), so any stderr output
counts as a failure; ExecStart must name an existing executable, so the test verifies a copy
that points at this venv's interpreter.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
UNIT = REPO / "systemd" / "admittance.service"
RULE = REPO / "systemd" / "99-admittance-ftdi.rules"
MAX_EXPOSURE = 3.0

analyze = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(analyze is None, reason="systemd-analyze is not installed")


def unit_copy(tmp_path: Path) -> Path:
    text = re.sub(r"^ExecStart=\S+", f"ExecStart={sys.executable}", UNIT.read_text(), flags=re.M)
    path = tmp_path / "admittance.service"
    path.write_text(text)
    return path


def settings() -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in UNIT.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith(("#", "[")):
            name, value = line.split("=", 1)
            out.setdefault(name.strip(), []).append(value.strip())
    return out


@needs_analyze
def test_unit_verifies_without_any_message(tmp_path):
    result = subprocess.run([analyze, "verify", str(unit_copy(tmp_path))], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stderr.strip() == "", result.stderr


@needs_analyze
def test_unit_exposure_is_at_most_3(tmp_path):
    result = subprocess.run([analyze, "security", "--offline=true", str(unit_copy(tmp_path))],
                            capture_output=True, text=True, timeout=60)
    match = re.search(r"Overall exposure level for \S+: (\d+(?:\.\d+)?)", result.stdout)
    if match is None and "offline" in result.stderr:
        pytest.skip(f"this systemd-analyze has no --offline: {result.stderr.strip()}")
    assert match, result.stdout + result.stderr
    assert float(match.group(1)) <= MAX_EXPOSURE, result.stdout


def test_unit_has_the_required_settings():
    s = settings()
    required = {
        "Type": "notify", "NotifyAccess": "main", "Restart": "on-failure", "KillSignal": "SIGINT",
        "SupplementaryGroups": "dialout", "DevicePolicy": "closed", "RestrictRealtime": "no",
    }
    for name, value in required.items():
        assert s.get(name) == [value], name
    for name in ("WatchdogSec", "LimitRTPRIO", "LimitMEMLOCK"):
        assert name in s, name
    assert any(v.startswith("char-ttyUSB") for v in s["DeviceAllow"])
    assert "PrivateDevices" not in s  # it would hide the serial ports
    assert "CPUSchedulingPolicy" not in s  # it would make every thread real-time


def test_a_fault_that_needs_a_person_is_not_restarted_and_one_a_restart_may_cure_is():
    """docs/faults.md: exit 69 stays down, exit 75 (and any other failure) is restarted."""
    from admittance.errors import EXIT_TEMPFAIL, EXIT_UNAVAILABLE

    s = settings()
    prevented = " ".join(s.get("RestartPreventExitStatus", [])).split()
    assert str(EXIT_UNAVAILABLE) in prevented and str(EXIT_TEMPFAIL) not in prevented
    assert s["Restart"] == ["on-failure"] and "SuccessExitStatus" not in s


def test_udev_rule_sets_the_ftdi_latency_timer_to_1():
    rules = [line for line in RULE.read_text().splitlines() if line.strip() and not line.startswith("#")]
    assert len(rules) == 1
    rule = rules[0]
    assert 'DRIVERS=="ftdi_sio"' in rule
    assert 'ATTR{latency_timer}="1"' in rule
    assert 'SUBSYSTEM=="usb-serial"' in rule
