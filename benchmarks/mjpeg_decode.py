"""What an MJPEG eye costs the driver: the decode time per frame, to grey and to BGR, beside
the YUYV conversions it replaces, and how large the frames are.

Renders colour frames of the synthetic scene (a textured wall, a ball, sensor noise), encodes
each with OpenCV at a webcam-like JPEG quality (75 by default), then times the driver's own
converters (:mod:`stereod_v4l2_minoru.convert`) on them: ``mjpeg_to_gray`` (libjpeg-turbo
decoding the luma only), ``mjpeg_to_bgr``, and, for reference, ``yuyv_to_gray`` and
``yuyv_to_bgr`` on the same frames as YUYV. Each is the median over the frames of one pass,
best of ``--repeat`` passes (other load on the machine only ever slows a pass down).

It also prints the frames' size in bits a pixel, and that of colour white noise at the same
quality: the worst a scene can do, against the 8 bits a pixel (1 byte) the USB 2.0 preflight
counts for an MJPEG frame (:mod:`stereod_v4l2_minoru.bandwidth`).

Usage: ``python benchmarks/mjpeg_decode.py [--frames N] [--quality Q] [--repeat R]``.
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time
from collections.abc import Callable

import cv2
import numpy as np

from stereod_fakes.synth import Ball, Renderer, Scene
from stereod_v4l2_minoru.convert import mjpeg_to_bgr, mjpeg_to_gray, yuyv_to_bgr, yuyv_to_gray

SIZES = ((320, 240), (640, 480))


def render(w: int, h: int, n: int) -> list[np.ndarray]:
    """``n`` colour left-eye frames (BGR uint8) with a ball crossing the view."""
    fps = 30.0
    ball = Ball(heading_deg=60, speed_mps=0.7, t_on_s=0.0, t_off_s=1e9, t_mid_s=n / 2 / fps)
    scene = Scene(
        width_px=w, height_px=h, fps=fps, duration_s=(n + 0.5) / fps, balls=[ball], color=True
    )
    return [left.image for left, _ in Renderer(scene).frames()][:n]


def to_yuyv(bgr: np.ndarray) -> bytes:
    """A BGR frame as the YUYV 4:2:2 bytes a camera would send (BT.601, chroma of each pixel
    pair averaged)."""
    yuv = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV).astype(np.uint16)
    h, w = yuv.shape[:2]
    out = np.empty((h, w, 2), np.uint8)
    out[..., 0] = yuv[..., 0]
    out[:, 0::2, 1] = (yuv[:, 0::2, 1] + yuv[:, 1::2, 1]) // 2
    out[:, 1::2, 1] = (yuv[:, 0::2, 2] + yuv[:, 1::2, 2]) // 2
    return out.tobytes()


def median_ms(fn: Callable[[bytes], object], data: list[bytes], repeat: int) -> float:
    """Best over ``repeat`` passes of the median time of ``fn`` on each item, ms."""
    best = float("inf")
    for _ in range(repeat):
        times = []
        for d in data:
            t0 = time.perf_counter()
            fn(d)
            times.append(time.perf_counter() - t0)
        best = min(best, statistics.median(times) * 1e3)
    return best


def bits_per_pixel(jpgs: list[bytes], w: int, h: int) -> float:
    return float(np.mean([len(j) for j in jpgs])) * 8 / (w * h)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60, help="frames per size (default 60)")
    ap.add_argument("--quality", type=int, default=75, help="JPEG quality (default 75)")
    ap.add_argument("--repeat", type=int, default=5, help="passes; best kept (default 5)")
    a = ap.parse_args()
    q = [cv2.IMWRITE_JPEG_QUALITY, a.quality]
    print(f"JPEG quality {a.quality}, {a.frames} frames, median of a pass, best of {a.repeat}")
    print(
        "| size | MJPEG to grey | MJPEG to BGR | YUYV to grey | YUYV to BGR | bits/px "
        "| white noise bits/px |"
    )
    print("|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    for w, h in SIZES:
        frames = render(w, h, a.frames)
        jpgs = [cv2.imencode(".jpg", f, q)[1].tobytes() for f in frames]
        yuyv = [to_yuyv(f) for f in frames]
        assert all(mjpeg_to_gray(j) is not None for j in jpgs)
        noise = [
            cv2.imencode(".jpg", rng.integers(0, 256, (h, w, 3), dtype=np.uint8), q)[1].tobytes()
            for _ in range(3)
        ]
        gray = median_ms(mjpeg_to_gray, jpgs, a.repeat)
        bgr = median_ms(mjpeg_to_bgr, jpgs, a.repeat)
        ygray = median_ms(functools.partial(yuyv_to_gray, width=w, height=h), yuyv, a.repeat)
        ybgr = median_ms(functools.partial(yuyv_to_bgr, width=w, height=h), yuyv, a.repeat)
        print(
            f"| {w}x{h} | {gray:.2f} ms | {bgr:.2f} ms | {ygray:.3f} ms | {ybgr:.3f} ms "
            f"| {bits_per_pixel(jpgs, w, h):.2f} | {bits_per_pixel(noise, w, h):.2f} |"
        )


if __name__ == "__main__":
    main()
