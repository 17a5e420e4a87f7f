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

from stereod import __version__
from stereod.cli.common import EPILOG_KEYS, quiet_third_party, stdout_to_nowhere
from stereod.cli.signals import defer, deferred_left
from stereod.errors import (
    EX_IOERR,
    EX_SOFTWARE,
    EX_USAGE,
    InternalError,
    Interrupted,
    ReaderGone,
    StereodError,
    one_line,
)
from stereod.files.output_file import signal_name
from stereod.files.paths import shown
from stereod.files.stop import clear_stop, raise_stop

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
        self._refuse_undecodable(parsed)
        return parsed

    def _refuse_undecodable(self, parsed: argparse.Namespace) -> None:
        """Refuse (64) an argument that is not valid UTF-8 (bytes a terminal or a script
        passed as they were, ``$'caf\\xe9'``): a key expression, a title or a host name
        of such bytes fails deep in Zenoh, matplotlib or asyncio. A path was already refused
        by its own type, naming it."""
        for action in self._chosen_actions(parsed):
            value = getattr(parsed, action.dest, None)
            for item in value if isinstance(value, list) else [value]:
                if isinstance(item, str) and not _is_text(item):
                    flag = "/".join(action.option_strings) or str(action.metavar or action.dest)
                    self.command_parser(parsed).error(
                        f"{flag} {shown(item)}: not valid UTF-8 text; give it in UTF-8"
                    )

    def _chosen_actions(self, parsed: argparse.Namespace) -> list[argparse.Action]:
        """The actions of this parser and of the (sub)commands ``parsed`` chose."""
        found: list[argparse.Action] = []
        for action in self._actions:
            found.append(action)
            if isinstance(action, argparse._SubParsersAction):
                chosen = action.choices.get(getattr(parsed, action.dest, None) or "")
                if isinstance(chosen, Parser):
                    found += chosen._chosen_actions(parsed)
        return found

    def command_parser(self, parsed: argparse.Namespace) -> Parser:
        """The parser of the (sub)command ``parsed`` chose, innermost first: this one when it
        has no subcommands."""
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                chosen = action.choices.get(getattr(parsed, action.dest, None) or "")
                if isinstance(chosen, Parser):
                    return chosen.command_parser(parsed)
        return self


def _is_text(value: str) -> bool:
    """Whether ``value`` is valid text: no lone surrogates (undecodable bytes of argv)."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


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
        # argv as it is, bytes that are not UTF-8 escaped (\xff): the log is always written
        with path.open("w", encoding="utf-8", errors="backslashreplace") as fh:
            fh.write(f"stereod {__version__}: {' '.join(sys.argv)}\n")
            traceback.print_exception(exc, file=fh)
    except Exception:  # no folder, a full disk: the one line says the details are lost
        return None
    return path


def one_shot_signals(command: str) -> None:
    """SIGTERM and SIGHUP (a closed terminal, ``kill -HUP``) end a one-shot command (every
    one but the daemon, whose SIGHUP reloads) as Ctrl-C does: :class:`Interrupted` unwinds
    it, so an output being written removes its temporary file and a recording being made
    is finished or removed as its command says (exit 143 or 129). A command that handles
    SIGTERM itself (``record``'s normal end, ``export``) sees SIGHUP through that same
    handler, whenever it is installed."""

    def on_term(signum: int, _frame: Any) -> None:
        raise_stop(f"{command} interrupted by {signal_name(signum)}", signum)

    def on_hup(signum: int, frame: Any) -> None:
        handler = signal.getsignal(signal.SIGTERM)
        if callable(handler):
            handler(signum, frame)
        elif handler != signal.SIG_IGN:
            on_term(signum, frame)

    if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGHUP, on_hup)
    from stereod._entry import HANGUPS

    if HANGUPS:  # a hang-up during start-up: the command ends before it does anything
        HANGUPS.clear()
        on_hup(signal.SIGHUP, None)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``stereod`` console script; returns the exit code."""
    quiet_third_party()
    saved = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)}
    stdout = sys.stdout
    if stdout is not None:  # None: started with stdout closed (>&-), and print writes nothing
        sys.stdout = _Watched(stdout)  # type: ignore[assignment]
    try:
        return _main(argv)
    finally:  # a caller in this process (a test) gets its own handlers and stdout back
        sys.stdout = stdout
        clear_stop()
        deferred_left()  # and no signal kept for a command that ended on an error
        for signum, handler in saved.items():
            if handler is not None:
                signal.signal(signum, handler)


def _main(argv: Sequence[str] | None) -> int:
    try:
        args = build_parser().parse_args(argv)
        reloads = getattr(args, "reloads_on_sighup", False)
        if not reloads:
            one_shot_signals(args.command)
        else:  # its handlers come with its files: until then a SIGHUP is ignored, and a
            signal.signal(signal.SIGHUP, signal.SIG_IGN)  # SIGTERM kept for them
            defer((signal.SIGTERM,))
        code: int = args.func(args)
        early = deferred_left() if reloads else None
        if early is not None and code == 0:  # ended before its handlers were in
            raise Interrupted(f"{args.command} interrupted by {signal_name(early)}", early)
        if sys.stdout is not None:  # what is still buffered fails here, not at the exit
            sys.stdout.flush()
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
    except OSError as exc:
        if not isinstance(sys.stdout, _Watched) or sys.stdout.failed is not exc:
            return _internal(exc)
        # `stereod schema > /dev/full`: the user's output, not our bug; the interpreter's own
        # last flush goes nowhere, so this line is the only one.
        print(f"stereod: cannot write to standard output: {exc.strerror or exc}", file=sys.stderr)
        stdout_to_nowhere()
        return EX_IOERR
    except Exception as exc:  # the last guard: one line, the details in a file
        return _internal(exc)


def _internal(exc: BaseException) -> int:
    """An unexpected ``exc``: one line, the details in a file, and exit 70."""
    print(
        f"stereod: internal error: {type(exc).__name__}: {one_line(str(exc))[:200]} "
        f"({_details(exc)})",
        file=sys.stderr,
    )
    return EX_SOFTWARE


class _Watched:
    """Standard output that remembers the error a write or flush of it raised, so that the
    user's full disk behind ``> FILE`` is told apart from an error of ours."""

    def __init__(self, stream: Any) -> None:
        self._stream = stream
        self.failed: OSError | None = None

    def write(self, text: str) -> int:
        try:
            return int(self._stream.write(text))
        except OSError as exc:
            self.failed = exc
            raise

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as exc:
            self.failed = exc
            raise

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def _details(exc: BaseException) -> str:
    """Where the traceback of an unexpected ``exc`` went (its crash log), for its one line."""
    path = crash_log(exc)
    where = f"details in {path}" if path else "and the details could not be written"
    return f"{where}; please report it"


if __name__ == "__main__":
    sys.exit(main())
