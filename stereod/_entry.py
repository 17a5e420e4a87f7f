"""The ``stereod`` command's entry point, as light as a module can be: it sets what Ctrl-C
and SIGHUP do before the command line's imports (a fifth of a second; a command then loads
NumPy, OpenCV or Zenoh as it runs, most of a second more), where Python's defaults would print
a traceback, or end a daemon that a reload was asked of while it started."""

from __future__ import annotations

import signal
import sys


def main() -> int:
    """Run the ``stereod`` command: exit 130 on a Ctrl-C during its imports. SIGHUP is ignored
    until the command is known: the daemon (``run``) then handles it as a reload once it has
    read its configuration, any other command ends on it as on SIGTERM (see
    :func:`stereod.cli.one_shot_signals`)."""
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        from stereod.cli import main as command
    except KeyboardInterrupt:
        return 130
    return command()


if __name__ == "__main__":
    sys.exit(main())
