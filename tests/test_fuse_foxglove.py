"""``stereod fuse --foxglove``: the room live over the Foxglove WebSocket protocol, from a real
fusion process fed by a rig generator through a router on loopback; a protocol client as in
``test_foxglove`` reads the room's ``/tf_static`` and its tracks.

Truth: the room file's poses and the generator's closed-form walker."""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import websockets
from scipy.spatial.transform import Rotation

from stereod.fusion.room import load_room
from stereod_fakes.room_messages import Walker

from .fuse_procs import ROOM, fuse_procs, stop
from .test_foxglove import SUBPROTOCOLS, Client, stamp_ns, xyz

pytestmark = pytest.mark.slow

WALKER = {"id": 1, "start_m": [0.6, 0.0, 3.0], "velocity_mps": [0.0, 0.0, 0.3]}
"""In rig a's view (and c's)."""
ROOM_TOPICS = {"/tf_static", "/stereod/lab/tracks/odom", "/stereod/lab/tracks/markers"}


def served_port(fuse: subprocess.Popen) -> int:
    """The port fuse's log says its Foxglove server listens on (the only one it names: the
    SDK server's own loopback port behind the front is not for users)."""
    assert fuse.stderr is not None
    deadline = time.monotonic() + 60  # a guard against a hang, not a measurement
    while time.monotonic() < deadline:
        line = fuse.stderr.readline()
        assert "Started server on" not in line, line
        got = re.search(r"foxglove: serving room lab at ws://127\.0\.0\.1:(\d+)", line)
        if got:
            return int(got.group(1))
        assert line or fuse.poll() is None, "fuse ended before serving"
    raise AssertionError("fuse never said where it serves Foxglove")


async def watch(port: int, enough: int) -> Client:
    """Subscribe to everything advertised; read until ``enough`` room odometry messages."""
    url = f"ws://127.0.0.1:{port}"
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        client = Client(ws)
        info = json.loads(await asyncio.wait_for(ws.recv(), 10))
        assert info["op"] == "serverInfo" and info["name"] == "stereod lab"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (
            set(client.messages) >= ROOM_TOPICS
            and len(client.messages["/stereod/lab/tracks/odom"]) >= enough
        ):
            with contextlib.suppress(TimeoutError):
                await client.receive(2)
    return client


def test_fuse_serves_the_room_to_foxglove_with_every_rig_in_tf(tmp_path: Path) -> None:
    """``/tf_static`` places each rig of the room file at its translation, turned by its
    rotation; the room's odometry is at the walker's true place, in the room frame."""
    room = tmp_path / "room.toml"
    room.write_text(ROOM)
    with fuse_procs() as run:
        fuse = run.start_fuse(room, "--foxglove", "--foxglove-port", "0")
        port = served_port(fuse)
        gen = run.generator(room, "a", json.dumps([WALKER]), 5)
        t0 = run.go([gen])
        client = asyncio.run(watch(port, 20))
        stop(gen)
    assert set(client.messages) >= ROOM_TOPICS, set(client.messages)
    (_, tf), *_ = client.decoded("/tf_static")
    placed = {t.child_frame_id: t for t in tf.transforms}
    for rig in load_room(room).rigs:
        t = placed[f"stereod_{rig.name}"]
        assert t.header.frame_id == "stereod_lab_optical"
        np.testing.assert_allclose(xyz(t.transform.translation), rig.translation_m, atol=1e-9)
        q = t.transform.rotation
        body_in_room = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        # the rig's body X (its optical Z, forward) is R's third column in the room
        np.testing.assert_allclose(body_in_room[:, 0], rig.rotation()[:, 2], atol=1e-9)
    walker = Walker(1, tuple(WALKER["start_m"]), tuple(WALKER["velocity_mps"]), t0)  # type: ignore[arg-type]
    odom = client.decoded("/stereod/lab/tracks/odom")
    assert len(odom) >= 20
    assert {o.header.frame_id for _, o in odom} == {"stereod_lab_optical"}
    err = np.array(
        [xyz(o.pose.pose.position) - walker.position(stamp_ns(o.header)) for _, o in odom]
    )
    # across rig a's view (X) the generator's noise is 1 cm; along it (Z) 18 cm at 3 m
    assert np.abs(err[:, 0]).max() < 0.05 and abs(float(np.median(err[:, 2]))) < 0.1, err
