"""What a SIGHUP reload may change while the daemon runs, and what waits for a restart.

The driver, Zenoh, the daemon's threads and queues, ROS 2, the rig's name and the pairer are
built once per run; everything else (the rig's geometry, the detector, the tracker) is handed
to the pipeline thread, which swaps it in between two pairs.
"""

from __future__ import annotations

from stereod.daemon.config import StereodConfig

RELOAD_REFUSED = "reload refused, keeping the running configuration"
"""How a refused reload's problem begins; a reload taken later takes those off the status."""
RELOAD_WAITING = "reload: changes to"
"""How a reload's notice of changes that wait for a restart begins."""


def effective(running: StereodConfig, new: StereodConfig) -> StereodConfig:
    """What of a reloaded configuration ``new`` runs now: all of it but what only a restart
    can change, which stays as ``running`` has it. The config queryable reports this."""
    return new.model_copy(
        update={
            "driver": running.driver,
            "zenoh": running.zenoh,
            "daemon": running.daemon,
            "ros2": running.ros2,
            "rig": new.rig.model_copy(update={"name": running.rig.name}),
            "pairing": new.pairing.model_copy(
                update={
                    "tolerance_ms": running.pairing.tolerance_ms,
                    "max_pending": running.pairing.max_pending,
                }
            ),
        }
    )


def waiting(running: StereodConfig, new: StereodConfig) -> list[str]:
    """The settings ``new`` changes that take effect only at the next restart."""
    return [
        name
        for name, now, then in (
            ("driver", new.driver, running.driver),
            ("zenoh", new.zenoh, running.zenoh),
            ("daemon", new.daemon, running.daemon),
            ("ros2", new.ros2, running.ros2),
            ("rig.name", new.rig.name, running.rig.name),
            ("pairing.tolerance_ms", new.pairing.tolerance_ms, running.pairing.tolerance_ms),
            ("pairing.max_pending", new.pairing.max_pending, running.pairing.max_pending),
        )
        if now != then
    ]
