"""Calibrated stereo geometry (paper sec. IV, eq. 13-20): rectify centroids, then triangulate.

Only blob centroids are undistorted and rectified (``cv2.undistortPoints`` with R1/P1 and
R2/P2, eq. 20's M_L and M_R with the distortion of eq. 16 undone first), never whole frames:
8-32 us for a handful of points instead of milliseconds per frame. In rectified coordinates the
two eyes are a canonical pair again (same rows, parallel axes), so matching and triangulation
are those of eq. 9 with the rectified focal length, baseline and principal points. Points are
expressed in the rig frame: the rectified cameras' common orientation, origin at the midpoint
of the baseline.
"""

from __future__ import annotations

import cv2
import numpy as np

from stereod.vision.calibration import Calibration
from stereod.vision.geometry import Geometry
from stereod.vision.geometry.stereo import (
    Rectified,
    _grey,
    project_rectified,
    triangulate_rectified,
)


class CalibratedRig:
    """The geometry of one :class:`~stereod.vision.calibration.Calibration`."""

    geometry = Geometry.CALIBRATED

    def __init__(self, cal: Calibration) -> None:
        self.calibration = cal
        self.width_px, self.height_px = cal.image_size
        self._k1, self._d1 = cal.array("K1"), cal.array("D1")
        self._k2, self._d2 = cal.array("K2"), cal.array("D2")
        self._r1, self._r2 = cal.array("R1"), cal.array("R2")
        self._p1, self._p2 = cal.array("P1"), cal.array("P2")
        self.focal_px = float(self._p1[0, 0])
        self.baseline_m = float(-self._p2[0, 3] / self._p2[0, 0])
        self.cx_left_px = float(self._p1[0, 2])
        self.cx_right_px = float(self._p2[0, 2])
        self.cy_px = float(self._p1[1, 2])
        self.rectified = Rectified(
            self.focal_px, self.baseline_m, self.cx_left_px, self.cx_right_px, self.cy_px
        )
        """The rectified pair (:class:`~stereod.vision.geometry.stereo.Rectified`)."""
        self._map_cache: list[tuple[np.ndarray, np.ndarray] | None] = [None, None]
        self.margin_px = max(self.width_px, self.height_px) // 8
        if not self.baseline_m > 0:
            raise ValueError(
                f"calibration {cal.id}: rectified baseline {self.baseline_m:.4g} is not positive "
                "(left and right swapped?)"
            )

    @property
    def calibration_id(self) -> str | None:
        return self.calibration.id

    def _maps(self, left: bool) -> tuple[np.ndarray, np.ndarray]:
        """Rectification maps of one eye (rectified px -> image px), made on first use, over
        the rectified image and a margin of ``margin_px`` around it (a blob at a barrel-
        distorted image's corner reaches past the rectified frame): rectified (x, y) is at
        [y + margin, x + margin]."""
        key = 0 if left else 1
        if self._map_cache[key] is None:
            k, d, r, p = (
                (self._k1, self._d1, self._r1, self._p1)
                if left
                else (self._k2, self._d2, self._r2, self._p2)
            )
            m = self.margin_px
            shifted = np.array(p[:3, :3], dtype=np.float64, copy=True)
            shifted[0, 2] += m
            shifted[1, 2] += m
            size = (self.width_px + 2 * m, self.height_px + 2 * m)
            self._map_cache[key] = cv2.initUndistortRectifyMap(k, d, r, shifted, size, cv2.CV_32FC1)
        maps = self._map_cache[key]
        assert maps is not None
        return maps

    def _map_window(
        self, left: bool, x0: int, y0: int, x1: int, y1: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """The maps' window over rectified px [x0, x1) x [y0, y1), within the margin."""
        mx, my = self._maps(left)
        m = self.margin_px
        return mx[y0 + m : y1 + m, x0 + m : x1 + m], my[y0 + m : y1 + m, x0 + m : x1 + m]

    def rectified_patch(
        self, image: np.ndarray, left: bool, x0: int, y0: int, x1: int, y1: int
    ) -> np.ndarray:
        """The (y1 - y0, x1 - x0) uint8 grey patch of an eye's image over a rectified-px
        rectangle, resampled through the rectification (only that window)."""
        mx, my = self._map_window(left, x0, y0, x1, y1)
        patch = cv2.remap(image, mx, my, cv2.INTER_LINEAR)
        return _grey(patch)

    def rectified_support(
        self, left: bool, bbox: np.ndarray, support: np.ndarray
    ) -> tuple[tuple[int, int, int, int], np.ndarray]:
        """A blob's box (x, y, w, h) and (h, w) support mask in rectified px."""
        x, y, w, h = (int(v) for v in bbox)
        corners = np.array([[x, y], [x + w, y], [x, y + h], [x + w, y + h]], np.float64)
        rect = self.rectify_left(corners) if left else self.rectify_right(corners)
        rx0, ry0 = np.floor(rect.min(axis=0)).astype(int)
        rx1, ry1 = np.ceil(rect.max(axis=0)).astype(int)
        rx0, ry0 = max(int(rx0), 0), max(int(ry0), 0)
        rx1, ry1 = min(int(rx1), self.width_px), min(int(ry1), self.height_px)
        if rx1 <= rx0 or ry1 <= ry0:
            return (x, y, w, h), support
        mx, my = self._map_window(left, rx0, ry0, rx1, ry1)
        warped = cv2.remap(
            support,
            mx - np.float32(x),
            my - np.float32(y),
            cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        return (rx0, ry0, rx1 - rx0, ry1 - ry0), warped

    def rectified_silhouette(
        self, left: bool, bbox: np.ndarray, support: np.ndarray
    ) -> tuple[float, float, np.ndarray]:
        """A blob's outline in rectified px: its area (px), its width (px), and how far its
        centroid lies from its image centroid rectified as a point (px, (2,)). Lens distortion
        and rectification stretch an image by up to a fifth at a wide lens's corners, and
        bend it, so a large blob's centroid, rectified as a point, is off its rectified
        outline's centroid by a pixel at 100 px wide. The support is resampled bilinearly
        (coverage, not a nearest-pixel cut) over its rectified box only; a blob whose
        outline leaves the maps' margin keeps its image area, width and centroid."""
        x, y, w, h = (int(v) for v in bbox)
        m = cv2.moments(support, binaryImage=True)
        if m["m00"] <= 0.0:
            return 0.0, float(w), np.zeros(2)
        plain = (float(m["m00"]), float(w), np.zeros(2))
        image_centroid = np.array([[x + m["m10"] / m["m00"], y + m["m01"] / m["m00"]]])
        corners = np.array([[x, y], [x + w, y], [x, y + h], [x + w, y + h]], np.float64)
        rectify = self.rectify_left if left else self.rectify_right
        rect = rectify(corners)
        rx0, ry0 = (int(v) - 1 for v in np.floor(rect.min(axis=0)))
        rx1, ry1 = (int(v) + 2 for v in np.ceil(rect.max(axis=0)))
        margin = self.margin_px
        if min(rx0, ry0) < -margin or rx1 > self.width_px + margin or ry1 > self.height_px + margin:
            return plain
        mx, my = self._map_window(left, rx0, ry0, rx1, ry1)
        cover = cv2.remap(
            (support > 0).astype(np.float32),
            mx - np.float32(x),
            my - np.float32(y),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0.0,
        )
        r = cv2.moments(cover)
        if r["m00"] <= 0.0:
            return plain
        centroid = np.array([rx0 + r["m10"] / r["m00"], ry0 + r["m01"] / r["m00"]])
        width = float(np.count_nonzero(cover.max(axis=0) >= 0.5))
        return float(r["m00"]), width, centroid - rectify(image_centroid)[0]

    def _rectify(
        self, pts: np.ndarray, k: np.ndarray, d: np.ndarray, r: np.ndarray, p: np.ndarray
    ) -> np.ndarray:
        a = np.asarray(pts, dtype=np.float64).reshape(-1, 1, 2)
        if a.shape[0] == 0:
            return np.zeros((0, 2))
        return cv2.undistortPoints(a, k, d, R=r, P=p).reshape(-1, 2)

    def rectify_left(self, points_px: np.ndarray) -> np.ndarray:
        """(n, 2) left image points (px) to rectified left coordinates (px)."""
        return self._rectify(points_px, self._k1, self._d1, self._r1, self._p1)

    def rectify_right(self, points_px: np.ndarray) -> np.ndarray:
        """(n, 2) right image points (px) to rectified right coordinates (px)."""
        return self._rectify(points_px, self._k2, self._d2, self._r2, self._p2)

    def triangulate(
        self,
        left_px: np.ndarray,
        right_px: np.ndarray,
        sigma_px: float = 0.5,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(n, 2) rectified left and right points (px) to (n, 3) rig-frame points and their
        (n, 3, 3) covariance; depth sigma from the disparity (eq. 12's D^2 / (B f) per px);
        see :func:`stereod.vision.geometry.stereo.triangulate_rectified`."""
        return triangulate_rectified(
            left_px,
            right_px,
            focal_px=self.focal_px,
            baseline_m=self.baseline_m,
            cx_left_px=self.cx_left_px,
            cx_right_px=self.cx_right_px,
            cy_px=self.cy_px,
            sigma_px=sigma_px,
        )

    def principal_point_px(self, left: bool) -> tuple[float, float]:
        """(cx, cy) of one eye in rectified coordinates (px)."""
        return (self.cx_left_px if left else self.cx_right_px), self.cy_px

    def project_rectified(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rig-frame points (n, 3) m to rectified left and right px (n, 2), where the pipeline
        measures centroids (not the raw images: see :func:`stereod.view.overlay.project`)."""
        return project_rectified(
            points_m,
            focal_px=self.focal_px,
            baseline_m=self.baseline_m,
            cx_left_px=self.cx_left_px,
            cx_right_px=self.cx_right_px,
            cy_px=self.cy_px,
        )

    def depth_error_one_px_m(self, depth_m: np.ndarray | float) -> np.ndarray | float:
        """Depth change (m) for one pixel of disparity error, D^2 / (B f)."""
        return np.square(depth_m) / (self.baseline_m * self.focal_px)
