"""The daemon in-process: status, queryables, liveliness, live sources, bad frames, drops."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import re
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from stereod.daemon.config import load_config
from stereod.daemon.daemon import Daemon
from stereod.sources.frames import Driver, Eye, EyeSource, Frame, SourceInfo, StereoSource
from stereod_fakes.synth import SyntheticDriver
from stereod_fakes.v4l2_kernel import FakeCamera, FakeKernel
from stereod_v4l2_minoru.driver import MinoruDriver


def config(endpoint: str, **daemon: Any):
    return load_config(overrides={"zenoh": {"connect": [endpoint]}, "daemon": daemon})


def live_synthetic(fps: int) -> dict[str, Any]:
    """Options of a small synthetic camera playing a 2 s scene live, over and over."""
    return {
        "live": True,
        "loop": True,
        "fps": fps,
        "duration_s": 2.0,
        "width_px": 160,
        "height_px": 120,
    }


def start(daemon: Daemon) -> tuple[threading.Thread, dict]:
    out: dict = {}
    t = threading.Thread(target=lambda: out.setdefault("summary", daemon.run()))
    t.start()
    return t, out


def wait_alive(session: zenoh.Session, key: str, timeout: float = 10) -> None:
    seen = threading.Event()
    sub = session.liveliness().declare_subscriber(
        key, lambda s: seen.set() if s.kind == zenoh.SampleKind.PUT else None, history=True
    )
    assert seen.wait(timeout), f"liveliness token {key} never appeared"
    sub.undeclare()


def query(session: zenoh.Session, key: str) -> dict:
    replies = list(session.get(key, timeout=5))
    assert replies, f"no reply on {key}"
    return json.loads(replies[0].ok.payload.to_bytes())


def test_queryables_liveliness_and_status_on_new_subscriber(
    endpoint: str, listener: zenoh.Session
) -> None:
    cfg = config(endpoint, status_period_s=30.0)
    daemon = Daemon(cfg, SyntheticDriver({"duration_s": 20.0, "fps": 15}), rate=1.0)
    thread, _ = start(daemon)
    try:
        wait_alive(listener, "stereod/minoru/alive")
        assert query(listener, "stereod/minoru/config")["rig"]["name"] == "minoru"
        cal = query(listener, "stereod/minoru/calibration")
        assert cal["geometry"] == "canonical" and cal["baseline_m"] == 0.06
        deadline = time.monotonic() + 10
        stats = query(listener, "stereod/minoru/stats")
        while stats["pairs"] < 5 and time.monotonic() < deadline:
            time.sleep(0.2)
            stats = query(listener, "stereod/minoru/stats")
        assert stats["schema"] == "stereod.stats/1"
        assert stats["pairs"] >= 5 and min(stats["frames"].values()) >= stats["pairs"]
        assert 0 < stats["pipeline_ms_p50"] <= stats["pipeline_ms_p99"] < 1000
        assert stats["publish_errors"] == 0 and stats["queue_depth"] >= 0
        # The status period is 30 s and the run 20 s: a status arriving at once, running,
        # comes from the new-subscriber path (not the period, nor the end of the run).
        got = threading.Event()
        states: list[str] = []

        def on_status(sample: zenoh.Sample) -> None:
            states.append(json.loads(sample.payload.to_bytes())["state"])
            got.set()

        sub = listener.declare_subscriber("stereod/minoru/status", on_status)
        t0 = time.monotonic()
        assert got.wait(5), "no status re-sent for a new subscriber"
        assert time.monotonic() - t0 < 5
        assert states[0] == "running"
        sub.undeclare()
    finally:
        daemon.stop()
        thread.join(15)
    assert not thread.is_alive()
    # The token is withdrawn when the daemon stops.
    left = list(listener.liveliness().get("stereod/minoru/alive", timeout=1))
    assert left == []


def test_a_second_daemon_under_the_same_rig_name_says_so(
    endpoint: str, listener: zenoh.Session
) -> None:
    """Two daemons publishing one rig's keys on one bus mix their messages; the one that comes
    second finds the first's liveliness token and says so on its status, and the first, to
    which Zenoh merges the two tokens on one key, says so once the second's status comes on
    its rig's status key (it never learned of it)."""
    first = Daemon(config(endpoint), SyntheticDriver({"duration_s": 3.0, "fps": 15}), rate=1.0)
    thread, _ = start(first)
    try:
        wait_alive(listener, "stereod/minoru/alive")
        second = Daemon(config(endpoint), SyntheticDriver({"duration_s": 0.5, "fps": 15}))
        summary = second.run()
        deadline = time.monotonic() + 10  # the first's next status period or two
        while time.monotonic() < deadline and not first.health.problems():
            time.sleep(0.05)
    finally:
        first.stop()
        thread.join(15)
    assert summary.error is None
    assert any("another stereod already publishes rig 'minoru'" in p for p in summary.problems)
    (said,) = [p for p in first.health.problems() if "another stereod" in p]
    assert said.startswith("another stereod publishes rig 'minoru' under stereod/minoru/ too")


def test_live_source_runs_one_thread_per_eye(endpoint: str, listener: zenoh.Session) -> None:
    msgs: list[dict] = []
    sub = listener.declare_subscriber(
        "stereod/minoru/objects", lambda s: msgs.append(json.loads(s.payload.to_bytes()))
    )
    driver = SyntheticDriver({"duration_s": 2.0, "fps": 15, "skew_s": 0.01, "live": True})
    daemon = Daemon(config(endpoint), driver)
    summary = daemon.run()
    time.sleep(0.3)
    sub.undeclare()
    assert summary.error is None and summary.pairs == 30
    assert msgs and all(abs(m["skew_ns"] - 10_000_000) < 1_000_000 for m in msgs)
    # The left frame waits 10 ms for its partner: the idle pipeline detects it meanwhile (how
    # often depends on what else the host runs, so only that it happens is asserted).
    assert daemon._worker is not None and daemon._worker.pipeline.detected_ahead >= 1
    # Live times are on this host's monotonic clock; UTC stamps are near now.
    assert abs(msgs[-1]["stamp_utc_ns"] - time.time_ns()) < 5e9


class _ListEye(EyeSource):
    """Frames from a list; an entry that is an exception is raised by that read instead."""

    def __init__(self, eye: Eye, frames: list[Frame | Exception]) -> None:
        self.eye = eye
        self._frames = list(frames)
        self.recovered = 0

    def read(self) -> Frame | None:
        if not self._frames:
            return None
        item = self._frames.pop(0)
        if isinstance(item, Exception):
            raise item
        return item

    def recover(self) -> None:
        self.recovered += 1


class ListDriver(Driver):
    """A driver over frames held in memory: the daemon's own seam, for fault injection."""

    name = "list"

    def __init__(
        self, left: list[Frame | Exception], right: list[Frame | Exception], live: bool = False
    ) -> None:
        self.args = (left, right, live)
        self.source: StereoSource | None = None

    def open(self) -> StereoSource:
        left, right, live = self.args
        first = next(f for f in left if isinstance(f, Frame))
        h, w = first.image.shape[:2]
        info = SourceInfo(w, h, 10.0, live, "frames in a list")
        self.source = StereoSource(_ListEye(Eye.LEFT, left), _ListEye(Eye.RIGHT, right), info)
        return self.source


def frames(
    eye: Eye, n: int, size: tuple[int, int] = (48, 64), period_ns: int = 10**8
) -> list[Frame]:
    img = np.full(size, 100, np.uint8)
    return [Frame(eye, img, 10**9 + k * period_ns, k) for k in range(n)]


def test_wrong_size_frame_mid_stream_is_skipped_and_reported(
    endpoint: str, listener: zenoh.Session
) -> None:
    statuses: list[dict] = []
    sub = listener.declare_subscriber(
        "stereod/minoru/status", lambda s: statuses.append(json.loads(s.payload.to_bytes()))
    )
    left, right = frames(Eye.LEFT, 20), frames(Eye.RIGHT, 20)
    left[7] = Frame(Eye.LEFT, np.zeros((24, 32), np.uint8), left[7].t_ns, 7)
    daemon = Daemon(config(endpoint), ListDriver(left, right), rate=0, wait_subscriber_s=0)
    summary = daemon.run()
    time.sleep(0.3)
    sub.undeclare()
    assert summary.error is None
    assert summary.pairs == 19
    assert any(
        "left eye: frame 7 is 32x24, stream is 64x48; skipped" in p for p in summary.problems
    )
    final = statuses[-1]
    assert final["state"] == "finished" and final["left"]["errors"] == 1
    assert "frame 7 is 32x24" in final["problems"][-1]


def test_a_failed_run_says_failed_on_its_last_status(
    endpoint: str, listener: zenoh.Session
) -> None:
    """A run that ends with an error says ``failed``, not ``finished``, on its last status,
    with the error as its last problem."""
    statuses: list[dict] = []
    sub = listener.declare_subscriber(
        "stereod/minoru/status", lambda s: statuses.append(json.loads(s.payload.to_bytes()))
    )
    left: list[Frame | Exception] = list(frames(Eye.LEFT, 20))
    left.insert(8, RuntimeError("the decoder crashed"))
    daemon = Daemon(config(endpoint), ListDriver(left, frames(Eye.RIGHT, 20)), rate=0)
    summary = daemon.run()
    time.sleep(0.3)
    sub.undeclare()
    assert summary.error is not None
    assert statuses[-1]["state"] == "failed", statuses[-1]
    assert "the decoder crashed" in statuses[-1]["problems"][-1]


def test_pipeline_behind_drops_oldest_and_counts(endpoint: str) -> None:
    """A live source faster than the pipeline: memory stays bounded, drops are counted."""
    n = 400
    # 640x480 frames 0.2 ms apart (5000 a second), delivered as fast as memory allows: far
    # beyond the pipeline.
    left = frames(Eye.LEFT, n, (480, 640), period_ns=200_000)
    right = frames(Eye.RIGHT, n, (480, 640), period_ns=200_000)
    cfg = config(endpoint, queue_size=2)
    summary = Daemon(cfg, ListDriver(left, right, live=True), rate=0).run()
    assert summary.error is None
    dropped = summary.drops.get("pipeline_behind", 0)
    assert dropped > 0
    assert summary.published + dropped == summary.pairs


@pytest.mark.parametrize("rate", [0.0, 4.0])
def test_rate_paces_replay(rate: float, endpoint: str) -> None:
    driver = SyntheticDriver({"duration_s": 1.0, "fps": 15})
    t0 = time.monotonic()
    summary = Daemon(config(endpoint), driver, rate=rate).run()
    elapsed = time.monotonic() - t0
    assert summary.pairs == 15
    if rate:
        assert elapsed >= 14 / 15 / rate, f"{elapsed:.2f} s is faster than {rate}x real time"


def test_any_exception_in_an_eye_marks_it_down_and_it_recovers(endpoint: str) -> None:
    """A live eye whose read raises something unexpected (a ValueError from a short buffer,
    say) is not a dead thread: the eye is reported down, counted, recovered as after a
    re-plug, and streams on; the run ends cleanly."""
    left: list[Frame | Exception] = list(frames(Eye.LEFT, 30, period_ns=10**7))
    left.insert(10, ValueError("buffer is smaller than requested size"))
    right: list[Frame | Exception] = list(frames(Eye.RIGHT, 30, period_ns=10**7))
    driver = ListDriver(left, right, live=True)
    daemon = Daemon(config(endpoint), driver, rate=0)
    summary = daemon.run()
    assert summary.error is None
    assert summary.errors.get("left_failed") == 1, summary.errors
    assert daemon.health.stats().reconnects == {"left": 1}
    assert any("left eye down: buffer is smaller" in p for p in summary.problems)
    assert any("left eye streaming again" in p for p in summary.problems)
    assert summary.frames["left"] == 30 and summary.pairs >= 10
    assert driver.source is not None and driver.source.left.recovered == 1  # type: ignore[attr-defined]


def test_a_daemon_whose_jsonl_reader_goes_away_runs_on_and_says_so(
    endpoint: str, tmp_path: Path
) -> None:
    """``run --jsonl FIFO``: when the pipe's reader closes it after a line, the daemon stops
    writing the JSONL, says so on its status, and processes every pair to the end."""
    fifo = tmp_path / "objects.fifo"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # a reader before the writer opens
    driver = SyntheticDriver({"duration_s": 2.0, "fps": 15})
    daemon = Daemon(config(endpoint), driver, rate=1.0, jsonl=fifo)
    thread, out = start(daemon)
    got = b""
    deadline = time.monotonic() + 20
    while b"\n" not in got and time.monotonic() < deadline:
        with contextlib.suppress(BlockingIOError):
            got += os.read(reader, 65536)
        time.sleep(0.01)
    os.close(reader)
    thread.join(60)
    summary = out["summary"]
    assert json.loads(got.split(b"\n")[0])["seq"] == 0
    assert summary.error is None and summary.pairs == 30 and summary.published == 30
    gone = [p for p in summary.problems if "its reader closed it" in p]
    assert gone == [f"{fifo}: its reader closed it; the JSONL output is no longer written"]


def test_a_live_daemon_whose_jsonl_reader_stops_reading_publishes_on_and_says_so(
    endpoint: str, tmp_path: Path
) -> None:
    """``run --jsonl FIFO`` on a camera: a reader that keeps the pipe open but stops reading
    would hold the output thread, and every Zenoh message behind it. After
    ``JSONL_STALL_S`` the JSONL counts as gone, the status says so, and publishing goes on."""
    import fcntl

    from stereod.daemon.daemon import JSONL_STALL_S

    fifo = tmp_path / "objects.fifo"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # open, and never read
    fcntl.fcntl(reader, 1031, 4096)  # F_SETPIPE_SZ: a page, full after a few messages
    options = live_synthetic(30)
    daemon = Daemon(config(endpoint), SyntheticDriver(options), jsonl=fifo)
    thread, out = start(daemon)
    said = f"{fifo}: its reader took nothing for {JSONL_STALL_S:g} s"
    try:
        deadline = time.monotonic() + 30
        while not any(said in p for p in daemon.health.problems()):
            assert time.monotonic() < deadline and thread.is_alive(), daemon.health.problems()
            time.sleep(0.1)
        assert daemon._publisher is not None
        before = daemon._publisher.published
        time.sleep(1.0)
        assert daemon._publisher.published >= before + 15  # 30 pairs a second flow on
    finally:
        daemon.stop()
        thread.join(30)
        os.close(reader)
    summary = out["summary"]
    assert summary.error is None
    assert f"{said}; the JSONL output is no longer written" in summary.problems


def test_a_slow_jsonl_reader_gets_what_it_can_take_and_holds_back_no_message(
    endpoint: str, tmp_path: Path
) -> None:
    """A reader that takes a page of the pipe every half second (it never stops, so it is
    never given up): the JSONL was written on the Zenoh thread, which then published at the
    reader's pace (7 of 300 messages in 10 s). A live daemon's JSONL is now written from a
    queue of its own that drops its oldest line, counted as ``jsonl_behind``."""
    import fcntl

    fifo = tmp_path / "objects.fifo"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    fcntl.fcntl(reader, 1031, 4096)  # F_SETPIPE_SZ: one page
    options = live_synthetic(30)
    daemon = Daemon(config(endpoint), SyntheticDriver(options), jsonl=fifo)
    thread, out = start(daemon)
    got = b""
    try:
        deadline = time.monotonic() + 20
        while daemon._publisher is None or daemon._publisher.published < 10:
            assert time.monotonic() < deadline and thread.is_alive()
            time.sleep(0.05)
        before, t0 = daemon._publisher.published, time.monotonic()
        while time.monotonic() - t0 < 3.0:
            with contextlib.suppress(BlockingIOError):
                got += os.read(reader, 4096)
            time.sleep(0.5)
        published = daemon._publisher.published - before
        assert published >= 60, published  # 90 pairs in 3 s at 30 Hz, beside a slow reader
        assert daemon.health.counters()[0].get("jsonl_behind", 0) > 0
    finally:
        daemon.stop()
        with contextlib.suppress(BlockingIOError):
            while chunk := os.read(reader, 65536):
                got += chunk
        thread.join(30)
        os.close(reader)
    assert out["summary"].error is None
    lines = got.split(b"\n")
    seqs = [json.loads(line)["seq"] for line in lines[:-1]]
    assert seqs == sorted(seqs) and len(seqs) >= 3  # whole messages, in order, gaps allowed


def test_a_hung_pipeline_stops_feeding_the_watchdog_and_says_so(
    endpoint: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Frames flowing is not enough to feed systemd's watchdog: a pipeline thread stuck on
    one pair (a driver or library call that never returns) stops the pings, so systemd
    restarts the daemon, and the status key says which thread is stuck."""
    import stereod.daemon.daemon as daemon_module
    from stereod.daemon.sdnotify import Notifier

    from .processes import collect, receiver

    monkeypatch.setattr(daemon_module, "STUCK_S", 0.5)
    sock, address = receiver(tmp_path)
    notifier = Notifier({"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "400000"})
    options = live_synthetic(30)
    daemon = Daemon(config(endpoint), SyntheticDriver(options), notifier=notifier)
    release = threading.Event()
    thread, out = start(daemon)
    try:
        assert "WATCHDOG=1" in collect(sock, "WATCHDOG=1", 20)
        assert daemon._worker is not None
        pipeline = daemon._worker.pipeline
        monkeypatch.setattr(pipeline, "process", lambda pair: release.wait(30))
        deadline = time.monotonic() + 10
        while not any("pipeline thread: stuck" in p for p in daemon.health.problems()):
            assert time.monotonic() < deadline, daemon.health.problems()
            time.sleep(0.05)
        collect(sock, "no such line", 0.3)  # what was sent before it was seen stuck
        later = collect(sock, "WATCHDOG=1", 1.5)
        assert "WATCHDOG=1" not in later, later
        assert daemon.health.frames_flowing(1.0)  # frames flow all the while
    finally:
        release.set()
        daemon.stop()
        thread.join(30)
        notifier.close()
        sock.close()
    assert out["summary"].error is None


def test_a_stopped_file_run_writes_every_pair_it_processed_in_order(
    endpoint: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SIGTERM on ``run`` over a file: the pairs already processed still go out. With the
    output slower than the pipeline they were thrown away once the stop came, between pairs
    that went out, and the JSONL was kept with holes and nothing counted."""
    import random

    from stereod.pipeline import Pipeline

    real, rnd = Pipeline.process, random.Random(1)

    def process(self: Pipeline, pair: Any) -> Any:
        time.sleep(rnd.uniform(0.0, 0.04))
        return real(self, pair)

    monkeypatch.setattr(Pipeline, "process", process)
    jsonl = tmp_path / "objects.jsonl"
    options = {"fps": 15, "duration_s": 60.0, "width_px": 160, "height_px": 120}
    daemon = Daemon(
        config(endpoint, publish_queue_size=1, queue_size=20),
        SyntheticDriver(options),
        rate=0,
        jsonl=jsonl,
        on_message=lambda item: time.sleep(0.03),
    )
    thread, out = start(daemon)
    time.sleep(1.5)
    daemon.stop()
    thread.join(60)
    summary = out["summary"]
    seqs = [json.loads(line)["seq"] for line in jsonl.read_text().splitlines()]
    assert summary.error is None and len(seqs) > 10
    assert seqs == list(range(len(seqs)))
    assert summary.published == len(seqs)


def test_a_reloaded_pipeline_that_cannot_be_made_leaves_the_running_one(
    endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Making the new pipeline of a valid reload failed on the pipeline thread (out of
    memory, say) and ended the daemon with exit 70. The running pipeline and configuration
    now stay, and the status key says why."""
    from stereod.daemon.reload import RELOAD_REFUSED
    from stereod.pipeline import Pipeline

    options = live_synthetic(30)
    cfg = config(endpoint)
    new = cfg.model_copy(update={"detector": cfg.detector.model_copy(update={"threshold": 31})})
    daemon = Daemon(cfg, SyntheticDriver(options), reload_config=lambda: new)

    def no_memory(self: Pipeline, params: Any) -> Any:
        raise MemoryError("no room for the new pipeline")

    monkeypatch.setattr(Pipeline, "reconfigured", no_memory)
    thread, out = start(daemon)
    try:
        deadline = time.monotonic() + 20
        while daemon.health.stats().pairs < 5:
            assert time.monotonic() < deadline and thread.is_alive()
            time.sleep(0.05)
        daemon.reload()
        said = f"{RELOAD_REFUSED}: MemoryError: no room for the new pipeline"
        while said not in daemon.health.problems():
            assert time.monotonic() < deadline and thread.is_alive(), daemon.health.problems()
            time.sleep(0.05)
        pairs = daemon.health.stats().pairs
        time.sleep(0.5)
        assert daemon.health.stats().pairs > pairs  # it runs on
        assert daemon.cfg.detector.threshold == cfg.detector.threshold
    finally:
        daemon.stop()
        thread.join(30)
    assert out["summary"].error is None


def test_a_reload_replaced_before_use_and_one_refused_leave_the_running_one_everywhere(
    endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two reloads handed over before the pipeline thread took either (50 deg, then 42 deg,
    whose pipeline cannot be made): the first is dropped and the second refused, and the
    configuration, the calibration queryable and ROS 2 all keep the running 60 deg. They
    took each reload as it was handed over, and could name one that never ran."""
    import math

    from stereod.daemon.reload import RELOAD_REFUSED
    from stereod.daemon.replies import calibration_reply
    from stereod.pipeline import Pipeline

    def cfg(hfov: float) -> Any:
        overrides = {"zenoh": {"connect": [endpoint]}, "rig": {"hfov_deg": hfov}}
        return load_config(overrides={**overrides, "ros2": {"enabled": True}})

    hfov = {"now": 60.0}
    options = live_synthetic(15)
    daemon = Daemon(cfg(60.0), SyntheticDriver(options), reload_config=lambda: cfg(hfov["now"]))
    real = Pipeline.reconfigured

    def reconfigured(self: Pipeline, params: Any) -> Any:
        if params.rig.hfov_deg == 42.0:
            raise MemoryError("no room")
        return real(self, params)

    monkeypatch.setattr(Pipeline, "reconfigured", reconfigured)
    release = threading.Event()
    thread, out = start(daemon)
    try:
        deadline = time.monotonic() + 20
        while daemon.ros2 is None or daemon.health.stats().pairs < 3:
            assert time.monotonic() < deadline and thread.is_alive()
            time.sleep(0.05)
        worker = daemon._worker
        assert worker is not None
        monkeypatch.setattr(worker, "_swap", lambda: release.wait(30))  # hold the hand-over
        for h in (50.0, 42.0):
            hfov["now"] = h
            daemon.reload()
            while worker._pending is None or worker._pending[0].rig.hfov_deg != h:
                assert time.monotonic() < deadline, daemon.health.problems()
                time.sleep(0.02)
        monkeypatch.undo()  # the real swap (and reconfigured) again, then let it run
        monkeypatch.setattr(Pipeline, "reconfigured", reconfigured)
        release.set()
        while f"{RELOAD_REFUSED}: MemoryError: no room" not in daemon.health.problems():
            assert time.monotonic() < deadline, daemon.health.problems()
            time.sleep(0.02)
        assert daemon.cfg.rig.hfov_deg == 60.0
        assert json.loads(calibration_reply(worker.rig))["hfov_deg"] == 60.0
        want = 80 / math.tan(math.radians(30.0))
        assert daemon.ros2 is not None
        assert daemon.ros2.ros.calibration.array("P1")[0, 0] == pytest.approx(want)
    finally:
        release.set()
        daemon.stop()
        thread.join(30)
    assert out["summary"].error is None


def test_a_refusal_said_while_a_later_reload_waited_goes_once_that_one_runs(
    endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A reload (42 deg) whose pipeline cannot be made, refused only after a second SIGHUP
    (50 deg) had been handed over: the refusal stayed on the status key after the second
    one ran, naming a reload that no longer mattered."""
    from stereod.daemon.reload import RELOAD_REFUSED
    from stereod.pipeline import Pipeline

    def cfg(hfov: float) -> Any:
        return load_config(overrides={"zenoh": {"connect": [endpoint]}, "rig": {"hfov_deg": hfov}})

    hfov = {"now": 60.0}
    daemon = Daemon(
        cfg(60.0), SyntheticDriver(live_synthetic(15)), reload_config=lambda: cfg(hfov["now"])
    )
    real = Pipeline.reconfigured
    making, release = threading.Event(), threading.Event()

    def reconfigured(self: Pipeline, params: Any) -> Any:
        if params.rig.hfov_deg == 42.0:
            making.set()
            release.wait(30)
            raise MemoryError("no room")
        return real(self, params)

    monkeypatch.setattr(Pipeline, "reconfigured", reconfigured)
    thread, out = start(daemon)
    try:
        deadline = time.monotonic() + 20
        while daemon.health.stats().pairs < 3:
            assert time.monotonic() < deadline and thread.is_alive()
            time.sleep(0.05)
        hfov["now"] = 42.0
        daemon.reload()
        assert making.wait(20)  # the pipeline thread is making the 42 deg pipeline
        hfov["now"] = 50.0
        daemon.reload()
        worker = daemon._worker
        assert worker is not None
        while worker._pending is None or worker._pending[0].rig.hfov_deg != 50.0:
            assert time.monotonic() < deadline, daemon.health.problems()
            time.sleep(0.02)
        release.set()
        while daemon.cfg.rig.hfov_deg != 50.0:
            assert time.monotonic() < deadline, daemon.health.problems()
            time.sleep(0.02)
        assert not daemon.health.showing(RELOAD_REFUSED), daemon.health.problems()
    finally:
        release.set()
        daemon.stop()
        thread.join(30)
    assert out["summary"].error is None


def test_a_reload_of_the_geometry_reaches_the_ros2_node(endpoint: str) -> None:
    """A SIGHUP with a new field of view (or calibration) reached the pipeline and the
    calibration queryable but not ROS 2, whose camera_info kept the start-up focal length
    (138.6 px for 208.4): positions of one geometry beside the intrinsics of another."""
    import math

    def cfg(hfov: float) -> Any:
        overrides = {"zenoh": {"connect": [endpoint]}, "rig": {"hfov_deg": hfov}}
        return load_config(overrides={**overrides, "ros2": {"enabled": True}})

    hfov = {"now": 60.0}
    options = live_synthetic(15)
    daemon = Daemon(cfg(60.0), SyntheticDriver(options), reload_config=lambda: cfg(hfov["now"]))
    thread, out = start(daemon)
    try:
        deadline = time.monotonic() + 20
        while daemon.ros2 is None or daemon.health.stats().pairs < 3:
            assert time.monotonic() < deadline and thread.is_alive()
            time.sleep(0.05)
        hfov["now"] = 42.0
        daemon.reload()
        want = 80 / math.tan(math.radians(21.0))  # f = (w / 2) / tan(hfov / 2), px
        while abs(daemon.ros2.ros.calibration.array("P1")[0, 0] - want) > 1e-6:
            assert time.monotonic() < deadline, daemon.health.problems()
            time.sleep(0.05)
    finally:
        daemon.stop()
        thread.join(30)
    assert out["summary"].error is None


class _HangingEye(EyeSource):
    """A live eye whose reads return frames until ``hang`` is set, then never return (until
    the test releases them): a driver whose read cannot be interrupted."""

    def __init__(self, eye: Eye, hang: threading.Event, release: threading.Event) -> None:
        self.eye, self.hang, self.release, self.k = eye, hang, release, 0
        self.reading = self.closed_while_reading = False

    def read(self) -> Frame | None:
        if self.hang.is_set():
            self.reading = True
            self.release.wait(60)
            self.reading = False
            return None
        time.sleep(0.02)
        self.k += 1
        return Frame(self.eye, np.full((48, 64), 100, np.uint8), time.monotonic_ns(), self.k)

    def close(self) -> None:
        self.closed_while_reading |= self.reading


def test_a_stop_does_not_wait_for_ever_for_a_read_that_never_returns(endpoint: str) -> None:
    """The daemon waited for every eye's thread: one read that never returns (a third-party
    driver with no interrupt) kept it from ending, and its JSONL uncommitted. It now leaves
    such an eye behind ``EYES_STOP_S`` after the stop, says so, and ends."""
    hang, release = threading.Event(), threading.Event()

    eyes = (_HangingEye(Eye.LEFT, hang, release), _HangingEye(Eye.RIGHT, hang, release))

    class HangingDriver(Driver):
        name = "hanging"

        def open(self) -> StereoSource:
            return StereoSource(*eyes, SourceInfo(64, 48, 50.0, True, "hanging reads"))

    daemon = Daemon(config(endpoint), HangingDriver())
    thread, out = start(daemon)
    try:
        deadline = time.monotonic() + 20
        while daemon.health.stats().pairs < 5:
            assert time.monotonic() < deadline and thread.is_alive()
            time.sleep(0.05)
        hang.set()
        time.sleep(0.2)
        daemon.stop()
        thread.join(10)  # 1.25 s measured: 1 s for the eyes, then the drain
        assert not thread.is_alive()
        assert not any(e.closed_while_reading for e in eyes)  # that could crash a driver
    finally:
        release.set()
        thread.join(10)
    summary = out["summary"]
    assert summary.error is None
    late = [p for p in summary.problems if "reading still 1 s after the stop" in p]
    assert late and late[0].startswith("capture-"), summary.problems


def test_stats_before_run() -> None:
    """Every attribute exists from the constructor on: the stats are empty, not an error."""
    daemon = Daemon(load_config(), SyntheticDriver({"duration_s": 1.0}))
    stats = daemon.health.stats()
    assert stats.pairs == 0 and stats.drops == {} and stats.pipeline_ms_p50 is None


def _reload_configs(endpoint: str) -> Iterator[Any]:
    """Configurations that alternate a tracker setting, so each reload ends every track."""
    for k in itertools.count():
        yield load_config(
            overrides={
                "zenoh": {"connect": [endpoint]},
                "tracking": {"manoeuvre_chi2": 16.3 + (k % 2) * 0.1},
            }
        )


@pytest.mark.slow
def test_fifty_reloads_while_pairs_flow(endpoint: str, listener: zenoh.Session) -> None:
    """Reloads hand new parameters to the pipeline thread, which swaps them in between pairs:
    under 50 reloads no pair is lost, no track id is issued twice, and every track that
    ends (by a reload or at the end) gets its DELETE."""
    balls = [
        {
            "heading_deg": 90.0,
            "speed_mps": 0.3,
            "centre_m": [0.0, 0.0, 1.5],
            "t_on_s": 0.7,
            "t_off_s": 20.0,
            "t_mid_s": 10.0,
        },
        {
            "heading_deg": 270.0,
            "speed_mps": 0.2,
            "centre_m": [0.0, 0.15, 2.0],
            "t_on_s": 0.7,
            "t_off_s": 20.0,
            "t_mid_s": 10.0,
        },
    ]
    driver = SyntheticDriver(
        {"duration_s": 20.0, "fps": 15, "width_px": 160, "height_px": 120, "balls": balls}
    )
    seqs: list[int] = []
    lock = threading.Lock()

    appearances: dict[int, list[int]] = {}
    deleted: set[int] = set()

    def on_objects(s: zenoh.Sample) -> None:
        msg = json.loads(s.payload.to_bytes())
        with lock:
            seqs.append(msg["seq"])
            for o in msg["objects"]:
                appearances.setdefault(o["track_id"], []).append(msg["seq"])

    def on_track(s: zenoh.Sample) -> None:
        if s.kind == zenoh.SampleKind.DELETE:
            with lock:
                deleted.add(int(str(s.key_expr).rsplit("/", 1)[1]))

    subs = [
        listener.declare_subscriber("stereod/minoru/objects", on_objects),
        listener.declare_subscriber("stereod/minoru/objects/*", on_track),
    ]
    configs = _reload_configs(endpoint)
    daemon = Daemon(
        next(configs), driver, rate=2.0, wait_subscriber_s=5, reload_config=lambda: next(configs)
    )
    thread, out = start(daemon)
    wait_alive(listener, "stereod/minoru/alive")
    time.sleep(1.0)
    for _ in range(50):
        daemon.reload()
        time.sleep(0.1)
    thread.join(60)
    time.sleep(0.5)
    for sub in subs:
        sub.undeclare()
    summary = out["summary"]
    assert summary.error is None
    assert not any("processing failed" in p or "refused" in p for p in summary.problems)
    assert seqs == list(range(summary.pairs)), "a pair was lost or reordered"
    # An id is in every message from its first to its last (coasting included), then never
    # again: an id issued twice would come back after a gap. (Samples of different keys may
    # arrive in any order, so the DELETEs are checked as a set.)
    for tid, at in appearances.items():
        assert at == list(range(at[0], at[-1] + 1)), f"track {tid} came back after a gap"
    seen = set(appearances)
    assert seen and seen <= deleted, f"tracks without a DELETE: {seen - deleted}"
    assert len(deleted) >= 20, f"only {len(deleted)} tracks ended: did the reloads apply?"


def test_status_says_uncalibrated_depths_rest_on_the_field_of_view(endpoint: str) -> None:
    """Without a calibration the status says plainly what every depth assumes."""
    daemon = Daemon(config(endpoint), SyntheticDriver({"duration_s": 1.0, "fps": 15}), rate=0)
    daemon.run()
    notes = daemon.health.status().notes
    assert len(notes) == 1 and "60 deg" in notes[0] and "stereod calibrate" in notes[0]


def test_a_calibrated_rig_has_no_such_note() -> None:
    from stereod.daemon.status import geometry_note
    from stereod.vision.calibration import canonical
    from stereod.vision.geometry.rectified import CalibratedRig

    assert geometry_note(CalibratedRig(canonical(0.06, 60.0, 640, 480))) == ""


class _PacedKernel(FakeKernel):
    """The fake kernel delivering each frame at its camera's pace, as a real one does."""

    def __init__(self, cameras: dict[str, FakeCamera]) -> None:
        super().__init__(cameras)
        self.start = time.monotonic()

    def wait_readable(self, fd: int, timeout_s: float) -> bool:
        cam = self._cam(fd)
        if cam.stall_after is None or cam.next_seq < cam.stall_after:
            wait = self.start + cam.next_seq / cam.fps - time.monotonic()
            if wait > timeout_s:
                time.sleep(timeout_s)
                return False
            time.sleep(max(wait, 0.0))
        return super().wait_readable(fd, timeout_s)


def test_a_camera_that_stops_mid_stream_is_reported_and_reopened(endpoint: str) -> None:
    """The right eye delivers 30 frames, then nothing while it stays open: it is reported
    down (a stalled eye is no longer hidden behind the other eye's frames), reopened as after
    a re-plug, and streams again."""
    k = _PacedKernel({"/dev/fake0": FakeCamera(), "/dev/fake1": FakeCamera(stall_after=30)})
    opts = {"left": "/dev/fake0", "right": "/dev/fake1", "width": 64, "height": 48, "fps": 30}
    driver = MinoruDriver({**opts, "read_timeout_s": 0.1, "stall_s": 0.5}, io=k)
    daemon = Daemon(config(endpoint), driver, rate=0)
    t, out = start(daemon)
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and daemon.health.stats().reconnects != {"right": 1}:
            time.sleep(0.05)
    finally:
        daemon.stop()
        t.join(15)
    summary = out["summary"]
    assert daemon.health.stats().reconnects == {"right": 1}
    assert summary.errors.get("right_lost") == 1
    down = [p for p in summary.problems if p.startswith("right eye down")]
    assert len(down) == 1, summary.problems
    assert re.fullmatch(r"right eye down: /dev/fake1: no frame for \d\.\d s; retrying", down[0])
    assert "right eye streaming again" in summary.problems


def test_a_change_of_the_whole_scene_is_said_but_fails_no_replay(endpoint: str) -> None:
    """The lights go on at frame 25 of a file: the detectors find the whole image changed,
    which the status says, and they learn the scene again. That is the scene's doing, handled,
    not a fault of the input: a replay of it exits 0 (a notice, not a failing problem)."""
    from stereod.cli.common import run_daemon

    rng = np.random.default_rng(0)
    scene = rng.integers(20, 120, (48, 64), dtype=np.uint8)

    def eye(e: Eye) -> list[Frame | Exception]:
        return [Frame(e, scene + (90 if k >= 25 else 0), 10**9 + k * 10**8, k) for k in range(60)]

    daemon = Daemon(config(endpoint), ListDriver(eye(Eye.LEFT), eye(Eye.RIGHT)), rate=0)
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        assert run_daemon(daemon, quiet=True) == 0  # (it takes the signals, as a command does)
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)
    said = [p for p in daemon.health.problems() if "the whole scene changed" in p]
    assert said, daemon.health.problems()
    assert daemon.health.failing() == []


def test_a_looping_replay_says_its_damaged_frames_on_the_status_key_as_it_plays(
    endpoint: str, listener: zenoh.Session, tmp_path: Path
) -> None:
    """A looping replay may run for hours: a frame left out for its CRC-32 is said on the
    status key once the first lap is over, not only when the run ends."""
    from stereod_fakes.replay import ReplayDriver

    from .test_replay import lossless_recording, with_one_crc_changed

    rec = tmp_path / "rec"
    lossless_recording(rec)
    with_one_crc_changed(rec, 5)
    said = threading.Event()

    def on_status(sample: zenoh.Sample) -> None:
        if any("frame 5 decoded" in p for p in json.loads(sample.payload.to_bytes())["problems"]):
            said.set()

    sub = listener.declare_subscriber("stereod/minoru/status", on_status)
    daemon = Daemon(
        config(endpoint, status_period_s=0.2),
        ReplayDriver({"path": rec, "loop": True}),
        rate=1.0,
        wait_subscriber_s=0,
    )
    t, out = start(daemon)
    try:
        assert said.wait(20), "the status key never said the damaged frame"
        assert t.is_alive()  # said while the loop goes on
    finally:
        daemon.stop()
        t.join(30)
        sub.undeclare()
    problems = out["summary"].input_problems
    assert sum("frame 5 decoded" in p for p in problems) == 1, problems


def test_a_looping_replay_stopped_in_its_first_lap_still_names_its_damaged_frames(
    endpoint: str, listener: zenoh.Session, tmp_path: Path
) -> None:
    """Stopped before the first lap is over (a looping replay stopped early, a service
    stopped), the run still says which frames were left out for their CRC-32, so the frames
    without a partner are not put down to timestamps that disagree."""
    from stereod_fakes.replay import ReplayDriver

    from .test_replay import lossless_recording, with_one_crc_changed

    rec = tmp_path / "rec"
    lossless_recording(rec)
    with_one_crc_changed(rec, 1)
    # 12 frames at 30 Hz, played at a fifth of real time: the first lap takes 2 s.
    daemon = Daemon(
        config(endpoint), ReplayDriver({"path": rec, "loop": True}), rate=0.2, wait_subscriber_s=0
    )
    t, out = start(daemon)
    deadline = time.monotonic() + 30
    while daemon.pairer.stats.frames[Eye.LEFT] < 4 and time.monotonic() < deadline:
        time.sleep(0.02)
    daemon.stop()  # some 8 frames before the first lap's end
    t.join(30)
    problems = out["summary"].input_problems
    assert any("left.mkv: frame 1 decoded" in p for p in problems), problems
    assert not any("timestamps disagree" in p for p in problems), problems


def test_detection_off_publishes_one_empty_message_per_pair(
    endpoint: str, listener: zenoh.Session
) -> None:
    """``[daemon] detect = false``, a benchmark's floor: the same capture, pairing and
    publishing, an objects message per pair at the pipeline's instant, and no objects, where
    the same scene with detection on has its ball tracked. Each run has a rig name of its
    own: the first daemon's session may still deliver as the second starts."""
    got: dict[bool, list[dict]] = {True: [], False: []}
    for detect in (True, False):
        rig = "detecting" if detect else "floor"
        sub = listener.declare_subscriber(
            f"stereod/{rig}/objects",
            lambda s, d=detect: got[d].append(json.loads(s.payload.to_bytes())),
        )
        driver = SyntheticDriver({"duration_s": 2.0, "fps": 15, "skew_s": 0.01})
        cfg = load_config(
            overrides={
                "zenoh": {"connect": [endpoint]},
                "daemon": {"detect": detect},
                "rig": {"name": rig},
            }
        )
        summary = Daemon(cfg, driver).run()
        time.sleep(0.3)
        sub.undeclare()
        assert summary.error is None and summary.pairs == 30
        assert summary.published == 30 and len(got[detect]) == 30
    assert any(m["objects"] for m in got[True])
    assert not any(m["objects"] for m in got[False])
    # Both at the earlier eye's capture (the left here), pair by pair.
    assert [m["t_ns"] for m in got[False]] == [m["t_ns"] for m in got[True]]
    assert all(m["skew_ns"] == 10_000_000 for m in got[False])
