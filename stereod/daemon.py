"""The running daemon: capture threads, pairer, pipeline thread, publisher thread, status loop.

::

    eye thread(s) --frames--> Pairer --pairs--> [queue] --> pipeline --messages--> [queue] --> Zenoh
                                                                                         \\-> JSONL

A live source gets one capture thread per eye and drop-oldest queues (a camera cannot wait); a
file source gets one thread that merges the two eyes by timestamp, paced at ``rate`` times real
time (0 = as fast as possible), and blocking queues (nothing is lost). Every drop is counted by
reason and reported on the status key; a bad frame or a failing pair is counted and skipped.
"""

from __future__ import annotations

import collections
import json
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

from . import calibration
from .config import StereodConfig
from .errors import CalibrationError, DeviceLost, OutputError, StereodError
from .frames import (
    Driver,
    Eye,
    EyeSource,
    Frame,
    SourceInfo,
    StereoPair,
    StereoSource,
    merged,
)
from .geometry.rectified import CalibratedRig
from .geometry.stereo import CanonicalRig
from .messages import EyeStatus, StatsMessage, StatusMessage, dump
from .pairing import Pairer
from .pipeline import PairResult, Pipeline, PipelineParams
from .publish import Publisher
from .queues import BoundedQueue, Closed
from .sdnotify import Notifier

log = logging.getLogger(__name__)

DROP_PIPELINE_BEHIND = "pipeline_behind"
"""A pair waited too long for the pipeline and a newer one replaced it (live sources)."""
DROP_PUBLISH_BEHIND = "publish_behind"
"""A message waited too long for the publisher and a newer one replaced it (live sources)."""
DROP_PIPELINE_ERROR = "pipeline_error"
"""Processing a pair raised an error; the pair was skipped."""


def make_rig(cfg: StereodConfig, width: int, height: int) -> CanonicalRig | CalibratedRig:
    """The geometry for frames of ``width`` x ``height`` px: the configured calibration, checked
    against that size, or the canonical rig of eq. 9."""
    if cfg.rig.calibration is None:
        return CanonicalRig(cfg.rig.baseline_m, cfg.rig.hfov_deg, width, height)
    cal = calibration.load(cfg.rig.calibration, (width, height))
    try:
        return CalibratedRig(cal)
    except ValueError as exc:
        raise CalibrationError(f"{cfg.rig.calibration}: {exc}") from exc


def pipeline_params(cfg: StereodConfig, width: int, height: int) -> PipelineParams:
    """Pipeline parameters from a configuration, for frames of ``width`` x ``height`` px."""
    return PipelineParams(
        rig_name=cfg.rig.name,
        rig=make_rig(cfg, width, height),
        detector=cfg.detector.params(),
        matching=cfg.matching.params(),
        tracker=cfg.tracking.params(),
        centroid_sigma_px=cfg.matching.centroid_sigma_px,
        detect_workers=cfg.daemon.detect_workers,
        skew_compensation=cfg.pairing.skew_compensation,
        freeze_background=cfg.tracking.freeze_background,
    )


@dataclass
class RunSummary:
    """What a run did; ``error`` is set when it stopped on a fatal problem."""

    pairs: int = 0
    published: int = 0
    objects: int = 0
    frames: dict[str, int] = field(default_factory=dict)
    drops: dict[str, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    error: StereodError | None = None


@dataclass
class _Outgoing:
    payload: bytes
    tracks: list[tuple[int, bytes]]
    ended: list[int]
    n_objects: int


class _EyeHealth:
    def __init__(self) -> None:
        self.state = "starting"
        self.frames = 0
        self.errors = 0
        self.lost = 0
        self.last_error: str | None = None
        self._frames_at_last_status = 0

    def fps(self, period_s: float) -> float:
        n = self.frames - self._frames_at_last_status
        self._frames_at_last_status = self.frames
        return n / period_s if period_s > 0 else 0.0


class Daemon:
    """Runs one rig from an opened driver until the input ends or :meth:`stop` is called."""

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
    ) -> None:
        self.cfg = cfg
        self.driver = driver
        self.rate = rate
        self.jsonl = jsonl
        self.wait_subscriber_s = wait_subscriber_s
        self._reload_config = reload_config
        self._reload_requested = threading.Event()
        self._next_pipeline: Pipeline | None = None
        self._notifier = notifier if notifier is not None else Notifier()
        self._ready_sent = False
        self._last_frame_s = 0.0
        self._stop = threading.Event()
        self._status_now = threading.Event()
        self._lock = threading.Lock()
        self._problems: collections.deque[str] = collections.deque(maxlen=20)
        self._all_problems: list[str] = []
        self._problem_counts: dict[str, int] = {}
        self._eyes = {Eye.LEFT: _EyeHealth(), Eye.RIGHT: _EyeHealth()}
        self._pipeline_ms: collections.deque[float] = collections.deque(maxlen=2000)
        self._skews_ms: list[float] = []
        self._residuals: list[float] = []
        self._errors: collections.Counter[str] = collections.Counter()
        self._fatal: StereodError | None = None
        self._state = "starting"
        self._started = time.monotonic()
        self._summary = RunSummary()
        self._info: SourceInfo | None = None
        self._source: StereoSource | None = None
        self._pairer = Pairer(int(cfg.pairing.tolerance_ms * 1e6), cfg.pairing.max_pending)

    def stop(self) -> None:
        """Ask the daemon to stop: capture ends, queued work drains, the session closes."""
        if not self._stop.is_set():
            self._notifier.notify(STOPPING=1)
        self._stop.set()
        source = self._source
        if source is not None:
            source.left.interrupt()
            source.right.interrupt()

    def reload(self) -> None:
        """Ask for the configuration and calibration to be read again (SIGHUP); done by the
        status loop, so it is safe to call from a signal handler."""
        self._reload_requested.set()
        self._status_now.set()

    def problem(self, text: str, kind: str | None = None) -> None:
        """Record a non-fatal problem for the status key and the run summary.

        Problems of one ``kind`` (say, bad frames of one eye) are logged the 1st, 10th, 100th...
        time only, so a stream of bad frames cannot flood the journal.
        """
        with self._lock:
            n = self._problem_counts[kind or text] = self._problem_counts.get(kind or text, 0) + 1
            self._problems.append(text)
            if len(self._all_problems) < 1000:
                self._all_problems.append(text)
        if n == 1 or (kind is not None and math.log10(n).is_integer()):
            log.warning("%s%s", text, f" ({n} times)" if n > 1 else "")
        self._status_now.set()

    def run(self) -> RunSummary:
        """Open the source and the session, run to the end of input or :meth:`stop`."""
        jsonl_fh = self._open_jsonl()
        try:
            with self.driver.open() as source:
                self._info = source.info
                self._source = source
                if self._stop.is_set():
                    source.left.interrupt()
                    source.right.interrupt()
                return self._run(source, jsonl_fh)
        finally:
            if jsonl_fh is not None:
                jsonl_fh.close()

    def _open_jsonl(self) -> IO[bytes] | None:
        if self.jsonl is None:
            return None
        try:
            return self.jsonl.open("wb")
        except OSError as exc:
            raise OutputError(f"{self.jsonl}: cannot write JSONL output: {exc.strerror}") from exc

    def _run(self, source: StereoSource, jsonl_fh: IO[bytes] | None) -> RunSummary:
        cfg = self.cfg
        info = source.info
        live = info.live
        params = pipeline_params(cfg, info.width, info.height)
        rig = params.rig
        offset = info.utc_offset_ns
        if offset is None and live:
            offset = time.time_ns() - time.monotonic_ns()
        self._utc_offset_ns = offset
        self._pipeline = Pipeline(params, offset or 0)
        self._rig = rig
        self._pairs: BoundedQueue[tuple[StereoPair, int]] = BoundedQueue(
            cfg.daemon.queue_size, drop_oldest=live
        )
        self._out: BoundedQueue[_Outgoing] = BoundedQueue(
            cfg.daemon.publish_queue_size, drop_oldest=live
        )
        queryables = {
            "config": lambda: self.cfg.model_dump_json().encode(),
            "calibration": self._calibration_json,
            "stats": lambda: dump(self.stats()),
        }
        with Publisher(cfg.zenoh, cfg.rig.name, queryables, self._status_now.set) as pub:
            self._publisher = pub
            self._wait_for_subscriber(pub)
            self._state = "running"
            threads = self._capture_threads(source, live)
            threads.append(threading.Thread(target=self._pipeline_loop, name="pipeline"))
            publisher = threading.Thread(
                target=self._publish_loop, args=(pub, jsonl_fh), name="publish"
            )
            threads.append(publisher)
            for t in threads:
                t.start()
            period = cfg.daemon.status_period_s
            last = time.monotonic()
            pub.status(dump(self._status_message(period)))
            watchdog = self._notifier.watchdog_s
            last_dog = 0.0
            while publisher.is_alive():
                self._status_now.wait(min(period, 0.25))
                now = time.monotonic()
                if self._reload_requested.is_set():
                    self._reload_requested.clear()
                    self._do_reload(info.width, info.height)
                if self._status_now.is_set() or now - last >= period:
                    self._status_now.clear()
                    status = self._status_message(max(now - last, 1e-3))
                    pub.status(dump(status))
                    self._notify_status(status)
                    last = now
                if watchdog and now - last_dog >= watchdog / 2 and self._frames_flowing(watchdog):
                    self._notifier.notify(WATCHDOG=1)
                    last_dog = now
            for t in threads:
                t.join()
            self._pipeline.close()
            for p in source.problems():
                self.problem(p)
            self._state = "finished"
            pub.status(dump(self._status_message(max(time.monotonic() - last, 1e-3))))
        return self._finish()

    def _frames_flowing(self, within_s: float) -> bool:
        """Frames arrived within the last ``within_s`` seconds (else the watchdog starves and
        systemd restarts a stalled capture)."""
        return time.monotonic() - self._last_frame_s < within_s

    def _notify_status(self, status: StatusMessage) -> None:
        if not self._notifier.enabled:
            return
        drops = sum(status.drops.values())
        skew = f"{status.skew_ms_mean:.1f}" if status.skew_ms_mean is not None else "-"
        self._notifier.notify(
            STATUS=f"{status.state}: left {status.left.fps:.1f} fps, right "
            f"{status.right.fps:.1f} fps, {status.pairs_per_s:.1f} pairs/s, skew {skew} ms, "
            f"{drops} dropped"
        )

    def _do_reload(self, width: int, height: int) -> None:
        """Read the configuration and calibration again. A valid new one replaces the pipeline
        at the next pair; an invalid one leaves everything as it was and says why."""
        if self._reload_config is None:
            self.problem("reload requested but this run has no configuration file to re-read")
            return
        self._notifier.notify(RELOADING=1)
        try:
            cfg = self._reload_config()
            params = pipeline_params(cfg, width, height)
        except StereodError as exc:
            self.problem(f"reload refused, keeping the running configuration: {exc}")
            self._notifier.notify(READY=1)
            return
        needs_restart = [
            name
            for name in ("driver", "zenoh", "daemon")
            if getattr(cfg, name) != getattr(self.cfg, name)
        ]
        if cfg.rig.name != self.cfg.rig.name:
            needs_restart.append("rig.name")
        if needs_restart:
            self.problem(
                f"reload: changes to {', '.join(needs_restart)} take effect at the next restart"
            )
        self._next_pipeline = self._pipeline.reconfigured(params)
        self.cfg = cfg
        self._rig = params.rig
        log.info("configuration reloaded (geometry %s)", params.rig.geometry)
        self._notifier.notify(READY=1)
        self._status_now.set()

    def _wait_for_subscriber(self, pub: Publisher) -> None:
        deadline = time.monotonic() + self.wait_subscriber_s
        while time.monotonic() < deadline and not self._stop.is_set():
            if pub.has_objects_subscriber():
                return
            time.sleep(0.02)

    def _finish(self) -> RunSummary:
        s = self._summary
        st = self._pairer.stats
        s.pairs = st.pairs
        s.frames = {e.value: n for e, n in st.frames.items()}
        s.drops = self._drops()
        s.problems = list(self._all_problems)
        s.published = self._publisher.published
        s.error = self._fatal
        return s

    def _drops(self) -> dict[str, int]:
        d = dict(self._pairer.stats.drops)
        if self._source is not None:
            for eye in (self._source.left, self._source.right):
                for k, v in eye.stats().items():
                    d[f"{eye.eye.value}_{k}"] = v
        if self._pairs.dropped:
            d[DROP_PIPELINE_BEHIND] = self._pairs.dropped
        if self._out.dropped:
            d[DROP_PUBLISH_BEHIND] = self._out.dropped
        d.update(self._errors)
        return {k: v for k, v in d.items() if v}

    # -- capture ---------------------------------------------------------------------------

    def _capture_threads(self, source: StereoSource, live: bool) -> list[threading.Thread]:
        if live:
            self._eyes_done = 0
            return [
                threading.Thread(
                    target=self._eye_loop, args=(eye,), name=f"capture-{eye.eye.value}"
                )
                for eye in (source.left, source.right)
            ]
        return [threading.Thread(target=self._merge_loop, args=(source,), name="capture")]

    def _push(self, frame: Frame) -> bool:
        if frame.image.shape[:2] != (self._rig.height_px, self._rig.width_px):
            health = self._eyes[frame.eye]
            health.errors += 1
            health.last_error = (
                f"frame {frame.seq} is {frame.image.shape[1]}x{frame.image.shape[0]}, "
                f"stream is {self._rig.width_px}x{self._rig.height_px}"
            )
            self.problem(f"{frame.eye.value} eye: {health.last_error}; skipped", "bad_size")
            return True
        if self._utc_offset_ns is None:
            self._utc_offset_ns = time.time_ns() - frame.t_ns
            self._pipeline.utc_offset_ns = self._utc_offset_ns
        with self._lock:
            health = self._eyes[frame.eye]
            health.frames += 1
            health.state = "streaming"
            pairs = self._pairer.push(frame)
            self._last_frame_s = time.monotonic()
            ready = not self._ready_sent and all(h.frames for h in self._eyes.values())
            if ready:
                self._ready_sent = True
        if ready:
            self._notifier.notify(READY=1, STATUS="streaming")
        now = time.perf_counter_ns()
        return all(self._pairs.put((p, now), self._stop) for p in pairs)

    def _eye_loop(self, eye: EyeSource) -> None:
        health = self._eyes[eye.eye]
        try:
            while not self._stop.is_set():
                try:
                    frame = eye.read()
                except DeviceLost as exc:
                    # The source reconnects by itself on the next read; the eye is down
                    # until a frame arrives again.
                    health.state = "down"
                    health.last_error = str(exc)
                    health.lost += 1
                    self.problem(f"{eye.eye.value} eye down: {exc}; retrying")
                    continue
                if frame is None:
                    break
                if health.state == "down":
                    self.problem(f"{eye.eye.value} eye streaming again")
                self._push(frame)
        except StereodError as exc:
            health.state = "down"
            health.last_error = str(exc)
            self.problem(f"{eye.eye.value} eye: {exc}")
        finally:
            if health.state != "down":
                health.state = "ended"
            with self._lock:
                self._eyes_done += 1
                last = self._eyes_done == 2
            if last:
                self._end_capture()

    def _merge_loop(self, source: StereoSource) -> None:
        t_first: int | None = None
        wall_first = 0.0
        try:
            for frame in merged(source.left, source.right):
                if self._stop.is_set():
                    break
                if self.rate > 0:
                    if t_first is None:
                        t_first, wall_first = frame.t_ns, time.monotonic()
                    due = wall_first + (frame.t_ns - t_first) * 1e-9 / self.rate
                    delay = due - time.monotonic()
                    if delay > 0 and self._stop.wait(delay):
                        break
                if not self._push(frame):
                    break
        except StereodError as exc:
            self._fatal = exc
            self.problem(str(exc))
        finally:
            for h in self._eyes.values():
                if h.state != "down":
                    h.state = "ended"
            self._end_capture()

    def _end_capture(self) -> None:
        with self._lock:
            pairs = self._pairer.flush()
        now = time.perf_counter_ns()
        for p in pairs:
            self._pairs.put((p, now), self._stop)
        self._pairs.close()

    # -- pipeline and publishing -------------------------------------------------------------

    def _pipeline_loop(self) -> None:
        try:
            while True:
                try:
                    item = self._pairs.get(timeout=0.25)
                except Closed:
                    break
                if item is None:
                    continue
                pair, queued_at = item
                if self._next_pipeline is not None:
                    old, self._pipeline, self._next_pipeline = (
                        self._pipeline,
                        self._next_pipeline,
                        None,
                    )
                    ended = old.ended_by_reconfiguration
                    if ended:
                        self._out.put(_Outgoing(b"", [], ended, 0), self._stop)
                try:
                    result = self._pipeline.process(pair, time.perf_counter_ns() - queued_at)
                except Exception as exc:  # one bad pair must not stop the daemon
                    self._errors[DROP_PIPELINE_ERROR] += 1
                    self.problem(f"pair {pair.seq}: processing failed: {exc}", "pipeline_error")
                    continue
                self._account(pair, result)
                self._out.put(self._outgoing(result), self._stop)
            ended = self._pipeline.tracker.end_all()
            if ended:
                self._out.put(_Outgoing(b"", [], ended, 0), self._stop)
        finally:
            self._out.close()

    def _account(self, pair: StereoPair, result: PairResult) -> None:
        with self._lock:
            self._pipeline_ms.append(result.message.latency.pipeline_ms)
            self._skews_ms.append(abs(pair.skew_ns) * 1e-6)
            self._residuals.extend(float(r) for r in result.row_residuals_px)
        self._summary.objects += len(result.message.objects)

    @staticmethod
    def _outgoing(result: PairResult) -> _Outgoing:
        msg = result.message
        tracks = [(o.track_id, dump(o)) for o in msg.objects]
        return _Outgoing(dump(msg), tracks, result.ended, len(msg.objects))

    def _publish_loop(self, pub: Publisher, jsonl_fh: IO[bytes] | None) -> None:
        while True:
            try:
                out = self._out.get(timeout=0.25)
            except Closed:
                break
            if out is None:
                continue
            if out.payload:
                pub.objects(out.payload, out.tracks, out.ended)
                if jsonl_fh is not None:
                    jsonl_fh.write(out.payload + b"\n")
            else:
                pub.objects_end(out.ended)

    # -- status ------------------------------------------------------------------------------

    def _eye_status(self, eye: Eye, period_s: float) -> EyeStatus:
        h = self._eyes[eye]
        return EyeStatus(
            state=h.state,  # type: ignore[arg-type]
            fps=round(h.fps(period_s), 3),
            frames=h.frames,
            errors=h.errors,
            last_error=h.last_error,
        )

    def _status_message(self, period_s: float) -> StatusMessage:
        with self._lock:
            skews, self._skews_ms = self._skews_ms, []
            resid, self._residuals = self._residuals, []
            problems = list(self._problems)
        st = self._pairer.stats
        eyes_ok = all(h.state in ("starting", "streaming") for h in self._eyes.values())
        state = self._state
        if state == "running" and not eyes_ok and self._info is not None and self._info.live:
            state = "degraded"
        info = self._info
        return StatusMessage(
            rig=self.cfg.rig.name,
            state=state,  # type: ignore[arg-type]
            stamp_utc_ns=time.time_ns(),
            uptime_s=round(time.monotonic() - self._started, 3),
            driver=self.driver.name,
            source=info.description if info else "",
            left=self._eye_status(Eye.LEFT, period_s),
            right=self._eye_status(Eye.RIGHT, period_s),
            pairs=st.pairs,
            pairs_per_s=round(len(skews) / period_s, 3),
            published=self._publisher.published,
            drops=self._drops(),
            skew_ms_mean=round(float(np.mean(skews)), 3) if skews else None,
            skew_ms_max=round(float(np.max(skews)), 3) if skews else None,
            queue_depth=len(self._pairs),
            geometry=self._rig.geometry,  # type: ignore[arg-type]
            calibration_id=self._rig.calibration_id,
            epipolar_residual_px=round(float(np.median(resid)), 4) if resid else None,
            problems=problems,
        )

    def stats(self) -> StatsMessage:
        """Counters since start (the ``stats`` queryable)."""
        with self._lock:
            ms = np.array(self._pipeline_ms) if self._pipeline_ms else None
        st = self._pairer.stats
        return StatsMessage(
            rig=self.cfg.rig.name,
            frames={e.value: n for e, n in st.frames.items()},
            pairs=st.pairs,
            published=self._publisher.published,
            publish_errors=self._publisher.errors,
            drops=self._drops(),
            queue_depth=len(self._pairs),
            pipeline_ms_p50=float(np.percentile(ms, 50)) if ms is not None else None,
            pipeline_ms_p99=float(np.percentile(ms, 99)) if ms is not None else None,
        )

    def _calibration_json(self) -> bytes:
        r = self._rig
        if isinstance(r, CalibratedRig):
            return r.calibration.model_dump_json().encode()
        return json.dumps(
            {
                "geometry": "canonical",
                "baseline_m": r.baseline_m,
                "hfov_deg": r.hfov_deg,
                "width_px": r.width_px,
                "height_px": r.height_px,
                "focal_px": r.focal_px,
                "cx_px": r.cx_px,
                "cy_px": r.cy_px,
            }
        ).encode()
