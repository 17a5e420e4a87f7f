"""Pixel format conversion against OpenCV's own converters."""

from __future__ import annotations

import cv2
import numpy as np

from stereod_v4l2_minoru.convert import mjpeg_to_gray, yuyv_to_bgr, yuyv_to_gray


def yuyv_frame(w: int = 64, h: int = 48) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(16, 236, (h, w, 2), dtype=np.uint8)


def test_yuyv_gray_is_the_luma_opencv_extracts() -> None:
    f = yuyv_frame()
    want = cv2.cvtColor(f, cv2.COLOR_YUV2GRAY_YUYV)
    np.testing.assert_array_equal(yuyv_to_gray(f.tobytes(), 64, 48), want)


def test_yuyv_bgr_matches_opencv() -> None:
    f = yuyv_frame()
    np.testing.assert_array_equal(
        yuyv_to_bgr(f.tobytes(), 64, 48), cv2.cvtColor(f, cv2.COLOR_YUV2BGR_YUYV)
    )


def test_mjpeg_decodes_to_gray_and_garbage_is_none() -> None:
    img = np.tile(np.arange(64, dtype=np.uint8) * 4, (48, 1))
    ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    out = mjpeg_to_gray(jpg.tobytes())
    assert out is not None and out.shape == (48, 64)
    assert np.abs(out.astype(int) - img).max() <= 4
    assert mjpeg_to_gray(b"not a jpeg") is None
