"""Export a run to MCAP with standard ROS 2 messages (Foxglove, PlotJuggler, ``ros2 bag``).

The file holds only message types of ROS 2 Humble's standard packages, CDR-encoded, each
channel with its ``ros2msg`` schema (the definition text, comments stripped, comes from the type
store that ``rosbags`` ships, ``Stores.ROS2_HUMBLE``), so ROS tools open it without any stereod
package.
The MCAP profile is ``ros2``; a metadata record ``rosbag2`` names the distro (``humble``) and
``/tf_static`` carries rosbag2's ``offered_qos_profiles`` (reliable, transient local), so
``ros2 bag play run.mcap`` republishes it latched as tf2 expects.

The topics and frames are in :mod:`stereod.ros.names`, the mapping of each message in
:mod:`stereod.ros.mapping`, the writer in :mod:`stereod.ros.mcap_writer`.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from pydantic import ValidationError

from stereod.bus.messages import ObjectsMessage, ObjectState
from stereod.errors import InputError, MissingInputError, StereodError
from stereod.files.bounds import MAX_COORDINATE
from stereod.files.paths import text_path
from stereod.ros.mcap_writer import ExportSummary, McapRunWriter
from stereod.ros.names import NS_PER_S, value_text
from stereod.sources.frames import Eye, Frame
from stereod.sources.recording import (
    Manifest,
    checksum,
    damaged_frames_problem,
    read_frame_index,
    read_manifest,
)
from stereod.vision.calibration import Calibration, canonical

# -- offline export -------------------------------------------------------------------------


MAX_TRACK_ID = 2**31 - 1
"""Largest track id exported: a marker's id is an int32 (a daemon numbers its tracks from 1
and would need 68 years at one new track a second to reach it)."""


DAMAGED_SAID = 20
"""Damaged JSONL lines said one by one; the rest are counted."""


def _jsonl_messages(
    path: Path, damaged: list[str] | None = None
) -> Iterator[tuple[int, ObjectsMessage, str]]:
    """(line number, message, line) of each non-blank line, validated; errors name the line.
    With ``damaged`` a line that is no message (cut short, not UTF-8, or a track id no ROS
    marker carries) is said there and skipped. Each line is decoded on its own, so one
    damaged line costs no other."""
    skipped = 0

    def skip(problem: InputError) -> None:
        nonlocal skipped
        if damaged is None:
            raise problem
        skipped += 1
        if skipped <= DAMAGED_SAID:
            damaged.append(f"{problem}; skipped")

    try:
        fh = path.open("rb")
    except FileNotFoundError as exc:
        raise MissingInputError(
            f"{path}: no such JSONL file; write one with `stereod replay RECORDING --jsonl {path}`"
        ) from exc
    except OSError as exc:
        raise MissingInputError(f"{path}: cannot read JSONL file: {exc.strerror}") from exc
    regenerate = "regenerate the file with `stereod replay --jsonl`"
    with fh:
        try:
            for n, raw in enumerate(fh, start=1):
                try:
                    line = raw.decode("utf-8").rstrip("\r\n")
                except UnicodeDecodeError:
                    skip(InputError(f"{path} line {n}: not UTF-8 text; {regenerate}"))
                    continue
                if not line.strip():
                    continue
                try:
                    msg = ObjectsMessage.model_validate_json(line)
                except ValidationError as exc:
                    e = exc.errors(include_url=False)[0]
                    loc = ".".join(str(p) for p in e["loc"]) or "(line)"
                    skip(
                        InputError(
                            f"{path} line {n}: not a stereod.objects/1 message (field {loc}: "
                            f"{e['msg']}); {regenerate}"
                        )
                    )
                    continue
                far = [o.track_id for o in msg.objects if not 0 <= o.track_id <= MAX_TRACK_ID]
                if far:
                    skip(
                        InputError(
                            f"{path} line {n}: track_id {far[0]} is outside "
                            f"0..{MAX_TRACK_ID}, the ids a ROS marker (int32) can carry; "
                            f"{regenerate}"
                        )
                    )
                    continue
                odd = [o.track_id for o in msg.objects if not _plausible(o)]
                if odd:
                    skip(
                        InputError(
                            f"{path} line {n}: track {odd[0]}'s position or velocity is not "
                            f"finite, or beyond {MAX_COORDINATE:g} m or m/s; {regenerate}"
                        )
                    )
                    continue
                yield n, msg, line
        except OSError as exc:
            raise InputError(f"{path}: cannot read JSONL file: {exc.strerror}") from exc
    if skipped > DAMAGED_SAID and damaged is not None:
        damaged.append(f"{path}: {skipped - DAMAGED_SAID} more damaged lines skipped")


def _plausible(o: ObjectState) -> bool:
    """Whether an object's position and velocity are finite and within
    :data:`MAX_COORDINATE`."""
    return all(
        math.isfinite(v) and abs(v) <= MAX_COORDINATE for v in (*o.position_m, *o.velocity_mps)
    )


@dataclass
class _JsonlScan:
    """What a first pass over the JSONL found (messages are not kept: a run can be long)."""

    count: int = 0
    rigs: set[str] = field(default_factory=set)
    kinds: set[tuple[str, str | None]] = field(default_factory=set)
    offset_ns: int | None = None
    problems: list[str] = field(default_factory=list)
    """Its damaged lines, skipped."""


def _scan_jsonl(path: Path, bounds: tuple[int, int] | None, recording: Path | None) -> _JsonlScan:
    scan = _JsonlScan()
    for n, msg, _ in _jsonl_messages(path, scan.problems):
        scan.count += 1
        scan.rigs.add(msg.rig)
        scan.kinds.add((value_text(msg.geometry), msg.calibration_id))
        if scan.offset_ns is None:
            scan.offset_ns = msg.stamp_utc_ns - msg.t_ns
        if bounds is not None and not bounds[0] <= msg.t_ns <= bounds[1]:
            raise InputError(
                f"{path} line {n}: t_ns {msg.t_ns} is outside the recording {recording} "
                f"({bounds[0]}..{bounds[1]} ns): the JSONL is from another run; pass the "
                "matching pair"
            )
    if scan.problems and not scan.count:  # no message at all: no run's JSONL
        raise InputError(scan.problems[0].removesuffix("; skipped"))
    if not scan.count:
        raise InputError(
            f"{path}: no objects messages in the file (an empty run's file has one per pair); "
            "give the run's `stereod replay --jsonl` output"
        )
    return scan


@dataclass
class _Eye:
    eye: Eye
    video: Path
    t_ns: np.ndarray
    seq: np.ndarray
    crc: np.ndarray | None
    """Each frame's CRC-32 as recorded (lossless recordings), or None."""
    index: Path
    """The timestamp CSV the times and CRC-32s were read from."""


def _read_recording(directory: Path) -> tuple[Manifest, dict[Eye, _Eye]]:
    man = read_manifest(directory)
    eyes = {}
    for eye, files in ((Eye.LEFT, man.left), (Eye.RIGHT, man.right)):
        t, seq, crc = read_frame_index(directory / files.timestamps)
        if len(t) != files.frames:
            raise InputError(
                f"{directory / files.timestamps}: {len(t)} timestamps, the manifest says "
                f"{files.frames} frames; the recording is incomplete: record it again"
            )
        video = directory / files.video
        if not video.is_file():
            raise MissingInputError(f"{video}: no such video file; the recording is incomplete")
        eyes[eye] = _Eye(eye, video, t, seq, crc, directory / files.timestamps)
    return man, eyes


def _decode(rec: _Eye, gray: bool, problems: list[str]) -> Iterator[Frame]:
    cap = cv2.VideoCapture(text_path(rec.video, "video"), cv2.CAP_FFMPEG)
    if not cap.isOpened():
        raise InputError(f"{rec.video}: cannot open as a video (corrupt or unsupported codec)")
    if gray:
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    damaged: list[int] = []
    try:
        for i in itertools.count():
            ok, img = cap.read()
            if not ok or img is None:
                if i < len(rec.t_ns):
                    problems.append(
                        f"{rec.video}: truncated, {i} of {len(rec.t_ns)} frames decoded; "
                        "exported those"
                    )
                return
            if i >= len(rec.t_ns):
                raise InputError(
                    f"{rec.video}: has more frames than its {len(rec.t_ns)} timestamps; the "
                    "recording is inconsistent: record it again"
                )
            if gray and img.ndim == 3:
                img = np.ascontiguousarray(img[..., 0])
            if rec.crc is not None and checksum(img) != rec.crc[i]:
                damaged.append(i)
                continue
            yield Frame(rec.eye, img, int(rec.t_ns[i]), int(rec.seq[i]))
    finally:
        cap.release()
        if damaged:
            problems.append(damaged_frames_problem(rec.video, rec.index, damaged, "not exported"))


def _frame_events(
    rec: _Eye, order: int, offset: int, images: bool, gray: bool, problems: list[str]
) -> Iterator[tuple[int, int, Frame | Eye]]:
    """(stamp, order, frame) per decoded frame, or (stamp, order, eye) per timestamp row."""
    if images:
        for f in _decode(rec, gray, problems):
            yield f.t_ns + offset, order, f
    else:
        for t in rec.t_ns:
            yield int(t) + offset, order, rec.eye


def _created_utc_ns(man: Manifest) -> int | None:
    import datetime

    try:
        dt = datetime.datetime.strptime(man.created_utc, "%Y-%m-%dT%H:%M:%SZ")
    except ValueError:
        return None
    return int(dt.replace(tzinfo=datetime.timezone.utc).timestamp()) * NS_PER_S


def _choose_geometry(
    kinds: set[tuple[str, str | None]],
    jsonl: Path | None,
    calibration: Calibration | None,
    man: Manifest | None,
    recording: Path | None,
    baseline_m: float,
    hfov_deg: float,
) -> Calibration | None:
    recorded: Calibration | None = None
    if man is not None and man.calibration is not None:
        try:
            recorded = Calibration.model_validate(man.calibration)
        except ValidationError as exc:
            raise InputError(
                f"{recording}: the manifest's calibration is invalid; pass --calibration"
            ) from exc
        recorded = recorded.model_copy(update={"id": recorded.content_id()})
    if len(kinds) > 1:
        raise InputError(
            f"{jsonl}: the messages mix geometries {sorted(kinds, key=str)}; export one run"
        )
    used = next(iter(kinds)) if kinds else None
    cal: Calibration | None
    if used is not None and used[0] == "calibrated":
        want = used[1]
        if calibration is not None:
            if calibration.id != want:
                raise InputError(
                    f"{jsonl}: the run used calibration {want}, the one given is "
                    f"{calibration.id}: pass the calibration file the run used"
                )
            cal = calibration
        elif recorded is not None and recorded.id == want:
            cal = recorded
        else:
            raise MissingInputError(
                f"{jsonl}: the run used calibration {want}: pass that calibration file"
            )
    elif used is not None:
        if calibration is not None:
            raise InputError(
                f"{jsonl}: the run used the canonical rig but a calibration was given: drop the "
                "calibration, or replay the recording with it first"
            )
        cal = None
    else:
        cal = calibration if calibration is not None else recorded
    if cal is None and man is not None:
        try:
            cal = canonical(baseline_m, hfov_deg, man.width, man.height)
        except StereodError as exc:
            raise InputError(f"rig geometry: {exc}") from exc
    if cal is not None and man is not None and tuple(cal.image_size) != (man.width, man.height):
        w, h = cal.image_size
        raise InputError(
            f"{recording}: frames are {man.width}x{man.height}, the calibration is for {w}x{h}: "
            "pass the calibration made for this camera mode"
        )
    return cal


def export_run(
    out: Path,
    *,
    jsonl: Path | None,
    recording: Path | None,
    calibration: Calibration | None = None,
    baseline_m: float = 0.060,
    hfov_deg: float = 60.0,
    include_images: bool = True,
    rig: str | None = None,
    image_format: Literal["jpeg", "png"] = "jpeg",
    jpeg_quality: int = 90,
) -> ExportSummary:
    """Export a finished run to the MCAP file ``out`` (atomically: see :class:`McapRunWriter`).

    ``jsonl``: the ``stereod.objects/1`` messages (``stereod replay --jsonl``), one per line.
    ``recording``: the recording directory (images and per-frame camera_info; with
    ``include_images=False`` only camera_info, from the timestamp files, nothing decoded). At
    least one is needed. ``calibration``: the calibration the run used; when the JSONL says
    ``calibrated`` it must be that one (by id; the recording's own calibration is used when it
    matches). Otherwise the canonical rig of ``baseline_m`` (m) and ``hfov_deg`` (deg) is used,
    which must be the values the run used. ``rig``: default the JSONL's ``rig``, else ``minoru``.

    Stamps: a message's stamp is its ``stamp_utc_ns``. A frame's is its ``t_ns`` plus the UTC
    offset, taken from, in order: the JSONL (``stamp_utc_ns - t_ns`` of its first message, so
    frames and tracks line up exactly); the manifest's ``utc_offset_ns`` (live recordings); the
    manifest's ``created_utc`` minus the first frame's ``t_ns`` (an estimate to 1 s, e.g. for
    synthetic recordings); else 0, stamps then being the capture clock (``clock`` in the
    summary says which). Messages are written in stamp order.

    Raises :class:`~stereod.errors.MissingInputError`, :class:`~stereod.errors.InputError` or
    :class:`~stereod.errors.OutputError`; then ``out`` is as it was and no temporary is left.
    """
    if jsonl is None and recording is None:
        raise InputError(
            f"{out}: nothing to export: give the run's JSONL (stereod replay --jsonl) and/or "
            "its recording directory"
        )
    if not baseline_m > 0 or not 0 < hfov_deg < 180:
        raise InputError(
            f"rig geometry: baseline {baseline_m} m, field of view {hfov_deg} deg: need a baseline "
            "> 0 and a field of view in (0, 180), the values the run used"
        )
    man: Manifest | None = None
    eyes: dict[Eye, _Eye] = {}
    if recording is not None:
        man, eyes = _read_recording(recording)
    lo = min((int(e.t_ns[0]) for e in eyes.values() if len(e.t_ns)), default=None)
    hi = max((int(e.t_ns[-1]) for e in eyes.values() if len(e.t_ns)), default=None)
    bounds = (lo, hi) if lo is not None and hi is not None else None
    scan = _scan_jsonl(jsonl, bounds, recording) if jsonl is not None else _JsonlScan()
    if len(scan.rigs) > 1:
        raise InputError(f"{jsonl}: messages from several rigs {sorted(scan.rigs)}; export one rig")
    if rig is None:
        rig = next(iter(scan.rigs)) if scan.rigs else "minoru"
    elif scan.rigs and rig not in scan.rigs:
        raise InputError(
            f"{jsonl}: the messages are from rig {next(iter(scan.rigs))!r}, not {rig!r}"
        )
    cal = _choose_geometry(scan.kinds, jsonl, calibration, man, recording, baseline_m, hfov_deg)

    clock, offset = "monotonic", 0
    if scan.offset_ns is not None:
        clock, offset = "jsonl", scan.offset_ns
    elif man is not None and man.utc_offset_ns is not None:
        clock, offset = "manifest", man.utc_offset_ns
    elif lo is not None and man is not None and (created := _created_utc_ns(man)) is not None:
        clock, offset = "created_utc", created - lo

    problems: list[str] = list(scan.problems)
    gray = man is None or not man.color
    streams: list[Iterator[tuple[int, int, Any]]] = [
        _frame_events(rec, order, offset, include_images, gray, problems)
        for order, rec in enumerate(eyes.values())
    ]
    if jsonl is not None:
        said_once: list[str] = []  # the scan said the damaged lines
        streams.append(
            (m.stamp_utc_ns, 2, (m, line)) for _, m, line in _jsonl_messages(jsonl, said_once)
        )

    writer = McapRunWriter(
        out,
        rig=rig,
        calibration=cal,
        baseline_m=baseline_m,
        image_format=image_format,
        jpeg_quality=jpeg_quality,
    )
    with writer:
        for stamp, _, item in heapq.merge(*streams, key=lambda e: e[0]):
            if isinstance(item, Frame):
                writer.write_frame(item, stamp)
            elif isinstance(item, Eye):
                if cal is not None:
                    writer.write_camera_info(item, stamp)
            else:
                msg, line = item
                writer.write_objects(msg, raw_json=line)
        summary = writer.close()
    summary.clock = clock
    summary.utc_offset_ns = offset
    summary.problems = problems
    return summary
