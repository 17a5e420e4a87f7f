"""Stereo geometry: matching blobs between the eyes and triangulating them in the rig frame."""

from __future__ import annotations

import enum


class Geometry(str, enum.Enum):
    """Which camera model positions are triangulated with (every message says which)."""

    CANONICAL = "canonical"
    """Two identical parallel pinhole cameras (eq. 9), from a baseline and a field of view."""
    CALIBRATED = "calibrated"
    """The rectified geometry of a calibration file (eq. 13-20)."""
