"""Calibrated geometry: rectified centroids and triangulation against known 3D points."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereod.sources.frames import Eye
from stereod.vision.calibration import canonical
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.stereo import CanonicalRig, silhouette_depth
from stereod_fakes.rig import RigSpec, minoru_like


def test_points_through_a_distorted_rotated_rig_are_recovered() -> None:
    """Project known points through the true cameras (distortion, rotation); triangulating the
    image points with the true calibration gives them back, in the rectified rig frame."""
    spec = minoru_like()
    cal = spec.calibration()
    rig = CalibratedRig(cal)
    rng = np.random.default_rng(1)
    world = np.column_stack(
        [rng.uniform(-0.6, 0.6, 50), rng.uniform(-0.4, 0.4, 50), rng.uniform(0.8, 4.0, 50)]
    )
    left = spec.project(Eye.LEFT, world)
    right = spec.project(Eye.RIGHT, world)
    lr, rr = rig.rectify_left(left), rig.rectify_right(right)
    np.testing.assert_allclose(lr[:, 1], rr[:, 1], atol=1e-6)  # same rows once rectified
    got, cov = rig.triangulate(lr, rr)
    # Truth in the rig frame: rectified left camera's axes, origin at the baseline midpoint.
    shift = np.array([0.03, 0.0, 0.0])
    truth = (world + shift) @ cal.array("R1").T - np.array([rig.baseline_m / 2, 0.0, 0.0])
    np.testing.assert_allclose(got, truth, atol=1e-6)
    assert rig.baseline_m == pytest.approx(0.060, rel=1e-9)
    assert np.all(np.sqrt(cov[:, 2, 2]) > 0)


def test_canonical_calibration_equals_canonical_rig() -> None:
    canon = CanonicalRig(0.06, 60.0, 640, 480)
    cal = canonical(0.06, 60.0, 640, 480)
    rig = CalibratedRig(cal)
    pts = np.array([[0.2, -0.1, 1.5], [-0.4, 0.3, 3.0]])
    left, right = canon.project(pts)
    a, _ = canon.triangulate(left, right)
    b, _ = rig.triangulate(rig.rectify_left(left), rig.rectify_right(right))
    np.testing.assert_allclose(b, a, atol=1e-9)


def test_swapped_calibration_is_refused() -> None:
    spec = minoru_like()
    cal = spec.calibration(R=np.eye(3), T=np.array([0.06, 0, 0]))
    with pytest.raises(ValueError, match="swapped"):
        CalibratedRig(cal)


def _sphere_view(
    spec: RigSpec, eye: Eye, centre_m: np.ndarray, radius_m: float, n: int = 8
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sphere's image through one distorted camera, ray-cast n x n per pixel (each
    sub-pixel undistorted to its ray): its coverage-weighted centroid (px), and the box
    (x, y, w, h) and uint8 support of its pixels at least half covered, as the detector
    reports a blob."""
    cam = spec.camera(eye)
    u0, v0 = spec.project(eye, centre_m[None])[0]
    reach = 1.3 * cam.fx * radius_m / spec.to_camera(eye, centre_m[None])[0, 2] + 3.0
    x0, x1, y0, y1 = int(u0 - reach), int(u0 + reach) + 1, int(v0 - reach), int(v0 + reach) + 1
    ys, xs = np.mgrid[y0 * n : y1 * n, x0 * n : x1 * n]
    sub = np.stack([(xs + 0.5) / n - 0.5, (ys + 0.5) / n - 0.5], -1).reshape(-1, 1, 2)
    stop = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
    norm = cv2.undistortPoints(sub, cam.K, cam.D, criteria=stop).reshape(-1, 2)
    rays = spec.to_world_direction(eye, np.column_stack([norm, np.ones(len(norm))]))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    rel = centre_m - spec.centre_world(eye)
    along = rays @ rel
    hit = (rel @ rel - along * along < radius_m**2).reshape(xs.shape)
    cover = hit.reshape(y1 - y0, n, x1 - x0, n).mean(axis=(1, 3))
    yy, xx = np.mgrid[y0:y1, x0:x1]
    centroid = np.array([(cover * xx).sum(), (cover * yy).sum()]) / cover.sum()
    mask = cover >= 0.5
    cols, rows = np.nonzero(mask.any(axis=0))[0], np.nonzero(mask.any(axis=1))[0]
    bbox = np.array([x0 + cols[0], y0 + rows[0], len(cols), len(rows)])
    support = mask[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1].astype(np.uint8) * 255
    return centroid, bbox, support


@pytest.mark.parametrize(
    ("centre", "plain_off_m"),
    [
        ((0.0, 0.0, 1.0), 2e-3),
        ((0.3, 0.2, 1.5), 2e-3),
        ((0.45, 0.3, 1.0), 0.0),
        ((-0.45, -0.3, 1.0), 0.0),
        ((0.4, -0.28, 0.9), 0.0),
    ],
)
def test_a_spheres_depth_through_a_distorted_rig_is_its_centres(
    centre: tuple[float, float, float], plain_off_m: float
) -> None:
    """A 10 cm ball through barrel-distorted, rotated eyes, out to the image's corners
    (uncorrected, 3.5-10 mm too near): with its outlines measured in rectified px (area,
    width and centroid), the silhouette depth correction puts it at its centre within
    0.5 mm. With the image's area and width and the centroids rectified as points, the same
    correction misses by over ``plain_off_m`` (at the corners its two errors, the area's
    stretch and the centroid's bend, happen to cancel in part)."""
    spec = minoru_like()
    cal = spec.calibration()
    rig = CalibratedRig(cal)
    c, r = np.array(centre), 0.1
    truth = (c + np.array([0.03, 0.0, 0.0])) @ cal.array("R1").T - [rig.baseline_m / 2, 0, 0]
    (lc, lbox, lsup), (rc, rbox, rsup) = (_sphere_view(spec, e, c, r) for e in Eye)
    left, right = rig.rectify_left(lc[None]), rig.rectify_right(rc[None])
    area_l, width_l, shift_l = rig.rectified_silhouette(True, lbox, lsup)
    area_r, width_r, shift_r = rig.rectified_silhouette(False, rbox, rsup)
    raw, cov = rig.triangulate(left + shift_l, right + shift_r)
    area, width = np.array([(area_l + area_r) / 2]), np.array([(width_l + width_r) / 2])
    got, _, _ = silhouette_depth(raw, cov, area, rig.focal_px, width)
    np.testing.assert_allclose(got[0], truth, atol=5e-4)
    plain, cov = rig.triangulate(left, right)
    area = np.array([(np.count_nonzero(lsup) + np.count_nonzero(rsup)) / 2])
    width = np.array([(lbox[2] + rbox[2]) / 2])
    plain, _, _ = silhouette_depth(plain, cov, area, rig.focal_px, width)
    assert np.abs(plain[0] - truth).max() > plain_off_m
    assert truth[2] - raw[0, 2] > 3e-3


def test_an_undistorted_rigs_outlines_are_the_images() -> None:
    rig = CalibratedRig(canonical(0.06, 60.0, 640, 480))
    support = np.zeros((40, 30), np.uint8)
    cv2.ellipse(support, (15, 20), (12, 18), 0, 0, 360, 255, -1)
    area, width, shift = rig.rectified_silhouette(True, np.array([300, 200, 30, 40]), support)
    assert area == pytest.approx(np.count_nonzero(support), rel=1e-3)
    assert width == 25.0
    np.testing.assert_allclose(shift, 0.0, atol=1e-3)
