"""``stereod fuse --foxglove``: the room live in the Foxglove app, through the bridge the rig
view uses (:class:`stereod.ros.foxglove.FoxgloveBridge`), with the topics and frames of
``fuse --mcap`` (:mod:`stereod.fusion.mcap`).

The room's keys are a rig's under ``<prefix>/rooms`` (its name as the rig's), so the bridge
subscribes to them as to a rig's: Odometry, markers, speed/heading and the JSON on
``/stereod/<room>/...`` in the room frame. What differs is the geometry: a room has no
cameras, and its ``/tf_static`` is the room's tree, every rig of the room file placed by its
pose (sent at start, to every client that subscribes to it, and again when the room file is
read again).
"""

from __future__ import annotations

import zenoh

from stereod.bus import keys
from stereod.errors import NotInstalledError
from stereod.fusion.mcap import RoomRosMessages
from stereod.fusion.room import Room
from stereod.ros.foxglove import FoxgloveBridge

DEFAULT_PORT = 8767
"""The room's Foxglove WebSocket port (the rig view's is 8766, so both can run on one host;
``stereod fuse --foxglove-port``'s default too)."""


class RoomFoxgloveBridge(FoxgloveBridge):
    """A :class:`FoxgloveBridge` for the room ``room`` published under ``<prefix>/rooms``."""

    serves = "room"

    def __init__(
        self,
        session: zenoh.Session,
        room: Room,
        *,
        prefix: str = keys.DEFAULT_PREFIX,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
    ) -> None:
        super().__init__(session, rig=room.name, prefix=f"{prefix}/rooms", host=host, port=port)
        self.room_ros = RoomRosMessages(room)
        self.ros = self.room_ros
        self.names = self.ros.names

    def start(self) -> RoomFoxgloveBridge:
        """Serve, and send the room's ``/tf_static`` (nothing to ask a daemon for)."""
        try:
            super().start()
        except NotInstalledError as exc:
            raise NotInstalledError(
                "stereod fuse --foxglove needs foxglove-sdk: pip install 'stereod[foxglove]'"
            ) from exc
        self._send_tf()
        return self

    def _ask_geometry(self) -> None:
        """The room's geometry is its room file's: send its tree again (the node's ``alive``
        token came back)."""
        self._send_tf()

    def set_room(self, room: Room) -> None:
        """The room file read again: its rigs' new poses in ``/tf_static`` from now on."""
        with self._lock:
            self.room_ros.room = room
        self._send_tf()
