"""Whether the two eyes see the same thing in a candidate pair of blobs: the zero-mean
normalised cross-correlation of their boxes' grey patches, each resampled to one small size.

A pair made of two different things (the floor a pushed box uncovered, in one eye, and the box
at its new place, in the other: the same rows and size) triangulates to a point that does not
exist, 0.16 m from the rig, and becomes a track that stands there. Where size and row cannot
tell a blob's partners apart, appearance can (:func:`stereod.vision.geometry.stereo.
match_blobs`)."""

from __future__ import annotations

import cv2
import numpy as np

PATCH_PX = 24
"""Both boxes are resampled to this square (px) before they are compared: fine enough for a
texture, coarse enough that the eyes' 6 cm of parallax and a pixel of box jitter do not count."""

FLAT_GREY = 3.0
"""A patch whose grey levels vary less than this (standard deviation, 8-bit levels) has no
texture to compare: its correlation says nothing, and it counts as agreeing."""


def _patch(image: np.ndarray, box_px: np.ndarray) -> np.ndarray | None:
    """The grey patch of ``image`` under ``box_px`` (x, y, w, h; clipped to the image), as
    PATCH_PX x PATCH_PX float32, or None where the box holds no pixel."""
    h, w = image.shape[:2]
    x, y, bw, bh = (int(v) for v in box_px)
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + bw, w), min(y + bh, h)
    if x1 <= x0 or y1 <= y0:
        return None
    roi = image[y0:y1, x0:x1]
    if roi.ndim == 3:
        roi = cv2.cvtColor(roi, cv2.COLOR_BGR2GRAY)
    return cv2.resize(roi, (PATCH_PX, PATCH_PX), interpolation=cv2.INTER_AREA).astype(np.float32)


def eye_agreement(
    left: np.ndarray, right: np.ndarray, left_box_px: np.ndarray, right_box_px: np.ndarray
) -> float:
    """How alike (normalised cross-correlation, -1 to 1) the left image under ``left_box_px``
    and the right under ``right_box_px`` (x, y, w, h, image px) are; 1.0 where either patch is
    flat (``FLAT_GREY``) or a box lies outside its image, which gives no evidence of a
    mismatch. On the independent renderer a real object's two eyes give 0.7-1.0 (median 0.98);
    the uncovered floor against the box, 0.3."""
    a, b = _patch(left, left_box_px), _patch(right, right_box_px)
    if a is None or b is None:
        return 1.0
    a -= a.mean()
    b -= b.mean()
    sa, sb = float(np.sqrt((a * a).mean())), float(np.sqrt((b * b).mean()))
    if sa < FLAT_GREY or sb < FLAT_GREY:
        return 1.0
    return float((a * b).mean() / (sa * sb))
