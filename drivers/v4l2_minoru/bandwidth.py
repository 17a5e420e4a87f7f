"""Whether both eyes fit one USB 2.0 bus, before either is opened: the isochronous time each
eye's stream reserves in every 125 us microframe, as Linux's EHCI scheduler counts it.

Both eyes of a Minoru sit behind its own USB 2.0 hub, so they share one high-speed bus whatever
port it is plugged into. A UVC camera streams through an isochronous endpoint whose packet size
it picks from its descriptors for the mode asked for, and the host reserves that packet's time
in every microframe for as long as it streams, used or not. The model here:

- bytes per microframe an eye must move: its worst-case frame size (bytes) times the frame rate
  (Hz), over 8000 microframes a second, plus the 12-byte UVC payload header;
- the camera reserves whole 1024-byte transactions for that (``wMaxPacketSize`` 1024, times 1,
  2 or 3 per microframe): the largest packet a high-speed endpoint has, as cameras' alternate
  settings come, and the floor uvcvideo itself applies when it estimates a camera's bandwidth;
- each reservation costs ``HS_USECS_ISO(1024 * mult)`` us of bus time (``include/linux/usb/
  hcd.h``: protocol overhead plus worst-case bit stuffing, 7/6 of the bits);
- the periodic transfers of a microframe get 100 us of its 125 (USB 2.0 sec. 5.6.4: 80 %;
  EHCI's ``uframe_periodic_max`` default), shared by both eyes.

The worst case of a frame: YUYV is exactly 2 bytes a pixel. An MJPEG frame varies with the
scene; its descriptor's ``dwMaxVideoFrameBufferSize`` is on such cameras the uncompressed size
(a buffer bound, not the rate a compressed stream needs: counting it would deny MJPEG the
modes it exists for), so :data:`MJPEG_WORST_BYTES_PER_PIXEL` takes 1 byte a pixel, half of
YUYV: more than white noise needs at webcam quality (6.1 bits a pixel at JPEG quality 85, 4.8
at 75, colour noise at 640x480; a real scene with sensor noise: 0.9 to 1.5).

So: 640x480 YUYV at 30 Hz takes 3 transactions (61 us) an eye, 122 us for two, and does not
fit; at 15 Hz 2 (41 us) an eye, 82 us, and fits, as does 320x240 at 30 Hz (1, 21 us); 640x480
MJPEG at 30 Hz is 2 transactions an eye even at its worst, 82 us, and fits.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Literal

MICROFRAMES_PER_S = 8000
"""High-speed USB microframes a second (one every 125 us)."""
PERIODIC_BUDGET_US = 100
"""Isochronous and interrupt time of one microframe, us: 80 % of 125 (USB 2.0 sec. 5.6.4)."""
UVC_HEADER_BYTES = 12
"""The UVC payload header of each isochronous packet, bytes (as uvcvideo assumes)."""
TRANSACTION_BYTES = 1024
"""The largest high-speed isochronous packet, bytes."""
MAX_TRANSACTIONS = 3
"""The most transactions a high-bandwidth endpoint has in one microframe."""
MJPEG_WORST_BYTES_PER_PIXEL = 1.0
"""The largest MJPEG frame counted, bytes a pixel (half of YUYV's 2; see the module's text)."""

Format = Literal["yuyv", "mjpeg"]
FOURCC: dict[str, str] = {"yuyv": "YUYV", "mjpeg": "MJPG"}
"""The V4L2 fourcc each setting of ``pixel_format`` streams."""


def hs_usecs_iso(nbytes: int) -> int:
    """Bus time one high-speed isochronous transfer of ``nbytes`` takes, us, rounded up: the
    kernel's ``HS_USECS_ISO`` (38 bytes of protocol, worst-case bit stuffing at 2.083 ns a bit,
    5 ns of host delay)."""
    bit_time = 7 * 8 * nbytes // 6
    ns = (38 * 8 * 2083 + 2083 * (3 + bit_time)) // 1000 + 5
    return -(-ns // 1000)


def frame_bytes(fmt: Format, width: int, height: int) -> int:
    """The largest frame of a format counted, bytes: YUYV 2 a pixel, MJPEG
    :data:`MJPEG_WORST_BYTES_PER_PIXEL`."""
    per_pixel = 2.0 if fmt == "yuyv" else MJPEG_WORST_BYTES_PER_PIXEL
    return math.ceil(width * height * per_pixel)


@dataclass(frozen=True)
class EyeReservation:
    """What one eye's stream reserves in every microframe."""

    bytes_per_microframe: int
    """Payload plus UVC header one microframe must carry, bytes."""
    transactions: int
    """Whole 1024-byte transactions reserved for it (more than 3: the stream cannot run)."""
    usecs: int
    """Bus time of those transactions, us of each 125 us microframe."""


def reservation(fmt: Format, width: int, height: int, fps: float) -> EyeReservation:
    """One eye's reservation at ``width`` x ``height`` px and ``fps`` Hz."""
    per_microframe = frame_bytes(fmt, width, height) * fps / MICROFRAMES_PER_S
    if not math.isfinite(per_microframe):  # an infinite rate: more than any bus
        per_microframe = float(sys.maxsize)
    need = math.ceil(per_microframe) + UVC_HEADER_BYTES
    mult = -(-need // TRANSACTION_BYTES)
    return EyeReservation(need, mult, hs_usecs_iso(TRANSACTION_BYTES * mult))


def fits(fmt: Format, width: int, height: int, fps: float, eyes: int = 2) -> bool:
    """Whether ``eyes`` streams of this mode fit one USB 2.0 bus's periodic time."""
    r = reservation(fmt, width, height, fps)
    return r.transactions <= MAX_TRANSACTIONS and eyes * r.usecs <= PERIODIC_BUDGET_US


def describe(fmt: Format, width: int, height: int, fps: float, eyes: int = 2) -> str:
    """Why a mode does not fit, in a clause: what the eyes reserve against the budget."""
    r = reservation(fmt, width, height, fps)
    mode = f"{width}x{height} {FOURCC[fmt]} at {fps:g} fps"
    if r.transactions > MAX_TRANSACTIONS:
        return (
            f"{mode} needs {r.bytes_per_microframe} bytes per 125 us microframe an eye, more "
            f"than one USB 2.0 endpoint carries ({MAX_TRANSACTIONS * TRANSACTION_BYTES})"
        )
    return (
        f"{mode} reserves {r.usecs} us of every 125 us USB 2.0 microframe an eye, "
        f"{eyes * r.usecs} us for both, over the {PERIODIC_BUDGET_US} us a bus gives "
        "isochronous streams"
    )


def resolve(setting: str, width: int, height: int, fps: float) -> Format:
    """The format a ``pixel_format`` setting (``yuyv``, ``mjpeg`` or ``auto``) streams:
    ``auto`` is YUYV when both eyes fit the bus uncompressed, else MJPEG."""
    if setting == "auto":
        return "yuyv" if fits("yuyv", width, height, fps) else "mjpeg"
    if setting in ("yuyv", "mjpeg"):
        return "yuyv" if setting == "yuyv" else "mjpeg"
    raise ValueError(f"unknown pixel format {setting!r}: use yuyv, mjpeg or auto")


def choose(setting: str, width: int, height: int, fps: float) -> Format:
    """:func:`resolve`, checked: raises ``ValueError`` with a one-line reason and what to do
    when both eyes in the format it picks do not fit one USB 2.0 bus."""
    fmt = resolve(setting, width, height, fps)
    if fits(fmt, width, height, fps):
        return fmt
    why = describe(fmt, width, height, fps)
    if fmt == "yuyv" and fits("mjpeg", width, height, fps):
        fix = 'set pixel_format = "mjpeg" (or "auto"), or lower the size or rate'
    else:
        fix = "lower the size or rate"
    raise ValueError(f"{why}; {fix} (640x480 at 15 fps and 320x240 at 30 fps fit as YUYV)")
