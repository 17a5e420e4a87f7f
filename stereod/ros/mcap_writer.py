"""One run into an MCAP file, message by message: images, camera_info, tf and the tracks.

Images: each eye's frames as JPEG (default, quality 90) or PNG, ``format`` ``"jpeg"`` or
``"png"``, 8-bit grey or BGR as recorded. camera_info is published with every frame, same stamp
and frame id as the image (image_transport's pairing): K, D (``plumb_bob``, k1 k2 p1 p2 k3), R
(R1/R2), P (P1/P2, so the right eye's P[0, 3] = -fx B), width and height, from the calibration,
or from :func:`stereod.vision.calibration.canonical` for the canonical rig. A frame's stamp is its
capture instant ``t_ns`` plus the run's UTC offset (see :func:`export_run` for where the offset
comes from).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Literal, cast

import cv2
import numpy as np

from stereod.bus.messages import ObjectsMessage
from stereod.errors import InputError
from stereod.files.output_file import AtomicOutput
from stereod.ros.mapping import RosMessage, RosMessages
from stereod.ros.names import QOS_LATCHED, ROS_DISTRO, ros2_msgdef
from stereod.sources.frames import Eye, Frame
from stereod.vision.calibration import Calibration


@dataclass
class ExportSummary:
    """What an export wrote. Times are MCAP log times (UTC, ns); ``clock`` says where the UTC
    offset of frame stamps came from (``jsonl``, ``manifest``, ``created_utc`` (estimated, 1 s
    resolution), ``monotonic`` (unknown: stamps are the capture clock) or ``caller``)."""

    path: Path
    messages: dict[str, int]
    start_ns: int | None
    end_ns: int | None
    clock: str = "caller"
    utc_offset_ns: int | None = None
    problems: list[str] = field(default_factory=list)

    @property
    def total(self) -> int:
        """Number of messages in the file."""
        return sum(self.messages.values())

    def line(self, problems: bool = True) -> str:
        """One line for a user: file, message and topic counts, duration (s), clock, and
        what went wrong with the input unless ``problems`` is false (said apart)."""
        dur = 0.0
        if self.start_ns is not None and self.end_ns is not None:
            dur = (self.end_ns - self.start_ns) / 1e9
        return (
            f"wrote {self.path}: {self.total} messages on {len(self.messages)} topics, "
            f"{dur:.2f} s, clock from {self.clock}"
            + "".join(f"; {p}" for p in (self.problems if problems else []))
        )


class McapRunWriter:
    """Write one run into an MCAP file, message by message, while it is in progress or offline.

    ``out`` is written by the rule of :mod:`stereod.files.output_file`: a regular file goes to a
    temporary file beside it (``.<name>.<random>.part``, beside the file a symbolic link points
    to) renamed over it by :meth:`close`, and :meth:`abort` (or an exception inside ``with``)
    removes it, leaving a previous ``out`` untouched; a device or a FIFO (``/dev/null``, a pipe
    to a reader) is written in place. Feed it in capture order: :meth:`write_frame` per eye
    frame, :meth:`write_objects` per ``stereod.objects/1`` message. ``/tf_static`` is written
    before the first message, at its stamp. Calls may come from several threads. If the process
    dies before :meth:`close`, the temporary file stays behind; ``mcap recover`` salvages it.

    ``calibration`` gives camera_info and the cameras' frames (use
    :func:`stereod.vision.calibration.canonical` for the canonical rig); without one, ``baseline_m``
    (m) places the cameras and no camera_info is written.
    """

    def __init__(
        self,
        out: Path,
        *,
        rig: str = "minoru",
        calibration: Calibration | None = None,
        baseline_m: float | None = None,
        image_format: Literal["jpeg", "png"] = "jpeg",
        jpeg_quality: int = 90,
    ) -> None:
        from mcap_ros2.writer import Writer

        if calibration is None and (baseline_m is None or not baseline_m > 0):
            raise ValueError("McapRunWriter needs a calibration or a positive baseline_m")
        if image_format not in ("jpeg", "png"):
            raise ValueError(f"image_format must be 'jpeg' or 'png', got {image_format!r}")
        self.out = Path(out)
        self.rig = rig
        self.ros = RosMessages(rig, calibration=calibration, baseline_m=baseline_m)
        self.names = self.ros.names
        self.calibration = calibration
        self.image_format = image_format
        self._encode_params = (
            [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if image_format == "jpeg" else []
        )
        self._lock = threading.Lock()
        self._file = AtomicOutput(self.out)
        try:
            self._ros = Writer(cast(IO[bytes], self._file))
            self._ros.add_metadata("rosbag2", {"ROS_DISTRO": ROS_DISTRO})
        except BaseException:
            self._discard()
            raise
        self._schemas: dict[str, Any] = {}
        self._counts: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self._static_done = False
        self._start: int | None = None
        self._end: int | None = None
        self._closed = False

    @property
    def baseline_m(self) -> float:
        """Distance between the cameras' frames in ``/tf_static``, m."""
        assert self.ros.baseline_m is not None
        return self.ros.baseline_m

    # -- public API ---------------------------------------------------------------------------

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, by topic."""
        with self._lock:
            return dict(self._counts)

    def write_frame(self, frame: Frame, stamp_utc_ns: int, *, image: bool = True) -> None:
        """Write one eye frame captured at ``stamp_utc_ns`` (UTC, ns): its camera_info (when a
        calibration is known) and, with ``image``, the compressed image."""
        data = b""
        if image:
            data = self._encode(frame)
        with self._lock:
            self._check_open()
            self._static(stamp_utc_ns)
            if self.calibration is not None:
                self._check_size(frame)
                self._camera_info_locked(frame.eye, stamp_utc_ns)
            if image:
                self._write(
                    self.ros.compressed_image(
                        self.names.image_topic(frame.eye),
                        self.names.eye_frame(frame.eye),
                        self.image_format,
                        data,
                        stamp_utc_ns,
                    )
                )

    def write_camera_info(self, eye: Eye, stamp_utc_ns: int) -> None:
        """Write one camera_info of ``eye`` at ``stamp_utc_ns`` (UTC, ns) without an image."""
        if self.calibration is None:
            raise ValueError("camera_info needs a calibration")
        with self._lock:
            self._check_open()
            self._static(stamp_utc_ns)
            self._camera_info_locked(eye, stamp_utc_ns)

    def write_objects(self, msg: ObjectsMessage, *, raw_json: str | None = None) -> None:
        """Write one ``stereod.objects/1`` message: Odometry per track state, speed/heading per
        valid state, the MarkerArray and the JSON (``raw_json`` if given, else re-serialised)."""
        with self._lock:
            self._check_open()
            messages = self.ros.objects(msg, raw_json=raw_json)
            self._static(msg.stamp_utc_ns)
            for m in messages:
                self._write(m)

    def close(self) -> ExportSummary:
        """Finish the MCAP (summary, indexes), sync it and rename it over ``out``."""
        with self._lock:
            self._check_open()
            self._closed = True
            try:
                self._ros.finish()
                self._file.commit()
            except BaseException:
                self._discard()
                raise
            return ExportSummary(
                path=self.out,
                messages=dict(sorted(self._counts.items())),
                start_ns=self._start,
                end_ns=self._end,
            )

    def abort(self) -> None:
        """Stop writing and remove the temporary file; ``out`` is left as it was. Idempotent."""
        with self._lock:
            self._closed = True
            self._discard()

    def __enter__(self) -> McapRunWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is not None:
            self.abort()
        elif not self._closed:
            self.close()

    # -- internals ----------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"{self.out}: MCAP writer already closed")

    def _check_size(self, frame: Frame) -> None:
        assert self.calibration is not None
        w, h = self.calibration.image_size
        if frame.image.shape[:2] != (h, w):
            raise InputError(
                f"{frame.eye.value} frame {frame.seq} is {frame.image.shape[1]}x"
                f"{frame.image.shape[0]}, the calibration is for {w}x{h}: use the calibration "
                "made for this camera mode"
            )

    def _discard(self) -> None:
        self._file.discard()

    def _schema(self, typename: str) -> Any:
        schema = self._schemas.get(typename)
        if schema is None:
            schema = self._ros.register_msgdef(typename, ros2_msgdef(typename))
            self._schemas[typename] = schema
        return schema

    def _register_latched(self, topic: str, typename: str) -> None:
        # mcap-ros2-support registers channels without metadata; rosbag2 needs the QoS profile
        # of a latched topic there, so register the channel ourselves when its internals allow.
        schema = self._schema(typename)
        inner = getattr(self._ros, "_writer", None)
        ids = getattr(self._ros, "_channel_ids", None)
        if inner is None or not isinstance(ids, dict) or topic in ids:
            return
        ids[topic] = inner.register_channel(
            topic=topic,
            message_encoding="cdr",
            schema_id=schema.id,
            metadata={"offered_qos_profiles": QOS_LATCHED},
        )

    def _put(self, topic: str, typename: str, message: dict[str, Any], stamp_ns: int) -> None:
        if stamp_ns < 0:
            raise InputError(
                f"{topic}: stamp {stamp_ns} ns is before 1970: the UTC offset is wrong"
            )
        seq = self._seq.get(topic, 0)
        self._ros.write_message(
            topic,
            self._schema(typename),
            message,
            log_time=stamp_ns,
            publish_time=stamp_ns,
            sequence=seq,
        )
        self._seq[topic] = seq + 1
        self._counts[topic] = self._counts.get(topic, 0) + 1
        self._start = stamp_ns if self._start is None else min(self._start, stamp_ns)
        self._end = stamp_ns if self._end is None else max(self._end, stamp_ns)

    def _write(self, m: RosMessage) -> None:
        self._put(m.topic, m.typename, m.body, m.stamp_ns)

    def _static(self, stamp_ns: int) -> None:
        if self._static_done:
            return
        self._static_done = True
        static = self.ros.tf_static(stamp_ns)
        assert static is not None  # the writer always has a calibration or a baseline
        self._register_latched(static.topic, static.typename)
        self._write(static)

    def _camera_info_locked(self, eye: Eye, stamp_ns: int) -> None:
        info = self.ros.camera_info(eye, stamp_ns)
        if info is not None:
            self._write(info)

    def _encode(self, frame: Frame) -> bytes:
        ext = ".jpg" if self.image_format == "jpeg" else ".png"
        img = frame.image
        if img.dtype != np.uint8 or img.ndim not in (2, 3):
            raise InputError(
                f"{frame.eye.value} frame {frame.seq}: expected 8-bit grey or BGR pixels, got "
                f"{img.dtype} of shape {img.shape}"
            )
        ok, buf = cv2.imencode(ext, img, self._encode_params)
        if not ok:
            raise InputError(f"{frame.eye.value} frame {frame.seq}: cannot encode as {ext}")
        return buf.tobytes()
