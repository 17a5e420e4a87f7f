"""A plain float numpy + scipy.ndimage implementation of paper sec. II.

It follows eq. 2-5 literally (float luminance in [0, 255], float background, d >= t) and exists to
check the fast OpenCV path in ``vision/detect.py`` and to benchmark against it. It needs scipy
(a development dependency) and is never used by the daemon.
"""

from __future__ import annotations

import numpy as np

from stereod.vision.blobs import Blobs
from stereod.vision.detect_params import DetectorParams, Luminance


class ReferenceDetector:
    """Eq. 2-5 on float64 arrays, with the parameters of :class:`stereod.vision.detect.Detector`."""

    def __init__(self, params: DetectorParams) -> None:
        from scipy import ndimage

        self._ndimage = ndimage
        self.params = params
        self._background: np.ndarray | None = None
        self._seen = 0

    def detect(self, image: np.ndarray) -> Blobs:
        """Find blobs in one frame, then update the background by eq. 3."""
        nd = self._ndimage
        p = self.params
        if image.ndim == 2:
            v = image.astype(np.float64)
        elif p.luminance is Luminance.MEAN:
            v = image.astype(np.float64).sum(axis=2) / 3.0
        else:
            b, g, r = (image[..., i].astype(np.float64) for i in range(3))
            v = 0.299 * r + 0.587 * g + 0.114 * b
        if self._background is None:
            self._background = v.copy()
            self._seen = 1
            return Blobs.empty()
        if self._seen < p.warmup_frames:
            self._seen += 1
            self._background += (v - self._background) / self._seen
            return Blobs.empty()
        d = np.abs(self._background - v)
        f = d >= p.threshold
        if p.open_px > 1:
            f = nd.binary_opening(f, structure=np.ones((p.open_px, p.open_px), bool))
        self._background = self._background * (1.0 - p.beta) + v * p.beta
        labels, n = nd.label(f, structure=np.ones((3, 3), bool))
        if n == 0:
            return Blobs.empty()
        idx = np.arange(1, n + 1)
        area = nd.sum_labels(np.ones_like(labels), labels, idx).astype(np.int32)
        cy, cx = np.asarray(nd.center_of_mass(f, labels, idx), dtype=np.float64).T
        slices = nd.find_objects(labels)
        bbox = np.array(
            [
                [s[1].start, s[0].start, s[1].stop - s[1].start, s[0].stop - s[0].start]
                for s in slices
            ],
            dtype=np.int32,
        )
        keep = area >= p.min_area_px
        return Blobs(np.stack([cx, cy], axis=1)[keep], bbox[keep], area[keep])
