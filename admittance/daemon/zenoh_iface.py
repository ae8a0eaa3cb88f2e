"""The daemon's Zenoh interface, and the client side of ``admittance monitor``, ``set`` and ``tare``.

This is the only module that imports zenoh, so the rest of the daemon is testable without a
network and the zenoh API (which changed between 0.11 and 1.x) is confined to one file.

Zenoh runs its callbacks on its own Rust threads, and each one takes the GIL. The daemon
therefore declares no Python callbacks at all: queries to ``<prefix>/params`` and
``<prefix>/tare`` land in bounded FIFO channels that the supervisor's main loop drains (:meth:`DaemonInterface.poll`),
and state/stats are published from that same loop. A burst of queries can only fill the
channel; it never stalls anything but the main loop's own next tick.

Networking is loopback-only by default (listen on tcp/127.0.0.1:7447, multicast scouting
off): a bench daemon should not appear on a lab network unless its configuration says so.

Queries are hostile input. A query *acts* (sets parameters, tares) only when its key
expression is exactly the queryable's key and it carries a payload: ``get <prefix>/**`` reaches
every queryable under the prefix, and must read, never act. Whatever a handler raises becomes a
refusal reply (and a rate-limited log line), and a reply that cannot be sent is logged; neither
ends the supervisor's loop.

The session opens (the endpoint is claimed) when the interface is built, early in the start
order, before any servo is written; the queryables and the liveliness token are declared by
:meth:`DaemonInterface.serve`, once the loop runs.
"""

from __future__ import annotations

import json
import logging
import queue
import re
import socket
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import zenoh

from admittance.daemon.messages import (
    Codec, ParamsReply, SetReply, decode, decode_set_request, decode_tare_request,
)
from admittance.daemon.schema import clip
from admittance.errors import AdmittanceError, ConfigError, DataError, DeviceError
from admittance.logs import RateLimitedLog

QUERY_BACKLOG = 32
MAX_QUERIES_PER_POLL = 8  # per key and tick: at a 100 Hz tick 800 sets/s, and the state still goes out each tick
PARAMS_TIMEOUT_S = 2.0  # the monitor's reads of the parameters
MAX_PARAMS_REQUESTS = 4  # reads of the parameters in flight at once (a slow router must not pile them up)
log = logging.getLogger(__name__)


def make_config(*, mode: str = "peer", listen: list[str] | None = None, connect: list[str] | None = None,
                scouting: bool = False, security: dict[str, Any] | None = None) -> zenoh.Config:
    """A session configuration; ``security`` holds zenoh_security.security_entries (JSON5 path -> value)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(scouting))
    if not scouting:
        conf.insert_json5("scouting/gossip/enabled", "false")
    if listen is not None:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    for path, value in (security or {}).items():
        try:
            conf.insert_json5(path, json.dumps(value))
        except zenoh.ZError as exc:
            raise ConfigError(f"[zenoh]: {path}: {_short(str(exc))}") from None
    return conf


def security_of(zcfg: Any) -> dict[str, Any]:
    """The security entries of a [zenoh] table (its paths are already absolute: config.py)."""
    from pathlib import Path

    from admittance.daemon.zenoh_security import security_entries

    return security_entries(zcfg, Path.cwd())


def open_session(conf: zenoh.Config | Callable[[], zenoh.Config], what: str, log_level: str = "error") -> zenoh.Session:
    """A session from ``conf`` (or from a function that builds it, whose errors are caught too:
    zenoh refuses a malformed endpoint while the configuration is built); one-line DeviceError."""
    zenoh.init_log_from_env_or(log_level)
    try:
        return zenoh.open(conf() if callable(conf) else conf)
    except zenoh.ZError as exc:
        raise DeviceError(f"zenoh: cannot open a session {what}: {_short(str(exc))}") from None


def _short(message: str) -> str:
    """Zenoh's errors carry Rust source locations and nested brackets; keep the cause."""
    if "Address already in use" in message:
        return "address already in use (another daemon on this endpoint? change [zenoh].listen)"
    return re.sub(r"\s+at \S+\.rs:\d+\.?", "", message).replace("[", "").replace("]", "").strip()


class Handler(Protocol):
    """What the interface asks of the supervisor (all called from the supervisor's own thread)."""

    def get_params(self) -> dict[str, Any]: ...

    def set_params(self, request: dict[str, Any]) -> tuple[bool, str]: ...

    def tare(self, samples: int) -> tuple[bool, str]: ...


class DaemonInterface:
    """``<prefix>/state``, ``/stats`` (publications), ``/params``, ``/tare`` (queryables), ``/alive``."""

    def __init__(self, zcfg, codec: Codec, handler: Handler) -> None:
        self.prefix = zcfg.prefix
        self._codec = codec
        self._handler = handler
        self._log = RateLimitedLog(log)  # at most one line per kind of query problem per 10 s
        self._encoding = zenoh.Encoding.APPLICATION_JSON if codec.encoding == "json" else zenoh.Encoding(
            "application/msgpack")
        self._state_pub = self._stats_pub = None
        self._queryables: dict[str, tuple[Any, Callable[[bytes, bool], Any]]] = {}
        self._token = None
        self._serving = False
        self._waiting: list[Callable[[zenoh.Session], None]] = []  # what declares on the session once it opens
        self._link = RouterLink(zcfg)
        # None while a client's router is down: the loop runs, the link keeps trying (RouterLink).
        self._session: zenoh.Session | None = self._link.open(
            lambda mode, listen: make_config(mode=mode, listen=listen, connect=zcfg.connect, scouting=zcfg.scouting,
                                             security=security_of(zcfg)))
        if self._session is not None:
            self._declare_publishers()
        self.queries = 0
        self.query_errors = 0
        self.longest_poll_gap_s = 0.0  # the longest a query could have waited for the main thread
        self._last_poll: float | None = None
        self.requester: str | None = None  # who sent the query being answered (requester())

    def where(self) -> str:
        """Where the daemon really is on the network now (for the start line)."""
        return self._link.where(self._session)

    def watch_link(self) -> None:
        """On the main thread, every tick: take the client session a retry opened (then declare
        everything on it), and log once when a client's router comes or goes."""
        if self._session is None:
            session = self._link.opened()
            if session is None:
                return
            self._session = session
            self._declare_publishers()
            if self._serving:
                self._declare_served()
            waiting, self._waiting = self._waiting, []
            for declare in waiting:
                try:
                    declare(session)
                except Exception as exc:  # one view that cannot declare must not stop the loop
                    log.error("zenoh: a view could not declare on the session: %s: %s", type(exc).__name__,
                              clip(str(exc), 160))
        self._link.watch(self._session)

    def serve(self) -> None:
        """Declare the queryables and the liveliness token: the daemon is now visible and steerable
        (once its session is open: at once, or when a client's router comes up)."""
        self._serving = True
        if self._session is not None:
            self._declare_served()

    def when_connected(self, declare: Callable[[zenoh.Session], None]) -> None:
        """Call ``declare(session)`` with the daemon's own session, now or once it opens (the
        ROS 2 bridge declares its publishers and tokens on it)."""
        if self._session is not None:
            declare(self._session)
        else:
            self._waiting.append(declare)

    def _declare_publishers(self) -> None:
        declare = self._session.declare_publisher
        self._state_pub = declare(f"{self.prefix}/state", encoding=self._encoding,
                                  congestion_control=zenoh.CongestionControl.DROP, express=True)
        self._stats_pub = declare(f"{self.prefix}/stats", encoding=self._encoding)

    def _declare_served(self) -> None:
        self._queryables = {
            f"{self.prefix}/{leaf}": (self._session.declare_queryable(
                f"{self.prefix}/{leaf}", zenoh.handlers.FifoChannel(QUERY_BACKLOG)), answer)
            for leaf, answer in (("params", self._answer_params), ("tare", self._answer_tare))
        }
        self._token = self._session.liveliness().declare_token(f"{self.prefix}/alive")

    @property
    def session(self) -> zenoh.Session | None:
        """The daemon's own session (None while a client's router is down: ``when_connected``)."""
        return self._session

    def publish_state(self, message: Any) -> None:
        if self._state_pub is not None:  # no session yet: nobody could receive it
            self._state_pub.put(self._codec.encode(message))

    def publish_stats(self, message: Any) -> None:
        if self._stats_pub is not None:
            self._stats_pub.put(self._codec.encode(message))

    def poll(self) -> int:
        """Answer the pending queries, at most MAX_QUERIES_PER_POLL per key (a flood of sets
        waits for the next ticks instead of starving the state's publication); returns how many
        were answered. Never raises."""
        now = time.monotonic()
        if self._last_poll is not None:
            self.longest_poll_gap_s = max(self.longest_poll_gap_s, now - self._last_poll)
        self._last_poll = now
        answered = 0
        for key, (queryable, answer) in self._queryables.items():
            for _ in range(MAX_QUERIES_PER_POLL):
                if (query := queryable.try_recv()) is None:
                    break
                try:
                    self._answer(key, query, answer)
                finally:
                    query.drop()
                answered += 1
        self.queries += answered
        return answered

    def _answer(self, key: str, query: Any, answer: Callable[[bytes, bool], Any]) -> None:
        self.requester = requester(query)
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            # Exactly this key: a wildcard (`<prefix>/**`) reaches every queryable and may only read.
            reply = answer(payload, str(query.key_expr) == key)
        except Exception as exc:  # a handler's bug must cost one refusal, never the daemon
            self.query_errors += 1
            self._log("handler", f"{key}: a query failed inside the daemon and was refused: "
                                 f"{type(exc).__name__}: {clip(str(exc), 120)}")
            reply = SetReply(accepted=False, reason=f"internal error ({type(exc).__name__}); see the daemon's log")
        finally:
            # Who asked matters only while the handler runs. Cleared before the reply leaves: a
            # client that has its answer finds no stale requester (cleared after the reply, a
            # test saw it still set on a loaded machine).
            self.requester = None
        try:
            query.reply(key, self._codec.encode(reply), encoding=self._encoding)
        except Exception as exc:  # the asker left, the session is closing: nothing to undo
            self._log("reply", f"{key}: a reply could not be sent: {type(exc).__name__}: "
                               f"{clip(str(exc), 120)}")

    def _answer_params(self, payload: bytes, exact: bool) -> ParamsReply | SetReply:
        if not payload.strip():
            return ParamsReply(params=self._handler.get_params())
        if not exact:
            return SetReply(accepted=False, reason=f"a set needs the exact key {self.prefix}/params, not a wildcard")
        return _apply(decode_set_request, self._handler.set_params, payload)

    def _answer_tare(self, payload: bytes, exact: bool) -> SetReply:
        if not exact:
            return SetReply(accepted=False, reason=f"a tare needs the exact key {self.prefix}/tare, not a wildcard")
        return _apply(decode_tare_request, self._handler.tare, payload)

    def close(self) -> None:
        """Withdraw the liveliness token first, so watchers see the daemon leave at once."""
        queryables = [queryable for queryable, _ in self._queryables.values()]
        publishers = [pub for pub in (self._state_pub, self._stats_pub) if pub is not None]
        entities = [self._token] if self._token is not None else []
        for entity in (*entities, *queryables, *publishers):
            entity.undeclare()
        if self._session is not None:
            self._session.close()
        self._link.close()


MAX_LOGIN_CHARS = 64


def requester(query: Any) -> str:
    """Who sent a query, in words: the login its session states (``admittance set`` attaches it;
    the router checked that login's password, the daemon only reads the name), else a session
    without a login. The attachment is untrusted: bounded, printable, or ignored."""
    try:
        attached = query.attachment.to_bytes() if query.attachment is not None else b""
        login = json.loads(attached[:256]).get("login", "") if attached else ""
    except Exception:  # malformed: treated as absent
        login = ""
    if isinstance(login, str) and login and len(login) <= MAX_LOGIN_CHARS and login.isprintable():
        return f"login {login!r}"
    return "a session without a login"


LOGIN_KEY = "transport/auth/usrpwd/user"  # zenoh_security's entry for the session's login


def endpoint_accepts(endpoint: str, timeout: float = 1.0) -> bool:
    """Whether a TCP connection to a tcp/ or tls/ endpoint is accepted (something listens there)."""
    match = re.fullmatch(r"(?:tcp|tls)/\[?([^\]]+?)\]?:(\d+)(?:#.*)?", endpoint)
    if match is None:
        return False
    try:
        with socket.create_connection((match.group(1), int(match.group(2))), timeout=timeout):
            return True
    except OSError:
        return False


class RouterLink:
    """A daemon's place on the network, and a client's link to its router.

    A daemon in ``mode = "client"`` must run its loop whether or not the lab's router is up. It
    opens a zenoh client session; when that fails because no router answers, the loop runs
    without a session and a thread (:class:`_Reopener`) opens the client session again every
    :data:`RETRY_PERIOD_S` until a router answers; the main thread takes it (:meth:`opened`) and
    declares everything on it. Why not a peer session that keeps connecting (what this did
    before): a router does not route between two peers, and the lab's tools (``Client``) are
    peers, so such a daemon was connected to its router and yet never seen. What the start line
    says, and the lines when the router comes and goes, are read from the session, not from the
    configuration.
    """

    CHECK_PERIOD_S = 1.0
    RETRY_PERIOD_S = 1.0

    def __init__(self, zcfg) -> None:
        self.client = zcfg.mode == "client"
        self.mode = zcfg.mode
        self.listen = zcfg.listen if zcfg.listen and not self.client else None  # clients do not listen
        self.connect = list(zcfg.connect)
        self._listening = list(zcfg.listen)
        self._connected: bool | None = None
        self._next_check = 0.0
        self._reopener: _Reopener | None = None

    def open(self, config: Callable[[str, list[str] | None], zenoh.Config]) -> zenoh.Session | None:
        """The session, or None when a client's router is down (then :meth:`opened` hands it over later)."""
        if not self.client:
            return open_session(lambda: config(self.mode, self.listen),
                                f"listening on {', '.join(self._listening) or 'defaults'}")
        what = f"as a client of {', '.join(self.connect)}"
        try:
            return open_session(lambda: config("client", None), what, log_level="off")
        except DeviceError as exc:
            if "Unable to connect" not in str(exc):  # a bad endpoint or security file: not a router that is down
                raise
        log.warning("zenoh: no router at %s yet; the loop runs without it and keeps trying to reach it",
                    ", ".join(self.connect))
        self._connected = False
        self._reopener = _Reopener(lambda: open_session(lambda: config("client", None), what, log_level="off"),
                                   self.RETRY_PERIOD_S)
        return None

    def opened(self) -> zenoh.Session | None:
        """The client session a retry has opened since (once), else None."""
        return self._reopener.take() if self._reopener is not None else None

    def close(self) -> None:
        if self._reopener is not None:
            self._reopener.stop()

    def routers(self, session: zenoh.Session) -> int:
        try:
            return len(list(session.info.routers_zid()))
        except Exception:  # a closing session: no router
            return 0

    def where(self, session: zenoh.Session | None) -> str:
        if not self.client:
            extra = f", connecting to {', '.join(self.connect)}" if self.connect else ""
            return f"listening on {', '.join(self._listening) or 'zenoh defaults'}{extra}"
        self._connected = session is not None and self.routers(session) > 0
        # No session yet: the daemon's own thread opens one when the router answers (_Reopener);
        # a session whose router went away is zenoh's to reconnect.
        retry = (f"the daemon tries again every {self.RETRY_PERIOD_S:g} s" if session is None
                 else "zenoh keeps retrying")
        state = "connected" if self._connected else f"NOT connected yet (the loop runs; {retry})"
        return f"a client of the router at {', '.join(self.connect)}, {state}"

    def watch(self, session: zenoh.Session) -> None:
        now = time.monotonic()
        if not self.client or now < self._next_check:
            return
        self._next_check = now + self.CHECK_PERIOD_S
        connected = self.routers(session) > 0
        if connected != self._connected and self._connected is not None:
            if connected:
                log.info("zenoh: connected to the router at %s", ", ".join(self.connect))
            else:
                log.warning("zenoh: the router at %s is gone; the loop runs on, zenoh keeps retrying",
                            ", ".join(self.connect))
        self._connected = connected


class _Reopener:
    """A thread that calls ``open_client()`` every ``period`` s until it returns a session (each
    failure is a router still down: zenoh says "Unable to connect", and the first try at start
    already refused anything else), and keeps it for the main thread (:meth:`take`). Opening a
    session costs the thread a fraction of a second; the loop never waits for it."""

    def __init__(self, open_client: Callable[[], zenoh.Session], period: float) -> None:
        self._open = open_client
        self._period = period
        self._stopped = threading.Event()
        self._ready: queue.Queue = queue.Queue(maxsize=1)
        self._thread = threading.Thread(target=self._run, name="zenoh-reopen", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stopped.wait(self._period):
            try:
                session = self._open()
            except Exception:  # still no router (or a transient refusal): try again
                continue
            if self._stopped.is_set():  # the daemon closed meanwhile: nobody will take it
                session.close()
            else:
                self._ready.put(session)
            return

    def take(self) -> zenoh.Session | None:
        try:
            return self._ready.get_nowait()
        except queue.Empty:
            return None

    def stop(self) -> None:
        self._stopped.set()
        self._thread.join(timeout=5.0)
        leftover = self.take()  # opened after the daemon's last tick
        if leftover is not None:
            leftover.close()


def _apply(decode_request: Any, apply: Any, payload: bytes) -> SetReply:
    """Decode a request and hand it to the supervisor; a malformed or refused one is rejected
    with why (an AdmittanceError raised by the handler is a refusal like any other)."""
    try:
        accepted, reason = apply(decode_request(payload))
    except AdmittanceError as exc:
        return SetReply(accepted=False, reason=str(exc))
    return SetReply(accepted=accepted, reason="" if accepted else reason)


class Client:
    """A short-lived session for ``monitor``, ``set`` and ``tare``: connects to a daemon, listens nowhere."""

    def __init__(self, connect: list[str], security: dict[str, Any] | None = None) -> None:
        self.connect = connect
        self.login = (security or {}).get(LOGIN_KEY)
        # zenoh's own log lines (raw, coloured, with Rust paths) stay off: each failure is told as one
        # line below, by what the session saw (RUST_LOG still turns them on for a bug hunt).
        self._session = open_session(lambda: make_config(mode="peer", listen=[], connect=connect, security=security),
                                     f"connecting to {', '.join(connect)}", log_level="off")

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *_exc) -> None:
        self._session.close()

    def query_params(self, prefix: str, request: dict[str, Any] | None = None,
                     timeout: float = 3.0) -> dict[str, Any]:
        """Query ``<prefix>/params`` (a set when ``request`` is given); the reply as a dict."""
        return self.query(f"{prefix}/params", request, timeout)

    def query(self, key: str, request: dict[str, Any] | None = None, timeout: float = 3.0) -> dict[str, Any]:
        """The first reply to a get on ``key`` as a dict; DeviceError when no daemon answers."""
        kwargs = {"payload": json.dumps(request).encode()} if request is not None else {}
        # Who asks, for the daemon's log line (the login this session gave the router, or none).
        kwargs["attachment"] = json.dumps({"login": self.login or ""}).encode()
        for reply in self._session.get(key, timeout=timeout, **kwargs):
            if reply.ok is not None:
                return decode(reply.ok.payload.to_bytes())
            raise DeviceError(f"{key}: the daemon replied with an error: {reply.err.payload.to_string()}")
        raise DeviceError(self.why_no_answer(key, timeout))

    def linked(self) -> bool:
        """Whether this session has a link to any router or peer (a login refused leaves none)."""
        info = self._session.info
        return bool(list(info.routers_zid()) or list(info.peers_zid()))

    def why_no_answer(self, key: str, timeout: float) -> str:
        """One line for a query nobody answered: no link (nothing listens, or the login was
        refused), a daemon that is up but whose commands this login may not send (the ACL), or
        no daemon on that key."""
        via = ", ".join(self.connect)
        who = f"user {self.login!r}" if self.login else "no login"
        if not self.linked():
            if any(endpoint_accepts(endpoint) for endpoint in self.connect):
                return (f"{via} refused this session ({who}): check auth_user and its password file, or the "
                        f"TLS certificate, in --zenoh-config")
            return f"nothing answers at {via}: is the router or `admittance run` up there?"
        prefix = key.rsplit("/", 1)[0]
        if self.publishing(prefix, timeout=1.0):
            return (f"the daemon at {prefix} is up but did not answer {key}: the router's access control lets "
                    f"only its operators send commands, and this session has {who}")
        return (f"no daemon answered on {key} via {via} within {timeout:g} s "
                f"(is `admittance run` up, with the same prefix?)")

    def try_stream(self, prefix: str) -> Any:
        """A subscriber whose ``try_recv()`` never blocks (for a redraw loop with its own clock)."""
        return _Polled(self._session.declare_subscriber(f"{prefix}/*", zenoh.handlers.RingChannel(16)))

    def try_stream_benches(self, prefix: str) -> Any:
        """Like try_stream, for every bench under ``prefix``, for the monitor: drain() gives
        (kind, message, bench) for each state and stats, each liveliness change of
        ``<bench>/alive`` (``("alive", {"alive": bool}, bench)``, the tokens present at the start
        included) and each reply to ``request_params()`` (``("params", {"params": ...}, bench)``)."""
        session = self._session
        data = session.declare_subscriber(f"{prefix}/**", zenoh.handlers.RingChannel(256))
        alive = session.liveliness().declare_subscriber(f"{prefix}/**/alive", zenoh.handlers.FifoChannel(256),
                                                         history=True)
        # A read of every bench's parameters (a wildcard get only ever reads: zenoh_iface's rule).
        request = lambda: session.get(f"{prefix}/**/params", zenoh.handlers.FifoChannel(64),  # noqa: E731
                                      timeout=PARAMS_TIMEOUT_S)
        return _Polled(data, with_bench=True, alive=alive, request_params=request)

    def publishing(self, prefix: str, timeout: float = 1.0) -> bool:
        """Whether ``<prefix>/state`` arrives within ``timeout`` (what any login may read)."""
        subscriber = self._session.declare_subscriber(f"{prefix}/state", zenoh.handlers.RingChannel(1))
        try:
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                if subscriber.try_recv() is not None:
                    return True
                time.sleep(0.02)
            return False
        finally:
            subscriber.undeclare()

    def alive(self, prefix: str, timeout: float = 2.0) -> bool:
        return any(r.ok is not None for r in self._session.liveliness().get(f"{prefix}/alive", timeout=timeout))


class _Polled:
    def __init__(self, subscriber: Any, with_bench: bool = False, alive: Any = None,
                 request_params: Callable[[], Any] | None = None) -> None:
        self._subscriber = subscriber
        self._with_bench = with_bench
        self._alive = alive
        self._request = request_params
        self._params_replies: list[Any] = []  # the handlers of gets still answering

    def request_params(self) -> None:
        if self._request is not None and len(self._params_replies) < MAX_PARAMS_REQUESTS:
            self._params_replies.append(self._request())

    def drain(self) -> list[tuple]:
        out = self._drain_alive() + self._drain_params()
        while (sample := self._subscriber.try_recv()) is not None:
            bench, _, leaf = str(sample.key_expr).rpartition("/")
            if leaf not in ("state", "stats"):
                continue
            try:
                message = decode(sample.payload.to_bytes())
            except DataError:
                continue  # someone else's payload on a matching key: not ours to show
            out.append((leaf, message, bench) if self._with_bench else (leaf, message))
        return out

    def _drain_alive(self) -> list[tuple]:
        out = []
        while self._alive is not None and (sample := self._alive.try_recv()) is not None:
            bench = str(sample.key_expr).rpartition("/")[0]
            out.append(("alive", {"alive": sample.kind == zenoh.SampleKind.PUT}, bench))
        return out

    def _drain_params(self) -> list[tuple]:
        out, pending = [], []
        for replies in self._params_replies:
            try:
                while (reply := replies.try_recv()) is not None:
                    if reply.ok is None:
                        continue  # refused (access control) or failed: the view keeps what it had
                    try:
                        message = decode(reply.ok.payload.to_bytes())
                    except DataError:
                        continue
                    if isinstance(message, dict) and isinstance(message.get("params"), dict):
                        out.append(("params", message, str(reply.ok.key_expr).rpartition("/")[0]))
                pending.append(replies)
            except zenoh.ZError:  # the get is over (every queryable answered, or its timeout)
                continue
        self._params_replies = pending
        return out

    def close(self) -> None:
        self._subscriber.undeclare()
        if self._alive is not None:
            self._alive.undeclare()

