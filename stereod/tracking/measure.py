"""A matched pair of blobs measured for the tracker: its detection (the fastest image motion
it can have, whether an image edge cuts it), how much its depth changed since each eye last
saw it from its blobs' sizes (for skew compensation), how much its blobs should have grown by
its track's filter, and its observation from its triangulation (eq. 9, 12)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from stereod.tracking import kalman, skew
from stereod.tracking.track import Track
from stereod.tracking.types import Detection, Observation
from stereod.vision.blobs import Blobs
from stereod.vision.geometry.errors import cos_off_axis, cut_rows, touches_side
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.stereo import CanonicalRig
from stereod.vision.geometry.triangulate import Triangulated
from stereod.vision.grouping import EDGE_SIGMA_PX


def detections(
    lb: Blobs,
    rb: Blobs,
    idx: np.ndarray,
    lpx: np.ndarray,
    rpx: np.ndarray,
    rig: CanonicalRig | CalibratedRig,
    max_speed_mps: float,
    max_image_speed_wps: float,
    uncovered: Sequence[bool] | None = None,
) -> list[Detection]:
    """Matched blob pairs as the tracker's detections (rectified px), each with the fastest
    image motion it can have: ``max_speed_mps`` at its depth (f / Z = disparity / B pixels
    per metre), or the fastest image motion at all (``max_image_speed_wps`` image widths a
    second) when its disparity is too small to say (a skewed first sight of a fast object);
    ``uncovered``: which pairs are background a moved object uncovered (default: none)."""
    ceiling = max_image_speed_wps * rig.width_px
    out = []
    for k, (i, j) in enumerate(idx):
        d = float(lpx[k, 0] - rpx[k, 0])
        limit = min(max_speed_mps * d / rig.baseline_m, ceiling) if d >= 2 else ceiling
        out.append(
            Detection(
                left_px=lpx[k],
                right_px=rpx[k],
                left_bbox_px=lb.bbox_px[i],
                right_bbox_px=rb.bbox_px[j],
                area_px=int(min(lb.area_px[i], rb.area_px[j])),
                image_speed_pxps=limit,
                clipped=touches_side(lb.bbox_px[i], rig) or touches_side(rb.bbox_px[j], rig),
                cut=cut_rows(lb.bbox_px[i], rig) or cut_rows(rb.bbox_px[j], rig),
                uncovered=bool(uncovered[k]) if uncovered is not None else False,
            )
        )
    return out


def expected_growth(tr: Track | None, eye_times_ns: tuple[int, int]) -> tuple[float, float] | None:
    """How much a track's blob should have grown in each eye since that eye last saw it,
    as the log of the area ratio: 2 log(Z then / Z now), with Z at that eye's two instants
    (``eye_times_ns``, left and right) from the track's filter (so the eyes' skew is allowed
    for exactly, whatever it is); ``None`` for no track, or before the filter runs (a track's
    first two observations)."""
    if tr is None:
        return None
    if not tr.started:
        return None
    out: list[float] = []
    for history, t_now in (
        (tr.left_history, eye_times_ns[0]),
        (tr.right_history, eye_times_ns[1]),
    ):
        z_then = kalman.point_at(tr.kf, history[-1][0])[2]
        z_now = kalman.point_at(tr.kf, t_now)[2]
        if z_then <= 0 or z_now <= 0:
            return None
        out.append(2.0 * math.log(z_then / z_now))
    return out[0], out[1]


def depth_ratios(
    tr: Track | None,
    det: Detection,
    eye_times_ns: tuple[int, int],
    areas_px: tuple[int, int],
    rig: CanonicalRig | CalibratedRig,
    max_speed: float,
) -> tuple[float | None, float | None]:
    """How much a track's depth changed since each eye last saw it (Z now over Z then),
    from its blob's areas in that eye (``areas_px`` now, left and right), each seen at
    its angle off that eye's axis, and no faster than ``max_speed`` (m/s) from its last
    depth (:func:`stereod.tracking.skew.size_depth_ratio`); unknown for a new track (None),
    or when either blob is cut by the image's edge, now or then."""
    if tr is None:
        return None, None
    last = tr.last
    if last.clipped or det.clipped or last.cut or det.cut:
        return None, None
    z_then = float(last.position_m[2])
    out: list[float | None] = []
    for e, (then_px, now_px, area_then) in enumerate(
        ((last.left_px, det.left_px, last.left_area_px),
         (last.right_px, det.right_px, last.right_area_px))
    ):  # fmt: skip
        history = tr.right_history if e else tr.left_history
        dt_s = (eye_times_ns[e] - history[-1][0]) * 1e-9
        centre = rig.principal_point_px(e == 0)
        out.append(
            skew.size_depth_ratio(
                area_then,
                areas_px[e],
                cos_off_axis(then_px, centre, rig.focal_px),
                cos_off_axis(now_px, centre, rig.focal_px),
                max_speed * dt_s / z_then if z_then > 0 else math.inf,
            )
        )
    return out[0], out[1]


def apart_in_time(
    ob: Observation, skew_s: float, speed_sigma_mps: float, focal_px: float
) -> Observation:
    """An observation whose eyes' centroids are ``skew_s`` apart in time and could not be
    brought to one instant (a track's first sight, before its image motion is known): an
    object moving across the view at ``speed_sigma_mps`` (one sigma) moves in one eye's
    image by ``speed f / Z`` px a second before the other eye sees it, which is as much
    disparity error. Its covariance is widened along its ray by what that does to its
    position (P scales as 1/d: dP/dd = -P/d, eq. 9 and 12): at 2 m, 30 ms of skew at
    2 m/s reads Z within 2 m, not the 7 cm of its centroids alone."""
    z, d = float(ob.position_m[2]), float(ob.disparity_px)
    if skew_s == 0.0 or z <= 0.0 or d <= 0.0:
        return ob
    sigma_d = speed_sigma_mps * focal_px / z * abs(skew_s)
    ray = ob.position_m / d
    return dataclasses.replace(ob, cov_m2=ob.cov_m2 + np.outer(ray, ray) * sigma_d * sigma_d)


def observation(
    t: Triangulated,
    lb: Blobs,
    rb: Blobs,
    i: int,
    j: int,
    left_px: np.ndarray,
    right_px: np.ndarray,
    exact: bool,
    clipped: bool,
) -> Observation:
    """The tracker's observation of left blob ``i`` and right blob ``j``, matched at the
    rectified centroids ``left_px``, ``right_px`` and triangulated as ``t``; ``exact``: both
    eyes brought to one instant, ``clipped``: cut by one side of the image."""
    return Observation(
        position_m=t.position_m,
        cov_m2=t.cov_m2,
        left_px=left_px,
        right_px=right_px,
        left_image_px=lb.centroid_px[i],
        right_image_px=rb.centroid_px[j],
        left_bbox_px=lb.bbox_px[i],
        right_bbox_px=rb.bbox_px[j],
        left_area_px=int(lb.area_px[i]),
        right_area_px=int(rb.area_px[j]),
        disparity_px=t.disparity_px,
        size_m=t.size_m,
        exact=exact,
        clipped=clipped,
        cut=t.cut,
        depth_factor=t.depth_factor,
        edge_depth=t.edge_depth,
        row_gap_px=t.row_gap_px,
        extent_m=t.extent_m,
    )


EDGE_AGREES = 0.25
"""The most an edge's disparity may differ from what the filter expects (a share of that, and
at least ``EDGE_AGREES_PX``) to be the object's own: one much farther is the edge of what
joins it, reached across it (a near person in the middle of a wider far object's blob: both
sides are the far one's)."""
EDGE_AGREES_PX = 2.0

OUTLINE_SIGMA = 0.15
"""The sigma of a centre placed from an object's free edge by its own outline (a share of its
width): a walking person's swinging arms and legs move their silhouette's centroid within
their box by about this much from frame to frame."""


def outline_m(ob: Observation) -> tuple[float, float]:
    """How far an observation's silhouettes' centroid lies from their boxes' left and right
    edges (m at its depth, the mean of both eyes): what places its centre from one edge when
    the other edge is not its own (:func:`by_edge`)."""
    lx, _, lw, _ = (float(v) for v in ob.left_bbox_px)
    rx, _, rw, _ = (float(v) for v in ob.right_bbox_px)
    cl, cr = float(ob.left_image_px[0]), float(ob.right_image_px[0])
    metres_per_px = ob.size_m / max(0.5 * (lw + rw), 1.0)
    left = 0.5 * ((cl - lx) + (cr - rx)) * metres_per_px
    right = 0.5 * ((lx + lw - cl) + (rx + rw - cr)) * metres_per_px
    return left, right


def by_edge(
    ob: Observation,
    joined_right: bool,
    behind_px: float,
    outline: tuple[float, float] | None = None,
    expected_m: float | None = None,
) -> Observation:
    """An object seen in one blob with another behind it that joins it on one side (on its
    right, ``joined_right``, or its left), measured like one cut by the image's edge: its
    depth from the disparity of its outline's other side (one surface point for both eyes),
    so what shows of the other moves neither. An edge's disparity is the centroids' plus how
    much further from its centroid that edge lies in the left image than in the right. Near
    where the two cross, what shows of the one behind may be on one side in one eye and on the
    other in the other eye: an edge whose disparity is not larger than the other object's
    (``behind_px``) is not the front one's in both eyes, and the other side's is tried; with
    neither, the observation only says the object is there (clipped, no depth: the filter
    predicts). Of two edges that both may be its own, the one whose depth is nearer the depth
    its filter expects (``expected_m``, m) is, whatever side its prediction put the other on
    (as they cross, a prediction that lags puts it on the wrong side, and the other's edge
    taken for its own moves it further back). Its lateral position: with its own ``outline``
    (:func:`outline_m`, seen alone before), its centroid placed that far from its free edge
    in each eye, within ``OUTLINE_SIGMA`` of its width; without, anywhere across what is seen
    (the blend's centroid, with half the blob's width as sigma). The blend's centroid lags or
    leads the object by what shows of the other: taken loosely for a crossing's 0.6 s, the
    filter kept the velocity of a person's first three frames and lagged 0.2 m behind where
    they came out."""
    lx, _, lw, _ = (float(v) for v in ob.left_bbox_px)
    rx, _, rw, _ = (float(v) for v in ob.right_bbox_px)
    cl, cr = float(ob.left_image_px[0]), float(ob.right_image_px[0])
    sides = [
        (ob.disparity_px + (lx - cl) - (rx - cr), True),
        (ob.disparity_px + (lx + lw - cl) - (rx + rw - cr), False),
    ]
    if not joined_right:
        sides.reverse()
    mine = [(e, right) for e, right in sides if e > behind_px and e > 0]
    if expected_m is not None and expected_m > 0 and ob.position_m[2] > 0:
        # disparity is inverse depth: the edge nearest the expected depth's disparity, and
        # none that is far from it
        d_expected = ob.disparity_px * float(ob.position_m[2]) / ob.depth_factor / expected_m
        slack = max(EDGE_AGREES * d_expected, EDGE_AGREES_PX)
        mine = [side for side in mine if abs(side[0] - d_expected) <= slack]
        mine.sort(key=lambda side: abs(side[0] - d_expected))
    if not mine or ob.disparity_px <= 0:
        return dataclasses.replace(ob, clipped=True, edge_depth=False)
    edge, joined_right = mine[0]
    scale = ob.disparity_px / edge / ob.depth_factor  # Z along the same ray
    position = ob.position_m * scale
    z = float(position[2])
    cov = ob.cov_m2 * scale * scale
    metres_per_px = ob.size_m * scale / max(0.5 * (lw + rw), 1.0)
    shift = np.zeros(2)
    if outline is not None:
        from_free_m = outline[0] if joined_right else -outline[1]
        # the free edge in each eye, and the centroid that far from it (px)
        free_l, free_r = (lx, rx) if joined_right else (lx + lw, rx + rw)
        shift = np.array([free_l - cl, free_r - cr]) + from_free_m / metres_per_px
        position[0] += float(shift.mean()) * metres_per_px
        cov[0, 0] += (OUTLINE_SIGMA * (outline[0] + outline[1])) ** 2
    else:
        cov[0, 0] += (0.25 * (lw + rw) * metres_per_px) ** 2
    cov[2, 2] += (z / edge * EDGE_SIGMA_PX) ** 2
    moved = {}
    if outline is not None:
        dl, dr = np.array([shift[0], 0.0]), np.array([shift[1], 0.0])
        moved = {
            "left_px": ob.left_px + dl, "right_px": ob.right_px + dr,
            "left_image_px": ob.left_image_px + dl, "right_image_px": ob.right_image_px + dr,
        }  # fmt: skip
    return dataclasses.replace(
        ob, position_m=position, cov_m2=cov, disparity_px=edge, size_m=ob.size_m * scale,
        clipped=True, edge_depth=True, depth_factor=1.0, **moved,
    )  # fmt: skip
