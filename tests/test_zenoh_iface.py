"""The daemon's Zenoh keys over real loopback sessions: params get/set, state, stats, liveliness,
and the `admittance set` / `monitor` commands against them."""

from __future__ import annotations

import json
import logging
import threading
import time

import pytest

from admittance.cli import main
from admittance.daemon.config import ZenohConfig
from admittance.daemon.messages import Codec, JointState, State, decode
from admittance.daemon.zenoh_iface import Client, DaemonInterface, RouterLink
from admittance.logs import RateLimitedLog
from admittance.errors import DeviceError

from helpers import free_endpoint


class FakeHandler:
    """All-or-nothing like the loop: any negative value rejects the whole request."""

    def __init__(self):
        self.values = {"1.virtual_damping": 0.05, "1.virtual_inertia": 0.02}
        self.requests = []
        self.tares = []

    def get_params(self):
        return dict(self.values)

    def tare(self, samples):
        self.tares.append(samples)
        return True, ""

    def set_params(self, request):
        self.requests.append(request)
        bad = [k for k, v in request.items() if isinstance(v, float) and v < 0]
        if bad:
            return False, f"{bad[0]} must be >= 0"
        self.values.update({f"1.{k}" if "." not in k else k: v for k, v in request.items()})
        return True, ""


@pytest.fixture(params=["json", "msgpack"])
def daemon(request):
    endpoint = free_endpoint()
    params = FakeHandler()
    iface = DaemonInterface(ZenohConfig(prefix="test/arm", listen=[endpoint]), Codec(request.param), params)
    iface.serve()
    stop = threading.Event()
    state = State(cycle=7, joints=[JointState(id=1, t=1.0, force=2.0, tau=0.2, theta=0.1, omega=0.0,
                                              goal_tick=2100, present_tick=2099)])

    def pump():  # the supervisor's main loop, reduced to what the interface needs
        while not stop.is_set():
            iface.poll()
            iface.publish_state(state)
            stop.wait(0.01)

    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    yield endpoint, params, iface
    stop.set()
    thread.join()
    iface.close()


def test_params_get_set_and_all_or_nothing_rejection(daemon):
    endpoint, params, _ = daemon
    with Client([endpoint]) as client:
        assert client.alive("test/arm")
        assert client.query_params("test/arm") == {"params": params.values}
        assert client.query_params("test/arm", {"virtual_damping": 0.1}) == {"accepted": True}
        assert params.values["1.virtual_damping"] == 0.1
        reply = client.query_params("test/arm", {"virtual_inertia": 0.5, "virtual_damping": -1.0})
        assert reply == {"accepted": False, "reason": "virtual_damping must be >= 0"}
        assert params.values["1.virtual_inertia"] == 0.02


def test_malformed_requests_are_rejected_with_a_reason(daemon):
    endpoint, params, _ = daemon
    with Client([endpoint]) as client:
        for payload in (b'{"virtual_damping": "soft"}', b"\xff\x00"):
            replies = list(client._session.get("test/arm/params", payload=payload, timeout=3.0))
            reply = decode(replies[0].ok.payload.to_bytes(), dict)
            assert reply["accepted"] is False and reply["reason"]
    assert params.requests == []


def test_state_is_published_and_decoded(daemon):
    endpoint, _, _ = daemon
    with Client([endpoint]) as client:
        sub = client.try_stream("test/arm")
        messages = []
        for _ in range(300):
            messages += sub.drain()
            if messages:
                break
            time.sleep(0.01)
        sub.close()
    kind, state = messages[0]
    assert kind == "state" and state["cycle"] == 7 and state["joints"][0]["present_tick"] == 2099


def test_no_daemon_is_a_clear_device_error():
    with Client([free_endpoint()]) as client, pytest.raises(DeviceError, match="nothing answers at tcp/127.0.0.1"):
        client.query_params("nobody/here", timeout=0.5)


def test_set_command_says_what_changed_and_fails_when_refused(daemon, capsys):
    endpoint, params, _ = daemon
    assert main(["set", "virtual_damping=0.2", "--prefix", "test/arm", "--connect", endpoint]) == 0
    assert capsys.readouterr().out == "accepted: 1.virtual_damping 0.05 → 0.2 N·m·s/rad, at once\n"
    assert main(["set", "virtual_damping=-2", "--prefix", "test/arm", "--connect", endpoint]) == 1
    assert capsys.readouterr().out == "refused: virtual_damping must be >= 0\n"
    assert params.values["1.virtual_damping"] == 0.2
    assert main(["set", "1.virtual_damping=0.3", "--json", "--prefix", "test/arm", "--connect", endpoint]) == 0
    assert json.loads(capsys.readouterr().out) == {"accepted": True}
    assert main(["set", "virtual_damping=-2", "--json", "--prefix", "test/arm", "--connect", endpoint]) == 1
    assert json.loads(capsys.readouterr().out)["accepted"] is False


def test_get_command_prints_names_values_and_units_or_json(daemon, capsys):
    endpoint, params, _ = daemon
    assert main(["get", "--prefix", "test/arm", "--connect", endpoint]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split() for line in lines] == [["1.virtual_damping", "0.05", "N·m·s/rad"],
                                                 ["1.virtual_inertia", "0.02", "kg·m²"]]
    assert main(["get", "1.virtual_inertia", "--json", "--prefix", "test/arm", "--connect", endpoint]) == 0
    assert json.loads(capsys.readouterr().out) == {"1.virtual_inertia": 0.02}
    assert main(["get", "1.virtual_inertia", "1.nope", "--prefix", "test/arm", "--connect", endpoint]) == 1
    captured = capsys.readouterr()
    assert captured.out.split() == ["1.virtual_inertia", "0.02", "kg·m²"]
    assert "unknown parameter(s): 1.nope" in captured.err and captured.err.count("\n") == 1


def test_set_command_without_a_daemon_exits_non_zero(capsys):
    code = main(["set", "virtual_damping=0.2", "--prefix", "nobody", "--connect", free_endpoint(),
                 "--timeout", "0.5"])
    assert code != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nothing answers at tcp/127.0.0.1" in err


def test_monitor_prints_plain_lines_when_not_a_tty(daemon, capsys):
    endpoint, _, _ = daemon
    assert main(["monitor", "--prefix", "test/arm", "--connect", endpoint, "--duration", "0.6"]) == 0
    out = capsys.readouterr().out
    assert "joint 1 " in out and "\x1b[" not in out


def test_tare_requests_reach_the_handler_and_bad_ones_are_rejected(daemon, capsys):
    endpoint, handler, _ = daemon
    assert main(["tare", "--samples", "250", "--prefix", "test/arm", "--connect", endpoint]) == 0
    assert capsys.readouterr().out.startswith("accepted: the next 250 force samples become the sensor's zero")
    assert main(["tare", "--samples", "250", "--json", "--prefix", "test/arm", "--connect", endpoint]) == 0
    assert json.loads(capsys.readouterr().out) == {"accepted": True}
    with Client([endpoint]) as client:
        assert client.query("test/arm/tare", {}) == {"accepted": True}  # an empty object: 100 samples
        reply = client.query("test/arm/tare")  # no payload: a read, not a tare
        assert reply["accepted"] is False and "needs a payload" in reply["reason"]
        reply = client.query("test/arm/tare", {"samples": 0})
        assert reply["accepted"] is False and "samples" in reply["reason"]
        assert client.query("test/arm/tare", {"sample": 5})["accepted"] is False
    assert handler.tares == [250, 250, 100]


def replies(client, key, payload=None):
    """Every reply to a get on ``key`` (a wildcard reaches several queryables), decoded."""
    kwargs = {} if payload is None else {"payload": payload}
    return {str(r.ok.key_expr): decode(r.ok.payload.to_bytes()) for r in client._session.get(key, timeout=3.0, **kwargs)}


def test_a_wildcard_get_reads_but_never_acts(daemon):
    """`get <prefix>/**` reaches the tare and params queryables: it may read the parameters, but
    tares and sets need the exact key (a wildcard get re-zeroed the sensor under a pushing hand)."""
    endpoint, handler, _ = daemon
    with Client([endpoint]) as client:
        read = replies(client, "test/arm/**")
        assert read["test/arm/params"] == {"params": handler.values}
        assert read["test/arm/tare"]["accepted"] is False and "exact key" in read["test/arm/tare"]["reason"]
        for key in ("test/arm/**", "test/arm/*", "test/**", "test/arm/ta$*"):
            acted = replies(client, key, b'{"samples": 5, "virtual_damping": 0.3}')
            assert all(reply["accepted"] is False for reply in acted.values()), (key, acted)
            assert all("exact key" in reply["reason"] for reply in acted.values())
    assert handler.tares == [] and handler.requests == []


def test_a_handler_that_raises_costs_one_refusal_not_the_loop(daemon, caplog):
    endpoint, handler, iface = daemon

    def broken(request):
        raise OverflowError("int too large to convert to float")

    handler.set_params = broken
    with Client([endpoint]) as client:
        for _ in range(3):
            reply = client.query_params("test/arm", {"virtual_damping": 0.1})
            assert reply["accepted"] is False and "internal error (OverflowError)" in reply["reason"]
        assert client.query_params("test/arm") == {"params": handler.values}, "still answering"
    assert iface.query_errors == 3
    lines = [r.getMessage() for r in caplog.records if r.name == "admittance.daemon.zenoh_iface"]
    assert len(lines) == 1 and "OverflowError" in lines[0], "rate-limited: one line"


def test_a_reply_that_cannot_be_sent_is_logged_and_the_poll_goes_on(caplog):
    class Query:
        payload, key_expr = None, "k/params"

        def reply(self, *args, **kwargs):
            raise RuntimeError("the asker left")

        def drop(self):
            pass

    iface = interface_over([Query(), Query()], "test.reply")
    assert iface.poll() == 2
    lines = [r.getMessage() for r in caplog.records if r.name == "test.reply"]
    assert len(lines) == 1 and "could not be sent" in lines[0]


def interface_over(queries: list, logger: str) -> DaemonInterface:
    """A DaemonInterface with no session whose params queryable holds ``queries``."""
    class Channel:
        def __init__(self):
            self.queue = list(queries)

        def try_recv(self):
            return self.queue.pop() if self.queue else None

    iface = DaemonInterface.__new__(DaemonInterface)
    iface._log = RateLimitedLog(logging.getLogger(logger))
    iface._codec, iface._handler = Codec("json"), FakeHandler()
    iface._queryables = {"k/params": (Channel(), iface._answer_params)}
    iface.queries = iface.query_errors = 0
    iface.longest_poll_gap_s, iface._last_poll = 0.0, None
    iface.prefix = "k"
    return iface


def test_a_flood_of_queries_is_answered_a_few_per_tick():
    """A poll answers at most MAX_QUERIES_PER_POLL queries per key; the rest wait for the next
    tick, so the state still goes out between them."""
    from admittance.daemon import zenoh_iface

    class Query:
        payload, key_expr = None, "k/params"

        def reply(self, *args, **kwargs):
            pass

        def drop(self):
            pass

    iface = interface_over([Query() for _ in range(3 * zenoh_iface.MAX_QUERIES_PER_POLL + 1)], "test.flood")
    polls = [iface.poll() for _ in range(5)]
    assert polls == [zenoh_iface.MAX_QUERIES_PER_POLL] * 3 + [1, 0]


def test_router_with_a_malformed_endpoint_is_one_line(capsys):
    """Zenoh refuses the endpoint while the configuration is built; that is a one-line error too."""
    from admittance.cli import main

    assert main(["router", "--listen", "not-an-endpoint", "--duration", "0.1"]) == 3
    err = capsys.readouterr().err.strip()
    assert "cannot open a session as a router on not-an-endpoint" in err and "Traceback" not in err
    assert len(err.splitlines()) == 1


def test_a_client_runs_without_its_router_says_so_and_connects_when_it_appears(caplog):
    """[zenoh] mode = "client": the interface starts with the router down (the loop must run), the
    start line says it is not connected, and once a router listens there the state reaches it, and
    the lab's tools (``Client``: a session that listens nowhere, connected to the router) see the
    daemon alive and have their queries answered through the router. (A daemon that fell back to a
    peer session was connected, but a router does not route between two peers: it was never seen.)"""
    import zenoh

    from admittance.daemon.zenoh_iface import make_config

    endpoint = free_endpoint()
    zcfg = ZenohConfig(prefix="lab/arm1", mode="client", connect=[endpoint], listen=[])
    iface = DaemonInterface(zcfg, Codec("json"), FakeHandler())
    iface.serve()
    router = None
    try:
        assert iface.where() == (f"a client of the router at {endpoint}, NOT connected yet (the loop runs; the daemon "
                                 f"tries again every {RouterLink.RETRY_PERIOD_S:g} s)")
        assert iface.poll() == 0  # nothing to answer, and no error, before there is a session
        router = zenoh.open(make_config(mode="router", listen=[endpoint]))
        got = []
        router.declare_subscriber("lab/arm1/state", lambda sample: got.append(sample))
        caplog.set_level(logging.INFO, logger="admittance.daemon.zenoh_iface")
        deadline = time.monotonic() + 20
        while not (got and "zenoh: connected" in caplog.text) and time.monotonic() < deadline:
            iface.publish_state(State(cycle=1, joints=[]))
            iface.watch_link()
            time.sleep(0.1)
        assert got, "the state never reached the router"
        assert iface.where().endswith(", connected")
        assert f"zenoh: connected to the router at {endpoint}" in caplog.text
        with Client([endpoint]) as tool:
            assert tool.alive("lab/arm1", timeout=2.0), "the lab's tools never saw the daemon alive"
            answers = []
            asker = threading.Thread(target=lambda: answers.append(tool.query_params("lab/arm1", timeout=5.0)))
            asker.start()
            deadline = time.monotonic() + 6
            while asker.is_alive() and time.monotonic() < deadline:
                iface.poll()  # the supervisor's tick answers queries
                time.sleep(0.02)
            asker.join(timeout=1)
            assert answers and answers[0]["params"]["1.virtual_damping"] == 0.05
    finally:
        iface.close()
        if router is not None:
            router.close()


@pytest.mark.parametrize("login, attachment, who", [
    ("alice", None, "login 'alice'"),
    (None, None, "a session without a login"),
    (None, b"\xff not json", "a session without a login"),  # hostile bytes: ignored, the set still answered
    (None, b'{"login": "' + b"x" * 100 + b'"}', "a session without a login"),  # too long: not a name
    (None, b'{"login": "a\\u001b[31mred"}', "a session without a login"),  # not printable
])
def test_the_daemon_knows_who_sent_a_set(daemon, login, attachment, who):
    endpoint, params, iface = daemon
    seen = []
    original = params.set_params
    params.set_params = lambda request: (seen.append(iface.requester), original(request))[1]
    with Client([endpoint]) as client:
        client.login = login
        if attachment is None:
            assert client.query_params("test/arm", {"virtual_damping": 0.3}) == {"accepted": True}
        else:
            replies = list(client._session.get("test/arm/params", payload=b'{"virtual_damping": 0.3}',
                                               attachment=attachment, timeout=3.0))
            assert replies and replies[0].ok is not None
    assert seen == [who]
    assert iface.requester is None  # cleared once the query is answered
