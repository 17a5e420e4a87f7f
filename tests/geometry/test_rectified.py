"""Calibrated geometry: rectified centroids and triangulation against known 3D points."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.calibration import canonical
from stereod.frames import Eye
from stereod.geometry.rectified import CalibratedRig
from stereod.geometry.stereo import CanonicalRig
from stereod_fakes.rig import minoru_like


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
