"""Rectangles of an image: the box around the pixels above a level, a box clipped or grown, and
the rows of a plane that eq. 3 learns every ``learn_stride``-th row of."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

Rect = tuple[int, int, int, int]
"""A rectangle of an image (x0, y0, x1, y1) px, the end exclusive."""


def above_any(diff: np.ndarray, level: float) -> tuple[int, int, int, int]:
    """The bounding box (x, y, w, h px) of the pixels of ``diff`` where any channel is above
    ``level`` (see :func:`above`). Every pixel whose mean over the channels is above it is
    among them, so the box holds eq. 4's colour foreground; a channel alone may add a little
    to it, and the every-pixel pass inside decides. Taking the channels as they lie, as one
    row of bytes, saves averaging them over the whole grid."""
    if diff.ndim == 2:
        return above(diff, level)
    n = diff.shape[2]
    x, y, w, h = above(diff.reshape(diff.shape[0], -1), level)
    if h == 0:
        return (0, 0, 0, 0)
    return (x // n, y, (x + w - 1) // n - x // n + 1, h)


def above(diff: np.ndarray, level: float) -> tuple[int, int, int, int]:
    """The bounding box (x, y, w, h px) of the pixels of ``diff`` above ``level``, (0, 0, 0, 0)
    when there are none: the columns' maxima give its sides, and the bitmap of only the
    columns between them its top and bottom (no whole-frame bitmap)."""
    cols = diff.max(axis=0) > level
    x0 = int(cols.argmax())
    if not cols[x0]:
        return (0, 0, 0, 0)
    x1 = cols.size - int(cols[::-1].argmax())
    _, slab = cv2.threshold(diff[:, x0:x1], level, 255, cv2.THRESH_BINARY)
    _, y, _, h = cv2.boundingRect(slab)
    return (x0, y, x1 - x0, h)


def rows_within(y0: int, y1: int, first: int, stride: int) -> slice:
    """The rows ``first + stride k`` (k >= 0) that lie in [y0, y1), as indices k."""
    lo = max(0, -(-(y0 - first) // stride))
    hi = max(lo, -(-(y1 - first) // stride))
    return slice(lo, hi)


def put_rows(dst: np.ndarray, src: np.ndarray, x: int, y: int, first: int, stride: int) -> None:
    """Into ``dst``, whose rows are ``first + stride k`` of a plane, the rows of ``src`` (at
    (``x``, ``y``) of that plane) that are among them."""
    k = rows_within(y, y + src.shape[0], first, stride)
    if k.stop > k.start:
        top = first + stride * k.start - y
        dst[k, x : x + src.shape[1]] = src[top::stride][: k.stop - k.start]


def clipped(rect: Sequence[int], x1: int, y1: int, x0: int = 0, y0: int = 0) -> Rect | None:
    """A rectangle (x0, y0, x1, y1 px) cut to the window [x0, x1) x [y0, y1); ``None`` if
    nothing is left."""
    cx0, cy0 = max(int(rect[0]), x0), max(int(rect[1]), y0)
    cx1, cy1 = min(int(rect[2]), x1), min(int(rect[3]), y1)
    return (cx0, cy0, cx1, cy1) if cx1 > cx0 and cy1 > cy0 else None


def grown_rect(rect: Sequence[int], margin: int, shape: tuple[int, ...]) -> Rect | None:
    """A rectangle (x, y, w, h) grown by ``margin`` px and clipped to the image, as (x0, y0,
    x1, y1); ``None`` for an empty one."""
    x, y, w, h = rect
    if w == 0 or h == 0:
        return None
    return (
        max(x - margin, 0),
        max(y - margin, 0),
        min(x + w + margin, shape[1]),
        min(y + h + margin, shape[0]),
    )


def box_rect(bbox: Sequence[int] | np.ndarray, margin: int) -> Rect:
    """A blob's box (x, y, w, h px) grown by ``margin`` px each way, as (x0, y0, x1, y1)."""
    x, y, w, h = (int(v) for v in bbox)
    return (x - margin, y - margin, x + w + margin + 1, y + h + margin + 1)
