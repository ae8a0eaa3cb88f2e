"""A lab on loopback: `admittance router` with user/password and an ACL, three daemons in client
mode on simulated benches behind it, one monitor that shows all three, and `set`/`get` that
address one bench; a viewer login reads but cannot set; ROS 2 topics from one bench.

Under load (three daemons, each with its own simulated bench, beside a full machine) what costs
is starting Python processes: each start imports zenoh and NumPy, about 0.3 s of CPU when idle
and tens of seconds of wall time when the test's processes get a small share of the CPUs. So
the router and the daemons are the only processes started; the commands a lab types (`monitor`,
`set`, `get`, `tare`) run through the CLI's own ``main`` in this process, with its exit status and
its output (file-descriptor level, so a Rust log line would show too). Every wait is on a
condition with a generous bound.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
import tomli_w

from admittance import data
from admittance.cli import main
from admittance.daemon import config
from admittance.daemon.zenoh_iface import Client, make_config, open_session, security_of

from daemon_process import ADMITTANCE, EXIT_TIMEOUT_S, START_TIMEOUT_S
from helpers import free_endpoint

pytestmark = pytest.mark.hil

MX64 = data.params_file("MX-64")
BENCHES = ("lab/arm1", "lab/arm2", "lab/arm3")
# On a starved machine a daemon's start has taken most of a minute (imports), and the router's
# as long: the lab gets one deadline of several starts.
LAB_START_TIMEOUT_S = 4 * START_TIMEOUT_S
WAIT_S = 30.0  # a condition over Zenoh (states, tokens) that takes well under a second when idle


def write_toml(path: Path, doc: dict) -> Path:
    path.write_text(tomli_w.dumps(doc))
    return path


def lab_files(tmp_path: Path, router: str) -> dict[str, Path]:
    (tmp_path / "users.txt").write_text("bench:bench-pw\nalice:alice-pw\nvisitor:visitor-pw\n")
    for user in ("bench", "alice", "visitor"):
        (tmp_path / f"{user}.pw").write_text(f"{user}-pw\n")
    files = {"router": write_toml(tmp_path / "router.toml", {"zenoh": {
        "prefix": "lab", "listen": [router], "auth_dictionary": "users.txt", "operators": ["bench", "alice"]}})}
    for user in ("alice", "visitor"):
        files[user] = write_toml(tmp_path / f"{user}.toml", {"zenoh": {
            "connect": [router], "auth_user": user, "auth_password_file": f"{user}.pw"}})
    for i, prefix in enumerate(BENCHES):
        files[prefix] = write_toml(tmp_path / f"bench{i + 1}.toml", {
            "bus": {"port": "mock"},
            "joints": [{"id": 1, "model": "MX-64", "params": str(MX64), "name": f"arm{i + 1}_joint"}],
            "sensor": {"kind": "optoforce", "port": "mock", "lever_arm": 0.105, "tare_samples": 50},
            "loop": {"rate_hz": 500.0, "sync_read_divisor": 5},
            "zenoh": {"prefix": prefix, "mode": "client", "connect": [router], "state_rate_hz": 50.0,
                      "auth_user": "bench", "auth_password_file": "bench.pw"},
            "ros2": {"enabled": i == 0, "namespace": "/arm1"},
        })
    return files


def login(path: Path) -> Client:
    zen = config.load_zenoh_table(path)
    return Client(zen.connect, {k: v for k, v in security_of(zen).items() if k != "access_control"})


def command(capfd):
    """``admittance ARGS`` as a lab types it, run by the CLI's ``main`` in this process: its exit
    status and what it wrote (at the file-descriptor level)."""
    def run(*args: str) -> SimpleNamespace:
        capfd.readouterr()  # nothing from before the command
        code = main(list(args))
        out, err = capfd.readouterr()
        return SimpleNamespace(returncode=code, stdout=out, stderr=err)
    return run


@contextlib.contextmanager
def lab(files: dict[str, Path]):
    """The router and the three benches, started together: on a starved machine what takes the
    time is each process's own start (its imports), and each runnable process gets its own share
    of the CPUs, so starting them one after another only adds the waits up. (Started together
    they once missed setup replies; a pseudo-terminal's setup now waits 3 s for a reply, and
    never sends again: open_setup_bus.) Their logs go to files (a pipe nobody reads would block
    a daemon once it filled)."""
    procs, logs = [], []

    def start(*args: str) -> subprocess.Popen:
        logs.append(files["router"].parent / f"{Path(args[-1]).stem}.log")
        with logs[-1].open("w") as log:
            procs.append(subprocess.Popen([str(ADMITTANCE), *args], stdout=subprocess.DEVNULL, stderr=log))
        return procs[-1]

    try:
        deadline = time.monotonic() + LAB_START_TIMEOUT_S
        start("router", "--zenoh-config", str(files["router"]))
        benches = {prefix: (start("run", "--config", str(files[prefix])), logs[-1]) for prefix in BENCHES}
        with login(files["alice"]) as alice:
            for prefix, (proc, log) in benches.items():
                while not alice.alive(prefix, timeout=0.5):
                    assert time.monotonic() < deadline, f"{prefix} never came up behind the router"
                    assert proc.poll() is None, log.read_text()
        yield procs
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in reversed(procs):
            proc.wait(timeout=EXIT_TIMEOUT_S)


def client_session(path: Path):
    """A login's raw Zenoh session in client mode, as any Zenoh tool would open it (the router
    relays a client's publications; a peer's it leaves to the peers' own mesh)."""
    zen = config.load_zenoh_table(path)
    security = {k: v for k, v in security_of(zen).items() if k != "access_control"}
    return open_session(make_config(mode="client", connect=zen.connect, security=security), "forger")


def forged_state_arrives(forger, reader: Client, key: str) -> bool:
    """Whether a state message ``forger`` (a raw session) puts on a daemon's key reaches ``reader``
    (the daemon's own states arrive too: the forged ones are told by their marker)."""
    forged, genuine = [], []
    sub = reader._session.declare_subscriber(
        key, lambda sample: (forged if b"FORGED" in sample.payload.to_bytes() else genuine).append(1))
    try:
        deadline = time.monotonic() + WAIT_S
        while not genuine and time.monotonic() < deadline:  # the subscription is in place
            time.sleep(0.05)
        assert genuine, "the daemon's own states never arrived"
        for _ in range(5):
            forger.put(key, b'{"cycle": -1, "joints": [], "note": "FORGED"}')
            time.sleep(0.1)
        time.sleep(0.5)
        return bool(forged)
    finally:
        sub.undeclare()


def ros2_tokens(visitor: Client, done) -> list[str]:
    """The liveliness tokens of the ROS 2 graph, asked again until ``done(tokens)`` (bounded)."""
    deadline = time.monotonic() + WAIT_S
    while True:
        tokens = [str(r.ok.key_expr) for r in visitor._session.liveliness().get("@ros2_lv/0/**", timeout=2.0)
                  if r.ok is not None]
        if done(tokens) or time.monotonic() > deadline:
            return tokens


def test_router_three_benches_one_monitor_and_an_acl(tmp_path, capfd):
    router = free_endpoint()
    files = lab_files(tmp_path, router)
    admittance = command(capfd)
    with lab(files):

        monitor = admittance("monitor", "--prefix", "lab", "--zenoh-config", str(files["visitor"]),
                             "--duration", "10")
        assert monitor.returncode == 0, monitor.stderr
        for i, prefix in enumerate(BENCHES):
            assert f"{prefix}  joint 1 " in monitor.stdout  # every bench, from one monitor, as a visitor

        as_alice = ["--zenoh-config", str(files["alice"])]
        changed = admittance("set", "virtual_damping=0.123", "--json", "--prefix", "lab/arm2", *as_alice)
        assert changed.returncode == 0 and json.loads(changed.stdout) == {"accepted": True}, changed.stderr
        values = {p: json.loads(admittance("get", "1.virtual_damping", "--json", "--prefix", p, *as_alice).stdout)
                  for p in BENCHES}
        assert values["lab/arm2"] == {"1.virtual_damping": 0.123}
        assert values["lab/arm1"] == values["lab/arm3"] != values["lab/arm2"]  # only the bench addressed

        refused = admittance("set", "virtual_damping=0.5", "--prefix", "lab/arm1", "--timeout", "2",
                             "--zenoh-config", str(files["visitor"]))
        assert refused.returncode == 3 and refused.stderr.count("\n") == 1, refused.stderr
        assert ("the daemon at lab/arm1 is up but did not answer lab/arm1/params: the router's access control "
                "lets only its operators send commands, and this session has user 'visitor'") in refused.stderr
        tare = admittance("tare", "--prefix", "lab/arm1", "--timeout", "2", "--zenoh-config", str(files["visitor"]))
        assert tare.returncode == 3
        assert json.loads(admittance("get", "--json", "--prefix", "lab/arm1", *as_alice).stdout)["1.virtual_damping"] != 0.5

        with contextlib.closing(client_session(files["visitor"])) as visitor, login(files["alice"]) as alice:
            assert not forged_state_arrives(visitor, alice, "lab/arm1/state"), "a visitor published a bench's state"

        with login(files["visitor"]) as visitor:  # ROS 2 graph of bench 1, through the router
            tokens = ros2_tokens(visitor, lambda ts: any("/NN/%/%arm1/admittance" in t for t in ts)
                                 and sum("/MP/" in t for t in ts) >= 2)
        assert any("/NN/%/%arm1/admittance" in t for t in tokens), tokens
        assert sum("/MP/" in t for t in tokens) == 2, tokens


def test_a_bench_started_before_its_router_is_reached_once_the_router_is_up(tmp_path, capfd):
    """A lab after a power cut: the daemon is up before its router. It says so and runs; once the
    router listens, the lab's tools see it alive, read its parameters and its ROS 2 graph through
    the router, with the ACL on. (It used to fall back to a peer session: connected, and never
    seen, since a router does not route between two peers.)"""
    files = lab_files(tmp_path, free_endpoint())
    admittance = command(capfd)
    log = tmp_path / "arm1.log"
    procs = []
    try:
        with log.open("w") as err:
            procs.append(subprocess.Popen([str(ADMITTANCE), "run", "--config", str(files["lab/arm1"])],
                                          stdout=subprocess.DEVNULL, stderr=err))
        deadline = time.monotonic() + LAB_START_TIMEOUT_S
        while "no router at" not in log.read_text():
            assert time.monotonic() < deadline and procs[0].poll() is None, log.read_text()
            time.sleep(0.1)
        procs.append(subprocess.Popen([str(ADMITTANCE), "router", "--zenoh-config", str(files["router"])],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        with login(files["alice"]) as alice:
            deadline = time.monotonic() + WAIT_S
            while not alice.alive("lab/arm1", timeout=0.5):
                assert time.monotonic() < deadline, f"never seen behind the router:\n{log.read_text()}"
        got = admittance("get", "1.virtual_damping", "--json", "--prefix", "lab/arm1", "--zenoh-config",
                         str(files["alice"]))
        assert got.returncode == 0 and "1.virtual_damping" in json.loads(got.stdout), got.stderr
        with login(files["visitor"]) as visitor:
            tokens = ros2_tokens(visitor, lambda ts: any("/NN/%/%arm1/admittance" in t for t in ts))
        assert any("/NN/%/%arm1/admittance" in t for t in tokens), tokens
        assert "zenoh: connected to the router" in log.read_text()
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in reversed(procs):
            proc.wait(timeout=EXIT_TIMEOUT_S)
