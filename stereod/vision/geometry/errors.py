"""How far one object's two centroids may be off (px): where its blobs touch the image's edges,
how far off its optical axis it is seen, and the error models of the centroids across the rows
and of two eyes segmenting it differently, which widen its covariance (eq. 12)."""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from stereod.vision.blobs import Blobs
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.stereo import CanonicalRig


class Seen(Protocol):
    """What the error models read of a track's last observation
    (:class:`stereod.tracking.tracker.Observation`)."""

    @property
    def left_area_px(self) -> int: ...
    @property
    def right_area_px(self) -> int: ...
    @property
    def clipped(self) -> bool: ...
    @property
    def cut(self) -> bool: ...
    @property
    def row_gap_px(self) -> float | None: ...


def cos_off_axis(point_px: np.ndarray, centre_px: tuple[float, float], focal_px: float) -> float:
    """Cosine of the angle between an eye's optical axis and the ray through a point (px)."""
    dx, dy = float(point_px[0]) - centre_px[0], float(point_px[1]) - centre_px[1]
    return focal_px / math.sqrt(focal_px * focal_px + dx * dx + dy * dy)


def touches_side(bbox: np.ndarray, rig: CanonicalRig | CalibratedRig) -> bool:
    """Whether a blob's box (x, y, w, h px) reaches the image's left or right edge: part of
    the object may be cut off there, differently in each eye, so its disparity is off."""
    x, _, w, _ = (int(v) for v in bbox)
    return x <= 0 or x + w >= rig.width_px


def cut_rows(bbox: np.ndarray, rig: CanonicalRig | CalibratedRig) -> bool:
    """Whether a blob's box (x, y, w, h px) reaches the image's top or bottom edge: a person
    close to the camera, head or feet out of view. Both eyes lose the same rectified rows, so
    its disparity holds; only its height is unknown."""
    _, y, _, h = (int(v) for v in bbox)
    return y <= 0 or y + h >= rig.height_px


_SQRT_HALF = math.sqrt(0.5)


def row_error_px(gap: float, gap_before: float) -> float:
    """How far (px, one sigma, per centroid) the two eyes' centroids of one object may be
    off across the rows, from how far apart their rows are now and were at the track's last
    observation (``gap``, ``gap_before``: y_L - y_R in rectified px, each at one instant). A
    rectified pair sees a point on one row in both eyes, so a gap is the two segmentations
    disagreeing: one eye took in or lost a part of the object that the other did not (the
    colour of the background behind it in that eye only), which moves its centroid across as
    much as along, and the disparity (eq. 9) is then as likely off by as much as the rows
    are apart: each centroid's error is that over sqrt(2). What counts is the smaller of the
    gap and its change since the last observation: a gap that stays (a calibration's row
    error, or the skew interpolation's on an object whose image motion speeds up) is no
    segmentation's doing. A robot cylinder at 1.6 m, 640x480 and 42 deg (eq. 12: 5 cm of
    depth a px of disparity), has its rows 0.5 to 1 px apart on about one frame in eight,
    and its depth 1.5 to 3 cm off there (0.3 to 0.6 px of disparity)."""
    return min(abs(gap), abs(gap - gap_before)) * _SQRT_HALF


SEGMENTATION_SLACK = 0.03
"""How far (as a share) an object's two blob areas may differ, or their ratio change from
one observation to the next, before its centroids are trusted less: noise, the object's own
turning and the side of a box that one eye sees more of than the other change it by a few
percent."""


def segmentation_error_px(
    lb: Blobs,
    rb: Blobs,
    i: int,
    j: int,
    before: Seen,
    width_px: float,
    areas: tuple[float, float] | None = None,
    growth: tuple[float, float] | None = None,
    *,
    size_noise: float,
) -> float:
    """How far (px, one sigma) the centroids may have moved because the two eyes segmented
    the object differently. Where part of an object is the colour of what is behind it, each
    eye loses or regains that part on its own frame (each sees another patch of background),
    and the eye that lost a share ``s`` of the object's area has its centroid moved by up to
    ``s`` times half the object's width: the disparity, so the depth, is off for as long as
    the loss lasts. Two signs tell it apart: the two eyes' area changes since ``before``
    (logs) differ by ``s`` on the frame it happens, and the two areas themselves differ by
    ``s`` for every frame it lasts (the eyes of a canonical rig see the same outline to a
    few percent). An object coming closer or going away grows in both, and differently
    through the eyes' skew alone. With the track's filter running, ``growth`` gives what
    each eye's change should be (:func:`stereod.tracking.measure.expected_growth`), and the
    two changes count by how far their difference is from the expected one: a loss in one eye
    counts in full on its first frame, and a thrown ball's skewed growth not at all. Before
    that, what counts is the excess over the mean growth (by at most half a frame's growth apart
    through the skew); the mean holds half of a loss in one eye alone, so such a loss then
    counts from twice the slack (6 %), at half its size. The two areas apart count beyond
    the mean growth. Either counts beyond ``SEGMENTATION_SLACK`` and the areas' own noise,
    2 ``size_noise`` / sqrt(A) of the smallest of the four areas A (a difference of two log
    area ratios, each twice the half-log that :func:`stereod.tracking.skew.size_depth_ratio`
    bounds by ``size_noise`` / sqrt(A), :data:`stereod.tracking.skew.SIZE_NOISE`: a ball 5 px
    across wobbles by a fifth); the larger, times half the blob's width ``width_px``, is
    added to the centroid error of this observation, so the filter leans on its prediction
    across the loss instead of following it. The two areas are compared as ``areas`` (left,
    right) gives them, in rectified px where lens distortion scales the two eyes' images
    differently (the images' areas when None)."""
    area_l, area_r = max(int(lb.area_px[i]), 1), max(int(rb.area_px[j]), 1)
    then_l, then_r = max(before.left_area_px, 1), max(before.right_area_px, 1)
    left = math.log(area_l / then_l)
    right = math.log(area_r / then_r)
    grew = abs(left + right) / 2.0
    rect_l, rect_r = areas if areas is not None else (area_l, area_r)
    apart = abs(math.log(max(rect_l, 1.0) / max(rect_r, 1.0))) - grew
    if growth is None:
        changed = abs(left - right) - grew
    else:
        changed = abs((left - right) - (growth[0] - growth[1]))
    noise = 2.0 * size_noise / math.sqrt(min(area_l, area_r, then_l, then_r))
    return max(max(changed, apart) - SEGMENTATION_SLACK - noise, 0.0) * 0.5 * width_px
