"""Pixel format conversion against OpenCV's own converters."""

from __future__ import annotations

import cv2
import numpy as np

from stereod_v4l2_minoru.convert import mjpeg_to_bgr, mjpeg_to_gray, yuyv_to_bgr, yuyv_to_gray


def yuyv_frame(w: int = 64, h: int = 48) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(16, 236, (h, w, 2), dtype=np.uint8)


def test_yuyv_gray_is_the_luma_opencv_extracts() -> None:
    f = yuyv_frame()
    want = cv2.cvtColor(f, cv2.COLOR_YUV2GRAY_YUYV)
    np.testing.assert_array_equal(yuyv_to_gray(f.tobytes(), 64, 48), want)


def bt601_bgr(y: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """BGR of BT.601 video-range YCbCr (Y 16-235, Cb and Cr 16-240), the closed form."""
    c, d, e = 1.164 * (y - 16.0), u - 128.0, v - 128.0
    bgr = np.stack([c + 2.018 * d, c - 0.391 * d - 0.813 * e, c + 1.596 * e], axis=-1)
    return np.clip(bgr, 0, 255)


def test_yuyv_bgr_is_bt601_video_range() -> None:
    f = yuyv_frame()
    y = f[..., 0].astype(float)
    u = np.repeat(f[:, 0::2, 1], 2, axis=1).astype(float)  # Y0 U Y1 V: each pair shares U, V
    v = np.repeat(f[:, 1::2, 1], 2, axis=1).astype(float)
    got = yuyv_to_bgr(f.tobytes(), 64, 48)
    assert got.shape == (48, 64, 3)
    assert np.abs(got - bt601_bgr(y, u, v)).max() <= 1.5


def test_mjpeg_decodes_to_gray_and_garbage_is_none() -> None:
    img = np.tile(np.arange(64, dtype=np.uint8) * 4, (48, 1))
    ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    out = mjpeg_to_gray(jpg.tobytes())
    assert out is not None and out.shape == (48, 64)
    assert np.abs(out.astype(int) - img).max() <= 4
    assert mjpeg_to_gray(b"not a jpeg") is None


def test_mjpeg_decodes_to_bgr() -> None:
    img = np.zeros((48, 64, 3), np.uint8)
    img[:, :32] = (200, 40, 10)  # blue on the left, red on the right
    img[:, 32:] = (10, 40, 200)
    ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    out = mjpeg_to_bgr(jpg.tobytes())
    assert out is not None and out.shape == (48, 64, 3)
    assert np.abs(out[4:-4, 4:28].astype(int) - (200, 40, 10)).max() <= 8
    assert np.abs(out[4:-4, 36:60].astype(int) - (10, 40, 200)).max() <= 8
    assert mjpeg_to_bgr(b"not a jpeg") is None
