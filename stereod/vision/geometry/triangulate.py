"""One matched object's position in the rig frame: its two rectified centroids triangulated
(eq. 9) with a covariance from the centroid error (eq. 12), widened by the error models of
:mod:`stereod.vision.geometry.errors`, the instants a rolling shutter saw its blobs, and whether
the position can be used."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from stereod.vision.blobs import Blobs
from stereod.vision.geometry import Geometry
from stereod.vision.geometry.errors import Seen, cut_rows, row_error_px, segmentation_error_px
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.refine import RefineParams, refine_match
from stereod.vision.geometry.stereo import CanonicalRig, centre_depth, sym3
from stereod.vision.grouping import EDGE_SIGMA_PX, edge_disparity_px, extent_m


class Matched(NamedTuple):
    """One stereo pair's matched blobs (:meth:`stereod.pipeline.Pipeline._match`): each eye's
    blobs (grouped), the (left, right) indices of each match (``matches``) and its rectified
    centroids (px)."""

    left: Blobs
    right: Blobs
    matches: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray


@dataclass(frozen=True, slots=True)
class Triangulated:
    """One object's position (m, rig frame) and covariance (m^2), its disparity (px) and
    width (m), whether its rows are cut, how much its depth was moved from the silhouettes to
    its centre, whether its depth is its edges', its centroids' row gap (px, None when not
    used) and its extent about the position (m)."""

    position_m: np.ndarray
    cov_m2: np.ndarray
    disparity_px: float
    size_m: float
    cut: bool
    depth_factor: float
    edge_depth: bool
    row_gap_px: float | None
    extent_m: tuple[np.ndarray, np.ndarray] | None


def triangulate_object(
    rig: CanonicalRig | CalibratedRig,
    lb: Blobs,
    rb: Blobs,
    i: int,
    j: int,
    tri_left: np.ndarray,
    tri_right: np.ndarray,
    sigma_px: float,
    clipped: bool,
    before: Seen | None,
    growth: tuple[float, float] | None,
    one_instant: bool,
    *,
    silhouette_depth: bool,
    refined: bool,
    size_noise: float,
) -> Triangulated:
    """Left blob ``i`` and right blob ``j`` triangulated from the centroids ``tri_*``
    (rectified px, moved to one instant when skew is compensated; ``one_instant`` whether they
    are at one) with ``sigma_px`` of centroid error per axis, widened by how the eyes' outlines
    disagree since ``before`` (the track's last observation; ``growth`` how much its blob should
    have grown in each eye since, see :func:`segmentation_error_px`) and across the rows; an
    object ``clipped`` by one side of the image takes its depth from its other side's edges.
    ``silhouette_depth``: depth moved to the object's centre (:func:`centre_depth`);
    ``refined``: the right centroids were placed by appearance, not segmented."""
    width_px = 0.5 * (int(lb.bbox_px[i, 2]) + int(rb.bbox_px[j, 2]))
    area_l, area_r = float(lb.area_px[i]), float(rb.area_px[j])
    if rig.geometry is Geometry.CALIBRATED and lb.support and rb.support:
        # Outlines in rectified px: a distorted image's blob is stretched and bent.
        area_l, width_l, shift_l = rig.rectified_silhouette(True, lb.bbox_px[i], lb.support[i])
        area_r, width_r, shift_r = rig.rectified_silhouette(False, rb.bbox_px[j], rb.support[j])
        tri_left, tri_right = tri_left + shift_l, tri_right + shift_r
        width_px = 0.5 * (width_l + width_r)
    area = 0.5 * (area_l + area_r)
    sigma = sigma_px
    cut = cut_rows(lb.bbox_px[i], rig) or cut_rows(rb.bbox_px[j], rig)
    whole = not clipped and not cut
    if before is not None and whole and not before.clipped and not before.cut:
        seg = segmentation_error_px(
            lb, rb, i, j, before, width_px, (area_l, area_r), growth, size_noise=size_noise
        )
        sigma = math.hypot(sigma, seg)
    xl, yl = tri_left.tolist()
    xr, yr = tri_right.tolist()
    edge = None
    if clipped:  # cut by one side of the image: the depth from its other side's edges
        edge = edge_disparity_px(
            lb.bbox_px[i], rb.bbox_px[j], xl - float(lb.centroid_px[i, 0]),
            xr - float(rb.centroid_px[j, 0]), rig.width_px,
        )  # fmt: skip
        if edge is not None:
            mid = 0.5 * (xl + xr)
            xl, xr = mid + 0.5 * edge, mid - 0.5 * edge
            sigma = math.hypot(sigma, EDGE_SIGMA_PX)
    # The rows' gap says how the two segmentations disagree only where both centroids
    # are at one instant and segmented (not placed on one row by appearance matching).
    # An outline cut by the image's edge counts too: its gap is as much a sign that its
    # centroids are off, and the smaller of the gap and its change bounds what it adds.
    row_gap = yl - yr if one_instant and not refined else None
    if row_gap is not None and before is not None and before.row_gap_px is not None:
        sigma = math.hypot(sigma, row_error_px(row_gap, before.row_gap_px))
    point, cov = rig.rectified.triangulate(xl, yl, xr, yr, sigma)
    factor = 1.0
    if silhouette_depth and not cut and edge is None:
        point, cov, factor = centre_depth(point, cov, area, rig.focal_px, width_px)
    centre = np.array(point)
    cov_m2 = sym3(cov)
    if cut:  # its centre's height is anywhere within its cut box: half its height as sigma
        h_px = max(int(lb.bbox_px[i, 3]), int(rb.bbox_px[j, 3]))
        cov_m2[1, 1] += (0.5 * h_px * float(point[2]) / rig.focal_px) ** 2
    if edge is not None:  # its centre lies anywhere across what is seen of it
        cov_m2[0, 0] += (0.5 * width_px * float(point[2]) / rig.focal_px) ** 2
    extent = None
    if np.all(np.isfinite(centre)):  # (one that is not is refused by in_range)
        lo, hi = extent_m(centre, lb.bbox_px[i], rb.bbox_px[j], lb.centroid_px[i], rig.focal_px)
        extent = (lo - centre, hi - centre)
    return Triangulated(
        position_m=centre,
        cov_m2=cov_m2,
        disparity_px=float(tri_left[0] - tri_right[0]),
        size_m=float(width_px * point[2] / rig.focal_px),
        cut=cut,
        depth_factor=factor,
        edge_depth=edge is not None,
        row_gap_px=row_gap,
        extent_m=extent,
    )


def in_range(
    position_m: np.ndarray,
    cov_m2: np.ndarray,
    exact: bool,
    rig: CanonicalRig | CalibratedRig,
    min_disparity_px: float,
) -> bool:
    """Whether a triangulated position can be used: finite, and, once both eyes are
    brought to one instant (``exact``), in front of the rig and no further than the matcher's
    smallest disparity allows. Blobs are matched with room for the eyes' skew, so two
    views of one object at the same image position in both eyes (no parallax: far away,
    or not a stereo view at all) can be matched, and at one instant their disparity is
    nil or negative: such a position is at infinity or behind the rig, and would poison a
    track. (A track's first sight, not brought to one instant, only places it, and a fast
    object's may well lie behind the rig.) With skew compensation off every observation is
    taken as at one instant, so a fast object whose skewed disparity falls out of range
    is dropped for that pair rather than placed far off or behind the rig."""
    if not (np.all(np.isfinite(position_m)) and np.all(np.isfinite(cov_m2))):
        return False
    if not exact:
        return True
    far = rig.baseline_m * rig.focal_px / max(min_disparity_px, 1e-3)
    return 0.0 < float(position_m[2]) <= far


def blob_instants(
    lb: Blobs, rb: Blobs, idx: np.ndarray, eye_times_ns: tuple[int, int], line_ns: float
) -> list[tuple[int, int]]:
    """Each matched pair's capture instants (ns), left and right: its frame's instant plus
    its centroid's image row times the rolling shutter's time per row (``line_ns``, 0 for a
    global shutter)."""
    if line_ns <= 0.0:
        return [eye_times_ns] * len(idx)
    t_left, t_right = eye_times_ns
    line = line_ns
    return [
        (
            t_left + round(max(float(lb.centroid_px[i, 1]), 0.0) * line),
            t_right + round(max(float(rb.centroid_px[j, 1]), 0.0) * line),
        )
        for i, j in idx.tolist()
    ]


def refine_rights(
    rig: CanonicalRig | CalibratedRig,
    images: tuple[np.ndarray, np.ndarray],
    lb: Blobs,
    idx: np.ndarray,
    lpx: np.ndarray,
    rpx: np.ndarray,
    params: RefineParams,
) -> None:
    """Replace each right centroid in ``rpx`` (rectified px) by where the left blob's
    appearance is found in the right image of ``images`` (left, right) along its row
    (:mod:`stereod.vision.geometry.refine`), when it is found confidently."""
    size = (rig.width_px, rig.height_px)
    limg, rimg = images

    def left(x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        return rig.rectified_patch(limg, True, x0, y0, x1, y1)

    def right(x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        return rig.rectified_patch(rimg, False, x0, y0, x1, y1)

    for k, i in enumerate(idx[:, 0]):
        if not lb.support:
            return
        box, support = rig.rectified_support(True, lb.bbox_px[i], lb.support[i])
        rpx[k], _ = refine_match(left, right, size, box, support, lpx[k], rpx[k], params)
