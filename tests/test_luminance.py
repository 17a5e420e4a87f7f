"""Eq. 2's luminance and the channel mean of eq. 4's colour difference."""

from __future__ import annotations

import cv2
import numpy as np

from stereod.vision.detect_params import Luminance
from stereod.vision.luminance import MEAN_RGB, channel_mean, luminance, mean_channels


def every_triple() -> np.ndarray:
    """Every (b, g, r) triple of uint8 levels, as a 4096 x 4096 BGR image."""
    levels = np.arange(256, dtype=np.uint8)
    grid = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), axis=-1)
    return grid.reshape(4096, 4096, 3)


def test_channel_mean_is_opencvs_uint8_transform_for_every_triple() -> None:
    image = every_triple()
    assert np.array_equal(channel_mean(image), cv2.transform(image, MEAN_RGB))


def test_channel_mean_is_the_rounded_mean() -> None:
    image = every_triple()
    total = image.astype(np.int32).sum(axis=2)
    assert np.array_equal(channel_mean(image), (2 * total + 3) // 6)  # round(total / 3)


def test_channel_mean_of_a_crop_and_a_grey_frame() -> None:
    rng = np.random.default_rng(1)
    frame = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    crop = frame[5:30, 7:50]  # a view, not contiguous
    assert np.array_equal(channel_mean(crop), cv2.transform(np.ascontiguousarray(crop), MEAN_RGB))
    grey = frame[..., 0].copy()
    assert mean_channels(grey) is grey
    assert luminance(grey, Luminance.MEAN) is grey
    assert np.array_equal(luminance(frame, Luminance.MEAN), cv2.transform(frame, MEAN_RGB))
