"""The rows' median disparity against discs drawn at known sub-pixel positions."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereod.vision import row_disparity as rd
from stereod.vision.blobs import Blobs

SUB = 16  # supersampling of the drawn discs: coverage to 1/256 of a pixel


def disc_weight(cx: float, cy: float, r: float, shape: tuple[int, int]) -> np.ndarray:
    """A disc's coverage of each pixel (float32 0..1), pixel (x, y) centred on x, y."""
    h, w = shape
    ys, xs = np.mgrid[0 : h * SUB, 0 : w * SUB]
    inside = ((xs + 0.5) / SUB - 0.5 - cx) ** 2 + ((ys + 0.5) / SUB - 0.5 - cy) ** 2 <= r * r
    return inside.reshape(h, SUB, w, SUB).mean(axis=(1, 3)).astype(np.float32)


def centroid_x(prof: np.ndarray) -> float:
    return float(prof[:, 2].sum() / prof[:, 1].sum())


def test_profile_sums_to_the_weights_moments() -> None:
    rng = np.random.default_rng(3)
    weight = rng.random((17, 23)).astype(np.float32)
    prof = rd.profile(weight, 40, 7)
    m = cv2.moments(weight)
    assert prof[:, 0].tolist() == list(range(7, 24))
    assert prof[:, 1].sum() == pytest.approx(m["m00"], rel=1e-6)
    assert centroid_x(prof) == pytest.approx(40 + m["m10"] / m["m00"], abs=1e-5)


def test_a_crescent_in_one_eye_does_not_move_the_median() -> None:
    """Left: a disc at x 30.37; right: the same disc 11.62 px to the left plus a shadow's
    crescent under it, off to one side (what one eye takes in and the other does not). The
    centroids' disparity is off by far more than the rows' median's."""
    truth = 11.62
    shape = (60, 70)
    left = disc_weight(30.37, 25.2, 16.0, shape)
    right = disc_weight(30.37 - truth, 25.2, 16.0, shape)
    right[40:44, 18:34] = np.maximum(right[40:44, 18:34], 1.0)  # the crescent, 4 rows
    pl, pr = rd.profile(left, 0, 0), rd.profile(right, 0, 0)
    plain = centroid_x(pl) - centroid_x(pr)
    shift = rd.median_shift_px(pl, pr, 0)
    assert shift is not None
    assert abs(plain - truth) > 0.3
    assert plain + shift == pytest.approx(truth, abs=0.03)


def test_rows_are_paired_by_the_offset() -> None:
    """The right eye's disc sits 3 rows lower (seen later while the object falls)."""
    shape = (66, 70)
    left = disc_weight(35.0, 27.0, 19.0, shape)
    right = disc_weight(35.0 - 8.25, 30.0, 19.0, shape)
    right[47:50, 28:40] = 1.0
    pl, pr = rd.profile(left, 0, 0), rd.profile(right, 0, 0)
    shift = rd.median_shift_px(pl, pr, 3)
    assert shift is not None
    assert centroid_x(pl) - centroid_x(pr) + shift == pytest.approx(8.25, abs=0.03)


def test_too_few_rows_or_no_weight_gives_none() -> None:
    small = rd.profile(disc_weight(10.0, 10.0, 6.0, (24, 24)), 0, 0)
    assert rd.median_shift_px(small, small, 0) is None  # 12 rows: a disc fit's size
    big = rd.profile(disc_weight(30.0, 30.0, 20.0, (64, 64)), 0, 0)
    assert rd.median_shift_px(big, big, 0) == pytest.approx(0.0, abs=1e-9)
    assert rd.median_shift_px(big, big, 40) is None  # no rows in common
    assert rd.median_shift_px(big, rd.EMPTY, 0) is None


def test_merged_pieces_are_the_union_and_cut_keeps_rows() -> None:
    rng = np.random.default_rng(5)
    whole = rng.random((30, 20)).astype(np.float32)
    top, bottom = whole.copy(), whole.copy()
    top[12:], bottom[:12] = 0.0, 0.0
    pieces = [rd.profile(top[:12], 5, 9), rd.profile(bottom[8:], 5, 17)]  # rows 17-20 overlap
    got = rd.merged(pieces)
    want = rd.profile(whole, 5, 9)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-4)
    kept = rd.cut(want, 20, 25)
    assert kept[:, 0].tolist() == [20, 21, 22, 23, 24]
    moved = rd.moved(want, 3, -2)
    assert moved[:, 0].tolist() == (want[:, 0] - 2).tolist()
    assert centroid_x(moved) == pytest.approx(centroid_x(want) + 3)


def blobs_of(weights: list[tuple[np.ndarray, int, int]]) -> Blobs:
    """Blobs whose row profiles and centroids are those of ``weights`` placed at (x0, y0)."""
    profs = [rd.profile(w, x0, y0) for w, x0, y0 in weights]
    centres = []
    for w, x0, y0 in weights:
        m = cv2.moments(w)
        centres.append((x0 + m["m10"] / m["m00"], y0 + m["m01"] / m["m00"]))
    boxes = []
    for w, x0, y0 in weights:
        bx, by, bw, bh = cv2.boundingRect((w > 0.5).astype(np.uint8))
        boxes.append((x0 + bx, y0 + by, bw, bh))
    areas = [int(np.count_nonzero(w > 0.5)) for w, _, _ in weights]
    return Blobs(
        np.array(centres), np.array(boxes, np.int32), np.array(areas, np.int32), rows=tuple(profs)
    )


def test_rows_median_moves_only_pairs_that_disagree_beyond_the_noise() -> None:
    """Pair 0: a crescent in the right eye (the centroids 0.5 px off, the median right);
    pair 1: clean (a shift under the threshold leaves it); pair 2: touching the image's
    border (its rows are cut, so it is left)."""
    truth = 10.4
    disc = disc_weight(30.3, 30.0, 18.0, (62, 62))
    crescent = disc.copy()
    crescent[46:50, 14:30] = 1.0
    cut = disc_weight(30.3, 30.0, 18.0, (62, 62))
    cut[46:52, 10:34] = 1.0  # a larger crescent: this pair would move, but for the border
    lb = blobs_of([(disc, 100, 50), (disc, 300, 50), (disc[:, 13:], 0, 150)])
    shift = round(truth)  # the right eye's blobs truth px to the left: whole px + a sub-px part
    right = disc_weight(30.3 - (truth - shift), 30.0, 18.0, (62, 62))
    right_crescent = right.copy()
    right_crescent[46:50, 14:30] = 1.0
    right_cut = right.copy()
    right_cut[46:52, 10:34] = 1.0
    rb = blobs_of(
        [
            (right_crescent, 100 - shift, 50),
            (right, 300 - shift, 50),
            (right_cut[:, 13:], 0, 150),
        ]
    )
    idx = np.array([[0, 0], [1, 1], [2, 2]], np.intp)
    lpx, rpx = lb.centroid_px.copy(), rb.centroid_px.copy()
    before = lpx[:, 0] - rpx[:, 0]
    assert abs(before[0] - truth) > 0.3
    border = rd.median_shift_px(lb.rows[2], rb.rows[2], 0)
    assert border is not None and abs(border) > rd.SIGMAS * 0.15
    moved = rd.rows_median(lb, rb, idx, lpx, rpx, 0.15, (640, 480))
    after = lpx[:, 0] - rpx[:, 0]
    assert moved == 1
    assert after[0] == pytest.approx(truth, abs=0.03)
    assert lpx[0, 0] + rpx[0, 0] == pytest.approx(lb.centroid_px[0, 0] + rb.centroid_px[0, 0])
    assert after[1] == before[1] and after[2] == before[2]
    assert np.array_equal(lpx[:, 1], lb.centroid_px[:, 1])
    assert rd.rows_median(Blobs.empty(), rb, idx[:0], lpx[:0], rpx[:0], 0.15, (640, 480)) == 0


def test_a_crescent_at_either_end_with_vertical_motion_reads_the_truth() -> None:
    """The right eye sees the left's disc ``down`` rows lower (it moved between the eyes'
    instants) and 8.6 px to the left, with 5 rows of crescent under it or over it: that end
    moves 5 rows and the centroid about 2; the rows' median disparity is still the truth."""
    truth = 8.6
    disc = disc_weight(30.0, 30.0, 18.0, (62, 62))  # rows 12-48 covered more than half
    lb = blobs_of([(disc, 100, 40)])
    for down, crescent in ((2, slice(51, 56)), (7, slice(14, 19))):
        right = np.zeros((80, 62), np.float32)
        right[down : down + 62] = disc_weight(30.0 - 0.6, 30.0, 18.0, (62, 62))
        right[crescent, 12:28] = 1.0  # off to one side: it pulls the centroid sideways
        rb = blobs_of([(right, 92, 40)])
        offset = rd.row_offset(lb, rb, 0, 0)
        shift = rd.median_shift_px(lb.rows[0], rb.rows[0], offset)
        assert shift is not None
        plain = float(lb.centroid_px[0, 0] - rb.centroid_px[0, 0])
        assert abs(plain - truth) > 0.3
        assert plain + shift == pytest.approx(truth, abs=0.05), (down, offset)


def test_rows_lost_at_one_end_do_not_pair_rows_apart() -> None:
    """A slanted bar (its rows' centres 0.6 px further right each row down), 60 rows tall:
    the right eye lost its top 4 rows. Top rows are 4 apart, bottom rows 0, centroids about
    2: the rows pair as they are (0), and the rows' median disparity is the truth."""
    truth, h = 9.3, 60

    def bar(dx: float, rows: range) -> np.ndarray:
        w = np.zeros((h, 90), np.float32)
        for r in rows:
            w[r] = np.clip(np.arange(90) + 0.5 - (10 + dx + 0.6 * r), 0, 1) - np.clip(
                np.arange(90) + 0.5 - (30 + dx + 0.6 * r), 0, 1
            )
        return w

    lb = blobs_of([(bar(truth, range(h)), 0, 20)])
    rb = blobs_of([(bar(0.0, range(4, h)), 0, 20)])
    assert rd.row_offset(lb, rb, 0, 0) == 0
    shift = rd.median_shift_px(lb.rows[0], rb.rows[0], 0)
    assert shift is not None
    plain = float(lb.centroid_px[0, 0] - rb.centroid_px[0, 0])
    assert abs(plain - truth) > 1.0
    assert plain + shift == pytest.approx(truth, abs=0.05)


def turned(deg: float, dx: float, dy: float, scale: float = 1.0) -> rd.Rectify:
    """A rectification that turns image px by ``deg`` about (320, 240), scales and shifts
    them: a calibrated eye's, without its lens's distortion (a disc stays a disc)."""
    c, s = scale * np.cos(np.radians(deg)), scale * np.sin(np.radians(deg))

    def rectify(p: np.ndarray) -> np.ndarray:
        q = np.asarray(p, np.float64) - (320.0, 240.0)
        turned = np.column_stack((c * q[:, 0] - s * q[:, 1], s * q[:, 0] + c * q[:, 1]))
        return turned + np.array([320.0 + dx, 240.0 + dy])

    return rectify


def unturned(rectify: rd.Rectify, point: tuple[float, float]) -> tuple[float, float]:
    """The image px that ``rectify`` takes to ``point`` (its inverse, by fixed-point iteration:
    ``rectify`` is near a shift)."""
    p = np.array([point], np.float64)
    for _ in range(60):
        across = np.linalg.norm(rectify(p + np.array([1.0, 0.0])) - rectify(p))
        p = p - (rectify(p) - point) / across
    return float(p[0, 0]), float(p[0, 1])


@pytest.mark.parametrize(
    ("turn", "scale"),
    [((0.9, -0.7), 1.03), ((3.0, -2.5), 1.03), ((0.9, -0.7), 1.1)],
    ids=["minoru", "3 deg", "wide right eye"],
)
def test_a_calibrated_pair_reads_the_true_disparity(
    turn: tuple[float, float], scale: float
) -> None:
    """Each eye turned its own way and shifted (a Minoru's eyes are about a degree apart), the
    right eye's px ``scale`` times the left's in rectified px: the same disc at a known
    rectified disparity, the right eye with a shadow's crescent under it in its own image
    rows. The rows' median moves the rectified centroids to the truth, each eye by its half
    of the shift in its own px, in opposite directions."""
    rect_l, rect_r = turned(turn[0], 3.0, -2.0), turned(turn[1], -4.0, 1.5, scale)
    truth = 9.3
    centre = (352.4, 180.6)  # rectified px of the left disc's centre
    lx, ly = unturned(rect_l, centre)
    rx, ry = unturned(rect_r, (centre[0] - truth, centre[1]))
    x0l, y0l, x0r, y0r = int(lx) - 31, int(ly) - 31, int(rx) - 31, int(ry) - 31
    left = disc_weight(lx - x0l, ly - y0l, 20.0, (62, 62))
    right = disc_weight(rx - x0r, ry - y0r, 20.0 / scale, (62, 62))
    right[49:56, 16:33] = 1.0  # the crescent, in the right eye's image rows
    lb, rb = blobs_of([(left, x0l, y0l)]), blobs_of([(right, x0r, y0r)])
    idx = np.array([[0, 0]], np.intp)
    lpx, rpx = rect_l(lb.centroid_px), rect_r(rb.centroid_px)
    before = float(lpx[0, 0] - rpx[0, 0])
    assert abs(before - truth) > 0.3
    start = lpx.copy(), rpx.copy()
    assert rd.rows_median(lb, rb, idx, lpx, rpx, 0.15, (640, 480), (rect_l, rect_r)) == 1
    assert float(lpx[0, 0] - rpx[0, 0]) == pytest.approx(truth, abs=0.08)
    moved_l, moved_r = lpx[0, 0] - start[0][0, 0], rpx[0, 0] - start[1][0, 0]
    across = scale * np.cos(np.radians(turn[1])) / np.cos(np.radians(turn[0]))
    assert moved_l * moved_r < 0
    assert -moved_r / moved_l == pytest.approx(across, rel=1e-3)
    assert lpx[0, 1] == rect_l(lb.centroid_px)[0, 1]  # heights stay


def test_rows_steeper_than_the_limit_leave_the_centroids() -> None:
    """Eyes turned 12 deg each way about their axes: their image rows lie far from their
    rectified rows, and the pair keeps its centroids."""
    rect_l, rect_r = turned(12.0, 0.0, 0.0), turned(-12.0, 0.0, 0.0)
    disc = disc_weight(30.3, 30.0, 18.0, (62, 62))
    crescent = disc.copy()
    crescent[46:52, 14:32] = 1.0
    lb, rb = blobs_of([(disc, 300, 200)]), blobs_of([(crescent, 290, 200)])
    idx = np.array([[0, 0]], np.intp)
    lpx, rpx = rect_l(lb.centroid_px), rect_r(rb.centroid_px)
    before = lpx.copy(), rpx.copy()
    assert rd.rows_median(lb, rb, idx, lpx.copy(), rpx.copy(), 0.15, (640, 480)) == 1  # level
    assert rd.rows_median(lb, rb, idx, lpx, rpx, 0.15, (640, 480), (rect_l, rect_r)) == 0
    assert np.array_equal(lpx, before[0]) and np.array_equal(rpx, before[1])
