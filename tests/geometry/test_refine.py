"""Disparity by appearance matching: what it measures where the two masks disagree."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereod.vision.geometry.refine import RefineParams, refine_match


def textured(h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (h // 4, w // 4), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


@pytest.mark.parametrize("shift", [7.0, 7.3, 12.6])
def test_the_left_object_is_found_in_the_right_image_to_a_tenth_of_a_pixel(shift: float) -> None:
    """A textured object moved by a known sub-pixel disparity between the eyes: the match
    finds the shift whatever the right mask would have said (here the initial guess is 2 px
    off, as a biased segmentation gives)."""
    h, w = 120, 160
    obj = textured(40, 40, seed=3).astype(np.float32)
    left = np.full((h, w), 90, np.float32)
    left[40:80, 80:120] = obj
    m = np.float32([[1, 0, -shift], [0, 1, 0]])
    right = cv2.warpAffine(left, m, (w, h), borderValue=90)
    left8, right8 = left.astype(np.uint8), np.clip(right, 0, 255).astype(np.uint8)
    support = np.full((40, 40), 255, np.uint8)
    lpx = np.array([99.5, 59.5])
    guess = lpx - [shift + 2.0, 0.0]
    got, score = refine_match(
        lambda x0, y0, x1, y1: left8[y0:y1, x0:x1],
        lambda x0, y0, x1, y1: right8[y0:y1, x0:x1],
        (w, h),
        (80, 40, 40, 40),
        support,
        lpx,
        guess,
        RefineParams(enabled=True),
    )
    assert score > 0.9
    assert got[0] == pytest.approx(lpx[0] - shift, abs=0.1)
    assert got[1] == pytest.approx(lpx[1], abs=0.1)


def test_no_texture_keeps_the_centroids() -> None:
    """A flat patch matches everywhere equally: no confident peak, the given centroid stays."""
    flat = np.full((60, 80), 120, np.uint8)
    given = np.array([30.0, 30.0])
    got, score = refine_match(
        lambda x0, y0, x1, y1: flat[y0:y1, x0:x1],
        lambda x0, y0, x1, y1: flat[y0:y1, x0:x1],
        (80, 60),
        (30, 20, 20, 20),
        np.full((20, 20), 255, np.uint8),
        np.array([40.0, 30.0]),
        given,
        RefineParams(enabled=True),
    )
    assert score == 0.0 and np.array_equal(got, given)
