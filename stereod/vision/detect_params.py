"""The detector's parameters (paper sec. II and what is added to it) and their choices: how the
luminance of eq. 2 and the centre of eq. 5 are taken, and how the first background is made."""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Centroid(str, enum.Enum):
    """How a blob's centre is computed."""

    BINARY = "binary"
    """Eq. 5 exactly: the mean position of the blob's foreground pixels."""
    COVERAGE = "coverage"
    """Eq. 5 over the filled support, edge pixels weighted by a ramp of eq. 4's difference."""
    MATTE = "matte"
    """Eq. 5 over the filled support, each edge pixel weighted by the share of it the object
    covers, solved from the pixel, the background behind it and the object's colour nearby."""


class Luminance(str, enum.Enum):
    """How a colour frame becomes the luminance matrix L of eq. 2 (when not using colour)."""

    BT601 = "bt601"
    """OpenCV's 0.299 R + 0.587 G + 0.114 B: what a YUYV camera's Y plane already is (free)."""
    MEAN = "mean"
    """The paper's exact eq. 2, (R + G + B) / 3."""


class Warmup(str, enum.Enum):
    """How the initial background is made from the first frames."""

    MEDIAN = "median"
    """Per-pixel median: what passes by during the warm-up leaves nothing behind."""
    MEAN = "mean"
    """Running mean: the average of the frames."""


MAX_WARMUP_FRAMES = 1000
"""Most frames the initial background may be made of (the warm-up keeps them all in memory:
1000 BGR frames at 640x480 are 0.9 GB)."""


@dataclass(frozen=True, slots=True)
class DetectorParams:
    """Parameters of sec. II and of what is added to it (:mod:`stereod.vision.detect`).

    ``beta``: background update coefficient of eq. 3, 0 <= beta << 1 (per frame).
    ``threshold``: t of eq. 4 in 8-bit grey levels (the paper's [0, 1] scale times 255).
    ``min_area_px``: smallest object kept (px); smaller ones are noise.
    ``warmup_frames``: frames that make the initial background before detecting.
    ``open_px``, ``close_px``: sides of the opening and closing kernels (px), 0 or 1 to skip.
    ``luminance``: eq. 2 exactly or the camera's luma; ``centroid``: eq. 5 exactly or with
    the edge pixels weighted (by the share the object covers, or by a ramp).
    ``color``: difference colour frames channel by channel instead of by luminance.
    ``hold_foreground``: do not learn foreground pixels (grown by ``hold_margin_px``) until
    they have stayed foreground ``absorb_s`` seconds.
    ``fill_holes``: an object's support is its filled outline, not only its foreground pixels
    (and a pinhole is foreground before the opening);
    ``convex``: and that outline is the convex hull of the blob (a part of a robot or a ball
    as bright and coloured as the floor behind it leaves a notch, not a hole).
    ``merge_gap``: pieces closer than this share of the smaller one's size are one object.
    ``max_foreground``, ``max_blobs``: beyond these a frame is saturated.
    ``gain``: follow a global change of brightness (lighting drift, auto-exposure) at once.
    ``hysteresis``, ``grow_px``: pixels whose difference reaches ``hysteresis`` times ``t``
    join the foreground within ``grow_px`` of it (three steps), so the part of an object
    nearly the colour of the wall behind it is kept; 0 turns this off.
    ``learn_stride``: eq. 3 updates every ``learn_stride``-th row each frame, in turn (1: all).
    ``disc_max_px``: a round blob (:func:`stereod.vision.disc.is_round`) at most this wide and high
    (px) is centred by fitting a disc to the image (:func:`stereod.vision.disc.disc_centres`) when
    matting; 0 turns this off.
    ``shadows``: foreground that is the background darkened (its brightness times a factor
    within ``shadow_ratio``, its colour's proportions and its texture kept) is a cast shadow,
    not the object (:func:`stereod.vision.shadows.shadow_mask`), and is left out before the
    centre is taken.
    ``near_objects``: a foreground over ``max_foreground`` is an object close to the camera
    unless the photometric model explains it or it covers the image edge to edge
    (:func:`stereod.vision.shadows.scene_changed`); off, any such frame is saturated.
    """

    beta: float = 0.02
    threshold: float = 25.0
    min_area_px: int = 12
    warmup_frames: int = 10
    warmup: Warmup = Warmup.MEDIAN
    open_px: int = 3
    close_px: int = 5
    luminance: Luminance = Luminance.BT601
    centroid: Centroid = Centroid.MATTE
    color: bool = True
    hold_foreground: bool = True
    hold_margin_px: int = 2
    absorb_s: float = 5.0
    fill_holes: bool = True
    convex: bool = True
    merge_gap: float = 0.3
    max_foreground: float = 0.5
    max_blobs: int = 200
    gain: bool = True
    hysteresis: float = 0.65
    grow_px: int = 4
    learn_stride: int = 6
    disc_max_px: int = 24
    shadows: bool = True
    shadow_ratio: tuple[float, float] = (0.15, 0.92)
    near_objects: bool = True


PAPER = DetectorParams(
    warmup=Warmup.MEAN,
    close_px=0,
    centroid=Centroid.BINARY,
    color=False,
    hold_foreground=False,
    shadows=False,
    near_objects=False,
    fill_holes=False,
    convex=False,
    merge_gap=0.0,
    gain=False,
    hysteresis=0.0,
    learn_stride=1,
)
"""The paper's sec. II as written (eq. 2-5 with eq. 3 everywhere), plus only the opening."""
