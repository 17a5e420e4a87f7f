"""Rigs in network namespaces of their own: each rig's message generator runs under
``unshare -rn`` (a user and a network namespace of its own: only its own loopback), and reaches
the router through a Unix socket (``unixsock-stream``, a file both sides see); ``stereod
fuse`` and the test's subscriber use the router's TCP port on this host's loopback.

Truth: the namespaces (``/proc/<pid>/ns/net``, and the router's TCP port refused from inside
one) and the generators' closed-form walkers, as in ``test_fuse_cli``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from stereod.bus.messages import ObjectsMessage
from stereod.fusion.status import FuseStatus
from stereod_fakes.room_messages import Walker, walkers_from_json

from .conftest import zenoh_config
from .fuse_procs import ROOM, fuse_procs, stop

pytestmark = pytest.mark.slow

UNSHARE = ("unshare", "-rn")
WALKERS = json.dumps(
    [
        {"id": 1, "start_m": [0.6, 0.0, 3.0], "velocity_mps": [0.0, 0.0, 0.05]},
        {"id": 2, "start_m": [2.5, 0.0, 6.0], "velocity_mps": [1.0, 0.0, 0.0]},
    ]
)
"""Object 1 stands in rigs a and c's overlap; object 2 walks from a's view into b's."""
PROBE = """
import socket, sys
try:
    socket.create_connection(("127.0.0.1", int(sys.argv[1])), timeout=5).close()
except OSError:
    sys.exit(3)
"""
"""Exits 3 if the router's TCP port on 127.0.0.1 cannot be reached, 0 if it can."""


def _namespaces_allowed() -> str | None:
    """Why a process cannot have a network namespace of its own here, or None if it can."""
    try:
        res = subprocess.run([*UNSHARE, "true"], capture_output=True, text=True, timeout=30)
    except FileNotFoundError:
        return "unshare(1) is not installed"
    if res.returncode != 0:
        return f"unshare -rn is refused here (no unprivileged user namespaces): {res.stderr}"
    return None


def test_rigs_in_their_own_network_namespaces_fuse_through_the_router(tmp_path: Path) -> None:
    """Three generators, each in a network namespace of its own (distinct from each other's
    and this one's, where the router's TCP port cannot be reached), publish through the
    router's Unix socket; the room has exactly two ids, each at its own object's place, and
    every rig is live on the fusion node's status."""
    why = _namespaces_allowed()
    if why is not None:
        pytest.skip(why)
    room = tmp_path / "room.toml"
    room.write_text(ROOM)
    sock = f"unixsock-stream/{tmp_path / 'router.sock'}"
    messages: list[ObjectsMessage] = []
    with fuse_procs(sock) as run:
        port = run.endpoint.rsplit(":", 1)[1]
        # From a namespace of its own this host's loopback is not there: the TCP port is
        # unreachable (exit 3), where from here it answers.
        probe = subprocess.run(
            [*UNSHARE, sys.executable, "-c", PROBE, port],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert probe.returncode == 3, probe
        assert subprocess.run([sys.executable, "-c", PROBE, port], timeout=60).returncode == 0
        fuse = run.start_fuse(room)
        with zenoh.open(zenoh_config(connect=[run.endpoint], mode="client")) as session:
            session.declare_subscriber(
                "stereod/rooms/lab/objects",
                lambda s: messages.append(ObjectsMessage.model_validate_json(s.payload.to_bytes())),
            )
            gens = [
                run.generator(room, rig, WALKERS, seed, endpoint=sock, wrap=UNSHARE)
                for seed, rig in enumerate("abc")
            ]
            spaces = {os.readlink(f"/proc/{g.pid}/ns/net") for g in gens}
            assert len(spaces) == 3 and os.readlink("/proc/self/ns/net") not in spaces, spaces
            t0 = run.go(gens)
            deadline = time.monotonic() + 120  # a guard against a hang, not a measurement
            while time.monotonic() < deadline and not (
                messages and messages[-1].stamp_utc_ns > t0 + 2_500_000_000
            ):
                time.sleep(0.1)
            replies = list(session.get("stereod/rooms/lab/stats", timeout=10))
            status = FuseStatus.model_validate_json(replies[0].ok.payload.to_bytes())
            for g in gens:
                stop(g)
        fuse.send_signal(signal.SIGTERM)
        _, err = fuse.communicate(timeout=30)
    assert fuse.returncode == 0, err
    assert all(status.rigs[r].live and status.rigs[r].messages for r in "abc"), status.rigs
    truth = [Walker(w.truth_id, w.start_m, w.velocity_mps, t0) for w in walkers_from_json(WALKERS)]
    ids: dict[int, int] = {}
    for m in messages:
        for o in m.objects:
            d = [float(np.linalg.norm(np.array(o.position_m) - w.position(o.stamp_utc_ns)))
                 for w in truth]  # fmt: skip
            nearest = int(np.argmin(d))
            err = np.abs(np.array(o.position_m) - truth[nearest].position(o.stamp_utc_ns))
            assert np.all(err < 4 * np.array(o.position_sigma_m) + 0.02), (o, err)
            assert ids.setdefault(o.track_id, nearest) == nearest, "an id switched objects"
    assert sorted(ids.values()) == [0, 1], ids
