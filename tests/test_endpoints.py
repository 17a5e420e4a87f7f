"""Zenoh endpoints are checked where they are read: a malformed one is refused with the reason,
never handed to Zenoh to wait for a peer that cannot exist."""

from __future__ import annotations

import pytest

from stereod.bus.endpoints import check_endpoint

GOOD = [
    "tcp/127.0.0.1:7447",
    "tcp/[::1]:7447",
    "tcp/[fe80::1%eth0]:7447",
    "tcp/localhost:0",
    "tls/daemon.example.org:7447",
    "udp/10.0.0.1:7447",
    "quic/[::]:7447",
    "ws/127.0.0.1:8000",
    "tcp/127.0.0.1:7447?iface=lo",
    "unixsock-stream//run/stereod.sock",
]

BAD = [
    ("tcp/[::1", "closed by ']'"),
    ("tcp/[::1]", "end in a port"),
    ("tcp/[::1]7447", "end in a port"),
    ("tcp/::1:7447", "not an address"),
    ("tcp/127.0.0.1", "end in a port"),
    ("tcp/127.0.0.1:", "end in a port"),
    ("tcp/127.0.0.1:65536", "end in a port"),
    ("tcp/256.0.0.1:7447", "not an address"),
    ("tcp/1.2.3:7447", "not an address"),
    ("tcp/[nonsense]:7447", "not an address"),
    ("tcp/a b:7447", "<protocol>/<address>"),
    ("tcp/:7447", "not an address"),
    ("tpc/127.0.0.1:7447", "unknown protocol 'tpc'"),
    ("127.0.0.1:7447", "<protocol>/<address>"),
]


@pytest.mark.parametrize("endpoint", GOOD)
def test_a_well_formed_endpoint_is_kept(endpoint: str) -> None:
    assert check_endpoint(endpoint) == endpoint


@pytest.mark.parametrize(("endpoint", "reason"), BAD, ids=[e for e, _ in BAD])
def test_a_malformed_endpoint_is_refused_with_the_reason(endpoint: str, reason: str) -> None:
    with pytest.raises(ValueError, match=reason.replace("[", r"\[").replace("]", r"\]")):
        check_endpoint(endpoint)
