"""Constant-velocity Kalman filter against closed forms and a batch least-squares reference."""

from __future__ import annotations

import numpy as np
import pytest

from stereod import kalman, motion


def test_transition_and_process_noise_closed_form() -> None:
    f = kalman.transition(0.5)
    x = np.array([1.0, 2.0, 3.0, 0.2, -0.4, 1.0])
    np.testing.assert_allclose(f @ x, [1.1, 1.8, 3.5, 0.2, -0.4, 1.0])
    q = kalman.process_noise(0.5, 2.0)
    # White acceleration: var(p) = q dt^3 / 3, cov(p, v) = q dt^2 / 2, var(v) = q dt.
    assert q[0, 0] == pytest.approx(2.0 * 0.125 / 3)
    assert q[0, 3] == pytest.approx(2.0 * 0.25 / 2)
    assert q[3, 3] == pytest.approx(1.0)
    assert q[0, 1] == 0.0


def test_noise_free_constant_velocity_converges_exactly() -> None:
    v = np.array([0.4, 0.0, -0.7])
    p0 = np.array([0.1, 0.2, 2.0])
    r = np.eye(3) * 1e-4
    s = kalman.initiate(p0, r, 0, velocity_sigma_mps=2.0)
    for k in range(1, 40):
        t = k * 66_666_667
        s = kalman.update(kalman.predict(s, t, q=1e-6), p0 + v * t * 1e-9, r)
    np.testing.assert_allclose(s.velocity_mps, v, atol=1e-3)
    np.testing.assert_allclose(s.position_m, p0 + v * s.t_ns * 1e-9, atol=1e-4)


def test_without_process_noise_it_equals_weighted_least_squares() -> None:
    """With q = 0 and a diffuse prior the filter is recursive least squares: its final velocity
    is the weighted line fit through all positions (each weighted by its own sigma)."""
    rng = np.random.default_rng(0)
    n = 25
    t = np.sort(rng.uniform(0, 2.0, n))
    t[0] = 0.0
    sig = np.column_stack([np.full(n, 0.01), np.full(n, 0.02), rng.uniform(0.02, 0.2, n)])
    truth = np.array([0.0, 0.1, 1.5]) + t[:, None] * np.array([0.5, 0.0, 0.3])
    z = truth + rng.normal(size=(n, 3)) * sig
    s = kalman.initiate(z[0], np.diag(sig[0] ** 2), 0, velocity_sigma_mps=1e4)
    for k in range(1, n):
        tk = int(round(t[k] * 1e9))
        s = kalman.update(kalman.predict(s, tk, q=0.0), z[k], np.diag(sig[k] ** 2))
    v_ls, v_sigma = motion.fit_velocity(t, z, sig)
    np.testing.assert_allclose(s.velocity_mps, v_ls, atol=1e-6)
    np.testing.assert_allclose(np.sqrt(np.diag(s.velocity_cov)), v_sigma, rtol=1e-4)


def test_mahalanobis_distance() -> None:
    s = kalman.initiate(np.zeros(3), np.diag([0.01, 0.04, 0.09]), 0, 1.0)
    # S = P_pos + R = 2 R here.
    d2 = kalman.mahalanobis2(s, np.array([0.1, 0.2, 0.3]), np.diag([0.01, 0.04, 0.09]))
    assert d2 == pytest.approx(1.5)
