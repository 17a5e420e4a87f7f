"""Eq. 21-23 and the least-squares velocity."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stereod.tracking import motion


def test_eq21_finite_difference() -> None:
    v = motion.finite_difference(np.array([1.0, 2.0, 3.0]), np.array([1.5, 2.0, 2.0]), 0.5)
    np.testing.assert_allclose(v, [1.0, 0.0, -2.0])
    with pytest.raises(ValueError):
        motion.finite_difference(np.zeros(3), np.zeros(3), 0.0)


def test_eq22_speed() -> None:
    assert motion.speed(np.array([3.0, 4.0, 12.0])) == pytest.approx(13.0)


@pytest.mark.parametrize(
    ("dx", "dz", "expected"),
    [(0, 1, 0), (1, 1, 45), (1, 0, 90), (0, -1, 180), (-1, -1, 225), (-1, 0, 270), (-1, 1, 315)],
)
def test_eq23_heading_convention(dx: float, dz: float, expected: float) -> None:
    assert motion.heading_deg(dx, dz) == pytest.approx(expected)


def test_heading_sigma_first_order_matches_sampling() -> None:
    rng = np.random.default_rng(2)
    vx, vz, sx, sz = 0.6, 0.35, 0.01, 0.03
    samples = np.degrees(np.arctan2(rng.normal(vx, sx, 200000), rng.normal(vz, sz, 200000)))
    assert motion.heading_sigma_deg(vx, vz, sx, sz) == pytest.approx(samples.std(), rel=0.03)


def test_heading_sigma_counts_the_covariance_of_the_two_components() -> None:
    """Errors in vx and vz that go together along the velocity move the speed, not the
    heading: the first-order sigma with their covariance matches sampling, and without it
    would be twice too large here."""
    rng = np.random.default_rng(3)
    vx, vz, sx, sz, rho = 0.6, 0.6, 0.03, 0.03, 0.8
    cov = np.array([[sx * sx, rho * sx * sz], [rho * sx * sz, sz * sz]])
    v = rng.multivariate_normal([vx, vz], cov, 200000)
    samples = np.degrees(np.arctan2(v[:, 0], v[:, 1]))
    got = motion.heading_sigma_deg(vx, vz, sx, sz, cov[0, 1])
    assert got == pytest.approx(samples.std(), rel=0.03)
    assert motion.heading_sigma_deg(vx, vz, sx, sz) > 2.0 * got


def test_fit_velocity_exact_on_a_line_and_equals_eq21_for_two_points() -> None:
    t = np.array([0.0, 0.1, 0.25, 0.4])
    v_true = np.array([0.3, -0.1, 0.7])
    p = np.array([1.0, 0.2, 2.0]) + t[:, None] * v_true
    v, sigma = motion.fit_velocity(t, p)
    np.testing.assert_allclose(v, v_true, atol=1e-12)
    np.testing.assert_allclose(sigma, 0.0, atol=1e-9)
    v2, _ = motion.fit_velocity(t[[0, -1]], p[[0, -1]])
    np.testing.assert_allclose(v2, motion.finite_difference(p[0], p[-1], 0.4))


def test_fit_velocity_sigma_is_calibrated() -> None:
    """With known per-sample sigma the reported velocity sigma matches the spread over trials."""
    rng = np.random.default_rng(4)
    t = np.linspace(0, 0.5, 8)
    sig = np.tile([0.005, 0.005, 0.05], (8, 1))
    est = []
    for _ in range(4000):
        p = t[:, None] * np.array([0.5, 0.0, 0.5]) + rng.normal(0, 1, (8, 3)) * sig
        v, s = motion.fit_velocity(t, p, sig)
        est.append(v)
    np.testing.assert_allclose(np.std(est, axis=0), s, rtol=0.05)
    assert math.isclose(float(np.mean(est, axis=0)[2]), 0.5, abs_tol=0.005)


def test_circular_median_wraps_at_north() -> None:
    assert motion.circular_median_deg([359.0, 0.5, 1.0, 358.5, 0.2]) == pytest.approx(0.2)
    assert motion.circular_median_deg([170, 180, 190]) == pytest.approx(180)
    assert motion.circular_median_deg([10.0]) == pytest.approx(10.0)
