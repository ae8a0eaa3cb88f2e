"""The typed boundary to the Rust core: the stub ``admittance/_rtcore.pyi`` against the built
module (mypy's stubtest: every name, every signature, nothing missing or extra), the loop's
configuration builder and the supervisor against the stub's types (mypy), and the defaults and
the key grammar the daemon takes from the core."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from admittance import _rtcore

REPO = Path(__file__).resolve().parents[1]
# The modules mypy holds to the stub's types (make test-stub runs the same list).
TYPED_MODULES = ("admittance/daemon/loopconfig.py", "admittance/loop_config.py", "admittance/daemon/supervisor.py")
pytest.importorskip("mypy")


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=REPO, capture_output=True, text=True, timeout=300)


def test_the_stub_matches_the_built_module():
    done = _run("mypy.stubtest", "admittance._rtcore")
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_loop_configuration_is_built_to_its_type():
    done = _run("mypy", "--follow-imports=silent", "--ignore-missing-imports", "--no-incremental",
                *TYPED_MODULES)
    assert done.returncode == 0, done.stdout + done.stderr


# Keys the daemon declares its own default for although the loop reads them too, and why.
DAEMON_OWN_DEFAULTS = {"rt_priority": "the daemon asks for SCHED_FIFO 80, above a bare loop's 50 (docs/daemon.md)"}


def _loop_keys() -> set[str]:
    """Every key the loop reads (the typed configuration's fields, at any depth)."""
    from admittance import loop_config

    structs = (loop_config.RtLoopConfig, loop_config.RtJoint, loop_config.RtLimits, loop_config.RtFaultPolicy)
    return {name for struct in structs for name in struct.__struct_fields__}


# The daemon's tables the loop's configuration is built from (daemon/loopconfig.py).
LOOP_TABLES = ("BusConfig", "JointConfig", "LimitsConfig", "SensorConfig", "LoopConfig", "FaultsConfig")


def _declared_defaults() -> dict[str, ast.expr | None]:
    """The keys of LOOP_TABLES (config.py's source) that the loop also reads, each with the
    expression of its declared default (None: required). ``port`` is left out: [bus].port is the
    loop's (required in both), [sensor].port the sensor's own device."""
    tree = ast.parse((REPO / "admittance" / "daemon" / "config.py").read_text())
    tables = [node for node in tree.body if isinstance(node, ast.ClassDef) and node.name in LOOP_TABLES]
    assert len(tables) == len(LOOP_TABLES)
    found: dict[str, ast.expr | None] = {}
    for node in (n for table in tables for n in table.body):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(node.value, ast.Call)
                and getattr(node.value.func, "id", "") == "key" and node.target.id in _loop_keys() - {"port"}
                and ast.literal_eval(node.value.args[0]) != "table"):  # [joints.limits]: its keys are scanned
            found[node.target.id] = node.value.args[1] if len(node.value.args) > 1 else None
    return found


def test_the_daemon_takes_the_loops_defaults_from_the_core():
    """One declaration of every default the daemon shares with the loop: the Rust core's, which the
    daemon's tables read from LOOP_DEFAULTS by the key's own name (a literal is refused, even an
    equal one), and every exported default is used."""
    declared = _declared_defaults()
    assert {"bus_lost_timeout_s", "servo_silent_ms", "velocity_max", "rate_hz"} <= set(declared)  # the scan sees
    for name, default in declared.items():
        if default is None or (isinstance(default, ast.Constant) and default.value is None):
            continue  # required, or filled from the plant or the reach by config.resolve
        if name in DAEMON_OWN_DEFAULTS:
            continue
        assert ast.unparse(default) == f"LOOP_DEFAULTS[{name!r}]", \
            f"config.py declares {name}'s default as {ast.unparse(default)}; take it from LOOP_DEFAULTS"
    assert set(_rtcore.LOOP_DEFAULTS) <= set(declared) - set(DAEMON_OWN_DEFAULTS)


def test_the_daemon_takes_the_fault_policys_bounds_from_the_core():
    """The bounds the loop itself sets (a fixed ring of recoveries, a glitch check that means
    something) are read from LOOP_BOUNDS, not restated; the configuration refuses past them."""
    tree = ast.parse((REPO / "admittance" / "daemon" / "config.py").read_text())
    keys = {node.target.id: {k.arg: ast.unparse(k.value) for k in node.value.keywords}
            for node in ast.walk(tree) if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
            and isinstance(node.value, ast.Call) and node.target.id in _rtcore.LOOP_BOUNDS}
    assert set(keys) == set(_rtcore.LOOP_BOUNDS)
    for name, keywords in keys.items():
        assert (keywords["lo"], keywords["hi"]) == (f"LOOP_BOUNDS[{name!r}][0]", f"LOOP_BOUNDS[{name!r}][1]"), name


def test_the_daemons_defaults_equal_the_loops():
    from admittance.daemon import config

    tables = (config.BusConfig, config.JointConfig, config.LimitsConfig, config.SensorConfig, config.LoopConfig,
              config.FaultsConfig)
    fields = {f.name: f for table in tables for f in config.dataclasses.fields(table)}
    for name, value in _rtcore.LOOP_DEFAULTS.items():
        field = fields[name]
        default = field.default_factory() if field.default is config.dataclasses.MISSING else field.default
        assert default == value and type(default) is type(value), name


@pytest.mark.parametrize("name, parsed", [
    ("virtual_damping", (None, "virtual_damping")),
    ("3.virtual_damping", (3, "virtual_damping")),
    ("3.limits.velocity_max", (3, "velocity_max")),
    ("limits.velocity_max", (None, "velocity_max")),
    ("252.x", (252, "x")),
    ("x.y", (None, "x.y")),
])
def test_one_parser_of_the_key_grammar(name, parsed):
    assert _rtcore.split_param_name(name) == parsed


@pytest.mark.parametrize("name", ["253.virtual_damping", "999.virtual_damping", "0001000.x"])
def test_an_id_beyond_the_dynamixel_range_is_refused(name):
    with pytest.raises(ValueError, match=f"0..={_rtcore.MAX_JOINT_ID}"):
        _rtcore.split_param_name(name)
