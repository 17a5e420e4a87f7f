"""Signal handlers relayed to a thread of their own (stereod.cli.signals)."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from stereod.cli.signals import relayed

pytestmark = pytest.mark.skipif(
    threading.current_thread() is not threading.main_thread(),
    reason="signal handlers are set from the main thread only",
)


def test_a_handler_runs_on_the_signals_thread_and_the_previous_one_comes_back() -> None:
    got: list[tuple[int, str]] = []
    done = threading.Event()

    def handler(signum: int) -> None:
        got.append((signum, threading.current_thread().name))
        done.set()

    before = signal.getsignal(signal.SIGUSR1)
    with relayed({signal.SIGUSR1: handler}):
        os.kill(os.getpid(), signal.SIGUSR1)
        assert done.wait(5)
    assert got == [(signal.SIGUSR1, "signals")]
    assert signal.getsignal(signal.SIGUSR1) == before
    assert "signals" not in {t.name for t in threading.enumerate()}


def test_a_handler_that_raises_is_logged_and_the_next_signal_still_handled(
    caplog: pytest.LogCaptureFixture,
) -> None:
    calls: list[int] = []
    second = threading.Event()

    def handler(signum: int) -> None:
        calls.append(signum)
        if len(calls) == 1:
            raise RuntimeError("first one fails")
        second.set()

    with (
        caplog.at_level(logging.ERROR, logger="stereod.cli.signals"),
        relayed({signal.SIGUSR2: handler}),
    ):
        os.kill(os.getpid(), signal.SIGUSR2)
        deadline = time.monotonic() + 5
        while not calls and time.monotonic() < deadline:
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGUSR2)
        assert second.wait(5)
    assert calls == [signal.SIGUSR2, signal.SIGUSR2]
    assert "the handler of signal" in caplog.text and "first one fails" in caplog.text


_CHILD = textwrap.dedent(
    """
    import signal, sys, threading, time
    from stereod.cli.signals import relayed

    event = threading.Event()
    count = 0

    def handler(_signum):
        global count
        count += 1
        event.set()

    def spin():
        print("ready", flush=True)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            event.set()  # the main thread holds the event's lock again and again
            event.clear()

    if sys.argv[1] == "relayed":
        with relayed({signal.SIGINT: handler}):
            spin()
    else:
        signal.signal(signal.SIGINT, lambda signum, _frame: handler(signum))
        spin()
    print("done", count, flush=True)
    """
)


def _burst(how: str) -> subprocess.CompletedProcess[str] | None:
    """A process that sets and clears an event in its main thread, sent 300 SIGINTs whose
    handler sets the same event; None when it hung."""
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, how], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
    for _ in range(300):
        proc.send_signal(signal.SIGINT)
        time.sleep(0.0002)
    try:
        out, _ = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return None
    return subprocess.CompletedProcess(proc.args, proc.returncode, out)


def test_a_burst_of_signals_never_deadlocks_a_main_thread_holding_the_handlers_lock() -> None:
    """Ctrl-C pressed twice, or ``timeout`` signalling a process and its group: a handler
    setting an event the main thread was setting waited for itself for ever (a handler set
    directly hangs in this test every time on this machine). Relayed, every run ends."""
    for _ in range(2):
        done = _burst("relayed")
        assert done is not None, "the process hung"
        assert done.returncode == 0 and done.stdout.startswith("done ")
        assert int(done.stdout.split()[1]) > 0


def test_a_signal_handed_on_by_another_handler_runs_that_handlers_work() -> None:
    """A one-shot command's SIGHUP calls whatever handles SIGTERM (``record`` ends on
    either): the relayed SIGTERM handler must take it as its own, not look up a SIGHUP
    handler it was never given."""
    got: list[int] = []
    done = threading.Event()

    def on_term(signum: int) -> None:
        got.append(signum)
        done.set()

    with relayed({signal.SIGTERM: on_term}):
        handler = signal.getsignal(signal.SIGTERM)
        assert callable(handler)
        handler(signal.SIGHUP, None)
        assert done.wait(5)
    assert got == [signal.SIGHUP]


@pytest.mark.parametrize("command", ["subscribe", "view"])
def test_a_second_signal_while_a_consumer_winds_down_keeps_its_clean_exit(command: str) -> None:
    """``subscribe`` and ``view`` end on a signal with 0; a second one 10 ms later (Ctrl-C
    pressed twice, ``timeout`` signalling the group) while they wind down changes nothing (it
    killed them by the signal, 143)."""
    import signal
    import time

    from .conftest import free_endpoint
    from .processes import start_stereod

    extra = ["--port", "0"] if command == "view" else []
    proc = start_stereod(command, "--connect", free_endpoint(), *extra)
    time.sleep(3.0)  # up, and waiting
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err


def test_a_signal_kept_during_start_up_reaches_the_handlers_installed_later() -> None:
    """defer() keeps a SIGUSR2 that came before the command had its handlers (its default
    action would end the process) and relayed() hands it to them once installed."""
    from stereod.cli.signals import defer, deferred_left

    before = signal.getsignal(signal.SIGUSR2)
    got: list[int] = []
    done = threading.Event()
    try:
        defer((signal.SIGUSR2,))
        os.kill(os.getpid(), signal.SIGUSR2)
        time.sleep(0.05)  # still alive: kept, not acted on
        with relayed({signal.SIGUSR2: lambda s: (got.append(s), done.set())}):
            assert done.wait(5)
        assert got == [signal.SIGUSR2]
        assert deferred_left() is None  # taken
    finally:
        signal.signal(signal.SIGUSR2, before)


def test_a_signal_kept_that_no_handler_took_is_left_to_say() -> None:
    from stereod.cli.signals import defer, deferred_left

    before = signal.getsignal(signal.SIGUSR2)
    try:
        defer((signal.SIGUSR2,))
        os.kill(os.getpid(), signal.SIGUSR2)
        time.sleep(0.05)
        assert deferred_left() == signal.SIGUSR2
        assert deferred_left() is None  # forgotten once asked
    finally:
        signal.signal(signal.SIGUSR2, before)


@pytest.mark.parametrize("reaches_handlers, code", [(True, 0), (False, 143)])
def test_a_sigterm_while_a_long_running_command_starts(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], reaches_handlers: bool,
    code: int,
) -> None:  # fmt: skip
    """A SIGTERM while the fusion node (or the daemon) reads its files stops it as one once
    running does (exit 0) when its handlers come; a command that ends before it has any
    (``run --check``) ends as interrupted, 143 with one line. (The default action killed the
    node with no word.)"""
    import stereod.cli as cli
    from stereod.cli import fuse

    stopped: list[int] = []

    def starts(_args: object) -> int:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)  # its files read, its session opened
        if reaches_handlers:
            done = threading.Event()
            with relayed({signal.SIGTERM: lambda s: (stopped.append(s), done.set())}):
                assert done.wait(5)
        return 0

    monkeypatch.setattr(fuse, "run", starts)
    assert cli.main(["fuse", "--room", "room.toml"]) == code
    err = capsys.readouterr().err
    if reaches_handlers:
        assert stopped == [signal.SIGTERM] and err == ""
    else:
        assert err == "stereod: fuse interrupted by SIGTERM\n"


def test_a_signal_kept_for_a_command_that_failed_is_not_handed_to_the_next(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A SIGTERM kept while a node started, which then failed on its files, is forgotten with
    it: a later command in the same process (a test's) does not stop on it at once."""
    import stereod.cli as cli
    from stereod.cli import fuse
    from stereod.errors import ConfigError

    def fails(_args: object) -> int:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
        raise ConfigError("room.toml: bad")

    monkeypatch.setattr(fuse, "run", fails)
    assert cli.main(["fuse", "--room", "room.toml"]) == 78
    got: list[int] = []
    with relayed({signal.SIGTERM: got.append}):
        time.sleep(0.2)
    assert got == []
