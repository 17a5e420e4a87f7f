"""One V4L2 video capture device: query, configure, stream through mmap buffers.

Every system call goes through :mod:`.ioctl`'s ``IO`` object, so tests can replace the kernel.
Foreign errors become :class:`~stereod.errors.DeviceError` naming the device and the fix;
``ENODEV``/``EIO`` while streaming become :class:`DeviceLost`, which the driver recovers from.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from types import TracebackType
from typing import Any, TypeVar

from stereod.errors import ConfigError, DeviceError, DeviceLost

from . import raw
from .ioctl import IO, SystemIO, xioctl

log = logging.getLogger(__name__)

_PICK_NODE = "point the eye at a camera's capture node (`stereod devices` lists them)"
"""The fix for a node that is not a camera's: a wrong path, which retrying will not mend."""

S = TypeVar("S", bound=ctypes.Structure)


@dataclass(frozen=True)
class Capture:
    """One dequeued frame: a copy of its bytes, the kernel's capture time and sequence."""

    data: bytes
    t_ns: int
    sequence: int
    error: bool
    monotonic: bool


@dataclass(frozen=True)
class Control:
    """A control as QUERYCTRL describes it."""

    id: int
    name: str
    minimum: int
    maximum: int
    step: int
    default: int


class V4L2Device:
    """A capture device node (``/dev/videoN``); use as a context manager."""

    def __init__(self, path: str, io: IO | None = None) -> None:
        self.path = path
        self.io: IO = io or SystemIO()
        self.fd: int | None = None
        self._buffers: list[Any] = []
        self._streaming = False
        self.width = 0
        self.height = 0
        self.pixelformat = 0

    # -- lifecycle -------------------------------------------------------------------------

    def open(self) -> V4L2Device:
        try:
            self.fd = self.io.open(self.path)
        except FileNotFoundError as exc:
            raise DeviceLost(f"{self.path}: no such device (is the camera plugged in?)") from exc
        except PermissionError as exc:
            raise DeviceError(
                f"{self.path}: permission denied: add the user to group 'video' or install the "
                "udev rules (stereod install-service)"
            ) from exc
        except OSError as exc:
            raise DeviceError(f"{self.path}: cannot open: {exc.strerror}") from exc
        try:
            caps = self.querycap()
        except DeviceError as exc:
            self.close()
            if isinstance(exc.__cause__, OSError) and exc.__cause__.errno == errno.ENOTTY:
                raise ConfigError(f"{self.path}: not a V4L2 device; {_PICK_NODE}") from exc
            raise
        if not caps["capabilities"] & raw.V4L2_CAP_VIDEO_CAPTURE:
            self.close()
            raise ConfigError(
                f"{self.path}: not a video capture device ({caps['card']}); {_PICK_NODE}"
            )
        return self

    def close(self) -> None:
        if self.fd is None:
            return
        try:
            self.stop()
        except DeviceError as exc:
            log.debug("%s: stop while closing: %s", self.path, exc)
        with contextlib.suppress(OSError):
            self.io.close(self.fd)
        self.fd = None

    def __enter__(self) -> V4L2Device:
        return self.open()

    def __exit__(
        self, et: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _ioctl(self, request: int, arg: Any, what: str) -> None:
        if self.fd is None:
            raise DeviceError(f"{self.path}: not open")
        try:
            xioctl(self.io, self.fd, request, arg)
        except OSError as exc:
            if exc.errno in (errno.ENODEV, errno.EIO, errno.ENXIO, errno.EBADF):
                raise DeviceLost(f"{self.path}: device lost during {what}: {exc.strerror}") from exc
            raise DeviceError(f"{self.path}: {what} failed: {exc.strerror}") from exc

    # -- queries ---------------------------------------------------------------------------

    def querycap(self) -> dict[str, Any]:
        cap = raw.v4l2_capability()
        self._ioctl(raw.VIDIOC_QUERYCAP, cap, "QUERYCAP")
        caps = cap.device_caps if cap.capabilities & raw.V4L2_CAP_DEVICE_CAPS else cap.capabilities
        return {
            "driver": cap.driver.decode(errors="replace"),
            "card": cap.card.decode(errors="replace"),
            "bus_info": cap.bus_info.decode(errors="replace"),
            "capabilities": caps,
        }

    def _enumerate(
        self, request: int, make: Callable[[int, S | None], S], what: str, limit: int = 256
    ) -> Iterator[S]:
        """Every struct an ENUM/QUERY ioctl fills: ``make(i, previous)`` builds the i-th
        request (an index, or the previous id with V4L2_CTRL_FLAG_NEXT_CTRL); the driver's
        EINVAL after the last one ends the loop (linuxpy's ``iter_read``)."""
        previous: S | None = None
        for i in range(limit):
            s = make(i, previous)
            try:
                self._ioctl(request, s, what)
            except DeviceLost:
                raise
            except DeviceError:
                return
            yield s
            previous = s

    def formats(self) -> list[tuple[str, str]]:
        """(fourcc, description) of every capture format."""
        return [
            (raw.fourcc_str(d.pixelformat), d.description.decode(errors="replace"))
            for d in self._enumerate(
                raw.VIDIOC_ENUM_FMT,
                lambda i, _: raw.v4l2_fmtdesc(index=i, type=raw.V4L2_BUF_TYPE_VIDEO_CAPTURE),
                "ENUM_FMT",
            )
        ]

    def frame_sizes(self, fourcc: str) -> list[tuple[int, int]]:
        """Discrete frame sizes (w, h) px of a format (a stepwise range: its two ends)."""
        out: list[tuple[int, int]] = []
        for s in self._enumerate(
            raw.VIDIOC_ENUM_FRAMESIZES,
            lambda i, _: raw.v4l2_frmsizeenum(index=i, pixel_format=raw.fourcc(fourcc)),
            "ENUM_FRAMESIZES",
        ):
            if s.type != raw.V4L2_FRMSIZE_TYPE_DISCRETE:
                sw = s.stepwise
                return [*out, (sw.min_width, sw.min_height), (sw.max_width, sw.max_height)]
            out.append((s.discrete.width, s.discrete.height))
        return out

    def frame_rates(self, fourcc: str, width: int, height: int) -> list[float]:
        """Discrete frame rates (Hz) of a format and size."""
        out: list[float] = []
        for f in self._enumerate(
            raw.VIDIOC_ENUM_FRAMEINTERVALS,
            lambda i, _: raw.v4l2_frmivalenum(
                index=i, pixel_format=raw.fourcc(fourcc), width=width, height=height
            ),
            "ENUM_FRAMEINTERVALS",
        ):
            if f.type != raw.V4L2_FRMIVAL_TYPE_DISCRETE:
                break
            if f.discrete.numerator:
                out.append(f.discrete.denominator / f.discrete.numerator)
        return out

    def controls(self) -> list[Control]:
        """Every enabled control."""
        return [
            Control(
                q.id, q.name.decode(errors="replace"), q.minimum, q.maximum, q.step, q.default_value
            )
            for q in self._enumerate(
                raw.VIDIOC_QUERYCTRL,
                lambda _, prev: raw.v4l2_queryctrl(
                    id=(prev.id if prev is not None else 0) | raw.V4L2_CTRL_FLAG_NEXT_CTRL
                ),
                "QUERYCTRL",
            )
            if not q.flags & raw.V4L2_CTRL_FLAG_DISABLED
        ]

    def get_control(self, cid: int) -> int:
        c = raw.v4l2_control(id=cid)
        self._ioctl(raw.VIDIOC_G_CTRL, c, f"G_CTRL {cid:#x}")
        return int(c.value)

    def set_control(self, cid: int, value: int) -> None:
        c = raw.v4l2_control(id=cid, value=value)
        self._ioctl(raw.VIDIOC_S_CTRL, c, f"S_CTRL {cid:#x}")

    # -- configuration ---------------------------------------------------------------------

    def set_format(self, width: int, height: int, fourcc: str) -> None:
        """S_FMT; the device must accept exactly this size and format."""
        f = raw.v4l2_format(type=raw.V4L2_BUF_TYPE_VIDEO_CAPTURE)
        f.fmt.pix.width, f.fmt.pix.height = width, height
        f.fmt.pix.pixelformat = raw.fourcc(fourcc)
        f.fmt.pix.field = raw.V4L2_FIELD_NONE
        self._ioctl(raw.VIDIOC_S_FMT, f, f"S_FMT {width}x{height} {fourcc}")
        got = (f.fmt.pix.width, f.fmt.pix.height, raw.fourcc_str(f.fmt.pix.pixelformat))
        if got != (width, height, fourcc):
            raise DeviceError(
                f"{self.path}: asked for {width}x{height} {fourcc}, the device gives "
                f"{got[0]}x{got[1]} {got[2]}: pick a mode from `stereod devices`"
            )
        self.width, self.height, self.pixelformat = width, height, f.fmt.pix.pixelformat

    def set_fps(self, fps: float) -> float:
        """S_PARM with 1/fps per frame; returns the rate the device chose (Hz)."""
        p = raw.v4l2_streamparm(type=raw.V4L2_BUF_TYPE_VIDEO_CAPTURE)
        p.parm.capture.timeperframe.numerator = 1000
        p.parm.capture.timeperframe.denominator = int(round(fps * 1000))
        self._ioctl(raw.VIDIOC_S_PARM, p, f"S_PARM {fps:g} fps")
        tpf = p.parm.capture.timeperframe
        return tpf.denominator / tpf.numerator if tpf.numerator else fps

    # -- streaming -------------------------------------------------------------------------

    def start(self, n_buffers: int = 4) -> None:
        """REQBUFS, mmap and queue every buffer, STREAMON."""
        req = raw.v4l2_requestbuffers(
            count=n_buffers, type=raw.V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=raw.V4L2_MEMORY_MMAP
        )
        self._ioctl(raw.VIDIOC_REQBUFS, req, "REQBUFS")
        if req.count < 2:
            raise DeviceError(f"{self.path}: only {req.count} buffer(s) granted")
        assert self.fd is not None
        for i in range(req.count):
            b = self._buffer(i)
            self._ioctl(raw.VIDIOC_QUERYBUF, b, "QUERYBUF")
            try:
                self._buffers.append(self.io.mmap(self.fd, b.length, b.m.offset))
            except OSError as exc:
                raise DeviceError(f"{self.path}: mmap failed: {exc.strerror}") from exc
            self._ioctl(raw.VIDIOC_QBUF, b, "QBUF")
        try:
            self._ioctl(
                raw.VIDIOC_STREAMON, ctypes.c_int(raw.V4L2_BUF_TYPE_VIDEO_CAPTURE), "STREAMON"
            )
        except DeviceLost:
            raise
        except DeviceError as exc:
            cause = exc.__cause__
            if isinstance(cause, OSError) and cause.errno == errno.ENOSPC:
                raise DeviceError(
                    f"{self.path}: not enough USB bandwidth for "
                    f"{self.width}x{self.height} {raw.fourcc_str(self.pixelformat)}: both eyes "
                    'of a Minoru share one USB 2.0 hub; set pixel_format = "mjpeg", or use '
                    "640x480 at 15 fps or 320x240 at 30 fps (YUYV)"
                ) from exc
            raise
        self._streaming = True

    def _buffer(self, index: int) -> raw.v4l2_buffer:
        return raw.v4l2_buffer(
            index=index, type=raw.V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=raw.V4L2_MEMORY_MMAP
        )

    def read(self, timeout_s: float = 1.0) -> Capture | None:
        """The next frame (its bytes copied, the buffer re-queued), or ``None`` on timeout."""
        assert self.fd is not None
        try:
            ready = self.io.wait_readable(self.fd, timeout_s)
        except OSError as exc:
            raise DeviceLost(f"{self.path}: device lost: {exc.strerror}") from exc
        if not ready:
            return None
        b = self._buffer(0)
        try:
            self._ioctl(raw.VIDIOC_DQBUF, b, "DQBUF")
        except DeviceLost:
            raise
        except DeviceError as exc:
            cause = exc.__cause__
            if isinstance(cause, OSError) and cause.errno == errno.EAGAIN:
                return None
            raise
        # Read everything before re-queueing: QBUF writes the (now queued) buffer state back
        # into the same struct, with the timestamp and sequence cleared.
        t_ns = b.timestamp.tv_sec * 1_000_000_000 + b.timestamp.tv_usec * 1000
        flags, sequence = int(b.flags), int(b.sequence)
        try:
            data = bytes(self._buffers[b.index][: b.bytesused])
        finally:
            self._ioctl(raw.VIDIOC_QBUF, b, "QBUF")
        mono = (flags & raw.V4L2_BUF_FLAG_TIMESTAMP_MASK) == raw.V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC
        return Capture(data, t_ns, sequence, bool(flags & raw.V4L2_BUF_FLAG_ERROR), mono)

    def stop(self) -> None:
        """STREAMOFF and release the buffers (idempotent)."""
        if self._streaming:
            self._streaming = False
            self._ioctl(
                raw.VIDIOC_STREAMOFF, ctypes.c_int(raw.V4L2_BUF_TYPE_VIDEO_CAPTURE), "STREAMOFF"
            )
        for m in self._buffers:
            close = getattr(m, "close", None)
            if close is not None:
                close()
        if self._buffers:
            self._buffers = []
            req = raw.v4l2_requestbuffers(
                count=0, type=raw.V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=raw.V4L2_MEMORY_MMAP
            )
            with contextlib.suppress(DeviceError):
                self._ioctl(raw.VIDIOC_REQBUFS, req, "REQBUFS 0")
