"""Waiting in the main thread: a signal that lands on another thread still ends the wait."""

from __future__ import annotations

import signal
import threading

from stereod.cli.interrupt import wait_until


def test_a_signal_delivered_to_another_thread_still_runs_its_handler_during_the_wait() -> None:
    """The kernel may hand a process's signal to any thread (Zenoh's native ones, say). Python
    then runs the handler only when the main thread next runs bytecode: a plain
    ``Event.wait(5)`` returns False after 5 s, with the handler run too late. ``wait_until``
    sees the event the handler sets."""
    done = threading.Event()
    previous = signal.signal(signal.SIGUSR1, lambda *_: done.set())
    release = threading.Event()
    other = threading.Thread(target=release.wait, args=(10,))
    other.start()
    try:
        assert other.ident is not None
        signal.pthread_kill(other.ident, signal.SIGUSR1)
        assert wait_until(done, 5.0)
    finally:
        release.set()
        other.join()
        signal.signal(signal.SIGUSR1, previous)


def test_wait_until_times_out_and_returns_at_once_when_set() -> None:
    ev = threading.Event()
    assert not wait_until(ev, 0.25)
    ev.set()
    assert wait_until(ev)
    assert wait_until(ev, 0.0)
