"""The fusion node's order of work: a due room message never goes out ahead of a waiting rig
message's tracks, and never waits more than a second period."""

from __future__ import annotations

from stereod.daemon.config import ZenohConfig
from stereod.fusion.clock import ClockWatch
from stereod.fusion.fuser import Fuser
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
