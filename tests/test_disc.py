"""The disc fit of a small round blob's centre, against pixels integrated by supersampling."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from stereod.vision.detect import Detector
from stereod.vision.detect_params import DetectorParams
from stereod.vision.disc import coverage, disc_centre, is_round

SUB = 16
"""Samples per pixel side when integrating a pixel's colour."""


def _sphere(h: int, w: int, u: float, v: float, r: float, light: np.ndarray) -> np.ndarray:
    """(h, w, 2): share of each pixel a sphere of image radius ``r`` px centred at (u, v)
    covers, and its mean Lambertian shading there (ambient 0.2, the rest from ``light``, a
    unit vector in camera axes), both averaged over SUB x SUB samples per pixel."""
    ys, xs = np.mgrid[0 : h * SUB, 0 : w * SUB]
    px, py = (xs + 0.5) / SUB - 0.5, (ys + 0.5) / SUB - 0.5
    nx, ny = (px - u) / r, (py - v) / r
    rho2 = nx * nx + ny * ny
    inside = rho2 <= 1.0
    nz = -np.sqrt(np.clip(1.0 - rho2, 0.0, None))  # facing the camera
    shade = 0.2 + 0.8 * np.clip(nx * light[0] + ny * light[1] + nz * light[2], 0.0, None)
    cover = inside.reshape(h, SUB, w, SUB).mean(axis=(1, 3))
    shaded = (inside * shade).reshape(h, SUB, w, SUB).mean(axis=(1, 3))
    return np.dstack([cover, shaded])


def _wall(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """(h, w, 3) float: a smooth random colour texture, a grey level about 110 +- 25."""
    coarse = rng.normal(110.0, 25.0, (h // 4 + 1, w // 4 + 1, 3))
    return cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)


def _centre_errors(
    rng: np.random.Generator,
    wall: np.ndarray,
    frame: np.ndarray,
    centre: tuple[float, float],
    noise: float,
    errors: dict[int, list[float]],
) -> None:
    """For each ``disc_max_px`` in ``errors`` (0: the matte alone), detect the ball of
    ``frame`` against ``wall`` (both float, noise ``noise`` grey levels added) and append each
    blob's distance from the true ``centre`` (px); at most one blob."""
    for size in errors:
        det = Detector(DetectorParams(warmup_frames=1, disc_max_px=size))
        det.detect(np.clip(wall + rng.normal(0.0, noise, wall.shape), 0, 255).astype(np.uint8))
        img = np.clip(frame + rng.normal(0.0, noise, frame.shape), 0, 255).astype(np.uint8)
        blobs = det.detect(img)
        assert len(blobs) <= 1
        errors[size].extend(float(np.hypot(*(c - centre))) for c in blobs.centroid_px)


def test_coverage_is_the_share_of_a_pixel_a_straight_edge_leaves_inside() -> None:
    """The closed form against a pixel sampled 200 x 200 times, for edges at every angle and
    distance (inside is the side the normal points away from)."""
    rng = np.random.default_rng(4)
    g = (np.arange(200) + 0.5) / 200 - 0.5
    gx, gy = np.meshgrid(g, g)
    for _ in range(60):
        angle, s = rng.uniform(0, 2 * math.pi), rng.uniform(-0.9, 0.9)
        nx, ny = math.cos(angle), math.sin(angle)
        sampled = float(np.mean(gx * nx + gy * ny <= s))
        share, _ = coverage(np.array([s]), np.array([nx]), np.array([ny]))
        assert share[0] == pytest.approx(sampled, abs=0.01)
        ahead, _ = coverage(np.array([s + 1e-4]), np.array([nx]), np.array([ny]))
        back, slope = coverage(np.array([s - 1e-4]), np.array([nx]), np.array([ny]))
        assert slope[0] == pytest.approx((ahead[0] - back[0]) / 2e-4, abs=0.02)


def test_a_ball_whose_shaded_side_matches_the_wall_is_centred_by_the_disc() -> None:
    """A Lambertian ball 6-11 px across, lit from above, in front of a textured wall of which
    the quarter below and right of the ball's centre is the colour of the ball's unlit side:
    the segmentation loses that part of the ball, so the matte centroid sits 0.5-1 px up and
    to the left; the disc fitted to the parts of the outline that can be seen brings that
    down four- to fivefold (what remains is the shading there, which the fit's smooth colour
    model does not follow into its shadow)."""
    rng = np.random.default_rng(8)
    h, w = 48, 48
    light = np.array([0.0, -0.8, -0.6])
    errors: dict[int, list[float]] = {0: [], 24: []}
    for _ in range(20):
        colour = rng.uniform(120.0, 230.0, 3)
        wall = _wall(rng, h, w)
        u, v, r = rng.uniform(20, 28), rng.uniform(20, 28), rng.uniform(3.0, 5.5)
        corner = (np.arange(h)[:, None, None] > v) & (np.arange(w)[None, :, None] > u)
        wall = np.where(corner, colour * 0.3 + rng.normal(0.0, 3.0, wall.shape), wall)
        ball = _sphere(h, w, u, v, r, light)
        frame = ball[..., 1:2] * colour + (1.0 - ball[..., :1]) * wall
        _centre_errors(rng, wall, frame, (u, v), 1.0, errors)
    assert len(errors[0]) == len(errors[24]) >= 15
    matte, fitted = float(np.median(errors[0])), float(np.median(errors[24]))
    assert matte > 0.5, f"the scene is meant to be hard for the matte: {matte:.3f} px"
    assert fitted < 0.3, f"disc fit median error {fitted:.3f} px (matte {matte:.3f} px)"
    assert fitted < 0.35 * matte


def test_a_ball_four_to_six_pixels_across_is_centred_by_the_disc() -> None:
    """A ball 4.4-5.6 px across (a thrown ball far off) is drawn by a handful of pixels: its
    support may fill its box, and is fitted all the same. Its
    matte centroid errs by 0.3-0.4 px in one blob in ten; the disc's by under 0.12 px."""
    rng = np.random.default_rng(6)
    h, w = 32, 32
    light = np.array([0.3, -0.6, -0.74]) / math.sqrt(0.3**2 + 0.6**2 + 0.74**2)
    errors: dict[int, list[float]] = {0: [], 24: []}
    for _ in range(20):
        colour = rng.uniform(120.0, 230.0, 3)
        wall = _wall(rng, h, w)
        u, v, r = rng.uniform(13, 18), rng.uniform(13, 18), rng.uniform(2.2, 2.8)
        ball = _sphere(h, w, u, v, r, light)
        frame = ball[..., 1:2] * colour + (1.0 - ball[..., :1]) * wall
        _centre_errors(rng, wall, frame, (u, v), 2.0, errors)
    assert len(errors[24]) >= 10
    matte, fitted = float(np.percentile(errors[0], 90)), float(np.percentile(errors[24], 90))
    assert matte > 0.25, f"the scene is meant to be hard for the matte: {matte:.3f} px"
    assert fitted < 0.12, f"disc fit 90th percentile {fitted:.3f} px (matte {matte:.3f} px)"


def test_only_a_round_blob_inside_the_image_is_fitted() -> None:
    """A filled square or a tall box is not round, nor is a half disc 7 px tall; a disc is,
    however small, and so is a ball's support a handful of pixels across, which fills its
    box or is a row longer than wide; a blob whose margin leaves the image gets no fit."""
    square = np.full((10, 10), 255, np.uint8)
    tall = np.full((20, 8), 255, np.uint8)
    assert not is_round(square, cv2.countNonZero(square))
    assert not is_round(tall, cv2.countNonZero(tall))
    for shape in ((4, 4), (5, 3), (4, 6)):  # a ball 4-5 px across, or a row longer
        assert is_round(np.full(shape, 255, np.uint8), shape[0] * shape[1])
    yy, xx = np.mgrid[0:7, 0:7] - 3.0
    half = np.where(xx * xx + yy * yy <= 3.5**2, 255, 0).astype(np.uint8)[:, :4]
    assert not is_round(half, cv2.countNonZero(half))  # 7 x 4
    assert not is_round(np.full((7, 4), 255, np.uint8), 28)
    for side in (7, 11, 20):
        yy, xx = np.mgrid[0:side, 0:side] - (side - 1) / 2
        disc = np.where(xx * xx + yy * yy <= (side / 2) ** 2, 255, 0).astype(np.uint8)
        assert is_round(disc, cv2.countNonZero(disc))
    frame = np.zeros((20, 20, 3), np.uint8)
    assert disc_centre(frame, frame, (0, 5, 8, 8), (4.0, 9.0), 50) is None
    assert disc_centre(frame, frame, (13, 5, 6, 6), (16.0, 8.0), 28) is None


def test_a_grey_ball_is_centred_as_a_colour_one() -> None:
    """Grey frames (a camera with colour off) go through the same fit with one channel: it
    gives what the fit gives on the same picture in three equal channels, and puts a shaded
    ball lit from the side over a textured wall within 0.15 px (the shading's terminator,
    which the smooth colour model does not follow, leaves about 0.1 px)."""
    rng = np.random.default_rng(3)
    h, w = 40, 40
    for _ in range(5):
        wall = cv2.resize(rng.normal(90.0, 20.0, (11, 11)), (w, h), interpolation=cv2.INTER_CUBIC)
        u, v, r = rng.uniform(17, 23), rng.uniform(17, 23), rng.uniform(3.5, 6.0)
        ball = _sphere(h, w, u, v, r, np.array([0.3, -0.5, -0.81]))
        frame = np.clip(ball[..., 1] * 230.0 + (1.0 - ball[..., 0]) * wall, 0, 255)
        grey, behind = frame.astype(np.uint8), np.clip(wall, 0, 255).astype(np.uint8)
        box = (int(u - r), int(v - r), int(2 * r) + 2, int(2 * r) + 2)
        start, area = (u + 0.3, v - 0.2), int(round(math.pi * r * r))
        fit = disc_centre(grey, behind, box, start, area)
        three = disc_centre(np.dstack([grey] * 3), np.dstack([behind] * 3), box, start, area)
        assert fit is not None and three is not None
        np.testing.assert_allclose(fit, three, atol=1e-9)
        assert math.hypot(fit[0] - u, fit[1] - v) < 0.15


def test_the_fit_takes_at_most_three_steps_and_centres_the_ball_as_well(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Three Gauss-Newton steps (four LU solves with the starting colour's) are enough: balls
    4-16 px across, shaded, over a textured wall, started 0.3 px off, are centred within
    0.15 px (median 0.05 px) of the truth, and within 0.02 px of where the fit run to
    convergence puts them."""
    solves = [0]
    real_solve = cv2.solve

    def counted(*args: object) -> object:
        solves[0] += 1
        return real_solve(*args)  # type: ignore[call-overload]

    rng = np.random.default_rng(21)
    h, w = 40, 40
    errors, apart, most = [], [], 0
    for _ in range(30):
        wall = _wall(rng, h, w)
        u, v, r = rng.uniform(17, 23), rng.uniform(17, 23), rng.uniform(2.0, 8.0)
        light = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), -0.8])
        ball = _sphere(h, w, u, v, r, light / np.linalg.norm(light))
        frame = ball[..., 1:2] * rng.uniform(60.0, 220.0, 3) + (1.0 - ball[..., :1]) * wall
        img = np.clip(frame + rng.normal(0.0, 2.0, frame.shape), 0, 255).astype(np.uint8)
        behind = np.clip(wall, 0, 255).astype(np.uint8)
        box = (int(u - r), int(v - r), int(2 * r) + 2, int(2 * r) + 2)
        start = (u + rng.uniform(-0.3, 0.3), v + rng.uniform(-0.3, 0.3))
        area = int(round(math.pi * r * r))
        with monkeypatch.context() as m:
            m.setattr(cv2, "solve", counted)
            solves[0] = 0
            fit = disc_centre(img, behind, box, start, area)
            most = max(most, solves[0])
        with monkeypatch.context() as m:  # the same fit run until it no longer moves
            m.setattr("stereod.vision.disc._ITERATIONS", 50)
            m.setattr("stereod.vision.disc._CONVERGED_PX", 1e-9)
            converged = disc_centre(img, behind, box, start, area)
        assert fit is not None and converged is not None
        errors.append(math.hypot(fit[0] - u, fit[1] - v))
        apart.append(math.hypot(fit[0] - converged[0], fit[1] - converged[1]))
    assert most <= 4, f"{most} LU solves for one ball (at most 1 + 3 steps)"
    assert max(apart) < 0.02, f"{max(apart):.4f} px from the converged fit"
    assert max(errors) < 0.15 and float(np.median(errors)) < 0.05, (max(errors), errors)
