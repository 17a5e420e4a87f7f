"""Canonical stereo geometry (paper sec. III) and blob matching between the eyes.

Rig frame (design sec. 3): origin at the midpoint of the baseline, X to the right as the camera
sees, Y down, Z forward along the parallel optical axes; metres. The canonical rig has two
identical pinhole cameras at x = -B/2 (left) and x = +B/2 (right) with square pixels and the
principal point at the image centre ((w - 1) / 2, (h - 1) / 2) in OpenCV pixel coordinates.
"""

from __future__ import annotations

import bisect
import collections
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

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
