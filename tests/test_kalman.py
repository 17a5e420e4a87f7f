"""Constant-velocity Kalman filter against closed forms and a batch least-squares reference."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from stereod.tracking import kalman, motion
from stereod.vision.geometry.stereo import triangulate_rectified


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


def test_transition_and_process_noise_are_their_blocks_in_every_entry() -> None:
    """F = [[I, dt I], [0, I]] and Q = [[q dt^3/3 I, q dt^2/2 I], [q dt^2/2 I, q dt I]] in
    every entry, each axis alike, nothing off the blocks' diagonals."""
    eye, zero = np.eye(3), np.zeros((3, 3))
    for dt, q in ((0.5, 2.0), (0.033, 0.25), (1e-3, 40.0)):
        want_f = np.block([[eye, dt * eye], [zero, eye]])
        assert np.array_equal(kalman.transition(dt), want_f)
        pp, pv, vv = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
        want_q = np.block([[pp * eye, pv * eye], [pv * eye, vv * eye]])
        np.testing.assert_allclose(kalman.process_noise(dt, q), want_q, rtol=1e-15, atol=0.0)


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


def test_a_known_acceleration_predicts_a_free_fall_exactly() -> None:
    """p = p0 + v0 t + a t^2 / 2 and v = v0 + a t; two positions of the fall give the
    velocity at the second (the chord's velocity is that of the midpoint)."""
    g = np.array([0.0, 9.81, 0.0])
    p0, v0 = np.array([0.1, -0.2, 5.0]), np.array([1.0, -3.0, -10.0])
    s = kalman.initiate(p0, np.eye(3) * 1e-4, 0, 1.0)
    s.x[3:] = v0
    t = 0.1
    out = kalman.predict(s, int(t * 1e9), 0.0, g)
    np.testing.assert_allclose(out.position_m, p0 + v0 * t + 0.5 * g * t * t, atol=1e-12)
    np.testing.assert_allclose(out.velocity_mps, v0 + g * t, atol=1e-12)

    def at(t_s: float) -> np.ndarray:
        return p0 + v0 * t_s + 0.5 * g * t_s * t_s

    r = np.eye(3) * 1e-6
    two = kalman.initiate_two(at(0.0), r, 0, at(0.05), r, 50_000_000, g)
    np.testing.assert_allclose(two.velocity_mps, v0 + g * 0.05, atol=1e-9)
    line = kalman.initiate_two(at(0.0), r, 0, at(0.05), r, 50_000_000)
    np.testing.assert_allclose(line.velocity_mps, v0 + g * 0.025, atol=1e-9)


def test_log_likelihood_is_the_gaussian_density() -> None:
    s = kalman.initiate(np.zeros(3), np.diag([0.01, 0.04, 0.09]), 0, 1.0)
    r = np.diag([0.01, 0.0, 0.01])
    z = np.array([0.1, -0.2, 0.3])
    var = np.array([0.02, 0.04, 0.10])
    expected = float(np.sum(-0.5 * (z * z / var + np.log(2 * np.pi * var))))
    assert kalman.log_likelihood(s, z, r) == pytest.approx(expected, rel=1e-12)


def test_inverse3_matches_lapack_and_refuses_what_is_no_covariance() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        a = rng.normal(size=(3, 3)) * rng.uniform(1e-3, 1.0, size=3)  # sigmas 1 mm to 1 m
        cov = a @ a.T + np.eye(3) * 1e-9
        got = kalman.inverse3(cov)
        if np.linalg.det(cov) < kalman.ILL_CONDITIONED * np.prod(np.diag(cov)):
            assert got is None  # left to LAPACK
            continue
        assert got is not None
        inv, det = got
        np.testing.assert_allclose(inv @ cov, np.eye(3), atol=1e-6)
        assert det == pytest.approx(np.linalg.det(cov), rel=1e-8)
    assert kalman.inverse3(np.diag([1.0, 1.0, 0.0])) is None
    assert kalman.inverse3(np.diag([1.0, -1.0, 1.0])) is None
    assert kalman.inverse3(np.full((3, 3), np.nan)) is None
    assert kalman.inverse3(np.diag([-1.0, -2.0, 3.0])) is None  # det > 0, yet no covariance


def _exact_solve(m: np.ndarray, y: np.ndarray) -> np.ndarray:
    """m^-1 y in exact rational arithmetic (Gauss-Jordan on Fractions of the float inputs)."""
    rows = [[Fraction(float(v)) for v in row] + [Fraction(float(t))] for row, t in zip(m, y)]
    for c in range(3):
        pivot = next(r for r in range(c, 3) if rows[r][c] != 0)
        rows[c], rows[pivot] = rows[pivot], rows[c]
        for r in range(3):
            if r != c:
                ratio = rows[r][c] / rows[c][c]
                rows[r] = [x - ratio * z for x, z in zip(rows[r], rows[c])]
    return np.array([float(rows[r][3] / rows[r][r]) for r in range(3)])


def _adjugate_solve(m: np.ndarray, y: np.ndarray) -> np.ndarray:
    """m^-1 y by the float adjugate with no conditioning guard: the positive control."""
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    adj = np.array(
        [
            [e * i - f * h, c * h - b * i, b * f - c * e],
            [f * g - d * i, a * i - c * g, c * d - a * f],
            [d * h - e * g, b * g - a * h, a * e - b * d],
        ]
    )
    return adj @ y / (a * adj[0, 0] + b * adj[1, 0] + c * adj[2, 0])


def test_inverse3_leaves_a_far_objects_covariance_to_lapack() -> None:
    """A far object's depth and lateral errors are almost one (X = x Z / f): the adjugate's
    cancellation would lose most digits (4e-7 of the Mahalanobis distance at 300 m), so the
    closed form declines and the distance stays within 1e-8 of the exact (rational) one."""
    f, b, sigma = 800.0, 0.06, 0.15
    for depth_m, closed in ((2.0, True), (300.0, False)):
        d = b * f / depth_m
        _, r = triangulate_rectified(
            np.array([[600.0 + d / 2, 300.0]]),
            np.array([[600.0 - d / 2, 300.0]]),
            focal_px=f,
            baseline_m=b,
            cx_left_px=320.0,
            cx_right_px=320.0,
            cy_px=240.0,
            sigma_px=sigma,
        )
        cov = r[0] + np.eye(3) * 1e-8
        assert (kalman.inverse3(cov) is not None) is closed
        s = kalman.initiate(np.zeros(3), cov, 0, 1.0)
        z = np.array([0.1, 0.0, depth_m * 0.01])
        exact = float(z @ _exact_solve(cov + r[0], z))
        assert kalman.mahalanobis2(s, z, r[0]) == pytest.approx(exact, rel=1e-8)
        unguarded = float(z @ _adjugate_solve(cov + r[0], z))
        assert (unguarded == pytest.approx(exact, rel=1e-8)) is closed
        got = kalman.update(s, z, r[0])
        want = s.P[:, :3] @ _exact_solve(cov + r[0], z)
        np.testing.assert_allclose(got.x, want, rtol=0, atol=1e-8 * np.abs(want).max())
    s = kalman.initiate(np.zeros(3), np.zeros((3, 3)), 0, 1.0)
    assert kalman.log_likelihood(s, np.ones(3), np.diag([1.0, 0.0, 1.0])) == -np.inf


def test_inverse3_refuses_a_negative_determinant_behind_a_negative_diagonal() -> None:
    """Leading minors 1 and 1e-10 are positive, i = -1: det = -1e-10 is over the
    conditioning floor (which a negative i makes negative), so only det > 0 stops it."""
    b = math.sqrt(1.0 - 1e-10)
    m = np.array([[1.0, b, 0.0], [b, 1.0, 0.0], [0.0, 0.0, -1.0]])
    assert np.linalg.det(m) < 0.0
    assert kalman.inverse3(m) is None


def test_correct_widens_a_surprised_prediction_then_updates() -> None:
    """One predict-correct equals its closed-form parts: the likelihood under the prediction
    as it was, a covariance widened by the squared distance over the bound while beyond it
    (three times at most), and the Kalman update of that, here by LAPACK."""
    s = kalman.initiate(np.zeros(3), np.diag([0.01, 0.04, 0.09]), 0, 1.0)
    pred = kalman.predict(s, 33_000_000, 0.5)
    r = np.diag([0.02, 0.01, 0.3])
    for z, chi2 in ((np.array([0.05, -0.1, 0.2]), 11.3), (np.array([3.0, -2.0, 9.0]), 11.3)):
        got, ll = kalman.correct(pred, z, r, chi2)
        cov = pred.P[:3, :3] + r
        y = z - pred.x[:3]
        expected_ll = -0.5 * (
            y @ np.linalg.solve(cov, y) + np.log(np.linalg.det(cov)) + 3 * np.log(2 * np.pi)
        )
        assert ll == pytest.approx(expected_ll, rel=1e-10)
        p = pred.P
        for _ in range(3):
            nis = y @ np.linalg.solve(p[:3, :3] + r, y)
            if nis <= chi2:
                break
            p = p * (nis / chi2)
        k = np.linalg.solve(p[:3, :3] + r, p[:3, :]).T
        np.testing.assert_allclose(got.x, pred.x + k @ y, rtol=1e-9, atol=1e-12)
        ikh = np.eye(6) - k @ kalman.H
        np.testing.assert_allclose(got.P, ikh @ p @ ikh.T + k @ r @ k.T, rtol=1e-8, atol=1e-14)
    assert not np.allclose(kalman.correct(pred, z, r, chi2)[0].P, kalman.update(pred, z, r).P)


def test_a_precise_measurement_after_a_long_coast_keeps_a_covariance() -> None:
    """A track seen once, coasted for seconds, then corrected by a position known to
    micrometres or better (P up to 10^14 times R): every variance of the update must stay
    non-negative. P - K H P, equal in exact arithmetic, loses the sign of one here through
    rounding (9 of these 900 updates); Joseph's form does not."""
    rng = np.random.default_rng(1)
    bad = 0
    for _ in range(300):
        s = kalman.initiate(rng.normal(size=3), np.eye(3) * 10 ** rng.uniform(-10, -6), 0, 2.0)
        s = kalman.predict(s, int(rng.uniform(0.5, 5.0) * 1e9), float(rng.uniform(0.1, 10.0)))
        for r in (1e-10, 1e-12, 1e-14):
            got = kalman.update(s, s.x[:3] + rng.normal(scale=1e-6, size=3), np.eye(3) * r)
            bad += int(np.any(np.diag(got.P) < 0.0))
    assert bad == 0


def test_point_at_is_position_at_to_the_bit() -> None:
    """The predicted position in Python floats is numpy's, bit for bit, with and without a
    known acceleration, ahead of the state's instant and behind it."""
    rng = np.random.default_rng(5)
    gravity = np.array([0.0, 9.81, 0.0])
    for _ in range(300):
        s = kalman.KalmanState(rng.normal(0.0, 3.0, 6), np.eye(6), int(rng.integers(0, 10**10)))
        t = s.t_ns + int(rng.integers(-(10**8), 10**9))
        for accel in (None, gravity, rng.normal(0.0, 5.0, 3)):
            got = kalman.point_at(s, t, accel)
            assert all(type(c) is float for c in got)
            assert got == tuple(kalman.position_at(s, t, accel).tolist())
