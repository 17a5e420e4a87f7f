"""JPEG bytes for the driver tests, made by OpenCV's encoder, and their segments read apart
here (independently of the driver's own parser)."""

from __future__ import annotations

import cv2
import numpy as np


def encode(image: np.ndarray, quality: int = 90) -> bytes:
    """``image`` (grey or BGR) as a baseline JPEG, as ``cv2.imencode`` writes it."""
    ok, jpg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return jpg.tobytes()


def segments(jpg: bytes) -> list[tuple[int, bytes]]:
    """(marker, whole segment bytes) of each header segment after SOI, up to and with SOS."""
    assert jpg[:2] == b"\xff\xd8"
    out, i = [], 2
    while True:
        marker, length = jpg[i + 1], int.from_bytes(jpg[i + 2 : i + 4], "big")
        out.append((marker, jpg[i : i + 2 + length]))
        if marker == 0xDA:
            return out
        i += 2 + length


def strip_dht(jpg: bytes) -> bytes:
    """``jpg`` without its Huffman tables (every DHT segment before the scan), as many UVC
    cameras send Motion-JPEG frames."""
    head = segments(jpg)
    scan_at = 2 + sum(len(s) for _, s in head[:-1])
    kept = b"".join(s for m, s in head[:-1] if m != 0xC4)
    return jpg[:2] + kept + jpg[scan_at:]


def huffman_tables(jpg: bytes) -> dict[int, bytes]:
    """Each Huffman table of ``jpg``'s DHT segments by its class-and-id byte: the 16 counts and
    the values."""
    tables = {}
    for marker, seg in segments(jpg):
        if marker != 0xC4:
            continue
        body, i = seg[4:], 0
        while i < len(body):
            n = sum(body[i + 1 : i + 17])
            tables[body[i]] = body[i + 1 : i + 17 + n]
            i += 17 + n
    return tables


def scene(width: int, height: int, level: int = 120) -> np.ndarray:
    """A smooth BGR test image (JPEG keeps it within a few levels): a blue left half, a red
    right half, and a vertical brightness ramp from ``level``."""
    img = np.empty((height, width, 3), np.uint8)
    ramp = np.linspace(0, 40, height, dtype=np.float32)[:, None]
    img[:, : width // 2] = (200, 60, 20)
    img[:, width // 2 :] = (30, 60, 190)
    img[..., 1] = np.clip(level + ramp, 0, 255).astype(np.uint8)
    return img
