"""Canonical geometry (eq. 9, 10, 12) and blob matching."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stereod.vision.agreement import eye_agreement
from stereod.vision.geometry.stereo import (
    SILHOUETTE_Q_MAX,
    CanonicalRig,
    MatchParams,
    box_edges,
    match_blobs,
    side_cut_edges,
    silhouette_depth,
    silhouette_depth_factor,
)

RIG = CanonicalRig(baseline_m=0.06, hfov_deg=60.0, width_px=640, height_px=480)


def test_focal_length_from_field_of_view() -> None:
    # A point at the edge of the field of view projects to the image edge.
    z = 2.0
    x_edge = z * math.tan(math.radians(30.0))
    left, _ = CanonicalRig(0.06, 60.0, 640, 480).project(np.array([[x_edge - 0.03, 0.0, z]]))
    assert left[0, 0] == pytest.approx(RIG.cx_px + 320.0)


def test_eq9_recovers_projected_points() -> None:
    rng = np.random.default_rng(0)
    pts = np.column_stack(
        [rng.uniform(-1, 1, 200), rng.uniform(-0.5, 0.5, 200), rng.uniform(0.5, 6, 200)]
    )
    left, right = RIG.project(pts)
    got, _ = RIG.triangulate(left, right)
    np.testing.assert_allclose(got, pts, atol=1e-9)
    # Eq. 9 verbatim: D = B x0 / (2 tan(phi0 / 2) (xL - xR)).
    d_eq9 = 0.06 * 640 / (2 * math.tan(math.radians(30)) * (left[:, 0] - right[:, 0]))
    np.testing.assert_allclose(got[:, 2], d_eq9, rtol=1e-12)


def test_eq12_one_pixel_error() -> None:
    d = np.array([0.5, 1.0, 2.0, 4.0])
    expected = d**2 / 0.06 * math.tan(math.radians(60) / 640)  # eq. 10 and 12
    np.testing.assert_allclose(RIG.depth_error_one_px_m(d), expected)
    # To first order a one-pixel disparity error moves Z by D^2 / (B f); eq. 12 uses the angle of
    # one pixel, phi0 / x0, in place of 1 / f = 2 tan(phi0 / 2) / x0, a ratio fixed by the lens.
    phi0 = math.radians(60)
    ratio = math.tan(phi0 / 640) * RIG.focal_px
    assert ratio == pytest.approx(phi0 / 2 / math.tan(phi0 / 2), rel=1e-5)
    for z in d:
        disp = RIG.baseline_m * RIG.focal_px / z
        exact = RIG.baseline_m * RIG.focal_px / (disp - 1) - z
        first_order = z**2 / (RIG.baseline_m * RIG.focal_px)
        assert exact == pytest.approx(first_order * disp / (disp - 1), rel=1e-9)
        assert float(RIG.depth_error_one_px_m(z)) == pytest.approx(first_order * ratio, rel=1e-9)


def test_covariance_matches_monte_carlo() -> None:
    rng = np.random.default_rng(1)
    p = np.array([[0.4, -0.2, 2.5]])
    left, right = RIG.project(p)
    sigma = 0.5
    n = 20000
    nl = left + rng.normal(0, sigma, (n, 2))
    nr = right + rng.normal(0, sigma, (n, 2))
    samples, _ = RIG.triangulate(nl, nr)
    _, cov = RIG.triangulate(left, right, sigma_px=sigma)
    mc = np.cov(samples.T)
    np.testing.assert_allclose(np.sqrt(np.diag(cov[0])), np.sqrt(np.diag(mc)), rtol=0.05)
    # Z sigma for sqrt(2) sigma of disparity is eq. 12's shape: D^2 / (B f) per pixel.
    assert math.sqrt(cov[0, 2, 2]) == pytest.approx(
        2.5**2 / (0.06 * RIG.focal_px) * sigma * math.sqrt(2), rel=1e-9
    )


def _sphere_silhouette(
    centre_m: np.ndarray, radius_m: float, f: float, cx: float, cy: float, n: int = 8
) -> tuple[np.ndarray, float]:
    """Centroid (px) and area (px) of a sphere's image in a pinhole camera at the origin,
    ray-cast: an n x n supersampled ray hits the sphere when it passes within r of its centre
    (pixel (i, j)'s centre is at x = j, y = i)."""
    z = float(centre_m[2])
    reach = 2.0 * f * radius_m / math.sqrt(z * z - radius_m**2) + 3.0
    u0, v0 = f * centre_m[0] / z + cx, f * centre_m[1] / z + cy
    x0, x1, y0, y1 = int(u0 - reach), int(u0 + reach) + 1, int(v0 - reach), int(v0 + reach) + 1
    ys, xs = np.mgrid[y0 * n : y1 * n, x0 * n : x1 * n]
    rays = np.stack(
        [((xs + 0.5) / n - 0.5 - cx) / f, ((ys + 0.5) / n - 0.5 - cy) / f, np.ones(xs.shape)], -1
    )
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    along = rays @ centre_m
    hit = centre_m @ centre_m - along * along < radius_m**2
    cover = hit.reshape(y1 - y0, n, x1 - x0, n).mean(axis=(1, 3))
    yy, xx = np.mgrid[y0:y1, x0:x1]
    area = float(cover.sum())
    return np.array([(cover * xx).sum() / area, (cover * yy).sum() / area]), area


def _cylinder_silhouette(
    centre_m: np.ndarray, radius_m: float, half_height_m: float, f: float, cx: float, cy: float
) -> tuple[np.ndarray, float, float]:
    """Centroid (px), area (px) and box width (px, columns at least half covered) of an
    upright cylinder's image (axis along Y through ``centre_m``), ray-cast 8 x 8 per pixel: a
    ray hits when the stretch of it inside the infinite cylinder meets the slab of heights."""
    n, (xc, yc, zc) = 8, (float(v) for v in centre_m)
    reach = 2.0 * f * max(radius_m, half_height_m) / (zc - radius_m) + 3.0
    u0, v0 = f * xc / zc + cx, f * yc / zc + cy
    x0, x1, y0, y1 = int(u0 - reach), int(u0 + reach) + 1, int(v0 - reach), int(v0 + reach) + 1
    ys, xs = np.mgrid[y0 * n : y1 * n, x0 * n : x1 * n]
    dx, dy = ((xs + 0.5) / n - 0.5 - cx) / f, ((ys + 0.5) / n - 0.5 - cy) / f
    # (t dx - xc)^2 + (t - zc)^2 = r^2 for the ray (dx, dy, 1) t
    a, b = dx * dx + 1.0, -2.0 * (dx * xc + zc)
    disc = b * b - 4.0 * a * (xc * xc + zc * zc - radius_m**2)
    root = np.sqrt(np.maximum(disc, 0.0))
    t_in, t_out = (-b - root) / (2.0 * a), (-b + root) / (2.0 * a)
    lo, hi = yc - half_height_m, yc + half_height_m
    with np.errstate(divide="ignore"):
        ta, tb = lo / dy, hi / dy
    s_in = np.where(dy > 0, ta, np.where(dy < 0, tb, -np.inf))
    s_out = np.where(dy > 0, tb, np.where(dy < 0, ta, np.inf))
    if np.any(dy == 0):
        flat = (dy == 0) & (not lo <= 0.0 <= hi)  # a level ray stays at height 0
        s_in, s_out = np.where(flat, np.inf, s_in), np.where(flat, -np.inf, s_out)
    hit = (disc >= 0) & (np.maximum(t_in, s_in) <= np.minimum(t_out, s_out))
    cover = hit.reshape(y1 - y0, n, x1 - x0, n).mean(axis=(1, 3))
    yy, xx = np.mgrid[y0:y1, x0:x1]
    area = float(cover.sum())
    width = float((cover.max(axis=0) >= 0.5).sum())
    return np.array([(cover * xx).sum() / area, (cover * yy).sum() / area]), area, width


@pytest.mark.parametrize(
    ("centre", "radius"),
    [((0.0, 0.0, 1.2), 0.15), ((0.3, -0.2, 1.2), 0.15), ((0.5, 0.3, 1.0), 0.1)],
)
def test_silhouette_depth_is_corrected_to_a_spheres_centre(
    centre: tuple[float, float, float], radius: float
) -> None:
    # A sphere's silhouette centroids triangulate to Z - r^2 / Z (its near half looks larger);
    # with their areas the depth is its centre's, to a tenth of a millimetre.
    c = np.array(centre)
    half = np.array([RIG.baseline_m / 2, 0.0, 0.0])
    f, cx, cy = RIG.focal_px, RIG.cx_px, RIG.cy_px
    left, area_l = _sphere_silhouette(c + half, radius, f, cx, cy)
    right, area_r = _sphere_silhouette(c - half, radius, f, cx, cy)
    raw, raw_cov = RIG.triangulate(left[None], right[None])
    assert raw[0, 2] - c[2] == pytest.approx(-(radius**2) / c[2], abs=3e-4)
    np.testing.assert_allclose(raw[0, :2], c[:2], atol=1e-4)
    got, cov, k = silhouette_depth(raw, raw_cov, np.array([(area_l + area_r) / 2]), RIG.focal_px)
    np.testing.assert_allclose(got[0], c, atol=2e-4)
    # The depth's spread scales with it, plus half the shift for the shape it assumes;
    # X and Y are untouched.
    assert k[0] == pytest.approx(got[0, 2] / raw[0, 2], rel=1e-12)
    shift = got[0, 2] - raw[0, 2]
    assert cov[0, 2, 2] == pytest.approx(k[0] ** 2 * raw_cov[0, 2, 2] + (shift / 2) ** 2)
    np.testing.assert_allclose(cov[0, :2, :2], raw_cov[0, :2, :2], rtol=1e-12)
    # Its width (here far larger than its minor axis, as a box would measure it) changes nothing.
    width = np.array([2.0 * math.sqrt(area_l / math.pi) + 1.0])
    also, _, _ = silhouette_depth(raw, raw_cov, np.array([area_l]), RIG.focal_px, width)
    again, _, _ = silhouette_depth(raw, raw_cov, np.array([area_l]), RIG.focal_px)
    np.testing.assert_array_equal(also, again)


@pytest.mark.parametrize("centre", [(0.0, 0.0, 1.5), (-0.4, -0.1, 1.2), (0.2, 0.3, 1.5)])
def test_silhouette_depth_is_corrected_to_an_upright_cylinders_axis(
    centre: tuple[float, float, float],
) -> None:
    # A robot-like cylinder taller than wide: sideways its silhouette is nearly a sphere's of
    # its radius (Z - r^2 / Z, and its rims' near halves bulge a little more); its width gives
    # that to a millimetre, its area would overstate it.
    c, r, h = np.array(centre), 0.1, 0.15
    half = np.array([RIG.baseline_m / 2, 0.0, 0.0])
    f, cx, cy = RIG.focal_px, RIG.cx_px, RIG.cy_px
    left, area_l, width_l = _cylinder_silhouette(c + half, r, h, f, cx, cy)
    right, area_r, width_r = _cylinder_silhouette(c - half, r, h, f, cx, cy)
    area, width = np.array([(area_l + area_r) / 2]), np.array([(width_l + width_r) / 2])
    raw, cov = RIG.triangulate(left[None], right[None])
    assert -1.3 * r**2 / c[2] < raw[0, 2] - c[2] < -(r**2) / c[2]
    got, _, _ = silhouette_depth(raw, cov, area, RIG.focal_px, width)
    assert got[0, 2] == pytest.approx(c[2], abs=1e-3)
    by_area, _, _ = silhouette_depth(raw, cov, area, RIG.focal_px)
    assert by_area[0, 2] - c[2] > 4e-3


@pytest.mark.parametrize(("depth_m", "plain_sigmas"), [(3.0, 1.0), (1.5, 4.0)])
def test_a_flat_objects_depth_moves_at_most_the_cap_and_within_two_of_its_sigmas(
    depth_m: float, plain_sigmas: float
) -> None:
    # A door 0.9 m wide and 2 m tall, face on: its silhouettes' centroids triangulate to its
    # plane exactly (a plane's image is an affine copy), so any correction is an error. It is
    # taken as deep as it is wide, at most SILHOUETTE_Q_MAX of its depth, and the depth's
    # sigma grows to cover that guess.
    c, w_m, h_m = np.array([0.3, 0.0, depth_m]), 0.9, 2.0
    f, cx, cy = RIG.focal_px, RIG.cx_px, RIG.cy_px
    left = np.array([f * (c[0] + RIG.baseline_m / 2) / c[2] + cx, cy])
    right = np.array([f * (c[0] - RIG.baseline_m / 2) / c[2] + cx, cy])
    raw, raw_cov = RIG.triangulate(left[None], right[None], sigma_px=0.15)
    np.testing.assert_allclose(raw[0], c, atol=1e-9)
    width = f * w_m / c[2]
    area = width * f * h_m / c[2]
    got, cov, k = silhouette_depth(raw, raw_cov, np.array([area]), f, np.array([width]))
    q = min((w_m / 2 / c[2]) ** 2, SILHOUETTE_Q_MAX)
    assert k[0] == pytest.approx(1.0 + q, rel=1e-12)
    error = got[0, 2] - c[2]
    assert 0.0 < error <= SILHOUETTE_Q_MAX * c[2] + 1e-12
    assert error / math.sqrt(cov[0, 2, 2]) <= 2.0
    assert error / math.sqrt(raw_cov[0, 2, 2]) > plain_sigmas  # the sigma it would have had


def test_rig_rejects_nonsense() -> None:
    with pytest.raises(ValueError, match="baseline"):
        CanonicalRig(0.0, 60, 640, 480)
    with pytest.raises(ValueError, match="field of view"):
        CanonicalRig(0.06, 180, 640, 480)
    with pytest.raises(ValueError, match="finite number > 0 m"):
        CanonicalRig(math.inf, 60, 640, 480)
    for size in ((math.nan, 240), (320.5, 240), (True, 240)):
        with pytest.raises(ValueError, match="whole pixels"):
            CanonicalRig(0.06, 60, *size)  # type: ignore[arg-type]
    # a whole number given as a float (from a division, a JSON file) is taken as the int
    rig = CanonicalRig(0.06, 60, 320.0, np.int64(240))  # type: ignore[arg-type]
    assert (rig.width_px, rig.height_px) == (320, 240) and isinstance(rig.width_px, int)


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


def test_the_depth_factor_of_each_silhouette_is_the_closed_form_with_numpys_nans() -> None:
    """Each silhouette's factor is 1 + min(area cos(theta) / (pi f^2), (w / 2f)^2, cap),
    computed here on arrays as numpy does (a NaN anywhere gives a NaN factor)."""
    rng = np.random.default_rng(2)
    n = 400
    area = rng.uniform(0, 5000, n)
    x, y = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    width = rng.uniform(1, 120, n)
    area[::37], width[5::41], x[11::43] = np.nan, np.nan, np.nan
    f = 450.0
    q = area / np.sqrt(1 + x * x + y * y) / (math.pi * f * f)
    expected = 1 + np.minimum(np.minimum(q, (0.5 * width / f) ** 2), SILHOUETTE_Q_MAX)
    got = silhouette_depth_factor(area, x, y, f, width)
    np.testing.assert_allclose(got, expected, rtol=1e-12, equal_nan=True)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))
