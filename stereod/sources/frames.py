"""Frames, stereo pairs and the one interface every frame source implements.

A driver (V4L2 camera, replay of files, synthetic renderer) opens a :class:`StereoSource`, which
hands out one :class:`EyeSource` per eye. The daemon reads each eye in its own thread when the
source is live, or merges the two by timestamp in one thread when it is a file (so nothing is
dropped and playback can be paced by the recorded timestamps).
"""

from __future__ import annotations

import enum
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from stereod.files.stop import check_stop


class Eye(str, enum.Enum):
    """Which camera of the rig a frame came from."""

    LEFT = "left"
    """The camera at x = -B/2 in the rig frame (on the left as the camera sees)."""
    RIGHT = "right"
    """The camera at x = +B/2 in the rig frame."""


@dataclass(frozen=True, slots=True)
class Frame:
    """One image from one eye.

    ``image`` is (h, w) uint8 luminance or (h, w, 3) uint8 BGR. ``t_ns`` is the capture instant on
    the source's monotonic clock (the kernel's CLOCK_MONOTONIC for cameras), never the time it
    was processed; ``seq`` is the source's frame sequence number (V4L2 ``sequence``).
    """

    eye: Eye
    image: np.ndarray
    t_ns: int
    seq: int

    def __post_init__(self) -> None:
        """Refuse what the detectors cannot read, with what to do, rather than failing deep
        inside OpenCV frames later; ``"left"``/``"right"`` are taken for the :class:`Eye`, and
        an image not laid out row by row (a transpose) is copied into one that is."""
        try:
            eye = Eye(self.eye)
        except ValueError:
            raise ValueError(f"eye must be 'left' or 'right', got {self.eye!r}") from None
        object.__setattr__(self, "eye", eye)
        image = self.image
        where = f"{eye.value} frame {self.seq}"
        if not isinstance(image, np.ndarray):
            raise TypeError(f"{where}: image must be a numpy array, got {type(image).__name__}")
        if image.dtype != np.uint8:
            raise TypeError(
                f"{where}: image must be uint8 (0-255), got {image.dtype}: scale it and "
                "convert with image.astype(np.uint8)"
            )
        if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)) or not image.size:
            hint = ""
            if image.ndim == 3 and image.shape[2] == 4:
                hint = ": drop alpha with cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)"
            raise ValueError(
                f"{where}: image must be grey (h, w) or BGR (h, w, 3), got shape "
                f"{image.shape}{hint}"
            )
        if not image.flags.c_contiguous:
            object.__setattr__(self, "image", np.ascontiguousarray(image))
        t = self.t_ns
        if isinstance(t, (bool, float)) or not isinstance(t, (int, np.integer)):
            raise TypeError(
                f"{where}: t_ns must be an integer count of nanoseconds, got "
                f"{t!r}: for seconds, use round(t * 1e9)"
            )
        if not -MAX_T_NS - 1 <= int(t) <= MAX_T_NS:
            raise ValueError(
                f"{where}: t_ns {int(t)} does not fit a clock's signed 64-bit count of "
                "nanoseconds (-2^63 to 2^63 - 1)"
            )
        object.__setattr__(self, "t_ns", int(t))


def frames_missed(last_seq: int | None, seq: int) -> int:
    """How many frames a camera took between its sequence numbers ``last_seq`` and ``seq`` that
    were never seen: 0 for the first frame, for the next one, and after the counter went back
    (a camera re-plugged counts from 0 again)."""
    return 0 if last_seq is None else max(int(seq) - int(last_seq) - 1, 0)


MAX_T_NS = 2**63 - 1
"""The largest capture instant (ns) a frame may carry (the least: -2^63): a clock's count fits
a signed 64-bit integer, as the kernel's timestamps and the wire format do. (A time line of
one's own may start below 0: a right eye stamped 10 ms before a left eye's 0.)"""

RETRY_FIRST_S = 0.1
"""Pause (s) before an eye whose reads keep failing is read again; doubles per failure in a
row, up to :data:`RETRY_MAX_S`. A lost camera's first retry is at once (its source reopens
it, with a backoff of its own); one that fails again without a frame between waits too, so a
camera that opens and then fails every read is not reopened thousands of times a second."""
RETRY_MAX_S = 5.0


@dataclass(frozen=True, slots=True)
class StereoPair:
    """A left and a right frame taken close enough in time to be triangulated together.

    ``skew_ns`` = right.t_ns - left.t_ns; ``t_ns`` is the midpoint of the two capture instants.
    """

    seq: int
    left: Frame
    right: Frame

    @classmethod
    def of(
        cls,
        left_image: np.ndarray,
        right_image: np.ndarray,
        t_left_ns: int,
        t_right_ns: int,
        seq: int = 0,
    ) -> StereoPair:
        """A pair from two images (uint8 grey (h, w) or BGR (h, w, 3)) and their capture
        instants (ns, one monotonic clock); both frames get sequence number ``seq``."""
        return cls(
            seq,
            Frame(Eye.LEFT, left_image, t_left_ns, seq),
            Frame(Eye.RIGHT, right_image, t_right_ns, seq),
        )

    @property
    def skew_ns(self) -> int:
        return self.right.t_ns - self.left.t_ns

    @property
    def t_ns(self) -> int:
        return (self.left.t_ns + self.right.t_ns) // 2


@dataclass
class EyeCounters:
    """What one eye's source counted since it opened, kept apart by kind.

    ``drops``: frames the camera took that never arrived (sequence gaps), by reason;
    ``errors``: frames that arrived unusable or were corrected (corrupt, undecodable, a
    timestamp not on CLOCK_MONOTONIC), by reason.
    """

    drops: dict[str, int] = field(default_factory=dict)
    errors: dict[str, int] = field(default_factory=dict)


class EyeSource(ABC):
    """Frames of one eye, in capture order."""

    eye: Eye

    @abstractmethod
    def read(self) -> Frame | None:
        """Block until the next frame; ``None`` at the end of a finite source.

        Raises :class:`stereod.errors.DeviceLost` when a live device went away (the next read
        reopens it), or another :class:`stereod.errors.StereodError` on a failure to report.
        """

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the eye's resources; idempotent."""

    def recover(self) -> None:
        """Start over after an unexpected failure of :meth:`read`, as after a re-plug: by
        default the eye is closed, and a live source reopens it on the next read."""
        self.close()

    def interrupt(self) -> None:  # noqa: B027 - optional hook
        """Make a blocked :meth:`read` return ``None`` soon (the daemon is stopping); called
        from another thread."""

    def counters(self) -> EyeCounters:
        """Drops and errors the source counted (none by default)."""
        return EyeCounters()


@dataclass
class SourceInfo:
    """What a source says of itself: image size (px), nominal rate (Hz), free-form settings."""

    width: int
    height: int
    fps: float | None
    live: bool
    description: str
    settings: dict[str, Any] = field(default_factory=dict)
    utc_offset_ns: int | None = None
    """Wall clock minus the source's monotonic clock (ns), when the source knows it."""
    inputs: list[Path] = field(default_factory=list)
    """Files the source reads (an output must never overwrite one of them)."""
    files: dict[str, str] = field(default_factory=dict)
    """Text files a recording of the source keeps beside its frames (name: text), such as a
    synthetic scene's truth."""


class StereoSource:
    """An opened stereo source: two eyes and a description. Use as a context manager."""

    def __init__(self, left: EyeSource, right: EyeSource, info: SourceInfo) -> None:
        self._left, self._right, self._info = left, right, info

    @property
    def info(self) -> SourceInfo:
        """Size, rate and whether frames arrive in real time from hardware (``live``)."""
        return self._info

    @property
    def left(self) -> EyeSource:
        return self._left

    @property
    def right(self) -> EyeSource:
        return self._right

    def problems(self) -> list[str]:
        """Non-fatal problems found while reading (for example a truncated video), one line each."""
        return []

    def final_problems(self) -> list[str]:
        """Problems that can only be said once reading has stopped (what a pass over a file
        cut short by the end of the run had found so far), one line each; none by default."""
        return []

    def close(self) -> None:
        self.left.close()
        self.right.close()

    def __enter__(self) -> StereoSource:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def merged(left: EyeSource, right: EyeSource) -> Iterator[Frame]:
    """Both eyes' frames in capture-time order, reading each eye only as needed (file sources:
    this is how they are fed to the pairer without dropping anything)."""
    heads = {Eye.LEFT: left.read(), Eye.RIGHT: right.read()}
    sources = {Eye.LEFT: left, Eye.RIGHT: right}
    while True:
        ready = [f for f in heads.values() if f is not None]
        if not ready:
            return
        frame = min(ready, key=lambda f: f.t_ns)
        check_stop()
        yield frame
        heads[frame.eye] = sources[frame.eye].read()


class Driver(ABC):
    """A named way to open a :class:`StereoSource`, registered in the ``stereod.drivers``
    entry-point group; its options come from the ``[driver.options]`` table of the config."""

    name: str = ""

    @abstractmethod
    def open(self) -> StereoSource:
        """Open the source; raise a :class:`stereod.errors.StereodError` naming what failed."""

    def inputs(self) -> list[Path]:
        """The files the source will read, known from the options before it is opened (a
        recording folder, videos, timestamp CSVs, device nodes), so that no output of the
        command is one of them; empty for a source that reads no file."""
        return []

    def frame_size(self) -> tuple[int, int] | None:
        """The (width, height) px of the frames the options ask for, known before the source
        is opened (so that ``run --check`` can hold a calibration against it); None when only
        the opened source knows."""
        return None

    def options_read(self) -> dict[str, Any] | None:
        """The options given, as the driver read them (``"15"`` from the environment as the
        number 15), for ``run --check`` to print; None to print them as given."""
        return None
