"""Blob matching between the eyes (paper sec. III): blobs paired on one rectified row, at a
disparity in range and of a similar size, and the box edges that weigh a blob cut by the
image's side or a tall one whose two eyes' segmentations cut one end apart."""

from __future__ import annotations

import bisect
import collections
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from stereod.vision.geometry.stereo import CanonicalRig


@dataclass(frozen=True, slots=True)
class MatchParams:
    """How left and right blobs are matched.

    ``row_tolerance_px``: largest |y_L - y_R| (px) on rectified rows.
    ``row_tolerance_share``: for a pair of blobs clear of the image's border whose top rows or
    bottom rows agree within ``row_tolerance_px`` (and whose sides do not), the tolerance
    grows to this share of the shorter one's height (0: never): where the eyes segment one
    end of an object differently (a contact shadow under a ball in one eye), its centroid's
    row moves by a share of its height, beyond any fixed number of pixels at a larger image
    (:func:`match_blobs`).
    ``min_disparity_px`` / ``max_disparity_px``: allowed x_L - x_R (px); the maximum sets the
    nearest depth, B f / d_max. ``max_area_ratio``: largest ratio between the two blob areas.
    """

    row_tolerance_px: float = 6.0
    row_tolerance_share: float = 0.1
    min_disparity_px: float = 0.5
    max_disparity_px: float = 200.0
    max_area_ratio: float = 2.5

    def __post_init__(self) -> None:
        if not self.row_tolerance_px > 0:
            raise ValueError(f"row tolerance must be > 0 px, got {self.row_tolerance_px}")
        if not 0.0 <= self.row_tolerance_share < 1.0:
            raise ValueError(
                f"row tolerance share must be in [0, 1), got {self.row_tolerance_share}"
            )
        if not self.max_disparity_px > self.min_disparity_px:
            raise ValueError(
                f"max_disparity_px ({self.max_disparity_px:g}) must be larger than "
                f"min_disparity_px ({self.min_disparity_px:g}): nothing could match"
            )

    @property
    def tall_px(self) -> float:
        """The height (image px) below which a blob's row tolerance is ``row_tolerance_px``
        (``row_tolerance_share`` of it is no more); infinite when it never grows."""
        share = self.row_tolerance_share
        return self.row_tolerance_px / share if share > 0 else math.inf


EDGE_TOLERANCE_PX = 2.0
"""How far (px) two eyes' outline edges of one object may disagree beyond their disparity:
a segmentation's edge is a pixel or two off (a closing, a hysteresis)."""

AGREEMENT_WEIGHT = 2.0
"""What full disagreement between the eyes' images adds to an ambiguous candidate pair's cost:
two row tolerances, more than any pair within the row and size gates differs by otherwise."""


def match_blobs(
    left_px: np.ndarray,
    left_area: np.ndarray,
    right_px: np.ndarray,
    right_area: np.ndarray,
    params: MatchParams,
    slack_px: float = 0.0,
    agreement: Callable[[int, int], float] | None = None,
    edges: tuple[np.ndarray, np.ndarray] | None = None,
    heights: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Match blobs by row, disparity range and size; return (m, 2) int index pairs (left, right).

    Candidates must lie on the same row within the tolerance, at a disparity in range, with
    similar areas. ``slack_px`` widens the disparity range both ways by how far an object may
    move in the image between the two eyes' capture instants (skew): a fast object seen by a
    late right eye can even show a negative disparity. Each blob is used once: pairs are taken
    greedily by increasing cost (row difference in tolerances, log area ratio, and how far out
    of the range without slack the disparity is, in slacks; ties by index), which is optimal
    for the few, well separated blobs a scene has and needs no solver. Only the right blobs
    within the row tolerance of a left blob are looked at (by bisection on their rows), one
    pair at a time in Python floats: a scene has a few blobs, and a saturated one a few per
    row.

    Where a blob could pair with more than one blob of the other eye, size and row alone may
    pick the wrong one (the floor a pushed box uncovered, in one eye, is the size of the box
    at its new place in the other). Given ``agreement`` (left index, right index -> how alike
    the two eyes' images of the pair are, at most 1: :func:`stereod.vision.agreement.
    eye_agreement`), such candidates cost ``AGREEMENT_WEIGHT`` times their disagreement more.

    Given ``edges`` (each eye's :func:`box_edges`), a pair of which either blob is cut by the
    image's left or right side is held to its boxes instead of its centroids: each eye sees a
    different part of the object there, so the centroids' rows and disparity are no evidence.
    Its rows are the boxes' top and bottom rows that neither eye's image edge cuts (none: a
    person taller than the view, no row evidence, costed as a full tolerance), its disparity
    that of the boxes' edges on the side no image edge cuts.

    Given the edges and ``heights`` (each eye's blobs' heights, image px), a pair of blobs
    that both lie clear of the image's border, whose top rows or bottom rows agree within
    ``row_tolerance_px`` and whose sides do not both lie one disparity apart has a row
    tolerance of ``row_tolerance_share`` of the shorter one's height where that is more: the
    eyes segmented its other end differently (a contact shadow's crescent in one eye), which
    moves a centroid's row by a share of the object's height. Its row difference still costs
    by ``row_tolerance_px``, so the pairs within that rank as without it. An outline cut
    short at one end whose sides agree is left to :mod:`stereod.vision.grouping`, which pairs
    it by the rows both eyes show.
    """
    nl, nr = len(left_px), len(right_px)
    if nl == 0 or nr == 0:
        return np.zeros((0, 2), dtype=np.intp)
    left, right = np.asarray(left_px).tolist(), np.asarray(right_px).tolist()
    l_area = np.maximum(np.asarray(left_area), 1).tolist()
    r_area = np.maximum(np.asarray(right_area), 1).tolist()
    # a row that is not a number matches nothing (and would break the rows' order)
    by_row = sorted((j for j in range(nr) if math.isfinite(right[j][1])), key=lambda j: right[j][1])
    rows = [right[j][1] for j in by_row]
    tol, lo, hi = params.row_tolerance_px, params.min_disparity_px, params.max_disparity_px
    max_ratio = math.log(params.max_area_ratio)
    l_box = r_box = None
    if edges is not None:
        l_box, r_box = (np.asarray(e, np.float64).reshape(-1, 4).tolist() for e in edges)
    sided = [j for j in by_row if r_box is not None and _cut_side(r_box[j])]
    grow = l_box is not None and r_box is not None and heights is not None
    share = params.row_tolerance_share if grow else 0.0
    l_h, r_h = (h.tolist() for h in heights) if heights is not None and grow else ([], [])
    candidates = []
    for i, (xl, yl) in enumerate(left):
        if not math.isfinite(yl):
            continue
        tol_i = tol
        if share > 0 and l_box is not None and _clear(l_box[i]):
            tol_i = max(tol, share * l_h[i])  # no pair of blob i has a larger one
        if l_box is not None and _cut_side(l_box[i]):
            near = by_row  # its centroid's row says nothing: every right blob may be it
        else:
            lo_k = bisect.bisect_left(rows, yl - tol_i)
            hi_k = bisect.bisect_right(rows, yl + tol_i)
            near = by_row[lo_k:hi_k]
            near += [j for j in sided if not yl - tol_i <= right[j][1] <= yl + tol_i]
        for j in near:
            xr, yr = right[j]
            tol_ij = tol
            if tol_i > tol and l_box is not None and r_box is not None:
                tol_ij = _end_tolerance(l_box[i], r_box[j], tol, share * min(l_h[i], r_h[j]))
            dy, disp = abs(yl - yr), xl - xr
            if l_box is not None and r_box is not None:
                dy, disp = _box_evidence(l_box[i], r_box[j], dy, disp, tol)
            ratio = abs(math.log(l_area[i] / float(r_area[j])))
            if dy > tol_ij or ratio > max_ratio or not lo - slack_px <= disp <= hi + slack_px:
                continue
            cost = dy / tol + ratio
            if slack_px > 0:
                cost += (max(lo - disp, 0.0) + max(disp - hi, 0.0)) / slack_px
            candidates.append((cost, i, j))
    if agreement is not None and candidates:
        per_l = collections.Counter(i for _, i, _ in candidates)
        per_r = collections.Counter(j for _, _, j in candidates)
        candidates = [
            (c + AGREEMENT_WEIGHT * max(1.0 - agreement(i, j), 0.0), i, j)
            if per_l[i] > 1 or per_r[j] > 1
            else (c, i, j)
            for c, i, j in candidates
        ]
    candidates.sort()
    used_l, used_r = [False] * nl, [False] * nr
    out = []
    for _, i, j in candidates:
        if used_l[i] or used_r[j]:
            continue
        used_l[i] = used_r[j] = True
        out.append((i, j))
    return np.array(out, dtype=np.intp).reshape(-1, 2)


def box_edges(rig: CanonicalRig | _Rectifies, bbox_px: np.ndarray, left: bool) -> np.ndarray:
    """One eye's blobs' boxes (n, 4: x, y, w, h image px) as :func:`match_blobs` weighs a
    blob cut by the image's side: (n, 4) rectified px of its left and right columns and top
    and bottom rows (x0, x1, y0, y1; each at the middle of its side), NaN where that side of
    the box reaches the image's edge (the object may go on beyond it)."""
    b = np.asarray(bbox_px, np.float64).reshape(-1, 4)
    x0, y0, w, h = b.T
    x1, y1 = x0 + w, y0 + h
    xc, yc = x0 + 0.5 * w, y0 + 0.5 * h
    pts = np.stack([np.c_[x0, yc], np.c_[x1, yc], np.c_[xc, y0], np.c_[xc, y1]], axis=1)
    rect = (rig.rectify_left if left else rig.rectify_right)(pts.reshape(-1, 2)).reshape(-1, 4, 2)
    out = np.stack([rect[:, 0, 0], rect[:, 1, 0], rect[:, 2, 1], rect[:, 3, 1]], axis=1)
    out[np.c_[x0 <= 0, x1 >= rig.width_px, y0 <= 0, y1 >= rig.height_px]] = np.nan
    return out


def side_cut_edges(
    rig: CanonicalRig | _Rectifies,
    left_bbox_px: np.ndarray,
    right_bbox_px: np.ndarray,
    params: MatchParams | None = None,
    centroids_px: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Both eyes' :func:`box_edges` when a blob of either reaches the image's left or right
    side, or (given ``params`` and ``centroids_px``, each eye's rectified centroids) is at
    least :attr:`MatchParams.tall_px` tall in the image with no blob of the other eye within
    ``row_tolerance_px`` of its row; else None. :func:`match_blobs` then weighs every pair
    by its centroids with one row tolerance, as it would with the edges (but for a tall
    blob that has a partner within it), and most pairs are spared rectifying four points a
    box (0.2 ms an eye on a calibrated rig)."""

    def needs(bbox_px: np.ndarray, own: np.ndarray | None, other: np.ndarray | None) -> bool:
        b = np.asarray(bbox_px).reshape(-1, 4)
        if np.any((b[:, 0] <= 0) | (b[:, 0] + b[:, 2] >= rig.width_px)):
            return True
        if params is None or own is None or other is None:
            return False
        tall = b[:, 3] >= params.tall_px
        if not tall.any():
            return False
        if len(other) == 0:  # nothing to pair it with
            return False
        gap = np.abs(own[tall, None] - other[None, :])
        return bool(np.any(~(gap.min(axis=1) <= params.row_tolerance_px)))

    rows_l = rows_r = None
    if centroids_px is not None:
        rows_l, rows_r = np.asarray(centroids_px[0])[:, 1], np.asarray(centroids_px[1])[:, 1]
    if not (needs(left_bbox_px, rows_l, rows_r) or needs(right_bbox_px, rows_r, rows_l)):
        return None
    return box_edges(rig, left_bbox_px, True), box_edges(rig, right_bbox_px, False)


class _Rectifies(Protocol):
    """A rig as :func:`box_edges` uses it: its image size and each eye's rectification."""

    width_px: int
    height_px: int

    def rectify_left(self, points_px: np.ndarray) -> np.ndarray: ...
    def rectify_right(self, points_px: np.ndarray) -> np.ndarray: ...


def _clear(box: list[float]) -> bool:
    """Whether a :func:`box_edges` box lies clear of the image's border on all four sides."""
    return all(v == v for v in box)


def _end_tolerance(lb: list[float], rb: list[float], tol: float, grown: float) -> float:
    """The row tolerance (px) of a pair of :func:`box_edges` boxes: ``grown`` (at least
    ``tol``) where both lie clear of the image's border, their top rows or bottom rows agree
    within ``tol`` and their sides do not both lie one disparity apart (within two
    :data:`EDGE_TOLERANCE_PX`: that outline is one cut short at one end, grouping's to pair
    by its shared rows), else ``tol``."""
    clear = _clear(lb) and _clear(rb)
    if not (clear and (abs(lb[2] - rb[2]) <= tol or abs(lb[3] - rb[3]) <= tol)):
        return tol
    d0, d1 = lb[0] - rb[0], lb[1] - rb[1]
    if min(d0, d1) > 0 and abs(d0 - d1) <= 2 * EDGE_TOLERANCE_PX:
        return tol
    return max(tol, grown)


def _cut_side(box: list[float]) -> bool:
    """Whether a :func:`box_edges` box reaches the image's left or right side."""
    return box[0] != box[0] or box[1] != box[1]


def _box_evidence(
    lb: list[float], rb: list[float], dy: float, disp: float, tol: float
) -> tuple[float, float]:
    """A candidate pair's row difference and disparity (px) from its :func:`box_edges` boxes
    ``lb``, ``rb`` where either is cut by the image's side, else its centroids' ``dy`` and
    ``disp`` as they are: the largest difference of the top and bottom rows that neither eye
    cuts (``tol`` when none is uncut in both), and the disparity of the side columns that
    neither eye cuts (the centroids' when both sides are cut in one eye or the other)."""
    if not (_cut_side(lb) or _cut_side(rb)):
        return dy, disp
    rows = [abs(a - b) for a, b in ((lb[2], rb[2]), (lb[3], rb[3])) if a == a and b == b]
    dy = max(rows) if rows else tol
    if lb[0] == lb[0] and rb[0] == rb[0]:
        disp = lb[0] - rb[0]
    elif lb[1] == lb[1] and rb[1] == rb[1]:
        disp = lb[1] - rb[1]
    return dy, disp
