"""Zenoh endpoints (``tcp/127.0.0.1:7447``) checked when they are given, so a typo is an error
naming the flag or field, not a session that never connects."""

from __future__ import annotations

import ipaddress
import re
from typing import Annotated

from pydantic import (
    AfterValidator,
)

_IP_LINKS = ("tcp", "udp", "tls", "quic", "ws")
_OTHER_LINKS = ("unixsock-stream", "unixpipe", "serial", "vsock")
_HOST_NAME = re.compile(r"[A-Za-z0-9_]([A-Za-z0-9_.-]*[A-Za-z0-9_])?\.?")


def _ip_address_ok(host: str) -> bool:
    """Whether ``host`` is what a Zenoh IP link takes: ``[IPv6]`` (brackets required, an
    optional ``%scope``), a dotted IPv4 address, or a host name."""
    if host.startswith("["):
        if not host.endswith("]"):
            return False
        inner = host[1:-1].split("%", 1)[0]
        try:
            ipaddress.IPv6Address(inner)
        except ValueError:
            return False
        return True
    if re.fullmatch(r"[0-9.]+", host):
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            return False
        return True
    return _HOST_NAME.fullmatch(host) is not None


def check_endpoint(value: str) -> str:
    """A Zenoh endpoint ``<protocol>/<address>``: a protocol Zenoh knows, and for IP links an
    address ``host:port`` (IPv6 in brackets, port 0-65535), so a typo is refused where it is
    read instead of leaving a session that waits for a peer that cannot exist."""
    proto, sep, rest = value.partition("/")
    address = rest.split("?", 1)[0].split("#", 1)[0]
    if not (sep and proto and address) or any(c.isspace() for c in value):
        raise ValueError("an endpoint is <protocol>/<address>, e.g. tcp/127.0.0.1:7447")
    if proto not in _IP_LINKS + _OTHER_LINKS:
        raise ValueError(
            f"unknown protocol {proto!r}: use one of {', '.join(_IP_LINKS + _OTHER_LINKS)}, "
            "e.g. tcp/127.0.0.1:7447"
        )
    if proto in _IP_LINKS:
        if address.startswith("["):
            host, bracket, after = address.partition("]")
            if not bracket:
                raise ValueError(
                    f"an IPv6 address is closed by ']' before its port, e.g. {proto}/[::1]:7447"
                )
            host, colon, port = host + bracket, after[:1], after[1:]
            colon = colon if colon == ":" else ""
        else:
            host, colon, port = address.rpartition(":")
        if not (colon and port.isdigit() and int(port) <= 65535):
            raise ValueError(
                f"{proto} endpoints end in a port 0-65535, e.g. {proto}/127.0.0.1:7447"
            )
        if not _ip_address_ok(host):
            raise ValueError(
                f"{host!r} is not an address: an IPv4 address, a host name or an IPv6 "
                f"address in brackets, e.g. {proto}/127.0.0.1:7447 or {proto}/[::1]:7447"
            )
    return value


Endpoint = Annotated[str, AfterValidator(check_endpoint)]
