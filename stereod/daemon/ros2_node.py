"""The daemon's ROS 2 node (``[ros2] enabled``): made on the daemon's session with the
geometry in force, and given a reloaded geometry as the pipeline takes it."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from stereod.daemon.config import StereodConfig
from stereod.daemon.status import Health
from stereod.vision.calibration import Calibration, canonical
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.stereo import CanonicalRig

if TYPE_CHECKING:
    import zenoh

    from stereod.ros.ros2_live import Ros2Live

log = logging.getLogger(__name__)

Rig = CanonicalRig | CalibratedRig


def ros_calibration(rig: Rig) -> Calibration:
    """The calibration ROS 2 publishes for ``rig`` (camera_info, tf): a calibrated rig's own,
    or the canonical rig's (``vision.calibration.canonical``)."""
    if isinstance(rig, CalibratedRig):
        return rig.calibration
    return canonical(rig.baseline_m, rig.hfov_deg, rig.width_px, rig.height_px)


def make_node(
    cfg: StereodConfig, session: zenoh.Session, rig: Rig, health: Health
) -> Ros2Live | None:
    """The ROS 2 node of ``cfg``'s ``[ros2]`` on ``session``, or None when it is off."""
    r = cfg.ros2
    if not r.enabled:
        return None
    from stereod.ros.ros2_live import Ros2Live  # with its CDR encoders: only when [ros2] is on

    node = Ros2Live(
        session,
        cfg.rig.name,
        calibration=ros_calibration(rig),
        domain_id=r.domain_id,
        namespace=r.namespace,
        topics=r.topics,
        image_rate_hz=cfg.daemon.image_rate_hz,
        jpeg_quality=cfg.daemon.image_quality,
        health=health,
    )
    log.info("ros2: node %s, domain %d", node.node, r.domain_id)
    return node


def give_geometry(node: Ros2Live | None, rig: Rig, health: Health) -> None:
    """Give ``node`` (if any) the geometry of ``rig``; a failure is said, never raised (ROS
    output never stops the daemon)."""
    if node is None:
        return
    try:
        node.set_geometry(ros_calibration(rig))
    except Exception as exc:
        health.problem(f"ros2: the new geometry was not taken: {exc}", "ros2_error")
