"""``stereod fuse`` reads its room file again on SIGHUP: a real fusion process and a rig message
generator through a router on loopback.

Truth: the generator places its walker in rig b's frame by the room file it was given, in which
b stands 1 m further along X than in the file the fusion node starts with. Until the node reads
the new file the walker is 1 m off its true place in the room; after, it is at it. A bad file
then is refused on the status (key and ``stats``) and in the log, and the room runs on.
"""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh
from rosbags.highlevel import AnyReader

from stereod.bus.messages import ObjectsMessage
from stereod.cli.fuse import RELOAD_REFUSED
from stereod.fusion.status import FuseStatus
from stereod_fakes.room_messages import Walker

from .conftest import zenoh_config
from .fuse_procs import ROOM, fuse_procs, stop
from .test_fuse_mcap import TYPESTORE

pytestmark = pytest.mark.slow

MOVED = ROOM.replace("translation_m = [4.0, 0.0, 10.0]", "translation_m = [5.0, 0.0, 10.0]")
"""Rig b 1 m further along the room's X (looking along -Z from z = 10 m, as before)."""
WALKER = {"id": 1, "start_m": [4.5, 0.0, 6.0], "velocity_mps": [0.0, 0.0, 0.05]}
"""Seen by b only (behind c, outside a's 60 deg), in either of b's poses."""
NEAR_M = 0.15
"""A room track this close to the walker along X (across b's view: b's depth, along Z, is
the noisy axis) is at its place, m."""


def wait_for(what: Callable[[], bool], why: str, timeout_s: float = 60.0) -> None:
    """Poll ``what`` until true; fail naming ``why`` after ``timeout_s`` (a guard against a
    hang, not a measurement)."""
    deadline = time.monotonic() + timeout_s
    while not what():
        assert time.monotonic() < deadline, why
        time.sleep(0.1)


def test_sighup_reads_the_room_file_again_and_a_bad_one_is_refused(tmp_path: Path) -> None:
    room, moved = tmp_path / "room.toml", tmp_path / "moved.toml"
    room.write_text(ROOM)
    moved.write_text(MOVED)
    messages: list[ObjectsMessage] = []
    statuses: list[FuseStatus] = []
    mcap = tmp_path / "room.mcap"
    with fuse_procs() as run:
        fuse = run.start_fuse(room, "--mcap", str(mcap))
        with zenoh.open(zenoh_config(connect=[run.endpoint], mode="client")) as session:

            def query(name: str) -> bytes | None:
                for r in session.get(f"stereod/rooms/lab/{name}", timeout=5):
                    if r.ok is not None:
                        return r.ok.payload.to_bytes()
                return None

            def rig_b_x() -> float | None:
                got = query("calibration")
                return None if got is None else json.loads(got)["rigs"]["b"]["translation_m"][0]

            session.declare_subscriber(
                "stereod/rooms/lab/objects",
                lambda s: messages.append(ObjectsMessage.model_validate_json(s.payload.to_bytes())),
            )
            session.declare_subscriber(
                "stereod/rooms/lab/status",
                lambda s: statuses.append(FuseStatus.model_validate_json(s.payload.to_bytes())),
            )
            wait_for(lambda: rig_b_x() == 4.0, "the fusion node never answered")
            gen = run.generator(moved, "b", json.dumps([WALKER]), 3)
            t0 = run.go([gen])
            walker = Walker(1, tuple(WALKER["start_m"]), tuple(WALKER["velocity_mps"]), t0)  # type: ignore[arg-type]

            def errors(since: int) -> list[float]:
                """Each room object's offset from the walker along X, in the messages after
                ``since`` (m)."""
                return [
                    o.position_m[0] - float(walker.position(o.stamp_utc_ns)[0])
                    for m in list(messages)[since:]
                    for o in m.objects
                ]

            wait_for(lambda: len(errors(0)) >= 10, "no room track from rig b")
            before = errors(0)
            assert all(abs(e + 1.0) < NEAR_M for e in before), before

            room.write_text(MOVED)
            fuse.send_signal(signal.SIGHUP)
            wait_for(lambda: rig_b_x() == 5.0, "the moved pose was not taken")
            # The track made in the old pose coasts out (2 s); one at the true place stays.
            wait_for(
                lambda: len(e := errors(len(messages) - 1)) == 1 and abs(e[0]) < NEAR_M,
                "the walker never came to its true place alone after the reload",
            )
            assert fuse.poll() is None

            room.write_text(ROOM.replace('name = "c"', 'name = "a"'))
            fuse.send_signal(signal.SIGHUP)

            def refused() -> bool:
                got = query("stats")
                return got is not None and any(
                    p.startswith(RELOAD_REFUSED)
                    for p in FuseStatus.model_validate_json(got).problems
                )

            wait_for(refused, "the bad room file was not reported on the stats queryable")
            wait_for(
                lambda: any(
                    p.startswith(RELOAD_REFUSED) and "rig 'a' is listed twice" in p
                    and str(room) in p
                    for st in list(statuses) for p in st.problems
                ),
                "the bad room file was not reported on the status key",
            )  # fmt: skip
            assert rig_b_x() == 5.0  # the room loaded before runs on
            n = len(messages)
            wait_for(lambda: len(errors(n)) >= 5, "fusion stopped after the refused reload")
            assert all(abs(e) < NEAR_M for e in errors(n)), errors(n)
            assert fuse.poll() is None
            stop(gen)
            fuse.send_signal(signal.SIGTERM)
            _, err = fuse.communicate(timeout=30)
            assert fuse.returncode == 0, err
    assert "room file reloaded: 3 rigs, moved or gone: b" in err, err
    (line,) = [ln for ln in err.splitlines() if RELOAD_REFUSED in ln]
    assert "rig 'a' is listed twice" in line and str(room) in line
    # The MCAP's /tf_static (latched: its last message is the tree) follows the reload: rig b
    # where the moved file puts it, 1 m further along X than at the start.
    with AnyReader([mcap]) as reader:
        statics = [
            TYPESTORE.deserialize_cdr(raw, c.msgtype)
            for c, _, raw in reader.messages()
            if c.topic == "/tf_static"
        ]
    b_x = [
        t.transform.translation.x
        for st in statics
        for t in st.transforms
        if t.child_frame_id == "stereod_b"
    ]
    assert b_x[0] == 4.0 and b_x[-1] == 5.0, b_x
