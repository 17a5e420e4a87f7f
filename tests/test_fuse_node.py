"""The fusion node's order of work: a due room message never goes out ahead of a waiting rig
message's tracks, and never waits more than a second period; and its status counts every rig
message's added latency."""

from __future__ import annotations

import itertools
import time

import pytest

from stereod.daemon.config import ZenohConfig
from stereod.fusion.clock import ClockWatch
from stereod.fusion.fuser import Fuser
from stereod.fusion.histogram import EDGES_MS, difference, quantile_ms
from stereod.fusion.node import FuseNode, RoomPublisher
from stereod.fusion.room import RigPose, Room


def _node(max_rate_hz: float) -> FuseNode:
    """A node of a two-rig room (its publisher not opened: nothing here publishes)."""
    room = Room(name="lab", rigs=[RigPose(name="a"), RigPose(name="b")])
    publisher = RoomPublisher(ZenohConfig(), room.name, {})
    clock = ClockWatch([r.name for r in room.rigs])
    return FuseNode(room, Fuser(room), clock, publisher, None, "stereod", max_rate_hz=max_rate_hz)


def test_a_due_room_message_waits_for_a_waiting_rig_message_for_one_period_at_most() -> None:
    """At 20 Hz (a 50 ms period): before 50 ms the room's message is not due; from 50 ms it
    goes out at once with nothing waiting, but not while a rig message waits, until 100 ms
    have passed."""
    node = _node(20.0)
    assert not node._room_turn(0.049)
    assert node._room_turn(0.05) and node._room_turn(0.3)
    node.inbox.append((0.0, "stereod/rigs/a/objects", b"{}"))
    assert not node._room_turn(0.049)
    assert not node._room_turn(0.05) and not node._room_turn(0.099)
    assert node._room_turn(0.1) and node._room_turn(0.3)


def test_every_rig_message_s_added_latency_is_counted_in_the_status_histogram() -> None:
    """Two rig messages that arrived 30 and 150 ms before their step land in the bins just
    above those latencies (a step takes a fraction of a millisecond, not the 10 and 50 ms that
    would carry them on to the next edges), and two readings' difference holds exactly the
    messages between them."""
    node = _node(20.0)
    before = node.status().added_ms_counts
    now = time.monotonic()
    node._step(1_000_000_000, [], [now - 0.030, now - 0.150])
    status = node.status()
    assert status.added_ms_edges == list(EDGES_MS)
    between = difference(status.added_ms_counts, before)
    assert sum(between) == 2
    assert between[EDGES_MS.index(40.0)] == 1 and between[EDGES_MS.index(200.0)] == 1
    assert quantile_ms(between, 0.5) <= 40.0 < quantile_ms(between, 0.99) <= 200.0


def test_a_rig_silent_past_the_rig_timeout_is_not_live_though_no_stamp_moves_on() -> None:
    """Both rigs of a room fall silent: no newer stamp comes to make them stale, yet each is
    not live once its last message is older than the rig timeout by the node's clock, and the
    status says which and for how long (they stayed live for ever)."""
    from stereod.bus.messages import dump_objects
    from stereod.fusion.wire import decode
    from stereod_fakes.room_messages import RigSim, Walker

    node = _node(20.0)
    t0 = time.time_ns()
    walker = [Walker(1, (0.3, 0.0, 3.0), (0.2, 0.0, 0.0), t0)]
    now = time.monotonic()
    for name, age_s in (("a", 0.0), ("b", 5.0)):
        payload, _ = dump_objects(RigSim(RigPose(name=name), seed=1).message(walker, t0))
        node.fuser.ingest_wire(decode(payload))
        node._count([(now - age_s, f"stereod/{name}/objects", payload)])
    status = node.status()
    assert status.rigs["a"].live and not status.rigs["b"].live
    (said,) = [p for p in status.problems if "no message for" in p]
    assert said.startswith("rig b: no message for 5.0 s") and "1 s" in said


def test_a_rig_heard_whose_stamps_lie_behind_the_rig_timeout_is_said() -> None:
    """Rig b's messages come, but its host's clock is 2 s behind: its tracks are left out of
    the room (not live), and the status says why and what to check (it said nothing: b
    showed as not live with no problem)."""
    from stereod.bus.messages import dump_objects
    from stereod.fusion.wire import decode
    from stereod_fakes.room_messages import RigSim, Walker

    node = _node(20.0)
    t0 = time.time_ns()
    now = time.monotonic()
    for name, behind_s in (("a", 0.0), ("b", 2.0)):
        t = t0 - int(behind_s * 1e9)
        walker = [Walker(1, (0.3, 0.0, 3.0), (0.2, 0.0, 0.0), t)]
        payload, _ = dump_objects(RigSim(RigPose(name=name), seed=1).message(walker, t))
        node.fuser.ingest_wire(decode(payload))
        node._count([(now, f"stereod/{name}/objects", payload)])
    status = node.status()
    assert status.rigs["a"].live and not status.rigs["b"].live
    (said,) = [p for p in status.problems if "behind" in p]
    assert said.startswith("rig b: its stamps are 2.0 s behind rig a's, past the rig timeout")
    assert "check both hosts' clocks" in said


def _room_stamps(late_s: float, behind_s: float) -> tuple[dict[int, list[int]], list[int]]:
    """Rig a's and rig b's messages of one walker, 15 Hz, one a step, each of b's after a's
    of ``late_s`` later (its instant that much before a's newest), b's clock ``behind_s``
    behind: every room track's published stamps (by id), and a's message stamps."""
    import json

    from stereod.bus.messages import dump_objects
    from stereod_fakes.room_messages import RigSim, Walker

    node = _node(20.0)
    published: dict[int, list[int]] = {}

    def tracks(touched: list[tuple[int, bytes]], ended: list[int]) -> None:
        for rid, body in touched:
            published.setdefault(rid, []).append(json.loads(body)["t_ns"])

    node.pub.tracks = tracks  # type: ignore[method-assign]
    t0 = time.time_ns()
    behind = int(behind_s * 1e9)
    walkers = {  # b's clock reads true time minus ``behind``: its walker starts earlier
        "a": [Walker(1, (0.3, 0.0, 3.0), (0.2, 0.0, 0.0), t0)],
        "b": [Walker(1, (0.3, 0.0, 3.0), (0.2, 0.0, 0.0), t0 - behind)],
    }
    sims = {n: RigSim(RigPose(name=n), seed=1) for n in ("a", "b")}
    stamps_a = []
    for k in range(30):
        t = t0 + k * 66_666_667
        stamps_a.append(t)
        for name, at in (("a", t), ("b", t - int(late_s * 1e9) - behind)):
            payload, _ = dump_objects(sims[name].message(walkers[name], at))
            node._handle([(time.monotonic(), f"stereod/{name}/objects", payload)], None)
    return published, stamps_a


def test_a_rig_message_that_comes_late_never_sends_a_room_track_back_in_time() -> None:
    """Rig b's message of an instant 33 ms before rig a's newest came after it: the room
    tracks it touched went out stamped 33 ms back, then forward again, 30 times in 2 s (a
    walker stepping back and forth). A step is now at the room's newest instant, b's tracks
    predicted on to it."""
    published, _ = _room_stamps(0.033, 0.0)
    assert published
    for stamps in published.values():
        assert all(b >= a for a, b in itertools.pairwise(stamps)), stamps


def test_a_rig_left_out_for_its_clock_does_not_restamp_the_room() -> None:
    """Rig b's clock 3 s behind: the status said its tracks were left out of the room, yet
    each of its messages re-stamped the room's tracks with its own time, 3 s back (122
    times in 10 s). The room's tracks now keep rig a's instants."""
    published, stamps_a = _room_stamps(0.0, 3.0)
    assert published
    for stamps in published.values():
        assert all(b >= a for a, b in itertools.pairwise(stamps)), stamps
        assert set(stamps) <= set(stamps_a)


def test_what_is_not_a_rig_s_objects_on_its_key_is_refused_naming_the_rig() -> None:
    """Garbage on rig b's key was counted as one of b's messages (b showed live on garbage
    alone) and the status named no rig; a message of rig a's sent on b's key (a copied
    config) was fused as a's. Both are now refused, named by the key's rig, and not counted
    as b's messages."""
    from stereod.bus.messages import dump_objects
    from stereod_fakes.room_messages import RigSim, Walker

    node = _node(20.0)
    node.pub.tracks = lambda touched, ended: None  # type: ignore[method-assign]
    t0 = time.time_ns()
    walker = [Walker(1, (0.3, 0.0, 3.0), (0.2, 0.0, 0.0), t0)]
    own, _ = dump_objects(RigSim(RigPose(name="a"), seed=1).message(walker, t0))
    now = time.monotonic()
    node._handle([(now, "stereod/b/objects", b"[1, 2, 3]")], None)
    status = node.status()
    assert status.rigs["b"].messages == 0 and not status.rigs["b"].live
    (said,) = [p for p in status.problems if "not its objects" in p]
    assert said.startswith("samples on a rig's objects key that were not its objects: 1")
    assert "(the last: rig b: " in said
    node._handle([(now, "stereod/b/objects", own)], None)
    status = node.status()
    assert status.rigs["b"].messages == 0 and node.fuser.rig_stamp("a") is None
    (said,) = [p for p in status.problems if "not its objects" in p]
    assert said.endswith("2 (the last: rig b: a message of rig 'a' on its key)")
    node._handle([(now, "stereod/a/objects", own)], None)
    assert node.status().rigs["a"].messages == 1 and node.fuser.rig_stamp("a") == t0


def test_a_reload_that_adds_a_rig_says_so(caplog: pytest.LogCaptureFixture) -> None:
    """A room file read again with rig c added logged "3 rigs, no rig moved", naming no new
    rig; it now names it."""
    import logging

    node = _node(20.0)
    node.pending_room = Room(name="lab", rigs=[RigPose(name=n) for n in ("a", "b", "c")])
    with caplog.at_level(logging.INFO, logger="stereod.fuse"):
        node._take_room()
    assert "room file reloaded: 3 rigs, added: c; no rig moved" in caplog.text
    assert node.fuser.knows("c") and "c" in node.received
