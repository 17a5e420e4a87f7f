"""A fake V4L2 kernel at the driver's IO seam (open, close, ioctl, mmap, wait_readable).

It answers the ioctls a capture device needs with a webcam's behaviour: YUYV at a few sizes
and rates, mmap buffers, frames whose timestamps advance by the frame period and whose
sequence numbers can skip, an error-flagged frame on request, ENOSPC on STREAMON when asked,
and ENODEV after :meth:`FakeKernel.unplug`.
"""

from __future__ import annotations

import ctypes
import errno
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stereod_v4l2_minoru import raw


@dataclass
class FakeCamera:
    """One /dev/video node's state."""

    width: int = 64
    height: int = 48
    fps: float = 30.0
    t0_ns: int = 5_000_000_000
    controls: dict[int, int] = field(
        default_factory=lambda: {
            raw.CONTROLS["exposure_auto"]: 3,
            raw.CONTROLS["exposure_absolute"]: 100,
            raw.CONTROLS["gain"]: 10,
            raw.CONTROLS["auto_white_balance"]: 1,
        }
    )
    skip_sequences: set[int] = field(default_factory=set)
    error_sequences: set[int] = field(default_factory=set)
    short_sequences: set[int] = field(default_factory=set)
    """Frames whose buffer comes back with half its bytes (a truncated transfer)."""
    clock_copy: bool = False
    """Stamp buffers with V4L2_BUF_FLAG_TIMESTAMP_COPY instead of MONOTONIC."""
    enospc_on_streamon: bool = False
    stall_after: int | None = None
    """From this sequence on the camera delivers nothing (its buffers never become readable)
    while it stays open; closing and streaming it again cures it, as a USB hiccup is."""
    present: bool = True
    streaming: bool = False
    buffers: list[bytearray] = field(default_factory=list)
    queued: list[int] = field(default_factory=list)
    next_seq: int = 0


class FakeKernel:
    """Implements the driver's ``IO`` protocol for a set of fake device nodes."""

    SIZES = ((64, 48), (320, 240), (640, 480))
    RATES = (15.0, 30.0)
    U, V = 90, 170
    """The chroma of every pixel (a reddish orange); the luma changes with the sequence."""

    def __init__(self, cameras: dict[str, FakeCamera]) -> None:
        self.cameras = cameras
        self._fds: dict[int, str] = {}
        self._next_fd = 100

    def unplug(self, path: str) -> None:
        self.cameras[path].present = False

    def replug(self, path: str) -> None:
        cam = self.cameras[path]
        cam.present, cam.streaming, cam.buffers, cam.queued = True, False, [], []
        cam.controls.update({raw.CONTROLS["exposure_auto"]: 3})

    def open(self, path: str) -> int:
        cam = self.cameras.get(path)
        if cam is None or not cam.present:
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", path)
        fd = self._next_fd
        self._next_fd += 1
        self._fds[fd] = path
        return fd

    def close(self, fd: int) -> None:
        self._fds.pop(fd, None)

    def _cam(self, fd: int) -> FakeCamera:
        cam = self.cameras[self._fds[fd]]
        if not cam.present:
            raise OSError(errno.ENODEV, "No such device")
        return cam

    def mmap(self, fd: int, length: int, offset: int) -> Any:
        return self._cam(fd).buffers[offset // 4096]

    def wait_readable(self, fd: int, timeout_s: float) -> bool:
        cam = self._cam(fd)
        if cam.stall_after is not None and cam.next_seq >= cam.stall_after:
            time.sleep(timeout_s)  # select() timing out
            return False
        return cam.streaming and bool(cam.queued)

    def ioctl(self, fd: int, request: int, arg: Any) -> None:
        cam = self._cam(fd)
        handler = getattr(self, "_" + {v: k for k, v in raw.REQUESTS.items()}[request].lower())
        handler(cam, arg)

    # -- ioctls --------------------------------------------------------------------------

    def _vidioc_querycap(self, cam: FakeCamera, c: raw.v4l2_capability) -> None:
        c.driver, c.card, c.bus_info = b"uvcvideo", b"Fake Vimicro", b"usb-fake"
        c.capabilities = raw.V4L2_CAP_VIDEO_CAPTURE | raw.V4L2_CAP_STREAMING

    def _vidioc_enum_fmt(self, cam: FakeCamera, d: raw.v4l2_fmtdesc) -> None:
        if d.index != 0:
            raise OSError(errno.EINVAL, "Invalid argument")
        d.pixelformat, d.description = raw.V4L2_PIX_FMT_YUYV, b"YUYV 4:2:2"

    def _vidioc_enum_framesizes(self, cam: FakeCamera, s: raw.v4l2_frmsizeenum) -> None:
        if s.index >= len(self.SIZES):
            raise OSError(errno.EINVAL, "Invalid argument")
        s.type = raw.V4L2_FRMSIZE_TYPE_DISCRETE
        s.discrete.width, s.discrete.height = self.SIZES[s.index]

    def _vidioc_enum_frameintervals(self, cam: FakeCamera, f: raw.v4l2_frmivalenum) -> None:
        if f.index >= len(self.RATES):
            raise OSError(errno.EINVAL, "Invalid argument")
        f.type = raw.V4L2_FRMIVAL_TYPE_DISCRETE
        f.discrete.numerator, f.discrete.denominator = 1, int(self.RATES[f.index])

    def _vidioc_s_fmt(self, cam: FakeCamera, f: raw.v4l2_format) -> None:
        w, h = f.fmt.pix.width, f.fmt.pix.height
        if (w, h) not in self.SIZES:
            w, h = self.SIZES[-1]
        cam.width, cam.height = w, h
        f.fmt.pix.width, f.fmt.pix.height = w, h
        f.fmt.pix.pixelformat = raw.V4L2_PIX_FMT_YUYV
        f.fmt.pix.bytesperline, f.fmt.pix.sizeimage = 2 * w, 2 * w * h

    def _vidioc_s_parm(self, cam: FakeCamera, p: raw.v4l2_streamparm) -> None:
        tpf = p.parm.capture.timeperframe
        cam.fps = tpf.denominator / tpf.numerator
        tpf.numerator, tpf.denominator = 1, int(round(cam.fps))

    def _vidioc_queryctrl(self, cam: FakeCamera, q: raw.v4l2_queryctrl) -> None:
        ids = sorted(cam.controls)
        want = q.id & ~raw.V4L2_CTRL_FLAG_NEXT_CTRL
        nxt = [i for i in ids if i > want] if q.id & raw.V4L2_CTRL_FLAG_NEXT_CTRL else [want]
        if not nxt or nxt[0] not in cam.controls:
            raise OSError(errno.EINVAL, "Invalid argument")
        q.id, q.name, q.minimum, q.maximum, q.step = nxt[0], b"ctrl", 0, 10000, 1

    def _vidioc_g_ctrl(self, cam: FakeCamera, c: raw.v4l2_control) -> None:
        c.value = cam.controls[c.id]

    def _vidioc_s_ctrl(self, cam: FakeCamera, c: raw.v4l2_control) -> None:
        if c.id not in cam.controls:
            raise OSError(errno.EINVAL, "Invalid argument")
        cam.controls[c.id] = c.value

    def _vidioc_reqbufs(self, cam: FakeCamera, r: raw.v4l2_requestbuffers) -> None:
        cam.buffers = [bytearray(2 * cam.width * cam.height) for _ in range(r.count)]
        cam.queued = []

    def _vidioc_querybuf(self, cam: FakeCamera, b: raw.v4l2_buffer) -> None:
        b.length, b.m.offset = len(cam.buffers[b.index]), b.index * 4096

    def _vidioc_qbuf(self, cam: FakeCamera, b: raw.v4l2_buffer) -> None:
        cam.queued.append(b.index)
        b.timestamp.tv_sec = b.timestamp.tv_usec = 0
        b.sequence = 0

    def _vidioc_dqbuf(self, cam: FakeCamera, b: raw.v4l2_buffer) -> None:
        if not cam.queued:
            raise OSError(errno.EAGAIN, "Resource temporarily unavailable")
        while cam.next_seq in cam.skip_sequences:
            cam.next_seq += 1
        seq = cam.next_seq
        cam.next_seq += 1
        index = cam.queued.pop(0)
        y = np.full((cam.height, cam.width), (seq * 7) % 200 + 20, np.uint8)
        uv = np.empty_like(y)
        uv[:, 0::2], uv[:, 1::2] = self.U, self.V  # YUYV: Y0 U Y1 V
        frame = np.stack([y, uv], axis=-1)
        cam.buffers[index][:] = frame.tobytes()
        t = cam.t0_ns + round(seq * 1e9 / cam.fps)
        used = len(cam.buffers[index]) // (2 if seq in cam.short_sequences else 1)
        b.index, b.bytesused, b.sequence = index, used, seq
        b.timestamp.tv_sec, b.timestamp.tv_usec = t // 1_000_000_000, (t % 1_000_000_000) // 1000
        b.flags = (
            raw.V4L2_BUF_FLAG_TIMESTAMP_COPY
            if cam.clock_copy
            else raw.V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC
        )
        if seq in cam.error_sequences:
            b.flags |= raw.V4L2_BUF_FLAG_ERROR

    def _vidioc_streamon(self, cam: FakeCamera, t: ctypes.c_int) -> None:
        if cam.enospc_on_streamon:
            raise OSError(errno.ENOSPC, "No space left on device")
        if cam.stall_after is not None and cam.next_seq >= cam.stall_after:
            cam.stall_after = None
        cam.streaming = True

    def _vidioc_streamoff(self, cam: FakeCamera, t: ctypes.c_int) -> None:
        cam.streaming = False
