"""One schema for every parameter: a value the configuration file refuses is refused by a live
set too (``Supervisor.set_params``, which every ``<prefix>/params`` set goes through), with a
reason that names the key, and nothing changes.

The bad values are written out here, key by key, rather than derived from the schema: deleting
a bound from config.py must make one of these cases fail. Each value lies just outside the
schema's bound and inside the Rust loop's wider envelope (its second gate), and the live
reason is checked to be the schema's (``"<key>: must ..."``, a wording the loop never uses),
so the loop's gate cannot stand in for a missing schema bound.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
import tomli_w

from admittance import _rtcore, data
from admittance.daemon import config
from admittance.daemon.loopconfig import loop_config
from admittance.daemon.supervisor import Supervisor
from admittance.errors import ConfigError

MX64 = data.params_file("MX-64")
NAN, INF = float("nan"), float("inf")

# Joint 1's zero tick 1000 reaches [-1.534, 4.749] rad, joint 2's 3000 reaches [-4.602, 1.678]:
# position limits inside the schema's ±π can still be beyond a joint's reach.
JOINTS = [{"id": 1, "model": "MX-64", "params": str(MX64), "zero_tick": 1000},
          {"id": 2, "model": "MX-64", "params": str(MX64), "zero_tick": 3000}]

# (request, the key the reason must name). Values just outside the schema, inside the loop's envelope.
OUT_OF_RANGE = [
    ({"virtual_inertia": 0.5e-4}, "virtual_inertia"),  # the inertia floor (1e-4); the loop's is 1e-6
    ({"virtual_inertia": 10.5}, "virtual_inertia"),
    ({"virtual_damping": -0.01}, "virtual_damping"),
    ({"virtual_inertia": 5.0, "virtual_damping": 101.0}, "virtual_damping"),  # stable (I high): only the bound
    ({"virtual_coulomb": -0.01}, "virtual_coulomb"),
    ({"virtual_coulomb": 10.1}, "virtual_coulomb"),
    ({"lever_arm": 0.0}, "lever_arm"),
    ({"lever_arm": 0.0005}, "lever_arm"),
    ({"2.lever_arm": -0.0005}, "lever_arm"),
    ({"lever_arm": 2.02}, "lever_arm"),
    ({"lever_arm": -2.02}, "lever_arm"),
    ({"1.position_max": 3.2}, "position_max"),  # within joint 1's reach, beyond ±π
    ({"2.position_min": -3.2}, "position_min"),  # within joint 2's reach, beyond ±π
    ({"1.position_min": -2.0}, "position_min"),  # within ±π, beyond joint 1's reach
    ({"2.limits.position_max": 2.0}, "position_max"),  # within ±π, beyond joint 2's reach
    ({"1.position_min": 1.0, "1.position_max": 0.5}, "position_min"),  # each valid, in the wrong order
    ({"velocity_max": 12.12}, "velocity_max"),
    ({"velocity_max": 0.0}, "velocity_max"),
    ({"limits.acceleration_max": 1010.0}, "acceleration_max"),
    ({"acceleration_max": 0.0}, "acceleration_max"),
    ({"deadband": -0.1}, "deadband"),
    ({"deadband": 101.0}, "deadband"),
    ({"lowpass_hz": -1.0}, "lowpass_hz"),
    ({"lowpass_hz": 500.0}, "lowpass_hz"),  # below its bound (2000 Hz), not below half the rate
    ({"stale_timeout_ms": 0.0}, "stale_timeout_ms"),
    ({"stale_timeout_ms": 505.0}, "stale_timeout_ms"),
    ({"stale_timeout_ms": 1e12}, "stale_timeout_ms"),
    ({"ramp_time_s": -0.1}, "ramp_time_s"),
    ({"ramp_time_s": 10.1}, "ramp_time_s"),
    ({"ramp_time_s": 1e9}, "ramp_time_s"),
    ({"bias": [0.0] * 5}, "bias"),
    ({"bias": [0.0, 0.0, 2001.0, 0.0, 0.0, 0.0]}, "bias"),
    ({"bias": [0.0, 0.0, 0.0, 0.0, 0.0, -2001.0]}, "bias"),
    # Individually valid, jointly unstable: h·B/I = 1e-3 · 50 / 0.02 = 2.5.
    ({"virtual_inertia": 0.02, "virtual_damping": 50.0}, "virtual_*"),
    ({"servo_compensation": 1.01}, "servo_compensation"),
    ({"servo_compensation": -0.01}, "servo_compensation"),
    ({"1.servo_compensation": 0.5}, "servo_compensation"),  # in [0, 1], but the file has no [servo] model
    ({"passivity_guard": 2}, "passivity_guard"),  # 0 or 1; the loop's envelope takes only those too
    ({"2.passivity_guard": -1}, "passivity_guard"),
    ({"passivity_margin": 0.5e-5}, "passivity_margin"),  # the schema's floor (1e-5 J); the loop's is 1e-9
    ({"passivity_margin": 10.5}, "passivity_margin"),
    ({"passivity_damping_max": 0.0}, "passivity_damping_max"),
    ({"1.passivity_damping_max": 101.0}, "passivity_damping_max"),
]
SCALAR_KEYS = sorted(set(config.JOINT_LIVE) | set(config.LOOP_LIVE) - {"bias"})
NOT_FINITE = [({key: value}, key) for key in SCALAR_KEYS for value in (NAN, INF, -INF)] + [
    ({"bias": [0.0, NAN, 0.0, 0.0, 0.0, 0.0]}, "bias"), ({"bias": [INF] * 6}, "bias")]
WRONG_TYPE = [({key: "soft"}, key) for key in SCALAR_KEYS] + [({"bias": 1.0}, "bias"), ({"bias": ["a"] * 6}, "bias")]
CASES = OUT_OF_RANGE + NOT_FINITE + WRONG_TYPE


def test_every_live_key_has_an_out_of_range_case():
    """A new live key needs its own bad values above (it is validated either way, but untested)."""
    covered = {key for request, _ in OUT_OF_RANGE for name in request for key in [name.rsplit(".", 1)[-1]]}
    assert covered == set(config.JOINT_LIVE) | set(config.LOOP_LIVE)


def write_config(tmp_path: Path, request: dict | None = None) -> Path:
    """The test configuration, with ``request``'s values written where a file would hold them."""
    doc = {"bus": {"port": "/dev/ttyUSB0"}, "joints": [dict(j) for j in JOINTS],
           "sensor": {"kind": "optoforce", "port": "/dev/ttyACM0", "lever_arm": 0.1}, "loop": {"rate_hz": 1000.0}}
    for name, value in (request or {}).items():
        head, _, rest = name.partition(".")
        ids, key = ([int(head)], rest) if head.isdigit() else ([j["id"] for j in JOINTS], name)
        key = key.removeprefix("limits.")
        if key in config.LOOP_LIVE:
            doc.setdefault(config.LOOP_LIVE[key][0], {})[key] = value
            continue
        for joint in doc["joints"]:
            if joint["id"] in ids:
                table = joint.setdefault("limits", {}) if key in config.LIMIT_KEYS else joint
                table[key] = value
    path = tmp_path / "daemon.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


@pytest.fixture(scope="module")
def supervisor(tmp_path_factory) -> Supervisor:
    """The live path as the daemon runs it: the supervisor's set_params on the real loop (not started)."""
    cfg = config.load_config(write_config(tmp_path_factory.mktemp("live")))
    sup = Supervisor(cfg, backends=None)
    sup.loop = _rtcore.AdmittanceLoop(loop_config(cfg, "/dev/null-admittance-test"))
    return sup


@pytest.mark.parametrize("request_, key", CASES, ids=[repr(r)[:60] for r, _ in CASES])
def test_a_bad_value_is_refused_live_and_in_the_file_with_the_same_key_named(supervisor, tmp_path, request_, key):
    before = supervisor.loop.params()
    accepted, reason = supervisor.set_params(dict(request_))
    assert not accepted
    assert re.search(rf"{re.escape(key)}(\[\d\])?: ", reason), f"the schema's reason naming {key}, got: {reason}"
    assert len(reason) < 300 and "\n" not in reason
    assert _same(supervisor.loop.params(), before), "all or nothing"
    with pytest.raises(ConfigError) as refused:
        config.load_config(write_config(tmp_path, request_))
    assert key.rstrip("*") in str(refused.value) and "\n" not in str(refused.value)


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(a[k] == b[k] or (a[k] != a[k] and b[k] != b[k]) for k in a)


@pytest.mark.parametrize("request_", [
    {"virtual_damping": 0.08, "1.virtual_inertia": 0.03},
    {"1.position_min": -1.5, "2.position_max": 1.6, "velocity_max": 12.0, "acceleration_max": 1000.0},
    {"lever_arm": -0.001, "deadband": 100.0, "lowpass_hz": 499.0, "stale_timeout_ms": 500.0, "ramp_time_s": 10.0,
     "servo_compensation": 0.0},
    {"bias": [2000, -2000, 0, 0, 0, 1], "virtual_inertia": 1e-4, "virtual_damping": 0.0, "virtual_coulomb": 10.0},
])
def test_values_at_the_bounds_are_accepted_on_both_paths(supervisor, tmp_path, request_):
    assert supervisor.set_params(dict(request_)) == (True, "")
    config.load_config(write_config(tmp_path, request_))
    params = supervisor.loop.params()
    for name, value in request_.items():
        shown = [params[name]] if name in params else [v for k, v in params.items() if k.endswith(f".{name}")]
        assert all(v == pytest.approx(value) for v in shown), name


@pytest.mark.parametrize("name, says", [
    ("rate_hz", "[loop].rate_hz and [foxglove].rate_hz are not live"),
    ("1.zero_tick", "[joints].zero_tick is not live"),
    ("listen", "[zenoh].listen is not live"),
    ("tare_samples", "[sensor].tare_samples is not live"),
    ("virtual_dampng", "unknown parameter 'virtual_dampng' (did you mean 'virtual_damping'?)"),
    ("7.virtual_damping", "no joint with id 7"),
    ("99999999999999999999.virtual_damping", "no joint with id"),
    ("1.deadband", "deadband is loop-wide"),
    ("x" * 100_000, "unknown parameter"),
])
def test_names_that_are_not_live_parameters_are_refused_with_a_reason(supervisor, name, says):
    accepted, reason = supervisor.set_params({name: 1.0})
    assert not accepted and says in reason and len(reason) < 400


def test_a_huge_integer_is_refused_with_a_short_reason(supervisor):
    for request in ({"velocity_max": 10**400}, {"bias": [0, 0, 10**400, 0, 0, 0]}, {"deadband": 2**53 + 1}):
        accepted, reason = supervisor.set_params(request)
        assert not accepted and "2^53" in reason and len(reason) < 200


def test_the_issue_nan_set_is_refused(supervisor):
    """`set virtual_damping=0 virtual_coulomb=0 virtual_inertia=1e-20` once made the model NaN."""
    sup = supervisor
    accepted, reason = sup.set_params({"virtual_damping": 0.0, "virtual_coulomb": 0.0, "virtual_inertia": 1e-20})
    assert not accepted and "virtual_inertia: must be >= 0.0001" in reason
    assert math.isfinite(sup.loop.params()["1.virtual_inertia"])
