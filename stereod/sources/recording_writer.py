"""Writing a recording: each eye's frames to a video, their timestamps and checksums to a CSV,
and the manifest last, so a folder with a manifest is a whole recording."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2

from stereod.errors import (
    InputError,
    Interrupted,
    OutputError,
    StereodError,
)
from stereod.files.output_file import write_failed
from stereod.files.paths import text_path
from stereod.files.stop import check_stop
from stereod.sources.frames import Eye, Frame
from stereod.sources.recording import (
    CHECKSUM_COLUMN,
    FORMAT,
    MANIFEST,
    Codec,
    EyeFiles,
    Manifest,
    checksum,
    size_problem,
)

MIN_FREE_BYTES = 16 * 2**20
"""A recording stops with an error (exit 73) once its file system has less free space than
this plus a few frames: OpenCV's video writer does not report a full disk."""


_FOURCC = {Codec.FFV1: "FFV1", Codec.MJPG: "MJPG"}
_EXT = {Codec.FFV1: ".mkv", Codec.MJPG: ".avi"}


class RecordingWriter:
    """Write frames of both eyes into a new recording directory; use as a context manager.

    Everything is written into a hidden temporary directory beside ``directory`` and moved into
    place when the writer closes, so a recording that fails before its first frame leaves
    nothing behind, and an existing directory is never written into: ``directory`` must not
    exist or be empty. A failure after frames were written still moves them into place (the
    manifest counts what was written), so what was recorded is kept; a signal's
    :class:`~stereod.errors.Interrupted` drops it instead (a render that ``synth`` did not
    finish is no recording; ``record`` ends on a signal normally, with its frames). A file
    system running out of space stops the recording with :class:`~stereod.errors.OutputError`,
    and so does a frame size the video writer cannot store as it is (see
    :func:`size_problem`), before anything is written.

    ``color`` says whether the videos hold BGR (True) or grey (False) frames; a frame of the
    other kind is converted. ``None`` lets the first frame written decide (BGR stays BGR, grey
    stays grey), so a recording keeps what its source delivers; the videos are then opened
    with that frame, and a recording with no frame at all is grey.
    """

    def __init__(
        self,
        directory: Path,
        width: int,
        height: int,
        *,
        fps: float | None,
        codec: Codec = Codec.FFV1,
        color: bool | None = False,
        settings: dict[str, Any] | None = None,
        utc_offset_ns: int | None = None,
        calibration: dict[str, Any] | None = None,
    ) -> None:
        self.directory = directory
        text_path(directory, "recording directory", OutputError)
        problem = size_problem(width, height)
        if problem is not None:
            raise OutputError(f"{directory}: {problem} (nothing was written)")
        try:
            occupied = directory.exists() and (not directory.is_dir() or any(directory.iterdir()))
        except OSError as exc:
            raise OutputError(f"{directory}: cannot look into it: {exc.strerror}") from exc
        if occupied:
            what = "a folder that is not empty" if directory.is_dir() else "a file"
            raise OutputError(
                f"{directory}: already exists, and is {what}; a recording goes into a new "
                "folder (nothing was written)"
            )
        try:
            directory.parent.mkdir(parents=True, exist_ok=True)
            self._tmp = Path(
                tempfile.mkdtemp(prefix=f".{directory.name}.", suffix=".part", dir=directory.parent)
            )
            self._tmp.chmod(0o777 & ~_umask())
        except OSError as exc:
            raise OutputError(
                f"{directory}: cannot create the recording directory: {exc.strerror}"
            ) from exc
        self._manifest = dict(
            format=FORMAT,
            width=width,
            height=height,
            fps=fps,
            codec=codec,
            color=color,
            utc_offset_ns=utc_offset_ns,
            settings=settings or {},
            calibration=calibration,
            created_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        )
        self._writers: dict[Eye, cv2.VideoWriter] = {}
        self._ts: dict[Eye, Any] = {}
        self._extra: dict[str, str] = {}
        self._counts = {Eye.LEFT: 0, Eye.RIGHT: 0}
        self._size = (height, width)
        self._codec, self._fps = codec, fps
        self._checksums = Codec(codec) is Codec.FFV1
        """Whether each frame's CRC-32 is kept beside it: only a lossless video gives back the
        pixels it was given."""
        self._frame_bytes = width * height * (1 if color is False else 3)
        self._writes = 0
        self._closed = False
        try:
            for eye in Eye:
                try:
                    # a row a frame, on disk as it is written (what a killed recorder leaves,
                    # and what a watcher sees, says how far it got)
                    fh = (self._tmp / f"{eye.value}.csv").open("w", newline="", buffering=1)
                    fh.write(f"t_ns,seq,{CHECKSUM_COLUMN}\n" if self._checksums else "t_ns,seq\n")
                except OSError as exc:
                    raise OutputError(
                        f"{directory}: cannot write timestamps: {exc.strerror}"
                    ) from exc
                self._ts[eye] = fh
            if color is not None:
                self._open_videos(color)
        except BaseException:
            self.discard()
            raise

    def _open_videos(self, color: bool) -> None:
        """Open both eyes' video writers for BGR (``color``) or grey frames; the manifest
        says which."""
        height, width = self._size
        codec = self._codec
        fourcc = cv2.VideoWriter.fourcc(*_FOURCC[codec])
        try:
            for eye in Eye:
                video = self._tmp / f"{eye.value}{_EXT[codec]}"
                w = cv2.VideoWriter(
                    text_path(video, "video", OutputError),
                    cv2.CAP_FFMPEG,
                    fourcc,
                    self._fps or 30.0,
                    (width, height),
                    isColor=color,
                )
                if not w.isOpened():
                    raise OutputError(
                        f"{self.directory / video.name}: cannot open for writing with codec "
                        f"{codec.value}"
                    )
                self._writers[eye] = w
        except BaseException:
            for w in self._writers.values():
                w.release()
            self._writers.clear()
            raise
        self._manifest["color"] = color
        self._frame_bytes = width * height * (3 if color else 1)

    def set_utc_offset(self, utc_offset_ns: int) -> None:
        """Keep ``utc_offset_ns`` (wall clock minus the frames' clock, ns) in the manifest when
        the source gave none: the offset an MCAP written alongside stamps frames with, so a
        later ``stereod export`` of this recording stamps them the same."""
        if self._manifest.get("utc_offset_ns") is None:
            self._manifest["utc_offset_ns"] = int(utc_offset_ns)

    def write(self, frame: Frame) -> None:
        """Append one frame (its pixels, capture time and sequence number)."""
        check_stop()  # a signal whose exception library code swallowed stops it here
        img = frame.image
        if img.shape[:2] != self._size:
            raise InputError(
                f"{frame.eye.value} frame {frame.seq} is {img.shape[1]}x{img.shape[0]} px, the "
                f"recording {self.directory} is {self._size[1]}x{self._size[0]} px: its source "
                f"changed the frame size; recording stopped, {self._kept()}"
            )
        if not self._writers:  # the first frame decides: BGR stays BGR, grey stays grey
            self._open_videos(img.ndim == 3)
        if self._writes % 8 == 0:
            self._check_space()
        self._writes += 1
        color = bool(self._manifest["color"])
        if color and img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        elif not color and img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        self._writers[frame.eye].write(img)
        try:
            row = (
                f"{frame.t_ns},{frame.seq},{checksum(img)}"
                if self._checksums
                else (f"{frame.t_ns},{frame.seq}")
            )
            self._ts[frame.eye].write(row + "\n")
        except OSError as exc:
            raise OutputError(f"{self.directory}: {write_failed(exc)}") from exc
        self._counts[frame.eye] += 1

    def _check_space(self) -> None:
        try:
            st = os.statvfs(self._tmp)
        except OSError:
            return
        free = st.f_bavail * st.f_frsize
        if free < MIN_FREE_BYTES + 16 * self._frame_bytes:
            raise OutputError(
                f"{self.directory}: the disk is full ({free // 2**20} MiB free); recording "
                f"stopped, {self._kept()}"
            )

    def _kept(self) -> str:
        """What a failure now leaves (see :meth:`__exit__`), for its message."""
        return "the frames recorded so far were kept" if self.frames else "nothing written"

    def write_text(self, name: str, text: str) -> None:
        """Add a small text file (``truth.json``) to the recording, moved into place with it."""
        self._extra[name] = text

    @property
    def frames(self) -> int:
        """Frames written so far, both eyes together."""
        return sum(self._counts.values())

    def close(self) -> None:
        """Finish the videos, write the manifest last and move the recording into place."""
        if self._closed:
            return
        self._closed = True
        try:
            if not self._writers:  # no frame said BGR or grey: empty videos, grey
                self._open_videos(False)
        except BaseException:
            self.discard()
            raise
        for w in self._writers.values():
            w.release()
        self._writers.clear()
        try:
            for fh in self._ts.values():
                fh.close()
            ext = _EXT[Codec(self._manifest["codec"])]
            man = Manifest(
                left=EyeFiles(
                    video=f"left{ext}", timestamps="left.csv", frames=self._counts[Eye.LEFT]
                ),
                right=EyeFiles(
                    video=f"right{ext}", timestamps="right.csv", frames=self._counts[Eye.RIGHT]
                ),
                **self._manifest,
            )
            for name, text in self._extra.items():
                (self._tmp / name).write_text(text)
            (self._tmp / MANIFEST).write_text(
                json.dumps(man.model_dump(mode="json"), indent=2) + "\n"
            )
            os.replace(self._tmp, self.directory)
        except OSError as exc:
            self.discard()
            raise OutputError(f"{self.directory}: {write_failed(exc)}") from exc

    def discard(self) -> None:
        """Drop everything written; ``directory`` stays as it was."""
        self._closed = True
        for w in self._writers.values():
            w.release()
        self._writers.clear()
        for fh in self._ts.values():
            with contextlib.suppress(OSError):
                fh.close()
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            try:  # a signal whose exception library code swallowed still stops the recording
                check_stop()
            except Interrupted:
                self.discard()
                raise
        failed = exc_type is not None and not issubclass(exc_type, Interrupted)
        if exc_type is None or (self.frames and failed and issubclass(exc_type, StereodError)):
            self.close()
        else:
            self.discard()


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
