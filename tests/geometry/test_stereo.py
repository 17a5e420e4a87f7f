"""Canonical geometry (eq. 9, 10, 12) and the silhouette depth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereod.vision.geometry.stereo import (
    SILHOUETTE_Q_MAX,
    CanonicalRig,
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
