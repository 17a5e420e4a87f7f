"""An object's disparity read row by row: the median over the rows both eyes see of the
difference of each row's centre, so that a few rows one eye segments differently (a contact
shadow's crescent, a patch of floor) cannot move its depth.

A blob's row profile is an (n, 3) float64 array, one row per image row it covers: the row
(image px), the row's weight (its share of eq. 5's weights: the matte's coverage, or the
edge ramp's) and the weighted sum of its columns (px); a binary centroid keeps none (a row's
centre would be whole pixels). The centroid's x (eq. 5) is the profile's total
weighted sum over its total weight; each row's centre is its own. A rectified pair's rows
match (same object, same row in both eyes), so each common row gives one disparity, and the
median of those ignores rows where one eye took in a little more or less than the other.

A calibrated rig's image rows are not quite its rectified rows (each eye is turned by a degree
or so, and distorted), but within one eye an object's image rows still cross it level, so each
row's centre is the object's in that eye; the rows are paired as a rectified pair's, the offset
between them chosen as for an object that moved up or down between the eyes' instants
(:func:`row_offset`), and the shift in image px is scaled into each eye's rectified px.
(Row centres rectified as points and compared at equal rectified heights would read a ramp
across the rows, each eye's rows tilting their own way, whose median a crescent moves.)
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from stereod.vision.blobs import Blobs

__all__ = [
    "EMPTY",
    "MAD_TIE_PX",
    "MAX_TILT_DEG",
    "MIN_ROWS",
    "MIN_ROW_WEIGHT",
    "SIGMAS",
    "Rectify",
    "cut",
    "median_shift_px",
    "merged",
    "moved",
    "profile",
    "row_offset",
    "rows_median",
]

Rectify = Callable[[np.ndarray], np.ndarray]
"""One eye's image px (n, 2) to rectified px (n, 2)."""
MAX_TILT_DEG = 4.0
"""The steepest an eye's image row may lie in rectified px, at the blob (deg), for its rows to
be paired as rectified rows: a Minoru's eyes are turned by about a degree, and rows turned 3
and -2.5 deg still read a disc's disparity to 0.08 px. An eye turned further about its axis,
or the rows of two cameras toed in towards each other away from mid-height, keep their
centroids. (Toed-in rows at mid-height lie level: there the shift is read, scaled by how much
wider one eye sees the object, which corrects most of a crescent's error.)"""

MIN_ROWS = 32
"""Fewest common rows (px) for the median to be read. A round blob of 24 px or less is
centred by a disc fit (``DetectorParams.disc_max_px``), whose centre is not the profile's;
over 25 to 31 rows the median's own noise (a row's centre is the mean of its two partial
edge pixels) matches what it removes: on the independent renderer's balls under a lamp, a
26-row ball's heading moved by up to 1.4 deg either way."""
MIN_ROW_WEIGHT = 1.0
"""Least weight (px) a row needs in both eyes to count: a row that is only the edge band's
partial pixels has no centre to speak of."""
SIGMAS = 2.0 * math.sqrt(2.0)
"""How many centroid errors the rows' median disparity must differ from the centroids' by
to replace it: twice the noise of a difference of two centroids."""
EMPTY = np.zeros((0, 3), np.float64)
EMPTY.setflags(write=False)


def profile(weight: np.ndarray, x0: int, y0: int) -> np.ndarray:
    """The row profile of a weight image (h, w) float32 whose top left is image (x0, y0)."""
    h, w = weight.shape
    out = np.empty((h, 3), np.float64)
    out[:, 0] = np.arange(y0, y0 + h)
    out[:, 1] = weight.sum(axis=1, dtype=np.float64)
    out[:, 2] = weight @ np.arange(x0, x0 + w, dtype=np.float64)
    return out


def moved(prof: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """The profile of the same weights ``dx``, ``dy`` px further right and down (a crop's
    profile in its image's px)."""
    if dx == 0 and dy == 0:
        return prof
    out = prof.copy()
    out[:, 0] += dy
    out[:, 2] += dx * out[:, 1]
    return out


def merged(profiles: list[np.ndarray]) -> np.ndarray:
    """One profile of several pieces of one object: their weights and sums added row by row."""
    if not profiles:
        return EMPTY
    if len(profiles) == 1:
        return profiles[0]
    stacked = np.concatenate(profiles)
    rows, at = np.unique(stacked[:, 0], return_inverse=True)
    out = np.zeros((rows.size, 3), np.float64)
    out[:, 0] = rows
    np.add.at(out[:, 1], at, stacked[:, 1])
    np.add.at(out[:, 2], at, stacked[:, 2])
    return out


def cut(prof: np.ndarray, y0: int, y1: int) -> np.ndarray:
    """The profile's rows from ``y0`` to ``y1`` (image px, end exclusive)."""
    return prof[(prof[:, 0] >= y0) & (prof[:, 0] < y1)]


def _row_disparities(left: np.ndarray, right: np.ndarray, offset: int) -> np.ndarray | None:
    """Each common row's disparity (px): left row r's centre less right row r + ``offset``'s,
    over rows with :data:`MIN_ROW_WEIGHT` in both; None under :data:`MIN_ROWS` of them."""
    lk = left[left[:, 1] >= MIN_ROW_WEIGHT]
    rk = right[right[:, 1] >= MIN_ROW_WEIGHT]
    _, il, ir = np.intersect1d(lk[:, 0], rk[:, 0] - offset, assume_unique=True, return_indices=True)
    if il.size < MIN_ROWS:
        return None
    return lk[il, 2] / lk[il, 1] - rk[ir, 2] / rk[ir, 1]


def median_shift_px(left: np.ndarray, right: np.ndarray, row_offset: int) -> float | None:
    """How far (px) the median of the common rows' disparities lies from the disparity of the
    two profiles' centroids: add it to a centroid disparity to read the rows' median instead.
    Right row ``r + row_offset`` is left row ``r``'s (0 for a rectified pair seen at one
    instant). None where fewer than :data:`MIN_ROWS` rows have :data:`MIN_ROW_WEIGHT` in both
    eyes, or a profile has no weight."""
    return _shift(left, right, _row_disparities(left, right, row_offset))


def _shift(left: np.ndarray, right: np.ndarray, each: np.ndarray | None) -> float | None:
    """:func:`median_shift_px` from the rows' disparities ``each`` already read."""
    wl, wr = float(left[:, 1].sum()), float(right[:, 1].sum())
    if each is None or wl <= 0.0 or wr <= 0.0:
        return None
    whole = float(left[:, 2].sum()) / wl - float(right[:, 2].sum()) / wr
    return float(np.median(each)) - whole


MAD_TIE_PX = 0.05
"""Median absolute deviations (px) of the rows' disparities closer than this are a tie."""


def row_offset(lb: Blobs, rb: Blobs, i: int, j: int) -> int:
    """Which right row is left row 0's (px): of how far apart the two boxes' top rows are,
    their bottom rows and their centroids' rows, the one under which the rows' disparities
    agree best (the least median absolute deviation, to :data:`MAD_TIE_PX`), and of those
    the nearest 0 (a rectified pair's rows, where nothing moved up or down between the eyes'
    instants). Rows one eye added or lost at one end (a shadow's crescent under an object)
    move that end and, less, the centroid, but not the other end. A round or straight-sided
    object's rows agree under any of these, and then its disparity does not depend on which."""
    return _paired(lb, rb, i, j)[0]


def _paired(lb: Blobs, rb: Blobs, i: int, j: int) -> tuple[int, np.ndarray | None]:
    """:func:`row_offset`, and the rows' disparities under it (None: too few rows)."""
    top = int(rb.bbox_px[j, 1] - lb.bbox_px[i, 1])
    bottom = top + int(rb.bbox_px[j, 3] - lb.bbox_px[i, 3])
    centre = round(float(rb.centroid_px[j, 1] - lb.centroid_px[i, 1]))
    best: tuple[int, int] | None = None
    chosen: tuple[int, np.ndarray | None] = (centre, None)
    for offset in dict.fromkeys((centre, top, bottom)):
        each = _row_disparities(lb.rows[i], rb.rows[j], offset)
        if each is None:
            continue
        mad = float(np.median(np.abs(each - np.median(each))))
        key = (int(mad / MAD_TIE_PX), abs(offset))
        if best is None or key < best:
            best, chosen = key, (offset, each)
    return chosen


def _own(blobs: Blobs, i: int) -> bool:
    """Whether blob ``i``'s centroid is its row profile's (eq. 5 over those weights, to
    1e-3 px): not replaced by a disc fit, a group's area-weighted mean or a cut's moments."""
    prof = blobs.rows[i]
    w = float(prof[:, 1].sum())
    if w <= 0.0:
        return False
    cx, cy = (float(v) for v in blobs.centroid_px[i])
    return (
        abs(float(prof[:, 2].sum()) / w - cx) < 1e-3
        and abs(float(prof[:, 0] @ prof[:, 1]) / w - cy) < 1e-3
    )


def _inside(box: np.ndarray, width: int, height: int) -> bool:
    x, y, w, h = (int(v) for v in box)
    return x > 0 and y > 0 and x + w < width and y + h < height


def rows_median(
    lb: Blobs,
    rb: Blobs,
    idx: np.ndarray,
    lpx: np.ndarray,
    rpx: np.ndarray,
    sigma_px: float,
    size: tuple[int, int],
    rectify: tuple[Rectify, Rectify] | None = None,
) -> int:
    """Move each matched pair's centroids ``lpx``, ``rpx`` (rectified px, in place) apart or
    together by :func:`median_shift_px` where that exceeds :data:`SIGMAS` times a centroid's
    error ``sigma_px``: the rows' median disparity replaces the centroids' where the two
    disagree beyond the centroids' own noise, so rows one eye's segmentation took in and the
    other's did not move neither the depth nor, before the skew stage interpolates along
    each eye's 2D track, the disparity of that track's samples. Each centroid moves half the
    shift (which eye took in the rows is not known), so their mean stays. For a canonical
    (already rectified) rig, whose image rows are its rectified rows; a calibrated rig gives
    its eyes' ``rectify`` (left, right), and each eye's half of the shift, read in its image
    px, is scaled by how many rectified px an image px across is at its centroid (where one
    eye's px are s times the other's, the shift, read in the eye that took in the rows, is
    then off by about (s - 1) / 2 of itself: a thousandth for a Minoru's eyes, whose focal
    lengths are within a few per cent). Left alone: pairs with a blob touching the image's
    border (``size``: width, height px; its rows are cut), a blob whose centroid is not its
    profile's (:func:`_own`), and a calibrated eye whose rows lie steeper than
    :data:`MAX_TILT_DEG`. Gives how many pairs moved."""
    if len(lb.rows) != len(lb) or len(rb.rows) != len(rb):
        return 0
    moved_pairs = 0
    for k, (i, j) in enumerate(idx.tolist()):
        if not (_inside(lb.bbox_px[i], *size) and _inside(rb.bbox_px[j], *size)):
            continue
        if not (_own(lb, i) and _own(rb, j)):
            continue
        shift = _shift(lb.rows[i], rb.rows[j], _paired(lb, rb, i, j)[1])
        if shift is not None and abs(shift) > SIGMAS * sigma_px:
            scales = (1.0, 1.0) if rectify is None else _scales(lb, rb, i, j, rectify)
            if scales is None:
                continue
            left, right = scales
            lpx[k, 0] += 0.5 * shift * left
            rpx[k, 0] -= 0.5 * shift * right
            moved_pairs += 1
    return moved_pairs


def _scales(
    lb: Blobs, rb: Blobs, i: int, j: int, rectify: tuple[Rectify, Rectify]
) -> tuple[float, float] | None:
    """Rectified px per image px across (x), at each eye's centroid; None where an image row
    lies steeper than :data:`MAX_TILT_DEG` in rectified px."""
    out = []
    for blobs, k, fn in ((lb, i, rectify[0]), (rb, j, rectify[1])):
        c = blobs.centroid_px[k]
        ends = fn(np.array([[c[0] - 0.5, c[1]], [c[0] + 0.5, c[1]]], np.float64))
        dx, dy = (float(v) for v in ends[1] - ends[0])
        if not dx > 0.0 or abs(math.degrees(math.atan2(dy, dx))) > MAX_TILT_DEG:
            return None
        out.append(dx)
    return out[0], out[1]
