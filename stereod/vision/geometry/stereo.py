"""Canonical stereo geometry (paper sec. III); blobs are matched between the eyes in
:mod:`stereod.vision.geometry.matching`.

Rig frame (design sec. 3): origin at the midpoint of the baseline, X to the right as the camera
sees, Y down, Z forward along the parallel optical axes; metres. The canonical rig has two
identical pinhole cameras at x = -B/2 (left) and x = +B/2 (right) with square pixels and the
principal point at the image centre ((w - 1) / 2, (h - 1) / 2) in OpenCV pixel coordinates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from stereod.vision.geometry import Geometry


@dataclass(frozen=True, slots=True)
class Rectified:
    """A rectified (canonical) stereo pair, rig frame at the midpoint of the baseline:
    ``focal_px``, ``baseline_m``, and the principal points (px). Its methods work on one
    point in Python floats: the pipeline handles a few objects one at a time, and numpy's
    per-call cost is most of the work on one point (eq. 9 and its covariance take 8 us so,
    100 us as arrays of one)."""

    focal_px: float
    baseline_m: float
    cx_left_px: float
    cx_right_px: float
    cy_px: float

    def triangulate(
        self, xl: float, yl: float, xr: float, yr: float, sigma_px: float
    ) -> tuple[tuple[float, float, float], Cov6]:
        """One matched pair of rectified points (px) to a rig-frame point (m) and its
        covariance (m^2) as its six distinct entries (xx, xy, xz, yy, yz, zz): eq. 9, X and Y
        from the mean of the two rays, the covariance propagated from an isotropic centroid
        error of ``sigma_px`` per coordinate per eye through the Jacobian of (X, Y, Z) in
        (x_L, x_R, y_L, y_R). A nil disparity gives an infinite point as IEEE arithmetic
        would, without an error."""
        f, b = self.focal_px, self.baseline_m
        ul, ur = xl - self.cx_left_px, xr - self.cx_right_px
        d = ul - ur
        z = _div(b * f, d)
        u = 0.5 * (ul + ur)
        v = 0.5 * (yl + yr) - self.cy_px
        dz = _div(-z, d)  # dZ/dx_L; dZ/dx_R = -dZ/dx_L
        half = 0.5 * z / f
        j00, j01 = half + u / f * dz, half - u / f * dz
        j10, j11 = v / f * dz, -v / f * dz
        s2 = sigma_px * sigma_px
        cov = (
            s2 * (j00 * j00 + j01 * j01),
            s2 * (j00 * j10 + j01 * j11),
            s2 * (j00 * dz - j01 * dz),
            s2 * (j10 * j10 + j11 * j11 + half * half + half * half),
            s2 * (j10 * dz - j11 * dz),
            s2 * (dz * dz + dz * dz),
        )
        return (u * z / f, v * z / f, z), cov

    def project(self, x: float, y: float, z: float, left: bool) -> tuple[float, float]:
        """A rig-frame point (m) to rectified px in one eye (each eye half the baseline
        from the origin): the inverse of :meth:`triangulate`."""
        f, half = self.focal_px, 0.5 * self.baseline_m
        if left:
            return _div(f * (x + half), z) + self.cx_left_px, _div(f * y, z) + self.cy_px
        return _div(f * (x - half), z) + self.cx_right_px, _div(f * y, z) + self.cy_px


def _div(a: float, b: float) -> float:
    """a / b as IEEE arithmetic (numpy's) has it: an infinity or NaN for b = 0, no error."""
    if b != 0.0:
        return a / b
    if a != a or a == 0.0:
        return math.nan
    return math.copysign(math.inf, a) * math.copysign(1.0, b)


def sym3(c: Sequence[float]) -> np.ndarray:
    """A symmetric (3, 3) matrix from its six distinct entries (xx, xy, xz, yy, yz, zz)."""
    xx, xy, xz, yy, yz, zz = c
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def _whole(v: object) -> bool:
    """Whether ``v`` is a whole number (an int, or a float with nothing after the point)."""
    if isinstance(v, bool):
        return False
    return isinstance(v, (int, np.integer)) or (isinstance(v, float) and v.is_integer())


@dataclass(frozen=True, slots=True)
class CanonicalRig:
    """Two parallel identical cameras ``baseline_m`` apart with horizontal field of view
    ``hfov_deg`` over ``width_px`` pixels (eq. 9's B, phi_0 and x_0)."""

    baseline_m: float
    hfov_deg: float
    width_px: int
    height_px: int
    focal_px: float = field(init=False, repr=False, compare=False)
    """f = x_0 / (2 tan(phi_0 / 2)) (px): eq. 9 is then D = B f / (x_L - x_R)."""
    cx_px: float = field(init=False, repr=False, compare=False)
    cy_px: float = field(init=False, repr=False, compare=False)
    rectified: Rectified = field(init=False, repr=False, compare=False)
    """The pair as :class:`Rectified` (it is rectified already)."""

    def __post_init__(self) -> None:
        if not 0 < self.baseline_m < math.inf:
            raise ValueError(f"baseline must be a finite number > 0 m, got {self.baseline_m}")
        if not 0 < self.hfov_deg < 180:
            raise ValueError(
                f"horizontal field of view must be in (0, 180) deg, got {self.hfov_deg}"
            )
        size = (self.width_px, self.height_px)
        if not all(_whole(v) for v in size):
            raise ValueError(f"image size must be whole pixels, got {size[0]}x{size[1]}")
        object.__setattr__(self, "width_px", int(self.width_px))
        object.__setattr__(self, "height_px", int(self.height_px))
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError(f"image size must be positive, got {self.width_px}x{self.height_px}")
        focal = self.width_px / (2.0 * math.tan(math.radians(self.hfov_deg) / 2.0))
        cx, cy = (self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0
        object.__setattr__(self, "focal_px", focal)
        object.__setattr__(self, "cx_px", cx)
        object.__setattr__(self, "cy_px", cy)
        object.__setattr__(self, "rectified", Rectified(focal, self.baseline_m, cx, cx, cy))

    def principal_point_px(self, left: bool) -> tuple[float, float]:
        """(cx, cy) of one eye (px; both eyes share it)."""
        return self.cx_px, self.cy_px

    @property
    def pixel_angle_rad(self) -> float:
        """Eq. 10: the angle of view of one pixel, delta phi = phi_0 / x_0 (rad)."""
        return math.radians(self.hfov_deg) / self.width_px

    def depth_error_one_px_m(self, depth_m: np.ndarray | float) -> np.ndarray | float:
        """Eq. 12: distance error of a one-pixel positioning error, D^2 / B tan(delta phi) (m)."""
        return np.square(depth_m) / self.baseline_m * math.tan(self.pixel_angle_rad)

    def project(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pinhole projection of (n, 3) rig-frame points (m) into left and right (n, 2) px."""
        return project_rectified(
            points_m,
            focal_px=self.focal_px,
            baseline_m=self.baseline_m,
            cx_left_px=self.cx_px,
            cx_right_px=self.cx_px,
            cy_px=self.cy_px,
        )

    def project_rectified(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rig-frame points (n, 3) m to rectified px (n, 2) per eye: :meth:`project` here."""
        return self.project(points_m)

    @property
    def calibration_id(self) -> str | None:
        return None

    geometry = Geometry.CANONICAL

    def rectify_left(self, points_px: np.ndarray) -> np.ndarray:
        """Image to rectified coordinates of the left eye: the identity for the canonical rig."""
        return np.asarray(points_px, dtype=np.float64).reshape(-1, 2)

    def rectify_right(self, points_px: np.ndarray) -> np.ndarray:
        """Image to rectified coordinates of the right eye: the identity here."""
        return np.asarray(points_px, dtype=np.float64).reshape(-1, 2)

    def rectified_patch(
        self, image: np.ndarray, left: bool, x0: int, y0: int, x1: int, y1: int
    ) -> np.ndarray:
        """The (y1 - y0, x1 - x0) uint8 grey patch of an eye's image over a rectified-px
        rectangle: a crop here, where rectified and image coordinates are one."""
        return _grey(image[y0:y1, x0:x1])

    def rectified_support(
        self, left: bool, bbox: np.ndarray, support: np.ndarray
    ) -> tuple[tuple[int, int, int, int], np.ndarray]:
        """A blob's box (x, y, w, h) and (h, w) support mask in rectified px: as they are."""
        x, y, w, h = (int(v) for v in bbox)
        return (x, y, w, h), support

    def rectified_silhouette(
        self, left: bool, bbox: np.ndarray, support: np.ndarray
    ) -> tuple[float, float, np.ndarray]:
        """A blob's area (px), width (px) and centroid offset (px, (2,)) in rectified px
        (see :meth:`stereod.vision.geometry.rectified.CalibratedRig.rectified_silhouette`): its own,
        and none, here."""
        return float(np.count_nonzero(support)), float(bbox[2]), np.zeros(2)

    def triangulate(
        self,
        left_px: np.ndarray,
        right_px: np.ndarray,
        sigma_px: float = 0.5,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Eq. 9 and the pinhole model: (n, 2) matched centroids (px) to (n, 3) points (m) and
        their (n, 3, 3) covariance (m^2); see :func:`triangulate_rectified`."""
        return triangulate_rectified(
            left_px,
            right_px,
            focal_px=self.focal_px,
            baseline_m=self.baseline_m,
            cx_left_px=self.cx_px,
            cx_right_px=self.cx_px,
            cy_px=self.cy_px,
            sigma_px=sigma_px,
        )


def _grey(patch: np.ndarray) -> np.ndarray:
    """A uint8 patch as one channel (BT.601 luma of a BGR patch)."""
    return cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY) if patch.ndim == 3 else patch


def project_rectified(
    points_m: np.ndarray,
    *,
    focal_px: float,
    baseline_m: float,
    cx_left_px: float,
    cx_right_px: float,
    cy_px: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) rig-frame points (m) to rectified left and right (n, 2) px: the inverse of
    :func:`triangulate_rectified` (each eye half the baseline from the origin), by
    :meth:`Rectified.project`."""
    r = Rectified(focal_px, baseline_m, cx_left_px, cx_right_px, cy_px)
    p = np.atleast_2d(np.asarray(points_m, dtype=np.float64)).tolist()
    left = np.array([r.project(x, y, z, True) for x, y, z in p], np.float64).reshape(-1, 2)
    right = np.array([r.project(x, y, z, False) for x, y, z in p], np.float64).reshape(-1, 2)
    return left, right


def triangulate_rectified(
    left_px: np.ndarray,
    right_px: np.ndarray,
    *,
    focal_px: float,
    baseline_m: float,
    cx_left_px: float,
    cx_right_px: float,
    cy_px: float,
    sigma_px: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate (n, 2) rectified left and right points (px) into the rig frame (m).

    Z = B f / d with d = (x_L - cx_L) - (x_R - cx_R) (eq. 9); X and Y from the mean of the two
    rays, shifted so the origin is the midpoint of the baseline. Returns the (n, 3) points and
    their (n, 3, 3) covariance (m^2), propagated from an isotropic centroid error of
    ``sigma_px`` per coordinate per eye through the Jacobian. A one-pixel disparity error moves
    Z by D^2 / (B f), the exact form of eq. 12's D^2 / B tan(delta phi). A nil disparity
    gives an infinite point (and a negative one a point behind the rig), without a warning:
    the caller decides what to do with it. Points that are silhouettes' centroids lie
    nearer than the object's centre: see :func:`silhouette_depth`. Each point is
    :meth:`Rectified.triangulate`'s.
    """
    r = Rectified(focal_px, baseline_m, cx_left_px, cx_right_px, cy_px)
    left = np.atleast_2d(np.asarray(left_px, dtype=np.float64)).tolist()
    right = np.atleast_2d(np.asarray(right_px, dtype=np.float64)).tolist()
    got = [
        r.triangulate(xl, yl, xr, yr, sigma_px)
        for (xl, yl), (xr, yr) in zip(left, right, strict=True)
    ]
    points = np.array([p for p, _ in got], np.float64).reshape(-1, 3)
    cov = np.array([sym3(c) for _, c in got], np.float64).reshape(-1, 3, 3)
    return points, cov


SILHOUETTE_Q_MAX = 0.05
"""The largest depth correction :func:`silhouette_depth_factor` makes, as a share of the
depth: a sphere of radius r at 4.6 r (a 10 cm ball at 46 cm). A flat object (a door, a
wall poster) needs none, and a large one seen near would otherwise be moved far."""


def silhouette_depth_factor(
    area_px: np.ndarray,
    x_norm: np.ndarray,
    y_norm: np.ndarray,
    focal_px: float,
    width_px: np.ndarray | None = None,
) -> np.ndarray:
    """How much deeper a convex object's centre lies than its silhouettes' centroids
    triangulate: a factor on Z, from the silhouette's area (rectified px), its width
    (rectified px, when known) and its direction (x, y) (normalised image coordinates, i.e.
    tangents off the optical axis).

    A sphere of radius r centred on (X, Y, Z) projects to an ellipse centred on
    (X, Y) / (Z - r^2 / Z), not on (X, Y) / Z: its near half looks the larger. Both eyes see
    the same Z, so both centroids are scaled alike; triangulation (eq. 9) then keeps X and Y
    and returns Z' = Z - r^2 / Z, a bias of a third of a centimetre for a ball of 7 cm radius
    at 1.6 m, the same at every resolution. The ellipse's semi-minor axis is q^(1/2) = r /
    (Z^2 - r^2)^(1/2) on the axis, and its area pi q / cos(theta) at theta off it, so q =
    area cos(theta) / (pi f^2) and Z = Z' (1 + q) exactly on the axis, to first order in q
    off it.

    An upright cylinder of radius r is nearly the same sideways, its silhouette about
    w = 2 f r (1 + x^2)^(1/2) / Z wide, and its area, taller than wide, would overstate q: so
    q is the smaller of the area's and (w / 2 f)^2. For a sphere that is the area's (its width
    is exactly 2 f q^(1/2) (1 + x^2)^(1/2)). The width's q is not divided by the 1 + x^2 its
    width gains off the axis: a cylinder's rims' near halves bulge too, and ray-cast, the
    division left 0.8-4.9 mm of a 7-12 mm shift beside the axis where this leaves 0.5-3.8 mm
    (0.9 mm on the axis: a 20 cm robot 30 cm tall at 1.5 m, 6 mm by its area, 7.5 mm
    uncorrected; above or below the axis its caps show, and 6 mm of 14 remain at 18 deg).
    Any other object is taken to be as deep as the smaller of its two
    cross-sections, up to ``SILHOUETTE_Q_MAX``.
    """
    area, x, y = (
        np.atleast_1d(np.asarray(a, np.float64)).tolist() for a in (area_px, x_norm, y_norm)
    )
    width = [None] * len(area) if width_px is None else np.atleast_1d(width_px).tolist()
    return np.array(
        [depth_factor(*args, focal_px) for args in zip(area, x, y, width, strict=True)], np.float64
    )


def depth_factor(
    area_px: float, x_norm: float, y_norm: float, width_px: float | None, focal_px: float
) -> float:
    """:func:`silhouette_depth_factor` of one silhouette (``width_px`` ``None``: unknown)."""
    cos_theta = 1.0 / math.sqrt(1.0 + x_norm * x_norm + y_norm * y_norm)
    q = area_px * cos_theta / (math.pi * focal_px * focal_px)
    if width_px is not None:
        half = 0.5 * width_px / focal_px
        if math.isnan(half) or half * half < q:  # numpy's minimum: a NaN of either wins
            q = half * half
    return 1.0 + min(q, SILHOUETTE_Q_MAX)


def silhouette_depth(
    points_m: np.ndarray,
    cov_m2: np.ndarray,
    area_px: np.ndarray,
    focal_px: float,
    width_px: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move (n, 3) points triangulated from silhouettes' centroids (m) to their objects'
    centres (:func:`centre_depth` of each): their (n, 3, 3) covariance (m^2) and k (n,) with
    them, from the silhouettes' mean area and width (n,) (rectified px)."""
    points = np.atleast_2d(np.asarray(points_m, np.float64)).tolist()
    covs = np.asarray(cov_m2, np.float64).reshape(-1, 3, 3)
    area = np.atleast_1d(np.asarray(area_px, np.float64)).tolist()
    width = [None] * len(area) if width_px is None else np.atleast_1d(width_px).tolist()
    got = [
        centre_depth(tuple(p), tuple(c[np.triu_indices(3)].tolist()), a, focal_px, w)
        for p, c, a, w in zip(points, covs, area, width, strict=True)
    ]
    return (
        np.array([p for p, _, _ in got], np.float64).reshape(-1, 3),
        np.array([sym3(c) for _, c, _ in got], np.float64).reshape(-1, 3, 3),
        np.array([k for _, _, k in got], np.float64),
    )


Cov6 = tuple[float, float, float, float, float, float]
"""A symmetric 3 x 3 covariance (m^2) as its six distinct entries (xx, xy, xz, yy, yz, zz)."""


def centre_depth(
    point_m: tuple[float, float, float],
    cov: Cov6,
    area_px: float,
    focal_px: float,
    width_px: float | None = None,
) -> tuple[tuple[float, float, float], Cov6, float]:
    """Move a point triangulated from silhouettes' centroids (m) to its object's centre: Z
    times :func:`silhouette_depth_factor`'s k, from the silhouettes' mean area and width
    (rectified px); X and Y need no correction. Returns the point, its covariance and k. The
    covariance scales with Z, and the depth's variance gains ((k - 1) Z / 2)^2: whether the
    object is as deep as it is wide is a guess (right for a ball or a column, a whole
    (k - 1) Z too far for a flat object), and the filter should weigh it as one."""
    x, y, z = point_m
    k = depth_factor(area_px, _div(x, z), _div(y, z), width_px, focal_px)
    xx, xy, xz, yy, yz, zz = cov
    extra = 0.5 * (k - 1.0) * z
    return (x, y, z * k), (xx, xy, xz * k, yy, yz * k, zz * k * k + extra * extra), k
