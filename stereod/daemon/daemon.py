"""The running daemon: it opens the source and the session, starts the threads, and runs the
status loop (status key, systemd notifications, reloads) until the input ends or a stop.

::

    capture thread(s) --pairs--> [queue] --> pipeline thread --payloads--> [queue] --> output
      (capture.py)                           (processing.py)                         (output.py)
                                                                                 Zenoh, JSONL
    status loop (this module): status key, sd_notify, SIGHUP reloads, fatal errors
    image thread (images.py): draws and encodes pictures, only while someone subscribes

A live source gets drop-oldest queues (a camera cannot wait); a file source gets blocking
queues (nothing is lost). Every thread's failure reaches the run's result: a capture or output
failure ends the run with that error; anything else that escapes a thread ends it with an
internal error (exit 70) naming the log.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from stereod.bus.images import ImagePublishers, ImageWorker
from stereod.bus.messages import DaemonState, StatusMessage, dump
from stereod.bus.publish import Publisher
from stereod.daemon.capture import Capture, Queued
from stereod.daemon.config import StereodConfig
from stereod.daemon.memory import release_library_pages, separate_large_buffers
from stereod.daemon.output import Output
from stereod.daemon.params import pipeline_params
from stereod.daemon.processing import Outgoing, PipelineWorker
from stereod.daemon.reload import RELOAD_REFUSED, RELOAD_WAITING, effective, waiting
from stereod.daemon.replies import calibration_reply, config_reply
from stereod.daemon.ros2_node import give_geometry, make_node
from stereod.daemon.sdnotify import Notifier
from stereod.daemon.shared_rig import SharedRig
from stereod.daemon.status import Health, geometry_note
from stereod.errors import InternalError, ReaderGone, StereodError
from stereod.files.output_file import AtomicOutput, check_outputs, give_up_writing
from stereod.pipeline import Pipeline
from stereod.sources.frames import Driver, Eye, StereoSource
from stereod.sources.pairing import Pairer
from stereod.sources.queues import BoundedQueue

if TYPE_CHECKING:
    import zenoh

    from stereod.ros.ros2_live import Ros2Live

log = logging.getLogger(__name__)

UNPAIRED_SHARE = 0.1
"""At the end of a file, more than this share of its frames without a partner is a fault of
the input (its eyes' timestamps disagree), not chance: a few frames at its ends may be."""

STOP_WRITE_S = 2.0
"""Once a stop is asked for, how long (s) an output written in place (a pipe) may wait for a
reader that stopped reading before it counts as gone: the daemon then ends all the same."""
EYES_STOP_S = 1.0
"""How long (s) after a stop the daemon waits for an eye's read to return before it leaves
that eye behind and ends the run with what is queued (the docs promise an exit within 2 s;
the units' ``TimeoutStopSec`` is 5 s)."""
STUCK_S = 5.0
"""A pipeline or output thread working on one item (a pair, a message) for longer than this
(s) is hung (a live source's: a file's may wait for its JSONL's reader): said on the status
key, and the systemd watchdog is no longer fed. A pair takes milliseconds, and a live JSONL
write into a pipe gives up after ``JSONL_STALL_S``."""
JSONL_STALL_S = 2.0
"""How long (s) a live daemon's JSONL written into a pipe may wait for its reader to take a
message: a reader that stays open and stops reading would otherwise hold the output thread,
and with it every Zenoh message. It then counts as gone (said on the status key)."""

DROP_PIPELINE_BEHIND = "pipeline_behind"
"""A pair waited too long for the pipeline and a newer one replaced it (live sources)."""
DROP_PUBLISH_BEHIND = "publish_behind"
"""A message waited too long for the output thread and a newer one replaced it (live sources)."""


@dataclass
class RunSummary:
    """What a run did; ``error`` is set when it stopped on a fatal problem."""

    pairs: int = 0
    published: int = 0
    objects: int = 0
    frames: dict[str, int] = field(default_factory=dict)
    drops: dict[str, int] = field(default_factory=dict)
    errors: dict[str, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    input_problems: list[str] = field(default_factory=list)
    """The problems of a file source's input itself, found at its end (a truncated video,
    eyes that never paired): such a run exits 65, a daemon's run too."""
    error: StereodError | None = None


def _both(
    first: Callable[[Outgoing], None], second: Callable[[Outgoing], None] | None
) -> Callable[[Outgoing], None]:
    if second is None:
        return first

    def call(item: Outgoing) -> None:
        first(item)
        second(item)

    return call


class Daemon:
    """Runs one rig from a driver until the input ends or :meth:`stop` is called.

    ``rate`` paces file sources (1 real time, 0 as fast as possible); ``jsonl`` also writes
    every ``objects`` message to that file (committed at the end of the run);
    ``wait_subscriber_s`` waits that long for a subscriber before capture starts;
    ``reload_config`` re-reads the configuration on :meth:`reload`; ``inputs`` are files the
    run reads besides the source's own (the config file), which ``jsonl`` must not be;
    ``on_message`` sees every published pair on the output thread (its frames in
    ``Outgoing.pair`` with ``keep_frames``); it publishes on ``session`` (the caller's to close)
    when given, else on a session of ``cfg.zenoh``'s.
    """

    def __init__(
        self,
        cfg: StereodConfig,
        driver: Driver,
        *,
        rate: float = 1.0,
        jsonl: Path | None = None,
        wait_subscriber_s: float = 0.0,
        reload_config: Callable[[], StereodConfig] | None = None,
        notifier: Notifier | None = None,
        on_message: Callable[[Outgoing], None] | None = None,
        keep_frames: bool = False,
        inputs: Sequence[Path] = (),
        session: zenoh.Session | None = None,
    ) -> None:
        self.cfg = cfg
        self.driver = driver
        self.rate = rate
        self.jsonl = jsonl
        self.wait_subscriber_s = wait_subscriber_s
        self._reload_config = reload_config
        self._notifier = notifier if notifier is not None else Notifier()
        self._on_message = on_message
        self._keep_frames = keep_frames
        self._inputs = [*inputs, *([cfg.rig.calibration] if cfg.rig.calibration else [])]
        self._session = session
        self._stop = threading.Event()
        self._status_now = threading.Event()
        self._reload_requested = threading.Event()
        self._fatal_lock = threading.Lock()
        self._fatal: StereodError | None = None
        self._settled = False
        """Set once the run's outcome is decided (its output committed or discarded): an error
        after that is logged, not made the run's, so what is reported matches what is on disk."""
        self._source: StereoSource | None = None
        self._problems_said: set[str] = set()
        """What the source has said of its input and this run has reported (see
        :meth:`_input_problems`)."""
        self._worker: PipelineWorker | None = None
        self._left_behind = False
        """Whether an eye was left behind at the stop (its read had not returned)."""
        self._publisher: Publisher | None = None
        self.pairer = Pairer(int(cfg.pairing.tolerance_ms * 1e6), cfg.pairing.max_pending)
        self.health = Health(cfg.rig.name, driver.name, self.pairer, self._status_now.set)
        self._shared = SharedRig(self.health, cfg.rig.name)
        self.summary = RunSummary()
        self.images: ImageWorker | None = None
        """The image worker of the last run (its counters), None when images were off."""
        self.ros2: Ros2Live | None = None
        """The ROS 2 node of the last run (``[ros2] enabled``), kept for its counters."""

    # -- control (any thread, signal handlers included) --------------------------------------

    def stop(self) -> None:
        """Ask the daemon to stop: capture ends, queued work drains, the session closes."""
        if not self._stop.is_set():
            self._notifier.notify(STOPPING=1)
            if self.health.state is DaemonState.RUNNING:
                self.health.state = DaemonState.STOPPING
        self._stop.set()
        self._status_now.set()
        give_up_writing(STOP_WRITE_S)  # a pipe's reader that stopped reading cannot hold it
        source = self._source
        if source is not None:
            source.left.interrupt()
            source.right.interrupt()

    def reload(self) -> None:
        """Ask for the configuration and calibration to be read again (SIGHUP); done by the
        status loop, so it is safe to call from a signal handler."""
        self._reload_requested.set()
        self._status_now.set()

    def fail(self, exc: BaseException) -> None:
        """End the run with ``exc`` as its error (the first one wins)."""
        if isinstance(exc, StereodError):
            err: StereodError = exc
        else:
            log.error("internal error", exc_info=exc)
            err = InternalError(f"internal error: {type(exc).__name__}: {exc}")
        with self._fatal_lock:
            if self._settled:
                log.warning("after the run ended: %s", err)
                return
            if self._fatal is None:
                self._fatal = err
        # The run's error is said once, by whoever reports the run's end; here only the
        # status key learns of it.
        self.health.problem(str(err), logged=False)
        self.stop()

    def _jsonl_reader_gone(self, exc: ReaderGone) -> None:
        """The reader of the JSONL, written into a pipe, closed it: a daemon runs on without
        it and says so on its status key (a replay ends instead)."""
        self.health.problem(f"{exc}; the JSONL output is no longer written")

    def _ready(self) -> None:
        self._notifier.notify(READY=1, STATUS="streaming")

    def stats(self) -> bytes:
        """The ``stats`` queryable's reply."""
        return dump(self.health.stats())

    # -- run ---------------------------------------------------------------------------------

    def run(self) -> RunSummary:
        """Open the source and the session, run to the end of input or :meth:`stop`."""
        source = self.driver.open()
        try:
            self._source = source
            info = source.info
            separate_large_buffers(info.width, info.height)
            self.pairer.in_order = not info.live  # a file's frames come merged in time order
            if self.jsonl is not None:
                check_outputs({"--jsonl": self.jsonl}, [*info.inputs, *self._inputs])
            params = pipeline_params(self.cfg, info.width, info.height)
            jsonl = AtomicOutput(self.jsonl) if self.jsonl is not None else None
            if jsonl is not None and info.live:
                jsonl.limit_stall(JSONL_STALL_S)
            pipeline = Pipeline(params)
            release_library_pages()  # everything is loaded: keep mapped what runs from here
            try:
                self._run(source, pipeline, jsonl)
            except BaseException:
                if jsonl is not None:
                    jsonl.discard()
                raise
            with self._fatal_lock:
                self._settled = True
                failed = self._fatal is not None
            if jsonl is not None:
                # A failed run never replaces what the file held before, nor one that wrote
                # no message (stopped before its first pair).
                if failed or (not jsonl.in_place and jsonl.tell() == 0):
                    jsonl.discard()
                else:
                    jsonl.commit()
        finally:
            if self._left_behind:  # closing it under an eye's read could crash the process
                log.warning("the source is left open: an eye's read has not returned")
            else:
                source.close()
        return self._finish()

    def _thread(
        self, target: Callable[[], None], name: str, daemon: bool = False
    ) -> threading.Thread:
        """A thread whose unexpected failure ends the run instead of vanishing (``daemon``:
        one the process need not wait for, an eye whose read may hang)."""

        def guarded() -> None:
            try:
                target()
            except BaseException as exc:
                self.fail(exc)

        return threading.Thread(target=guarded, name=name, daemon=daemon)

    def _run(self, source: StereoSource, pipeline: Pipeline, jsonl: AtomicOutput | None) -> None:
        cfg, info, h = self.cfg, source.info, self.health
        h.live = info.live
        h.source_description = info.description
        h.geometry = pipeline.params.rig.geometry
        h.calibration_id = pipeline.params.rig.calibration_id
        h.geometry_note = geometry_note(pipeline.params.rig)
        if h.geometry_note:
            log.info("%s", h.geometry_note)
        h.watch(source.left, source.right)
        pairs: BoundedQueue[Queued] = BoundedQueue(cfg.daemon.queue_size, drop_oldest=info.live)
        out: BoundedQueue[Outgoing] = BoundedQueue(
            cfg.daemon.publish_queue_size, drop_oldest=info.live
        )
        h.queue_depth = pairs.__len__
        h.watch_queue(DROP_PIPELINE_BEHIND, pairs)
        h.watch_queue(DROP_PUBLISH_BEHIND, out)
        capture = Capture(
            source,
            self.pairer,
            pairs,
            h,
            self._stop,
            rate=self.rate,
            on_ready=self._ready,
            on_fatal=self.fail,
        )
        output_gone = threading.Event()
        worker = PipelineWorker(
            pipeline,
            pairs,
            out,
            h,
            rig_name=cfg.rig.name,
            utc_offset_ns=lambda: capture.utc_offset_ns,
            output_gone=output_gone,
        )
        worker.keep_pairs = self._keep_frames
        worker.detect = cfg.daemon.detect
        self._worker = worker
        queryables = {
            "config": lambda: config_reply(self.cfg),
            "calibration": lambda: calibration_reply(worker.rig),
            "stats": self.stats,
        }
        status_now, session = self._status_now.set, self._session
        with Publisher(cfg.zenoh, cfg.rig.name, queryables, status_now, session=session) as pub:
            self._publisher = pub
            if pub.rig_taken:
                self._rig_taken(pub)
            self._wait_for_subscriber(pub)
            if not self._stop.is_set():
                h.state = DaemonState.RUNNING
            images = self._image_worker(pub)
            on_message = self._on_message
            if images is not None:
                worker.want_images = images.wanted
                on_message = _both(images.offer, self._on_message)
            ros2 = self.ros2 = make_node(cfg, pub.session, worker.rig, h)
            if ros2 is not None:  # frames by reference: each eye's instant, images on demand
                worker.keep_pairs = True
                on_message = _both(ros2.offer, on_message)
            output = Output(
                out,
                pub,
                h,
                jsonl=jsonl,
                on_fatal=self.fail,
                on_message=on_message,
                on_reader_gone=self._jsonl_reader_gone,
                live=info.live,
            )
            eyes = [self._thread(loop, name, daemon=True) for name, loop in capture.loops()]
            sender = self._thread(output.loop, "output")
            threads = [self._thread(worker.loop, "pipeline"), sender]
            painter = self._thread(images.loop, "images") if images is not None else None
            try:
                for t in [*eyes, *threads, *([painter] if painter else [])]:
                    t.start()
                self._status_loop(pub, sender, capture, eyes, (info.width, info.height))
            finally:  # also on Ctrl-C in this thread: no thread outlives the run
                output_gone.set()  # the output thread has ended, or is to: nothing waits for it
                if any(t.is_alive() for t in [*eyes, *threads]):
                    self.stop()
                until = time.monotonic() + EYES_STOP_S  # one wait for all, none if left behind
                for t in eyes:
                    if t.ident is not None and not self._left_behind:
                        t.join(max(until - time.monotonic(), 0.0))
                self._leave_behind(capture, eyes)  # before the pipeline, which waits for them
                for t in threads:
                    if t.ident is not None:
                        t.join()
                if ros2 is not None:
                    ros2.close()
                if images is not None and painter is not None:
                    images.close()
                    if painter.ident is not None:
                        painter.join()
                    images.publishers.close()
                    self.images = images
            self._input_problems(final=True)
            self._check_paired()
            with self._fatal_lock:
                failed = self._fatal is not None
            h.state = DaemonState.FAILED if failed else DaemonState.FINISHED
            pub.status(dump(h.status(final=True)))
            self.summary.objects = worker.objects

    def _image_worker(self, pub: Publisher) -> ImageWorker | None:
        """The image thread's worker, or None when images are off (``image_rate_hz = 0``)."""
        d = self.cfg.daemon
        if d.image_rate_hz <= 0:
            return None
        publishers = ImagePublishers(pub.session, self.cfg.rig.name, prefix=self.cfg.zenoh.prefix)
        return ImageWorker(
            publishers, self.health, rate_hz=d.image_rate_hz, quality=d.image_quality
        )

    def _status_loop(
        self,
        pub: Publisher,
        sender: threading.Thread,
        capture: Capture,
        eyes: list[threading.Thread],
        size: tuple[int, int],
    ) -> None:
        period = self.cfg.daemon.status_period_s
        stopped_at: float | None = None
        last = time.monotonic()
        pub.status(dump(self.health.status()))
        watchdog = self._notifier.watchdog_s
        last_dog = 0.0
        while sender.is_alive():
            self._status_now.wait(min(period, 0.25))
            now = time.monotonic()
            if self._reload_requested.is_set():
                self._reload_requested.clear()
                self._do_reload(*size)
            if self._stop.is_set() and stopped_at is None:
                stopped_at = now
            elif stopped_at is not None and now - stopped_at > EYES_STOP_S:
                self._leave_behind(capture, eyes)
                stopped_at = math.inf
            if self._status_now.is_set() or now - last >= period:
                self._status_now.clear()
                self._input_problems()
                self._shared.check(pub.foreign_status_at, pub.base, period)
                status = self.health.status(now)
                pub.status(dump(status))
                self._notify_status(status)
                last = now
            moving = not (self.health.live and self.health.check_stuck(STUCK_S, bool(watchdog)))
            if watchdog and now - last_dog >= watchdog / 2 and self.health.frames_flowing(watchdog):
                if moving:
                    self._notifier.notify(WATCHDOG=1)
                last_dog = now

    def _input_problems(self, final: bool = False) -> None:
        """Report what the source has said of its input since last asked (a file's truncated
        or damaged video, found as it plays): on the status key as the run goes (a looping
        replay may never end), and, from a file, among the run's input problems; ``final``
        once reading has stopped, with what only then can be said."""
        source = self._source
        if source is None:
            return
        for p in source.problems() + (source.final_problems() if final else []):
            if p not in self._problems_said:
                self._problems_said.add(p)
                self.health.problem(p)
                if not source.info.live:
                    self.summary.input_problems.append(p)

    def _notify_status(self, status: StatusMessage) -> None:
        if not self._notifier.enabled:
            return
        drops = sum(status.drops.values())
        skew = f"{status.skew_ms_mean:.1f}" if status.skew_ms_mean is not None else "-"
        self._notifier.notify(
            STATUS=f"{status.state.value}: left {status.left.fps:.1f} fps, right "
            f"{status.right.fps:.1f} fps, {status.pairs_per_s:.1f} pairs/s, skew {skew} ms, "
            f"{drops} dropped"
        )

    def _do_reload(self, width: int, height: int) -> None:
        """Read the configuration and calibration again. A valid new one is handed to the
        pipeline thread, which swaps it in between two pairs; whatever the new files hold,
        an invalid one leaves everything as it was and says why."""
        if self._reload_config is None:
            self.health.problem(
                "reload requested but this run has no configuration file to re-read", notice=True
            )
            return
        self._notifier.notify(RELOADING=1)
        try:
            new = self._reload_config()
            cfg = effective(self.cfg, new)
            params = pipeline_params(cfg, width, height)
        except Exception as exc:  # nothing in a new file may kill a running daemon
            reason = str(exc) if isinstance(exc, StereodError) else f"{type(exc).__name__}: {exc}"
            self.health.restate(RELOAD_REFUSED, f"{RELOAD_REFUSED}: {reason}", notice=True)
            self._notifier.notify(READY=1)
            return
        waits = waiting(self.cfg, new)
        self.health.resolved(RELOAD_WAITING)  # what an earlier reload said waits may not now
        if waits:
            self.health.problem(
                f"{RELOAD_WAITING} {', '.join(waits)} take effect at the next restart",
                notice=True,
            )
        assert self._worker is not None

        def applied() -> None:  # on the pipeline thread, once the new pipeline runs
            # An earlier reload refused while this one waited said so after the resolve below.
            self.health.resolved(RELOAD_REFUSED)
            self.cfg = cfg
            give_geometry(self.ros2, params.rig, self.health)
            log.info("configuration reloaded (geometry %s)", params.rig.geometry.value)

        def failed(why: str) -> None:  # there too: the running pipeline and cfg stay
            self.health.restate(RELOAD_REFUSED, f"{RELOAD_REFUSED}: {why}", notice=True)

        self.health.resolved(RELOAD_REFUSED)  # before the swap, which may refuse it yet
        self._worker.reconfigure(params, applied, failed)
        self._notifier.notify(READY=1)
        self._status_now.set()

    def _leave_behind(self, capture: Capture, eyes: list[threading.Thread]) -> None:
        """Leave behind the eyes still reading (once): the run ends without them, and their
        source is not closed under their reads."""
        late = [t.name for t in eyes if t.is_alive()]
        if late and not self._left_behind:
            self.health.problem(
                f"{', '.join(late)}: reading still {EYES_STOP_S:g} s after the stop (the "
                "driver's read cannot be interrupted); left behind"
            )
            capture.leave_behind()
            self._left_behind = True

    def _rig_taken(self, pub: Publisher) -> None:
        """Another daemon's token for this rig was on the bus at open (a replay refuses)."""
        self._shared.taken_at_open(pub.base)

    def _wait_for_subscriber(self, pub: Publisher) -> None:
        deadline = time.monotonic() + self.wait_subscriber_s
        while time.monotonic() < deadline and not self._stop.is_set():
            if pub.has_objects_subscriber():
                return
            time.sleep(0.02)

    def _check_paired(self) -> None:
        """At the end of a run in which both eyes gave frames and none found a partner, say
        how far apart the eyes' last frames were (on the last status and in the summary); at
        the end of a file in which more than ``UNPAIRED_SHARE`` of the frames found none, say
        that (its timestamps disagree part of the way: a timestamp file that jumps), unless
        the input has already said why frames are missing (a truncated or damaged video: the
        other eye's frames of those instants have no partner, whatever their timestamps)."""
        st = self.pairer.stats
        frames = sum(st.frames.values())
        unpaired = frames - 2 * st.pairs
        live = self._source is None or self._source.info.live
        explained = bool(self.summary.input_problems)
        if st.pairs and not live and not explained and unpaired > UNPAIRED_SHARE * frames:
            text = (
                f"{unpaired} of {frames} frames found no partner of the other eye within "
                f"{self.pairer.tolerance_ns / 1e6:g} ms: the eyes' timestamps disagree for "
                "part of the input"
            )
            self.health.problem(text)
            self.summary.input_problems.append(text)
        left, right = self.pairer.last_ns(Eye.LEFT), self.pairer.last_ns(Eye.RIGHT)
        if self.pairer.stats.pairs == 0 and left is not None and right is not None:
            text = (
                f"no pairs: no frame had a partner of the other eye within "
                f"{self.pairer.tolerance_ns / 1e6:g} ms; the eyes' last frames were "
                f"{abs(left - right) / 1e9:.3g} s apart, so their clocks or timestamp files "
                "do not agree"
            )
            self.health.problem(text)
            if self._source is not None and not self._source.info.live:
                self.summary.input_problems.append(text)

    def _finish(self) -> RunSummary:
        s = self.summary
        st = self.pairer.stats
        drops, errors, _ = self.health.counters()
        s.pairs = st.pairs
        s.frames = {e.value: n for e, n in st.frames.items()}
        s.drops = drops
        s.errors = errors
        s.problems = self.health.problems()
        s.published = self._publisher.published if self._publisher is not None else 0
        s.error = self._fatal
        return s
