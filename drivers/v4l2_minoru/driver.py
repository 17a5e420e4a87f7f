"""The ``v4l2_minoru`` driver: both eyes of a Minoru streamed through V4L2, one thread each.

Each eye is configured the same way (size, rate, pixel format, and controls: manual exposure,
gain and white balance, so the background model is not fooled by auto exposure), and again
after every re-plug. Frames carry the kernel's CLOCK_MONOTONIC capture time and V4L2 sequence
number; sequence gaps, frames flagged as corrupt and MJPEG frames that do not decode are
counted. When an eye's device goes away (ENODEV, EIO, the node vanishes)
:meth:`CameraEye.read` raises :class:`~stereod.errors.DeviceLost` once, then keeps trying to
reopen it with a growing backoff, finding it again by its udev name or hub port, and streams
on when it is back.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from stereod.errors import ConfigError, DeviceError, DeviceLost, describe_validation_error
from stereod.files.bounds import (
    CAMERA_FPS,
    CAMERA_RETRY_S,
    CAMERA_STALL_S,
    CAMERA_TIMEOUT_S,
    IMAGE_SIDE_PX,
    NOT_BOOL,
)
from stereod.sources.frames import (
    Driver,
    Eye,
    EyeCounters,
    EyeSource,
    Frame,
    SourceInfo,
    StereoSource,
    frames_missed,
)

from . import bandwidth, raw
from .convert import mjpeg_to_bgr, mjpeg_to_gray, yuyv_to_bgr, yuyv_to_gray
from .device import V4L2Device
from .discovery import find_nodes, minoru_eyes
from .ioctl import IO

log = logging.getLogger(__name__)

NODE_POLL_S = 0.1
"""How often an eye whose node has gone looks for it again, s (a stat of a path or two)."""
INTERRUPT_S = 0.1
"""Longest single wait (s) for a frame: a read waits ``read_timeout_s`` in slices this long,
so that a stop ends it within this (the daemon leaves an eye behind after 1 s)."""


class MinoruOptions(BaseModel):
    """The ``[driver.options]`` of ``v4l2_minoru``."""

    model_config = ConfigDict(extra="forbid")

    left: str | None = Field(
        None,
        description="Left eye node; default /dev/minoru/left, else the Minoru eye on hub port 1",
    )
    right: str | None = Field(
        None,
        description="Right eye node; default /dev/minoru/right, else the Minoru eye on hub port 2",
    )
    # Bounds and their reasons (UVC modes, a USB 2.0 bus): stereod.files.bounds.
    width: Annotated[int, NOT_BOOL, IMAGE_SIDE_PX.validator()] = 640
    height: Annotated[int, NOT_BOOL, IMAGE_SIDE_PX.validator()] = 480
    fps: Annotated[float, NOT_BOOL, CAMERA_FPS.validator()] = Field(
        15.0, description="Frame rate, Hz (640x480 YUYV fits USB 2.0 at 15, MJPEG at 30)"
    )
    pixel_format: Literal["yuyv", "mjpeg", "auto"] = Field(
        "auto",
        description="What the eyes stream: yuyv (uncompressed), mjpeg (decoded here), or auto: "
        "yuyv when both eyes fit one USB 2.0 bus uncompressed at this size and rate, else mjpeg",
    )
    color: bool = Field(
        True,
        description="Deliver BGR frames, which colour differencing ([detect] color, the "
        "default) needs; false delivers the luma only (cheaper, for [detect] color = false)",
    )
    buffers: Annotated[int, NOT_BOOL] = Field(4, ge=2, le=32)
    manual_exposure: bool = Field(True, description="Lock exposure (exposure_auto = manual)")
    controls: dict[str, int] = Field(
        default_factory=dict,
        description="Controls set on both eyes after every open, by name (exposure_absolute, "
        "gain, white_balance_temperature, ...) or id (0x980913)",
    )
    retry_s: Annotated[float, NOT_BOOL, CAMERA_RETRY_S.validator()] = Field(
        0.5, description="First reconnect delay, s (doubles)"
    )
    retry_max_s: Annotated[float, NOT_BOOL, CAMERA_RETRY_S.validator()] = Field(
        5.0, description="Longest reconnect delay, s"
    )
    read_timeout_s: Annotated[float, NOT_BOOL, CAMERA_TIMEOUT_S.validator()] = 0.5
    stall_s: Annotated[float, NOT_BOOL, CAMERA_STALL_S.validator()] = Field(
        2.0,
        description="An eye streaming no frame for this long (s) is closed and reopened, as "
        "after a re-plug (a camera can stop mid-stream and stay open)",
    )

    @field_validator("pixel_format", mode="before")
    @classmethod
    def _format_name(cls, value: object) -> object:
        """Any case, and the fourccs: ``YUYV``, ``MJPG`` (the names this setting once took)."""
        if isinstance(value, str):
            name = value.strip().lower()
            return "mjpeg" if name == "mjpg" else name
        return value


FIRST_FRAME_S = 5.0
"""How long (s) an eye just opened may take to deliver its first frame before it counts as
stalled (``stall_s`` if longer)."""


def _control_id(name: str) -> int:
    if name in raw.CONTROLS:
        return raw.CONTROLS[name]
    try:
        return int(name, 0)
    except ValueError as exc:
        raise ConfigError(
            f"driver.options.controls.{name}: unknown control; known: "
            f"{', '.join(sorted(raw.CONTROLS))}, or a numeric id"
        ) from exc


class CameraEye(EyeSource):
    """One eye: opens, configures and streams its node; reconnects after a loss."""

    def __init__(self, eye: Eye, opts: MinoruOptions, path: str, io: IO | None = None) -> None:
        self.eye = eye
        self.opts = opts
        self.path = path
        self.io = io
        self.device: V4L2Device | None = None
        self._interrupted = threading.Event()
        self._last_seq: int | None = None
        self._counters = EyeCounters()
        self._delay = opts.retry_s
        self._waiting_since = 0.0
        """When (monotonic s) the eye started waiting for its next frame."""
        self.fps: float | None = None
        self.format: bandwidth.Format = bandwidth.resolve(
            opts.pixel_format, opts.width, opts.height, opts.fps
        )
        """What the eye streams (``auto`` resolved)."""

    def _locate(self) -> str:
        """The node now: the configured path when it exists, else the Minoru eye by port."""
        if Path(self.path).exists():
            return self.path
        found = minoru_eyes(find_nodes()).get(self.eye.value)
        return found or self.path

    def start(self) -> None:
        """Open, configure and start streaming (raises DeviceError naming what failed)."""
        o = self.opts
        dev = V4L2Device(self._locate(), self.io).open()
        try:
            dev.set_format(o.width, o.height, bandwidth.FOURCC[self.format])
            self.fps = dev.set_fps(o.fps)
            self._apply_controls(dev)
            dev.start(o.buffers)
        except Exception:
            dev.close()
            raise
        self.device = dev
        self._last_seq = None
        self._waiting_since = time.monotonic()
        log.info(
            "%s eye streaming from %s: %dx%d %s at %.3g fps, delivered as %s",
            self.eye.value,
            dev.path,
            o.width,
            o.height,
            bandwidth.FOURCC[self.format],
            self.fps,
            "BGR" if o.color else "grey",
        )

    def _node_present(self) -> bool:
        return Path(self._locate()).exists()

    def _pause(self, delay_s: float) -> bool:
        """Wait ``delay_s`` seconds before the next reopen; True when the eye's node, absent
        when the pause began, appeared meanwhile (a re-plug: udev made its name again). The
        node is looked for every ``NODE_POLL_S``, so a re-plugged eye streams again within a
        fraction of a second however long it was away."""
        absent = not self._node_present()
        deadline = time.monotonic() + delay_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or self._interrupted.wait(min(NODE_POLL_S, left) if absent else left):
                return False
            if absent and self._node_present():
                return True

    def _apply_controls(self, dev: V4L2Device) -> None:
        wanted: list[tuple[str, int, int]] = []
        if self.opts.manual_exposure:
            wanted.append(
                ("exposure_auto", raw.CONTROLS["exposure_auto"], raw.V4L2_EXPOSURE_MANUAL)
            )
            wanted.append(("exposure_auto_priority", raw.CONTROLS["exposure_auto_priority"], 0))
            wanted.append(("auto_white_balance", raw.CONTROLS["auto_white_balance"], 0))
        wanted += [(n, _control_id(n), v) for n, v in self.opts.controls.items()]
        available = {c.id for c in dev.controls()}
        for name, cid, value in wanted:
            if cid not in available:
                if name in self.opts.controls:
                    raise DeviceError(f"{dev.path}: has no control {name!r} (see stereod devices)")
                continue
            dev.set_control(cid, value)

    def read(self) -> Frame | None:
        while not self._interrupted.is_set():
            if self.device is None:
                try:
                    self.start()
                    self._delay = self.opts.retry_s
                except DeviceError as exc:
                    log.debug("%s eye: reopen failed: %s", self.eye.value, exc)
                    if self._pause(self._delay):
                        self._delay = self.opts.retry_s  # a node appeared: try it at once
                    else:
                        self._delay = min(self._delay * 2, self.opts.retry_max_s)
                    continue
            assert self.device is not None
            try:
                # in slices, so that a stop (interrupt) is seen within INTERRUPT_S
                cap = self.device.read(min(self.opts.read_timeout_s, INTERRUPT_S))
            except DeviceLost:
                self.close()
                raise
            if cap is None:
                stalled = time.monotonic() - self._waiting_since
                first = self._last_seq is None  # a camera may take a while to start
                if stalled >= (
                    max(self.opts.stall_s, FIRST_FRAME_S) if first else self.opts.stall_s
                ):
                    path = self.device.path
                    self.close()
                    raise DeviceLost(f"{path}: no frame for {stalled:.1f} s")
                continue
            self._waiting_since = time.monotonic()
            if cap.error:
                self._count(self._counters.errors, "frame_error")
                continue
            if missed := frames_missed(self._last_seq, cap.sequence):
                self._count(self._counters.drops, "sequence_gap", missed)
            self._last_seq = cap.sequence
            t_ns = cap.t_ns
            if not cap.monotonic:
                # The pairer, the filter and the UTC offset all assume CLOCK_MONOTONIC; a
                # driver that stamps otherwise (or not at all) is stamped here at dequeue.
                t_ns = time.monotonic_ns()
                if not self._counters.errors.get("clock_not_monotonic"):
                    log.warning(
                        "%s eye: %s does not stamp frames on CLOCK_MONOTONIC; stamping them "
                        "at dequeue instead (less exact)",
                        self.eye.value,
                        self.path,
                    )
                self._count(self._counters.errors, "clock_not_monotonic")
            o = self.opts
            if self.format == "yuyv":
                if len(cap.data) < 2 * o.width * o.height:
                    self._count(self._counters.errors, "short_frame")
                    continue
                convert = yuyv_to_bgr if o.color else yuyv_to_gray
                image = convert(cap.data, o.width, o.height)
            else:
                # A UVC camera's MJPEG frame can be empty, cut short (no EOI) or corrupt
                # without the kernel flagging it: it is counted and skipped, as a flagged one.
                decoded = (mjpeg_to_bgr if o.color else mjpeg_to_gray)(cap.data)
                if decoded is None:
                    self._count(self._counters.errors, "bad_jpeg")
                    continue
                if decoded.shape[:2] != (o.height, o.width):
                    self._count(self._counters.errors, "wrong_size")
                    continue
                image = decoded
            return Frame(self.eye, image, t_ns, cap.sequence)
        return None

    def interrupt(self) -> None:
        self._interrupted.set()

    @staticmethod
    def _count(into: dict[str, int], reason: str, n: int = 1) -> None:
        into[reason] = into.get(reason, 0) + n

    def counters(self) -> EyeCounters:
        c = self._counters
        return EyeCounters(dict(c.drops), dict(c.errors))

    def close(self) -> None:
        if self.device is not None:
            self.device.close()
            self.device = None


def _source(left: CameraEye, right: CameraEye, o: MinoruOptions) -> StereoSource:
    """Both eyes, started, with what they stream."""
    info = SourceInfo(
        width=o.width,
        height=o.height,
        fps=left.fps or o.fps,
        live=True,
        description=f"Minoru {left.path} + {right.path}",
        settings=o.model_dump(),
    )
    return StereoSource(left, right, info)


class MinoruDriver(Driver):
    """Streams both eyes of a Minoru (or any two V4L2 capture nodes) as a live source.

    Its options are checked against one USB 2.0 bus before any eye is opened
    (:mod:`.bandwidth`): a mode both eyes cannot stream together is a ConfigError naming the
    fix, not an ENOSPC from the second eye's STREAMON."""

    name = "v4l2_minoru"

    def __init__(self, options: dict[str, Any], io: IO | None = None) -> None:
        try:
            self.options = MinoruOptions.model_validate(options)
        except ValidationError as exc:
            raise ConfigError(
                describe_validation_error(exc, "driver.options", MinoruOptions)
            ) from exc
        o = self.options
        try:
            fmt = bandwidth.choose(o.pixel_format, o.width, o.height, o.fps)
        except ValueError as exc:
            raise ConfigError(f"driver.options: {exc}") from exc
        self.options = o.model_copy(update={"pixel_format": fmt})
        for name in self.options.controls:
            _control_id(name)
        self.io = io

    def frame_size(self) -> tuple[int, int]:
        """The mode asked for (a Minoru streams its modes at the size asked)."""
        return self.options.width, self.options.height

    def options_read(self) -> dict[str, Any]:
        """The options given, and the pixel format the bus's bandwidth chose."""
        given = self.options.model_dump(mode="json", exclude_unset=True)
        return {**given, "pixel_format": self.options.pixel_format}

    def _paths(self) -> tuple[str, str]:
        o = self.options
        found = {}
        if o.left is None or o.right is None:
            found = minoru_eyes(find_nodes())
        paths = []
        for eye, given in (("left", o.left), ("right", o.right)):
            default = f"/dev/minoru/{eye}"
            path = given or (default if Path(default).exists() else found.get(eye))
            if path is None:
                raise DeviceError(
                    f"no {eye} eye: no {default} and no Minoru eye on hub port "
                    f"{1 if eye == 'left' else 2}; plug the camera in, or set driver.options.{eye} "
                    f"in the --config file or STEREOD_DRIVER__OPTIONS__{eye.upper()} to its "
                    "/dev/videoN (see stereod devices; stereod replay runs without a camera)"
                )
            paths.append(path)
        return paths[0], paths[1]

    def inputs(self) -> list[Path]:
        """The device nodes named in the options (those found on the bus are not files an
        output could name by mistake)."""
        return [Path(p) for p in (self.options.left, self.options.right) if p is not None]

    def open(self) -> StereoSource:
        left_path, right_path = self._paths()
        left = CameraEye(Eye.LEFT, self.options, left_path, self.io)
        right = CameraEye(Eye.RIGHT, self.options, right_path, self.io)
        left.start()
        try:
            right.start()
        except Exception:
            left.close()
            raise
        return _source(left, right, self.options)
