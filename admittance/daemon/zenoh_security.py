"""Zenoh authentication, TLS and access control, built from the ``[zenoh]`` table.

The daemon, ``admittance router`` and the remote tools (monitor, set, get, tare) all open their
sessions through :func:`zenoh_iface.make_config`; this module turns the table's security keys
into the Zenoh configuration entries they stand for (docs/zenoh.md, docs/lab-network.md):

- ``auth_dictionary``: sessions that connect must log in (``transport/auth/usrpwd``) as one of
  the file's ``user:password`` lines; ``auth_user`` + ``auth_password_file`` are this side's login.
- ``tls_*``: the ``tls/`` link's CA, certificate and key; ``tls_client_auth`` asks peers for a
  certificate too (mutual TLS), whose common name then identifies them.
- ``operators``: access control. Two roles: *operators* (the listed user names or certificate
  common names) may send commands, i.e. queries on ``<prefix>/**`` (params, tare and any later
  command key), serve them, and publish (state, stats, the ``alive`` token: a daemon's own
  login is an operator); *everyone* authenticated may read: subscribe, and receive what is
  published (state, stats, alive, the ROS 2 topics and ``@ros2_lv`` tokens), and announce its
  own ROS 2 node (``@ros2_lv`` tokens). Anything else is denied: a reader can neither see the
  queryables (a command is a query) nor publish a forged state that other readers would take for
  the daemon's.

The check is made where the link ends: a daemon enforces it on sessions that connect to it
directly; behind a router, the router holds the ACL (its operators include the daemons' own
logins, since a daemon serves the command keys), because the daemon only sees the router's link.

Nothing here opens a socket, so the mapping is unit-tested without a network.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from admittance.errors import ConfigError

# What a reader may send (ingress) and receive (egress): subscriptions and liveliness queries.
SUBSCRIBE_MESSAGES = ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query")
# What is published: a reader receives it (egress only), an operator (a daemon) sends it too.
PUBLISH_MESSAGES = ("put", "delete", "liveliness_token")
COMMAND_MESSAGES = ("query", "declare_queryable", "reply")
# `**` never matches a chunk that starts with `@` (Zenoh's verbatim chunks), so the ROS 2 graph's
# liveliness tokens are named explicitly.
READ_KEYS = ("**", "@ros2_lv/**")
ROS2_GRAPH_KEYS = ("@ros2_lv/**",)
MAX_PASSWORD_BYTES = 4096


def security_entries(zen: Any, base: Path, *, command_prefixes: list[str] | None = None) -> dict[str, Any]:
    """Zenoh configuration entries (JSON5 path -> value) for the security keys of ``zen``.

    ``base`` is the folder relative paths are read from (the configuration file's).
    ``command_prefixes``: the key prefixes whose queries are commands (default ``[zen.prefix]``).
    """
    entries: dict[str, Any] = {}
    if zen.auth_dictionary:
        entries["transport/auth/usrpwd/dictionary_file"] = str(_file(base, zen.auth_dictionary, "auth_dictionary"))
    if zen.auth_user:
        entries["transport/auth/usrpwd/user"] = zen.auth_user
        entries["transport/auth/usrpwd/password"] = _password(_file(base, zen.auth_password_file,
                                                                    "auth_password_file"))
    entries.update(_tls_entries(zen, base))
    if zen.operators:
        entries["access_control"] = access_control(command_prefixes or [zen.prefix], zen.operators)
    return entries


def _tls_entries(zen: Any, base: Path) -> dict[str, Any]:
    tls = "transport/link/tls/"
    entries: dict[str, Any] = {}
    if zen.tls_ca:
        entries[tls + "root_ca_certificate"] = str(_file(base, zen.tls_ca, "tls_ca"))
    if zen.tls_certificate:
        cert = str(_file(base, zen.tls_certificate, "tls_certificate"))
        key = str(_file(base, zen.tls_private_key, "tls_private_key"))
        # The same identity whichever side opens the link.
        entries.update({tls + "listen_certificate": cert, tls + "listen_private_key": key,
                        tls + "connect_certificate": cert, tls + "connect_private_key": key})
    if zen.tls_client_auth:
        entries[tls + "enable_mtls"] = True
    return entries


def access_control(prefixes: list[str], operators: list[str]) -> dict[str, Any]:
    """The ACL: operators may query (command) under each prefix and publish; everyone may read."""
    command_keys = [f"{p}/**" for p in prefixes]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            {"id": "read", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": list(SUBSCRIBE_MESSAGES), "key_exprs": list(READ_KEYS)},
            {"id": "receive", "permission": "allow", "flows": ["egress"],
             "messages": list(PUBLISH_MESSAGES), "key_exprs": list(READ_KEYS)},
            {"id": "ros2-graph", "permission": "allow", "flows": ["ingress"],
             "messages": ["liveliness_token"], "key_exprs": list(ROS2_GRAPH_KEYS)},
            {"id": "publish", "permission": "allow", "flows": ["ingress"],
             "messages": list(PUBLISH_MESSAGES), "key_exprs": list(READ_KEYS)},
            {"id": "command", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": list(COMMAND_MESSAGES), "key_exprs": command_keys},
        ],
        # Attributes inside one subject must all match, so user names and certificate names
        # are two subjects; a subject with no attribute matches every link.
        "subjects": [
            {"id": "operator-users", "usernames": list(operators)},
            {"id": "operator-certificates", "cert_common_names": list(operators)},
            {"id": "anyone"},
        ],
        "policies": [
            {"rules": ["command", "publish"], "subjects": ["operator-users", "operator-certificates"]},
            {"rules": ["read", "receive", "ros2-graph"], "subjects": ["anyone"]},
        ],
    }


def _file(base: Path, name: str, key: str) -> Path:
    path = Path(name) if Path(name).is_absolute() else base / name
    if not path.is_file():
        raise ConfigError(f"[zenoh].{key}: file {str(path)!r} not found")
    return path


def _password(path: Path) -> str:
    try:
        raw = path.read_bytes()[: MAX_PASSWORD_BYTES + 1]
    except OSError as exc:
        raise ConfigError(f"[zenoh].auth_password_file: cannot read {path} ({exc.strerror})") from None
    if len(raw) > MAX_PASSWORD_BYTES:
        raise ConfigError(f"[zenoh].auth_password_file: {path} is longer than {MAX_PASSWORD_BYTES} bytes")
    try:
        password = raw.decode().strip("\r\n")
    except UnicodeDecodeError:
        raise ConfigError(f"[zenoh].auth_password_file: {path} is not UTF-8 text") from None
    if not password or "\n" in password:
        raise ConfigError(f"[zenoh].auth_password_file: {path} must hold the password on one line")
    return password
