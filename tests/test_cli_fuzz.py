"""Fuzzing the command line: every command's flags with any values, parsed in-process (many
examples), and a few whole runs of ``stereod`` as a subprocess. Whatever is typed: a run, or
one line on stderr and a sysexits code, in bounded time, never a traceback, the inputs
unchanged."""

from __future__ import annotations

import argparse
import contextlib
import io
import subprocess
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from stereod.cli import build_parser
from stereod_fakes.synth import Ball, Scene, write_scene

from .fuzz import EXAMPLES, FUZZ, SYSEXITS, digest, huge_numbers, not_killed
from .processes import run_stereod

PARSER = build_parser()
COMMANDS: dict[str, argparse.ArgumentParser] = next(
    a.choices for a in PARSER._actions if isinstance(a, argparse._SubParsersAction)
)


def options(parser: argparse.ArgumentParser) -> list[str]:
    """Every option string of a parser and of its sub-commands, --help and --version aside."""
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                out += options(sub)
        elif not isinstance(action, argparse._HelpAction | argparse._VersionAction):
            out += action.option_strings
    return sorted(set(out))


values = st.one_of(
    st.text(max_size=12),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(2**70), 2**70).map(str),
    huge_numbers,
    st.sampled_from(
        ["nan", "-1", "0", "1e-300", "1e400", "100000x100", "0x0", "r\udcff", "a//b", "heading=nan"]
    ),
)

argv_values = values.filter(lambda v: "\x00" not in v)
"""What a process can be given: execve cannot pass an argument holding a NUL."""


@st.composite
def command_lines(draw: st.DrawFn) -> list[str]:
    name = draw(st.sampled_from(sorted(COMMANDS)))
    sub = COMMANDS[name]
    argv = [name]
    sub_commands = [a for a in sub._actions if isinstance(a, argparse._SubParsersAction)]
    if sub_commands:
        argv.append(draw(st.sampled_from(sorted(sub_commands[0].choices))))
    flags = options(sub)
    for _ in range(draw(st.integers(0, 4)) if flags else 0):
        argv.append(draw(st.sampled_from(flags)))
        if draw(st.booleans()):
            argv.append(draw(values))
    if draw(st.booleans()):
        argv.append(draw(values))  # a positional
    return argv


@settings(FUZZ, max_examples=EXAMPLES * 5)
@given(argv=command_lines())
@example(argv=["replay", "--rate", "nan"])
@example(argv=["synth", "out", "--ball", "heading=nan"])
@example(argv=["demo", "--heading", "nan"])
@example(argv=["subscribe", "--count", "-1"])
@example(argv=["replay", "r\udcff"])
@example(argv=["view", "--foxglove-port", "9" * 1001])  # OverflowError: an int is no float
def test_every_flag_parses_or_is_one_line_64(argv: list[str]) -> None:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            build_parser().parse_args(argv)
        except SystemExit as exc:
            assert exc.code == 64, (exc.code, err.getvalue())
            lines = err.getvalue().splitlines()
            assert len(lines) == 1 and lines[0].startswith("stereod"), err.getvalue()


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    scene = Scene(width_px=32, height_px=24, fps=10, duration_s=0.5, balls=[Ball()])
    return write_scene(scene, tmp_path_factory.mktemp("rec") / "rec")


RUN_FLAGS = [
    "--baseline",
    "--hfov",
    "--beta",
    "--threshold",
    "--min-area",
    "--warmup",
    "--time-base",
    "--rig",
    "--prefix",
    "--mode",
    "--connect",
    "--listen",
    "--calibration",
]


@settings(FUZZ, max_examples=8, deadline=None)  # whole processes: each takes about a second
@given(
    command=st.sampled_from(["replay", "check"]),
    flags=st.lists(st.tuples(st.sampled_from(RUN_FLAGS), argv_values), max_size=3),
)
def test_whole_runs(tmp_path_factory, recording: Path, command: str, flags: list) -> None:
    extra = [x for flag, value in flags for x in (flag, value)]
    if command == "replay":
        argv = ["replay", str(recording), "--rate", "0", "-q", "--listen", "tcp/127.0.0.1:0"]
    else:
        argv = ["run", "--driver", "synthetic", "--check"]
    before = {p: digest(p) for p in recording.iterdir()}
    try:
        res = run_stereod(*argv, *extra, timeout=60, cwd=tmp_path_factory.mktemp("cwd"))
    except subprocess.TimeoutExpired:
        pytest.fail(f"stereod {' '.join(argv + extra)!r} hung")
    lines = res.stderr.splitlines()
    not_killed(res.returncode, res.stderr)
    assert res.returncode in {0} | (SYSEXITS - {70}), res.stderr
    assert "Traceback" not in res.stderr, res.stderr
    if res.returncode:
        assert len(lines) == 1 and lines[0].startswith("stereod"), res.stderr
    assert {p: digest(p) for p in recording.iterdir()} == before


def test_every_flag_and_argument_of_every_command_says_what_it_is_for() -> None:
    """``--help`` explains every flag: none is listed bare (``fuse --log-level`` was)."""

    def bare(parser: argparse.ArgumentParser, path: str) -> list[str]:
        out = []
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    out += bare(sub, f"{path} {name}")
            elif not action.help and action.help != argparse.SUPPRESS:
                out.append(f"{path} {'/'.join(action.option_strings) or action.dest}")
        return out

    assert bare(PARSER, "stereod") == []
