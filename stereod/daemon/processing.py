"""The pipeline thread: the only thread that ever touches a :class:`~stereod.pipeline.Pipeline`.

It takes pairs from the capture queue, runs them through the pipeline (and a lone frame that
waits for its partner through its eye's detector, ahead of the pair), turns each result into
its wire payloads (the ``objects`` message and one state per live track) and queues them for
the output thread. A reload hands new parameters over with :meth:`PipelineWorker.reconfigure`
from any thread; the swap happens here, between two pairs, so no pair is processed half by one
pipeline and half by another, the tracks that end get their DELETE, and ids are never reused.
A pair that fails to process is counted and skipped; the thread goes on.
"""

from __future__ import annotations

import itertools
import logging
import statistics
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from stereod.bus.messages import ObjectsMessage, dump_objects, objects_message
from stereod.daemon.capture import Queued
from stereod.daemon.status import Health, geometry_note
from stereod.pipeline import PairResult, Pipeline, PipelineParams, Timings
from stereod.sources.frames import Frame, StereoPair
from stereod.sources.queues import BoundedQueue, Closed
from stereod.view.overlay import PairImages
from stereod.vision.blobs import Blobs
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.stereo import CanonicalRig

log = logging.getLogger(__name__)

ERROR_PIPELINE = "pipeline_error"
"""Processing a pair raised an error; the pair was skipped."""


@dataclass
class Outgoing:
    """What the output thread sends for one pair (``message`` is None for a bare end of tracks).

    ``payload`` the ``objects`` JSON; ``tracks`` (track id, state JSON) per live track;
    ``ended`` the ids of tracks that ended (a DELETE each); ``images`` references to the
    pair's frames and masks, kept only while some image is subscribed (:mod:`stereod.bus.images`);
    ``pair`` the pair itself (its two frames), kept only when the daemon was asked to
    (``keep_frames``, for an MCAP file written during a replay).
    """

    message: ObjectsMessage | None
    payload: bytes = b""
    tracks: list[tuple[int, bytes]] = field(default_factory=list)
    ended: list[int] = field(default_factory=list)
    result: PairResult | None = None
    images: PairImages | None = None
    pair: StereoPair | None = None


def _empty(pair: StereoPair) -> PairResult:
    """A result with no blobs and no tracks for ``pair``, at the instant the pipeline would
    give it (the earlier eye's capture): what the daemon publishes with detection off."""
    t0 = time.perf_counter_ns()
    nothing = Blobs.empty()
    ms = (time.perf_counter_ns() - t0) * 1e-6
    return PairResult(
        seq=pair.seq,
        t_ns=min(pair.left.t_ns, pair.right.t_ns),
        skew_ns=pair.skew_ns,
        left_seq=pair.left.seq,
        right_seq=pair.right.seq,
        tracks=[],
        ended=[],
        left=nothing,
        right=nothing,
        timings=Timings(0.0, 0.0, 0.0, ms),
    )


READOUT_CHECK_PAIRS = 8
"""Pairs whose left instants give the frame period ``readout_s`` is checked against."""


class PipelineWorker:
    """Runs one pipeline on the pairs of one run (thread target: :meth:`loop`)."""

    def __init__(
        self,
        pipeline: Pipeline,
        pairs: BoundedQueue[Queued],
        out: BoundedQueue[Outgoing],
        health: Health,
        *,
        rig_name: str,
        utc_offset_ns: Callable[[], int | None],
        output_gone: threading.Event,
    ) -> None:
        self.pipeline = pipeline
        self.pairs = pairs
        self.out = out
        self.health = health
        self.rig_name = rig_name
        self._utc_offset_ns = utc_offset_ns
        self._output_gone = output_gone
        """Set once the output thread has ended: a put into a full queue then gives up. Until
        then every result goes out, after a stop too (the output drains what is queued), so a
        stopped file's JSONL holds every pair processed, in order."""
        self._pending: tuple[PipelineParams, Callable[[], None], Callable[[str], None]] | None
        self._pending = None
        self._lock = threading.Lock()
        self._saturated: dict[str, int] = {}
        self.keep_pairs = False
        """Whether each Outgoing keeps a reference to its pair (its frames)."""
        self.want_images: Callable[[], bool] | None = None
        """Asked once per pair: whether to keep references to its frames and masks."""
        self.objects = 0
        """Object states produced so far."""
        self.detect = True
        """Whether pairs go through the pipeline; False publishes an empty result per pair
        (``[daemon] detect = false``: the floor a benchmark compares the daemon with)."""
        self._lefts_ns: list[int] | None = []
        """The first pairs' left capture instants (ns) under the configuration in force,
        until :meth:`_check_readout` has read the frame period from them (then None)."""

    @property
    def rig(self) -> CanonicalRig | CalibratedRig:
        """The geometry in force: the running pipeline's (a reload's once it is swapped in)."""
        return self.pipeline.params.rig

    def reconfigure(
        self,
        params: PipelineParams,
        on_applied: Callable[[], None] = lambda: None,
        on_failure: Callable[[str], None] = lambda why: None,
    ) -> None:
        """Use ``params`` from the next pair on, or within a quarter second without pairs
        (any thread; the last call wins: one replaced before it was used is dropped). Once
        the new pipeline runs, ``on_applied`` is called; should it fail to be made, the
        running one stays and ``on_failure`` is told why (both on the pipeline thread)."""
        with self._lock:
            self._pending = (params, on_applied, on_failure)

    def _swap(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is None:
            return
        params, on_applied, on_failure = pending
        try:
            self.pipeline, ended = self.pipeline.reconfigured(params)
        except Exception as exc:  # nothing a reload brings may end a running daemon
            log.warning("reload: the new pipeline could not be made", exc_info=True)
            on_failure(f"{type(exc).__name__}: {exc}")
            return
        self._lefts_ns = []
        rig = params.rig
        self.health.geometry = rig.geometry
        self.health.calibration_id = rig.calibration_id
        self.health.geometry_note = geometry_note(rig)
        on_applied()  # before a put that may wait: the queryables and ROS 2 agree at once
        if ended:
            self.out.put(Outgoing(None, ended=ended), self._output_gone)

    def loop(self) -> None:
        try:
            while True:
                try:
                    item = self.pairs.get(timeout=0.25)
                except Closed:
                    break
                self._swap()
                if item is None:
                    continue
                what, queued_at = item
                if isinstance(what, Frame):
                    self._ahead(what)
                    continue
                pair = what
                queued_ms = (time.perf_counter_ns() - queued_at) * 1e-6
                self.health.busy("pipeline")
                try:
                    result = self.pipeline.process(pair) if self.detect else _empty(pair)
                    outgoing = self.outgoing(result, queued_ms)
                except Exception as exc:  # one bad pair must not stop the daemon
                    self.health.error(ERROR_PIPELINE)
                    self.health.problem(
                        f"pair {pair.seq}: processing failed: {exc}", ERROR_PIPELINE
                    )
                    log.debug("pair %d failed", pair.seq, exc_info=True)
                    continue
                finally:
                    self.health.idle("pipeline")
                self._count_saturated()
                self._check_readout(pair)
                self.health.pair_done(
                    result.timings.pipeline_ms, pair.skew_ns * 1e-6, result.row_residuals_px
                )
                self.objects += len(result.tracks)
                if self.want_images is not None and self.want_images():
                    outgoing.images = self._images(pair)
                if self.keep_pairs:
                    outgoing.pair = pair
                self.out.put(outgoing, self._output_gone)
            self._swap()
            ended = self.pipeline.finish()
            if ended:
                self.out.put(Outgoing(None, ended=ended), self._output_gone)
        finally:
            self.pipeline.close()
            self.out.close()

    def _ahead(self, frame: Frame) -> None:
        """Detect a frame whose partner is still to come (its pair is then quicker), unless a
        pair is already waiting (with two detect workers the pair would detect both eyes at
        once). A failure is left for the pair to report: it detects the frame again."""
        if len(self.pairs) or not self.detect:
            return
        try:
            self.pipeline.detect_ahead(frame)
        except Exception:
            log.debug("%s frame %d failed ahead", frame.eye.value, frame.seq, exc_info=True)

    def _images(self, pair: StereoPair) -> PairImages:
        """References (no copies) to what the pipeline used for ``pair``: its frames, which
        no one writes to, and the detectors' masks, which each frame replaces rather than
        overwrites (see :attr:`stereod.vision.detect.Detector.mask`)."""
        p = self.pipeline
        return PairImages(
            pair.left.image, pair.right.image, p.left.mask, p.right.mask, p.params.rig
        )

    def _check_readout(self, pair: StereoPair) -> None:
        """Once per configuration, from its first :data:`READOUT_CHECK_PAIRS` pairs: a
        ``readout_s`` longer than the frame period (their left instants' median step) cannot
        be a rolling shutter's, which reads a frame within its period; each blob's instant
        would be put that far off. Said on the status key (a notice: the run goes on)."""
        if self._lefts_ns is None:
            return
        self._lefts_ns.append(pair.left.t_ns)
        if len(self._lefts_ns) < READOUT_CHECK_PAIRS:
            return
        period_s = statistics.median(b - a for a, b in itertools.pairwise(self._lefts_ns)) * 1e-9
        self._lefts_ns = None
        readout_s = self.pipeline.params.readout_s
        if period_s > 0.0 and readout_s > period_s:
            self.health.problem(
                f"rig.readout_s {readout_s:g} s is longer than the frame period "
                f"{period_s:.4f} s ({1.0 / period_s:.3g} Hz): a rolling shutter reads a frame "
                "within its period; measure it (docs: concepts, rolling shutter), or set 0 for "
                "a global shutter",
                "readout_too_long",
                notice=True,
            )

    def _count_saturated(self) -> None:
        """Report frames the detectors found saturated (all foreground) since the last pair."""
        for name, det in (("left", self.pipeline.left), ("right", self.pipeline.right)):
            n = det.saturated - self._saturated.get(name, 0)
            if n > 0:
                self.health.error(f"{name}_saturated", n)
                self.health.problem(
                    f"{name} eye: the whole scene changed (most of the image is foreground); "
                    "no objects until the background has learned it again",
                    f"{name}_saturated",
                    notice=True,  # the scene's doing, handled: not a fault of the input
                )
            self._saturated[name] = det.saturated

    def outgoing(self, result: PairResult, queued_ms: float) -> Outgoing:
        """The wire payloads of one result, serialised once here."""
        rig = self.pipeline.params.rig
        msg = objects_message(
            result,
            rig=self.rig_name,
            geometry=rig.geometry,
            calibration_id=rig.calibration_id,
            utc_offset_ns=self._utc_offset_ns() or 0,
            queue_ms=queued_ms,
        )
        payload, tracks = dump_objects(msg)
        return Outgoing(msg, payload, tracks, result.ended, result)
