"""The replies of the daemon's ``config`` and ``calibration`` queryables, with secrets and
private paths left out (:mod:`stereod.daemon.redact`)."""

from __future__ import annotations

import json

from stereod.bus.messages import CanonicalGeometry, dump
from stereod.daemon.config import StereodConfig
from stereod.daemon.redact import public_config, public_text
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.stereo import CanonicalRig


def config_reply(cfg: StereodConfig) -> bytes:
    """The configuration in force, as JSON."""
    return json.dumps(public_config(cfg)).encode()


def calibration_reply(rig: CanonicalRig | CalibratedRig) -> bytes:
    """The geometry in force: a calibrated rig's calibration file, or the canonical rig's
    baseline (m), field of view (deg), size and intrinsics (px)."""
    if isinstance(rig, CalibratedRig):
        cal = rig.calibration
        return cal.model_copy(update={"source": public_text(cal.source)}).model_dump_json().encode()
    return dump(
        CanonicalGeometry(
            baseline_m=rig.baseline_m,
            hfov_deg=rig.hfov_deg,
            width_px=rig.width_px,
            height_px=rig.height_px,
            focal_px=rig.focal_px,
            cx_px=rig.cx_px,
            cy_px=rig.cy_px,
        )
    )
