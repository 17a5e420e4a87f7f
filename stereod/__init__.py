"""stereod: stereo motion daemon for a Minoru-style USB stereo webcam.

Frames from two eyes are paired by capture timestamp, moving objects are found by background
subtraction, triangulated to 3D in the rig frame, tracked over time and published over Zenoh.

Two ways to use it from Python: :class:`Pipeline` on frames you already have (no daemon, no
bus, no camera), and :mod:`stereod.client` for what a running daemon publishes.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stereod.pipeline import PairResult, Pipeline, PipelineParams, Timings
    from stereod.sources.frames import Eye, Frame, StereoPair
    from stereod.tracking.types import TrackLifecycle, TrackState
    from stereod.vision.geometry import Geometry
    from stereod.vision.geometry.rectified import CalibratedRig
    from stereod.vision.geometry.stereo import CanonicalRig

__version__ = "0.2.0"

_HOMES = {
    "Eye": ".sources.frames",
    "Frame": ".sources.frames",
    "StereoPair": ".sources.frames",
    "Geometry": ".vision.geometry",
    "CalibratedRig": ".vision.geometry.rectified",
    "CanonicalRig": ".vision.geometry.stereo",
    "PairResult": ".pipeline",
    "Pipeline": ".pipeline",
    "PipelineParams": ".pipeline",
    "Timings": ".pipeline",
    "TrackLifecycle": ".tracking.types",
    "TrackState": ".tracking.types",
}
"""Where each name of the public surface lives. They are imported on first use, so that
``import stereod`` (which every command does first) costs nothing until NumPy and OpenCV are
needed: the ``stereod`` command can then answer Ctrl-C and SIGHUP from its first instant."""


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'stereod' has no attribute {name!r}")
    value = getattr(importlib.import_module(home, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_HOMES})


__all__ = [
    "CalibratedRig",
    "CanonicalRig",
    "Eye",
    "Frame",
    "Geometry",
    "PairResult",
    "Pipeline",
    "PipelineParams",
    "StereoPair",
    "Timings",
    "TrackLifecycle",
    "TrackState",
    "__version__",
]
