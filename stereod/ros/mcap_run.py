"""An MCAP file written while a run is in progress: ``stereod record --mcap`` (each eye's frames,
camera_info, tf) and ``stereod replay --mcap`` (the same for the frames of every processed pair,
plus the tracks).

The file has the topics, types and frames of :mod:`stereod.ros.export_mcap` (it is written by its
:class:`~stereod.ros.mcap_writer.McapRunWriter`). It is opened when the frame size is known (the
geometry's camera_info depends on it), and renamed into place only by :meth:`RunMcap.commit`,
which a command calls once the run has succeeded; :meth:`RunMcap.abort` (a failed or interrupted
run) leaves a previous file at that path untouched. The path follows the rule of
:mod:`stereod.files.output_file` (a symbolic link is written through, a device or FIFO in place) and
is checked when the object is made, so an output that cannot be written is refused before the
run starts.

Stamps: a frame's stamp is its capture instant ``t_ns`` plus the run's UTC offset: for a replay,
``stamp_utc_ns - t_ns`` of the first message (so frames and tracks line up exactly, as in
``stereod export``); for a recording, the offset the recording's manifest gets (live cameras),
else the wall clock at the first frame minus its ``t_ns``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Literal

from stereod.daemon.config import StereodConfig
from stereod.daemon.params import make_rig
from stereod.daemon.processing import Outgoing
from stereod.files.output_file import output_target
from stereod.ros.mcap_writer import ExportSummary, McapRunWriter
from stereod.sources.frames import Eye, Frame, SourceInfo
from stereod.vision.calibration import Calibration, canonical
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.stereo import CanonicalRig

__all__ = ["RunMcap", "config_geometry", "rig_calibration"]


def rig_calibration(rig: CanonicalRig | CalibratedRig) -> Calibration:
    """The pipeline's geometry as a calibration (camera_info): the calibration file itself, or
    the canonical rig of eq. 9 written as one (:func:`stereod.vision.calibration.canonical`)."""
    if isinstance(rig, CalibratedRig):
        return rig.calibration
    return canonical(rig.baseline_m, rig.hfov_deg, rig.width_px, rig.height_px)


def config_geometry(cfg: StereodConfig) -> Callable[[int, int], Calibration]:
    """The geometry a run of ``cfg`` uses for frames of (width, height) px, as a calibration."""
    return lambda width, height: rig_calibration(make_rig(cfg, width, height))


class RunMcap:
    """One run's MCAP file at ``out`` for rig ``rig``. ``geometry(width, height)`` gives the
    calibration for frames of that size (px). ``images``: write each frame's compressed image
    (JPEG, ``jpeg_quality``, or PNG); without, only camera_info and tf. Safe to call from
    several threads. Raises :class:`~stereod.errors.OutputError` at once for an ``out`` that
    cannot be an output (a directory, a missing folder)."""

    def __init__(
        self,
        out: Path,
        *,
        rig: str,
        geometry: Callable[[int, int], Calibration],
        images: bool = True,
        image_format: Literal["jpeg", "png"] = "jpeg",
        jpeg_quality: int = 90,
    ) -> None:
        output_target(out)
        self.out = out
        self.rig = rig
        self.images = images
        self._geometry = geometry
        self._image_format: Literal["jpeg", "png"] = image_format
        self._jpeg_quality = jpeg_quality
        self._lock = threading.Lock()
        self._writer: McapRunWriter | None = None
        self._offset_ns: int | None = None
        self._last_t_ns: dict[Eye, int] = {}
        self.frames: dict[Eye, int] = dict.fromkeys(Eye, 0)
        """Frames written so far, per eye."""

    def start(self, width: int, height: int, utc_offset_ns: int | None) -> None:
        """Open the file for frames of ``width`` x ``height`` px; ``utc_offset_ns`` (wall clock
        minus the frames' clock, ns), when None, is taken at the first frame. Once only."""
        with self._lock:
            self._start_locked(width, height, utc_offset_ns)

    def start_source(self, info: SourceInfo, utc_offset_ns: int | None) -> None:
        """:meth:`start` for an opened source (``stereod.sources.record.record``'s ``on_start``)."""
        self.start(info.width, info.height, utc_offset_ns)

    def _start_locked(self, width: int, height: int, utc_offset_ns: int | None) -> None:
        if self._writer is not None:
            return
        cal = self._geometry(width, height)
        self._offset_ns = utc_offset_ns
        self._writer = McapRunWriter(
            self.out,
            rig=self.rig,
            calibration=cal,
            image_format=self._image_format,
            jpeg_quality=self._jpeg_quality,
        )

    def frame(self, frame: Frame) -> None:
        """Write one eye frame (its camera_info, and its image with ``images``). A frame not
        later than the last one written for that eye (a frame two pairs share) is skipped."""
        with self._lock:
            if self._writer is None:
                h, w = frame.image.shape[:2]
                self._start_locked(w, h, None)
            assert self._writer is not None
            last = self._last_t_ns.get(frame.eye)
            if last is not None and frame.t_ns <= last:
                return
            if self._offset_ns is None:
                self._offset_ns = time.time_ns() - frame.t_ns
            self._last_t_ns[frame.eye] = frame.t_ns
            self._writer.write_frame(frame, frame.t_ns + self._offset_ns, image=self.images)
            self.frames[frame.eye] += 1

    def outgoing(self, item: Outgoing) -> None:
        """What the daemon published for one pair (its ``on_message`` hook; the daemon must keep
        the frames, ``keep_frames=True``): the pair's two frames, then its ``objects`` message."""
        msg, pair = item.message, item.pair
        if msg is None:
            return
        if pair is not None:
            with self._lock:
                h, w = pair.left.image.shape[:2]
                self._start_locked(w, h, msg.stamp_utc_ns - msg.t_ns)
            for f in sorted((pair.left, pair.right), key=lambda f: f.t_ns):
                self.frame(f)
        with self._lock:
            if self._writer is None:
                raise RuntimeError("RunMcap: an objects message came before any frame")
            self._writer.write_objects(msg, raw_json=item.payload.decode())

    def commit(self) -> ExportSummary | None:
        """Finish the file and rename it over ``out``; None (and no file) when no frame came."""
        with self._lock:
            writer, self._writer = self._writer, None
        if writer is None:
            return None
        summary = writer.close()
        summary.clock = "run"
        summary.utc_offset_ns = self._offset_ns
        return summary

    def abort(self) -> None:
        """Remove the temporary file; a previous ``out`` stays as it was. Idempotent."""
        with self._lock:
            writer, self._writer = self._writer, None
        if writer is not None:
            writer.abort()
