"""Zenoh endpoints of the configuration: checked when the file loads, and judged for exposure.

An endpoint is ``<protocol>/<address>[?<metadata>][#<config>]`` (zenoh's locator syntax). A
mistyped one used to surface as a traceback from inside zenoh, after torque was already on;
here each is parsed at load, so a bad one is one line naming the key, before any device is
touched. Only what can be judged without the network is checked: the protocol, and for the IP
protocols a ``host:port`` with a port in 0..65535 and a host that is an IP address or a DNS
name (a name that does not resolve still fails, as one line, when the session opens, which is
also before any servo is written).

Exposure: the daemon listens on loopback by default. Anything else can be reached from the
network, and (until the access control of [zenoh] is configured) anyone who reaches it can set
parameters and tare, so the supervisor warns about it once at start.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass

from admittance.daemon.schema import shown
from admittance.errors import ConfigError

IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")
_DNS_NAME = re.compile(r"^(?=.{1,253}$)[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
                       r"(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$")
_DOTTED_NUMBERS = re.compile(r"^[0-9.]+$")


@dataclass(frozen=True)
class Endpoint:
    protocol: str
    host: str | None  # None for the protocols without an IP address (unix socket, serial)
    port: int | None

    @property
    def exposure(self) -> str:
        """"local" (a unix socket, a serial line), "loopback", "every interface" (0.0.0.0, ::)
        or "network"."""
        if self.host is None:
            return "local"
        if self.host == "localhost":
            return "loopback"
        address = ipaddress.ip_address(self.host) if _is_ip(self.host) else None
        if address is None:
            return "network"
        if address.is_loopback:
            return "loopback"
        return "every interface" if address.is_unspecified else "network"


def parse(text: str, where: str) -> Endpoint:
    """The endpoint ``text``, or a ConfigError naming ``where`` and what is wrong."""
    if not isinstance(text, str) or "/" not in text:
        raise ConfigError(f"{where}: {shown(text)} is not an endpoint (expected <protocol>/<address>, "
                          "e.g. \"tcp/127.0.0.1:7447\")")
    protocol, address = text.split("/", 1)
    address = re.split(r"[?#]", address, maxsplit=1)[0]
    if protocol in OTHER_PROTOCOLS:
        if not address:
            raise ConfigError(f"{where}: {shown(text)} has no address after {protocol}/")
        return Endpoint(protocol, None, None)
    if protocol not in IP_PROTOCOLS:
        raise ConfigError(f"{where}: {shown(text)}: unknown protocol {shown(protocol)} "
                          f"(known: {', '.join(IP_PROTOCOLS + OTHER_PROTOCOLS)})")
    host, port = _host_port(address, text, where)
    return Endpoint(protocol, host, port)


def _host_port(address: str, text: str, where: str) -> tuple[str, int]:
    host, sep, port_text = address.rpartition(":")
    if not sep or not host:
        raise ConfigError(f"{where}: {shown(text)}: expected HOST:PORT after the protocol")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
        if not _is_ip(host) or ":" not in host:
            raise ConfigError(f"{where}: {shown(text)}: {shown(host)} in brackets is not an IPv6 address")
    elif _DOTTED_NUMBERS.match(host):
        if not _is_ip(host):
            raise ConfigError(f"{where}: {shown(text)}: {shown(host)} is not an IPv4 address")
    elif not _DNS_NAME.match(host):
        raise ConfigError(f"{where}: {shown(text)}: {shown(host)} is not an IP address or a host name "
                          "(an IPv6 address goes in brackets: tcp/[::1]:7447)")
    if not port_text.isdigit() or int(port_text) > 65535:
        raise ConfigError(f"{where}: {shown(text)}: the port must be a number 0..65535, got {shown(port_text)}")
    return host, int(port_text)


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def exposure_warnings(zcfg) -> list[str]:
    """One line per way the daemon's session can be reached from outside this machine."""
    if zcfg.mode == "client":  # a client listens nowhere
        return []
    consequence = "any host that reaches it can set parameters and tare the sensor"
    if not zcfg.listen:
        return [f"[zenoh].listen is empty: zenoh then listens on every interface on a random port; "
                f"{consequence} (give a loopback endpoint such as tcp/127.0.0.1:7447)"]
    out = []
    for text in zcfg.listen:
        exposure = parse(text, "[zenoh].listen").exposure
        if exposure in ("network", "every interface"):
            reach = "every interface" if exposure == "every interface" else "the network"
            out.append(f"[zenoh].listen {text} is reachable from {reach}: {consequence}")
    return out
