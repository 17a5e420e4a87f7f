"""Several rigs, one room: rig tracks moved into a shared room frame, associated across rigs
and fused by their covariances (issue 38). Nothing here imports the daemon, and only
:mod:`.foxglove` (a bridge on the caller's session) touches Zenoh: the ``stereod fuse`` command
(:mod:`stereod.cli.fuse`) feeds it messages and publishes its output.

Modules by job: :mod:`.room` (the room file and each rig's pose), :mod:`.wire` (a rig's
message as one array per field), :mod:`.frames` (a rig's tracks moved into the room frame and
predicted to an instant), :mod:`.fuser` (association across rigs, the information-form fusion
and the room's ids), :mod:`.clock` (each rig's clock offset from shared observations, and the
correction of its stamps), :mod:`.output` (room tracks as an objects message), :mod:`.status`
(the fusion node's status message), :mod:`.mcap` (room tracks and every rig's frame as ROS 2
messages in MCAP), :mod:`.foxglove` (the same live to the Foxglove app) and
:mod:`.discipline` (how a host's clock is kept on UTC, for a daemon's status).
"""
