"""Eq. 2, a frame's luminance, and the mean over the colour channels that it and eq. 4's colour
difference take."""

from __future__ import annotations

import cv2
import numpy as np

from stereod.vision.detect_params import Luminance

MEAN_RGB = np.full((1, 3), 1.0 / 3.0, dtype=np.float32)


def channel_mean(image: np.ndarray) -> np.ndarray:
    """The mean of a (h, w, 3) uint8 image's channels, rounded to uint8: what
    ``cv2.transform(image, MEAN_RGB)`` gives, to the bit (``tests/test_luminance.py`` checks
    every triple of levels), taken in float32, where OpenCV's uint8 path is half as fast (290
    against 140 us at 640x480)."""
    return cv2.convertScaleAbs(cv2.transform(image.astype(np.float32), MEAN_RGB))


def luminance(image: np.ndarray, mode: Luminance) -> np.ndarray:
    """Eq. 2: the (h, w) uint8 luminance of a (h, w) grey or (h, w, 3) BGR uint8 frame."""
    if image.ndim == 2:
        return image
    if mode is Luminance.MEAN:
        return channel_mean(image)
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def mean_channels(diff: np.ndarray) -> np.ndarray:
    """The colour difference of eq. 4: the mean of the three channels' absolute differences
    (uint8); a one-channel difference as it is."""
    return channel_mean(diff) if diff.ndim == 3 else diff
