"""How alike the two eyes' images of a candidate pair are (normalised cross-correlation),
against closed forms: a patch against itself is 1, against its negative -1, and two
independent noise textures are near 0."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereod.vision.agreement import FLAT_GREY, eye_agreement

H, W = 120, 200


def texture(seed: int) -> np.ndarray:
    """A smooth random grey texture (8-bit), the size of the test images."""
    noise = np.random.default_rng(seed).normal(128, 60, (H, W)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 2.0), 0, 255).astype(np.uint8)


def test_the_same_patch_agrees_fully_and_its_negative_not_at_all() -> None:
    img = texture(0)
    box = np.array([40, 30, 50, 40])
    assert eye_agreement(img, img, box, box) == pytest.approx(1.0, abs=1e-6)
    assert eye_agreement(img, 255 - img, box, box) == pytest.approx(-1.0, abs=1e-6)


def test_the_same_thing_seen_shifted_agrees_and_another_thing_does_not() -> None:
    img = texture(1)
    shifted = np.roll(img, -17, axis=1)  # the right eye: 17 px of disparity
    left_box = np.array([60, 30, 67, 46])
    right_box = np.array([43, 30, 67, 46])
    assert eye_agreement(img, shifted, left_box, right_box) == pytest.approx(1.0, abs=1e-6)
    other = texture(2)
    assert abs(eye_agreement(img, other, left_box, right_box)) < 0.3


def test_colour_images_are_compared_in_grey() -> None:
    img = texture(3)
    bgr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    box = np.array([10, 10, 30, 30])
    assert eye_agreement(bgr, img, box, box) == pytest.approx(1.0, abs=1e-6)


def test_a_flat_patch_or_a_box_outside_the_image_is_no_evidence_against() -> None:
    img = texture(4)
    flat = np.full((H, W), 90, np.uint8)
    flat[::2] += int(FLAT_GREY) // 2  # varies, but by less than FLAT_GREY
    box = np.array([20, 20, 40, 40])
    assert eye_agreement(img, flat, box, box) == 1.0
    assert eye_agreement(img, img, box, np.array([W + 5, 20, 10, 10])) == 1.0
