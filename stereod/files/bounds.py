"""Physical bounds of every number a user can give: flags, the TOML config, ``STEREOD_*``
variables, calibration files and the chessboard.

Each :class:`Bound` holds its range, its unit and why: the reason comes from the physics of the
rig or from its hardware (a Minoru's baseline is 0.060 m; UVC webcams' lenses; a USB 2.0 bus),
and a value outside it is refused where it enters, in one line that names the flag, field or
file, the value, the range and that reason. :data:`BOUNDS` lists them all; the table under
"Bounds" in the documentation's configuration reference is :func:`markdown_table` of it.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pydantic import AfterValidator, BeforeValidator


@dataclass(frozen=True)
class Bound:
    """A closed range ``lo``..``hi`` in ``unit``; with ``zero_off`` a value of 0 is allowed
    too (it switches the setting off). ``where`` names the flags, fields and files it holds
    for; ``why`` is the physical or hardware reason for its ends."""

    where: tuple[str, ...]
    lo: float
    hi: float
    unit: str
    why: str
    zero_off: bool = False

    def range_text(self) -> str:
        """``0.005..10 m`` (with ``0 or`` in front when 0 switches it off)."""
        unit = f" {self.unit}" if self.unit else ""
        off = "0 or " if self.zero_off else ""
        return f"{off}{self.lo:g}..{self.hi:g}{unit}"

    def problem(self, value: float) -> str | None:
        """Why ``value`` is refused (``must be ...: why``), or None when it is inside."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            return f"must be a number in {self.range_text()}"
        if self.zero_off and value == 0:
            return None
        if math.isfinite(value) and self.lo <= value <= self.hi:
            return None
        return f"must be in {self.range_text()} ({self.why})"

    def check(self, value: Any) -> Any:
        """``value`` itself when inside; else ValueError with :meth:`problem`."""
        problem = self.problem(value)
        if problem is not None:
            raise ValueError(problem)
        return value

    def validator(self) -> AfterValidator:
        """A pydantic validator of a field (after its type is checked)."""
        return AfterValidator(self.check)

    def arg(self, *, integer: bool = False) -> Callable[[str], Any]:
        """An argparse type: the number the text writes, refused in one line (exit 64 by the
        parser) when it is not one or is outside."""

        def parse(text: str) -> float | int:
            try:
                value: float | int = int(text) if integer else float(text)
            except ValueError:
                kind = "a whole number" if integer else "a number"
                raise argparse.ArgumentTypeError(f"{text!r} is not {kind}") from None
            if not math.isfinite(value):
                raise argparse.ArgumentTypeError(
                    f"{text!r} must be a finite number in {self.range_text()} ({self.why})"
                )
            problem = self.problem(value)
            if problem is not None:
                raise argparse.ArgumentTypeError(f"{text}: {problem}")
            return value

        return parse


def not_bool(value: Any) -> Any:
    """Refuse true/false where a number is meant (pydantic would read true as 1): a TOML
    ``threshold = true`` is a mistake, not a threshold of one grey level."""
    if isinstance(value, bool):
        raise ValueError(f"must be a number, not {str(value).lower()}")
    if isinstance(value, list | tuple) and any(isinstance(v, bool) for v in value):
        raise ValueError("each component must be a number, not true/false")
    return value


NOT_BOOL = BeforeValidator(not_bool)
"""The before-validator of :func:`not_bool`, for numeric config fields."""


BASELINE_M = Bound(
    ("rig.baseline_m", "--baseline", "calibration baseline: norm of T, -P2[0][3]/P2[0][0]"),
    0.005,
    10.0,
    "m",
    "UVC camera boards cannot sit closer than 5 mm (a Minoru's eyes: 0.060 m); beyond 10 "
    "m two eyes share no view of a room; lengths are metres",
)
HFOV_DEG = Bound(
    ("rig.hfov_deg", "--hfov", "calibration K1, K2, P1, P2 focal lengths"),
    5.0,
    170.0,
    "deg",
    "UVC webcam lenses span about 20 (telephoto) to 170 deg (fisheye), 5 leaves room for "
    "a long lens; a pinhole diverges at 180 deg",
)
IMAGE_SIDE_PX = Bound(
    (
        "calibration image_size",
        "calibration import --size",
        "v4l2_minoru driver.options.width, height",
    ),
    16.0,
    8192.0,
    "px",
    "no camera mode is under 16 px a side; a UVC webcam's largest, 4K (3840x2160), fits "
    "USB 2.0 only as MJPEG: 8192 is twice its width",
)
SQUARE_M = Bound(
    ("--square", "calibration board.square"),
    0.0001,
    1.0,
    "m",
    "a webcam cannot see a printed square under 0.1 mm, and no one holds a board of 1 m "
    "squares in front of a rig; in metres, as every length",
)
MIN_BOARD_CORNERS = 3
"""The fewest inner corners a side of a chessboard may have: OpenCV's
``findChessboardCorners`` refuses fewer ("both width and height of the pattern should have
bigger than 2")."""
MIN_PAIRS = 6
"""``calibrate``'s default fewest usable chessboard pairs: fewer leave the focal length and
the lens distortion poorly fixed."""
MIN_ROOM_VIEWS = 3
"""``calibrate --room``'s default fewest board views each rig must have: one view's pose is
one noisy measurement of the rig-to-rig transform, a few average out."""
STATUS_PERIOD_S = Bound(
    ("daemon.status_period_s",),
    0.05,
    60.0,
    "s",
    "20 status messages a second is more than anyone reads (1e-9 s sent 4,400 a second at "
    "84 % CPU); a report a minute old is stale",
)
IMAGE_RATE_HZ = Bound(
    ("daemon.image_rate_hz",),
    0.01,
    120.0,
    "Hz",
    "no camera delivers over 120 frames a second (v4l2_minoru fps), so no more images "
    "exist; under one in 100 s is off, which is 0",
    zero_off=True,
)
TOLERANCE_MS = Bound(
    ("pairing.tolerance_ms",),
    0.1,
    1000.0,
    "ms",
    "two eyes on one USB 2.0 bus are stamped in 0.125 ms microframes, so less pairs "
    "nothing; 1 s spans a frame period even at 1 fps",
)
ABSORB_S = Bound(
    ("detector.absorb_s",),
    0.1,
    3600.0,
    "s",
    "under 0.1 s (3 frames at 30 fps) a moving object is learned as background; an hour is "
    "longer than lighting stays the same",
)
TIME_BASE_S = Bound(
    ("tracking.time_base_s", "--time-base"),
    0.01,
    60.0,
    "s",
    "tau of eq. 21 shorter than one frame at 100 fps measures noise, longer than a minute "
    "averages over a whole flight",
)
MAX_COAST_S = Bound(
    ("tracking.max_coast_s",),
    0.0,
    60.0,
    "s",
    "0 ends a track at its first miss; a prediction a minute old is a guess",
)
MAX_HIDDEN_S = Bound(
    ("tracking.max_hidden_s",),
    0.0,
    60.0,
    "s",
    "0 ends a hidden track like any other; an object a minute behind another is gone",
)
MAX_MEMBER_S = Bound(
    ("tracking.max_member_s",),
    0.0,
    600.0,
    "s",
    "0 ends a track taken into another's object at once (a box a robot pushed comes out of "
    "it with a new id); ten minutes inside another object and what comes out is another thing",
)
HOLD_STILL_S = Bound(
    ("tracking.hold_still_s",),
    0.0,
    86400.0,
    "s",
    "0 never holds a stopped object; longer than a day and a parked object is never learned",
)
STILL_AFTER_S = Bound(
    ("tracking.still_after_s",),
    0.1,
    3600.0,
    "s",
    "under 0.1 s (3 frames at 30 fps) a step's pause is a stop; an object still for an hour "
    "is part of the room",
)
READOUT_S = Bound(
    ("rig.readout_s",),
    0.0,
    0.1,
    "s",
    "0 is a global shutter; a rolling shutter reads a frame within its period, at most a "
    "tenth of a second at 10 fps",
)

THRESHOLD_GREY = Bound(
    ("detector.threshold", "--threshold"),
    0.5,
    255.0,
    "grey levels",
    "frames are 8-bit: under half a grey level every pixel's rounding is foreground, and no "
    "difference exceeds 255",
)
CENTROID_SIGMA_PX = Bound(
    ("matching.centroid_sigma_px",),
    0.001,
    10.0,
    "px",
    "no webcam blob's centroid is known to a thousandth of a pixel (less made the "
    "covariance singular); a 10 px error is no measurement",
)
MANOEUVRE_CHI2 = Bound(
    ("tracking.manoeuvre_chi2",),
    0.35,
    100.0,
    "",
    "chi-square of 3 dof: under its 5 % point, 0.35, almost every observation is a "
    "manoeuvre (1e-300 broke the filter); 100 never happens",
)

CAMERA_FPS = Bound(
    ("v4l2_minoru driver.options.fps",),
    1.0,
    120.0,
    "Hz",
    "no UVC webcam on USB 2.0 offers a mode slower than a frame a second or faster than 120 "
    "(a Minoru: 30 at 320x240, 15 at 640x480)",
)
CAMERA_RETRY_S = Bound(
    ("v4l2_minoru driver.options.retry_s, retry_max_s",),
    0.01,
    60.0,
    "s",
    "a USB device re-enumerates in tens of ms at best, so sooner only spins; a camera "
    "plugged back in should not wait over a minute",
)
CAMERA_TIMEOUT_S = Bound(
    ("v4l2_minoru driver.options.read_timeout_s",),
    0.01,
    10.0,
    "s",
    "a shorter wait for a frame only spins a core; a longer one delays a stop by as much",
)
CAMERA_STALL_S = Bound(
    ("v4l2_minoru driver.options.stall_s",),
    0.1,
    600.0,
    "s",
    "a frame period at 10 fps (keep it above the frame period at slower rates); ten "
    "minutes without frames is a camera that is gone",
)

PLAYBACK_RATE = Bound(
    ("--rate",),
    0.01,
    1000.0,
    "x real time",
    "0 plays as fast as it can; under 0.01 a replay stands still (1e-300 overflowed the "
    "wait for a frame); no pipeline keeps up with 1000",
    zero_off=True,
)

MAX_COORDINATE = 1e6
"""The largest position (m) or velocity component and speed (m/s) a run's or a truth's file
may hold for ``plot`` and ``export``: far beyond any scene a stereo webcam sees, well short of
what overflows a figure's axes or a consumer's arithmetic (1e308 does)."""
UTC_NS_MAX = 2**62
"""The latest UTC instant (ns since 1970, early in 2116) a stamp may carry: beyond it, a
replay's stream time or a fusion step's period added to it could pass the 64 bits that every
reader of the wire holds an integer in."""
UTC_START_NS_MAX = 4_102_444_800 * 10**9
"""The latest first instant (ns, 2100-01-01) a replay may be given: the stream time it adds
then stays within :data:`UTC_NS_MAX` for 16 years of recording."""
ROS_TIME_NS_MAX = (2**31 - 1) * 10**9 + 999_999_999
"""The latest instant (ns) a ROS 2 ``builtin_interfaces/Time`` holds (its seconds are int32:
2038-01-19): what an MCAP of ROS 2 messages can stamp."""


BOUNDS: tuple[Bound, ...] = (
    BASELINE_M,
    HFOV_DEG,
    IMAGE_SIDE_PX,
    SQUARE_M,
    STATUS_PERIOD_S,
    IMAGE_RATE_HZ,
    TOLERANCE_MS,
    ABSORB_S,
    TIME_BASE_S,
    MAX_COAST_S,
    MAX_HIDDEN_S,
    MAX_MEMBER_S,
    HOLD_STILL_S,
    STILL_AFTER_S,
    READOUT_S,
    THRESHOLD_GREY,
    CENTROID_SIGMA_PX,
    MANOEUVRE_CHI2,
    CAMERA_FPS,
    CAMERA_RETRY_S,
    CAMERA_TIMEOUT_S,
    CAMERA_STALL_S,
    PLAYBACK_RATE,
)
"""Every physical bound, in the order of the configuration reference's table."""


def focal_range_px(side_px: float) -> tuple[float, float]:
    """The focal lengths (px) that give a field of view within :data:`HFOV_DEG` over an image
    ``side_px`` px across: f = side / (2 tan(fov / 2))."""

    def focal(fov_deg: float) -> float:
        return side_px / (2.0 * math.tan(math.radians(fov_deg) / 2.0))

    return focal(HFOV_DEG.hi), focal(HFOV_DEG.lo)


def markdown_table() -> str:
    """The table of :data:`BOUNDS` (where each applies, its range and why), as the
    configuration reference shows it."""
    rows = ["| Flag, field or file | Allowed | Why |", "|---|---|---|"]
    for b in BOUNDS:
        where = ", ".join(f"`{w}`" for w in b.where)
        rows.append(f"| {where} | {b.range_text()} | {b.why} |")
    return "\n".join(rows) + "\n"
