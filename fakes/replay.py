"""The ``replay`` driver: a recording directory (design sec. 6) or two plain video files.

Plain videos take either a frame rate (both eyes stamped ``i / fps``, no skew) or one timestamp
CSV per eye (header ``t_ns``, one integer per frame). Inconsistent inputs (missing or unreadable
files, different sizes or frame counts between the eyes, timestamps that do not increase) are
refused before anything plays; a video that decodes fewer frames than its header or timestamp
file announce plays what it has and reports the truncation through ``problems()``. A
recording's frame whose pixels do not match the CRC-32 recorded beside it (a lossless video
damaged on disk still decodes, into other pixels) is left out and reported the same way, as
a camera's dropped frame would be: the pipeline never sees it.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from stereod.errors import (
    ConfigError,
    InputError,
    MissingInputError,
    StereodError,
    describe_validation_error,
)
from stereod.files.output_file import same_file
from stereod.files.paths import TextPath, text_path
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
from stereod.sources.recording import (
    MANIFEST,
    checksum,
    damaged_frames_problem,
    read_frame_index,
    read_manifest,
    read_timestamps,
)

log = logging.getLogger(__name__)


class ReplayOptions(BaseModel):
    """Options of the replay driver (the ``[driver.options]`` table)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    path: TextPath | None = Field(None, description="Recording directory")
    left_video: TextPath | None = None
    right_video: TextPath | None = None
    fps: float | None = Field(
        None, ge=0.01, le=10000.0, description="Frame rate of plain videos, Hz"
    )
    left_ts: TextPath | None = Field(None, description="Left timestamps CSV (t_ns)")
    right_ts: TextPath | None = Field(None, description="Right timestamps CSV (t_ns)")
    loop: bool = Field(False, description="Start again at the end, timestamps continuing")
    utc_start_ns: int | None = Field(
        None,
        ge=0,
        le=2**63 - 1,
        description="The first frame's UTC instant, ns: several replays of one scene then "
        "stamp their messages on one clock (default: the recording's own offset, else the "
        "wall clock when the first frame plays)",
    )

    @model_validator(mode="after")
    def _one_input(self) -> ReplayOptions:
        videos = self.left_video is not None or self.right_video is not None
        if (self.path is None) == (not videos):
            raise ValueError("give either path (a recording) or left_video and right_video")
        if videos:
            if self.left_video is None or self.right_video is None:
                raise ValueError("plain videos need both left_video and right_video")
            has_ts = self.left_ts is not None or self.right_ts is not None
            if has_ts and (self.left_ts is None or self.right_ts is None):
                raise ValueError("timestamps need both left_ts and right_ts")
            if has_ts and self.fps is not None:
                raise ValueError(
                    "fps and left_ts/right_ts are exclusive: give fps (frame i at i / fps) or "
                    "the two timestamp files, not both"
                )
            if not has_ts and self.fps is None:
                raise ValueError("plain videos need either fps or left_ts and right_ts")
            if same_file(self.left_video, self.right_video):
                raise ValueError(
                    "left_video and right_video are one file: each eye needs its own video "
                    "(one video for both has no disparity, and every match between the eyes "
                    "would be a wrong one)"
                )
        return self


def _open_capture(path: Path, gray: bool) -> cv2.VideoCapture:
    name = text_path(path, "video")
    if not path.exists():
        raise MissingInputError(f"{path}: no such video file")
    if not path.is_file():
        raise MissingInputError(f"{path}: not a file")
    cap = cv2.VideoCapture(name, cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise InputError(f"{path}: cannot open as a video (not a video file, or unsupported codec)")
    if gray:
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    return cap


def probe_video(path: Path) -> tuple[int, int, int]:
    """(width, height, header frame count) of a video; the first frame must decode."""
    cap = _open_capture(path, gray=False)
    try:
        ok, img = cap.read()
        if not ok or img is None:
            raise InputError(f"{path}: no frame decodes (corrupt or unsupported video)")
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        return img.shape[1], img.shape[0], max(n, 0)
    finally:
        cap.release()


class VideoEye(EyeSource):
    """One eye read from a video file with one timestamp per frame."""

    def __init__(
        self,
        eye: Eye,
        path: Path,
        t_ns: np.ndarray | None,
        seq: np.ndarray | None,
        size: tuple[int, int],
        *,
        fps: float | None = None,
        gray: bool,
        expected: int,
        expected_from: str,
        loop: bool = False,
        crc: np.ndarray | None = None,
        crc_file: Path | None = None,
    ) -> None:
        self.eye = eye
        self.path = path
        if t_ns is None and fps is None:
            raise ValueError("a video eye needs timestamps or a frame rate")
        self._t = t_ns
        self._seq = seq
        self._fps = fps
        self._size = size
        self._gray = gray
        self._expected = expected
        self._expected_from = expected_from
        self._loop = loop
        self._crc = crc
        """Each frame's CRC-32 as recorded (a lossless recording's), or None: not checked."""
        self.crc_file = crc_file
        """The file ``crc`` was read from."""
        self._lap_frames = 0
        """Frames this lap of a loop has given so far."""
        self._cap: cv2.VideoCapture | None = _open_capture(path, gray)
        self._i = 0
        self._offset_ns = 0
        self._seq_offset = 0
        self.lap: tuple[int, int] | None = None
        """How far (ns, sequence numbers) each lap of a loop moves this eye's stamps; both
        eyes get the same (:func:`common_lap`), else each eye's own decoded frames decide."""
        self._counters = EyeCounters()
        self.decoded = 0
        self.bad_frames = 0
        self.damaged: list[int] = []
        """Frames (from 0) left out because they differ from their CRC-32 (the first lap)."""
        self._damage_said = False
        self.problems: list[str] = []
        self.other: VideoEye | None = None
        """The other eye of the stereo input: a loop stops once that one has ended for good
        (nothing it could pair with would come)."""
        self.ended = False
        """Whether this eye has given its last frame."""

    def read(self) -> Frame | None:
        while True:
            if self._cap is None:
                return None
            ok, img = self._cap.read()
            if not ok or img is None:
                if self._offset_ns == 0:
                    self.problems += self.damage_problems()
                if self._i < self._expected and self._offset_ns == 0:
                    self.problems.append(
                        f"{self.path}: truncated: {self._expected_from} says {self._expected} "
                        f"frames, only {self._i} decoded; replayed those (the file is cut "
                        "short: restore it from a copy to replay the rest)"
                    )
                if self._loop and self._i > 0 and self._lap_frames == 0:
                    self.problems.append(
                        f"{self.path}: every frame of a lap was left out; nothing to loop"
                    )
                elif self._loop and self._i > 0 and not (self.other and self.other.ended):
                    self._restart()
                    continue
                self.ended = True
                self.close()
                return None
            if self._t is not None and self._i >= len(self._t):
                self.close()
                raise InputError(
                    f"{self.path}: has more frames than its {len(self._t)} timestamps "
                    "(one timestamp row per frame)"
                )
            i = self._i
            self._i += 1
            if (img.shape[1], img.shape[0]) != self._size:
                self.bad_frames += 1
                self.problems.append(
                    f"{self.path} frame {i}: size {img.shape[1]}x{img.shape[0]}, expected "
                    f"{self._size[0]}x{self._size[1]}; skipped"
                )
                continue
            if self._gray and img.ndim == 3:
                img = img[..., 0].copy()
            if self._crc is not None and i < len(self._crc) and checksum(img) != self._crc[i]:
                self.bad_frames += 1
                if self._offset_ns == 0:  # said once, not again on each lap of a loop
                    self.damaged.append(i)
                continue
            self.decoded += 1
            self._lap_frames += 1
            t, seq = self._stamp(i)
            if self._seq is not None and 0 < i < len(self._seq):
                missed = frames_missed(int(self._seq[i - 1]), int(self._seq[i]))  # as recorded
                if missed:
                    gaps = self._counters.drops
                    gaps["sequence_gap"] = gaps.get("sequence_gap", 0) + missed
            return Frame(self.eye, img, t + self._offset_ns, seq + self._seq_offset)

    def counters(self) -> EyeCounters:
        """Frames the camera took that the recording lacks (gaps in its sequence numbers,
        whatever lost them: the camera, or the recorder skipping a frame that would not
        decode), counted as each frame after one is played (again on each lap of a loop)."""
        return EyeCounters(dict(self._counters.drops), {})

    def damage_problems(self) -> list[str]:
        """The line naming the frames left out for their CRC-32, once: at the end of the first
        lap, or when the run ends before it."""
        if not self.damaged or self.crc_file is None or self._damage_said:
            return []
        self._damage_said = True
        return [damaged_frames_problem(self.path, self.crc_file, self.damaged, "left out")]

    def _stamp(self, i: int) -> tuple[int, int]:
        if self._t is None:
            assert self._fps is not None
            return round(i * 1e9 / self._fps), i
        return int(self._t[i]), int(self._seq[i]) if self._seq is not None else i

    def stated_span(self) -> tuple[int, int, int] | None:
        """(first, end) capture times (ns; end = last + one period) and the count of sequence
        numbers of this eye's input as its timestamps or frame count state it, whatever was
        decoded; None when it states nothing."""
        n = len(self._t) if self._t is not None else self._expected
        if n < 1:
            return None
        t0, s0 = self._stamp(0)
        t1, s1 = self._stamp(n - 1)
        period = (t1 - t0) // (n - 1) if n > 1 else round(1e9 / (self._fps or 30.0))
        return t0, t1 + period, s1 - s0 + 1

    def _restart(self) -> None:
        if self.lap is not None:
            self._offset_ns += self.lap[0]
            self._seq_offset += self.lap[1]
        else:
            n = self._i
            t0, s0 = self._stamp(0)
            t1, s1 = self._stamp(n - 1)
            period = (t1 - t0) // (n - 1) if n > 1 else 1
            self._offset_ns += t1 - t0 + period
            self._seq_offset += s1 - s0 + 1
        self._expected = self._i
        if self._cap is not None:
            self._cap.release()
        self._cap = _open_capture(self.path, self._gray)
        self._i = 0
        self._lap_frames = 0

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


def common_lap(left: VideoEye, right: VideoEye) -> None:
    """Give both eyes of a loop the same lap: the whole input's span as its timestamps state
    it, so that an eye whose video is truncated keeps its frames at their instants, lap after
    lap, beside the other eye's (each eye's own decoded span would drift the two apart by what
    is missing, and pair frames from different moments)."""
    if left._t is None or right._t is None:
        return  # a frame rate and a header's frame count: each eye's decoded frames decide
    spans = [s for s in (left.stated_span(), right.stated_span()) if s is not None]
    if not spans:
        return
    lap = (max(s[1] for s in spans) - min(s[0] for s in spans), max(s[2] for s in spans))
    if lap[0] > 0 and lap[1] > 0:
        left.lap = right.lap = lap


class ReplaySource(StereoSource):
    """Two :class:`VideoEye` and what the input says about itself."""

    def __init__(self, left: VideoEye, right: VideoEye, info: SourceInfo) -> None:
        super().__init__(left, right, info)
        self._eyes = (left, right)
        left.other, right.other = right, left
        common_lap(left, right)

    def problems(self) -> list[str]:
        """What the input has said of itself so far: each eye's lap, once over, says whether
        its video was truncated or damaged."""
        return self._eyes[0].problems + self._eyes[1].problems

    def final_problems(self) -> list[str]:
        """The frames a first lap cut short by the end of the run had left out for their
        CRC-32 (a looping replay stopped early)."""
        return self._eyes[0].damage_problems() + self._eyes[1].damage_problems()


class ReplayDriver(Driver):
    """Replay a recording or two plain videos through the pipeline (not live: paced by the
    daemon at the requested rate, never dropping frames)."""

    name = "replay"

    def __init__(self, options: dict[str, Any]) -> None:
        try:
            self.options = ReplayOptions.model_validate(options)
        except ValidationError as exc:
            raise ConfigError(
                describe_validation_error(exc, "driver.options", ReplayOptions)
            ) from exc

    def options_read(self) -> dict[str, Any]:
        return self.options.model_dump(mode="json", exclude_unset=True)

    def frame_size(self) -> tuple[int, int] | None:
        """The recording's size from its manifest, or the left video's from its first frame,
        so that ``run --check`` holds a calibration against it; None where they cannot be
        read (opening the source then says why)."""
        o = self.options
        try:
            if o.path is not None:
                man = read_manifest(o.path)
                return man.width, man.height
            if o.left_video is not None and o.left_video.is_file():
                w, h, _ = probe_video(o.left_video)
                return w, h
        except StereodError:
            return None
        return None

    def inputs(self) -> list[Path]:
        """The recording folder (its files with it), or the two videos and their CSVs."""
        o = self.options
        found = (o.path, o.left_video, o.right_video, o.left_ts, o.right_ts)
        return [p for p in found if p is not None]

    def open(self) -> ReplaySource:
        o = self.options
        if o.path is not None:
            return self._open_recording(o.path)
        assert o.left_video is not None and o.right_video is not None
        return self._open_videos(o.left_video, o.right_video)

    def _utc_offset(self, firsts: list[int], own: int | None) -> int | None:
        """Wall clock minus the frames' clock (ns): with ``utc_start_ns``, the one that puts
        the earlier eye's first frame (``firsts``, ns) at that instant; else ``own``."""
        start = self.options.utc_start_ns
        if start is None:
            return own
        return start - min(firsts, default=0)

    def _open_recording(self, directory: Path) -> ReplaySource:
        man = read_manifest(directory)
        eyes = []
        inputs = [directory / MANIFEST]
        firsts: list[int] = []
        for eye, files in ((Eye.LEFT, man.left), (Eye.RIGHT, man.right)):
            t, seq, crc = read_frame_index(directory / files.timestamps)
            if len(t):
                firsts.append(int(t[0]))
            if len(t) != files.frames:
                raise InputError(
                    f"{directory / files.timestamps}: {len(t)} timestamps, manifest says "
                    f"{files.frames} frames"
                )
            video = directory / files.video
            inputs += [video, directory / files.timestamps]
            if files.frames:
                w, h, _ = probe_video(video)
                if (w, h) != (man.width, man.height):
                    raise InputError(
                        f"{video}: frames are {w}x{h} but {directory / MANIFEST} says "
                        f"{man.width}x{man.height}: the recording is inconsistent; fix width "
                        "and height in the manifest or record again"
                    )
            eyes.append(
                VideoEye(
                    eye,
                    directory / files.video,
                    t,
                    seq,
                    (man.width, man.height),
                    gray=not man.color,
                    expected=files.frames,
                    expected_from="the manifest",
                    loop=self.options.loop,
                    crc=crc,
                    crc_file=directory / files.timestamps,
                )
            )
        info = SourceInfo(
            width=man.width,
            height=man.height,
            fps=man.fps,
            live=False,
            description=f"recording {directory}",
            settings=dict(man.settings),
            utc_offset_ns=self._utc_offset(firsts, man.utc_offset_ns),
            inputs=inputs,
        )
        return ReplaySource(eyes[0], eyes[1], info)

    def _open_videos(self, left: Path, right: Path) -> ReplaySource:
        o = self.options
        missing = [
            f"{path}: no such video file (the {eye} eye's: --{eye}-video or "
            f"driver.options.{eye}_video; check the path)"
            for eye, path in (("left", left), ("right", right))
            if not path.exists()
        ]
        if missing:
            raise MissingInputError("; ".join(missing))
        lw, lh, ln = probe_video(left)
        rw, rh, rn = probe_video(right)
        if (lw, lh) != (rw, rh):
            raise InputError(
                f"{left} is {lw}x{lh} but {right} is {rw}x{rh}: both eyes must have one size"
            )
        if o.fps is not None:
            if ln and rn and ln != rn:
                raise InputError(
                    f"{left} has {ln} frames but {right} has {rn}: both eyes must have "
                    "the same number of frames"
                )
            stamps: list[tuple[np.ndarray | None, np.ndarray | None, int, str]] = [
                (None, None, ln, "the video header"),
                (None, None, rn, "the video header"),
            ]
        else:
            assert o.left_ts is not None and o.right_ts is not None
            stamps = []
            for video, ts_path, n in ((left, o.left_ts, ln), (right, o.right_ts, rn)):
                t, seq = read_timestamps(ts_path)
                if n and len(t) < n:
                    raise InputError(
                        f"{video} has {n} frames but {ts_path} has only {len(t)} timestamps"
                    )
                stamps.append((t, seq, len(t), str(ts_path)))
            if stamps[0][2] != stamps[1][2]:
                raise InputError(
                    f"{o.left_ts} has {stamps[0][2]} timestamps but {o.right_ts} has "
                    f"{stamps[1][2]}: both eyes must have the same number of frames"
                )
        eyes = [
            VideoEye(
                eye,
                video,
                t,
                seq,
                (lw, lh),
                fps=o.fps,
                gray=False,
                expected=expected,
                expected_from=source,
                loop=o.loop,
            )
            for eye, video, (t, seq, expected, source) in (
                (Eye.LEFT, left, stamps[0]),
                (Eye.RIGHT, right, stamps[1]),
            )
        ]
        info = SourceInfo(
            width=lw,
            height=lh,
            fps=o.fps,
            live=False,
            description=f"videos {left} + {right}",
            inputs=[p for p in (left, right, o.left_ts, o.right_ts) if p is not None],
            utc_offset_ns=self._utc_offset(
                [int(t[0]) if t is not None and len(t) else 0 for t, _, _, _ in stamps], None
            ),
        )
        return ReplaySource(eyes[0], eyes[1], info)
