"""Image boxes (x, y, w, h px) and points, one pair at a time and every pair at once: inside,
overlap, union, intersection over union, distance to a segment, and whether two boxes are one
object's re-segmented (:func:`recuts`). The whole-array forms give each pair's own numbers."""

from __future__ import annotations

import math

import numpy as np


def to_segment(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance (px) from a point to the segment a-b (a point when a == b)."""
    ax, ay, px, py = float(a[0]), float(a[1]), float(point[0]), float(point[1])
    dx, dy = float(b[0]) - ax, float(b[1]) - ay
    n2 = dx * dx + dy * dy
    t = 0.0 if n2 == 0.0 else min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / n2))
    return math.hypot(px - (ax + t * dx), py - (ay + t * dy))


def inside(point: np.ndarray, bbox: np.ndarray, grow: float) -> bool:
    """Whether a point (px) lies in a box (x, y, w, h), grown by ``grow`` of its size on every
    side (its edges included)."""
    x, y, w, h = (float(v) for v in bbox)
    mx, my = grow * w, grow * h
    return bool(x - mx <= point[0] <= x + w + mx and y - my <= point[1] <= y + h + my)


def overlaps(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two boxes (x, y, w, h) share any area."""
    return bool(
        min(a[0] + a[2], b[0] + b[2]) > max(a[0], b[0])
        and min(a[1] + a[3], b[1] + b[3]) > max(a[1], b[1])
    )


def union(boxes: list[np.ndarray]) -> np.ndarray:
    """The smallest box (x, y, w, h) holding every one of ``boxes``."""
    a = np.asarray(boxes, np.float64).reshape(-1, 4)
    x0, y0 = a[:, 0].min(), a[:, 1].min()
    return np.array([x0, y0, (a[:, 0] + a[:, 2]).max() - x0, (a[:, 1] + a[:, 3]).max() - y0])


def moved(bbox: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """A box (x, y, w, h) moved by ``shift`` (2,) px."""
    return np.array([bbox[0] + shift[0], bbox[1] + shift[1], bbox[2], bbox[3]], np.float64)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boxes (x, y, w, h)."""
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = float(a[2] * a[3] + b[2] * b[3]) - inter
    return inter / union if union > 0 else 0.0


SMALL_PAIRS = 4
"""At most this many point-segment or point-box pairs are worked out one at a time in Python
floats (:func:`to_segments`, :func:`insides`), the same arithmetic to the bit: a pair with
one detection and one track would otherwise pay numpy's per-call cost for each of some thirty
operations on one number."""


def to_segments(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`to_segment` of every point ((n, 2) px) to every segment a-b ((m, 2) each), in
    one pass: (n, m) px."""
    if points.shape[0] * a.shape[0] <= SMALL_PAIRS:
        return to_segments_few(points, a, b)
    ax, ay = a[None, :, 0], a[None, :, 1]
    px, py = points[:, None, 0], points[:, None, 1]
    dx, dy = b[None, :, 0] - ax, b[None, :, 1] - ay
    n2 = dx * dx + dy * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.minimum(1.0, np.maximum(0.0, ((px - ax) * dx + (py - ay) * dy) / n2))
    t = np.where(n2 == 0.0, 0.0, t)
    return np.hypot(px - (ax + t * dx), py - (ay + t * dy))


def insides(points: np.ndarray, boxes: np.ndarray, grow: float = 0.0) -> np.ndarray:
    """:func:`inside` of every point ((m, 2) px) in every box ((n, 4) x, y, w, h, each grown
    by ``grow`` of its size on every side), in one pass: (n boxes, m points)."""
    if len(boxes) * points.shape[0] <= SMALL_PAIRS:
        return insides_few(points, boxes, grow)
    x, y, w, h = np.asarray(boxes, np.float64).T[:, :, None]
    px, py = points[None, :, 0], points[None, :, 1]
    if grow == 0.0:  # (x - 0 w is x: the same comparisons, without four products)
        return (x <= px) & (px <= x + w) & (y <= py) & (py <= y + h)
    mx, my = grow * w, grow * h
    return (x - mx <= px) & (px <= x + w + mx) & (y - my <= py) & (py <= y + h + my)


def to_segments_few(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`to_segments` one pair at a time in Python floats, the same operations in the
    same order (numpy's ``hypot``, which may differ from ``math.hypot`` in the last bit):
    (n, m) px."""
    out = []
    for px, py in points.tolist():
        row = []
        for (ax, ay), (bx, by) in zip(a.tolist(), b.tolist(), strict=True):
            dx, dy = bx - ax, by - ay
            n2 = dx * dx + dy * dy
            if n2 == 0.0:
                t = 0.0
            else:
                q = ((px - ax) * dx + (py - ay) * dy) / n2
                t = q if q != q else min(1.0, max(0.0, q))  # NaN stays NaN, as in numpy
            row.append(np.hypot(px - (ax + t * dx), py - (ay + t * dy)))
        out.append(row)
    return np.array(out, np.float64).reshape(len(points), len(a))


def insides_few(points: np.ndarray, boxes: np.ndarray, grow: float) -> np.ndarray:
    """:func:`insides` one pair at a time in Python floats: (n boxes, m points)."""
    pts = points.tolist()
    out = []
    for x, y, w, h in np.asarray(boxes, np.float64).reshape(-1, 4).tolist():
        if grow == 0.0:
            x0, x1, y0, y1 = x, x + w, y, y + h
        else:
            mx, my = grow * w, grow * h
            x0, x1, y0, y1 = x - mx, x + w + mx, y - my, y + h + my
        out.append([x0 <= px <= x1 and y0 <= py <= y1 for px, py in pts])
    return np.array(out, bool).reshape(len(out), len(pts))


def ious(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`iou` of every box of ``a`` ((n, 4) x, y, w, h) with every box of ``b`` ((m, 4)),
    in one pass: (n, m)."""
    a, b = a[:, None, :].astype(np.float64), b[None, :, :].astype(np.float64)
    lo_x, lo_y = np.maximum(a[..., 0], b[..., 0]), np.maximum(a[..., 1], b[..., 1])
    ix = np.maximum(0.0, np.minimum(a[..., 0] + a[..., 2], b[..., 0] + b[..., 2]) - lo_x)
    iy = np.maximum(0.0, np.minimum(a[..., 1] + a[..., 3], b[..., 1] + b[..., 3]) - lo_y)
    inter = ix * iy
    union = (a[..., 2] * a[..., 3] + b[..., 2] * b[..., 3]) - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


RECUT_END_PX = 4.0
"""How far (px) the ends two boxes share may lie apart in :func:`recuts`: a segmentation's
edge is a pixel or two off, and a prediction a pixel or two more."""


def recuts(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether each box of ``a`` ((n, 4) x, y, w, h px) and each of ``b`` ((m, 4)) are one
    object's boxes with an end of it segmented or not: one holds the other, and along the
    axis where they differ more they share one end at least, along the other both (each
    within :data:`RECUT_END_PX`). A ball's box and the box of the ball with its long shadow
    beside it share the ball's side, top and bottom; a ball and a person beside it, whose
    blob holds both, share the floor's end but not the person's sides. (n, m) bool."""
    a, b = a[:, None, :].astype(np.float64), b[None, :, :].astype(np.float64)
    e = RECUT_END_PX
    lo_a, hi_a = a[..., :2], a[..., :2] + a[..., 2:]
    lo_b, hi_b = b[..., :2], b[..., :2] + b[..., 2:]
    a_in_b = ((lo_a >= lo_b - e) & (hi_a <= hi_b + e)).all(axis=-1)
    b_in_a = ((lo_b >= lo_a - e) & (hi_b <= hi_a + e)).all(axis=-1)
    same_lo, same_hi = np.abs(lo_a - lo_b) <= e, np.abs(hi_a - hi_b) <= e
    wide = np.abs(a[..., 2] - b[..., 2]) >= np.abs(a[..., 3] - b[..., 3])  # differs across
    axis = np.where(wide, 0, 1)[..., None]
    one_end = np.take_along_axis(same_lo | same_hi, axis, axis=-1)[..., 0]
    both_ends = np.take_along_axis(same_lo & same_hi, 1 - axis, axis=-1)[..., 0]
    return (a_in_b | b_in_a) & one_end & both_ends
