"""Waiting in the main thread so that a signal always ends the wait.

Python runs signal handlers (Ctrl-C's KeyboardInterrupt, a SIGTERM handler) only in the main
thread, between bytecodes. The kernel delivers a process's signal to any thread that does not
block it; when that is one of Zenoh's or OpenCV's native threads, a main thread blocked in
``Event.wait()`` without a timeout is never woken to run the handler, and the process ignores
Ctrl-C and systemd's stop. Waiting in short slices bounds that delay to one slice.
"""

from __future__ import annotations

import threading
import time

from stereod.files.stop import check_stop

SLICE_S = 0.1
"""Longest a signal waits for the main thread to run its handler, s."""


def wait_until(event: threading.Event, timeout_s: float | None = None) -> bool:
    """Wait for ``event`` up to ``timeout_s`` seconds (``None``: for ever), running signal
    handlers at least every :data:`SLICE_S`; whether the event is set."""
    end = None if timeout_s is None else time.monotonic() + timeout_s
    while True:
        left = SLICE_S if end is None else min(SLICE_S, end - time.monotonic())
        if left <= 0:
            return event.is_set()
        if event.wait(left):
            return True
        check_stop()
