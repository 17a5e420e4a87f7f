"""Signal handlers that take no lock: their work runs on a thread of its own.

Python runs a signal's handler in the main thread, between two bytecodes, whatever that
thread is doing at the time: taking the lock of a ``threading.Event`` it is setting, say. A
handler that takes the same lock (``Event.set``, a daemon's ``stop``) then waits for itself
for ever, which a burst of signals (Ctrl-C pressed twice, ``timeout`` signalling the process
and its group) makes likely. :func:`relayed` installs handlers that only put the signal's
number on a :class:`queue.SimpleQueue` (whose ``put`` may interrupt itself), and calls the
real handlers from a thread that reads that queue, where a lock is only ever waited for.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import signal
import threading
from collections.abc import Callable, Iterator, Mapping
from types import FrameType
from typing import Any

log = logging.getLogger(__name__)


_EARLY: list[int] = []
"""Signals :func:`defer` kept, in the order they came, until a :func:`relayed` block takes
them."""


def defer(signums: tuple[signal.Signals, ...]) -> None:
    """Until a :func:`relayed` block installs handlers for them, each of ``signums`` is kept
    instead of acted on, and handed to those handlers then: a long-running command still
    starting (reading its files, before its outputs or its session are open) then stops as
    it would once running, not killed by the signal's default action. Off the main thread
    nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        return

    def keep(signum: int, _frame: FrameType | None) -> None:
        _EARLY.append(signum)  # a list's append is atomic: no lock a handler could wait on

    for signum in signums:
        signal.signal(signum, keep)


def deferred_left() -> int | None:
    """The first signal :func:`defer` kept that no :func:`relayed` block took (the command
    ended before it had one, as ``run --check`` does), or None; they are forgotten."""
    left = _EARLY[0] if _EARLY else None
    _EARLY.clear()
    return left


@contextlib.contextmanager
def relayed(handlers: Mapping[signal.Signals, Callable[[int], None]]) -> Iterator[None]:
    """Within the block, each signal of ``handlers`` calls its handler with the signal's
    number on the ``signals`` thread (in the order they came); after it the previous handlers
    are back. A signal handed to one of these handlers by another (a one-shot command's
    SIGHUP calls whatever handles SIGTERM) runs that handler's work, with its own number. A
    handler that raises is logged, and the next signal is still handled. Off the main thread
    (where no handler can be set) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: queue.SimpleQueue[tuple[signal.Signals, int] | None] = queue.SimpleQueue()

    def catcher(installed: signal.Signals) -> Callable[[int, FrameType | None], None]:
        def on_signal(signum: int, _frame: FrameType | None) -> None:
            pending.put((installed, signum))

        return on_signal

    def relay() -> None:
        while (caught := pending.get()) is not None:
            installed, signum = caught
            try:
                handlers[installed](signum)
            except Exception:
                log.exception("the handler of signal %d failed", signum)

    thread = threading.Thread(target=relay, name="signals", daemon=True)
    thread.start()
    previous: dict[signal.Signals, Callable[[int, FrameType | None], Any] | int | None] = {}
    try:
        for signum in handlers:
            previous[signum] = signal.signal(signum, catcher(signum))
        for kept in [k for k in _EARLY if k in handlers]:  # kept by defer() until now
            _EARLY.remove(kept)
            pending.put((signal.Signals(kept), kept))
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        pending.put(None)
        thread.join()
