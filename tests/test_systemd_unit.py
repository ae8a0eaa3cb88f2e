"""The systemd unit verifies cleanly and stays hardened; the udev rule sets the FTDI latency;
`admittance service install` writes both, for the venv it runs from, from the package alone.

`systemd-analyze verify` exits 0 even on bad values (it only prints them), so any stderr output
counts as a failure; ExecStart must name an existing executable, so the test verifies the unit
as `service install` writes it for this venv.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
UNIT = REPO / "admittance" / "data" / "systemd" / "admittance.service"
RULE = REPO / "admittance" / "data" / "systemd" / "99-admittance-ftdi.rules"
MAX_EXPOSURE = 3.0
ADMITTANCE = str(Path(sys.executable).parent / "admittance")

analyze = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(analyze is None, reason="systemd-analyze is not installed")


def unit_copy(tmp_path: Path, *options: str) -> Path:
    """The unit as `admittance service install` writes it below ``tmp_path``."""
    result = subprocess.run([ADMITTANCE, "service", "install", "--root", str(tmp_path), *options],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    return tmp_path / "etc" / "systemd" / "system" / "admittance.service"


def settings() -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in UNIT.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith(("#", "[")):
            name, value = line.split("=", 1)
            out.setdefault(name.strip(), []).append(value.strip())
    return out


@needs_analyze
@pytest.mark.parametrize("options", [(), ("--user", "daemon", "--config", "/srv/lab/arm1.toml")])
def test_installed_unit_verifies_without_any_message(tmp_path, options):
    result = subprocess.run([analyze, "verify", str(unit_copy(tmp_path, *options))], capture_output=True,
                            text=True, timeout=60)
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


def test_service_install_writes_the_unit_for_this_venv_and_the_packaged_rule(tmp_path):
    unit = unit_copy(tmp_path, "--config", "/srv/lab/arm1.toml").read_text()
    assert re.search(rf"^ExecStart={re.escape(ADMITTANCE)} run --config /srv/lab/arm1.toml$", unit, re.M), unit
    assert (tmp_path / "etc/udev/rules.d/99-admittance-ftdi.rules").read_text() == RULE.read_text()
    assert "DynamicUser=yes" in unit and "User=" not in unit.replace("DynamicUser", "")


def test_service_install_runs_as_a_named_user_and_reads_a_home_venv(tmp_path):
    from admittance import service

    unit = service.render_unit(Path("/home/lab/venv/bin/admittance"), Path("/etc/admittance/a.toml"), "lab")
    s = {line.split("=", 1)[0]: line.split("=", 1)[1] for line in unit.splitlines() if "=" in line and line[0] != "#"}
    assert s["DynamicUser"] == "no" and s["User"] == "lab"
    assert s["ProtectHome"] == "read-only"  # `yes` would hide the venv from the service
    assert "ProtectHome=yes" in service.render_unit(Path("/opt/a/bin/admittance"), Path("/etc/a.toml"))


@pytest.mark.parametrize("argv, message", [
    (["--user", "bad name"], "not a valid account name"),
    (["--config", "/etc/with space.toml"], "without spaces"),
])
def test_service_install_refuses_what_systemd_would_misread(tmp_path, argv, message):
    result = subprocess.run([ADMITTANCE, "service", "install", "--root", str(tmp_path), *argv],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "etc").exists()


def test_service_install_that_cannot_write_is_one_line(tmp_path):
    root = tmp_path / "a-file"
    root.write_text("not a folder")
    result = subprocess.run([ADMITTANCE, "service", "install", "--root", str(root)], capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 2 and "cannot write" in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
