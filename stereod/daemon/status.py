"""The daemon's health: eye states, counters, problems, and the status and stats messages.

Every thread reports here (the capture threads their frames and failures, the pipeline thread
its timings and errors, the output thread its write failures); the status loop reads it once a
second and on change. Counters are kept apart by kind: ``drops`` (data lost: frames or pairs),
``errors`` (data that arrived unusable, or processing that failed) and ``reconnects``.
Problems are one line each; a repeated kind is logged the 1st, 10th, 100th... time only, so a
stream of bad frames cannot flood the journal. What goes on the bus has its paths reduced to
file names (:mod:`stereod.daemon.redact`); the log keeps them whole.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from stereod.bus.messages import DaemonState, EyeState, EyeStatus, StatsMessage, StatusMessage
from stereod.daemon.redact import public_text
from stereod.fusion.discipline import DisciplineCache
from stereod.sources.frames import Eye, EyeSource
from stereod.sources.pairing import Pairer
from stereod.sources.queues import BoundedQueue
from stereod.vision.geometry import Geometry

log = logging.getLogger(__name__)


def _nonzero(counts: dict[str, int]) -> dict[str, int]:
    return {k: v for k, v in sorted(counts.items()) if v}


RATE_WINDOW_S = 0.5
"""The shortest time (s) a rate on the status key is measured over: a status sent sooner after
the last measure (at a new subscriber's request, or the last one of a run) repeats that
measure, rather than one over a few milliseconds (0 frames a second while streaming)."""


class Rate:
    """How fast a count grows (per s), measured over windows of at least
    :data:`RATE_WINDOW_S` from ``start_s`` (monotonic s) on."""

    def __init__(self, start_s: float) -> None:
        self._at_s = start_s
        self._count = 0
        self._measured = False
        self.value = 0.0

    def at(self, count: int, now_s: float, final: bool = False) -> float:
        """The rate over the window that ends at ``now_s`` with ``count``, if it is long
        enough (then a new window starts), else the last window's; ``final``: the run ends,
        and a run shorter than one window is measured over what there was."""
        dt = now_s - self._at_s
        if dt >= RATE_WINDOW_S or (final and not self._measured and dt > 0):
            self.value = (count - self._count) / dt
            self._at_s, self._count, self._measured = now_s, count, True
        return self.value


class EyeHealth:
    """One eye's state and frame count (updated by its capture thread)."""

    def __init__(self, start_s: float = 0.0) -> None:
        self.state = EyeState.STARTING
        self.frames = 0
        self.errors = 0
        self.last_error: str | None = None
        self.last_frame_s = 0.0
        """When (monotonic s) its last frame arrived; 0 before the first."""
        self.rate = Rate(start_s)
        """Its frames per second (see :class:`Rate`)."""


STALL_S = 3.0
"""A live eye that streamed but has delivered no frame for this long (s) is reported down,
whatever its driver does about it (the V4L2 driver reopens such an eye after its own
``stall_s``, 2 s): a camera can stop mid-stream and stay open, and the other eye's frames alone
make no pair. A Minoru delivers 15 or 30 frames a second."""


def geometry_note(rig: object) -> str:
    """What an uncalibrated run's depths rest on, said plainly; empty when calibrated."""
    hfov = getattr(rig, "hfov_deg", None)
    if getattr(rig, "calibration_id", None) is not None or hfov is None:
        return ""
    return (
        f"no calibration: every depth assumes a {hfov:g} deg horizontal field of view and a "
        f"{getattr(rig, 'baseline_m', 0.06):g} m baseline; a Minoru has been measured at about "
        "42 deg, and each depth scales with that figure (42 for 60 makes depths 1.5x too "
        "large): run stereod calibrate"
    )


class Health:
    """Shared, lock-protected health of one daemon run."""

    def __init__(self, rig: str, driver: str, pairer: Pairer, on_change: Callable[[], None]):
        self.rig = rig
        self.driver = driver
        self.pairer = pairer
        self.lock = threading.Lock()
        self.started_s = time.monotonic()
        self.eyes = {Eye.LEFT: EyeHealth(self.started_s), Eye.RIGHT: EyeHealth(self.started_s)}
        self.state = DaemonState.STARTING
        self.live = False
        self.source_description = ""
        self.geometry = Geometry.CANONICAL
        self.calibration_id: str | None = None
        self.geometry_note = ""
        self.last_frame_s = 0.0
        self.published = 0
        self.publish_errors = 0
        self.queue_depth: Callable[[], int] = lambda: 0
        self.log_problems = True
        """Log each problem as a warning when it happens (off when the command prints them)."""
        self._sources: list[EyeSource] = []
        self._queues: dict[str, BoundedQueue[Any]] = {}
        self._drops: collections.Counter[str] = collections.Counter()
        self._errors: collections.Counter[str] = collections.Counter()
        self._reconnects: collections.Counter[str] = collections.Counter()
        self._problems: collections.deque[str] = collections.deque(maxlen=20)
        self._all_problems: list[str] = []
        self._failing: list[str] = []
        self._problem_counts: dict[str, int] = {}
        self._pipeline_ms: collections.deque[float] = collections.deque(maxlen=2000)
        self._skews_ms: list[float] = []
        self._pairs_done = 0
        self._pair_rate = Rate(self.started_s)
        """Pairs processed per second (see :class:`Rate`)."""
        self._residuals: list[float] = []
        self._clock = DisciplineCache()
        """How this host's UTC clock is kept (chrony, PTP), for the status key."""
        self._on_change = on_change
        self._busy: dict[str, float] = {}
        """Per thread (``pipeline``, ``output``), when (monotonic s) it took the item it is
        working on; absent while it waits for one."""
        self._stuck: set[str] = set()

    def watch(self, *eyes: EyeSource) -> None:
        """Read these eyes' own counters (sequence gaps, corrupt frames) too."""
        self._sources = list(eyes)

    def watch_queue(self, reason: str, q: BoundedQueue[Any]) -> None:
        """Count what ``q`` drops (a live source's queues drop their oldest item) as ``reason``."""
        self._queues[reason] = q

    # -- reporting ---------------------------------------------------------------------------

    def problem(
        self, text: str, kind: str | None = None, *, logged: bool = True, notice: bool = False
    ) -> None:
        """Record a problem for the status key and the run summary. It is logged as a warning
        unless ``logged`` is false or :attr:`log_problems` is off (a command that prints its
        problems at the end says each once). A ``notice`` says what happened to a run that
        went right (a reload's changes wait for a restart, the scene changed): it is on the
        status key and in the summary, but is no fault of the input (see :meth:`failing`)."""
        key = kind or text
        with self.lock:
            n = self._problem_counts[key] = self._problem_counts.get(key, 0) + 1
            self._problems.append(text)
            if len(self._all_problems) < 1000:
                self._all_problems.append(text)
            if not notice and len(self._failing) < 1000:
                self._failing.append(text)
        if not (logged and (self.log_problems or notice)):  # a notice is never said later
            log.debug("problem: %s", text)
        elif n == 1 or (kind is not None and math.log10(n).is_integer()):
            log.warning("%s%s", text, f" ({n} times)" if n > 1 else "")
        self._on_change()

    def resolved(self, prefix: str) -> None:
        """Take the recent problems that begin with ``prefix`` off the status key: what they
        said holds no more (a reload refused, then one taken). The run's summary keeps them."""
        with self.lock:
            kept = [p for p in self._problems if not p.startswith(prefix)]
            self._problems.clear()
            self._problems.extend(kept)
        self._on_change()

    def restate(self, prefix: str, text: str, *, notice: bool = False) -> None:
        """Say ``text`` in place of the recent problems that begin with ``prefix``: the
        latest refusal of a reload replaces the one before, whose file is no more."""
        self.resolved(prefix)
        self.problem(text, notice=notice)

    def showing(self, prefix: str) -> bool:
        """Whether a recent problem on the status key begins with ``prefix`` (the key keeps
        the last 20: an older one has fallen off)."""
        with self.lock:
            return any(p.startswith(prefix) for p in self._problems)

    def drop(self, reason: str, n: int = 1) -> None:
        with self.lock:
            self._drops[reason] += n

    def error(self, reason: str, n: int = 1) -> None:
        with self.lock:
            self._errors[reason] += n

    def pair_done(self, pipeline_ms: float, skew_ms: float, residuals_px: np.ndarray) -> None:
        with self.lock:
            self._pipeline_ms.append(pipeline_ms)
            self._skews_ms.append(abs(skew_ms))
            self._pairs_done += 1
            self._residuals.extend(residuals_px.tolist())

    def notes(self) -> list[str]:
        """Standing conditions of the run (see :func:`geometry_note`)."""
        return [n for n in (self.geometry_note,) if n]

    def problems(self) -> list[str]:
        """Every problem so far (at most 1000), oldest first."""
        with self.lock:
            return list(self._all_problems)

    def failing(self) -> list[str]:
        """The problems so far that are not notices (at most 1000), oldest first: what makes
        a replay of a file exit 65."""
        with self.lock:
            return list(self._failing)

    def frames_flowing(self, within_s: float) -> bool:
        """Frames arrived within the last ``within_s`` seconds (the watchdog's condition: the
        daemon is not hung; an eye that is down is reported and reopened by its own thread,
        which a restart would not do better)."""
        return time.monotonic() - self.last_frame_s < within_s

    def busy(self, thread: str) -> None:
        """``thread`` took an item to work on (a pair, a message)."""
        self._busy[thread] = time.monotonic()

    def idle(self, thread: str) -> None:
        """``thread`` is done with its item."""
        self._busy.pop(thread, None)

    def check_stuck(self, limit_s: float, watchdog: bool = True) -> bool:
        """Whether a thread has worked on one item for more than ``limit_s`` (s): the daemon
        is hung though frames flow (the watchdog is then no longer fed, and systemd restarts
        it; ``watchdog``: whether there is one). Said on the status key once per thread, and
        taken off when it moves again."""
        now = time.monotonic()
        stuck = {t: now - at for t, at in list(self._busy.items()) if now - at > limit_s}
        for thread, age in stuck.items():
            if thread not in self._stuck:
                self._stuck.add(thread)
                fed = "the watchdog is no longer fed" if watchdog else "no watchdog restarts it"
                self.problem(
                    f"{thread} thread: stuck on one item for {age:.0f} s; {fed}",
                    f"{thread}_stuck",
                )
        for thread in self._stuck - stuck.keys():
            self._stuck.discard(thread)
            self.resolved(f"{thread} thread: stuck")
        return bool(stuck)

    def check_stalls(self) -> None:
        """Report each live eye that is streaming but has had no frame for ``STALL_S``: it is
        down (its next frame counts as a reconnect) and the daemon is degraded."""
        if not self.live:
            return
        now = time.monotonic()
        stalled = []
        with self.lock:
            for eye, h in self.eyes.items():
                quiet = now - h.last_frame_s
                if h.state is EyeState.STREAMING and quiet >= STALL_S:
                    h.state = EyeState.DOWN
                    h.last_error = f"no frame for {quiet:.1f} s"
                    self._errors[f"{eye.value}_stalled"] += 1
                    stalled.append((eye, h.last_error))
        for eye, why in stalled:
            self.problem(f"{eye.value} eye down: {why}; waiting for it", f"{eye.value}_down")

    # -- counters ----------------------------------------------------------------------------

    def counters(self) -> tuple[dict[str, int], dict[str, int], dict[str, int]]:
        """(drops, errors, reconnects) by reason, zeros left out. An eye's own counters (its
        sequence gaps, corrupt frames) are prefixed with the eye's name."""
        drops: dict[str, int] = {}
        errors: dict[str, int] = {}
        for src in self._sources:
            c = src.counters()
            e = src.eye.value
            drops.update({f"{e}_{k}": v for k, v in c.drops.items()})
            errors.update({f"{e}_{k}": v for k, v in c.errors.items()})
        with self.lock:
            drops.update(self.pairer.stats.drops)
            drops.update(self._drops)
            drops.update({reason: q.dropped for reason, q in self._queues.items()})
            errors.update(self._errors)
            reconnects = dict(self._reconnects)
        return _nonzero(drops), _nonzero(errors), _nonzero(reconnects)

    def recovered(self, eye: Eye) -> None:
        """An eye that was down streams again."""
        with self.lock:
            self._reconnects[eye.value] += 1

    # -- messages ----------------------------------------------------------------------------

    def _eye_status(self, eye: Eye, now_s: float, final: bool) -> EyeStatus:
        h = self.eyes[eye]
        return EyeStatus(
            state=h.state,
            fps=round(h.rate.at(h.frames, now_s, final), 3),
            frames=h.frames,
            errors=h.errors,
            last_error=public_text(h.last_error) if h.last_error is not None else None,
        )

    def status(self, now_s: float | None = None, final: bool = False) -> StatusMessage:
        """The status message at ``now_s`` (monotonic s, by default now): figures of the time
        since the last one (skews, residuals; reset), and rates over at least
        :data:`RATE_WINDOW_S` (``final``: the run's last, which measures a run shorter than
        that over what there was)."""
        now = time.monotonic() if now_s is None else now_s
        self.check_stalls()
        with self.lock:
            skews, self._skews_ms = self._skews_ms, []
            resid, self._residuals = self._residuals, []
            problems = list(self._problems)
        drops, errors, reconnects = self.counters()
        state = self.state
        eyes_ok = all(
            h.state in (EyeState.STARTING, EyeState.STREAMING) for h in self.eyes.values()
        )
        if state is DaemonState.RUNNING and self.live and not eyes_ok:
            state = DaemonState.DEGRADED
        return StatusMessage(
            rig=self.rig,
            state=state,
            stamp_utc_ns=time.time_ns(),
            uptime_s=round(time.monotonic() - self.started_s, 3),
            driver=self.driver,
            source=public_text(self.source_description),
            left=self._eye_status(Eye.LEFT, now, final),
            right=self._eye_status(Eye.RIGHT, now, final),
            pairs=self.pairer.stats.pairs,
            pairs_per_s=round(self._pair_rate.at(self._pairs_done, now, final), 3),
            published=self.published,
            drops=drops,
            errors=errors,
            reconnects=reconnects,
            skew_ms_mean=round(float(np.mean(skews)), 3) if skews else None,
            skew_ms_max=round(float(np.max(skews)), 3) if skews else None,
            queue_depth=self.queue_depth(),
            geometry=self.geometry,
            calibration_id=self.calibration_id,
            epipolar_residual_px=round(float(np.median(resid)), 4) if resid else None,
            problems=[public_text(p) for p in problems],
            notes=self.notes(),
            clock=self._clock.get(),
        )

    def stats(self) -> StatsMessage:
        """Counters since start (the ``stats`` queryable)."""
        with self.lock:
            ms = np.array(self._pipeline_ms) if self._pipeline_ms else None
        drops, errors, reconnects = self.counters()
        st = self.pairer.stats
        return StatsMessage(
            rig=self.rig,
            frames={e.value: n for e, n in st.frames.items()},
            pairs=st.pairs,
            published=self.published,
            publish_errors=self.publish_errors,
            drops=drops,
            errors=errors,
            reconnects=reconnects,
            queue_depth=self.queue_depth(),
            pipeline_ms_p50=float(np.percentile(ms, 50)) if ms is not None else None,
            pipeline_ms_p99=float(np.percentile(ms, 99)) if ms is not None else None,
        )
