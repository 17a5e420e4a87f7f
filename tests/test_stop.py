"""A stop signal whose exception library code swallows still stops a one-shot command, and
still keeps its output from being committed."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from stereod.cli import one_shot_signals
from stereod.cli.interrupt import wait_until
from stereod.errors import Interrupted
from stereod.files.output_file import AtomicOutput, stopped_by_signals
from stereod.files.stop import check_stop, clear_stop
from stereod.sources.frames import Eye, EyeSource, Frame, merged


def _swallowed_sigterm() -> None:
    """What an import or a regex compile does to a signal's exception when it lands inside a
    broad ``except Exception``: nothing is left of it."""
    with contextlib.suppress(Exception):
        signal.raise_signal(signal.SIGTERM)


class _Eye(EyeSource):
    """An endless eye that, at one frame, runs library code which swallows a signal."""

    def __init__(self, eye: Eye, swallow_at: int | None) -> None:
        self.eye = eye
        self.swallow_at = swallow_at
        self.k = 0

    def read(self) -> Frame | None:
        if self.k == self.swallow_at:
            _swallowed_sigterm()
        self.k += 1
        return Frame(self.eye, np.zeros((4, 4), np.uint8), self.k * 1000, self.k)


@pytest.fixture
def own_handlers() -> Iterator[None]:
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        yield
    finally:
        clear_stop()
        for s, h in saved.items():
            signal.signal(s, h)


@pytest.mark.usefixtures("own_handlers")
def test_a_live_loop_stops_on_the_frame_after_a_swallowed_sigterm() -> None:
    one_shot_signals("calibrate")
    seen = 0
    with pytest.raises(Interrupted) as info:
        for _frame in merged(_Eye(Eye.LEFT, 5), _Eye(Eye.RIGHT, None)):
            seen += 1
            assert seen < 100, "the loop ran on after SIGTERM"
    assert info.value.exit_code == 128 + signal.SIGTERM
    assert "calibrate interrupted by SIGTERM" in str(info.value)
    assert seen <= 12


@pytest.mark.usefixtures("own_handlers")
def test_an_output_is_not_committed_after_a_swallowed_sigterm(tmp_path: Path) -> None:
    out = tmp_path / "calibration.json"
    out.write_text("the old one")
    with pytest.raises(Interrupted), stopped_by_signals("calibrate", out), AtomicOutput(out) as f:
        f.write(b"half a new one")
        _swallowed_sigterm()
    assert out.read_text() == "the old one"
    assert [p.name for p in tmp_path.iterdir()] == ["calibration.json"]
    check_stop()  # the command ended: nothing is left pending


@pytest.mark.usefixtures("own_handlers")
def test_a_wait_in_the_main_thread_ends_on_a_swallowed_sigterm() -> None:
    one_shot_signals("subscribe")
    _swallowed_sigterm()
    with pytest.raises(Interrupted):
        wait_until(threading.Event(), 5.0)


@pytest.mark.usefixtures("own_handlers")
def test_a_pending_stop_is_the_main_threads_and_ends_with_its_command() -> None:
    one_shot_signals("record")
    _swallowed_sigterm()
    raised: list[BaseException] = []

    def worker() -> None:
        try:
            check_stop()
        except BaseException as exc:
            raised.append(exc)

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert raised == []
    with pytest.raises(Interrupted):
        check_stop()
    clear_stop()
    check_stop()
