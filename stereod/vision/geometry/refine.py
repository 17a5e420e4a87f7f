"""Disparity by matching the object's appearance between the eyes, not its two masks.

Each eye segments an object against a different patch of background (parallax), so where the
object is about as bright as what is behind it the two masks cover different parts of it, and
the difference of their centroids (eq. 5 in each eye) is a biased disparity: about a pixel,
which is a biased depth and, as the object moves, a wrong radial speed. Here the left eye's
view of the object (its rectified patch, masked by its support so the background behind it
does not count) is searched for along the same rectified rows of the right image, by zero-mean
normalised cross-correlation (OpenCV's masked ``TM_CCOEFF_NORMED``), and the peak is refined
to sub-pixel by a parabola through it and its neighbours. The right centroid becomes the left
centroid shifted by the match, so both eyes measure the same point of the object, whatever the
right mask covers. Only a window around each blob is searched, never whole frames.

The match compares the right image at its own capture instant with the left at its own, so
it measures the apparent displacement including any motion during the skew; skew compensation
(:mod:`stereod.tracking.skew`) then brings both to one instant as for centroids.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

Patch = Callable[[int, int, int, int], np.ndarray]
"""(x0, y0, x1, y1) in rectified px -> the (y1 - y0, x1 - x0) uint8 grey patch of one eye."""


@dataclass(frozen=True, slots=True)
class RefineParams:
    """``enabled``: refine the disparity by matching (False: eq. 5's centroids in each eye).
    ``margin_px``: the template is the blob's box grown by this (px). ``search_px``: how far
    (px) either way of the centroids' disparity to search, at least; ``search_rel`` of the
    blob's width if more. ``rows_px``: rows searched above and below. ``erode_px``: the
    template's mask is the support shrunk by this, so no background is in it.
    ``min_score``: a weaker peak (normalised correlation) keeps the centroids' disparity.
    """

    enabled: bool = False
    margin_px: int = 2
    search_px: float = 4.0
    search_rel: float = 0.3
    rows_px: int = 2
    erode_px: int = 1
    min_score: float = 0.6


def _parabola(a: float, b: float, c: float) -> float:
    """Offset in (-0.5, 0.5) of the vertex of the parabola through (-1, a), (0, b), (1, c)."""
    den = a - 2.0 * b + c
    if den >= 0.0:
        return 0.0
    return float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))


def refine_match(
    left: Patch,
    right: Patch,
    size: tuple[int, int],
    box: tuple[int, int, int, int],
    support: np.ndarray,
    left_px: np.ndarray,
    right_px: np.ndarray,
    params: RefineParams,
) -> tuple[np.ndarray, float]:
    """The right eye's centroid (2,) rectified px that matches ``left_px`` by appearance, and
    the match's score; the given ``right_px`` and 0 when there is no confident match.

    ``size`` (w, h) of the rectified images; ``box`` (x, y, w, h) the blob's box in rectified
    px, ``support`` its (h, w) uint8 mask.
    """
    width, height = size
    m = params.margin_px
    x, y, bw, bh = box
    x0, y0, x1, y1 = max(x - m, 0), max(y - m, 0), min(x + bw + m, width), min(y + bh + m, height)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return right_px, 0.0
    mask: np.ndarray = np.zeros((y1 - y0, x1 - x0), np.uint8)
    ax0, ay0, ax1, ay1 = max(x, x0), max(y, y0), min(x + bw, x1), min(y + bh, y1)
    if ax1 <= ax0 or ay1 <= ay0:
        return right_px, 0.0
    mask[ay0 - y0 : ay1 - y0, ax0 - x0 : ax1 - x0] = support[ay0 - y : ay1 - y, ax0 - x : ax1 - x]
    if params.erode_px > 0:
        k = 2 * params.erode_px + 1
        mask = cv2.erode(mask, np.ones((k, k), np.uint8))
    if cv2.countNonZero(mask) < 16:
        return right_px, 0.0
    d0 = float(left_px[0] - right_px[0])
    reach = max(params.search_px, params.search_rel * bw)
    lo = int(np.floor(d0 - reach))
    hi = int(np.ceil(d0 + reach))
    r = params.rows_px
    sx0, sx1 = x0 - hi, x1 - lo
    sy0, sy1 = y0 - r, y1 + r
    if sx0 < 0 or sy0 < 0 or sx1 > width or sy1 > height:
        cx0, cy0 = max(sx0, 0), max(sy0, 0)
        cx1, cy1 = min(sx1, width), min(sy1, height)
        if cx1 - cx0 < x1 - x0 + 2 or cy1 - cy0 < y1 - y0:
            return right_px, 0.0
        sx0, sy0, sx1, sy1 = cx0, cy0, cx1, cy1
    template = left(x0, y0, x1, y1)
    search = right(sx0, sy0, sx1, sy1)
    scores = cv2.matchTemplate(search, template, cv2.TM_CCOEFF_NORMED, mask=mask)
    scores = np.nan_to_num(scores, nan=-1.0, posinf=-1.0, neginf=-1.0)
    iy, ix = np.unravel_index(int(np.argmax(scores)), scores.shape)
    best = float(scores[iy, ix])
    if best < params.min_score or not 0 < ix < scores.shape[1] - 1:
        return right_px, best if best >= params.min_score else 0.0
    fx = _parabola(scores[iy, ix - 1], best, scores[iy, ix + 1])
    fy = (
        _parabola(scores[iy - 1, ix], best, scores[iy + 1, ix])
        if 0 < iy < scores.shape[0] - 1
        else 0.0
    )
    shift_x = sx0 + ix + fx - x0
    shift_y = sy0 + iy + fy - y0
    return np.array([left_px[0] + shift_x, left_px[1] + shift_y]), best
