"""Blob matching between the eyes: rows, disparity range, size, the box edges of a blob cut
by the image's side, and the row tolerance of tall blobs."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stereod.vision.agreement import eye_agreement
from stereod.vision.geometry.matching import MatchParams, box_edges, match_blobs, side_cut_edges
from stereod.vision.geometry.stereo import CanonicalRig

RIG = CanonicalRig(baseline_m=0.06, hfov_deg=60.0, width_px=640, height_px=480)


def test_matching_by_row_disparity_and_size() -> None:
    left = np.array([[300.0, 100.0], [200.0, 300.0], [500.0, 50.0]])
    right = np.array([[180.0, 301.0], [290.0, 100.5], [520.0, 50.0], [100.0, 100.0]])
    la = np.array([100, 400, 50])
    ra = np.array([380, 110, 50, 100])
    idx = match_blobs(left, la, right, ra, MatchParams(max_disparity_px=150))
    got = {(int(i), int(j)) for i, j in idx}
    # Blob 2 would need a negative disparity; right blob 3 is at 200 px, beyond the range.
    assert got == {(0, 1), (1, 0)}


def _walking_in(disparity_px: int, right_shift_px: int = 0) -> tuple[np.ndarray, ...]:
    """Each eye's one blob (OpenCV's centroid, area and box) of a flat figure at
    ``disparity_px`` walking in past the image's left side: a torso 50 px wide on rows 40-120
    over a leg 32 px wide on rows 120-200, both reaching 30 px beyond the side in the right
    eye (the right eye's rows moved down ``right_shift_px``, a pair that is not one object)."""
    out = []
    for x0, dy in ((-30 + disparity_px, 0), (-30, right_shift_px)):
        mask = np.zeros((RIG.height_px, RIG.width_px), np.uint8)
        mask[40 + dy : 120 + dy, max(x0, 0) : x0 + 50] = 255
        mask[120 + dy : 200 + dy, max(x0, 0) : x0 + 32] = 255
        n, _, stats, centroids = cv2.connectedComponentsWithStats(mask)
        assert n == 2
        out += [centroids[1:], stats[1:, cv2.CC_STAT_AREA], stats[1:, :4]]
    return tuple(out)


def test_a_blob_cut_by_the_images_side_is_matched_by_its_boxs_uncut_rows() -> None:
    """The left eye sees 12 px more of the figure than the right, most of it leg: its
    centroid lies 17 px lower, beyond the row tolerance, though both boxes span rows 40-200.
    Weighed by those rows (and its free right edge's 12 px disparity) the pair matches; a
    pair whose uncut rows differ by more than the tolerance still does not."""
    lc, la, lbox, rc, ra, rbox = _walking_in(12)
    assert abs(lc[0, 1] - rc[0, 1]) > MatchParams().row_tolerance_px
    assert len(match_blobs(lc, la, rc, ra, MatchParams())) == 0  # by centroids: no match
    edges = box_edges(RIG, lbox, True), box_edges(RIG, rbox, False)
    assert match_blobs(lc, la, rc, ra, MatchParams(), edges=edges).tolist() == [[0, 0]]
    # the free edge's disparity is the figure's: a range that excludes 12 px refuses it
    narrow = MatchParams(min_disparity_px=0.5, max_disparity_px=8.0)
    assert (lc[0, 0] - rc[0, 0]) < 8.0
    assert len(match_blobs(lc, la, rc, ra, narrow, edges=edges)) == 0
    lc, la, lbox, rc, ra, rbox = _walking_in(12, right_shift_px=10)
    edges = box_edges(RIG, lbox, True), box_edges(RIG, rbox, False)
    assert len(match_blobs(lc, la, rc, ra, MatchParams(), edges=edges)) == 0


def test_the_box_edges_are_made_only_where_a_blob_reaches_the_images_side() -> None:
    """Boxes clear of the left and right sides (one reaching the top) give no edges, and
    matching by centroids alone is what the edges would give; one box at the left side gives
    both eyes' :func:`box_edges`."""
    lc, la, lbox, rc, ra, rbox = _walking_in(12)
    inner = lbox + np.array([[5, 0, -10, 0]]), rbox + np.array([[5, 0, -10, 0]])
    assert side_cut_edges(RIG, *inner) is None
    edges = box_edges(RIG, inner[0], True), box_edges(RIG, inner[1], False)
    lc[0, 1] = rc[0, 1]
    plain = match_blobs(lc, la, rc, ra, MatchParams())
    assert plain.tolist() == match_blobs(lc, la, rc, ra, MatchParams(), edges=edges).tolist()
    got = side_cut_edges(RIG, lbox, rbox)
    assert got is not None
    np.testing.assert_array_equal(got[0], box_edges(RIG, lbox, True))
    np.testing.assert_array_equal(got[1], box_edges(RIG, rbox, False))


def test_matching_uses_each_blob_once_and_prefers_the_closer_row() -> None:
    left = np.array([[300.0, 100.0], [310.0, 103.0]])
    right = np.array([[250.0, 103.0]])
    idx = match_blobs(left, np.array([100, 100]), right, np.array([100]), MatchParams())
    assert idx.tolist() == [[1, 0]]


def test_an_ambiguous_blob_takes_the_partner_that_looks_like_it() -> None:
    """A robot pushed a box: each eye sees the box at its new place and the floor it uncovered,
    all four blobs on one row and about one size. By size the uncovered floor on the left
    (blob 0) pairs best with the box on the right (blob 0), 157 px apart, a point 0.16 m from
    the rig; the two eyes' images say it is the other right blob."""
    rng = np.random.default_rng(5)
    floor = rng.integers(0, 256, (46, 67), np.uint8)
    box = rng.integers(0, 256, (46, 67), np.uint8)
    left_img, right_img = np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.uint8)
    left_img[161:207, 205:272], left_img[161:207, 63:130] = floor, box
    right_img[161:207, 192:259], right_img[161:207, 48:115] = floor, box
    lbox = np.array([[205, 161, 67, 46], [63, 161, 67, 46]])
    rbox = np.array([[48, 161, 67, 46], [192, 161, 64, 46]])  # the floor cut by 3 px
    centre = lambda b: b[:, :2] + b[:, 2:] / 2.0  # noqa: E731
    area = lambda b: b[:, 2] * b[:, 3]  # noqa: E731
    args = (centre(lbox), area(lbox), centre(rbox), area(rbox), MatchParams())
    assert match_blobs(*args).tolist() == [[0, 0]]  # by size and row alone

    def agree(i: int, j: int) -> float:
        return eye_agreement(left_img, right_img, lbox[i], rbox[j])

    assert sorted(match_blobs(*args, agreement=agree).tolist()) == [[0, 1], [1, 0]]


def test_a_tall_blob_whose_bottom_one_eye_adds_to_still_matches() -> None:
    """A ball 75 px tall at 640x480 whose contact shadow's crescent one eye segments with it
    (8 rows more below and 9 px wider, its centroid 6.4 px lower, beyond the 6 px tolerance;
    both tops on one row): paired once the tolerance is a tenth of the shorter blob's height
    (7.5 px). Not paired so: blobs under 60 px tall, whose tolerance stays 6 px; blobs whose
    tops and bottoms both disagree (two objects, not one end cut differently); an outline
    cut short at one end whose sides agree (grouping pairs it by the rows both show); a blob
    that reaches the image's top, bottom or side (its end there is the image's)."""
    left, right = np.array([[300.0, 392.1]]), np.array([[270.0, 385.7]])
    la, ra = np.array([5830]), np.array([4630])
    p = MatchParams()

    def matched(lbox: list[int], rbox: list[int], params: MatchParams = p) -> bool:
        lb, rb = np.array([lbox]), np.array([rbox])
        edges = side_cut_edges(RIG, lb, rb, params, (left, right))
        hs = lb[:, 3], rb[:, 3]
        return len(match_blobs(left, la, right, ra, params, edges=edges, heights=hs)) == 1

    assert len(match_blobs(left, la, right, ra, p)) == 0  # by centroids alone
    assert p.tall_px == 60.0
    short = np.array([[256, 348, 87, 59]]), np.array([[226, 348, 78, 59]])
    assert side_cut_edges(RIG, *short, p, (left, right)) is None
    tall = np.array([[256, 348, 87, 83]]), np.array([[226, 348, 78, 75]])
    assert side_cut_edges(RIG, *tall, p, (left, right)) is not None
    within = left, right + np.array([[0.0, 6.0]])  # a partner within the tolerance
    assert side_cut_edges(RIG, *tall, p, within) is None
    assert matched([256, 348, 87, 83], [230, 348, 78, 75])
    assert matched([256, 340, 87, 83], [230, 348, 78, 75])  # the bottoms agree instead
    assert not matched([256, 348, 87, 83], [230, 348, 78, 75], MatchParams(row_tolerance_share=0))
    assert not matched([256, 348, 87, 59], [230, 348, 78, 59])
    assert not matched([256, 340, 87, 83], [230, 350, 78, 60])
    assert not matched([256, 348, 87, 83], [226, 348, 87, 75])  # sides one disparity apart
    assert not matched([256, 397, 87, 83], [230, 397, 78, 83])  # bottom at row 480
    assert not matched([256, 397, 87, 83], [230, 397, 78, 75])  # the left one's
    assert not matched([0, 348, 87, 83], [0, 348, 78, 75])  # at the image's left side


def test_a_row_tolerance_of_zero_is_refused() -> None:
    with pytest.raises(ValueError, match="row tolerance must be > 0 px"):
        MatchParams(row_tolerance_px=0.0)
    with pytest.raises(ValueError, match=r"row tolerance share must be in \[0, 1\)"):
        MatchParams(row_tolerance_share=1.0)
    with pytest.raises(ValueError, match=r"max_disparity_px \(5\) must be larger than"):
        MatchParams(min_disparity_px=10.0, max_disparity_px=5.0)


def test_matching_rejects_very_different_sizes() -> None:
    idx = match_blobs(
        np.array([[300.0, 100.0]]),
        np.array([1000]),
        np.array([[250.0, 100.0]]),
        np.array([100]),
        MatchParams(max_area_ratio=2.0),
    )
    assert idx.shape == (0, 2)


def _every_pair_matched(
    left: np.ndarray,
    la: np.ndarray,
    right: np.ndarray,
    ra: np.ndarray,
    p: MatchParams,
    slack: float,
    boxes: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[tuple[int, int]]:
    """The matching rule on every pair of blobs, without the bisection on rows: the
    reference for :func:`match_blobs`. ``boxes``: each eye's blobs' (x0, x1, y0, y1) px, NaN
    where the image's top or bottom cuts one, for the tolerance of tall blobs: one object
    whose top or bottom two segmentations cut apart has one end on one row in both eyes, and
    at least one side further than its disparity."""
    found = []
    tol = p.row_tolerance_px
    for i in range(len(left)):
        for j in range(len(right)):
            gate = tol
            if boxes is not None:
                (lx0, lx1, lt, lb), (rx0, rx1, rt, rb) = boxes[0][i], boxes[1][j]
                one_end = abs(lt - rt) <= tol or abs(lb - rb) <= tol  # False with a NaN
                d0, d1 = lx0 - rx0, lx1 - rx1
                sides = min(d0, d1) > 0 and abs(d0 - d1) <= 4.0
                if one_end and not sides and not np.isnan([lt, lb, rt, rb]).any():
                    gate = max(tol, p.row_tolerance_share * min(lb - lt, rb - rt))
            dy = abs(left[i, 1] - right[j, 1])
            disp = left[i, 0] - right[j, 0]
            ratio = abs(math.log(max(la[i], 1) / max(ra[j], 1)))
            if (
                dy <= gate
                and p.min_disparity_px - slack <= disp <= p.max_disparity_px + slack
                and ratio <= math.log(p.max_area_ratio)
            ):
                out = max(p.min_disparity_px - disp, 0.0) + max(disp - p.max_disparity_px, 0.0)
                cost = dy / tol + ratio + (out / slack if slack > 0 else 0.0)
                found.append((cost, i, j))
    used_l, used_r, pairs = set(), set(), []
    for _, i, j in sorted(found):
        if i not in used_l and j not in used_r:
            used_l.add(i)
            used_r.add(j)
            pairs.append((i, j))
    return pairs


@given(
    st.integers(0, 40),
    st.integers(0, 40),
    st.integers(0, 2**32 - 1),
    st.sampled_from([0.0, 3.0]),
    st.sampled_from([2.0, 6.0, 400.0]),
    st.booleans(),
)
def test_matching_looks_at_every_pair_that_can_match(
    nl: int, nr: int, seed: int, slack: float, tolerance: float, tall: bool
) -> None:
    """Blobs on a few rows (many within one tolerance, some exactly on its edge, some not a
    number), with boxes whose heights widen some pairs' tolerance (``tall``): the pairs found
    by bisection on the rows are those of the rule applied to every pair."""
    rng = np.random.default_rng(seed)
    rows = rng.choice([10.0, 12.0, 16.0, 100.0, 103.5, 240.0, np.nan], size=nl + nr)
    left = np.stack([rng.uniform(0, 640, nl), rows[:nl] + rng.choice([0.0, 0.5], nl)], 1)
    right = np.stack([rng.uniform(0, 640, nr), rows[nl:]], 1)
    la, ra = rng.integers(0, 400, nl), rng.integers(0, 400, nr)
    p = MatchParams(row_tolerance_px=tolerance, max_disparity_px=150.0)
    edges = heights = None
    if tall:  # boxes clear of the image's sides, some reaching its top or bottom (NaN)

        def boxes(n: int) -> tuple[np.ndarray, np.ndarray]:
            x0 = rng.choice([10.0, 14.0, 30.0], n)
            x1 = x0 + rng.choice([20.0, 24.0, 60.0], n)
            top = rng.choice([np.nan, 50.0, 52.0, 90.0], n)
            height = rng.choice([5.0, 40.0, 60.0, 160.0], n)
            bottom = top + height
            bottom[rng.random(n) < 0.2] = np.nan
            return np.stack([x0, x1, top, bottom], 1), height

        (lbox, lh), (rbox, rh) = boxes(nl), boxes(nr)
        edges, heights = (lbox, rbox), (lh, rh)
    got = match_blobs(
        left.reshape(-1, 2), la, right.reshape(-1, 2), ra, p, slack, edges=edges, heights=heights
    )
    want = _every_pair_matched(left, la, right, ra, p, slack, edges)
    assert [tuple(r) for r in got.tolist()] == want
