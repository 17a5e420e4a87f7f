"""Frames of shaded balls on a textured wall, rendered apart from the code under test: each
pixel the share a ball covers (sampled 8 x 8) of the ball's Lambertian-shaded colour, plus
sensor noise. Shared by the disc-fit tests."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np


def shaded_balls(
    rng: np.random.Generator, h: int, w: int, radii: Sequence[float], x0: float, dx: float
) -> tuple[np.ndarray, np.ndarray, list[tuple[float, float]]]:
    """A textured wall and a frame of it with a ball of each of ``radii`` (px), the k-th
    centred near x = ``x0`` + k ``dx`` (px) at a random row, both (h, w, 3) float64 with
    noise, and the balls' true centres (x, y px)."""
    coarse = rng.normal(110.0, 25.0, (h // 6 + 1, w // 6 + 1, 3))
    wall = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
    frame, truth, ss = wall.copy(), [], 8
    ys, xs = np.mgrid[0 : h * ss, 0 : w * ss]
    px, py = (xs + 0.5) / ss - 0.5, (ys + 0.5) / ss - 0.5
    for k, r in enumerate(radii):
        u, v = x0 + dx * k + rng.uniform(-3, 3), rng.uniform(25.0, h - 25.0)
        rho2 = ((px - u) ** 2 + (py - v) ** 2) / (r * r)
        inside = rho2 <= 1.0
        shade = 0.3 + 0.7 * np.sqrt(np.clip(1.0 - rho2, 0.0, None))
        cover = inside.reshape(h, ss, w, ss).mean(axis=(1, 3))[..., None]
        lit = (inside * shade).reshape(h, ss, w, ss).mean(axis=(1, 3))[..., None]
        frame = lit * rng.uniform(60.0, 240.0, 3) + (1.0 - cover) * frame
        truth.append((u, v))
    wall, frame = (np.clip(a + rng.normal(0.0, 1.5, a.shape), 0, 255) for a in (wall, frame))
    return wall, frame, truth
