"""The ``stereod`` command line: one module per command, found like drivers are.

Every command is a module with ``register(subparsers)``, listed in the ``stereod.commands``
entry-point group: the core's commands here, and commands that belong to a plug-in package in
that package (``synth`` in the fakes, ``devices`` in the V4L2 driver), so the core never
imports a driver by name. Shared options live in :mod:`.common`.

Every command ends with at most one line on stderr and a sysexits code: a
:class:`~stereod.errors.StereodError` is its own message and code, a bad flag is exit 64, and
anything unexpected is written in full to a crash log and summed up in one line, exit 70.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import time
import traceback
from collections.abc import Sequence
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, NoReturn

from .. import __version__
from ..errors import EX_SOFTWARE, EX_USAGE, InternalError, ReaderGone, StereodError, one_line
from .common import EPILOG_KEYS, quiet_third_party

GROUP = "stereod.commands"

ORDER = (
    "run",
    "replay",
    "subscribe",
    "view",
    "demo",
    "synth",
    "record",
    "export",
    "calibrate",
    "calibration",
    "devices",
    "install-service",
    "schema",
)
"""The order of the commands in ``--help`` (others follow, by name)."""


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error and exit 64, pointing to the help of the command whose
    line it is (``stereod replay --help`` for a flag ``replay`` does not have), and no
    abbreviated flags: ``--json out`` is refused, not taken for ``--jsonl out``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: {one_line(message)} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(EX_USAGE)

    def parse_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> argparse.Namespace:
        # argparse reports unknown arguments from the top-level parser, whose help does not
        # list a command's flags: report them from the command's own parser instead.
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            self.command_parser(parsed).error(f"unrecognized arguments: {' '.join(extras)}")
        return parsed

    def command_parser(self, parsed: argparse.Namespace) -> Parser:
        """The parser of the (sub)command ``parsed`` chose, innermost first: this one when it
        has no subcommands."""
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                chosen = action.choices.get(getattr(parsed, action.dest, None) or "")
                if isinstance(chosen, Parser):
                    return chosen.command_parser(parsed)
        return self


def build_parser() -> argparse.ArgumentParser:
    """The parser with every installed command."""
    parser = Parser(
        prog="stereod",
        description="Stereo motion daemon: finds moving objects in a stereo webcam's two views, "
        "triangulates them to 3D (m), tracks them, and publishes position, velocity (m/s), speed "
        "and heading (deg) over Zenoh.",
        epilog=EPILOG_KEYS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"stereod {__version__}")
    sub = parser.add_subparsers(
        dest="command", metavar="COMMAND", required=True, parser_class=Parser
    )
    found = {ep.name: ep for ep in entry_points(group=GROUP)}
    rank = {name: i for i, name in enumerate(ORDER)}
    for name in sorted(found, key=lambda n: (rank.get(n, len(ORDER)), n)):
        try:
            module = found[name].load()
        except ImportError:  # a plug-in whose dependencies are missing lacks its command
            continue
        module.register(sub)
    return parser


def crash_log(exc: BaseException) -> Path | None:
    """Write the traceback of an unexpected exception to a file; its path, or None."""
    directory = Path(os.environ.get("STEREOD_CRASH_DIR") or tempfile.gettempdir())
    path = directory / f"stereod-crash-{time.strftime('%Y%m%dT%H%M%S')}-{os.getpid()}.log"
    try:
        with path.open("w") as fh:
            fh.write(f"stereod {__version__}: {' '.join(sys.argv)}\n")
            traceback.print_exception(exc, file=fh)
    except OSError:
        return None
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``stereod`` console script; returns the exit code."""
    quiet_third_party()
    try:
        args = build_parser().parse_args(argv)
        if not getattr(args, "reloads_on_sighup", False) and hasattr(signal, "SIGHUP"):
            signal.signal(signal.SIGHUP, signal.SIG_DFL)  # a closed terminal ends the command
        code: int = args.func(args)
        return code
    except StereodError as exc:
        if isinstance(exc, ReaderGone) and exc.stdout:  # `--jsonl /dev/stdout | head`
            return 0  # as for stdout's own reader below
        line = one_line(str(exc))
        if isinstance(exc, InternalError) and exc.__cause__ is not None:
            # An unexpected exception another thread caught and named: its traceback too.
            line += f" ({_details(exc)})"
        print(f"stereod: {line}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # stdout went away (`stereod subscribe | head`): nothing more to say to anyone.
        sys.stderr.close()
        return 0
    except Exception as exc:  # the last guard: one line, the details in a file
        print(
            f"stereod: internal error: {type(exc).__name__}: {one_line(str(exc))[:200]} "
            f"({_details(exc)})",
            file=sys.stderr,
        )
        return EX_SOFTWARE


def _details(exc: BaseException) -> str:
    """Where the traceback of an unexpected ``exc`` went (its crash log), for its one line."""
    path = crash_log(exc)
    where = f"details in {path}" if path else "and the details could not be written"
    return f"{where}; please report it"


if __name__ == "__main__":
    sys.exit(main())
