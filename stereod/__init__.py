"""stereod: stereo motion daemon for a Minoru-style USB stereo webcam.

Frames from two eyes are paired by capture timestamp, moving objects are found by background
subtraction, triangulated to 3D in the rig frame, tracked over time and published over Zenoh.

Two ways to use it from Python: :class:`Pipeline` on frames you already have (no daemon, no
bus, no camera), and :mod:`stereod.client` for what a running daemon publishes.
"""

from .frames import Eye, Frame, StereoPair
from .geometry import Geometry
from .geometry.rectified import CalibratedRig
from .geometry.stereo import CanonicalRig
from .pipeline import PairResult, Pipeline, PipelineParams, Timings
from .tracking import TrackLifecycle, TrackState

__version__ = "0.2.0"

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
