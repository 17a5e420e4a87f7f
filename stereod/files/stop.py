"""A stop signal that is not lost when library code swallows the exception it raised.

A one-shot command stops on Ctrl-C or SIGTERM by raising :class:`Interrupted` from the signal
handler, in whatever frame the main thread is running. When that frame is inside library code
with a broad ``except Exception`` (an import, a regular expression being compiled, a codec
lookup), the exception is swallowed and the command would run on, a live one for ever. So the
handler also keeps the stop pending: the command's loops call :func:`check_stop` at each step,
and an output is never committed while a stop is pending.
"""

from __future__ import annotations

import threading
from typing import NoReturn

from stereod.errors import Interrupted

__all__ = ["check_stop", "clear_stop", "pending_stop", "raise_stop"]

_pending: tuple[str, int] | None = None


def raise_stop(message: str, signum: int) -> NoReturn:
    """Keep the stop pending, then raise it here (from a signal handler, in the main thread)."""
    global _pending
    _pending = (message, signum)
    raise Interrupted(message, signum)


def pending_stop() -> Interrupted | None:
    """The stop a signal asked for and nothing has cleared, or None."""
    return None if _pending is None else Interrupted(*_pending)


def check_stop() -> None:
    """Raise the pending stop, if any, when called in the main thread (where signal handlers
    run; a worker thread's loop is stopped by its own owner, not by this)."""
    if _pending is not None and threading.current_thread() is threading.main_thread():
        raise Interrupted(*_pending)


def clear_stop() -> None:
    """Forget a pending stop: the command it stopped has ended."""
    global _pending
    _pending = None
