"""Pixel formats to what the pipeline needs: grey (the luminance of eq. 2) or BGR.

YUYV carries the BT.601 luma Y of every pixel at even byte offsets, so grey is a strided copy
(0.28 ms at 640x480) and costs no colour conversion; MJPEG decodes straight to grey.
"""

from __future__ import annotations

import cv2
import numpy as np


def yuyv_to_gray(data: bytes | memoryview | np.ndarray, width: int, height: int) -> np.ndarray:
    """(h, w) uint8 luma of a YUYV 4:2:2 frame (2 bytes per pixel)."""
    a = np.frombuffer(data, dtype=np.uint8, count=width * height * 2)
    return a[0::2].reshape(height, width).copy()


def yuyv_to_bgr(data: bytes | memoryview | np.ndarray, width: int, height: int) -> np.ndarray:
    """(h, w, 3) uint8 BGR of a YUYV frame."""
    a = np.frombuffer(data, dtype=np.uint8, count=width * height * 2).reshape(height, width, 2)
    return cv2.cvtColor(a, cv2.COLOR_YUV2BGR_YUYV)


def mjpeg_to_gray(data: bytes | memoryview | np.ndarray) -> np.ndarray | None:
    """(h, w) uint8 grey of one MJPEG frame; ``None`` when it does not decode."""
    buf = np.frombuffer(data, dtype=np.uint8)
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
