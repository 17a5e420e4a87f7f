"""What a USB webcam does to a frame between the sensor and the host, each step optional.

* Rolling shutter: image row r (0 = top) starts exposing ``r * readout_s / H`` after row 0;
  the renderer casts every row at its own instants (``Quality.rolling_band_rows`` = 1), or,
  to save time, bands of that many rows at the instant of the band's middle row.
* Mains flicker: lamps on 50 Hz mains pulse at ``flicker_hz`` = 100 Hz; the scene brightness
  is ``1 - depth * (1 + cos(2 pi f t + phase)) / 2`` (t scene seconds), averaged exactly over
  each row's exposure, so with a rolling shutter it varies from row to row (dark bands).
* 4:2:2 chroma (YUYV): BT.601 full-range Y, Cb, Cr (as in JPEG) quantised to 8 bits, Cb and
  Cr averaged over each horizontal pixel pair (0-1, 2-3, ...), then back to BGR.
* MJPEG: JPEG encoding and decoding by OpenCV at ``mjpeg_quality`` (1..100; 0 = off).

The order is: radiance, flicker, photometric gain and noise, 8-bit rounding, 4:2:2, MJPEG.
Everything is deterministic.  Truth and ``t_ns`` stay the frame's nominal instant: the
instant row 0 starts its exposure (``readout_s`` is written to scene.json and truth.csv).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ._base import F64, U8


@dataclass(frozen=True)
class Transport:
    """Webcam transport options (all off by default: a global-shutter, lossless camera)."""

    rolling_shutter: bool = False
    readout_s: float = 0.030  # row 0 to row H of a rolling shutter (used when it is on)
    yuyv_422: bool = False
    mjpeg_quality: int = 0  # 0: off; else the JPEG quality, 1..100
    flicker_depth: float = 0.0  # 0: off; 1: the light goes fully dark at each trough
    flicker_hz: float = 100.0
    flicker_phase_rad: float = 0.0

    def __post_init__(self) -> None:
        if self.readout_s < 0.0:
            raise ValueError("Transport.readout_s must be >= 0")
        if not 0 <= self.mjpeg_quality <= 100:
            raise ValueError("Transport.mjpeg_quality must be 0 (off) or 1..100")
        if not 0.0 <= self.flicker_depth <= 1.0:
            raise ValueError("Transport.flicker_depth must lie in [0, 1]")

    @property
    def row_readout_s(self) -> float:
        """Readout time actually in effect: ``readout_s`` with a rolling shutter, else 0."""
        return self.readout_s if self.rolling_shutter else 0.0

    def row_starts_s(self, t_s: float, height_px: int) -> F64:
        """Exposure start of each row (H,), scene seconds, for a frame whose row 0 starts at t."""
        return np.asarray(t_s + np.arange(height_px) * (self.row_readout_s / height_px), np.float64)

    def flicker(self, row_starts_s: F64, exposure_s: float) -> F64:
        """Mean relative brightness of each row over its exposure (closed form)."""
        d = self.flicker_depth
        w = 2.0 * math.pi * self.flicker_hz
        ph = w * row_starts_s + self.flicker_phase_rad
        if exposure_s <= 0.0:
            mean_cos = np.cos(ph)
        else:
            mean_cos = (np.sin(ph + w * exposure_s) - np.sin(ph)) / (w * exposure_s)
        return np.asarray(1.0 - 0.5 * d * (1.0 + mean_cos))

    def encode(self, img: U8) -> U8:
        """Apply 4:2:2 chroma and MJPEG (as configured) to an 8-bit BGR frame."""
        out = img
        if self.yuyv_422:
            out = yuyv_422(out)
        if self.mjpeg_quality > 0:
            out = mjpeg(out, self.mjpeg_quality)
        return out


_TO_YCC = np.array(
    [[0.114, 0.587, 0.299], [0.5, -0.331264, -0.168736], [-0.081312, -0.418688, 0.5]]
)  # rows Y, Cb, Cr from columns B, G, R (BT.601 full range)
_FROM_YCC = np.array([[1.0, 1.772, 0.0], [1.0, -0.344136, -0.714136], [1.0, 0.0, 1.402]])


def to_ycc(img: U8) -> F64:
    """BT.601 full-range (Y, Cb, Cr) of a BGR image, not rounded; Cb, Cr centred on 128."""
    ycc = img.astype(np.float64) @ _TO_YCC.T
    ycc[..., 1:] += 128.0
    return np.asarray(ycc)


def yuyv_422(img: U8) -> U8:
    """BGR -> 8-bit Y, Cb, Cr -> chroma averaged over pixel pairs (YUYV) -> BGR, rounded."""
    ycc = np.clip(np.floor(to_ycc(img) + 0.5), 0.0, 255.0)
    w = img.shape[1]
    even = w - (w % 2)
    pair = ycc[:, :even, 1:].reshape(img.shape[0], even // 2, 2, 2).mean(axis=2)
    ycc[:, :even, 1:] = np.floor(np.repeat(pair, 2, axis=1) + 0.5)
    ycc[..., 1:] -= 128.0
    bgr = ycc @ _FROM_YCC.T
    return np.clip(np.floor(bgr + 0.5), 0.0, 255.0).astype(np.uint8)


def mjpeg(img: U8, quality: int) -> U8:
    """The frame after a JPEG round trip at ``quality`` (OpenCV's encoder and decoder)."""
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    out = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return np.asarray(out, dtype=np.uint8)
