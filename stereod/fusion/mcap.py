"""The room's tracks as ROS 2 messages in an MCAP file (``stereod fuse --mcap``).

The messages are those of a rig's run (:mod:`stereod.ros.mapping`) with the room's name as the
rig's: Odometry, speed/heading, markers and the JSON on ``/stereod/<room>/...``, every position
in the room frame ``stereod_<room>_optical`` (the room file's frame: X right, Y down, Z forward
of its reference). ``/tf_static`` places every rig of the room file in it::

    stereod_<room>  ->  stereod_<room>_optical           (body to optical, REP 103)
    stereod_<room>_optical  ->  stereod_<rig>             (the rig's pose: R, t of the room file,
                                                           with the rig's body rotation)
    stereod_<rig>  ->  stereod_<rig>_optical              (body to optical, as the rig's own file)

so ``stereod_<rig>_optical`` sits at ``t`` turned by ``R`` in the room frame (a rig point p is
R p + t in the room), and a rig's own MCAP (with its cameras under ``stereod_<rig>_optical``)
opens beside the room's in one tree.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from stereod.fusion.room import Room
from stereod.ros.mapping import RosMessage, RosMessages
from stereod.ros.mcap_writer import McapRunWriter
from stereod.ros.names import BODY_TO_OPTICAL, T_TF, RosNames, header, matrix_quaternion, quat, vec

OPTICAL_IN_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""The optical frame's axes as columns in body coordinates (p_body = M p_optical)."""


class RoomRosMessages(RosMessages):
    """:class:`RosMessages` of a room: its ``/tf_static`` is the room's tree of rig frames."""

    def __init__(self, room: Room) -> None:
        # A baseline is what RosMessages needs to have a tf at all; the room's own replaces it.
        super().__init__(room.name, baseline_m=1.0)
        self.room = room

    def tf_static(self, stamp_ns: int) -> RosMessage | None:
        """``/tf_static``: the room's body and optical frames, each rig's body and optical
        frame placed by its pose in the room file."""
        room_names = self.names

        def tf(parent: str, child: str, xyz: Iterable[float], q: Iterable[float]) -> dict[str, Any]:
            return {
                "header": header(stamp_ns, parent),
                "child_frame_id": child,
                "transform": {"translation": vec(xyz), "rotation": quat(q)},
            }

        transforms = [
            tf(room_names.body_frame, room_names.optical_frame, (0.0, 0.0, 0.0), BODY_TO_OPTICAL)
        ]
        for rig in self.room.rigs:
            names = RosNames.for_rig(rig.name)
            body_in_room = rig.rotation() @ OPTICAL_IN_BODY.T
            transforms.append(
                tf(
                    room_names.optical_frame,
                    names.body_frame,
                    rig.translation().tolist(),
                    matrix_quaternion(body_in_room),
                )
            )
            transforms.append(
                tf(names.body_frame, names.optical_frame, (0.0, 0.0, 0.0), BODY_TO_OPTICAL)
            )
        return RosMessage(room_names.tf_static_topic, T_TF, {"transforms": transforms}, stamp_ns)


class RoomMcapWriter(McapRunWriter):
    """An MCAP file of a room's objects messages (:meth:`write_objects`, one per fusion step),
    written by the output file rule: renamed into place by :meth:`close`, removed by
    :meth:`abort`."""

    def __init__(self, out: Path, room: Room) -> None:
        super().__init__(out, rig=room.name, baseline_m=1.0)
        self.room_ros = RoomRosMessages(room)
        self.ros = self.room_ros
        self.names = self.ros.names

    def set_room(self, room: Room) -> None:
        """A room file read again: ``/tf_static`` is written anew, with the rigs' new poses,
        before the next objects (a latched topic: its latest message is the tree)."""
        with self._lock:
            self.room_ros.room = room
            self._static_done = False
