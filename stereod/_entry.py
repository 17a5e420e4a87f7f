"""The ``stereod`` command's entry point, as light as a module can be: it sets what Ctrl-C
and SIGHUP do before the command line's imports (a fifth of a second; a command then loads
NumPy, OpenCV or Zenoh as it runs, most of a second more), where Python's defaults would print
a traceback, or end a daemon that a reload was asked of while it started."""

from __future__ import annotations

import signal
import sys

HANGUPS: list[int] = []
"""SIGHUPs that came before the command was known (see :func:`main`)."""


def _remember(signum: int, _frame: object) -> None:
    HANGUPS.append(signum)


def main() -> int:
    """Run the ``stereod`` command: exit 130 on a Ctrl-C during its imports. A SIGHUP is only
    remembered until the command is known: a daemon (``run``, ``fuse``) then handles the next
    as a reload once it has read its files (one before that asked for nothing they would not
    read anyway), any other command ends on it as on SIGTERM, at once if it came during
    start-up (see :func:`stereod.cli.one_shot_signals`)."""
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, _remember)
    try:
        from stereod.cli import main as command
    except KeyboardInterrupt:
        return 130
    code = command()
    # The command is over: a signal now (Ctrl-C twice, ``timeout`` signalling the group while
    # the interpreter winds down) changes nothing of what it did, nor its exit code.
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    return code


if __name__ == "__main__":  # (python -m stereod._entry): one module, so one HANGUPS
    sys.modules.setdefault("stereod._entry", sys.modules[__name__])
    sys.exit(main())
