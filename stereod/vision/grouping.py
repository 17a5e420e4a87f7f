"""Objects, not blobs: the matched blob pairs that stereo says are one physical object become
one detection (design sec. 11).

One eye's segmentation cuts a person into pieces (an arm that waves, a torso that stays, legs
that walk), and cuts them differently in the other eye. Each matched pair of blobs has a
disparity, so a depth: pieces whose depth ranges lie within ``disparity_margin_px`` of each
other and which lie close together in the image, within a box no larger than
``max_object_size_m`` at that depth, are one object. The object's blob in each eye is the union
of its pieces there, and its centre the area-weighted mean of theirs (eq. 5 over the union).
A blob left without a partner in one eye joins an object when it lies inside that object's rows
and, moved by the object's disparity, next to the object's pieces in the other eye: that is
what a piece segmented apart in one eye only looks like, and leaving it out would move that
eye's centroid alone, which is a depth error.

Everything here works on the few blobs of a frame, in Python floats and small masks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from stereod.vision import row_disparity
from stereod.vision.blobs import Blobs, Editable, editable, from_editable
from stereod.vision.geometry.matching import EDGE_TOLERANCE_PX

__all__ = ["GroupParams", "Grouped", "edge_disparity_px", "extent_m", "group_objects"]


@dataclass(frozen=True, slots=True)
class GroupParams:
    """How blob pairs are grouped into objects.

    ``enabled``: group at all (off: every matched pair is an object, as in the paper).
    ``max_object_size_m``: the largest object's width, height and depth (m): a standing
    person is about 1.8 m tall; two objects that together would be larger stay apart.
    ``max_gap_m``: pieces of one object lie at most this far apart in the image, measured in
    metres at their depth (m); two people side by side half a metre apart stay two.
    ``disparity_margin_px``: what two pieces' disparities may differ by beyond their own depth
    extents (px): segmentation noise of pieces a few tens of pixels wide. Twice that where a
    piece's outlines in the two eyes disagree by more than a segmentation's edge noise.
    """

    enabled: bool = True
    max_object_size_m: float = 2.0
    max_gap_m: float = 0.4
    disparity_margin_px: float = 0.5

    def __post_init__(self) -> None:
        for name in ("max_object_size_m", "max_gap_m", "disparity_margin_px"):
            value = getattr(self, name)
            if not 0 <= value < math.inf:
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")


@dataclass(frozen=True, slots=True)
class Grouped:
    """The blobs of both eyes with each object's pieces merged, and the objects' matches.

    ``left``/``right``: the objects' blobs first (``index`` k is object k in both eyes),
    then the blobs no object took; ``left_px``/``right_px`` (n, 2) the objects' rectified
    centroids; ``pieces`` how many matched pairs each object was made of.
    """

    left: Blobs
    right: Blobs
    index: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    pieces: tuple[int, ...]


_Box = tuple[float, float, float, float]
"""x0, y0, x1, y1 (rectified px, end exclusive)."""


def _rect_box(blobs: Blobs, i: int, rect_px: np.ndarray) -> _Box:
    """Blob ``i``'s box moved into rectified coordinates by the shift of its centroid (exact
    for the canonical rig; within a pixel or two of distortion across a blob otherwise)."""
    x, y, w, h = (float(v) for v in blobs.bbox_px[i])
    dx = float(rect_px[0]) - float(blobs.centroid_px[i, 0])
    dy = float(rect_px[1]) - float(blobs.centroid_px[i, 1])
    return (x + dx, y + dy, x + dx + w, y + dy + h)


def _union(a: _Box, b: _Box) -> _Box:
    return (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))


def _gap(a: _Box, b: _Box) -> float:
    """The distance (px) between two boxes, 0 when they touch or overlap."""
    dx = max(a[0] - b[2], b[0] - a[2], 0.0)
    dy = max(a[1] - b[3], b[1] - a[3], 0.0)
    return math.hypot(dx, dy)


@dataclass
class _Group:
    members: list[int]
    box: _Box
    """Union of the members' left boxes (rectified px)."""
    d_lo: float
    d_hi: float
    """The disparities (px) the members' depth extents span."""
    area: float
    lo_sure: bool
    hi_sure: bool
    """Whether the member that sets ``d_lo`` (``d_hi``) has outlines the two eyes agree on
    (:func:`_edge_disagreement` within ``EDGE_TOLERANCE_PX``): its disparity is as good as the
    segmentation's edges."""
    owners: frozenset[int] = frozenset()
    """The live tracks the members' pairs belong to (at most one: two tracks are two
    objects)."""


def group_objects(
    lb: Blobs,
    rb: Blobs,
    idx: np.ndarray,
    lpx: np.ndarray,
    rpx: np.ndarray,
    lrect: np.ndarray,
    rrect: np.ndarray,
    focal_px: float,
    baseline_m: float,
    params: GroupParams,
    owners: Sequence[int | None] | None = None,
    width_px: int | None = None,
) -> Grouped | None:
    """Merge the matched pairs ``idx`` (m, 2; rectified centroids ``lpx``/``rpx``) that are
    one object, and attach each eye's unmatched blobs (all rectified centroids ``lrect``/
    ``rrect``) that belong to one; ``None`` when nothing changes (the blobs stay as they are).
    ``focal_px`` and ``baseline_m`` turn a disparity into a depth (eq. 9: Z = f B / d).
    ``owners``: per matched pair, the live track it belongs to, if any: pairs that two
    tracks follow are two objects, whatever their depths (the disparities of two objects that
    cross, each moving its own way, are off by the eyes' skew until it is compensated).
    ``width_px``: the images' width, to tell the blobs that reach the image's sides (their
    side edges are the image's, not the object's) when pairing outlines one eye cut short."""
    if not params.enabled:
        return None
    cut = _cut_pairs(lb, rb, idx, lrect, rrect, width_px)
    if cut is not None:  # one eye's outline cut short where the other's goes on: its rows
        lb, rb, idx, lrect, rrect = cut
        lpx, rpx = lrect[idx[:, 0]], rrect[idx[:, 1]]
        owners = None if owners is None else [*owners, *[None] * (len(idx) - len(owners))]
    m = len(idx)
    if m == 0 or (cut is None and m == 1 and len(lb) == 1 and len(rb) == 1):
        return None
    fb = focal_px * baseline_m
    groups: list[_Group] = []
    for k in range(m):
        i = int(idx[k, 0])
        box = _rect_box(lb, i, lrect[i])
        d = float(lpx[k, 0] - rpx[k, 0])
        # As deep as it is wide: +-half its width, half * Z / f metres, which in disparity
        # (d / Z px per metre, eq. 9) is half * d / f px.
        half = max(0.5 * (box[2] - box[0]) * d / focal_px, 0.0)
        j = int(idx[k, 1])
        sure = _edge_disagreement(box, _rect_box(rb, j, rrect[j])) <= EDGE_TOLERANCE_PX
        owner = owners[k] if owners is not None else None
        groups.append(
            _Group(
                [k],
                box,
                d - half,
                d + half,
                float(lb.area_px[i]),
                sure,
                sure,
                frozenset() if owner is None else frozenset((owner,)),
            )
        )
    if m > 1:
        groups = _merge(groups, lpx, rpx, fb, focal_px, params)
    attached_l, attached_r = _attach(groups, lb, rb, idx, lrect, rrect, focal_px, fb, params)
    if cut is None and all(len(g.members) == 1 for g in groups) and not (attached_l or attached_r):
        return None
    return _build(groups, lb, rb, idx, lrect, rrect, attached_l, attached_r)


CUT_MIN_SHARE = 0.3
"""The least share of its taller outline's rows an outline cut short in one eye must keep to
be paired by the rows it shares (less: too little is left to place the object by)."""


def _cut_pairs(
    lb: Blobs,
    rb: Blobs,
    idx: np.ndarray,
    lrect: np.ndarray,
    rrect: np.ndarray,
    width_px: int | None,
) -> tuple[Blobs, Blobs, np.ndarray, np.ndarray, np.ndarray] | None:
    """Blobs left unmatched in both eyes that are one object whose outline one eye cut short
    at the top or the bottom (a person's legs as pale as the floor behind them in one eye and
    not in the other: the areas and centroid rows of the two disagree, and matching refuses
    them). Such a pair has one top (or bottom) row and left and right edges one disparity
    apart, within ``EDGE_TOLERANCE_PX``; the taller one is cut to the rows the shorter one
    spans (its support there: area, centroid and box anew), so both centroids are of one part
    of the object and their disparity is its depth. Returns both eyes' blobs with the taller
    ones cut, the matches with these pairs added, and the rectified centroids; None when there
    are none (or the blobs carry no support masks). A blob that reaches the image's side
    (``width_px``; without it, its left side only) takes no part: its side edge is the
    image's (the feet of a person walking in past it, paired so, made a track 0.5 m too
    near)."""
    if not lb.support or not rb.support or len(lb.support) != len(lb):
        return None
    if len(rb.support) != len(rb):
        return None
    right_side = width_px if width_px is not None else math.inf

    def inside(blobs: Blobs, i: int) -> bool:
        x, _, w, _ = (int(v) for v in blobs.bbox_px[i])
        return x > 0 and x + w < right_side

    paired_l, paired_r = set(idx[:, 0].tolist()), set(idx[:, 1].tolist())
    free_l = [i for i in range(len(lb)) if i not in paired_l and inside(lb, i)]
    free_r = [j for j in range(len(rb)) if j not in paired_r and inside(rb, j)]
    found: list[tuple[float, int, int]] = []
    for i in free_l:
        a = _rect_box(lb, i, lrect[i])
        for j in free_r:
            b = _rect_box(rb, j, rrect[j])
            d0, d1 = a[0] - b[0], a[2] - b[2]
            tol = EDGE_TOLERANCE_PX
            if min(d0, d1) <= 0 or abs(d0 - d1) > 2 * tol:
                continue  # not one object's sides one (positive) disparity apart
            top, bottom = abs(a[1] - b[1]) <= tol, abs(a[3] - b[3]) <= tol
            short, tall = sorted((a[3] - a[1], b[3] - b[1]))
            if top == bottom or short < CUT_MIN_SHARE * tall or tall - short <= 2 * tol:
                continue  # both ends agree (the matcher's to pair), or neither does
            found.append((abs(d0 - d1), i, j))
    if not found:
        return None
    out_l, out_r = editable(lb), editable(rb)
    rects = [lrect.copy(), rrect.copy()]
    pairs: list[list[int]] = []
    used_l: set[int] = set()
    used_r: set[int] = set()
    for _, i, j in sorted(found):
        if i in used_l or j in used_r:
            continue
        used_l.add(i)
        used_r.add(j)
        pairs.append([i, j])
        a, b = _rect_box(lb, i, lrect[i]), _rect_box(rb, j, rrect[j])
        e, k, keep = (1, j, a) if b[3] - b[1] > a[3] - a[1] else (0, i, b)
        blobs, rect = (rb, rrect) if e else (lb, lrect)
        dy = float(rect[k, 1]) - float(blobs.centroid_px[k, 1])
        _cut_rows(out_r if e else out_l, rects[e], blobs, k, keep[1] - dy, keep[3] - dy)
    matches = np.concatenate([idx.reshape(-1, 2), np.array(pairs, np.intp)]).astype(np.intp)
    return from_editable(out_l), from_editable(out_r), matches, rects[0], rects[1]


def _cut_rows(out: Editable, rect: np.ndarray, blobs: Blobs, k: int, y0: float, y1: float) -> None:
    """Replace blob ``k`` in ``out`` by its support within image rows ``y0``..``y1`` (end
    exclusive): its area, centroid (eq. 5 over what is left), box, mask and row profile; its
    rectified centroid in ``rect`` moves with its centroid."""
    x, y, _, h = (int(v) for v in blobs.bbox_px[k])
    r0 = min(max(int(round(y0)) - y, 0), h - 1)
    r1 = max(min(int(round(y1)) - y, h), r0 + 1)
    mask = blobs.support[k][r0:r1]
    mo = cv2.moments(mask, binaryImage=True)
    if mo["m00"] <= 0:
        return
    bx, by, bw, bh = cv2.boundingRect(mask)
    centre = np.array([x + mo["m10"] / mo["m00"], y + r0 + mo["m01"] / mo["m00"]])
    rect[k] += centre - blobs.centroid_px[k]
    centroid, bbox, area, support, rows = out
    centroid[k] = centre
    bbox[k] = (x + bx, y + r0 + by, bw, bh)
    area[k] = int(mo["m00"])
    support[k] = np.ascontiguousarray(mask[by : by + bh, bx : bx + bw])
    if rows:
        rows[k] = row_disparity.cut(rows[k], y + r0, y + r1)


def _merge(
    groups: list[_Group],
    lpx: np.ndarray,
    rpx: np.ndarray,
    fb: float,
    focal_px: float,
    params: GroupParams,
) -> list[_Group]:
    """Join groups pairwise, nearest in the image first, while the joined group still fits
    one object: disparity ranges at most ``disparity_margin_px`` apart (:func:`_depths_apart`),
    a gap of at most ``max_gap_m`` and a box of at most ``max_object_size_m`` each way, at the
    joined group's depth. Two 0.2 m balls side by side, 2.5 and 3.1 m from a Minoru at
    320x240 behind a 60 deg lens, are 1.29 px apart in disparity (eq. 9), 0.85 px beyond their
    own depths: two objects. Counted for each of them, the margin would have made them one."""
    while len(groups) > 1:
        best: tuple[float, int, int] | None = None
        for a in range(len(groups)):
            ga = groups[a]
            for b in range(a + 1, len(groups)):
                gb = groups[b]
                if _depths_apart(ga, gb, params.disparity_margin_px):
                    continue
                if len(ga.owners | gb.owners) > 1:
                    continue  # two tracks: two objects
                d = max(0.5 * (max(ga.d_lo, gb.d_lo) + min(ga.d_hi, gb.d_hi)), 1e-6)
                metres_per_px = fb / d / focal_px
                gap = _gap(ga.box, gb.box) * metres_per_px
                if gap > params.max_gap_m:
                    continue
                u = _union(ga.box, gb.box)
                size = max(u[2] - u[0], u[3] - u[1]) * metres_per_px
                if size > params.max_object_size_m:
                    continue
                zs = [fb / max(float(lpx[k, 0] - rpx[k, 0]), 1e-6) for k in ga.members + gb.members]
                if max(zs) - min(zs) > params.max_object_size_m:
                    continue
                if best is None or gap < best[0]:
                    best = (gap, a, b)
        if best is None:
            break
        _, a, b = best
        ga, gb = groups[a], groups[b]
        groups[a] = _Group(
            ga.members + gb.members,
            _union(ga.box, gb.box),
            min(ga.d_lo, gb.d_lo),
            max(ga.d_hi, gb.d_hi),
            ga.area + gb.area,
            _end_sure(ga.d_lo, ga.lo_sure, gb.d_lo, gb.lo_sure, min),
            _end_sure(ga.d_hi, ga.hi_sure, gb.d_hi, gb.hi_sure, max),
            ga.owners | gb.owners,
        )
        del groups[b]
    return groups


def _depths_apart(ga: _Group, gb: _Group, margin: float) -> bool:
    """Whether two groups' disparity ranges lie more than ``margin`` (px) apart: twice that
    where the member at either facing end has outlines the eyes disagree on (its disparity is
    that much less certain)."""
    if ga.d_hi < gb.d_lo:
        gap, sure = gb.d_lo - ga.d_hi, ga.hi_sure and gb.lo_sure
    elif gb.d_hi < ga.d_lo:
        gap, sure = ga.d_lo - gb.d_hi, gb.hi_sure and ga.lo_sure
    else:
        return False
    return gap > (margin if sure else 2.0 * margin)


def _end_sure(
    a: float, a_sure: bool, b: float, b_sure: bool, pick: Callable[[float, float], float]
) -> bool:
    """Whether the end ``pick`` (min or max) of two ranges' ends ``a`` and ``b`` is set by a
    member whose outlines agree (both, where they are equal)."""
    if a == b:
        return a_sure and b_sure
    return a_sure if pick(a, b) == a else b_sure


def _attach(
    groups: list[_Group],
    lb: Blobs,
    rb: Blobs,
    idx: np.ndarray,
    lrect: np.ndarray,
    rrect: np.ndarray,
    focal_px: float,
    fb: float,
    params: GroupParams,
) -> tuple[dict[int, int], dict[int, int]]:
    """Each eye's unmatched blobs that one group takes: blob -> group index. A blob joins the
    group it lies next to in its own eye (within ``max_gap_m``, the joined box within
    ``max_object_size_m``) if joining makes the group's boxes in the two eyes agree better
    (:func:`_mismatch`): the other eye saw that part too, inside a piece it did not cut
    apart."""
    out: tuple[dict[int, int], dict[int, int]] = ({}, {})
    if not groups:
        return out
    boxes = [[_own_box(g, lb, 0, idx, lrect), _own_box(g, rb, 1, idx, rrect)] for g in groups]
    for e, (blobs, rect) in enumerate(((lb, lrect), (rb, rrect))):
        matched = {int(i) for i in idx[:, e]}
        for i in range(len(blobs)):
            if i in matched:
                continue
            box = _rect_box(blobs, i, rect[i])
            best: tuple[float, int] | None = None
            for g, grp in enumerate(groups):
                d = 0.5 * (grp.d_lo + grp.d_hi)
                if d <= 0:
                    continue
                own, other = boxes[g][e], boxes[g][1 - e]
                u = _union(box, own)
                pair_now, pair_then = (own, other), (u, other)
                if e:
                    pair_now, pair_then = (other, own), (other, u)
                gain = _mismatch(*pair_now) - _mismatch(*pair_then)
                if gain < 1.0:
                    continue  # the other eye did not see this part on the object
                metres_per_px = fb / d / focal_px
                gap = _gap(box, own) * metres_per_px
                size = max(u[2] - u[0], u[3] - u[1]) * metres_per_px
                if gap > params.max_gap_m or size > params.max_object_size_m:
                    continue
                if best is None or -gain < best[0]:
                    best = (-gain, g)
            if best is not None:
                out[e][i] = best[1]
                g = best[1]
                boxes[g][e] = _union(box, boxes[g][e])
    return out


def _edge_terms(left: _Box, right: _Box) -> tuple[float, float, float]:
    """How far two eyes' boxes of one object disagree edge by edge (px): their left and right
    edges should be one disparity apart, their top and bottom rows equal (rectified)."""
    return (
        abs((left[0] - right[0]) - (left[2] - right[2])),
        abs(left[1] - right[1]),
        abs(left[3] - right[3]),
    )


def _edge_disagreement(left: _Box, right: _Box) -> float:
    """How far the worst edge of one object's outline in one eye is from where the other
    eye's puts it (px)."""
    return max(_edge_terms(left, right))


def _mismatch(left: _Box, right: _Box) -> float:
    """How much two eyes' boxes of one object disagree in all (px)."""
    return sum(_edge_terms(left, right))


def _overlap(a: _Box, b: _Box) -> float:
    """The area (px^2) two boxes share."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    return w * h if w > 0 and h > 0 else 0.0


def _own_box(grp: _Group, blobs: Blobs, e: int, idx: np.ndarray, rect: np.ndarray) -> _Box:
    """A group's box in eye ``e`` (rectified px) from its members there."""
    box: _Box | None = None
    for k in grp.members:
        i = int(idx[k, e])
        b = _rect_box(blobs, i, rect[i])
        box = b if box is None else _union(box, b)
    assert box is not None
    return box


def _merged(
    blobs: Blobs, members: list[int], rect: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray | None]:
    """One eye's blob of an object from its ``members``' blobs: image centroid (eq. 5 over the
    union: the area-weighted mean), rectified centroid, box (x, y, w, h), area and support."""
    areas = blobs.area_px[members].astype(np.float64)
    total = float(areas.sum())
    centre = (blobs.centroid_px[members] * areas[:, None]).sum(axis=0) / total
    rect_centre = (rect[members] * areas[:, None]).sum(axis=0) / total
    boxes = blobs.bbox_px[members]
    x0, y0 = int(boxes[:, 0].min()), int(boxes[:, 1].min())
    x1 = int((boxes[:, 0] + boxes[:, 2]).max())
    y1 = int((boxes[:, 1] + boxes[:, 3]).max())
    support = None
    if blobs.support:
        support = np.zeros((y1 - y0, x1 - x0), np.uint8)
        for i in members:
            x, y, w, h = (int(v) for v in blobs.bbox_px[i])
            roi = support[y - y0 : y - y0 + h, x - x0 : x - x0 + w]
            cv2.bitwise_or(roi, blobs.support[i], dst=roi)
    box = np.array([x0, y0, x1 - x0, y1 - y0], np.int32)
    return centre, rect_centre, box, int(round(total)), support


def _build(
    groups: list[_Group],
    lb: Blobs,
    rb: Blobs,
    idx: np.ndarray,
    lrect: np.ndarray,
    rrect: np.ndarray,
    attached_l: dict[int, int],
    attached_r: dict[int, int],
) -> Grouped:
    eyes: list[Blobs] = []
    rects: list[np.ndarray] = []
    for e, (blobs, rect, attached) in enumerate(((lb, lrect, attached_l), (rb, rrect, attached_r))):
        centres, rcentres, boxes, areas, supports, profiles = [], [], [], [], [], []
        used: set[int] = set()
        for g, grp in enumerate(groups):
            members = [int(idx[k, e]) for k in grp.members]
            members += [i for i, to in attached.items() if to == g]
            used.update(members)
            c, rc, box, area, support = _merged(blobs, members, rect)
            centres.append(c)
            rcentres.append(rc)
            boxes.append(box)
            areas.append(area)
            supports.append(support)
            if blobs.rows:
                profiles.append(row_disparity.merged([blobs.rows[i] for i in members]))
        for i in range(len(blobs)):
            if i not in used:
                centres.append(blobs.centroid_px[i])
                rcentres.append(rect[i])
                boxes.append(blobs.bbox_px[i])
                areas.append(int(blobs.area_px[i]))
                supports.append(blobs.support[i] if blobs.support else None)
                if blobs.rows:
                    profiles.append(blobs.rows[i])
        eyes.append(
            Blobs(
                centroid_px=np.asarray(centres, np.float64).reshape(-1, 2),
                bbox_px=np.asarray(boxes, np.int32).reshape(-1, 4),
                area_px=np.asarray(areas, np.int32),
                support=tuple(s for s in supports if s is not None)
                if all(s is not None for s in supports)
                else (),
                rows=tuple(profiles),
            )
        )
        rects.append(np.asarray(rcentres, np.float64).reshape(-1, 2))
    n = len(groups)
    index = np.stack([np.arange(n), np.arange(n)], axis=1).astype(np.intp)
    return Grouped(
        left=eyes[0],
        right=eyes[1],
        index=index,
        left_px=rects[0][:n].copy(),
        right_px=rects[1][:n].copy(),
        pieces=tuple(len(g.members) for g in groups),
    )


def extent_m(
    position_m: np.ndarray,
    left_bbox_px: np.ndarray,
    right_bbox_px: np.ndarray,
    left_centroid_px: np.ndarray,
    focal_px: float,
) -> tuple[np.ndarray, np.ndarray]:
    """An object's 3D box in the rig frame (min, max corners, m) around its centre
    ``position_m``: its width and height from its blobs' boxes (the wider eye's width; px)
    at its depth, placed as the left blob's box lies around its centroid, and as deep as it is
    wide (stereo sees only its front)."""
    z = float(position_m[2])
    s = z / focal_px  # metres per pixel at the object's depth
    x, y, w, h = (float(v) for v in left_bbox_px)
    w = max(w, float(right_bbox_px[2]))
    cx, cy = float(left_centroid_px[0]), float(left_centroid_px[1])
    left_m = (cx - x) * s
    top_m = (cy - y) * s
    lo = np.array([position_m[0] - left_m, position_m[1] - top_m, z - 0.5 * w * s])
    hi = np.array([lo[0] + w * s, lo[1] + h * s, z + 0.5 * w * s])
    return lo, hi


EDGE_SIGMA_PX = 1.0
"""The noise (px) of a disparity read between two outlines' edges: each edge is a whole pixel
of a segmentation, not an area's mean."""


def edge_disparity_px(
    left_bbox_px: np.ndarray,
    right_bbox_px: np.ndarray,
    left_shift_px: float,
    right_shift_px: float,
    width_px: int,
) -> float | None:
    """The disparity (px) of an object cut by one side of the image, read between its
    outlines' other sides: an object near the rig that reaches past the image's right edge
    shows each eye a different part of itself, so its centroids' disparity is off, but its
    left edge is one surface point seen by both eyes. The boxes are x, y, w, h image px;
    ``*_shift_px`` move an eye's x into the coordinates the centroids are triangulated in
    (rectified, at one instant). ``None`` when it is cut by neither side or by both (wider
    than the view: no edge is seen by both eyes), or the edges give no positive disparity."""
    lx, _, lw, _ = (int(v) for v in left_bbox_px)
    rx, _, rw, _ = (int(v) for v in right_bbox_px)
    cut_left = lx <= 0 or rx <= 0
    cut_right = lx + lw >= width_px or rx + rw >= width_px
    if cut_left == cut_right:
        return None
    if cut_right:
        d = (lx + left_shift_px) - (rx + right_shift_px)
    else:
        d = (lx + lw + left_shift_px) - (rx + rw + right_shift_px)
    return d if d > 0 else None
