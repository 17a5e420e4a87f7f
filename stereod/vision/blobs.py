"""A frame's blobs (eq. 5's centres, boxes, areas and supports) as parallel arrays, and the
grouping of outlines into objects."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True, slots=True)
class Blobs:
    """Blobs of one frame as parallel arrays (n rows each).

    ``centroid_px`` (n, 2) float64 image x, y (eq. 5); ``bbox_px`` (n, 4) int32 x, y, w, h;
    ``area_px`` (n,) int32 pixel count of the support; ``support`` n uint8 (h, w) masks (255
    on the object) aligned with each bounding box; ``rows`` n row profiles of eq. 5's
    weights (:mod:`stereod.vision.row_disparity`), empty where not kept.
    """

    centroid_px: np.ndarray
    bbox_px: np.ndarray
    area_px: np.ndarray
    support: tuple[np.ndarray, ...] = ()
    rows: tuple[np.ndarray, ...] = ()

    def __len__(self) -> int:
        return int(self.area_px.shape[0])

    @staticmethod
    def empty() -> Blobs:
        """No blobs: one shared instance (its arrays are empty and read only)."""
        return _NO_BLOBS


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


_NO_BLOBS = Blobs(
    _frozen(np.zeros((0, 2))), _frozen(np.zeros((0, 4), np.int32)), _frozen(np.zeros(0, np.int32))
)


Editable = tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]
"""A blob set's centroids, boxes, areas, supports and row profiles, copied to edit."""


def editable(b: Blobs) -> Editable:
    """Copies of a blob set's fields, to replace some of its blobs in."""
    return b.centroid_px.copy(), b.bbox_px.copy(), b.area_px.copy(), list(b.support), list(b.rows)


def from_editable(fields: Editable) -> Blobs:
    """The blob set of edited fields."""
    centroid, bbox, area, support, rows = fields
    return Blobs(centroid, bbox, area, tuple(support), tuple(rows))


def groups(contours: Sequence[np.ndarray], gap: float) -> list[list[np.ndarray]]:
    """The outlines grouped into objects: two outlines whose boxes are closer than ``gap``
    times the smaller one's size (px) are pieces of one object (a stripe, a shadowed band as
    bright as the floor behind it, split it)."""
    n = len(contours)
    if n <= 1 or gap <= 0:
        return [[c] for c in contours]
    boxes = np.array([cv2.boundingRect(c) for c in contours], np.float64)
    x0, y0 = boxes[:, 0], boxes[:, 1]
    x1, y1 = x0 + boxes[:, 2], y0 + boxes[:, 3]
    size = np.maximum(boxes[:, 2], boxes[:, 3])
    gx = np.maximum(
        0.0, np.maximum(x0[:, None], x0[None, :]) - np.minimum(x1[:, None], x1[None, :])
    )
    gy = np.maximum(
        0.0, np.maximum(y0[:, None], y0[None, :]) - np.minimum(y1[:, None], y1[None, :])
    )
    near = np.maximum(gx, gy) <= gap * np.minimum(size[:, None], size[None, :])
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in zip(*np.nonzero(np.triu(near, 1)), strict=True):
        parent[root(int(i))] = root(int(j))
    groups: dict[int, list[np.ndarray]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(contours[i])
    return list(groups.values())
