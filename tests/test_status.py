"""The daemon's health: a live eye that stops delivering is reported."""

from __future__ import annotations

import re
import time

import numpy as np

from stereod.bus.messages import DaemonState, EyeState
from stereod.daemon.status import STALL_S, Health
from stereod.sources.frames import Eye
from stereod.sources.pairing import Pairer


def live_health() -> Health:
    h = Health("bench", "test", Pairer(), on_change=lambda: None)
    h.live = True
    h.state = DaemonState.RUNNING
    now = time.monotonic()
    for e in h.eyes.values():
        e.state = EyeState.STREAMING
        e.frames = 30
        e.last_frame_s = now
    h.last_frame_s = now
    return h


def test_eyes_streaming_are_healthy() -> None:
    h = live_health()
    st = h.status()
    assert st.state is DaemonState.RUNNING and st.problems == []
    assert h.frames_flowing(1.0)


def test_an_eye_quiet_for_the_stall_time_is_down_and_the_daemon_degraded() -> None:
    h = live_health()
    h.eyes[Eye.RIGHT].last_frame_s -= STALL_S + 0.5
    st = h.status()
    assert st.state is DaemonState.DEGRADED
    assert st.left.state is EyeState.STREAMING and st.right.state is EyeState.DOWN
    assert st.right.last_error is not None
    assert re.fullmatch(r"no frame for 3\.[5-9] s", st.right.last_error), st.right.last_error
    assert st.errors == {"right_stalled": 1}
    assert st.problems == [f"right eye down: {st.right.last_error}; waiting for it"]
    h.status()  # said once, not every second
    assert h.status().errors == {"right_stalled": 1}


def test_a_file_source_is_never_stalled() -> None:
    """A replay paces itself (and may be paused by its reader): no eye is judged by time."""
    h = live_health()
    h.live = False
    for e in h.eyes.values():
        e.last_frame_s -= 100.0
    st = h.status()
    assert st.right.state is EyeState.STREAMING and st.errors == {}


def test_a_notice_is_said_but_is_no_failing_problem() -> None:
    h = live_health()
    h.problem("reload: changes to zenoh take effect at the next restart", notice=True)
    h.problem("left eye: frame 7 is 32x24, stream is 64x48; skipped", "bad_size")
    assert len(h.problems()) == 2
    assert h.failing() == ["left eye: frame 7 is 32x24, stream is 64x48; skipped"]
    assert h.status().problems == h.problems()


def test_rates_are_measured_over_half_a_second_at_least() -> None:
    """An eye that delivered 30 frames and a pipeline that did 30 pairs in the first second
    report 30 a second; a status asked for 4 ms later (a new subscriber's, or a run's last)
    repeats that, not 0 over 4 ms; the next second's 15 reads 15."""
    h = live_health()
    t0 = h.started_s
    for _ in range(30):
        h.pair_done(1.0, 0.0, np.zeros(0))
    first = h.status(t0 + 1.0)
    assert (first.left.fps, first.right.fps, first.pairs_per_s) == (30.0, 30.0, 30.0)
    soon = h.status(t0 + 1.004)
    assert (soon.left.fps, soon.pairs_per_s) == (30.0, 30.0)
    for e in h.eyes.values():
        e.frames += 15
    for _ in range(15):
        h.pair_done(1.0, 0.0, np.zeros(0))
    later = h.status(t0 + 2.0)
    assert (later.left.fps, later.pairs_per_s) == (15.0, 15.0)


def test_a_run_shorter_than_a_rate_window_is_measured_over_what_there_was() -> None:
    """A run of 0.3 s that processed 9 pairs ends with 30 a second on its last status, not 0
    (no window of half a second ever closed)."""
    h = live_health()
    t0 = h.started_s
    assert h.status(t0 + 0.01).pairs_per_s == 0.0  # (the status at start)
    for _ in range(9):
        h.pair_done(1.0, 0.0, np.zeros(0))
    assert h.status(t0 + 0.3, final=True).pairs_per_s == 30.0
