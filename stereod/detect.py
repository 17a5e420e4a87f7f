"""Moving-object detection by background subtraction, paper sec. II, on OpenCV whole-array calls.

Per eye and per frame: luminance (eq. 2), absolute difference to a running-average background
(eq. 4's R), threshold at ``t`` (eq. 4's M), an optional small morphological opening (not in the
paper: it removes single-pixel sensor noise), connected components, and each component's centre
of gravity (eq. 5), bounding box and area. The background is then updated by eq. 3,
``T_i = T_{i-1} (1 - beta) + L_i beta``, kept in float32 (a uint8 background has a dead band of
0.5/beta grey levels and never adapts). The first ``warmup_frames`` frames are averaged into the
initial background the paper asks for; no blobs are reported during warm-up.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import cv2
import numpy as np

MAX_LABELS_16U = 65535
"""connectedComponents with 16-bit labels cannot hold more labels than this."""


class Centroid(str, enum.Enum):
    """How a blob's centre is computed."""

    BINARY = "binary"
    """Eq. 5 exactly: the mean position of the blob's foreground pixels."""
    COVERAGE = "coverage"
    """Eq. 5 with edge pixels weighted by how much of them the object covers (sub-pixel)."""


class Luminance(str, enum.Enum):
    """How a colour frame becomes the luminance matrix L of eq. 2."""

    BT601 = "bt601"
    """OpenCV's 0.299 R + 0.587 G + 0.114 B: what a YUYV camera's Y plane already is (free)."""
    MEAN = "mean"
    """The paper's exact eq. 2, (R + G + B) / 3."""


@dataclass(frozen=True, slots=True)
class DetectorParams:
    """Parameters of sec. II.

    ``beta``: background update coefficient of eq. 3, 0 <= beta << 1 (per frame).
    ``threshold``: t of eq. 4 in 8-bit grey levels (the paper's [0, 1] scale times 255).
    ``min_area_px``: smallest blob kept (px); smaller components are noise.
    ``warmup_frames``: frames averaged into the initial background before detecting.
    ``open_px``: side of the square opening kernel (px), 0 or 1 to disable.
    ``luminance``: eq. 2 exactly or the camera's luma; ``centroid``: eq. 5 exactly or weighted.
    ``max_foreground``: a frame whose foreground covers more than this share of the image is
    saturated (the lights changed, the camera moved): no blobs are reported from it, and after
    ``warmup_frames`` saturated frames in a row the background is learned afresh.
    """

    beta: float = 0.02
    threshold: float = 25.0
    min_area_px: int = 30
    warmup_frames: int = 10
    open_px: int = 3
    luminance: Luminance = Luminance.BT601
    centroid: Centroid = Centroid.COVERAGE
    max_foreground: float = 0.5


@dataclass(frozen=True, slots=True)
class Blobs:
    """Blobs of one frame as parallel arrays (n rows each).

    ``centroid_px`` (n, 2) float64 image x, y (eq. 5); ``bbox_px`` (n, 4) int32 x, y, w, h;
    ``area_px`` (n,) int32 pixel count.
    """

    centroid_px: np.ndarray
    bbox_px: np.ndarray
    area_px: np.ndarray

    def __len__(self) -> int:
        return int(self.area_px.shape[0])

    @staticmethod
    def empty() -> Blobs:
        return Blobs(np.zeros((0, 2)), np.zeros((0, 4), np.int32), np.zeros(0, np.int32))


_MEAN_RGB = np.full((1, 3), 1.0 / 3.0, dtype=np.float32)


def luminance(image: np.ndarray, mode: Luminance) -> np.ndarray:
    """Eq. 2: the (h, w) uint8 luminance of a (h, w) grey or (h, w, 3) BGR uint8 frame."""
    if image.ndim == 2:
        return image
    if mode is Luminance.MEAN:
        return cv2.transform(image, _MEAN_RGB)
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


class Detector:
    """Background-subtraction detector for one eye (stateful: it owns the background T)."""

    def __init__(self, params: DetectorParams) -> None:
        if not 0.0 <= params.beta < 1.0:
            raise ValueError(f"beta must be in [0, 1), got {params.beta}")
        self.params = params
        self._background: np.ndarray | None = None
        self._bg8: np.ndarray | None = None
        self._gray: np.ndarray | None = None
        self._seen = 0
        self._kernel = (
            cv2.getStructuringElement(cv2.MORPH_RECT, (params.open_px, params.open_px))
            if params.open_px > 1
            else None
        )
        self._thresh_u8 = float(math.ceil(params.threshold) - 1)
        """d >= t on integer grey levels is d > ceil(t) - 1 (THRESH_BINARY is strict)."""
        self.mask: np.ndarray | None = None
        """The last foreground bitmap M of eq. 4 (uint8, 0 or 255), for overlays and tests."""
        self.saturated = 0
        """Frames whose foreground covered more than ``max_foreground`` of the image (reported
        empty)."""
        self._saturated_run = 0

    @property
    def warming_up(self) -> bool:
        return self._seen < self.params.warmup_frames

    @property
    def background(self) -> np.ndarray | None:
        """The float32 background T (grey levels), ``None`` before the first frame."""
        return self._background

    def adopt(self, other: Detector) -> None:
        """Take over another detector's background (its parameters may differ)."""
        if other._background is not None:
            self._background = other._background.copy()
            self._seen = other._seen

    def reset(self) -> None:
        """Forget the background (after a lighting jump or a camera re-plug); the next frames
        are its warm-up again."""
        self._background = None
        self._seen = 0
        self._saturated_run = 0

    def detect(self, image: np.ndarray, update_mask: np.ndarray | None = None) -> Blobs:
        """Find moving blobs in one frame, then update the background (eq. 2-5).

        ``update_mask`` (h, w) uint8, non-zero where eq. 3 may update T; ``None`` updates all.
        """
        blobs = self.find(image)
        self.learn(update_mask)
        return blobs

    def find(self, image: np.ndarray) -> Blobs:
        """Eq. 2, 4 and 5 against the current background; call :meth:`learn` afterwards."""
        gray = luminance(image, self.params.luminance)
        self._gray = gray
        if self._background is None or self._background.shape != gray.shape:
            self._background = None
            self._seen = 0
            return Blobs.empty()
        if self.warming_up:
            return Blobs.empty()
        self._bg8 = cv2.convertScaleAbs(self._background, dst=self._bg8)
        diff = cv2.absdiff(gray, self._bg8)
        _, mask = cv2.threshold(diff, self._thresh_u8, 255, cv2.THRESH_BINARY)
        if self._kernel is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._kernel)
        self.mask = mask
        if cv2.countNonZero(mask) > self.params.max_foreground * mask.size:
            self.saturated += 1
            self._saturated_run += 1
            if self._saturated_run > self.params.warmup_frames:
                self.reset()  # the scene changed for good: learn it again
            return Blobs.empty()
        self._saturated_run = 0
        return self._components(mask, diff)

    def learn(self, update_mask: np.ndarray | None = None) -> None:
        """Eq. 3 with the frame last given to :meth:`find`: during warm-up a running mean (the
        initial background), then T = T (1 - beta) + L beta where ``update_mask`` allows."""
        gray = self._gray
        if gray is None:
            return
        self._gray = None
        if self._background is None:
            self._background = gray.astype(np.float32)
            self._seen = 1
        elif self.warming_up:
            self._seen += 1
            cv2.accumulateWeighted(gray, self._background, 1.0 / self._seen)
        else:
            cv2.accumulateWeighted(gray, self._background, self.params.beta, mask=update_mask)

    def _components(self, mask: np.ndarray, diff: np.ndarray) -> Blobs:
        if cv2.countNonZero(mask) >= MAX_LABELS_16U:
            n, labels, stats, centroids = cv2.connectedComponentsWithStats(
                mask, connectivity=8, ltype=cv2.CV_32S
            )
        else:
            n, labels, stats, centroids = cv2.connectedComponentsWithStats(
                mask, connectivity=8, ltype=cv2.CV_16U
            )
        if n <= 1:
            return Blobs.empty()
        keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= self.params.min_area_px) + 1
        stats = stats[keep]
        centre = centroids[keep].astype(np.float64)
        if self.params.centroid is Centroid.COVERAGE:
            for row, label in enumerate(keep):
                centre[row] = coverage_centroid(
                    labels, diff, int(label), stats[row, :4], self.params.threshold
                )
        return Blobs(
            centroid_px=centre,
            bbox_px=stats[:, :4].astype(np.int32),
            area_px=stats[:, cv2.CC_STAT_AREA].astype(np.int32),
        )


_RING = np.ones((3, 3), np.uint8)


def coverage_centroid(
    labels: np.ndarray, diff: np.ndarray, label: int, bbox: np.ndarray, threshold: float
) -> tuple[float, float]:
    """Sub-pixel centre of one blob (px): eq. 5 with eq. 4's hard threshold t softened into a
    ramp, each pixel of the blob grown by one pixel weighted (d - t/2) / t clipped to [0, 1].
    An edge pixel the object partly covers then counts in proportion instead of 0 or 1, which
    removes most of the binary centroid's quantisation error; the interior (d >= 1.5 t) weighs
    1, so neither shading inside the object nor the texture behind it pulls the centre."""
    h, w = labels.shape
    x, y, bw, bh = (int(v) for v in bbox)
    x0, y0 = max(x - 1, 0), max(y - 1, 0)
    x1, y1 = min(x + bw + 1, w), min(y + bh + 1, h)
    own = (labels[y0:y1, x0:x1] == label).astype(np.uint8)
    grown = cv2.dilate(own, _RING)
    d = diff[y0:y1, x0:x1].astype(np.float32)
    weight = np.clip((d - 0.5 * threshold) * (1.0 / threshold), 0.0, 1.0) * grown
    m = cv2.moments(weight)
    if m["m00"] <= 0:
        return (x + (bw - 1) / 2.0, y + (bh - 1) / 2.0)
    return (x0 + m["m10"] / m["m00"], y0 + m["m01"] / m["m00"])
