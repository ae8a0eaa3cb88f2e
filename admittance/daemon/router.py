"""``admittance router``: a Zenoh router for a lab of benches, from the Python package alone.

Daemons in ``mode = "client"`` (or peers) connect to it; ``monitor``, ``set``, ``get`` and
``tare`` connect to it too and reach every bench under its prefix. It is a plain router-mode
session of eclipse-zenoh (no zenohd binary needed); its ``[zenoh]`` table (``--zenoh-config``)
takes the same keys as the daemon's: ``listen``, ``connect`` (to other routers),
``auth_dictionary``, ``tls_*`` and ``operators``. With ``operators`` it enforces the ACL for
every bench under ``prefix`` (e.g. ``prefix = "bench"``: commands on ``bench/**``). A router
forwards queries to the daemons, so the daemons' own logins must be operators too
(docs/lab-network.md).
"""

from __future__ import annotations

import logging
from pathlib import Path

from admittance.daemon.config import ZenohConfig, load_zenoh_table
from admittance.daemon.stopsignals import StopRequest, stop_signals_call
from admittance.daemon.zenoh_iface import make_config, open_session, security_of

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"

log = logging.getLogger(__name__)


def run_router(zenoh_config: Path | None, listen: list[str] | None, duration: float | None) -> int:
    zen = load_zenoh_table(zenoh_config) if zenoh_config else ZenohConfig()
    endpoints = listen or zen.listen or [DEFAULT_LISTEN]
    stop = StopRequest()  # set from a signal handler: no lock (stopsignals.py says why)
    with stop_signals_call(lambda *_: stop.set()):
        # A function, so that zenoh's refusal of a malformed endpoint becomes open_session's one line.
        session = open_session(lambda: make_config(mode="router", listen=endpoints, connect=zen.connect,
                                                   scouting=zen.scouting, security=security_of(zen)),
                               f"as a router on {', '.join(endpoints)}")
        try:
            acl = f"; commands on {zen.prefix}/** only for {', '.join(zen.operators)}" if zen.operators else ""
            log.info("serving on %s (zid %s)%s; stop with Ctrl-C or SIGTERM", ", ".join(endpoints),
                     session.info.zid(), acl)
            stop.wait(duration)
        finally:
            session.close()
    return 0
