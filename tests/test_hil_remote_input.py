"""Hardware-in-loop: hostile Zenoh input against the real daemon (`admittance run` on the embedded
simulated bench, in a subprocess), from a raw zenoh session.

A person's hand is on the joint, so two things must hold whatever arrives: the daemon stays
alive (its liveliness token stays, its loop keeps cycling, it stops cleanly on SIGINT) and the
joint is never misdriven (no cycle moves the goal further than the fastest accepted speed
allows, and no fault of the model's state is ever raised). First the payloads of issue 10 that
crashed or misdrove the daemon, one by one; then a property-based fuzz (Hypothesis) of
everything else: huge integers, deep nesting, NaN/Infinity tokens, wrong types, huge strings,
invalid UTF-8, MessagePack, sets valid one by one but not together, valid sets (which are
accepted and change the dynamics under the pushing hand), wildcard keys. `HYPOTHESIS_SCALE`
runs more examples.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess

import msgspec
import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from daemon_process import (ADMITTANCE, EXIT_TIMEOUT_S, kill, read_recording, wait_alive, wait_for_cycles,
                            wait_for_state)
from helpers import examples, free_endpoint

pytestmark = pytest.mark.hil

PREFIX = "hil/fuzz"
RATE_HZ = 1000.0
TICK_RAD = 2 * math.pi / 4096
SPEED_BOUND = 12.0  # rad/s: the schema's velocity_max bound, the fastest any accepted set may go
PARAMS, TARE = f"{PREFIX}/params", f"{PREFIX}/tare"
KEYS = [PARAMS, TARE, f"{PREFIX}/**", f"{PREFIX}/*", "hil/**", f"{PREFIX}/ta$*", f"{PREFIX}/params?x=1"]
BIG = b"9" * 400


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    """The daemon, pushed by a sine hand, recording every cycle; yields (endpoint, tmp dir, process)."""
    tmp = tmp_path_factory.mktemp("fuzz")
    endpoint = free_endpoint()
    doc = {
        "bus": {"port": "mock"},
        "joints": [{"id": 1, "model": "MX-64", "virtual_inertia": 0.02, "virtual_damping": 0.1,
                    "virtual_coulomb": 0.02}],
        "sensor": {"kind": "optoforce", "port": "mock", "lever_arm": 0.105},
        "loop": {"sync_read_divisor": 1},
        "zenoh": {"prefix": PREFIX, "listen": [endpoint]},
        "bench": {"profile": "sine:amplitude=0.15,frequency=1", "hand_delay_s": 0.2},
    }
    config = tmp / "daemon.toml"
    config.write_text(tomli_w.dumps(doc))
    proc = subprocess.Popen([str(ADMITTANCE), "run", "--config", str(config), "--record", str(tmp / "rec"),
                             "--stats-json", str(tmp / "stats.json")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_alive(endpoint, PREFIX)
        yield endpoint, tmp, proc
    finally:
        if proc.poll() is None:
            kill(proc)


def ask(client, key: str, payload: bytes | None) -> list[dict]:
    """Every reply to one get, decoded; each must be a well-formed reply with a short reason."""
    from admittance.daemon.messages import decode

    kwargs = {} if payload is None else {"payload": payload}
    out = []
    for reply in client._session.get(key, timeout=10.0, **kwargs):
        assert reply.ok is not None, unanswered(client, key, payload, reply.err.payload.to_string())
        message = decode(reply.ok.payload.to_bytes(), dict)
        assert "params" in message or ("accepted" in message and len(message.get("reason", "")) < 400), message
        out.append(message)
    return out


def unanswered(client, key: str, payload: bytes | None, error: str) -> str:
    """Which get failed, and what the daemon's next stats said (its cycles, telemetry dropped, and
    queries answered, failed, the longest its queryables went unpolled): a starved main thread or
    a stuck query path."""
    try:
        stats = wait_for_state(client, PREFIX, lambda m: True, "any stats", timeout=5.0, leaf="stats")
        said = {name: stats.get(name) for name in ("cycles", "overruns", "telemetry_drops", "daemon")}
    except AssertionError as exc:
        said = str(exc)
    shown = "no payload" if payload is None else f"payload {payload[:60]!r} ({len(payload)} bytes)"
    return f"get {key} with {shown}: {error}; the daemon's stats then: {said}"


def params_of(client) -> dict:
    return ask(client, PARAMS, None)[0]["params"]


ISSUE_PAYLOADS = [
    b'{"virtual_damping": ' + BIG + b"}",  # OverflowError, then exit 1
    b'{"bias": [0, 0, ' + BIG + b", 0, 0, 0]}",  # the same inside bias
    b"[" * 100_000,  # RecursionError
    b'{"virtual_damping": 0, "virtual_coulomb": 0, "virtual_inertia": 1e-20}',  # the model went NaN
    b'{"stale_timeout_ms": 1e12}',  # a silent sensor let the joint run
    b'{"ramp_time_s": 1e9}',
    b'{"lever_arm": 0}',
    b'{"position_max": 100}',
    b'{"velocity_max": 1e300}',  # would have made clamp panic on the RT thread
    b'{"position_max": 3.1410}',  # beyond the reach of zero tick 2048 (3.1401 rad)
    msgspec.msgpack.encode({"velocity_max": float("nan")}),
    msgspec.msgpack.encode({"deadband": 2**64 - 1}),
]

live_names = st.sampled_from(["virtual_inertia", "virtual_damping", "virtual_coulomb", "lever_arm", "position_min",
                              "position_max", "velocity_max", "acceleration_max", "limits.velocity_max",
                              "deadband", "lowpass_hz", "stale_timeout_ms", "ramp_time_s", "bias"])
names = st.one_of(live_names, live_names.map(lambda n: f"1.{n}"), live_names.map(lambda n: f"7.{n}"),
                  st.sampled_from(["rate_hz", "zero_tick", "listen", "samples", "", "1.", ".", "1.rate_hz"]),
                  st.text(max_size=30))
numbers = st.one_of(st.floats(), st.integers(-2**70, 2**70), st.sampled_from([0, -0.0, 1e-20, 1e300, 10**30]))
values = st.recursive(st.one_of(numbers, st.booleans(), st.none(), st.text(max_size=20)),
                      lambda inner: st.lists(inner, max_size=7), max_leaves=10)
hostile_sets = st.dictionaries(names, values, min_size=1, max_size=4)
# Sets the schema accepts (mostly: they combine with whatever was accepted before them).
valid_sets = st.fixed_dictionaries({}, optional={
    "virtual_inertia": st.floats(0.005, 0.1), "virtual_damping": st.floats(0.0, 1.0),
    "virtual_coulomb": st.floats(0.0, 0.2), "lever_arm": st.sampled_from([0.105, -0.105, 0.05]),
    "velocity_max": st.floats(0.1, 12.0), "acceleration_max": st.floats(1.0, 1000.0),
    "position_min": st.floats(-3.0, -0.1), "position_max": st.floats(0.1, 3.0), "deadband": st.floats(0.0, 2.0),
    "lowpass_hz": st.floats(0.0, 100.0), "stale_timeout_ms": st.floats(5.0, 500.0), "ramp_time_s": st.floats(0, 1),
    "bias": st.lists(st.floats(-5.0, 5.0), min_size=6, max_size=6)})
# Each value valid, the set not: limits in the wrong order, an unstable joint (h·B/I ≥ 1).
jointly_invalid = st.one_of(
    st.tuples(st.floats(-3.0, 3.0), st.floats(0.0, 3.0)).map(
        lambda p: {"position_min": p[0], "position_max": p[0] - p[1]}),
    st.tuples(st.floats(1e-4, 0.05), st.floats(1.0, 50.0)).map(
        lambda p: {"virtual_inertia": p[0], "virtual_damping": min(100.0, p[0] * 1000.0 * p[1])}))


def encodings(request: dict) -> list[bytes]:
    """JSON (which writes NaN as null), and MessagePack (NaN as NaN) when it can hold every integer."""
    out = [msgspec.json.encode(request)]
    try:
        out.append(msgspec.msgpack.encode(request))
    except OverflowError:  # beyond 64 bits: JSON only
        pass
    return out


encoded = st.one_of(
    st.one_of(hostile_sets, valid_sets, jointly_invalid).flatmap(lambda request: st.sampled_from(encodings(request))),
    st.sampled_from([b'{"deadband": NaN}', b'{"deadband": Infinity}', b'{"bias": [-Infinity, 0, 0, 0, 0, 0]}',
                     b'{"samples": 5}', b"{}", b"", b'{"samples": ' + BIG + b"}"]),
    st.binary(max_size=64),  # invalid UTF-8, truncated MessagePack, anything
    st.integers(1, 200_000).map(lambda n: b"[" * n),
    st.integers(1, 5000).map(lambda n: b'{"deadband": ' + b"[" * n + b"]" * n + b"}"),
    st.integers(1, 5000).map(lambda n: b"\x81\xa8deadband" + b"\x91" * n + b"\x90"),
    st.integers(1, 20_000).map(lambda n: b'{"a":' * n),
    st.integers(1, 1 << 20).map(lambda n: b'{"deadband": "' + b"x" * n + b'"}'),
)


def test_hostile_payloads_neither_kill_nor_misdrive_the_joint(daemon):
    from admittance.daemon.zenoh_iface import Client

    endpoint, tmp, proc = daemon
    with Client([endpoint]) as client:
        wait_for_state(client, PREFIX, lambda m: abs(m["joints"][0]["tau"]) > 0.05, "the hand pushing")
        for payload in ISSUE_PAYLOADS:
            (reply,) = ask(client, PARAMS, payload)
            assert reply["accepted"] is False, payload[:60]
        # A wildcard get with a tare's payload must not tare (nor set) anything.
        bias = params_of(client)["bias"]
        assert all(r.get("accepted") is not True for r in ask(client, f"{PREFIX}/**", b'{"samples": 5}'))
        wait_for_cycles(client, PREFIX, 200)
        assert params_of(client)["bias"] == bias, "a wildcard get tared the sensor"

        outcomes = []

        @settings(max_examples=examples(150), suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
        @given(key=st.sampled_from(KEYS), payload=encoded)
        def attack(key, payload):
            outcomes.extend(reply.get("accepted") for reply in ask(client, key, payload))
            if len(outcomes) % 25 == 0:
                assert client.alive(PREFIX, timeout=5.0), "the daemon's liveliness token is gone"

        attack()
        # The fuzz reached the handlers: most payloads refused, some sets (and tares) accepted.
        assert outcomes.count(False) > 50 and outcomes.count(True) > 0, outcomes
        assert client.alive(PREFIX, timeout=5.0)
        wait_for_cycles(client, PREFIX, 500)  # the loop still cycles
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=EXIT_TIMEOUT_S)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr

    stats = json.loads((tmp / "stats.json").read_text())
    assert stats["faults"]["model_state_invalid"] == 0, "an invalid model state got through"
    assert not any(stats["faults"].values()), stats["faults"]
    assert stats["daemon"]["query_errors"] == 0, "a handler raised (the refusal is a crash averted, still a bug)"
    rec = read_recording(tmp / "rec")
    assert np.ptp(rec["theta_goal"]) > 0.05, "the hand moved the joint (else no jump could show)"
    steps = np.abs(np.diff(rec["theta_goal"]))
    # Per unit of the model's time (`t`, the deadline it was integrated to), not per cycle: a cycle
    # after an overrun catches up several steps at once (a loaded machine, as in CI), each bounded.
    model_steps = np.round(np.diff(rec["t"]) * RATE_HZ)
    allowed = SPEED_BOUND * model_steps / RATE_HZ + 1.5 * TICK_RAD
    assert np.all(steps <= allowed), f"a goal jumped by {steps.max():.3f} rad"
    assert np.all(rec["fault"] == 0)
