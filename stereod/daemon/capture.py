"""Capture: read both eyes, pace file sources, pair the frames, queue the pairs.

A live source gets one thread per eye, each blocking on its device; a file source gets one
thread that merges the two eyes by timestamp and paces them at ``rate`` times real time (0 = as
fast as possible). Every frame goes through :meth:`Capture.push`: its size is checked, the eye's
health updated, and the pairer fed under one lock; the pairs go to the pipeline's queue, and
a live frame still waiting for its partner goes there too when the queue is empty, so the
idle pipeline detects that eye meanwhile.

An eye thread survives anything its source raises: a :class:`~stereod.errors.DeviceLost` or
any other exception marks the eye down, is counted and reported, and the eye starts over as
after a re-plug (:meth:`~stereod.sources.frames.EyeSource.recover`), with a growing pause between
repeated failures. An eye that streams but then delivers nothing is reported down by the
status loop (:meth:`~stereod.daemon.status.Health.check_stalls`), and its next frame counts as a
reconnect. Only the file merge thread treats an error as the end of the run.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable

from stereod.bus.messages import EyeState
from stereod.daemon.status import Health
from stereod.errors import DeviceLost
from stereod.sources.frames import (
    RETRY_FIRST_S,
    RETRY_MAX_S,
    EyeSource,
    Frame,
    StereoPair,
    StereoSource,
    merged,
)
from stereod.sources.pairing import RESYNC_AFTER, Pairer
from stereod.sources.queues import BoundedQueue

log = logging.getLogger(__name__)

MAX_PACED_GAP_S = 5.0
"""A file's frames are paced at their capture times, but a gap between two of them longer
than this (s, stream time) is not slept through: the replay goes on at once and says so (a
recording that paused, or a timestamp file that jumps)."""

Queued = tuple[StereoPair | Frame, int]
"""A pair, or one eye's frame that is waiting for its partner (for the pipeline to detect
meanwhile, :meth:`~stereod.pipeline.Pipeline.detect_ahead`), and the
``time.perf_counter_ns()`` at which it was queued."""


class Capture:
    """The capture side of one run; :meth:`loops` are the thread targets to start."""

    def __init__(
        self,
        source: StereoSource,
        pairer: Pairer,
        pairs: BoundedQueue[Queued],
        health: Health,
        stop: threading.Event,
        *,
        rate: float,
        on_ready: Callable[[], None],
        on_fatal: Callable[[BaseException], None],
    ) -> None:
        self.source = source
        self.info = source.info
        self.pairer = pairer
        self.pairs = pairs
        self.health = health
        self.stop = stop
        self._order = threading.Lock()
        self.rate = rate
        self._on_ready = on_ready
        self._on_fatal = on_fatal
        self._ready = False
        self._eyes_done = 0
        self.utc_offset_ns: int | None = self.info.utc_offset_ns
        """Wall clock minus the frames' clock (ns): the source's, else measured at start
        (live) or at the first frame (files)."""
        if self.utc_offset_ns is None and self.info.live:
            self.utc_offset_ns = time.time_ns() - time.monotonic_ns()

    def loops(self) -> list[tuple[str, Callable[[], None]]]:
        """(thread name, target) of each capture thread: one per eye when live, else one."""
        if self.info.live:
            return [
                (f"capture-{eye.eye.value}", functools.partial(self._eye_loop, eye))
                for eye in (self.source.left, self.source.right)
            ]
        return [("capture", self._merge_loop)]

    def push(self, frame: Frame) -> bool:
        """Take one frame; False when the pipeline's queue no longer accepts pairs. One eye's
        frame at a time, from pairing to queueing: a pair decided by one eye's thread cannot
        be overtaken by a later one the other's decided meanwhile."""
        with self._order:
            return self._push(frame)

    def _push(self, frame: Frame) -> bool:
        h = self.health
        size = (self.info.height, self.info.width)
        if frame.image.shape[:2] != size:
            eye = h.eyes[frame.eye]
            with h.lock:
                eye.errors += 1
                eye.last_error = (
                    f"frame {frame.seq} is {frame.image.shape[1]}x{frame.image.shape[0]}, "
                    f"stream is {size[1]}x{size[0]}"
                )
            h.error(f"{frame.eye.value}_bad_size")
            h.problem(f"{frame.eye.value} eye: {eye.last_error}; skipped", "bad_size")
            return True
        if self.utc_offset_ns is None:
            self.utc_offset_ns = time.time_ns() - frame.t_ns
        with h.lock:
            eye = h.eyes[frame.eye]
            eye.frames += 1
            back = eye.state is EyeState.DOWN
            eye.state = EyeState.STREAMING
            resyncs = self.pairer.stats.resyncs[frame.eye]
            pairs = self.pairer.push(frame)
            jumped = self.pairer.stats.resyncs[frame.eye] != resyncs
            h.last_frame_s = eye.last_frame_s = time.monotonic()
            ready = not self._ready and all(e.frames for e in h.eyes.values())
            if ready:
                self._ready = True
        if back:
            h.recovered(frame.eye)
            h.problem(f"{frame.eye.value} eye streaming again")
        if jumped:
            h.problem(
                f"{frame.eye.value} eye: its frames went back in time by "
                f"{RESYNC_AFTER} in a row; the frames stamped ahead were dropped and pairing "
                "goes on from these",
                "clock_jump",
            )
        if ready:
            self._on_ready()
        now = time.perf_counter_ns()
        if not pairs:  # its partner is still to come: an idle pipeline may detect it now
            if self.info.live:  # (a file's run stays the same whatever the timing)
                self.pairs.put_if_empty((frame, now))
            return True
        return all(self.pairs.put((p, now), self.stop) for p in pairs)

    def _eye_loop(self, eye: EyeSource) -> None:
        h = self.health
        health = h.eyes[eye.eye]
        name = eye.eye.value
        pause, failing = RETRY_FIRST_S, False
        try:
            while not self.stop.is_set():
                try:
                    frame = eye.read()
                except Exception as exc:  # anything: the eye is down, never the thread
                    with h.lock:
                        health.state = EyeState.DOWN
                        health.last_error = str(exc) or type(exc).__name__
                    lost = isinstance(exc, DeviceLost)
                    h.error(f"{name}_{'lost' if lost else 'failed'}")
                    h.problem(f"{name} eye down: {health.last_error}; retrying", f"{name}_down")
                    if not lost:  # a lost device is reopened by its source
                        log.debug("%s eye: unexpected failure", name, exc_info=True)
                        self._recover(eye)
                    if lost and not failing:  # at once: its source reopens it with a backoff
                        failing = True
                        continue
                    failing = True
                    if self.stop.wait(pause):
                        break
                    pause = min(pause * 2, RETRY_MAX_S)
                    continue
                if frame is None:
                    break
                pause, failing = RETRY_FIRST_S, False
                if not self.push(frame):
                    break
        finally:
            if health.state is not EyeState.DOWN:
                health.state = EyeState.ENDED
            with h.lock:
                self._eyes_done += 1
                last = self._eyes_done == 2
            if last:
                self._end()

    def leave_behind(self) -> None:
        """Stop waiting for eyes whose read has not returned since the stop (a driver whose
        read cannot be interrupted): no pair is queued from here on, and the pipeline ends
        with what is queued. Their threads end when their reads return, or with the
        process."""
        self.pairs.close()

    def _recover(self, eye: EyeSource) -> None:
        """Ask ``eye`` to recover after a failed read; a recovery that fails too is said,
        and the eye is read again after the pause all the same."""
        try:
            eye.recover()
        except Exception as exc:
            log.debug("%s eye: recovery failed", eye.eye.value, exc_info=True)
            why = str(exc) or type(exc).__name__
            self.health.problem(
                f"{eye.eye.value} eye: recovering it failed: {why}; retrying",
                f"{eye.eye.value}_down",
            )

    def _merge_loop(self) -> None:
        t_first: int | None = None
        wall_first = 0.0
        last_ns = 0
        try:
            for frame in merged(self.source.left, self.source.right):
                if self.stop.is_set():
                    break
                if self.rate > 0:
                    if t_first is not None and frame.t_ns - last_ns > MAX_PACED_GAP_S * 1e9:
                        self.health.problem(
                            f"{frame.eye.value} eye: its frame {frame.seq} comes "
                            f"{(frame.t_ns - last_ns) * 1e-9:.3g} s after the one before; "
                            "played on at once, not after that wait",
                            "paced_gap",
                            notice=True,
                        )
                        t_first = None
                    if t_first is None:
                        t_first, wall_first = frame.t_ns, time.monotonic()
                    last_ns = max(last_ns, frame.t_ns)
                    due = wall_first + (frame.t_ns - t_first) * 1e-9 / self.rate
                    delay = due - time.monotonic()
                    if delay > 0 and self.stop.wait(delay):
                        break
                if not self.push(frame):
                    break
        except Exception as exc:  # a file that fails ends the run, with the reason
            self._on_fatal(exc)
        finally:
            for health in self.health.eyes.values():
                if health.state is not EyeState.DOWN:
                    health.state = EyeState.ENDED
            self._end()

    def _end(self) -> None:
        """End of capture: pair what is left and close the pipeline's queue."""
        with self.health.lock:
            pairs = self.pairer.flush()
        now = time.perf_counter_ns()
        for p in pairs:
            if not self.pairs.put((p, now), self.stop):
                break  # stopped: what is left goes from the end only, never from between
        self.pairs.close()
