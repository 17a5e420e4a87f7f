"""Capture: every frame through one door (size check, eye health, pairer), as the eye
threads deliver them."""

from __future__ import annotations

import threading

import numpy as np

from stereod.bus.messages import EyeState
from stereod.daemon.capture import Capture
from stereod.daemon.status import Health
from stereod.sources.frames import Eye, EyeSource, Frame, SourceInfo, StereoPair, StereoSource
from stereod.sources.pairing import Pairer
from stereod.sources.queues import BoundedQueue

MS = 1_000_000
IMG = np.zeros((4, 6), np.uint8)


class _Idle(EyeSource):
    def __init__(self, eye: Eye) -> None:
        self.eye = eye

    def read(self) -> Frame | None:
        return None


def capture() -> tuple[Capture, Health, BoundedQueue]:
    info = SourceInfo(6, 4, 30.0, True, "frames pushed by the test")
    source = StereoSource(_Idle(Eye.LEFT), _Idle(Eye.RIGHT), info)
    pairer = Pairer()
    health = Health("bench", "test", pairer, on_change=lambda: None)
    health.live = True
    pairs: BoundedQueue = BoundedQueue(1000, drop_oldest=True)
    cap = Capture(
        source,
        pairer,
        pairs,
        health,
        threading.Event(),
        rate=0.0,
        on_ready=lambda: None,
        on_fatal=lambda exc: None,
    )
    return cap, health, pairs


def test_a_frame_stamped_days_ahead_is_said_once_and_pairing_goes_on() -> None:
    cap, health, _ = capture()
    period = 33 * MS
    for k in range(60):
        t = k * period
        left_t = t + 10**15 if k == 20 else t  # 11.6 days ahead: a driver's glitch
        assert cap.push(Frame(Eye.LEFT, IMG, left_t, k))
        assert cap.push(Frame(Eye.RIGHT, IMG, t + 2 * MS, k))
    assert 60 - 5 <= cap.pairer.stats.pairs < 60
    jumps = [p for p in health.problems() if "went back in time" in p]
    assert len(jumps) == 1 and jumps[0].startswith("left eye:"), health.problems()
    assert health.counters()[0]["clock_jump"] == 1


def test_a_frame_of_another_size_is_skipped_and_said() -> None:
    cap, health, _ = capture()
    assert cap.push(Frame(Eye.LEFT, np.zeros((8, 6), np.uint8), 0, 0))
    assert health.eyes[Eye.LEFT].errors == 1 and cap.pairer.stats.frames[Eye.LEFT] == 0
    assert "frame 0 is 6x8, stream is 6x4; skipped" in health.problems()[-1]


def test_the_first_frame_after_an_eye_was_down_counts_a_reconnect() -> None:
    cap, health, _ = capture()
    health.eyes[Eye.RIGHT].state = EyeState.DOWN
    assert cap.push(Frame(Eye.RIGHT, IMG, 0, 0))
    assert health.eyes[Eye.RIGHT].state is EyeState.STREAMING
    assert health.counters()[2] == {"right": 1}
    assert health.problems()[-1] == "right eye streaming again"


class _Failing(EyeSource):
    """An eye whose every read fails with ``exc`` (a camera that opens and then fails each
    read, say), and whose recovery fails too when ``recover_fails``."""

    def __init__(self, eye: Eye, exc: Exception, recover_fails: bool = False) -> None:
        self.eye, self.exc, self.recover_fails = eye, exc, recover_fails
        self.reads = self.recovered = 0

    def read(self) -> Frame | None:
        self.reads += 1
        raise self.exc

    def recover(self) -> None:
        self.recovered += 1
        if self.recover_fails:
            raise OSError("the device node is gone")


def run_eye_for(cap: Capture, eye: EyeSource, seconds: float) -> None:
    t = threading.Thread(target=cap._eye_loop, args=(eye,))
    t.start()
    cap.stop.wait(seconds)
    cap.stop.set()
    t.join(10)
    assert not t.is_alive()


def test_a_camera_lost_on_every_read_is_retried_with_a_backoff() -> None:
    """A lost camera is retried at once (its source reopens it with a backoff of its own),
    but one lost again before any frame waits 0.1, 0.2, 0.4 s...: it was retried thousands
    of times a second, each retry a problem and a status message."""
    from stereod.errors import DeviceLost

    cap, health, _ = capture()
    eye = _Failing(Eye.LEFT, DeviceLost("/dev/video0: read failed: EIO"))
    run_eye_for(cap, eye, 1.0)
    assert 4 <= eye.reads <= 6, eye.reads  # at 0, 0, 0.1, 0.3, 0.7 s (and 1.5 s)
    assert health.counters()[1]["left_lost"] == eye.reads
    assert health.eyes[Eye.LEFT].state is EyeState.DOWN


def test_an_eye_whose_recovery_fails_too_is_retried_and_said() -> None:
    """A recovery that raises is said on the status and retried after the pause: it used to
    end the eye's thread, and with it the daemon."""
    cap, health, _ = capture()
    eye = _Failing(Eye.RIGHT, ValueError("short buffer"), recover_fails=True)
    run_eye_for(cap, eye, 0.5)
    assert eye.reads >= 2 and eye.recovered == eye.reads
    assert any(
        p == "right eye: recovering it failed: the device node is gone; retrying"
        for p in health.problems()
    ), health.problems()


def test_pairs_are_queued_in_the_order_they_were_decided(monkeypatch) -> None:
    """Pairs were decided under one lock and queued after it, so an eye's thread that lost
    the CPU in between let the other eye's later pair overtake its own (the pipeline then
    refused the older pair). Here the left eye's thread stops right after deciding pair 0,
    until the right eye's thread has pushed the frame that decides pair 1 (or 0.5 s)."""
    import stereod.daemon.capture as capture_module

    cap, _, pairs = capture()
    cap.push(Frame(Eye.LEFT, IMG, 0, 0))
    cap.push(Frame(Eye.RIGHT, IMG, 5 * MS, 0))
    decided, pushed = threading.Event(), threading.Event()
    real = capture_module.time

    class Slow:
        def __getattr__(self, name: str) -> object:
            return getattr(real, name)

        def perf_counter_ns(self) -> int:
            if threading.current_thread().name == "left" and not decided.is_set():
                decided.set()  # pair 0 is decided, not yet queued
                pushed.wait(0.5)
            return real.perf_counter_ns()

    monkeypatch.setattr(capture_module, "time", Slow())

    def right() -> None:
        decided.wait(5)
        cap.push(Frame(Eye.RIGHT, IMG, 38 * MS, 1))  # decides pair 1
        pushed.set()

    threads = [
        threading.Thread(target=cap.push, args=(Frame(Eye.LEFT, IMG, 33 * MS, 1),), name="left"),
        threading.Thread(target=right, name="right"),
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    queued = []
    while (item := pairs.get(0)) is not None:
        queued.append(item[0])
    assert [p.left.seq for p in queued if isinstance(p, StereoPair)] == [0, 1]
