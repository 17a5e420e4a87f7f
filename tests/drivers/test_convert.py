"""Pixel format conversion against OpenCV's own converters."""

from __future__ import annotations

import cv2
import numpy as np

from stereod_v4l2_minoru.convert import (
    STANDARD_DHT,
    has_huffman_tables,
    mjpeg_to_bgr,
    mjpeg_to_gray,
    with_standard_huffman,
    yuyv_to_bgr,
    yuyv_to_gray,
)

from .jpegs import encode, huffman_tables, scene, segments, strip_dht


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


def test_mjpeg_bad_frames_are_none_never_an_exception() -> None:
    """What a UVC camera can hand over as an MJPEG frame without flagging it: nothing
    (bytesused 0), a frame cut short (no EOI, or cut mid-scan), a header cut before its scan,
    bytes that are no JPEG at all. Each is ``None``, for the driver to count and skip."""
    jpg = encode(scene(64, 48))
    head = sum(len(s) for _, s in segments(jpg))
    bad = {
        "empty": b"",
        "no EOI": jpg[:-2],
        "half the scan": jpg[: (head + len(jpg)) // 2],
        "header only": jpg[:head],
        "half the header": jpg[: head // 2],
        "not a JPEG": bytes(range(256)) * 8,
        "SOI then zeros": b"\xff\xd8" + bytes(1000),
    }
    for name, data in bad.items():
        assert mjpeg_to_gray(data) is None, name
        assert mjpeg_to_bgr(memoryview(data)) is None, name
    assert mjpeg_to_bgr(jpg) is not None


def test_standard_huffman_tables_are_the_encoders() -> None:
    """The inserted tables are JPEG Annex K.3's, which is what libjpeg's encoder (OpenCV's
    imencode without optimisation) writes: compared table by table."""
    want = huffman_tables(encode(scene(64, 48)))
    assert set(want) == {0x00, 0x01, 0x10, 0x11}
    assert huffman_tables(b"\xff\xd8" + STANDARD_DHT + b"\xff\xda\x00\x02") == want


def test_a_frame_without_huffman_tables_decodes_to_the_same_pixels() -> None:
    """Many UVC cameras leave the DHT out of every MJPEG frame. Stripped from an OpenCV
    JPEG, such a frame decodes (grey and BGR) to exactly the pixels the whole one does, and
    with the standard tables put back it is a JPEG any decoder takes, again the same pixels."""
    jpg = encode(scene(64, 48), quality=75)
    bare = strip_dht(jpg)
    assert has_huffman_tables(jpg) and not has_huffman_tables(bare)
    assert len(bare) < len(jpg)
    whole = np.frombuffer(jpg, np.uint8)
    np.testing.assert_array_equal(mjpeg_to_bgr(bare), cv2.imdecode(whole, cv2.IMREAD_COLOR))
    np.testing.assert_array_equal(mjpeg_to_gray(bare), cv2.imdecode(whole, cv2.IMREAD_GRAYSCALE))
    fixed = with_standard_huffman(bare)
    assert fixed is not None and has_huffman_tables(fixed)
    assert [m for m, _ in segments(fixed)][-2:] == [0xC4, 0xDA]  # just before the scan
    np.testing.assert_array_equal(mjpeg_to_bgr(fixed), mjpeg_to_bgr(jpg))
    assert with_standard_huffman(b"not a jpeg") is None
