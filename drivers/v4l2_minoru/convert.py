"""Pixel formats to what the pipeline needs: BGR (for colour differencing, the detector's
default) or grey (the luminance of eq. 2).

YUYV carries the BT.601 luma Y of every pixel at even byte offsets, so grey is a copy of those
bytes (0.06 ms at 640x480) and BGR one conversion (0.16 ms); MJPEG decodes straight to either
through OpenCV (libjpeg-turbo), grey being the cheaper (``benchmarks/mjpeg_decode.py``).

UVC cameras send Motion-JPEG frames that often lack their Huffman tables (no DHT segment: the
AVI1 convention is that the standard tables of JPEG Annex K.3 apply). A frame that does not
decode and has no DHT gets those tables inserted and is decoded again.
"""

from __future__ import annotations

import cv2
import numpy as np

_SOI, _SOS, _DHT = 0xD8, 0xDA, 0xC4


def _table(tc_th: int, counts: list[int], values: list[int]) -> bytes:
    """One Huffman table of a DHT segment: class and id, 16 code-length counts, the values."""
    assert len(counts) == 16 and sum(counts) == len(values)
    return bytes([tc_th, *counts, *values])


_AC_LUMA_VALUES = bytes.fromhex(
    "01020300041105122131410613516107227114328191a1082342b1c11552d1f02433627282090a161718191a"
    "25262728292a3435363738393a434445464748494a535455565758595a636465666768696a73747576777879"
    "7a838485868788898a92939495969798999aa2a3a4a5a6a7a8a9aab2b3b4b5b6b7b8b9bac2c3c4c5c6c7c8c9"
    "cad2d3d4d5d6d7d8d9dae1e2e3e4e5e6e7e8e9eaf1f2f3f4f5f6f7f8f9fa"
)
_AC_CHROMA_VALUES = bytes.fromhex(
    "000102031104052131061241510761711322328108144291a1b1c109233352f0156272d10a162434e125f117"
    "18191a262728292a35363738393a434445464748494a535455565758595a636465666768696a737475767778"
    "797a82838485868788898a92939495969798999aa2a3a4a5a6a7a8a9aab2b3b4b5b6b7b8b9bac2c3c4c5c6c7"
    "c8c9cad2d3d4d5d6d7d8d9dae2e3e4e5e6e7e8e9eaf2f3f4f5f6f7f8f9fa"
)
_TABLES = b"".join(
    [
        _table(0x00, [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0], list(range(12))),
        _table(0x10, [0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 0x7D], list(_AC_LUMA_VALUES)),
        _table(0x01, [0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0], list(range(12))),
        _table(0x11, [0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 0x77], list(_AC_CHROMA_VALUES)),
    ]
)
STANDARD_DHT = bytes([0xFF, _DHT]) + (len(_TABLES) + 2).to_bytes(2, "big") + _TABLES
"""One DHT segment with the four standard Huffman tables (JPEG Annex K.3: DC and AC, luma
and chroma), the tables a Motion-JPEG frame without its own implies."""


def _segments_before_scan(data: bytes) -> list[tuple[int, int]]:
    """(marker, offset) of each segment from SOI up to and including SOS; empty when ``data``
    is not a JPEG or its header is cut short."""
    if len(data) < 4 or data[0] != 0xFF or data[1] != _SOI:
        return []
    out, i = [], 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return []
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte before a marker
            i += 1
            continue
        out.append((marker, i))
        if marker == _SOS:
            return out
        i += 2 + int.from_bytes(data[i + 2 : i + 4], "big")
    return []


def has_huffman_tables(data: bytes) -> bool:
    """Whether a JPEG's header (before its scan) holds a DHT segment."""
    return any(m == _DHT for m, _ in _segments_before_scan(data))


def with_standard_huffman(data: bytes) -> bytes | None:
    """``data`` with :data:`STANDARD_DHT` inserted before its scan (SOS); ``None`` when it is
    not a JPEG whose header reaches a scan."""
    sos = [i for m, i in _segments_before_scan(data) if m == _SOS]
    if not sos:
        return None
    return data[: sos[0]] + STANDARD_DHT + data[sos[0] :]


def _decode(data: bytes | memoryview | np.ndarray, flags: int) -> np.ndarray | None:
    buf = np.frombuffer(data, dtype=np.uint8)
    if buf.size == 0:
        return None
    try:
        image = cv2.imdecode(buf, flags)
    except cv2.error:
        return None
    if image is None:
        raw = buf.tobytes()
        if has_huffman_tables(raw):
            return None
        fixed = with_standard_huffman(raw)
        if fixed is None:
            return None
        try:
            image = cv2.imdecode(np.frombuffer(fixed, dtype=np.uint8), flags)
        except cv2.error:
            return None
    return image


def yuyv_to_gray(data: bytes | memoryview | np.ndarray, width: int, height: int) -> np.ndarray:
    """(h, w) uint8 luma of a YUYV 4:2:2 frame (2 bytes per pixel)."""
    a = np.frombuffer(data, dtype=np.uint8, count=width * height * 2).reshape(height, width, 2)
    return cv2.cvtColor(a, cv2.COLOR_YUV2GRAY_YUYV)


def yuyv_to_bgr(data: bytes | memoryview | np.ndarray, width: int, height: int) -> np.ndarray:
    """(h, w, 3) uint8 BGR of a YUYV frame."""
    a = np.frombuffer(data, dtype=np.uint8, count=width * height * 2).reshape(height, width, 2)
    return cv2.cvtColor(a, cv2.COLOR_YUV2BGR_YUYV)


def mjpeg_to_gray(data: bytes | memoryview | np.ndarray) -> np.ndarray | None:
    """(h, w) uint8 grey of one MJPEG frame, decoded straight to luma (no colour is built);
    ``None`` when it does not decode (empty, corrupt, cut short before its EOI)."""
    return _decode(data, cv2.IMREAD_GRAYSCALE)


def mjpeg_to_bgr(data: bytes | memoryview | np.ndarray) -> np.ndarray | None:
    """(h, w, 3) uint8 BGR of one MJPEG frame; ``None`` when it does not decode."""
    return _decode(data, cv2.IMREAD_COLOR)
