"""A rig whose clock is 40 ms ahead, fused by a real ``stereod fuse`` through a router on
loopback: two generator processes stand for the rigs (``stereod_fakes.room_messages``, one of
them stamping with ``--clock-offset-ms 40``; a depth sigma of 0.5 cm per squared metre, as a
640x480 rig's), two walkers cross both views.

Truth: the generators' closed-form walkers and the offset they were given."""

from __future__ import annotations

import json
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

WALKERS = json.dumps(
    [
        {"id": 1, "start_m": [0.0, 0.0, 2.5], "velocity_mps": [0.55, 0.0, 0.44]},
        {"id": 2, "start_m": [-0.5, 0.0, 3.125], "velocity_mps": [0.55, 0.0, 0.44]},
    ]
)
"""Through rig a's and rig c's views (at right angles) for 4.5 s at 0.7 m/s."""
OFFSET_MS = 40.0


def test_a_rig_clock_40_ms_ahead_is_found_and_its_stamps_corrected(tmp_path: Path) -> None:
    """The fusion node finds rig c 40 ms ahead (within 8 ms), flags it and corrects c's
    stamps by it; the room's last second of the crossing is at the walkers' true places."""
    room = tmp_path / "room.toml"
    room.write_text(ROOM)
    messages: list[ObjectsMessage] = []
    with fuse_procs() as run:
        run.start_fuse(room)
        with zenoh.open(zenoh_config(connect=[run.endpoint], mode="client")) as session:
            session.declare_subscriber(
                "stereod/rooms/lab/objects",
                lambda s: messages.append(ObjectsMessage.model_validate_json(s.payload.to_bytes())),
            )
            clock = ("--depth-sigma-per-m2", "0.005", "--clock-offset-ms")
            gens = [
                run.generator(room, "a", WALKERS, 31, *clock, "0.0"),
                run.generator(room, "c", WALKERS, 32, *clock, str(OFFSET_MS)),
            ]
            t0 = run.go(gens)
            truth = [
                Walker(w.truth_id, w.start_m, w.velocity_mps, t0)
                for w in walkers_from_json(WALKERS)
            ]
            time.sleep(4.3)  # the crossing; the checks below are on what was published
            replies = list(session.get("stereod/rooms/lab/stats", timeout=10))
            status = FuseStatus.model_validate_json(replies[0].ok.payload.to_bytes())
            for g in gens:
                stop(g)
    c = status.rigs["c"]
    assert c.clock_correction_ms == pytest.approx(OFFSET_MS, abs=8.0), c
    assert c.clock_offset_ms is not None and c.clock_off, c
    assert status.rigs["a"].clock_correction_ms == 0.0
    assert any("rig c's clock is" in p for p in status.problems), status.problems
    end = max(m.stamp_utc_ns for m in messages)
    errors = [
        min(
            float(np.linalg.norm(np.array(o.position_m) - w.position(o.stamp_utc_ns)))
            for w in truth
        )
        for m in messages
        if m.stamp_utc_ns > end - 1_000_000_000
        for o in m.objects
    ]
    assert len(errors) > 20 and float(np.median(errors)) < 0.03, np.median(errors)
